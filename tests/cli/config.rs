//! `ttball config print|check`, run as the real binary: output, exit codes and messages.
#![cfg(feature = "cli")]
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    clippy::panic,
    reason = "test helpers outside #[test] functions"
)]

use crate::common;

use std::path::{Path, PathBuf};
use std::process::Output;

use common::run as ttball;
use ttball::config::Config;
use ttball::config::yaml;

fn stdout(output: &Output) -> String {
    String::from_utf8(output.stdout.clone()).unwrap()
}

fn stderr(output: &Output) -> String {
    String::from_utf8(output.stderr.clone()).unwrap()
}

/// A file in a fresh temporary directory of this test.
fn temp_file(name: &str, text: &str) -> PathBuf {
    let path = common::scratch("cli-config").join(name);
    std::fs::write(&path, text).unwrap();
    path
}

const NO_OVERRIDES: &[&str] = &[];

#[test]
fn help_lists_the_commands() {
    let out = ttball(&["--help"]);
    assert!(out.status.success());
    let text = stdout(&out);
    assert!(text.starts_with("ttball: a real-time table-tennis ball-state estimator"));
    assert!(text.contains("config"));

    let out = ttball(&["config", "check", "--help"]);
    assert!(out.status.success());
    assert!(stdout(&out).contains("Examples:\n  ttball config check my.yaml"));
}

#[test]
fn print_gives_the_defaults_back() {
    let out = ttball(&["config", "print"]);
    assert_eq!(out.status.code(), Some(0), "{}", stderr(&out));
    let text = stdout(&out);
    assert!(text.contains("\n      plane_x: -1.6\n"), "{text}");
    let config = yaml::load_str(&text, Path::new("<stdout>"), NO_OVERRIDES).unwrap();
    assert_eq!(config, Config::default());
}

#[test]
fn print_applies_file_and_overrides() {
    let file = temp_file(
        "partial.yaml",
        "ttball:\n  ros__parameters:\n    table:\n      friction: 0.2\n",
    );
    let out = ttball(&[
        "config",
        "print",
        "--config",
        file.to_str().unwrap(),
        "-p",
        "intercept.plane_x:=-1.45",
        "--param",
        "topics.state:=/robot/ball_state",
    ]);
    assert_eq!(out.status.code(), Some(0), "{}", stderr(&out));
    let text = stdout(&out);
    assert!(text.contains("plane_x: -1.45\n"), "{text}");
    let config = yaml::load_str(&text, Path::new("<stdout>"), NO_OVERRIDES).unwrap();
    assert_eq!(config.table.friction, 0.2);
    assert_eq!(config.intercept.plane_x, -1.45);
    assert_eq!(config.topics.state, "/robot/ball_state");
}

#[test]
fn check_accepts_the_shipped_file() {
    let out = ttball(&["config", "check", "config/ttball.yaml"]);
    assert_eq!(out.status.code(), Some(0), "{}", stdout(&out));
    assert_eq!(stdout(&out), "config/ttball.yaml: ok\n");
}

#[test]
fn check_reports_a_typo_with_a_suggestion() {
    let file = temp_file(
        "typo.yaml",
        "ttball:\n  ros__parameters:\n    table:\n      restitutoin: 0.9\n",
    );
    let out = ttball(&["config", "check", file.to_str().unwrap()]);
    assert_eq!(out.status.code(), Some(2));
    let text = stdout(&out);
    assert!(text.contains("1 problem\n"), "{text}");
    assert!(
        text.contains(
            ":4: unknown parameter `table.restitutoin`; did you mean `table.restitution`?"
        ),
        "{text}"
    );
}

#[test]
fn check_reports_every_problem_and_applies_overrides() {
    let file = temp_file(
        "bad.yaml",
        "ttball:\n  ros__parameters:\n    table:\n      restitution: 1.5\n",
    );
    let out = ttball(&[
        "config",
        "check",
        file.to_str().unwrap(),
        "-p",
        "gating.probability:=1.0",
    ]);
    assert_eq!(out.status.code(), Some(2));
    let text = stdout(&out);
    assert!(text.contains("2 problems\n"), "{text}");
    assert!(text.contains("`table.restitution` = 1.5 is out of range"));
    assert!(text.contains("-p gating.probability:=1.0: `gating.probability` = 1 is out of range"));

    // An override can also repair the file.
    let out = ttball(&[
        "config",
        "check",
        file.to_str().unwrap(),
        "-p",
        "table.restitution:=0.92",
    ]);
    assert_eq!(out.status.code(), Some(0), "{}", stdout(&out));
}

#[test]
fn check_of_a_missing_file_exits_2() {
    let out = ttball(&["config", "check", "no/such/file.yaml"]);
    assert_eq!(out.status.code(), Some(2));
    assert!(stdout(&out).contains("configuration file `no/such/file.yaml` does not exist"));
}

#[test]
fn bad_override_exits_2_with_a_message_on_stderr() {
    let out = ttball(&["config", "print", "-p", "nonsense:=1"]);
    assert_eq!(out.status.code(), Some(2));
    assert!(out.stdout.is_empty());
    let text = stderr(&out);
    assert!(
        text.contains("error: the configuration has 1 problem:"),
        "{text}"
    );
    assert!(
        text.contains("-p nonsense:=1: unknown parameter `nonsense`"),
        "{text}"
    );

    let out = ttball(&["config", "print", "--config", "no/such/file.yaml"]);
    assert_eq!(out.status.code(), Some(2));
    assert!(stderr(&out).contains("`no/such/file.yaml` does not exist"));
}
