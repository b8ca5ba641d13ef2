//! `ttball evaluate`: the estimator's accuracy on simulated play with truth, for both camera
//! setups (the accuracy tables of README.md and docs/accuracy.md).

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::Context;
use clap::{Args, ValueEnum};
use nalgebra::Vector3;
use ttball::eval::real::{
    FlightResult, LauncherFlights, LeadOutcome, RealEvalOptions, RealReport, SpinKind,
    evaluate_flights, topspin,
};
use ttball::eval::sets::{
    LeadComparison, SETTLE_FLIGHTS, SetReport, TrialSet, run_set, set_efficiency, standard_sets,
};
use ttball::eval::sim::{Cameras, SimOptions, simulate};
use ttball::eval::{
    BatchPhysics, Comparison, Efficiency, EvalReport, efficiency, evaluate_learning,
};
use ttball::model::stats::{ErrorStats, nearest_rank};
use ttball::physics::{BallState, PhysicsParams};

mod tables;

pub use tables::DocTable;
use tables::{doc_table, readme_tables};

use super::import::{CsvFrame, FRAME_HELP};
use super::report::accuracy_table;
use super::{ConfigArgs, write_json, write_stdout};

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

    /// Also measure the filter's efficiency: its errors (interception and spin at the crossing
    /// at each lead, velocity after 100 ms of track, spin across the flight before the 900 fps
    /// camera sees the ball) divided by those of a batch fit of the same detections at the
    /// same stamps (1.0 is the best any estimator of a flight that follows the model can do),
    /// the fit flying the configured physics and, again, the physics the estimator had learned
    /// when the shot began. Fits every shot ten times: about 0.2 s per shot. With `--sets`:
    /// each set's shots again, the fit flying the learned physics and the set's true physics.
    #[arg(long)]
    pub efficiency: bool,

    /// Evaluate the harder sets instead: simulated play whose physics (drag, Magnus,
    /// restitution, friction), noise (1.5x the configured) and timing (a 143 Hz tracker with
    /// millisecond stamps, no net) differ from the configuration, and elite play (to 28 m/s and
    /// 960 rad/s, from both ends); `all`, or names separated by commas (exact-2cams,
    /// exact-wide, a-2cams, b-2cams, a-lab, b-lab, a-elite, b-elite). `--shots` is per set.
    #[arg(long, value_name = "SETS")]
    pub sets: Option<String>,

    /// Evaluate on real launcher flights instead: CSV files in the MPI launcher's format and
    /// frame (`trajectory,t_s,x_m,y_m,z_m`, x along the table from the launcher's end line, z up;
    /// e.g. `tests/data/mpi_launcher/*.csv`; `ttball import mpi --help`), grouped by the
    /// spin a file's name states (`backspin`, `no_spin`, `topspin`, else "not stated"). Every flight runs through
    /// its own estimator, which starts from what the flights before it taught; its crossing of
    /// a plane 20 ms after its measured bounce is predicted 200 and 100 ms ahead and compared
    /// with the measured one (the error, its bias, and its NEES per dimension: about 1 when the
    /// predicted covariance is honest). The 150 fps source's noise is set to the noise measured
    /// from the flights.
    #[arg(long, value_name = "FILE.csv", num_args = 1.., conflicts_with_all = ["sets", "efficiency"])]
    pub real: Vec<PathBuf>,

    /// With `--real`: every flight starts from the configuration, not from what the flights
    /// before it taught.
    #[arg(long, requires = "real")]
    pub each_alone: bool,

    #[arg(long, value_enum, default_value = "launcher", requires = "real", help = FRAME_HELP)]
    pub frame: CsvFrame,

    /// Print the accuracy tables of README.md instead, as README.md holds them: simulated play
    /// with truth (seed 1, 200 shots, both camera setups) and the real launcher flights of
    /// `tests/data/mpi_launcher/` (run from the repository's root). `cargo test` checks that
    /// README.md holds exactly these tables.
    #[arg(long, conflicts_with_all = ["sets", "efficiency", "real"])]
    pub readme: bool,

    /// Print a table of `docs/` instead, as the file holds it (run from the repository's
    /// root). `cargo test` checks that the files hold exactly these tables.
    #[arg(
        long,
        value_enum,
        value_name = "TABLE",
        conflicts_with_all = ["sets", "efficiency", "real", "readme"]
    )]
    pub doc_table: Option<DocTable>,

    /// Also write the report as JSON to this file (with `--real`: the summaries and every
    /// flight's outcome at each lead, in SI units).
    #[arg(long, value_name = "FILE")]
    pub json: Option<PathBuf>,

    /// The estimator's configuration (its camera noise is set to the simulated cameras').
    #[command(flatten)]
    pub config: ConfigArgs,
}

impl EvaluateArgs {
    /// Simulates, runs the estimator and prints the accuracy table.
    pub fn run(self) -> anyhow::Result<ExitCode> {
        if self.readme {
            let config = self.config.load()?;
            write_stdout(&readme_tables(&config)?)?;
            return Ok(ExitCode::SUCCESS);
        }
        if let Some(table) = self.doc_table {
            write_stdout(&doc_table(table, &self.config.layers())?)?;
            return Ok(ExitCode::SUCCESS);
        }
        if let Some(names) = &self.sets {
            return self.run_sets(names);
        }
        if !self.real.is_empty() {
            return self.run_real();
        }
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
            let (report, learning) = evaluate_learning(&config, &session);
            let elapsed = started.elapsed().as_secs_f64();
            write_stdout(&table(name, &report, elapsed))?;
            write_stdout(&format!(
                "{}\n",
                ttball::online::estimator::describe_params(&learning.params),
            ))?;
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
            write_json(path, &reports)?;
        }
        Ok(ExitCode::SUCCESS)
    }
}

/// The recorded flights of `files` (given in `frame`) in the table frame, and `config` with the
/// 150 fps camera's noise as measured from them.
fn launcher_flights(
    config: &ttball::config::Config,
    files: &[PathBuf],
    frame: CsvFrame,
) -> anyhow::Result<(LauncherFlights, ttball::config::Config)> {
    let mut config = config.clone();
    let launcher = super::import::recorded_flights(files, frame, &config)?;
    config.sources.wide_150fps.position_sigma = launcher.position_sigma();
    config
        .validate()
        .context("the configuration with the measured noise")?;
    Ok((launcher, config))
}

/// "a / b / c" of three values in `unit` scale, `decimals` each.
fn triple(values: [f64; 3], scale: f64, decimals: usize) -> String {
    values
        .map(|v| format!("{:.*}", decimals, v * scale))
        .join(" / ")
}

impl EvaluateArgs {
    /// Real launcher flights: the accuracy table, the detections gated after each bounce, the
    /// spin learned before it by kind, and the physics learned at the end.
    fn run_real(&self) -> anyhow::Result<ExitCode> {
        let (launcher, config) = launcher_flights(&self.config.load()?, &self.real, self.frame)?;
        let options = RealEvalOptions {
            carry_over: !self.each_alone,
            ..RealEvalOptions::default()
        };
        eprintln!(
            "running {} real flights through the estimator...",
            launcher.flights.len()
        );
        let report = evaluate_flights(&config, &launcher.flights, &options);
        let mut text = format!(
            "{} flights ({}); sources.wide_150fps.position_sigma {:.4} m (measured); plane {}\n\n",
            launcher.flights.len(),
            if self.each_alone {
                "each from the configuration"
            } else {
                "each from what the ones before it taught"
            },
            config.sources.wide_150fps.position_sigma,
            options.plane.describe()
        );
        text.push_str(&report.to_markdown());
        let tracks: u64 = report.flights.iter().map(|f| f.counters.tracks).sum();
        let reanchored: u64 = report.flights.iter().map(|f| f.counters.reanchored).sum();
        let gated: Vec<String> = report
            .flights
            .iter()
            .filter(|f| f.gated_after_bounce > 0)
            .map(|f| format!("{} {} ({})", f.spin_kind.name(), f.id, f.gated_after_bounce))
            .collect();
        text.push_str(&format!(
            "\ntracks {tracks} (re-anchored {reanchored}); flights with detections gated within \
             50 ms after the bounce: {} of {}{}\n",
            gated.len(),
            report.flights.len(),
            if gated.is_empty() {
                String::new()
            } else {
                format!(": {}", gated.join(", "))
            }
        ));
        text.push_str(&spin_before_bounce_text(&report));
        if let Some(learned) = &report.learned {
            text.push_str(&format!(
                "at the end: {}\n",
                ttball::online::estimator::describe_params(learned)
            ));
        }
        write_stdout(&text)?;
        if let Some(path) = &self.json {
            let json =
                real_report_json(&report, &options, config.sources.wide_150fps.position_sigma);
            write_json(path, &json)?;
        }
        Ok(ExitCode::SUCCESS)
    }

    /// The harder sets: one line per set, then the learned physics.
    fn run_sets(&self, names: &str) -> anyhow::Result<ExitCode> {
        let config = self.config.load()?;
        let all = standard_sets();
        let chosen: Vec<TrialSet> = if names == "all" {
            all
        } else {
            names
                .split(',')
                .map(|name| {
                    all.iter()
                        .find(|s| s.name == name.trim())
                        .copied()
                        .with_context(|| {
                            let known: Vec<&str> = all.iter().map(|s| s.name).collect();
                            format!("no set named {name:?}; the sets are {}", known.join(", "))
                        })
                })
                .collect::<anyhow::Result<_>>()?
        };
        let mut reports = Vec::new();
        write_stdout(&format!(
            "{} shots per set, seed {}; interception error at 200 / 100 ms lead over the shots \
             after the first {SETTLE_FLIGHTS}, against the same filter given the true physics\n\n\
             set            one track  no gate <50 ms   200 ms median/RMS [mm] (x true)      \
             100 ms median/RMS [mm] (x true)\n",
            self.shots, self.seed
        ))?;
        for set in &chosen {
            eprintln!("simulating {} ({} shots)...", set.name, self.shots);
            let r = run_set(&config, set, self.shots, self.seed)
                .with_context(|| format!("cannot simulate the set {}", set.name))?;
            write_stdout(&set_line(&r))?;
            reports.push(r);
        }
        let mut efficiencies = Vec::new();
        if self.efficiency {
            for set in &chosen {
                eprintln!(
                    "fitting every shot of {} as a whole at each lead...",
                    set.name
                );
                let lines = set_efficiency(&config, set, self.shots, self.seed)
                    .with_context(|| format!("cannot simulate the set {}", set.name))?;
                write_stdout(&format!("\n== {}\n{}", set.name, efficiency_table(&lines)))?;
                efficiencies.push(lines);
            }
        }
        write_stdout(
            "
learned physics at the end (relative error against the truth):
",
        )?;
        for r in &reports {
            let errors = r.learned_errors();
            let values = r.learned.params.to_vector();
            let parts: Vec<String> = PhysicsParams::NAMES
                .iter()
                .enumerate()
                .map(|(i, name)| format!("{name} {:.3} ({:+.1} %)", values[i], errors[i] * 100.0))
                .collect();
            write_stdout(&format!("  {:<13} {}\n", r.set.name, parts.join(", ")))?;
        }
        if let Some(path) = &self.json {
            let json: Vec<serde_json::Value> = reports
                .iter()
                .enumerate()
                .map(|(i, r)| {
                    serde_json::json!({
                        "set": r.set.name,
                        "single_track_fraction": r.single_track_fraction(),
                        "clean_bounce_fraction": r.clean_bounce_fraction(),
                        "settled": r.settled,
                        "learned": super::replay::learned_json(&r.learned),
                        "learned_relative_errors": r.learned_errors(),
                        "report": r.report,
                        "reference": r.reference,
                        "efficiency": efficiencies.get(i),
                    })
                })
                .collect();
            write_json(path, &json)?;
        }
        Ok(ExitCode::SUCCESS)
    }
}

/// A settled lead of a set: the filter's median / RMS [mm] (each `width` wide) and their ratios to
/// the same filter's given the true physics.
fn settled_lead(l: &LeadComparison, width: usize) -> String {
    format!(
        "{:width$.1} / {:width$.1} ({:.2} / {:.2})",
        l.filter.median * 1e3,
        l.filter.rms * 1e3,
        l.median_ratio,
        l.rms_ratio
    )
}

/// One set's line of the harder evaluation.
fn set_line(r: &SetReport) -> String {
    let leads: Vec<String> = r.settled.iter().map(|l| settled_lead(l, 6)).collect();
    format!(
        "{:<13} {:>8.1} %  {:>8.1} %      {}
",
        r.set.name,
        r.single_track_fraction() * 100.0,
        r.clean_bounce_fraction() * 100.0,
        leads.join("      ")
    )
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

/// The efficiency tables: the filter's errors and the batch fit's, with each physics.
fn efficiency_table(efficiencies: &[Efficiency]) -> String {
    let mut out = String::new();
    for e in efficiencies {
        out.push_str(&format!(
            "efficiency against the batch fit with {}:\n\
             quantity                              shots   online RMS/median   batch fit RMS/median   online / batch RMS, median\n",
            match e.physics {
                BatchPhysics::Configured => "the configured physics",
                BatchPhysics::Learned => "the physics the estimator had learned",
                BatchPhysics::True => "the true physics (the set's)",
            }
        ));
        let mut line = |name: &str, c: &Comparison, unit: f64| {
            out.push_str(&format!(
                "  {:<36} {:>5}   {:>7.2} {:>7.2}     {:>7.2} {:>7.2}          {:>5.2} {:>5.2}\n",
                name,
                c.shots,
                c.online.rms * unit,
                c.online.median * unit,
                c.batch.rms * unit,
                c.batch.median * unit,
                c.ratio,
                c.median_ratio
            ));
        };
        for l in &e.leads {
            line(
                &format!("interception at {:.0} ms lead [mm]", l.lead * 1e3),
                &l.position,
                1e3,
            );
        }
        for l in &e.leads {
            line(
                &format!("spin at the crossing, {:.0} ms [rad/s]", l.lead * 1e3),
                &l.spin,
                1.0,
            );
        }
        line("velocity after 100 ms [m/s]", &e.velocity_at_age, 1.0);
        line(
            "spin across v before the bounce [rad/s]",
            &e.spin_before_bounce,
            1.0,
        );
    }
    out
}

/// The spin just before the bounce on real flights: the filter's topspin component by kind, the
/// batch fit's of the same detections, and how the two compare across the velocity.
fn spin_before_bounce_text(report: &RealReport) -> String {
    let mut text = String::from(
        "topspin component just before the bounce [rad/s], filter / batch fit of the same \
         detections with the same physics:\n",
    );
    let present = |kind: &SpinKind| report.flights.iter().any(|f| f.spin_kind == *kind);
    for kind in SpinKind::GROUPS.into_iter().filter(present) {
        let of_kind = || report.flights.iter().filter(|f| f.spin_kind == kind);
        let list = |pick: &dyn Fn(&FlightResult) -> Option<BallState>| {
            let values: Vec<f64> = of_kind()
                .filter_map(|f| pick(f).as_ref().and_then(topspin))
                .collect();
            (listed(&values), ErrorStats::of(&deviations(&values)).rms)
        };
        let (online, online_scatter) = list(&|f| f.before_bounce);
        let (batch, batch_scatter) = list(&|f| f.batch_before_bounce);
        text.push_str(&format!(
            "  {:<9} filter {online} (scatter {online_scatter:.0})\n  {:<9} batch  {batch} \
             (scatter {batch_scatter:.0})\n",
            kind.name(),
            ""
        ));
    }
    let pairs: Vec<(Vector3<f64>, Vector3<f64>)> = report
        .flights
        .iter()
        .filter_map(FlightResult::spin_across_before_bounce)
        .collect();
    let ratios: Vec<f64> = pairs.iter().map(|(o, b)| o.norm() / b.norm()).collect();
    let within = ratios
        .iter()
        .filter(|r| (1.0 / 1.2..=1.2).contains(*r))
        .count();
    let differences: Vec<f64> = pairs.iter().map(|(o, b)| (o - b).norm()).collect();
    text.push_str(&format!(
        "spin across v before the bounce, filter against batch fit over {} flights: |filter| / \
         |batch| median {:.2}, within 1/1.2-1.2 on {within}; difference RMS {:.0} rad/s\n",
        pairs.len(),
        ErrorStats::of(&ratios).median,
        ErrorStats::of(&differences).rms,
    ));
    text
}

/// Most values listed one by one; more are summarised.
const LISTED: usize = 20;

/// The values one by one, or their median and middle half when there are more than [`LISTED`].
fn listed(values: &[f64]) -> String {
    if values.len() <= LISTED {
        let text: Vec<String> = values.iter().map(|w| format!("{w:.0}")).collect();
        return text.join(" ");
    }
    let mut sorted = values.to_vec();
    sorted.sort_by(f64::total_cmp);
    let at = |q: f64| nearest_rank(&sorted, q).unwrap_or(f64::NAN);
    format!(
        "median {:.0}, middle half {:.0} to {:.0} ({} flights)",
        at(0.5),
        at(0.25),
        at(0.75),
        sorted.len()
    )
}

/// Each value less the values' mean.
fn deviations(values: &[f64]) -> Vec<f64> {
    let mean = values.iter().sum::<f64>() / values.len().max(1) as f64;
    values.iter().map(|v| v - mean).collect()
}

/// `ttball evaluate --real --json`: the measured noise, the summaries of the table, every
/// flight's outcome at each lead (SI units: m, s, rad/s; a number that is not one, such as the
/// NEES of a lead without a valid prediction, is null) and what was learned.
fn real_report_json(
    report: &RealReport,
    options: &RealEvalOptions,
    position_sigma: f64,
) -> serde_json::Value {
    let kind_name = |k: Option<SpinKind>| k.map_or("all", SpinKind::name);
    let groups: Vec<serde_json::Value> = report
        .groups
        .iter()
        .map(|g| {
            let leads: Vec<serde_json::Value> = g
                .leads
                .iter()
                .map(|l| {
                    serde_json::json!({
                        "lead": l.lead,
                        "flights": l.flights,
                        "valid": l.valid,
                        "no_track": l.no_track,
                        "position_error": l.position_error,
                        "time_error": l.time_error,
                        "bias_y": l.mean_error[0],
                        "bias_z": l.mean_error[1],
                        "bias_time": l.mean_error[2],
                        "crossing_nees": l.crossing_nees,
                    })
                })
                .collect();
            serde_json::json!({
                "spin_kind": kind_name(g.spin_kind),
                "flights": g.flights,
                "scored": g.scored,
                "leads": leads,
            })
        })
        .collect();
    let flights: Vec<serde_json::Value> = report
        .flights
        .iter()
        .map(|f| {
            let leads: Vec<serde_json::Value> = options
                .leads
                .iter()
                .zip(&f.leads)
                .map(|(lead, outcome)| match outcome {
                    LeadOutcome::Predicted {
                        y_error,
                        z_error,
                        time_error,
                        sigma: [y_sigma, z_sigma, time_sigma],
                        nees,
                        ..
                    } => serde_json::json!({
                        "lead": lead,
                        "outcome": "predicted",
                        "position_error": y_error.hypot(*z_error),
                        "y_error": y_error,
                        "z_error": z_error,
                        "time_error": time_error,
                        "y_sigma": y_sigma,
                        "z_sigma": z_sigma,
                        "time_sigma": time_sigma,
                        "nees": nees,
                    }),
                    LeadOutcome::NoTrack => {
                        serde_json::json!({"lead": lead, "outcome": "no_track"})
                    }
                    LeadOutcome::Invalid(why) => serde_json::json!({
                        "lead": lead,
                        "outcome": "invalid",
                        "reason": why.describe(),
                    }),
                })
                .collect();
            serde_json::json!({
                "id": f.id,
                "spin_kind": f.spin_kind.name(),
                "scored": f.crossing.is_ok(),
                "not_scored_because": f.crossing.err().map(|why| why.describe()),
                "leads": leads,
                "topspin_before_bounce": f.topspin_before_bounce(),
                "spin_across_before_bounce": f.spin_across_before_bounce().map(|(filter, batch)| {
                    serde_json::json!({
                        "filter": [filter.x, filter.y, filter.z],
                        "batch_fit": [batch.x, batch.y, batch.z],
                    })
                }),
                "tracks": f.counters.tracks,
                "reanchored": f.counters.reanchored,
                "gated_after_bounce": f.gated_after_bounce,
            })
        })
        .collect();
    serde_json::json!({
        "flights_evaluated": report.flights.len(),
        "carry_over": options.carry_over,
        "plane": options.plane.describe(),
        "position_sigma": position_sigma,
        "groups": groups,
        "flights": flights,
        "learned": report.learned.as_ref().map(super::replay::learned_json),
    })
}
