//! `ttball evaluate`: the estimator's accuracy on simulated play with truth, for both camera
//! setups (the README's accuracy table).

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::Context;
use clap::{Args, ValueEnum};
use ttball::eval::{EvalReport, LeadEfficiency, efficiency, evaluate};
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

    /// Also measure the filter's efficiency: its interception error at each lead divided by
    /// that of a batch fit of the same detections (1.0 is the best any estimator with this
    /// model can do). Fits every shot three times: about 0.1 s per shot.
    #[arg(long)]
    pub efficiency: bool,

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
            let efficiency = if self.efficiency {
                eprintln!("fitting every shot as a whole at each lead...");
                let lines = efficiency(&config, &session);
                write_stdout(&efficiency_table(&lines))?;
                Some(lines)
            } else {
                None
            };
            reports.push(
                serde_json::json!({ "setup": name, "report": report, "efficiency": efficiency }),
            );
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

/// The efficiency table: online and batch interception errors per lead.
fn efficiency_table(lines: &[LeadEfficiency]) -> String {
    let mut out = String::from(
        "efficiency: interception error in the plane [mm], over the shots both predict\n\
         lead      shots   online RMS/median   batch fit RMS/median   online / batch RMS, median\n",
    );
    for l in lines {
        out.push_str(&format!(
            "  {:>3.0} ms  {:>5}   {:>7.1} {:>7.1}     {:>7.1} {:>7.1}          {:>5.2} {:>5.2}\n",
            l.lead * 1e3,
            l.shots,
            l.online.rms * 1e3,
            l.online.median * 1e3,
            l.batch.rms * 1e3,
            l.batch.median * 1e3,
            l.ratio,
            l.median_ratio
        ));
    }
    out
}
