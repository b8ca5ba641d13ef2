//! End-to-end latency of the live node on loopback, with two peers in turn publishing the
//! detections of a simulated 150 + 900 fps rally at their recorded pace and reading
//! `/ball/state` and `/ball/intercept`; the latency of each output is the time from the peer's
//! write of a detection to its read of the output with that stamp:
//! - a DDS peer we did not write (Eclipse Cyclone DDS through its Python binding,
//!   `tests/interop/dds_peer.py`): both DDS stacks and a Python interpreter;
//! - `ttball play --latency` (RustDDS, native code): the node's latency with a light peer; then
//!   again with the node's threads on one core (`node.cpus`).
//!
//! `ttball node` and the peer run in a network namespace with only loopback (`unshare -n`), both
//! limited to 127.0.0.1. The node prints its own share (received by DDS to published) when it
//! stops; the CPU time the hypervisor took for other guests during each run (`steal` in
//! `/proc/stat`) is printed beside it, as the tail follows it.
//!
//! `TTBALL_PYTHON=target/interop-venv/bin/python cargo bench --bench node_latency` (the venv that
//! `.ci/run` makes: `pip install cyclonedds mcap`). Needs permission to make a network namespace.
//! Under `cargo test --benches` it only says how to run it.
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    clippy::panic,
    reason = "benchmark: fail loudly"
)]

use std::path::PathBuf;
use std::process::Command;

#[path = "../tests/common/mod.rs"]
mod common;

/// Shots of the simulated rally (about 1.15 s each).
const SHOTS: usize = 50;

fn main() {
    if !std::env::args().any(|a| a == "--bench") {
        println!("node_latency: run with `cargo bench --bench node_latency` (and TTBALL_PYTHON)");
        return;
    }
    let Some(python) = std::env::var_os("TTBALL_PYTHON").map(PathBuf::from) else {
        println!("node_latency: set TTBALL_PYTHON to a Python with cyclonedds and mcap");
        return;
    };
    let root = common::root();
    let ttball = env!("CARGO_BIN_EXE_ttball");
    let dir = common::scratch("latency");
    let bag = dir.join("rally.mcap");
    let simulated = Command::new(ttball)
        .args([
            "simulate",
            "--shots",
            &SHOTS.to_string(),
            "--seed",
            "3",
            "-o",
        ])
        .arg(&bag)
        .status()
        .unwrap();
    assert!(simulated.success());
    // The node's threads on one core for the third run: the last this process may use.
    let cpu = std::thread::available_parallelism().map_or(0, |n| n.get() - 1);
    let script = format!(
        r#"
export ROS_DOMAIN_ID=43 ROS_LOCALHOST_ONLY=1
cd "{dir}"
# CPU time the hypervisor gave other guests while a run ran (/proc/stat "steal", 1/100 s).
steal() {{ awk '/^cpu /{{print $9}}' /proc/stat 2>/dev/null || echo 0; }}
s0=$(steal)
"{ttball}" node > node.out 2> node.err &
node=$!
"{python}" "{peer}" publish "{bag}" --wait-match 30 --out peer.json 2> peer.err
kill -TERM $node
wait $node
s1=$(steal)
"{ttball}" node > node_rust.out 2> node_rust.err &
node=$!
"{ttball}" play "{bag}" --latency --wait 30 > play.out 2> play.err
kill -TERM $node
wait $node
s2=$(steal)
"{ttball}" node -p "node.cpus:={cpu}" > node_pinned.out 2> node_pinned.err &
node=$!
"{ttball}" play "{bag}" --latency --wait 30 > play_pinned.out 2> play_pinned.err
kill -TERM $node
wait $node
s3=$(steal)
echo "$((s1 - s0)) $((s2 - s1)) $((s3 - s2))" > steal.txt
"#,
        dir = dir.display(),
        python = python.display(),
        peer = root.join("tests/interop/dds_peer.py").display(),
        bag = bag.display(),
    );
    common::run_on_loopback_only(&script);
    let read = |name: &str| std::fs::read_to_string(dir.join(name)).unwrap_or_default();
    let steal: Vec<String> = read("steal.txt")
        .split_whitespace()
        .map(|ticks| format!("hypervisor steal during the run: {ticks} x 10 ms of CPU time"))
        .collect();
    let steal = |run: usize| steal.get(run).cloned().unwrap_or_default();
    println!("== Cyclone DDS (Python) peer; {}", steal(0));
    println!("{}", read("peer.err").trim());
    println!("{}", read("node.out").trim());
    println!("== ttball play --latency (RustDDS) peer; {}", steal(1));
    println!("{}", read("play.out").trim());
    println!("{}", read("node_rust.out").trim());
    println!(
        "== ttball play --latency (RustDDS) peer, the node's threads on CPU {cpu} (node.cpus); {}",
        steal(2)
    );
    println!("{}", read("play_pinned.out").trim());
    println!("{}", read("node_pinned.out").trim());
    let _ = std::fs::remove_dir_all(&dir);
}
