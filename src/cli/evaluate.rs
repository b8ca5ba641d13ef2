//! `ttball evaluate`: the estimator's accuracy on simulated play with truth, for both camera
//! setups (the README's accuracy table).

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::Context;
use clap::{Args, ValueEnum};
use ttball::eval::{EvalReport, evaluate};
use ttball::sim::{Cameras, SimOptions, simulate};

use super::report::accuracy_table;
use super::{ConfigArgs, write_stdout};

/// Which camera setups to evaluate.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum Setup {
    /// The 150 fps camera only.
    Wide,
    /// The 150 fps and the 900 fps cameras.
    #[value(name = "wide+highspeed")]
    Both,
    /// Each of the two setups in turn.
    All,
}

/// Arguments of `ttball evaluate`.
#[derive(Debug, Args)]
pub struct EvaluateArgs {
    /// Number of simulated shots (half real rally balls, half random top/back/side/mixed spin).
    #[arg(long, default_value_t = 200)]
    pub shots: usize,

    /// Seed of the simulation: the same seed gives the same shots and detections.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,

    /// Camera setup(s).
    #[arg(long, value_enum, default_value = "all")]
    pub cameras: Setup,

    /// Also write the report as JSON to this file.
    #[arg(long, value_name = "FILE")]
    pub json: Option<PathBuf>,

    /// The estimator's configuration (its camera noise is set to the simulated cameras').
    #[command(flatten)]
    pub config: ConfigArgs,
}

impl EvaluateArgs {
    /// Simulates, runs the estimator and prints the accuracy table.
    pub fn run(self) -> anyhow::Result<ExitCode> {
        let mut config = self.config.load()?;
        let setups: &[(Cameras, &str)] = match self.cameras {
            Setup::Wide => &[(Cameras::WideOnly, "150 fps")],
            Setup::Both => &[(Cameras::WideAndHighSpeed, "150 + 900 fps")],
            Setup::All => &[
                (Cameras::WideOnly, "150 fps"),
                (Cameras::WideAndHighSpeed, "150 + 900 fps"),
            ],
        };
        let mut reports = Vec::new();
        for &(cameras, name) in setups {
            let options = SimOptions {
                cameras,
                shots: self.shots,
                seed: self.seed,
                ..SimOptions::default()
            };
            options.params.configure_estimator(&mut config);
            eprintln!(
                "simulating {} shots ({name}) and running the estimator...",
                self.shots
            );
            let session = simulate(&config, &options).context("cannot simulate the session")?;
            let started = std::time::Instant::now();
            let report = evaluate(&config, &session);
            let elapsed = started.elapsed().as_secs_f64();
            write_stdout(&table(name, &report, elapsed))?;
            reports.push(serde_json::json!({ "setup": name, "report": report }));
        }
        if let Some(path) = &self.json {
            let text = serde_json::to_string_pretty(&reports)?;
            std::fs::write(path, text + "\n")
                .with_context(|| format!("cannot write {}", path.display()))?;
        }
        Ok(ExitCode::SUCCESS)
    }
}

/// The accuracy table of one setup.
fn table(name: &str, r: &EvalReport, elapsed: f64) -> String {
    let c = &r.counters;
    let mut out = format!(
        "\n== {name}: {} shots, {} detections ({} fused, {} initialising, {} rejected), {:.1} s\n",
        r.shots,
        r.detections,
        c.fused,
        c.initializing,
        c.total_rejected(),
        elapsed
    );
    out.push_str(&accuracy_table(r));
    out
}
