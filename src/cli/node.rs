//! `ttball node`: the live ROS 2 node (see `ttball::node`), with ROS 2's `--ros-args` forms, a
//! clean stop on SIGINT/SIGTERM and logs through `tracing` (`RUST_LOG`).

use std::process::ExitCode;

use anyhow::Context;
use clap::Args;
use ttball::config::yaml::{self, Layer};
use ttball::config::{Config, names};
use ttball::node::{NodeError, NodeSummary, Placement, start};

use super::{BadUsage, ConfigArgs, write_stdout};

/// Arguments of `ttball node`.
#[derive(Debug, Args)]
pub struct NodeArgs {
    /// The configuration: node name and namespace, topics, QoS depths, the estimator.
    #[command(flatten)]
    pub config: ConfigArgs,

    /// Keep what the estimator learns in this file, a configuration to start the next run from
    /// (pass it to --config): the ball's and table's physics and each camera's noise. Rewritten
    /// whole as the node learns (at most once a diagnostics period) and when it stops, so a crash
    /// loses at most a period's learning (give it before --ros-args; an empty path keeps
    /// nothing).
    #[arg(long, value_name = "FILE.yaml")]
    pub learned: Option<std::path::PathBuf>,

    /// ROS 2 arguments, as `ros2 run` and launch_ros pass them: `--ros-args [-p NAME:=VALUE]
    /// [-r FROM:=TO] [--params-file FILE]... [--log-level LEVEL] [--enclave NAME]
    /// [--disable-rosout-logs] [--disable-stdout-logs] [--]`. The log goes to standard error and
    /// to /rosout at the level given (INFO by default). Parameters files and
    /// `-p` apply in the order given, after --config; a file's sections apply when they name
    /// this node (`ttball`, `/robot1/ttball`, `/**`, `/**/ttball`). Remaps rename a topic
    /// (`-r ball/detections:=/vision/ball`), the node (`-r __node:=ttball_left`) or its
    /// namespace (`-r __ns:=/robot1`: the topics, relative by default, follow it).
    #[arg(
        long = "ros-args",
        num_args = 0..,
        allow_hyphen_values = true,
        value_name = "ARGS"
    )]
    pub ros_args: Option<Vec<String>>,

    /// Also serve the detections and every output live to the Foxglove app, over the Foxglove
    /// WebSocket protocol, without ROS 2: in Foxglove, "Open connection" to ws://HOST:PORT
    /// (127.0.0.1:8765 is the app's default; 0.0.0.0:8765 for other machines).
    #[arg(long, value_name = "HOST:PORT")]
    pub foxglove: Option<String>,
}

/// The parts of `--ros-args` ttball understands.
#[derive(Debug, Clone, PartialEq)]
pub struct RosArgs {
    /// `-p NAME:=VALUE` / `--param` and `--params-file FILE`, in the order given (later ones
    /// override earlier ones, as in rcl).
    pub layers: Vec<Layer>,
    /// `-r FROM:=TO` / `--remap`.
    pub remaps: Vec<(String, String)>,
    /// `--log-level LEVEL` (or `--log-level NAME:=LEVEL`, whose name is ignored).
    pub log_level: Option<String>,
    /// Log records go to `/rosout` (rcl's default; `--disable-rosout-logs` turns it off).
    pub rosout_logs: bool,
    /// Log records go to the console, standard error (`--disable-stdout-logs` turns it off).
    pub stdout_logs: bool,
    /// `--enclave NAME` (`-e`): the security enclave, used only with `ROS_SECURITY_ENABLE=true`,
    /// which ttball refuses (ros2-client has no DDS security).
    pub enclave: Option<String>,
}

impl Default for RosArgs {
    fn default() -> Self {
        Self {
            layers: Vec::new(),
            remaps: Vec::new(),
            log_level: None,
            rosout_logs: true,
            stdout_logs: true,
            enclave: None,
        }
    }
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
            "-p" | "--param" => out.layers.push(Layer::Param(value("NAME:=VALUE")?)),
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
            "--params-file" => out.layers.push(Layer::File(value("a file")?.into())),
            "--log-level" => {
                let level = value("a level")?;
                let level = level.rsplit_once(":=").map_or(level.as_str(), |(_, l)| l);
                out.log_level = Some(rcl_level(level)?);
            }
            "-e" | "--enclave" => out.enclave = Some(value("an enclave")?),
            "--enable-rosout-logs" => out.rosout_logs = true,
            "--disable-rosout-logs" => out.rosout_logs = false,
            "--enable-stdout-logs" => out.stdout_logs = true,
            "--disable-stdout-logs" => out.stdout_logs = false,
            // rcl's external library (spdlog) writes log files; ttball writes none.
            "--enable-external-lib-logs" | "--disable-external-lib-logs" => {}
            other => {
                return Err(BadUsage(format!(
                    "`{other}` in --ros-args is not supported by ttball; it takes -p NAME:=VALUE, -r FROM:=TO, --params-file FILE, --log-level LEVEL, --enclave NAME and --enable/--disable-rosout-logs, -stdout-logs, -external-lib-logs"
                )));
            }
        }
    }
    Ok(out)
}

/// An rcl log level (`debug`, `info`, `warn`, `error`, `fatal`, any case) as the console
/// filter's (`fatal` is `error`: nothing is logged above it).
fn rcl_level(level: &str) -> Result<String, BadUsage> {
    match level.to_ascii_lowercase().as_str() {
        "debug" | "info" | "warn" | "error" => Ok(level.to_ascii_lowercase()),
        "fatal" => Ok("error".to_owned()),
        // Not rcl's, but what RUST_LOG users type.
        "trace" => Ok("trace".to_owned()),
        "warning" => Ok("warn".to_owned()),
        _ => Err(BadUsage(format!(
            "--log-level `{level}` is not a level: debug, info, warn, error or fatal"
        ))),
    }
}

/// The node's fully qualified name as the remaps make it (`__node`, `__ns`), if they rename it:
/// the parameters files' sections are matched against it.
pub fn remapped_node_fqn(remaps: &[(String, String)]) -> Option<String> {
    let mut config = Config::default();
    let renames = remaps.iter().any(|(from, _)| {
        let base = from.rsplit(':').next().unwrap_or(from);
        matches!(base, "__node" | "__name" | "__ns")
    });
    renames.then(|| {
        apply_remaps(&mut config, remaps);
        config.node_fqn()
    })
}

/// Applies ROS 2 remaps to the configuration as rcl does: first `__node`/`__name` and `__ns`,
/// then topic names, a remap `FROM:=TO` replacing the node's topics whose name resolved in the
/// node's namespace equals FROM resolved there, by TO resolved there. `node:FROM:=TO` applies to
/// that node only. Remaps of names the node does not use are listed in the result (ROS 2
/// ignores them too).
pub fn apply_remaps(config: &mut Config, remaps: &[(String, String)]) -> Vec<String> {
    let for_this_node = |from: &str, name: &str| -> Option<String> {
        match from.split_once(':') {
            Some((node, rest)) => (node == name).then(|| rest.to_owned()),
            None => Some(from.to_owned()),
        }
    };
    let mut topic_remaps = Vec::new();
    for (from, to) in remaps {
        let Some(from) = for_this_node(from, &config.node.name) else {
            continue;
        };
        match from.as_str() {
            "__node" | "__name" => config.node.name = to.clone(),
            "__ns" => config.node.namespace = if to == "/" { String::new() } else { to.clone() },
            _ => topic_remaps.push((from, to)),
        }
    }
    let (namespace, node) = (config.node.namespace.clone(), config.node.name.clone());
    let resolve = |name: &str| names::resolve(name, &namespace, &node);
    let mut unused = Vec::new();
    for (from, to) in topic_remaps {
        let (from, to) = (resolve(&from), resolve(to));
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
            if resolve(name) == from {
                name.clone_from(&to);
                hit = true;
            }
        }
        if !hit {
            unused.push(from);
        }
    }
    unused
}

impl NodeArgs {
    /// Runs the node until SIGINT or SIGTERM.
    pub fn run(self) -> anyhow::Result<ExitCode> {
        let ros = parse_ros_args(self.ros_args.as_deref().unwrap_or_default())?;
        super::init_logging(ros.log_level.as_deref(), ros.stdout_logs);
        if ros.enclave.is_some()
            && std::env::var("ROS_SECURITY_ENABLE").is_ok_and(|v| v.eq_ignore_ascii_case("true"))
        {
            return Err(BadUsage(
                "ROS_SECURITY_ENABLE=true: ttball's DDS (RustDDS through ros2-client) has no DDS \
                 security, so it cannot join a secured graph; unset ROS_SECURITY_ENABLE to run \
                 it in the open"
                    .to_owned(),
            )
            .into());
        }
        // ttball's own --config and -p first, then --ros-args' files and -p in their order.
        let layers: Vec<Layer> = (self.config.layers().into_iter())
            .chain(ros.layers.iter().cloned())
            .collect();
        let node_fqn = remapped_node_fqn(&ros.remaps);
        let mut config = yaml::load_layers(&layers, node_fqn.as_deref())?;
        let unused = apply_remaps(&mut config, &ros.remaps);
        config
            .validate()
            .map_err(|e| BadUsage(format!("after the remaps: {e}")))?;
        for name in unused {
            tracing::warn!("remap of {name}: the node has no such topic (ignored)");
        }
        let mut placement = Placement::from_env(&config).map_err(node_error)?;
        placement.live_view.clone_from(&self.foxglove);
        placement.rosout = ros.rosout_logs;
        // An empty path (a launch file's default) keeps nothing.
        placement.learned_file = self
            .learned
            .clone()
            .filter(|path| !path.as_os_str().is_empty());
        if let Some(path) = &placement.learned_file {
            super::check_learned_file(path)?;
            placement.learned_base =
                super::own_configuration(&layers, node_fqn.as_deref()).map(|mut own| {
                    apply_remaps(&mut own, &ros.remaps);
                    own
                });
        }

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
        if let Some(path) = &placement.learned_file {
            eprintln!(
                "what was learned written to {} (use it with --config {0})",
                path.display()
            );
        }
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
             --remap __ns:=/robot1 --params-file my.yaml --log-level debug --params-file b.yaml --",
        ))
        .unwrap();
        assert_eq!(
            ros.layers,
            [
                Layer::Param("intercept.plane_x:=-1.45".to_owned()),
                Layer::Param("ekf.q_a:=0.01".to_owned()),
                Layer::File("my.yaml".into()),
                Layer::File("b.yaml".into()),
            ]
        );
        assert_eq!(
            ros.remaps,
            [
                ("/ball/detections".to_owned(), "/vision/ball".to_owned()),
                ("__ns".to_owned(), "/robot1".to_owned())
            ]
        );
        assert_eq!(ros.log_level.as_deref(), Some("debug"));
        // What a launch file may pass besides: rcl's logging switches and the enclave.
        let rcl = parse_ros_args(&words(
            "--ros-args --enclave /ttball --disable-rosout-logs --disable-stdout-logs \
             --disable-external-lib-logs --log-level FATAL",
        ))
        .unwrap();
        assert_eq!(
            (rcl.enclave.as_deref(), rcl.rosout_logs, rcl.stdout_logs),
            (Some("/ttball"), false, false)
        );
        assert_eq!(rcl.log_level.as_deref(), Some("error"));
        let defaults = parse_ros_args(&words("--ros-args")).unwrap();
        assert!(defaults.rosout_logs && defaults.stdout_logs);
        for bad in [
            "-p",
            "-r nocolon",
            "--enclave",
            "--params-file",
            "--log-level loud",
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
                ("/robot1/ball/state".to_owned(), "state".to_owned()),
                ("__node".to_owned(), "ttball_left".to_owned()),
                ("ttball_left:__ns".to_owned(), "/robot1".to_owned()),
                ("other_node:__ns".to_owned(), "/elsewhere".to_owned()),
                ("/camera/image".to_owned(), "/x".to_owned()),
                ("ball/markers".to_owned(), "~/markers".to_owned()),
                ("/ball/intercept".to_owned(), "/y".to_owned()),
            ],
        );
        // Topic remaps match names resolved in the namespace the remaps give the node.
        assert_eq!(config.topics.detections, "/vision/ball");
        assert_eq!(config.topics.state, "/robot1/state");
        assert_eq!(config.topics.markers, "/robot1/ttball_left/markers");
        assert_eq!(config.topics.intercept, "ball/intercept");
        assert_eq!(config.resolved_topics().intercept, "/robot1/ball/intercept");
        assert_eq!(
            config.resolved_topics().trajectory,
            "/robot1/ball/trajectory"
        );
        assert_eq!(config.resolved_topics().diagnostics, "/diagnostics");
        assert_eq!(config.node.name, "ttball_left");
        assert_eq!(config.node.namespace, "/robot1");
        assert_eq!(unused, ["/camera/image", "/ball/intercept"]);
        config.validate().unwrap();
        assert_eq!(
            remapped_node_fqn(&[("__ns".to_owned(), "/r2".to_owned())]).as_deref(),
            Some("/r2/ttball")
        );
        assert_eq!(remapped_node_fqn(&[("a".to_owned(), "b".to_owned())]), None);
    }
}
