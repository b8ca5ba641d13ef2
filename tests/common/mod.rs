//! Helpers shared by the integration tests that run the `ttball` binary.
#![allow(dead_code, reason = "each test file uses the helpers it needs")]
#![allow(clippy::panic, reason = "test code: fail loudly")]

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// The package's root directory.
pub fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

/// Runs `ttball` from the package root and returns its output, whatever its exit code.
pub fn run(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_ttball"))
        .current_dir(root())
        .args(args)
        .output()
        .unwrap_or_else(|e| panic!("cannot run ttball: {e}"))
}

/// Runs `ttball`, asserts that it succeeded and returns its standard output.
pub fn ok(args: &[&str]) -> String {
    let out = run(args);
    assert!(
        out.status.success(),
        "ttball {args:?}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout).into_owned()
}

/// Whether this process may make a network namespace (`unshare -n`: root, or unprivileged user
/// namespaces), which [`run_on_loopback_only`] needs.
pub fn can_isolate_network() -> bool {
    Command::new("unshare")
        .args(["-n", "true"])
        .status()
        .is_ok_and(|s| s.success())
}

/// Runs a bash `script` in a new network namespace where only loopback is up (with multicast,
/// for DDS discovery), so nothing it sends leaves the machine; returns its exit status. Fails when
/// the namespace cannot be set up.
pub fn run_on_loopback_only(script: &str) -> std::process::ExitStatus {
    let script = format!(
        "ip link set lo up && ip link set lo multicast on && ip route add 224.0.0.0/4 dev lo || exit 90\n{script}"
    );
    let status = Command::new("unshare")
        .args(["-n", "bash", "-c", &script])
        .status()
        .unwrap_or_else(|e| panic!("cannot run unshare: {e}"));
    assert_ne!(
        status.code(),
        Some(90),
        "cannot set up loopback in the namespace"
    );
    status
}

/// A directory of this test process under Cargo's `target/tmp` (not the system's temporary
/// directory: `cargo clean` removes what tests leave).
pub fn scratch(name: &str) -> PathBuf {
    let d = Path::new(env!("CARGO_TARGET_TMPDIR")).join(format!("{name}-{}", std::process::id()));
    std::fs::create_dir_all(&d).unwrap_or_else(|e| panic!("cannot create {}: {e}", d.display()));
    d
}
