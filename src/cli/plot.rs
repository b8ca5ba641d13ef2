//! `ttball plot`: a figure (SVG or PNG) of what the estimator saw in a bag: top and side views of
//! detections, filtered track, predicted flights, bounce and interception points (and truth when
//! the bag has it), speed and spin over time.
//!
//! The bag's detections are run through the estimator again (the same code path as the replay,
//! deterministic: with the same configuration it is exactly what `ttball replay` wrote), so any
//! bag with detections can be plotted, a replay output or its input.

use std::fmt::Write as _;
use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{Context, bail};
use clap::Args;
use ttball::bag::decode;
use ttball::bag::replay::read_detections;
use ttball::model::detection::seconds_to_ns;
use ttball::online::estimator::{Estimator, TrackStatus};
use ttball::plot::{
    PlotData, PlotOptions, PlotTrajectory, PlotTruth, Selection, render_png, render_svg,
};
use ttball::ros::msgs::convert::state_from_msg;
use ttball::ros::msgs::ttball_msgs::msg::BallState;

use super::{ConfigArgs, write_file, write_stdout};

/// Arguments of `ttball plot`.
#[derive(Debug, Args)]
pub struct PlotArgs {
    /// The bag (a replay's output or any bag with detections).
    #[arg(value_name = "BAG.mcap")]
    pub bag: PathBuf,

    /// The figure to write: `.svg` or `.png`.
    #[arg(
        long,
        short,
        value_name = "FILE.svg|png",
        required_unless_present = "list"
    )]
    pub output: Option<PathBuf>,

    /// The track to draw [default: the longest].
    #[arg(long, value_name = "ID", conflicts_with = "window")]
    pub track: Option<u32>,

    /// A time window instead, in seconds from the bag's first detection: START,END.
    #[arg(long, value_name = "START,END", allow_hyphen_values = true)]
    pub window: Option<String>,

    /// List the tracks (id, start, duration) and exit.
    #[arg(long)]
    pub list: bool,

    /// Figure size in pixels, WIDTHxHEIGHT.
    #[arg(long, default_value = "1600x1000")]
    pub size: String,

    /// The estimator's configuration (use the replay's).
    #[command(flatten)]
    pub config: ConfigArgs,
}

/// Every this many estimates a predicted flight is recorded for the figure.
const PREDICTION_EVERY: usize = 20;

impl PlotArgs {
    /// Draws the figure.
    pub fn run(self) -> anyhow::Result<ExitCode> {
        let config = self.config.load()?;
        let bag = read_detections(&self.bag, &config)?;
        let truth_channel = bag.contents.channel(&config.resolved_topics().truth);
        let mut data = PlotData::new(&config);
        let mut estimator = Estimator::new(&config);
        let mut estimates = 0usize;
        for (m, index) in bag.contents.messages.iter().zip(&bag.message_detection) {
            if Some(m.channel) == truth_channel {
                if let Ok(msg) = decode::<BallState>(&m.data) {
                    let (stamp, _, state) = state_from_msg(&msg);
                    data.truth.push(PlotTruth::new(stamp, &state));
                }
                continue;
            }
            let Some(detection) = index.map(|i| bag.detections[i]) else {
                continue;
            };
            let out = estimator.handle(&detection);
            data.record(&detection, &out);
            if let Some(e) = out.estimate.filter(|e| e.status == TrackStatus::Tracking) {
                estimates += 1;
                if estimates.is_multiple_of(PREDICTION_EVERY)
                    && let Some((stamp, t)) = estimator.predicted_trajectory(
                        config.prediction.trajectory_dt,
                        config.prediction.horizon,
                    )
                {
                    data.trajectories
                        .push(PlotTrajectory::new(stamp, e.track_id, &t));
                }
            }
        }
        let tracks = data.tracks();
        if self.list {
            let origin = data.first_stamp().unwrap_or(0);
            let mut text = format!("{} tracks in {}\n", tracks.len(), self.bag.display());
            for t in &tracks {
                let _ = writeln!(
                    text,
                    "  track {:4}: from {:8.3} s for {:.3} s ({} estimates)",
                    t.track_id,
                    (t.first - origin) as f64 * 1e-9,
                    t.duration(),
                    t.estimates
                );
            }
            write_stdout(&text)?;
            return Ok(ExitCode::SUCCESS);
        }
        let selection = match (&self.window, self.track) {
            (Some(window), _) => {
                let (a, b) = window
                    .split_once(',')
                    .context("--window takes START,END in seconds, e.g. 0.5,1.2")?;
                let origin = data.first_stamp().unwrap_or(0);
                let at = |s: &str| -> anyhow::Result<i64> {
                    let v: f64 = s
                        .trim()
                        .parse()
                        .with_context(|| format!("`{s}` is not a number of seconds"))?;
                    Ok(origin + seconds_to_ns(v))
                };
                Selection::window(at(a)?, at(b)?)
            }
            (None, Some(id)) => Selection::track(id),
            (None, None) => {
                let Some(longest) = tracks
                    .iter()
                    .max_by_key(|t| (t.estimates, std::cmp::Reverse(t.track_id)))
                else {
                    bail!(
                        "{}: the estimator found no track in this bag",
                        self.bag.display()
                    );
                };
                Selection::track(longest.track_id)
            }
        };
        let (width, height) = self
            .size
            .split_once('x')
            .and_then(|(w, h)| Some((w.parse().ok()?, h.parse().ok()?)))
            .context("--size takes WIDTHxHEIGHT, e.g. 1600x1000")?;
        let options = PlotOptions {
            width,
            height,
            ..PlotOptions::default()
        };
        let Some(output) = &self.output else {
            bail!("give --output FILE.svg or FILE.png");
        };
        let extension = output
            .extension()
            .and_then(|e| e.to_str())
            .unwrap_or_default();
        let bytes = match extension.to_ascii_lowercase().as_str() {
            "svg" => render_svg(&data, &selection, &options)?.into_bytes(),
            "png" => render_png(&data, &selection, &options)?,
            _ => bail!(
                "{}: the figure's name must end in .svg or .png",
                output.display()
            ),
        };
        write_file(output, bytes)?;
        write_stdout(&format!("{}: {}\n", output.display(), selection.describe()))?;
        Ok(ExitCode::SUCCESS)
    }
}
