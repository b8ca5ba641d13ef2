//! `ttball smooth`: the whole-flight fit of every track of a bag, as `/ball/smoothed`.

use std::fmt::Write as _;
use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{Context, bail};
use clap::Args;
use ttball::bag::damage_text;
use ttball::bag::replay::{SmoothSummary, smooth_bag};

use super::{BadUsage, ConfigArgs, cancel_on_interrupt, progress_bar, write_stdout};

/// Arguments of `ttball smooth`.
#[derive(Debug, Args)]
pub struct SmoothArgs {
    /// The input bag: an MCAP file, or a rosbag2 directory (MCAP or sqlite3 storage).
    #[arg(value_name = "INPUT.mcap")]
    pub input: PathBuf,

    /// The output bag: the input's messages plus the smoothed states.
    #[arg(long, short, value_name = "OUT.mcap")]
    pub output: PathBuf,

    /// The physics the flights are fitted with, the noise of the cameras and the topics.
    #[command(flatten)]
    pub config: ConfigArgs,
}

impl SmoothArgs {
    /// Smooths the bag and prints what was done.
    pub fn run(self) -> anyhow::Result<ExitCode> {
        let config = self.config.load()?;
        if self.output == self.input {
            bail!(BadUsage(format!(
                "{} would overwrite its input; choose another --output",
                self.output.display()
            )));
        }
        // Only one handler per process (tests run several commands): a failure is ignored.
        let (cancel, _) = cancel_on_interrupt();
        let bar = progress_bar(
            format!("smoothing {}", self.input.display()),
            "{msg} [{bar:30}] {pos}/{len} flights (eta {eta})",
        );
        let mut progress = |done: usize, total: usize| {
            bar.set_length(total as u64);
            bar.set_position(done as u64);
        };
        let summary = smooth_bag(&self.input, &self.output, &config, &mut progress, &cancel)
            .with_context(|| format!("cannot smooth {}", self.input.display()))?;
        bar.finish_and_clear();
        write_stdout(&summary_text(&summary, &config.resolved_topics().smoothed))?;
        Ok(if summary.smoothing.skipped > 0 {
            ExitCode::FAILURE
        } else {
            ExitCode::SUCCESS
        })
    }
}

/// The summary a user reads at the end.
fn summary_text(s: &SmoothSummary, topic: &str) -> String {
    let m = &s.smoothing;
    let c = &m.counters;
    let mut out = format!("{} -> {}\n", s.input.display(), s.output.display());
    if let Some(damage) = damage_text(&s.damage) {
        let _ = writeln!(out, "  warning: the input is damaged; {damage}");
    }
    if m.skipped > 0 {
        let _ = writeln!(
            out,
            "  interrupted: {} flights not smoothed; the output holds the others, properly finished",
            m.skipped
        );
    }
    let _ = writeln!(
        out,
        "  detections read {}: smoothed {} on {} ({} flights fitted, {} marked outliers by the fit), undecodable {}, not in the table frame {}",
        s.detections,
        m.states.len(),
        topic,
        m.flights,
        m.outliers,
        s.undecodable,
        s.unknown_frame
    );
    let reasons: Vec<String> = c.rejections();
    if !reasons.is_empty() {
        let _ = writeln!(
            out,
            "  not smoothed, rejected by the estimator: {}",
            reasons.join(", ")
        );
    }
    for f in &m.failed {
        let _ = writeln!(
            out,
            "  track {} ({} detections) not smoothed: {}",
            f.track_id, f.detections, f.error
        );
    }
    if let Some(e) = &s.truth_errors {
        let _ = writeln!(
            out,
            "  against the bag's truth ({} states; {} within {:.0} ms of a bounce left out): position {:.2} mm, velocity {:.4} m/s, spin {:.1} rad/s RMS",
            e.count,
            e.at_bounce,
            ttball::eval::BOUNCE_WINDOW * 1e3,
            e.position * 1e3,
            e.velocity,
            e.spin
        );
    }
    let _ = writeln!(out, "  {} messages written", s.written);
    out
}
