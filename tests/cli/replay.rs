//! `ttball replay` as a user runs it: Ctrl-C (SIGINT) or SIGTERM (a supervisor stopping it) in
//! the middle of a long replay leaves a properly finished output bag and says so; the summary
//! reports the whole run; a file that cannot be opened or created is named, with why, and so is
//! a disk that fills; one core or more, the output is the same file.
#![cfg(all(feature = "cli", unix))]
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    reason = "test code: fail loudly"
)]

use crate::common;

use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use ttball::bag::read_bag_file;

#[test]
fn ctrl_c_and_sigterm_finish_the_output_bag() {
    let dir = common::scratch("sigint");
    let input = dir.join("long.mcap");
    common::ok(&[
        "simulate",
        "--output",
        input.to_str().unwrap(),
        "--shots",
        "150",
        "--seed",
        "9",
    ]);
    for signal in ["INT", "TERM"] {
        let output = dir.join(format!("out-{signal}.mcap"));
        stop_midway(&input, &output, signal);
    }
}

/// Replays `input` into `output`, sends `signal` once it is writing, and checks the output.
fn stop_midway(input: &std::path::Path, output: &std::path::Path, signal: &str) {
    let child = Command::new(env!("CARGO_BIN_EXE_ttball"))
        .args([
            "replay",
            input.to_str().unwrap(),
            "--output",
            output.to_str().unwrap(),
        ])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    // Wait until the replay is writing, then interrupt it as Ctrl-C would.
    let started = Instant::now();
    while std::fs::metadata(output).map_or(0, |m| m.len()) == 0
        && started.elapsed() < Duration::from_secs(30)
    {
        std::thread::sleep(Duration::from_millis(5));
    }
    std::thread::sleep(Duration::from_millis(150));
    let kill = Command::new("kill")
        .args([&format!("-{signal}"), &child.id().to_string()])
        .status()
        .unwrap();
    assert!(kill.success());
    let out = child.wait_with_output().unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    let contents = read_bag_file(output).unwrap();
    assert!(
        contents.damage.is_empty(),
        "SIG{signal}: the output is a finished MCAP file"
    );
    assert!(contents.channel("/ball/state").is_some());
    if stdout.contains("interrupted") {
        assert!(
            !out.status.success(),
            "an interrupted replay does not report success"
        );
    } else {
        // The replay won the race and finished first: still a complete, finished file.
        assert!(out.status.success(), "{stdout}");
    }
}

/// The summary says what the whole run cost beside the processing, on stdout and in `--report`:
/// the whole run includes the processing, so it is never the faster of the two.
#[test]
fn the_summary_reports_the_whole_run_beside_the_processing() {
    let dir = common::scratch("whole-run");
    let output = dir.join("out.mcap");
    let report = dir.join("report.json");
    let stdout = common::ok(&[
        "replay",
        "bags/sim_rally_wide.mcap",
        "-o",
        output.to_str().unwrap(),
        "--report",
        report.to_str().unwrap(),
    ]);
    assert!(
        stdout.contains(
            "whole run (reading, decoding, processing, encoding, compressing, writing): "
        ),
        "{stdout}"
    );
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&report).unwrap()).unwrap();
    let summary = &json[0];
    let whole = summary["whole_seconds"].as_f64().unwrap();
    let processing = summary["processing_seconds"].as_f64().unwrap();
    assert!(whole >= processing && processing > 0.0, "{summary}");
    let factor = summary["whole_real_time_factor"].as_f64().unwrap();
    let recorded = summary["recorded_seconds"].as_f64().unwrap();
    assert!(
        (factor * whole - recorded).abs() < 1e-6 * recorded,
        "{summary}"
    );
    assert!(
        factor <= summary["real_time_factor"].as_f64().unwrap(),
        "{summary}"
    );
}

/// A file that cannot be opened or created: the error names it and says why once, and the exit
/// code is the failure's.
#[test]
fn a_missing_input_or_output_is_named_with_the_reason_said_once() {
    let dir = common::scratch("missing-files");
    let missing = dir.join("no-such-bag.mcap");
    let unwritable = dir.join("no-such-dir").join("out.mcap");
    for (args, named) in [
        (
            vec!["replay", missing.to_str().unwrap()],
            "no-such-bag.mcap",
        ),
        (
            vec![
                "replay",
                "bags/sim_rally_wide.mcap",
                "-o",
                unwritable.to_str().unwrap(),
            ],
            "no-such-dir/out.mcap",
        ),
    ] {
        let out = common::run(&args);
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success(), "{stderr}");
        assert!(stderr.contains(named), "{stderr}");
        assert_eq!(
            stderr.matches("No such file or directory").count(),
            1,
            "{stderr}"
        );
    }
}

/// Runs `ttball` with `args` on one core (`taskset -c 0`), from the package root.
fn run_on_one_core(args: &[&str]) -> std::process::Output {
    Command::new("taskset")
        .current_dir(common::root())
        .args(["-c", "0", env!("CARGO_BIN_EXE_ttball")])
        .args(args)
        .output()
        .expect("cannot run taskset (util-linux)")
}

/// With more than one core the output is written on a thread of its own, with one in the
/// replay's: the file is the same, byte for byte.
#[test]
fn one_core_or_more_the_output_is_the_same_file() {
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    assert!(
        cores >= 2,
        "this test compares the one-core replay with the threaded one: it needs two cores, has {cores}"
    );
    let dir = common::scratch("one-core");
    let (threaded, inline) = (dir.join("threaded.mcap"), dir.join("inline.mcap"));
    let bag = "bags/sim_rally_2cams.mcap";
    let threaded_out = common::ok(&["replay", bag, "-o", threaded.to_str().unwrap()]);
    let out = run_on_one_core(&["replay", bag, "-o", inline.to_str().unwrap()]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let written = |stdout: &str| {
        stdout
            .lines()
            .find(|l| l.contains("messages written"))
            .and_then(|l| l.split("; ").last())
            .map(str::to_owned)
    };
    assert_eq!(
        written(&threaded_out),
        written(&String::from_utf8_lossy(&out.stdout)),
        "{threaded_out}"
    );
    assert!(written(&threaded_out).is_some(), "{threaded_out}");
    let (a, b) = (
        std::fs::read(&threaded).unwrap(),
        std::fs::read(&inline).unwrap(),
    );
    assert!(a.len() > 100_000, "{} bytes", a.len());
    assert!(a == b, "the threaded and the one-core outputs differ");
}

/// A disk that fills while the replay writes: the replay fails, says why, and ends (on one core,
/// where it writes in its own thread, and on more, where a thread of its own writes).
#[test]
fn a_full_disk_fails_the_replay_with_the_reason() {
    let args = ["replay", "bags/sim_rally_2cams.mcap", "-o", "/dev/full"];
    for out in [common::run(&args), run_on_one_core(&args)] {
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success(), "{stderr}");
        assert!(stderr.contains("/dev/full"), "{stderr}");
        assert!(stderr.contains("No space left on device"), "{stderr}");
    }
}

/// `--learned` writes what the replay's estimator learned as a configuration file: loaded, it
/// holds the report's learned physics, the camera noise and the model noise in place of the
/// configured values, and a replay started from it starts from them; it takes one input.
#[test]
fn what_a_replay_learned_is_a_configuration_to_start_from() {
    let dir = common::scratch("learned-config");
    let learned = dir.join("learned.yaml");
    let report = dir.join("report.json");
    common::ok(&[
        "replay",
        "bags/real_launcher.mcap",
        "-o",
        dir.join("out.mcap").to_str().unwrap(),
        "--report",
        report.to_str().unwrap(),
        "--learned",
        learned.to_str().unwrap(),
    ]);
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&report).unwrap()).unwrap();
    let summary = &json[0];
    let config = ttball::config::yaml::load::<&str>(Some(&learned), &[]).unwrap();
    let physics = &summary["learned_physics"]["params"];
    for (name, value) in [
        ("drag_scale", config.aero.drag_scale),
        ("magnus_scale", config.aero.magnus_scale),
        ("restitution", config.table.restitution),
        ("friction", config.table.friction),
    ] {
        // (A decimal's last digit may round either way through two parsers.)
        approx::assert_relative_eq!(
            value,
            physics[name]["value"].as_f64().unwrap(),
            max_relative = 1e-14
        );
    }
    let defaults = ttball::config::Config::default();
    // The real flights' camera is quieter than configured, and they stray from the model more.
    let wide = &config.sources.wide_150fps;
    assert!(wide.position_sigma < 0.5 * defaults.sources.wide_150fps.position_sigma);
    assert!(wide.stamp_sigma > 0.0);
    // The filter's own noise is configuration, not learned: as configured.
    assert_eq!(config.ekf, defaults.ekf);
    let text = std::fs::read_to_string(&learned).unwrap();
    // Only what was learned is in the file: no topic, no table size.
    assert!(
        !text.contains("topics") && !text.contains("length"),
        "{text}"
    );
    assert_eq!(config.topics, defaults.topics);
    // A replay from it starts from the learned physics.
    let again = common::ok(&[
        "replay",
        "bags/sim_rally_wide.mcap",
        "-o",
        dir.join("again.mcap").to_str().unwrap(),
        "--config",
        learned.to_str().unwrap(),
        "-p",
        "adaptation.enabled:=false",
    ]);
    let drag = format!("drag_scale {:.3}", config.aero.drag_scale);
    assert!(again.contains(&drag), "{again}");
    let two = common::run(&[
        "replay",
        "bags/sim_rally_wide.mcap",
        "bags/real_launcher.mcap",
        "--output-dir",
        dir.join("both").to_str().unwrap(),
        "--learned",
        learned.to_str().unwrap(),
    ]);
    assert_eq!(two.status.code(), Some(1));
    assert!(
        String::from_utf8_lossy(&two.stderr).contains("--learned takes one input"),
        "{two:?}"
    );
    // Nowhere to keep it: refused before the replay.
    let nowhere = common::run(&[
        "replay",
        "bags/sim_rally_wide.mcap",
        "-o",
        dir.join("nowhere.mcap").to_str().unwrap(),
        "--learned",
        "/no/such/directory/learned.yaml",
    ]);
    assert_eq!(nowhere.status.code(), Some(2), "{nowhere:?}");
    assert!(
        String::from_utf8_lossy(&nowhere.stderr).contains("does not exist"),
        "{nowhere:?}"
    );
    assert!(!dir.join("nowhere.mcap").exists());
}

/// A learned file written by a run started from an earlier one keeps what the earlier run
/// learned and this one did not move: replayed from the two cameras' lessons, a bag of the
/// 150 fps camera alone leaves the 900 fps camera's learned noise in the new file, and writes over the whole file it was started from.
#[test]
fn a_learned_file_keeps_what_earlier_runs_learned() {
    let dir = common::scratch("learned-kept");
    let first = dir.join("first.yaml");
    common::ok(&[
        "replay",
        "bags/sim_rally_2cams.mcap",
        "-o",
        dir.join("first.mcap").to_str().unwrap(),
        "--learned",
        first.to_str().unwrap(),
    ]);
    let earlier = ttball::config::yaml::load::<&str>(Some(&first), &[]).unwrap();
    let defaults = ttball::config::Config::default();
    let high_speed = &earlier.sources.highspeed_900fps;
    assert_ne!(
        high_speed.position_sigma,
        defaults.sources.highspeed_900fps.position_sigma
    );
    // Kept in place: the next run reads the file and rewrites it.
    let kept = dir.join("kept.yaml");
    std::fs::copy(&first, &kept).unwrap();
    let replayed = common::ok(&[
        "replay",
        "bags/sim_rally_wide.mcap",
        "-o",
        dir.join("second.mcap").to_str().unwrap(),
        "--config",
        kept.to_str().unwrap(),
        "--learned",
        kept.to_str().unwrap(),
    ]);
    assert!(
        !replayed.contains("highspeed_900fps position sigma"),
        "{replayed}"
    );
    let text = std::fs::read_to_string(&kept).unwrap();
    assert!(text.contains("sim_rally_wide.mcap"), "{text}");
    let later = ttball::config::yaml::load::<&str>(Some(&kept), &[]).unwrap();
    assert_eq!(later.sources.highspeed_900fps, *high_speed);
    // What this run learned replaces the earlier lesson.
    assert_ne!(later.aero.drag_scale, earlier.aero.drag_scale);
    assert_ne!(
        later.sources.wide_150fps.position_sigma,
        earlier.sources.wide_150fps.position_sigma
    );
}
