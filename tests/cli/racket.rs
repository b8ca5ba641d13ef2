//! `ttball rebound` and `ttball aim` run as a user would: the defaults, the planner's command fed
//! back into `rebound`, the chart, and bad input with exit code 2.
#![cfg(feature = "cli")]
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    reason = "test code: fail loudly"
)]

use crate::common;

use common::run as ttball;

fn json(args: &[&str]) -> serde_json::Value {
    serde_json::from_str(&common::ok(args)).unwrap()
}

fn vector(value: &serde_json::Value) -> String {
    let v: Vec<String> = value
        .as_array()
        .unwrap()
        .iter()
        .map(|x| format!("{:e}", x.as_f64().unwrap()))
        .collect();
    v.join(",")
}

#[test]
fn default_rebound_reports_the_impact_and_a_landing() {
    let out = ttball(&["rebound"]);
    assert!(out.status.success());
    let text = String::from_utf8(out.stdout).unwrap();
    for words in [
        "reduced mass M_r",
        "contact time",
        "wrist / grip load",
        "lands on the opponent's half",
    ] {
        assert!(text.contains(words), "{words}: {text}");
    }
}

/// The command `aim` prints, given to `rebound`, lands on the target within 1 mm.
#[test]
fn the_aimed_command_lands_on_the_target_through_rebound() {
    let plan = json(&[
        "aim",
        "--target",
        "1.0,-0.4",
        "--net-clearance",
        "0.2",
        "--offset",
        "0.04",
        "--json",
    ]);
    let racket = &plan["racket"];
    let rebound = json(&[
        "rebound",
        "--racket-velocity",
        &vector(&racket["velocity"]),
        "--normal",
        &vector(&racket["normal"]),
        "--offset",
        "0.04",
        "--json",
    ]);
    let landing = &rebound["rebound"]["landing"]["position"];
    let (x, y) = (landing[0].as_f64().unwrap(), landing[1].as_f64().unwrap());
    let miss = ((x - 1.0).powi(2) + (y + 0.4).powi(2)).sqrt();
    assert!(miss < 1e-3, "landed at ({x}, {y})");
    assert_eq!(rebound["rebound"]["lands_on_table"], true);
    let clearance = rebound["rebound"]["net"]["clearance"].as_f64().unwrap();
    assert!((clearance - 0.2).abs() < 1e-3, "{clearance}");
    // With the ball's uncertainty, the landing's: positive variances of x, y and time.
    let uncertain = json(&[
        "aim",
        "--target",
        "1.0,-0.4",
        "--sigma",
        "0.002,0.05,20",
        "--json",
    ]);
    let c: Vec<f64> = uncertain["landing_covariance"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect();
    assert!(
        c.len() == 9 && c[0] > 0.0 && c[4] > 0.0 && c[8] > 0.0,
        "{c:?}"
    );
    // Without it, the rubber's own (its calibration's covariance and scatter): smaller; none
    // with a rubber known exactly.
    let rubber_only = plan["landing_covariance"][0].as_f64().unwrap();
    assert!(
        rubber_only > 0.0 && rubber_only < c[0],
        "{rubber_only} vs {}",
        c[0]
    );
    let exact = json(&[
        "aim",
        "--target",
        "1.0,-0.4",
        "--config",
        &format!(
            "{}/config/presets/rubber_sriver_seed.yaml",
            env!("CARGO_MANIFEST_DIR")
        ),
        "--json",
    ]);
    assert_eq!(exact["landing_covariance"], serde_json::Value::Null);
}

#[test]
fn the_chart_is_written() {
    let dir = std::path::Path::new(env!("CARGO_TARGET_TMPDIR"))
        .join(format!("rebound-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("e.svg");
    let out = ttball(&["rebound", "--chart", path.to_str().unwrap()]);
    assert!(out.status.success());
    let svg = std::fs::read_to_string(&path).unwrap();
    assert!(svg.starts_with("<svg") && svg.contains("against impact speed"));
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn bad_requests_exit_2_with_what_to_do() {
    let cases: [(&[&str], &str); 5] = [
        (&["aim", "--target", "-0.5,0"], "opponent's half"),
        (
            &[
                "aim",
                "--target",
                "1.2,0",
                "--flight-time",
                "0.2",
                "-p",
                "stroke.max_racket_speed:=2",
            ],
            "stroke.max_racket_speed",
        ),
        (&["rebound", "--normal", "0,0,0"], "zero vector"),
        (&["rebound", "--offset", "0.5"], "off the face"),
        (&["rebound", "--chart", "e.txt"], ".svg or .png"),
    ];
    for (args, words) in cases {
        let out = ttball(args);
        assert_eq!(out.status.code(), Some(2), "{args:?}");
        let err = String::from_utf8(out.stderr).unwrap();
        assert!(err.contains(words), "{args:?}: {err}");
    }
}
