//! `ttball replay`: bags through the node's code path, with a summary (and accuracy when the bag
//! carries truth). Many bags run in parallel, one per core.

use std::fmt::Write as _;
use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Instant;

use anyhow::{Context, bail};
use clap::Args;
use ttball::bag::damage_text;
use ttball::bag::live_view::LiveView;
use ttball::bag::replay::{ReplaySummary, replay, replay_channels, replay_observed};
use ttball::online::estimator::{Dropped, LearnedParams, LearnedSourceNoise, Rejection};
use ttball::physics::PhysicsParams;

use super::report::accuracy_table;
use super::{ConfigArgs, cancel_on_interrupt, progress_bar, write_json, write_stdout};

/// Arguments of `ttball replay`.
#[derive(Debug, Args)]
pub struct ReplayArgs {
    /// Input bags: MCAP files, or rosbag2 directories from `ros2 bag record` (MCAP or sqlite3
    /// storage).
    #[arg(required = true, value_name = "INPUT.mcap")]
    pub inputs: Vec<PathBuf>,

    /// The output bag (one input).
    #[arg(long, short, value_name = "OUT.mcap", conflicts_with = "output_dir")]
    pub output: Option<PathBuf>,

    /// Directory for the output bags, each with its input's file name [default: replay-out].
    #[arg(long, value_name = "DIR")]
    pub output_dir: Option<PathBuf>,

    /// Write the summaries (and accuracy, when the bags carry truth) as JSON.
    #[arg(long, value_name = "FILE.json")]
    pub report: Option<PathBuf>,

    /// Also write what the estimator learned, as it ended, as a configuration file to start the
    /// node or the next replay from (pass it to --config after your own files): the ball's and
    /// table's physics in place of the configured values, and each camera's noise it learned in
    /// place of the configured one (one input).
    #[arg(long, value_name = "FILE.yaml")]
    pub learned: Option<PathBuf>,

    /// Also serve the bag's topics and the outputs live to the Foxglove app, at recorded pace,
    /// over the Foxglove WebSocket protocol (one input): in Foxglove, "Open connection" to
    /// ws://HOST:PORT. Waits for the app to connect first (--foxglove-wait).
    #[arg(long, value_name = "HOST:PORT")]
    pub foxglove: Option<String>,

    /// With --foxglove: how many times faster than recorded to play.
    #[arg(
        long,
        default_value_t = 1.0,
        requires = "foxglove",
        value_name = "FACTOR"
    )]
    pub rate: f64,

    /// With --foxglove: seconds to wait for the app to connect before starting (0: start at once).
    #[arg(
        long,
        default_value_t = 60.0,
        requires = "foxglove",
        value_name = "SECONDS"
    )]
    pub foxglove_wait: f64,

    /// The estimator's configuration and the topics.
    #[command(flatten)]
    pub config: ConfigArgs,
}

impl ReplayArgs {
    /// Replays every input.
    pub fn run(self) -> anyhow::Result<ExitCode> {
        let config = self.config.load()?;
        let jobs = self.jobs()?;
        if let Some(path) = &self.learned {
            if jobs.len() != 1 {
                bail!("--learned takes one input (each bag learns on its own)");
            }
            super::check_learned_file(path)?;
        }
        if let Some(address) = &self.foxglove {
            return self.run_with_live_view(address, &config, &jobs);
        }
        // Only one handler per process (tests run several commands): a failure is ignored.
        let (cancel, _) = cancel_on_interrupt();
        let workers = std::thread::available_parallelism()
            .map_or(1, |n| n.get())
            .min(jobs.len())
            .max(1);
        let next = AtomicUsize::new(0);
        let mut results: Vec<Option<Finished>> = (0..jobs.len()).map(|_| None).collect();
        let slots: Vec<std::sync::Mutex<Option<Finished>>> = (0..jobs.len())
            .map(|_| std::sync::Mutex::new(None))
            .collect();
        std::thread::scope(|scope| {
            for _ in 0..workers {
                scope.spawn(|| {
                    loop {
                        let i = next.fetch_add(1, Ordering::Relaxed);
                        let Some((input, output)) = jobs.get(i) else {
                            break;
                        };
                        let bar = progress_bar(
                            input.display().to_string(),
                            "{msg} [{bar:30}] {bytes}/{total_bytes} ({bytes_per_sec}, eta {eta})",
                        );
                        let mut progress = |done: u64, total: u64| {
                            bar.set_length(total);
                            bar.set_position(done);
                        };
                        // The whole run of this bag, as a user waits for it: reading,
                        // decoding, processing, encoding, compressing and writing.
                        let started = Instant::now();
                        let result = replay(input, output, &config, &mut progress, &cancel)
                            .with_context(|| format!("cannot replay {}", input.display()));
                        let whole_seconds = started.elapsed().as_secs_f64();
                        bar.finish_and_clear();
                        if let Ok(mut slot) = slots[i].lock() {
                            *slot = Some((result, whole_seconds));
                        }
                    }
                });
            }
        });
        for (slot, result) in slots.into_iter().zip(results.iter_mut()) {
            *result = slot.into_inner().ok().flatten();
        }
        let mut failed = false;
        let mut summaries = Vec::new();
        for (result, whole_seconds) in results.into_iter().flatten() {
            match result {
                Ok(summary) => {
                    write_stdout(&summary_text(&summary, Some(whole_seconds)))?;
                    self.write_learned(&config, &summary)?;
                    summaries.push((summary, whole_seconds));
                }
                Err(e) => {
                    eprintln!("error: {e:#}");
                    failed = true;
                }
            }
        }
        if let Some(path) = &self.report {
            let json: Vec<_> = summaries
                .iter()
                .map(|(summary, whole_seconds)| summary_json(summary, *whole_seconds))
                .collect();
            write_json(path, &json)?;
        }
        Ok(if failed || cancel.load(Ordering::Relaxed) {
            ExitCode::FAILURE
        } else {
            ExitCode::SUCCESS
        })
    }

    /// One bag replayed at recorded pace with its messages served to Foxglove as they are written.
    fn run_with_live_view(
        &self,
        address: &str,
        config: &ttball::config::Config,
        jobs: &[(PathBuf, PathBuf)],
    ) -> anyhow::Result<ExitCode> {
        let [(input, output)] = jobs else {
            bail!("--foxglove replays one bag at a time");
        };
        if !(self.rate > 0.0 && self.rate.is_finite()) {
            bail!(
                "--rate {} must be a positive factor (1 = recorded pace)",
                self.rate
            );
        }
        let channels = replay_channels(input, config)
            .with_context(|| format!("cannot replay {}", input.display()))?;
        let view = LiveView::start(address, &channels)?.at_recorded_pace(self.rate);
        let url = format!(
            "ws://{}:{}",
            address.rsplit_once(':').map_or("", |(h, _)| h),
            view.port()
        );
        eprintln!("Foxglove live view on {url} (in Foxglove: Open connection, {url})");
        if self.foxglove_wait > 0.0 {
            eprintln!(
                "waiting up to {} s for Foxglove to connect ...",
                self.foxglove_wait
            );
            if !view.wait_for_client(std::time::Duration::from_secs_f64(self.foxglove_wait)) {
                eprintln!("no client connected; replaying anyway");
            }
        }
        let (cancel, _) = cancel_on_interrupt();
        let mut view = view;
        let summary = replay_observed(
            input,
            output,
            config,
            &mut |_, _| {},
            &cancel,
            Some(Box::new(move |channel, log_time, payload| {
                view.log(channel, log_time, payload);
            })),
        )
        .with_context(|| format!("cannot replay {}", input.display()))?;
        write_stdout(&summary_text(&summary, None))?;
        self.write_learned(config, &summary)?;
        Ok(if cancel.load(Ordering::Relaxed) {
            ExitCode::FAILURE
        } else {
            ExitCode::SUCCESS
        })
    }

    /// With `--learned`: what the replay's estimator learned, as a configuration file.
    fn write_learned(
        &self,
        config: &ttball::config::Config,
        summary: &ReplaySummary,
    ) -> anyhow::Result<()> {
        let Some(path) = &self.learned else {
            return Ok(());
        };
        let by = format!("`ttball replay --learned` from {}", summary.input.display());
        let own = super::own_configuration(&self.config.layers(), None);
        let text = summary
            .learned
            .file_text(own.as_ref().unwrap_or(config), config, &by)
            .context("what the estimator learned is not a valid configuration")?;
        std::fs::write(path, text).with_context(|| format!("cannot write {}", path.display()))?;
        eprintln!(
            "what was learned written to {} (use it with --config {0})",
            path.display()
        );
        Ok(())
    }

    /// (input, output) pairs.
    fn jobs(&self) -> anyhow::Result<Vec<(PathBuf, PathBuf)>> {
        match (&self.output, &self.output_dir, self.inputs.as_slice()) {
            (Some(out), None, [input]) => Ok(vec![(input.clone(), out.clone())]),
            (Some(_), None, _) => {
                bail!("--output takes one input; use --output-dir DIR for several")
            }
            (None, dir, inputs) => {
                let dir = dir.clone().unwrap_or_else(|| PathBuf::from("replay-out"));
                let dir = &dir;
                std::fs::create_dir_all(dir)
                    .with_context(|| format!("cannot create {}", dir.display()))?;
                inputs
                    .iter()
                    .map(|input| {
                        let name = input
                            .file_name()
                            .with_context(|| format!("{} has no file name", input.display()))?;
                        let mut out = dir.join(name);
                        if out.extension().is_none_or(|e| e != "mcap") {
                            // A rosbag2 directory: its output is one file.
                            out.set_extension("mcap");
                        }
                        if out == *input {
                            bail!("{} would overwrite its input", out.display());
                        }
                        Ok((input.clone(), out))
                    })
                    .collect()
            }
            (Some(_), Some(_), _) => bail!("give either --output or --output-dir"),
        }
    }
}

/// One bag's replay as it ended, with the wall time of its whole run [s].
type Finished = (anyhow::Result<ReplaySummary>, f64);

/// The summary a user reads at the end of a replay; `whole_seconds`, when the bag was replayed as
/// fast as it goes, is the wall time of its whole run (reading to the finished output).
pub fn summary_text(s: &ReplaySummary, whole_seconds: Option<f64>) -> String {
    let c = &s.counters;
    let mut out = format!("{} -> {}\n", s.input.display(), s.output.display());
    if let Some(damage) = damage_text(&s.damage) {
        let _ = writeln!(out, "  warning: the input is damaged; {damage}");
    }
    if s.interrupted {
        out.push_str("  interrupted: the output holds what was replayed, properly finished\n");
    }
    let _ = writeln!(
        out,
        "  detections read {}, fused {}, initialising {}, rejected {}, undecodable {}; tracks {}{}",
        s.detections,
        c.fused,
        c.initializing,
        c.total_rejected(),
        s.undecodable,
        c.tracks,
        if c.reanchored > 0 {
            format!(" (re-anchored on their own detections {})", c.reanchored)
        } else {
            String::new()
        }
    );
    if c.seeded_by_hit + c.hits_not_seeded + s.robot_hits_refused > 0 {
        let _ = writeln!(
            out,
            "  robot hits: {} seeded the return's track, {} seeded none, {} refused",
            c.seeded_by_hit, c.hits_not_seeded, s.robot_hits_refused
        );
    }
    let reasons: Vec<String> = c.rejections();
    if !reasons.is_empty() {
        let _ = writeln!(out, "  rejected by reason: {}", reasons.join(", "));
    }
    if c.zero_spin_ignored > 0 {
        let _ = writeln!(
            out,
            "  {} detections claimed a spin of exactly zero: their positions were used, their spins ignored",
            c.zero_spin_ignored
        );
    }
    let _ = writeln!(
        out,
        "  late detections rolled back and re-applied {}; interceptions predicted in full {}, moved from the last full one {}",
        c.rollbacks, s.intercepts.full, s.intercepts.moved
    );
    if c.smoothed_lessons > 0 || c.lessons_dropped.iter().any(|n| *n > 0) {
        let dropped: Vec<String> = Dropped::ALL
            .iter()
            .map(|r| format!("{} {}", r.name(), c.lessons_dropped(*r)))
            .collect();
        let _ = writeln!(
            out,
            "  tracks that taught their flight smoothed {}; lessons dropped: {}",
            c.smoothed_lessons,
            dropped.join(", ")
        );
    }
    for line in s.learned.lines() {
        let _ = writeln!(out, "  {line}");
    }
    let _ = writeln!(
        out,
        "  processing per detection: mean {:.1} us, p99 {:.1} us (the lessons' smoothing it waited for or took over, {:.1} ms in all, left out); then {} trajectories: mean {:.1} us, p99 {:.1} us; {:.1} s recorded in {:.2} s ({:.0}x real time); {} messages written",
        s.processing_mean_ns * 1e-3,
        s.processing_p99_ns * 1e-3,
        s.lesson_wait_seconds * 1e3,
        s.trajectories,
        s.trajectory_mean_ns * 1e-3,
        s.trajectory_p99_ns * 1e-3,
        s.recorded_seconds,
        s.processing_seconds,
        s.real_time_factor(),
        s.written
    );
    if let Some(whole) = whole_seconds {
        let _ = writeln!(
            out,
            "  whole run (reading, decoding, processing, encoding, compressing, writing): {:.2} s ({:.0}x real time)",
            whole,
            s.recorded_seconds / whole.max(1e-9)
        );
    }
    if let Some(a) = &s.accuracy {
        let _ = writeln!(
            out,
            "  accuracy against the bag's truth ({} shots):",
            a.shots
        );
        for line in accuracy_table(a).lines() {
            let _ = writeln!(out, "    {line}");
        }
    }
    out
}

/// The learned noise of each source as JSON.
pub fn noise_json(noise: &[LearnedSourceNoise]) -> serde_json::Value {
    let sources: serde_json::Map<String, serde_json::Value> = noise
        .iter()
        .map(|n| {
            (
                n.source.to_string(),
                serde_json::json!({
                    "position_sigma": n.position_sigma,
                    "position_scale": n.estimate.position_scale,
                    "stamp_sigma": n.stamp_sigma,
                    "spin_scale": n.estimate.spin_scale,
                    "detections": n.estimate.weight,
                }),
            )
        })
        .collect();
    serde_json::Value::Object(sources)
}

/// The learned physical parameters as JSON: each by name with its value and sigma.
pub fn learned_json(l: &LearnedParams) -> serde_json::Value {
    let values = l.params.to_vector();
    let params: serde_json::Map<String, serde_json::Value> = PhysicsParams::NAMES
        .iter()
        .enumerate()
        .map(|(i, name)| {
            (
                (*name).to_string(),
                serde_json::json!({
                    "value": values[i],
                    "sigma": l.sigma[i],
                    "flight_sigma": l.flight_sigma[i],
                }),
            )
        })
        .collect();
    serde_json::json!({"tracks": l.tracks, "params": params})
}

fn summary_json(s: &ReplaySummary, whole_seconds: f64) -> serde_json::Value {
    let c = &s.counters;
    let rejected: serde_json::Map<String, serde_json::Value> = Rejection::ALL
        .iter()
        .map(|r| (r.name().to_string(), c.rejected(*r).into()))
        .collect();
    let lessons_dropped: serde_json::Map<String, serde_json::Value> = Dropped::ALL
        .iter()
        .map(|r| (r.name().to_string(), c.lessons_dropped(*r).into()))
        .collect();
    serde_json::json!({
        "input": s.input,
        "output": s.output,
        "damage": damage_text(&s.damage),
        "interrupted": s.interrupted,
        "detections": s.detections,
        "undecodable": s.undecodable,
        "fused": c.fused,
        "initializing": c.initializing,
        "rejected": rejected,
        "tracks": c.tracks,
        "reanchored": c.reanchored,
        "rollbacks": c.rollbacks,
        "smoothed_lessons": c.smoothed_lessons,
        "lessons_dropped": lessons_dropped,
        "intercepts_full": s.intercepts.full,
        "intercepts_moved": s.intercepts.moved,
        "learned_physics": learned_json(&s.learned.params),
        "learned_noise": noise_json(&s.learned.source_noise),
        "zero_spin_ignored": c.zero_spin_ignored,
        "seeded_by_hit": c.seeded_by_hit,
        "hits_not_seeded": c.hits_not_seeded,
        "robot_hits_refused": s.robot_hits_refused,
        "processing_mean_ns": s.processing_mean_ns,
        "processing_p99_ns": s.processing_p99_ns,
        "trajectories": s.trajectories,
        "trajectory_mean_ns": s.trajectory_mean_ns,
        "trajectory_p99_ns": s.trajectory_p99_ns,
        "recorded_seconds": s.recorded_seconds,
        "processing_seconds": s.processing_seconds,
        "lesson_wait_seconds": s.lesson_wait_seconds,
        "real_time_factor": s.real_time_factor(),
        "whole_seconds": whole_seconds,
        "whole_real_time_factor": s.recorded_seconds / whole_seconds.max(1e-9),
        "accuracy": s.accuracy,
    })
}
