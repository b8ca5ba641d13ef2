//! `ttball node`: the live ROS 2 node (see `ttball::node`), with ROS 2's `--ros-args` forms, a
//! clean stop on SIGINT/SIGTERM and logs through `tracing` (`RUST_LOG`).

use std::process::ExitCode;

use anyhow::Context;
use clap::Args;
use ttball::config::Config;
use ttball::node::{NodeError, NodeSummary, Placement, start};

use super::{BadUsage, ConfigArgs, write_stdout};

/// Arguments of `ttball node`.
#[derive(Debug, Args)]
pub struct NodeArgs {
    /// The configuration: node name and namespace, topics, QoS depths, the estimator.
    #[command(flatten)]
    pub config: ConfigArgs,

    /// ROS 2 arguments, as `ros2 run` passes them: `--ros-args [-p NAME:=VALUE]
    /// [-r FROM:=TO] [--params-file FILE] [--log-level LEVEL] [--]`. Remaps rename a topic
    /// (`-r /ball/detections:=/vision/ball`), the node (`-r __node:=ttball_left`) or its
    /// namespace (`-r __ns:=/robot1`).
    #[arg(
        long = "ros-args",
        num_args = 0..,
        allow_hyphen_values = true,
        value_name = "ARGS"
    )]
    pub ros_args: Option<Vec<String>>,
}

/// The parts of `--ros-args` ttball understands.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct RosArgs {
    /// `-p NAME:=VALUE` / `--param`.
    pub params: Vec<String>,
    /// `-r FROM:=TO` / `--remap`.
    pub remaps: Vec<(String, String)>,
    /// `--params-file FILE`.
    pub params_file: Option<std::path::PathBuf>,
    /// `--log-level LEVEL` (or `--log-level NAME:=LEVEL`, whose name is ignored).
    pub log_level: Option<String>,
}

/// Parses the words after `--ros-args` (up to a `--`, and further `--ros-args` blocks).
pub fn parse_ros_args(words: &[String]) -> Result<RosArgs, BadUsage> {
    let mut out = RosArgs::default();
    let mut words = words.iter();
    while let Some(word) = words.next() {
        let mut value = |what: &str| {
            words
                .next()
                .cloned()
                .ok_or_else(|| BadUsage(format!("`{word}` needs {what} after it")))
        };
        match word.as_str() {
            "--ros-args" | "--" => {}
            "-p" | "--param" => out.params.push(value("NAME:=VALUE")?),
            "-r" | "--remap" => {
                let remap = value("FROM:=TO")?;
                let (from, to) = remap.split_once(":=").ok_or_else(|| {
                    BadUsage(format!(
                        "remap `{remap}` is not FROM:=TO, e.g. `-r /ball/detections:=/vision/ball`"
                    ))
                })?;
                out.remaps
                    .push((from.trim().to_owned(), to.trim().to_owned()));
            }
            "--params-file" => {
                if out.params_file.is_some() {
                    return Err(BadUsage(
                        "give one --params-file (ttball reads one parameters file)".to_owned(),
                    ));
                }
                out.params_file = Some(value("a file")?.into());
            }
            "--log-level" => {
                let level = value("a level")?;
                let level = level.rsplit_once(":=").map_or(level.as_str(), |(_, l)| l);
                out.log_level = Some(level.to_ascii_lowercase());
            }
            other => {
                return Err(BadUsage(format!(
                    "`{other}` in --ros-args is not supported by ttball; it takes -p NAME:=VALUE, -r FROM:=TO, --params-file FILE and --log-level LEVEL"
                )));
            }
        }
    }
    Ok(out)
}

/// Applies ROS 2 remaps to the configuration: `__node`/`__name`, `__ns`, and topic names (the
/// node's topics whose name is FROM, absolute or relative to the root namespace). Remaps of
/// names the node does not use are listed in the result (ROS 2 ignores them too).
pub fn apply_remaps(config: &mut Config, remaps: &[(String, String)]) -> Vec<String> {
    let mut unused = Vec::new();
    for (from, to) in remaps {
        // `node_name:FROM:=TO` applies to that node only.
        let (target, from) = match from.split_once(':') {
            Some((node, rest)) => (Some(node), rest),
            None => (None, from.as_str()),
        };
        if target.is_some_and(|node| node != config.node.name) {
            continue;
        }
        match from {
            "__node" | "__name" => config.node.name = to.clone(),
            "__ns" => config.node.namespace = if to == "/" { String::new() } else { to.clone() },
            topic => {
                let absolute = |name: &str| {
                    if name.starts_with('/') {
                        name.to_owned()
                    } else {
                        format!("/{name}")
                    }
                };
                let (from, to) = (absolute(topic), absolute(to));
                let t = &mut config.topics;
                let mut hit = false;
                for name in [
                    &mut t.detections,
                    &mut t.state,
                    &mut t.intercept,
                    &mut t.trajectory,
                    &mut t.markers,
                    &mut t.diagnostics,
                ] {
                    if *name == from {
                        name.clone_from(&to);
                        hit = true;
                    }
                }
                if !hit {
                    unused.push(from);
                }
            }
        }
    }
    unused
}

impl NodeArgs {
    /// Runs the node until SIGINT or SIGTERM.
    pub fn run(self) -> anyhow::Result<ExitCode> {
        let ros = parse_ros_args(self.ros_args.as_deref().unwrap_or_default())?;
        let mut config_args = self.config.clone();
        if let Some(file) = ros.params_file.clone() {
            if config_args.config.is_some() {
                return Err(BadUsage(
                    "give either --config or --ros-args --params-file, not both".to_owned(),
                )
                .into());
            }
            config_args.config = Some(file);
        }
        config_args
            .overrides
            .params
            .extend(ros.params.iter().cloned());
        super::init_logging(ros.log_level.as_deref());
        let mut config = config_args.load()?;
        let unused = apply_remaps(&mut config, &ros.remaps);
        config
            .validate()
            .map_err(|e| BadUsage(format!("after the remaps: {e}")))?;
        for name in unused {
            tracing::warn!("remap of {name}: the node has no such topic (ignored)");
        }
        let placement = Placement::from_env(&config).map_err(node_error)?;

        let (signal_tx, signal_rx) = crossbeam::channel::bounded::<()>(1);
        ctrlc::set_handler(move || {
            let _ = signal_tx.try_send(());
        })
        .context("cannot install the SIGINT/SIGTERM handler")?;

        let node = start(&config, &placement).map_err(node_error)?;
        let name = node.name().to_owned();
        let ended = node.ended().clone();
        crossbeam::select! {
            recv(signal_rx) -> _ => tracing::info!("{name}: stopping (signal)"),
            recv(ended) -> _ => tracing::warn!("{name}: the DDS side stopped"),
        }
        let summary = node.stop().map_err(node_error)?;
        write_stdout(&summary_text(&name, &summary))?;
        Ok(ExitCode::SUCCESS)
    }
}

/// A bad domain id, name or CPU list is a usage error (exit code 2), the rest a failure.
pub fn node_error(e: NodeError) -> anyhow::Error {
    match e {
        NodeError::DomainId(_) | NodeError::Name(_) | NodeError::Cpus(_) => {
            BadUsage(e.to_string()).into()
        }
        other => other.into(),
    }
}

fn summary_text(name: &str, s: &NodeSummary) -> String {
    let c = &s.counters;
    let t = &s.transport;
    let mut rejected: Vec<String> = c.rejections();
    if t.undecodable > 0 {
        rejected.push(format!("undecodable {}", t.undecodable));
    }
    if t.dropped_queue_full > 0 {
        rejected.push(format!("queue full {}", t.dropped_queue_full));
    }
    format!(
        "{name} ran {:.1} s: detections received {}, fused {}, initialising {}, rejected {} ({}); tracks {}\n  \
         processing per detection: mean {:.1} us, max {:.1} us; in the node (received by DDS to published): \
         p50 {:.1} us, p99 {:.1} us, max {:.1} us\n  \
         lost before the node {}; service requests {}; publish errors {}\n",
        s.seconds,
        t.received,
        c.fused,
        c.initializing,
        c.total_rejected() + t.undecodable + t.dropped_queue_full,
        if rejected.is_empty() {
            "none".to_owned()
        } else {
            rejected.join(", ")
        },
        c.tracks,
        s.processing_mean_ns * 1e-3,
        s.processing_max_ns * 1e-3,
        s.in_node.p50 * 1e-3,
        s.in_node.p99 * 1e-3,
        s.in_node.max * 1e-3,
        t.lost_before_node,
        t.service_requests,
        t.publish_errors,
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    fn words(s: &str) -> Vec<String> {
        s.split_whitespace().map(str::to_owned).collect()
    }

    #[test]
    fn ros_args_forms() {
        let ros = parse_ros_args(&words(
            "-p intercept.plane_x:=-1.45 --param ekf.q_a:=0.01 -r /ball/detections:=/vision/ball \
             --remap __ns:=/robot1 --params-file my.yaml --log-level debug --",
        ))
        .unwrap();
        assert_eq!(ros.params, ["intercept.plane_x:=-1.45", "ekf.q_a:=0.01"]);
        assert_eq!(
            ros.remaps,
            [
                ("/ball/detections".to_owned(), "/vision/ball".to_owned()),
                ("__ns".to_owned(), "/robot1".to_owned())
            ]
        );
        assert_eq!(ros.params_file, Some("my.yaml".into()));
        assert_eq!(ros.log_level.as_deref(), Some("debug"));
        for bad in [
            "-p",
            "-r nocolon",
            "--enclave /x",
            "--params-file a --params-file b",
        ] {
            assert!(parse_ros_args(&words(bad)).is_err(), "{bad}");
        }
    }

    #[test]
    fn remaps_rename_topics_node_and_namespace() {
        let mut config = Config::default();
        let unused = apply_remaps(
            &mut config,
            &[
                ("ball/detections".to_owned(), "/vision/ball".to_owned()),
                ("/ball/state".to_owned(), "state".to_owned()),
                ("__node".to_owned(), "ttball_left".to_owned()),
                ("ttball_left:__ns".to_owned(), "/robot1".to_owned()),
                ("other_node:__ns".to_owned(), "/elsewhere".to_owned()),
                ("/camera/image".to_owned(), "/x".to_owned()),
            ],
        );
        assert_eq!(config.topics.detections, "/vision/ball");
        assert_eq!(config.topics.state, "/state");
        assert_eq!(config.node.name, "ttball_left");
        assert_eq!(config.node.namespace, "/robot1");
        assert_eq!(unused, ["/camera/image"]);
        config.validate().unwrap();
    }
}
