//! `ttball evaluate`: the estimator's accuracy on simulated play with truth, for both camera
//! setups (the README's accuracy table).

use std::fmt::Write as _;
use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::Context;
use clap::{Args, ValueEnum};
use ttball::eval::{ErrorStats, EvalReport, evaluate};
use ttball::sim::{Cameras, SimOptions, simulate};

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

fn stats_mm(s: &ErrorStats) -> String {
    format!(
        "{:6.1} {:6.1} {:6.1}",
        s.rms * 1e3,
        s.median * 1e3,
        s.p95 * 1e3
    )
}

fn stats(s: &ErrorStats) -> String {
    format!("{:6.2} {:6.2} {:6.2}", s.rms, s.median, s.p95)
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
    out.push_str("                                         RMS median    p95\n");
    let _ = writeln!(
        out,
        "velocity after 100 ms [m/s]           {}",
        stats(&r.velocity_error)
    );
    let _ = writeln!(
        out,
        "spin after 100 ms [rad/s]             {}",
        stats(&r.spin_error)
    );
    let _ = writeln!(
        out,
        "  perpendicular to v [rad/s]          {}",
        stats(&r.spin_error_perpendicular)
    );
    let _ = writeln!(
        out,
        "  along v [rad/s]                     {}",
        stats(&r.spin_error_parallel)
    );
    if r.spin_error_high_speed.count > 0 {
        let _ = writeln!(
            out,
            "velocity where 900 fps sees it [m/s]  {}",
            stats(&r.velocity_error_high_speed)
        );
        let _ = writeln!(
            out,
            "spin where 900 fps sees it [rad/s]    {}",
            stats(&r.spin_error_high_speed)
        );
    }
    let _ = writeln!(
        out,
        "state NEES per dimension              {:6.2}   (position {:.2}, velocity {:.2}, spin {:.2})",
        r.state_nees, r.block_nees[0], r.block_nees[1], r.block_nees[2]
    );
    let _ = writeln!(
        out,
        "velocity within 2 ms of the bounce    {}   ({} estimates, left out above)",
        stats(&r.velocity_error_at_bounce),
        r.velocity_error_at_bounce.count
    );
    let _ = writeln!(
        out,
        "  before / after the bounce             {:6.2} / {:.2}",
        r.bounce_nees[0], r.bounce_nees[1]
    );
    out.push_str("interception     valid   position [mm] RMS/median/p95   time [ms] RMS/median/p95   NEES/dim\n");
    for lead in &r.leads {
        let _ = writeln!(
            out,
            "  {:3.0} ms lead   {:5.1} %  {}      {}        {:5.2}",
            lead.lead * 1e3,
            lead.valid_fraction * 100.0,
            stats_mm(&lead.position_error),
            stats_mm(&lead.time_error),
            lead.position_nees
        );
    }
    out
}
