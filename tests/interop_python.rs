//! Interoperability with MCAP clients ttball did not write: Python `mcap` + `mcap-ros2-support`
//! and `rosbags` decode every message of a replay's output, smoothed (`ttball smooth`), to the
//! same values ttball wrote, and a bag written by `mcap-ros2-support` replays in ttball.
//!
//! Needs a Python with those packages: `.ci/run` makes a virtual environment and sets
//! `TTBALL_PYTHON` to its interpreter. Without it the test says so and passes, except under CI
//! (`CI=true`), where a missing interpreter fails it.
#![cfg(feature = "cli")]
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    reason = "test code: fail loudly"
)]

use std::path::{Path, PathBuf};
use std::process::Command;

mod common;

use common::ok as ttball;

fn dir() -> PathBuf {
    common::scratch("interop")
}

fn python() -> Option<PathBuf> {
    match std::env::var_os("TTBALL_PYTHON") {
        Some(p) => Some(PathBuf::from(p)),
        None => {
            assert!(
                std::env::var("CI").as_deref() != Ok("true"),
                "CI must set TTBALL_PYTHON (see .ci/run)"
            );
            eprintln!(
                "skipped: set TTBALL_PYTHON to a Python with mcap, mcap-ros2-support and rosbags (see .ci/run)"
            );
            None
        }
    }
}

fn script(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/interop")
        .join(name)
}

#[test]
fn python_clients_decode_every_message_ttball_writes_to_the_same_values() {
    let Some(python) = python() else { return };
    let d = dir();
    let sim = d.join("sim.mcap");
    let out = d.join("out.mcap");
    let s = |p: &Path| p.to_str().unwrap().to_string();
    ttball(&[
        "simulate",
        "--output",
        &s(&sim),
        "--shots",
        "2",
        "--seed",
        "5",
    ]);
    let replayed = d.join("replayed.mcap");
    ttball(&[
        "replay",
        &s(&sim),
        "--output",
        &s(&replayed),
        "-p",
        "topics.odometry:=ball/odometry",
    ]);
    // Smoothing the replay's output adds /ball/smoothed to everything above.
    ttball(&["smooth", &s(&replayed), "--output", &s(&out)]);
    let dump = ttball(&["dump", &s(&out)]);
    let dump_path = d.join("out.jsonl");
    std::fs::write(&dump_path, &dump).unwrap();
    let check = Command::new(&python)
        .arg(script("check_bag.py"))
        .arg(&out)
        .arg(&dump_path)
        .output()
        .unwrap();
    let report = String::from_utf8_lossy(&check.stdout);
    assert!(
        check.status.success(),
        "{report}{}",
        String::from_utf8_lossy(&check.stderr)
    );
    for topic in [
        "/ball/detections",
        "/ball/state",
        "/ball/intercept",
        "/ball/trajectory",
        "/ball/markers",
        "/ball/odometry",
        "/ball/truth",
        "/ball/smoothed",
    ] {
        assert!(
            report.contains(&format!("{topic}: ")),
            "{topic} not checked: {report}"
        );
    }
    // The standard types, decoded by rosbags' own Humble and Jazzy definitions as well.
    for standard in [
        "visualization_msgs/msg/MarkerArray (humble)",
        "visualization_msgs/msg/MarkerArray (jazzy)",
        "nav_msgs/msg/Odometry (humble)",
        "nav_msgs/msg/Odometry (jazzy)",
    ] {
        assert!(
            report.contains(standard),
            "{standard} not checked: {report}"
        );
    }
}

#[test]
fn a_bag_written_by_mcap_ros2_support_replays_in_ttball() {
    let Some(python) = python() else { return };
    let d = dir();
    let bag = d.join("python.mcap");
    let write = Command::new(&python)
        .arg(script("write_bag.py"))
        .arg(&bag)
        .arg(Path::new(env!("CARGO_MANIFEST_DIR")).join("msgs/msg"))
        .output()
        .unwrap();
    assert!(
        write.status.success(),
        "{}",
        String::from_utf8_lossy(&write.stderr)
    );
    let out = d.join("python-out.mcap");
    let summary = ttball(&[
        "replay",
        bag.to_str().unwrap(),
        "--output",
        out.to_str().unwrap(),
    ]);
    assert!(
        summary.contains("detections read 45, fused 41, initialising 4, rejected 0, undecodable 0"),
        "{summary}"
    );
    assert!(summary.contains("tracks 1"), "{summary}");
}
