//! `ttball predict` run as a user would: the default real rally ball, a CSV, bad input.
#![cfg(feature = "cli")]
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    reason = "test code: fail loudly"
)]

use crate::common;

use common::run as ttball;

#[test]
fn default_prediction_shows_the_bounce_and_the_hitting_plane() {
    let out = ttball(&["predict"]);
    assert!(out.status.success());
    let text = String::from_utf8(out.stdout).unwrap();
    assert!(text.contains("net crossed"), "{text}");
    assert!(text.contains("bounce on the robot's half"), "{text}");
    assert!(text.contains("hitting plane x = -1.600 m"), "{text}");
    // The events come in time order: net, bounce, plane.
    let net = text.find("net crossed").unwrap();
    let bounce = text.find("bounce on").unwrap();
    let plane = text.find("hitting plane").unwrap();
    assert!(net < bounce && bounce < plane);
}

#[test]
fn csv_has_a_header_and_one_row_per_sample() {
    let dir = std::path::Path::new(env!("CARGO_TARGET_TMPDIR"))
        .join(format!("predict-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("flight.csv");
    let out = ttball(&[
        "predict",
        "--velocity",
        "-6,0,1",
        "--spin",
        "0,-150,0",
        "--horizon",
        "0.5",
        "--dt",
        "0.01",
        "-p",
        "intercept.plane_x:=-1.45",
        "--csv",
        path.to_str().unwrap(),
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let csv = std::fs::read_to_string(&path).unwrap();
    let mut lines = csv.lines();
    assert_eq!(
        lines.next(),
        Some("t_s,x_m,y_m,z_m,vx_mps,vy_mps,vz_mps,wx_radps,wy_radps,wz_radps")
    );
    let rows: Vec<Vec<f64>> = lines
        .map(|l| l.split(',').map(|v| v.parse().unwrap()).collect())
        .collect();
    assert_eq!(rows.len(), 51, "t = 0, 0.01, ..., 0.5");
    assert_eq!(rows[0][4], -6.0);
    assert!((rows[50][0] - 0.5).abs() < 1e-9);
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn bad_vectors_and_bad_config_are_clear_errors() {
    let out = ttball(&["predict", "--velocity", "-6,0"]);
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("three comma-separated numbers"));
    let out = ttball(&["predict", "-p", "table.restitution:=1.5"]);
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("table.restitution"));
}
