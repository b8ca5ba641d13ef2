//! The shipped sample bags: the commands in bags/README.md reproduce them byte for byte (same
//! seed, same bytes), and each replays through the estimator.
#![cfg(feature = "cli")]
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    reason = "test code: fail loudly"
)]

use crate::common;

use std::path::{Path, PathBuf};

use common::{ok as ttball, root};

fn scratch(name: &str) -> PathBuf {
    common::scratch("bags").join(name)
}

fn same_bytes(a: &Path, b: &Path) {
    assert!(
        std::fs::read(a).unwrap() == std::fs::read(b).unwrap(),
        "{} differs from {}",
        a.display(),
        b.display()
    );
}

#[test]
fn the_simulated_bags_are_reproduced_by_their_commands() {
    let two = scratch("sim_rally_2cams.mcap");
    ttball(&[
        "simulate",
        "--output",
        two.to_str().unwrap(),
        "--shots",
        "8",
        "--seed",
        "1",
    ]);
    same_bytes(&two, &root().join("bags/sim_rally_2cams.mcap"));
    let wide = scratch("sim_rally_wide.mcap");
    ttball(&[
        "simulate",
        "--output",
        wide.to_str().unwrap(),
        "--shots",
        "8",
        "--seed",
        "2",
        "--cameras",
        "wide",
    ]);
    same_bytes(&wide, &root().join("bags/sim_rally_wide.mcap"));
}

#[test]
fn the_real_bag_is_reproduced_from_its_flights() {
    let data = root().join("tests/data/mpi_launcher");
    let out = scratch("real_launcher.mcap");
    let files: Vec<String> = [
        "mn5008_backspin.csv",
        "mn5008_no_spin.csv",
        "mn5008_topspin.csv",
    ]
    .iter()
    .map(|f| data.join(f).to_str().unwrap().to_string())
    .collect();
    let mut args = vec!["import", "mpi"];
    args.extend(files.iter().map(String::as_str));
    args.extend(["--output", out.to_str().unwrap()]);
    let report = ttball(&args);
    assert!(report.contains("40 flights, 4477 detections"), "{report}");
    same_bytes(&out, &root().join("bags/real_launcher.mcap"));
}

#[test]
fn every_shipped_bag_replays() {
    let dir = scratch("replayed");
    let summary = ttball(&[
        "replay",
        "bags/sim_rally_2cams.mcap",
        "bags/sim_rally_wide.mcap",
        "bags/real_launcher.mcap",
        "--output-dir",
        dir.to_str().unwrap(),
    ]);
    assert_eq!(
        summary
            .matches("accuracy against the bag's truth (8 shots)")
            .count(),
        2,
        "{summary}"
    );
    assert!(summary.contains("detections read 3873"), "{summary}");
    assert!(summary.contains("detections read 4477"), "{summary}");
    // The 40 real launcher flights are 40 tracks (a track refuted at a bounce is re-anchored
    // on its own detections, not split).
    let real = summary
        .lines()
        .find(|l| l.contains("detections read 4477"))
        .unwrap();
    let tracks = real
        .split("; tracks ")
        .nth(1)
        .and_then(|rest| rest.split(|c: char| !c.is_ascii_digit()).next())
        .and_then(|n| n.parse::<u32>().ok());
    assert_eq!(tracks, Some(40), "{real}");
    for name in [
        "sim_rally_2cams.mcap",
        "sim_rally_wide.mcap",
        "real_launcher.mcap",
    ] {
        assert!(dir.join(name).exists());
    }
}
