//! `ttball node` and `ttball play` refuse what they cannot run, before any DDS traffic: a bad
//! configuration, `ROS_DOMAIN_ID` or `--ros-args` exits with code 2 and says what to fix. (The
//! running node is tested against Cyclone DDS in `tests/node_dds.rs`, in a loopback-only network
//! namespace.)
#![cfg(feature = "cli")]
#![allow(clippy::unwrap_used, reason = "test code: fail loudly")]

use std::process::{Command, Output};

mod common;

fn ttball(env: &[(&str, &str)], args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_ttball"))
        .current_dir(common::root())
        .envs(env.iter().copied())
        .args(args)
        .output()
        .unwrap()
}

fn refused(env: &[(&str, &str)], args: &[&str], words: &[&str]) {
    let out = ttball(env, args);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{args:?}: {stderr}");
    for w in words {
        assert!(stderr.contains(w), "{args:?}: `{w}` not in {stderr}");
    }
}

#[test]
fn node_refuses_a_bad_configuration() {
    refused(
        &[],
        &["node", "-p", "node.queue_capacity:=0"],
        &["node.queue_capacity"],
    );
    refused(
        &[],
        &["node", "-p", "node.interface_address:=eth0"],
        &["node.interface_address", "IP address"],
    );
    refused(
        &[],
        &["node", "-p", "node.service_mapping:=fastdds"],
        &["node.service_mapping"],
    );
    refused(
        &[],
        &["node", "--config", "no/such/file.yaml"],
        &["does not exist"],
    );
}

#[test]
fn node_refuses_a_bad_domain_id() {
    refused(
        &[("ROS_DOMAIN_ID", "500")],
        &["node"],
        &["ROS_DOMAIN_ID", "0 to 232"],
    );
    refused(&[("ROS_DOMAIN_ID", "seven")], &["node"], &["ROS_DOMAIN_ID"]);
}

#[test]
fn node_refuses_bad_ros_args() {
    refused(
        &[],
        &["node", "--ros-args", "--enclave", "/x"],
        &["--enclave", "-r FROM:=TO"],
    );
    refused(&[], &["node", "--ros-args", "-r", "nocolon"], &["FROM:=TO"]);
    refused(
        &[],
        &["node", "--ros-args", "-r", "__ns:=robot1"],
        &["node.namespace"],
    );
    refused(
        &[],
        &["node", "--ros-args", "-r", "/ball/state:=/bad//name"],
        &["topics.state"],
    );
    refused(
        &[],
        &["node", "--ros-args", "-p", "ekf.nope:=1"],
        &["ekf.nope"],
    );
    refused(
        &[],
        &[
            "node",
            "--config",
            "config/ttball.yaml",
            "--ros-args",
            "--params-file",
            "config/ttball.yaml",
        ],
        &["either --config or --ros-args --params-file"],
    );
}

#[test]
fn play_refuses_bad_arguments_and_missing_bags() {
    refused(
        &[],
        &["play", "bags/sim_rally_wide.mcap", "--rate", "0"],
        &["--rate"],
    );
    refused(
        &[],
        &["play", "bags/sim_rally_wide.mcap", "--wait=-1"],
        &["--wait"],
    );
    let out = ttball(&[], &["play", "no/such.mcap"]);
    assert_eq!(out.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&out.stderr).contains("no/such.mcap"));
    let out = ttball(
        &[],
        &[
            "play",
            "bags/sim_rally_wide.mcap",
            "-p",
            "topics.detections:=/nope",
        ],
    );
    assert_eq!(out.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&out.stderr).contains("topics.detections"));
}

#[test]
fn help_explains_the_node() {
    let out = ttball(&[], &["node", "--help"]);
    let text = String::from_utf8_lossy(&out.stdout);
    for w in [
        "ROS_DOMAIN_ID",
        "--ros-args",
        "predict_trajectory",
        "RUST_LOG",
        "ttball play",
    ] {
        assert!(text.contains(w), "`{w}` not in node --help:\n{text}");
    }
}
