//! `ttball play`: a bag's detections on the DDS bus at their recorded pace (see
//! `ttball::node::play`).

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

use anyhow::Context;
use clap::Args;
use ttball::node::{Placement, PlayOptions, play};

use super::node::node_error;
use super::{BadUsage, ConfigArgs, cancel_on_interrupt, progress_bar, write_stdout};

/// Arguments of `ttball play`.
#[derive(Debug, Args)]
pub struct PlayArgs {
    /// The bag: an MCAP file, or a rosbag2 directory (MCAP or sqlite3 storage).
    #[arg(value_name = "BAG.mcap")]
    pub bag: PathBuf,

    /// Speed factor: 0.5 plays at half the recorded speed, 2 at twice.
    #[arg(long, default_value_t = 1.0, value_name = "X")]
    pub rate: f64,

    /// Play again and again until Ctrl-C; each pass's stamps follow the previous pass's.
    #[arg(long = "loop")]
    pub repeat: bool,

    /// Wait up to this long for a subscriber before the first detection (0: start at once).
    #[arg(long, default_value_t = 5.0, value_name = "SECONDS")]
    pub wait: f64,

    /// Also subscribe to the node's state and intercept topics and print its end-to-end
    /// latency: for each output, the time from publishing the detection with its stamp to
    /// receiving it (median, 99th percentile, largest; outputs more than 5 s late are not
    /// counted, so that `--loop --latency` runs in bounded memory). Run beside `ttball node`.
    #[arg(long)]
    pub latency: bool,

    /// Topic names, QoS depth, DDS interfaces.
    #[command(flatten)]
    pub config: ConfigArgs,
}

impl PlayArgs {
    /// Plays the bag.
    pub fn run(self) -> anyhow::Result<ExitCode> {
        if !(self.rate.is_finite() && self.rate > 0.0 && self.rate <= 1000.0) {
            return Err(BadUsage(format!("--rate must be in (0, 1000], got {}", self.rate)).into());
        }
        if !(self.wait.is_finite() && (0.0..=3600.0).contains(&self.wait)) {
            return Err(
                BadUsage(format!("--wait must be in [0, 3600] s, got {}", self.wait)).into(),
            );
        }
        super::init_logging(None, true);
        let config = self.config.load()?;
        let placement = Placement::from_env(&config).map_err(node_error)?;
        let (cancel, installed) = cancel_on_interrupt();
        installed.context("cannot install the SIGINT/SIGTERM handler")?;
        let bar = progress_bar(
            format!("playing {}", self.bag.display()),
            "{msg} [{bar:30}] {pos}/{len} detections, {elapsed_precise}",
        );
        let options = PlayOptions {
            rate: self.rate,
            repeat: self.repeat,
            wait_for_subscriber: Duration::from_secs_f64(self.wait),
            measure_latency: self.latency,
        };
        let mut progress = |done: u64, total: u64| {
            bar.set_length(total);
            bar.set_position(done);
        };
        let summary = play(
            &self.bag,
            &config,
            &placement,
            &options,
            &cancel,
            &mut progress,
        )
        .map_err(node_error)
        .with_context(|| format!("cannot play {}", self.bag.display()))?;
        bar.finish_and_clear();
        write_stdout(&format!(
            "{}: {} detections published on {} in {:.1} s ({} pass{}, {} subscriber{} at the start){}{}\n",
            self.bag.display(),
            summary.published,
            config.resolved_topics().detections,
            summary.seconds,
            summary.passes,
            if summary.passes == 1 { "" } else { "es" },
            summary.subscribers,
            if summary.subscribers == 1 { "" } else { "s" },
            if summary.undecodable > 0 {
                format!("; {} undecodable skipped", summary.undecodable)
            } else {
                String::new()
            },
            if summary.errors > 0 {
                format!("; {} refused by DDS", summary.errors)
            } else {
                String::new()
            },
        ))?;
        if let Some(latency) = &summary.latency {
            let line = |topic: &str, l: &ttball::node::Latency| {
                format!(
                    "  latency to {topic}: p50 {:.2} ms, p99 {:.2} ms, max {:.2} ms ({} of {} received)\n",
                    l.p50 * 1e3,
                    l.p99 * 1e3,
                    l.max * 1e3,
                    l.received,
                    summary.published
                )
            };
            write_stdout(&format!(
                "{}{}",
                line(&config.resolved_topics().state, &latency.state),
                line(&config.resolved_topics().intercept, &latency.intercept)
            ))?;
        }
        Ok(ExitCode::SUCCESS)
    }
}
