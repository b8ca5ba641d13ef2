//! `ttball simulate`: a bag of simulated play with its truth.

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::Context;
use clap::{Args, ValueEnum};
use ttball::bag::record::write_session;
use ttball::eval::sim::{Cameras, SimOptions, simulate};

use super::{ConfigArgs, write_stdout};

/// The cameras of a simulated bag.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum CameraSetup {
    /// The 150 fps camera over the whole table only.
    Wide,
    /// The 150 fps camera and the 900 fps camera over the robot's half (with spin).
    #[value(name = "wide+highspeed")]
    WideHighspeed,
}

/// Arguments of `ttball simulate`.
#[derive(Debug, Args)]
pub struct SimulateArgs {
    /// The bag to write (ROS 2 MCAP).
    #[arg(long, short, value_name = "FILE.mcap")]
    pub output: PathBuf,

    /// Number of shots (half real rally balls, half random top/back/side/mixed spin).
    #[arg(long, default_value_t = 20)]
    pub shots: usize,

    /// Seed: the same seed (and configuration) gives the same bytes.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,

    /// Which cameras see the ball.
    #[arg(long, value_enum, default_value = "wide+highspeed")]
    pub cameras: CameraSetup,

    /// Write the detections only, without the truth topics (as a camera system records them:
    /// a smaller bag, nothing to score against).
    #[arg(long)]
    pub no_truth: bool,

    /// The physics, table, hitting plane and topics of the simulation.
    #[command(flatten)]
    pub config: ConfigArgs,
}

impl SimulateArgs {
    /// Simulates and writes the bag.
    pub fn run(self) -> anyhow::Result<ExitCode> {
        let config = self.config.load()?;
        let options = SimOptions {
            cameras: match self.cameras {
                CameraSetup::Wide => Cameras::WideOnly,
                CameraSetup::WideHighspeed => Cameras::WideAndHighSpeed,
            },
            shots: self.shots,
            seed: self.seed,
            ..SimOptions::default()
        };
        let session = simulate(&config, &options).context("cannot simulate")?;
        let messages = write_session(&session, &config, &self.output, !self.no_truth)?;
        let bytes = std::fs::metadata(&self.output)
            .map(|m| m.len())
            .unwrap_or(0);
        let outliers = session.stream.iter().filter(|d| d.outlier).count();
        write_stdout(&format!(
            "{}: {} shots, {} detections ({} outliers), {} messages, {:.1} MB\n",
            self.output.display(),
            session.shots.len(),
            session.stream.len(),
            outliers,
            messages,
            bytes as f64 / 1e6
        ))?;
        Ok(ExitCode::SUCCESS)
    }
}
