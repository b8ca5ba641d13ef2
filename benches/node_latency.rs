//! End-to-end latency of the live node on loopback, with two peers in turn publishing the
//! detections of a simulated 150 + 900 fps rally at their recorded pace and reading
//! `/ball/state` and `/ball/intercept`; the latency of each output is the time from the peer's
//! write of a detection to its read of the output with that stamp:
//! - a DDS peer we did not write (Eclipse Cyclone DDS through its Python binding,
//!   `tests/interop/dds_peer.py`): both DDS stacks and a Python interpreter;
//! - `ttball play --latency` (RustDDS, native code): the node's latency with a light peer.
//!
//! `ttball node` and the peer run in a network namespace with only loopback (`unshare -n`), both
//! limited to 127.0.0.1. The node prints its own share (received by DDS to published) when it
//! stops.
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
    let script = format!(
        r#"
export ROS_DOMAIN_ID=43 ROS_LOCALHOST_ONLY=1
cd "{dir}"
"{ttball}" node > node.out 2> node.err &
node=$!
"{python}" "{peer}" publish "{bag}" --wait-match 30 --out peer.json 2> peer.err
kill -TERM $node
wait $node
"{ttball}" node > node_rust.out 2> node_rust.err &
node=$!
"{ttball}" play "{bag}" --latency --wait 30 > play.out 2> play.err
kill -TERM $node
wait $node
"#,
        dir = dir.display(),
        python = python.display(),
        peer = root.join("tests/interop/dds_peer.py").display(),
        bag = bag.display(),
    );
    common::run_on_loopback_only(&script);
    let read = |name: &str| std::fs::read_to_string(dir.join(name)).unwrap_or_default();
    println!("== Cyclone DDS (Python) peer");
    println!("{}", read("peer.err").trim());
    println!("{}", read("node.out").trim());
    println!("== ttball play --latency (RustDDS) peer");
    println!("{}", read("play.out").trim());
    println!("{}", read("node_rust.out").trim());
    let _ = std::fs::remove_dir_all(&dir);
}
