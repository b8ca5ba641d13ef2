//! `ttball calibrate`: the aero and bounce coefficients fitted to the flights of recorded bags,
//! written as a configuration snippet with standard errors, plus a chart.

use std::fmt::Write as _;
use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{Context, bail};
use clap::{Args, ValueEnum};
use ttball::bag::replay::read_detections;
use ttball::config::Config;
use ttball::config::yaml::changed_params_yaml;
use ttball::model::detection::Detection;
use ttball::offline::calibrate::{
    Calibration, FlightInput, FlightLabel, Holdout, Options, Parameter, calibrate, holdout,
};
use ttball::offline::smooth::split_flights;
use ttball::offline::two_level::{TwoLevelCalibration, calibrate_two_level};
use ttball::online::estimator::describe_params;
use ttball::online::learned::REYNOLDS_EXPONENT_NAMES;
use ttball::physics::params::PhysicsParams;
use ttball::plot::ChartOptions;

use super::{BadUsage, ConfigArgs, write_file, write_json, write_stdout};

mod rubber;

/// A group of constants to fit.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum Group {
    /// With --rebound: the rubber's restitution polynomial e_RB(V) (racket.rubber_restitution).
    RubberRestitution,
    /// With --rebound: the ball-rubber Coulomb friction (racket.rubber_friction).
    RubberFriction,
    /// With --rebound: the tangential restitution e_t (racket.rubber_tangential_restitution).
    RubberTangential,
    /// With --rebound: the torsional restitution e_z (racket.rubber_torsional_restitution).
    RubberTorsional,
    /// The C_D(Sp) and C_M(Sp) polynomial coefficients (aero.drag/magnus_coefficients).
    Aero,
    /// The scale factors on the configured C_D(Sp) and C_M(Sp) (aero.drag_scale,
    /// aero.magnus_scale): the parameters the estimator learns online; not with aero.
    Scales,
    /// Table restitution and friction (table.restitution, table.friction).
    Bounce,
    /// Air density (air.density); not with aero, which absorbs it.
    Density,
    /// The exponents of the Reynolds number's factors on C_D and C_M (aero.reynolds_exponents):
    /// how the coefficients change with speed; flights over a wide range of speeds determine
    /// them.
    Reynolds,
    /// The spin's decay rate in flight (aero.spin_decay_rate): how fast the spin's effect
    /// fades along a flight; --method batch.
    Decay,
}

/// How the flights are fitted.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum Method {
    /// Robust batch least squares: one deterministic trajectory per flight and the constants
    /// shared by all, by Levenberg-Marquardt (every --fit group).
    Batch,
    /// The estimator's own model of many flights: each flight smoothed with the filter's
    /// process noise and the noise it learned, its own drag, Magnus and restitution about the
    /// shared ones, solved for the shared ones at once (--fit scales and bounce only). On real
    /// flights these are the numbers the estimator learns online.
    Estimator,
}

/// Arguments of `ttball calibrate`.
#[derive(Debug, Args)]
pub struct CalibrateArgs {
    /// Bags of recorded flights (MCAP files or rosbag2 directories); their detections are cut
    /// into flights by the estimator's tracks.
    #[arg(
        required_unless_present = "rebound",
        conflicts_with = "rebound",
        value_name = "BAG"
    )]
    pub inputs: Vec<PathBuf>,

    /// Calibrate the racket's rubber instead, from recorded hits: a CSV file with the ball's
    /// velocity and spin before and after each hit (the tt_rackets columns v_in_*,
    /// spin_before_*, v_out_*, spin_after_*; optionally racket_velocity_*, racket_normal_*,
    /// impact_offset; docs/racket.md). Repeatable: the files are fitted
    /// together and their errors reported one by one.
    #[arg(long, value_name = "HITS.csv")]
    pub rebound: Vec<PathBuf>,

    /// With --rebound: order of the fitted restitution polynomial e_RB(V) (0-3).
    #[arg(long, value_name = "N", default_value_t = 1, requires = "rebound")]
    pub restitution_order: usize,

    /// With --rebound: folds of the cross-validation (hit i is held out in fold i mod k; 0: none).
    #[arg(long, value_name = "K", default_value_t = 5, requires = "rebound")]
    pub folds: usize,

    /// The configuration snippet to write (a ROS 2 parameters file: pass it to --config).
    #[arg(long, short, value_name = "FILE.yaml")]
    pub output: PathBuf,

    /// What to fit, comma separated [default: aero,bounce; with --method estimator:
    /// scales,bounce; with --rebound: every rubber-* group].
    #[arg(long, value_enum, value_delimiter = ',')]
    pub fit: Vec<Group>,

    /// How: `batch` fits one deterministic trajectory per flight; `estimator` fits with the
    /// estimator's own model (flights that stray from the model as the filter lets them, each
    /// with its own parameters about the shared ones) and writes the noise it learned too: the
    /// configuration a node started from keeps learning the same numbers (docs/calibration.md).
    #[arg(long, value_enum, default_value_t = Method::Batch, conflicts_with = "rebound")]
    pub method: Method,

    /// Order of the C_D polynomial (0-3) [default: chosen by AIC].
    #[arg(long, value_name = "N")]
    pub drag_order: Option<usize>,

    /// Order of the C_M polynomial (0-4) [default: chosen by AIC].
    #[arg(long, value_name = "N")]
    pub magnus_order: Option<usize>,

    /// Hold every other flight out of the fit and report how well the starting and the
    /// calibrated configurations forecast them (the second half of each from its first half).
    #[arg(long)]
    pub holdout: bool,

    /// Draw the fitted C_D(Sp), C_M(Sp) against the starting ones and the residual of every
    /// flight; with --rebound, predicted against measured outgoing velocity and spin of every
    /// hit (SVG or PNG by the file name).
    #[arg(long, value_name = "FILE.svg|FILE.png")]
    pub plot: Option<PathBuf>,

    /// Also write everything as JSON.
    #[arg(long, value_name = "FILE.json")]
    pub json: Option<PathBuf>,

    /// The starting configuration (camera noise, topics, the constants not fitted).
    #[command(flatten)]
    pub config: ConfigArgs,
}

/// The paths as the configuration snippet's comment names its inputs.
fn display_names(paths: &[PathBuf]) -> Vec<String> {
    paths.iter().map(|p| p.display().to_string()).collect()
}

/// Fraction of a held-out flight fitted before forecasting the rest.
const HOLDOUT_FRACTION: f64 = 0.5;

impl CalibrateArgs {
    /// Reads the bags, calibrates and writes the outputs.
    pub fn run(self) -> anyhow::Result<ExitCode> {
        let config = self.config.load()?;
        if let Some(plot) = &self.plot
            && !matches!(
                plot.extension().and_then(|e| e.to_str()),
                Some("svg" | "png")
            )
        {
            bail!(BadUsage(format!(
                "--plot {}: give a file name ending in .svg or .png",
                plot.display()
            )));
        }
        let rubber_groups = [
            Group::RubberRestitution,
            Group::RubberFriction,
            Group::RubberTangential,
            Group::RubberTorsional,
        ];
        if !self.rebound.is_empty() {
            if let Some(g) = self.fit.iter().find(|g| !rubber_groups.contains(g)) {
                bail!(BadUsage(format!(
                    "--fit {}: with --rebound only the rubber-* groups can be fitted",
                    g.to_possible_value()
                        .map_or_else(String::new, |v| v.get_name().to_owned())
                )));
            }
            return rubber::run(&self, &config);
        }
        let fit = self.flight_groups(&rubber_groups)?;
        let options = Options {
            aero: fit.contains(&Group::Aero),
            scales: fit.contains(&Group::Scales),
            bounce: fit.contains(&Group::Bounce),
            density: fit.contains(&Group::Density),
            reynolds: fit.contains(&Group::Reynolds),
            decay: fit.contains(&Group::Decay),
            drag_order: self.drag_order,
            magnus_order: self.magnus_order,
        };
        let flights = self.read_flights(&config)?;
        let (fitted, held): (Vec<_>, Vec<_>) = if self.holdout {
            let (a, b): (Vec<_>, Vec<_>) = flights
                .into_iter()
                .enumerate()
                .partition(|(i, _)| i % 2 == 0);
            (
                a.into_iter().map(|(_, f)| f).collect(),
                b.into_iter().map(|(_, f)| f).collect(),
            )
        } else {
            (flights, Vec::new())
        };
        if self.method == Method::Estimator {
            return self.run_estimator(&config, &fit, fitted, &held);
        }
        // Every iteration on a terminal or with TTBALL_VERBOSE set; the stages otherwise.
        let verbose = std::io::IsTerminal::is_terminal(&std::io::stderr())
            || std::env::var_os("TTBALL_VERBOSE").is_some();
        let mut progress = |line: &str| {
            if verbose || !line.starts_with("  ") {
                eprintln!("{line}");
            }
        };
        let calibration = calibrate(&config, &fitted, &options, &mut progress)
            .map_err(|e| BadUsage(format!("cannot calibrate: {e}")))?;
        let held_out = self
            .holdout
            .then(|| holdout(&config, &calibration.config, &held, HOLDOUT_FRACTION));

        write_file(
            &self.output,
            snippet(&calibration, &display_names(&self.inputs)),
        )?;
        if let Some(path) = &self.plot {
            let options = ChartOptions {
                width: 1800,
                height: 650,
            };
            let bytes = if path.extension().is_some_and(|e| e == "svg") {
                ttball::plot::render_calibration_svg(&calibration, &config, &options)?.into_bytes()
            } else {
                ttball::plot::render_calibration_png(&calibration, &config, &options)?
            };
            write_file(path, bytes)?;
        }
        if let Some(path) = &self.json {
            let json = serde_json::json!({
                "parameters": calibration.parameters,
                "orders": { "drag": calibration.orders.0, "magnus": calibration.orders.1 },
                "order_trials": calibration.order_trials,
                "flights": calibration.flights,
                "skipped": calibration.skipped,
                "position_rms_before": calibration.position_rms_before,
                "position_rms": calibration.position_rms,
                "reduced_chi_square": calibration.reduced_chi_square,
                "spin_parameter_5_50_95": calibration.spin_parameter,
                "holdout": held_out,
            });
            write_json(path, &json)?;
        }
        write_stdout(&report(&calibration, held_out.as_ref(), &self.output))?;
        Ok(ExitCode::SUCCESS)
    }
}

impl CalibrateArgs {
    /// The flight's groups to fit (`--fit`, else the method's default), refused with the reason
    /// where the method cannot fit them.
    fn flight_groups(&self, rubber_groups: &[Group]) -> anyhow::Result<Vec<Group>> {
        if let Some(g) = self.fit.iter().find(|g| rubber_groups.contains(g)) {
            bail!(BadUsage(format!(
                "--fit {}: the rubber is calibrated from recorded hits: give them with --rebound HITS.csv",
                g.to_possible_value()
                    .map_or_else(String::new, |v| v.get_name().to_owned())
            )));
        }
        let fit = match (self.fit.is_empty(), self.method) {
            (true, Method::Batch) => vec![Group::Aero, Group::Bounce],
            (true, Method::Estimator) => vec![Group::Scales, Group::Bounce, Group::Reynolds],
            (false, _) => self.fit.clone(),
        };
        if self.method == Method::Estimator {
            if let Some(g) = fit
                .iter()
                .find(|g| !matches!(g, Group::Scales | Group::Bounce | Group::Reynolds))
            {
                bail!(BadUsage(format!(
                    "--fit {}: --method estimator fits what the estimator learns, scales, bounce and reynolds; use --method batch for the rest",
                    g.to_possible_value()
                        .map_or_else(String::new, |v| v.get_name().to_owned())
                )));
            }
            if self.plot.is_some() || self.drag_order.is_some() || self.magnus_order.is_some() {
                bail!(BadUsage(
                    "--plot, --drag-order and --magnus-order are for --method batch".to_owned()
                ));
            }
        }
        Ok(fit)
    }

    /// The flights of every input, cut by the estimator's own tracks.
    fn read_flights(&self, config: &ttball::config::Config) -> anyhow::Result<Vec<FlightInput>> {
        let mut flights = Vec::new();
        for (recording, input) in self.inputs.iter().enumerate() {
            let bag = read_detections(input, config)
                .with_context(|| format!("cannot read {}", input.display()))?;
            let (tracks, _) = split_flights(config, &bag.detections);
            eprintln!("{}: {} flights", input.display(), tracks.len());
            flights.extend(tracks.into_iter().map(|f| FlightInput {
                label: FlightLabel {
                    recording,
                    track_id: f.track_id,
                },
                detections: f.members.iter().map(|&i| bag.detections[i]).collect(),
            }));
        }
        Ok(flights)
    }

    /// `--method estimator`: the flights through [`calibrate_two_level`], the groups not asked
    /// for held at their configured values.
    fn run_estimator(
        &self,
        config: &Config,
        fit: &[Group],
        flights: Vec<FlightInput>,
        held: &[FlightInput],
    ) -> anyhow::Result<ExitCode> {
        let detections: Vec<Vec<Detection>> = flights
            .into_iter()
            .map(|f| {
                let mut d = f.detections;
                d.sort_by_key(|d| d.stamp);
                d
            })
            .collect();
        let mut progress = |line: &str| eprintln!("{line}");
        let calibration =
            calibrate_two_level(&estimator_start(config, fit), &detections, &mut progress)
                .map_err(|e| BadUsage(format!("cannot calibrate: {e}")))?;
        let held_out = self
            .holdout
            .then(|| holdout(config, &calibration.config, held, HOLDOUT_FRACTION));
        let mut text = format!(
            "# Written by `ttball calibrate --method estimator` from {} flights in:\n",
            calibration.params.tracks
        );
        for i in display_names(&self.inputs) {
            let _ = writeln!(text, "#   {i}");
        }
        let _ = writeln!(
            text,
            "# calibrated: {}",
            describe_params(&calibration.params)
        );
        for line in calibration.online.lines() {
            let _ = writeln!(text, "# flight after flight, online: {line}");
        }
        text.push_str(&changed_params_yaml(config, &calibration.config));
        write_file(&self.output, text)?;
        if let Some(path) = &self.json {
            write_json(path, &estimator_json(&calibration, config, &held_out))?;
        }
        let mut out = estimator_table(&calibration, config);
        for line in calibration.online.lines().iter().skip(1) {
            let _ = writeln!(out, "  also written: {line}");
        }
        if let Some(h) = &held_out {
            out.push_str(&holdout_line(h));
        }
        out.push_str(&written_line(&self.output));
        write_stdout(&out)?;
        Ok(ExitCode::SUCCESS)
    }
}

/// The start of `--method estimator`: `config` with the groups not in `fit` held (their prior
/// sigmas zero).
fn estimator_start(config: &Config, fit: &[Group]) -> Config {
    let mut start = config.clone();
    // In the order of PhysicsParams::NAMES: the scales, then the bounce.
    let sigma = &mut start.adaptation.sigma;
    sigma.resize(4, 0.0);
    if !fit.contains(&Group::Scales) {
        sigma[0] = 0.0;
        sigma[1] = 0.0;
    }
    if !fit.contains(&Group::Bounce) {
        sigma[2] = 0.0;
        sigma[3] = 0.0;
    }
    if !fit.contains(&Group::Reynolds) {
        start.adaptation.reynolds_sigma = vec![0.0; 2];
    }
    start
}

/// `--method estimator`'s JSON: each parameter and exponent fitted, with its standard error, the
/// start and the online value.
fn estimator_json(
    calibration: &TwoLevelCalibration,
    config: &Config,
    held_out: &Option<Holdout>,
) -> serde_json::Value {
    let (p, online) = (&calibration.params, &calibration.online.params);
    let (fitted, online_values) = (p.params.to_vector(), online.params.to_vector());
    let start = PhysicsParams::from_config(config).to_vector();
    serde_json::json!({
        "method": "estimator",
        "flights": p.tracks,
        "parameters": PhysicsParams::NAMES.iter().enumerate().map(|(i, name)| {
            serde_json::json!({
                "name": name,
                "value": fitted[i],
                "std_error": p.sigma[i],
                "initial": start[i],
                "online": online_values[i],
            })
        }).collect::<Vec<_>>(),
        "reynolds_exponents": REYNOLDS_EXPONENT_NAMES.iter().enumerate().map(|(i, name)| {
            serde_json::json!({
                "name": name,
                "value": p.reynolds_exponents[i],
                "std_error": p.reynolds_sigma[i],
                "prior_sigma": p.reynolds_prior_sigma[i],
                "determined": p.reynolds_determined()[i],
                "online": online.reynolds_exponents[i],
            })
        }).collect::<Vec<_>>(),
        "iterations": calibration.iterations,
        "converged": calibration.converged,
        "holdout": held_out,
    })
}

/// `--method estimator`'s table: each parameter and exponent fitted (not held), its standard
/// error, the online value and the start.
fn estimator_table(calibration: &TwoLevelCalibration, config: &Config) -> String {
    let (p, online) = (&calibration.params, &calibration.online.params);
    let mut out = format!(
        "calibrated from {} flights with the estimator's model, {} iterations{}\n",
        p.tracks,
        calibration.iterations,
        if calibration.converged {
            ""
        } else {
            " (not converged: the last is written)"
        }
    );
    out.push_str("parameter                         fitted      +- std error   online     start\n");
    let (fitted, online_values) = (p.params.to_vector(), online.params.to_vector());
    let start = PhysicsParams::from_config(config).to_vector();
    for (i, name) in PhysicsParams::NAMES.iter().enumerate() {
        if p.sigma[i] > 0.0 {
            let _ = writeln!(
                out,
                "  {:<30} {:>10.5}  {:>10.5}   {:>9.5}  {:>9.5}",
                name, fitted[i], p.sigma[i], online_values[i], start[i]
            );
        }
    }
    let start_exponents = ttball::physics::FlightModel::new(config).reynolds_exponents();
    for (i, name) in REYNOLDS_EXPONENT_NAMES.iter().enumerate() {
        if p.reynolds_prior_sigma[i] > 0.0 {
            let determined = if p.reynolds_determined()[i] {
                ""
            } else {
                "   (not determined by these flights' speeds: kept at its prior)"
            };
            let _ = writeln!(
                out,
                "  {:<30} {:>10.5}  {:>10.5}   {:>9.5}  {:>9.5}{determined}",
                format!("Reynolds exponent {name}"),
                p.reynolds_exponents[i],
                p.reynolds_sigma[i],
                online.reynolds_exponents[i],
                start_exponents[i],
            );
        }
    }
    out
}

/// The configuration snippet: the fitted values, with the fit's numbers in comments.
fn snippet(c: &Calibration, inputs: &[String]) -> String {
    let mut out = String::new();
    let detections: usize = c.flights.iter().map(|f| f.detections).sum();
    let spins: usize = c.flights.iter().map(|f| f.measured_spins).sum();
    let _ = writeln!(
        out,
        "# Written by `ttball calibrate` from {} flights ({} detections, {} with measured spin) in:",
        c.flights.len(),
        detections,
        spins
    );
    for i in inputs {
        let _ = writeln!(out, "#   {i}");
    }
    let _ = writeln!(
        out,
        "# RMS position residual per axis: {:.3} mm with the starting configuration, {:.3} mm \
         calibrated; reduced chi-square {:.2}.",
        c.position_rms_before * 1e3,
        c.position_rms * 1e3,
        c.reduced_chi_square
    );
    let [lo, mid, hi] = c.spin_parameter;
    let _ = writeln!(
        out,
        "# Sp of the detections: 5 % {lo:.2}, median {mid:.2}, 95 % {hi:.2}; C_D and C_M are \
         supported by data there only."
    );
    let _ = writeln!(
        out,
        "# Value +- standard error (starting value), per fitted parameter:"
    );
    for p in &c.parameters {
        let _ = writeln!(
            out,
            "#   {} = {:.5} +- {:.5} ({:.5})",
            p.name, p.value, p.std_error, p.initial
        );
    }
    let fitted = |f: fn(&Parameter) -> bool| c.parameters.iter().any(|p| f(&p.parameter));
    let list = |v: &[f64]| {
        v.iter()
            .map(|x| format!("{x:.6}"))
            .collect::<Vec<_>>()
            .join(", ")
    };
    let cfg: &Config = &c.config;
    out.push_str("ttball:\n  ros__parameters:\n");
    if fitted(|p| matches!(p, Parameter::AirDensity)) {
        let _ = writeln!(out, "    air:\n      density: {:.6}", cfg.air.density);
    }
    let mut aero = String::new();
    if fitted(|p| matches!(p, Parameter::Drag(_) | Parameter::Magnus(_))) {
        let _ = writeln!(
            aero,
            "      drag_coefficients: [{}]\n      magnus_coefficients: [{}]",
            list(&cfg.aero.drag_coefficients),
            list(&cfg.aero.magnus_coefficients)
        );
    }
    if fitted(|p| matches!(p, Parameter::DragScale | Parameter::MagnusScale)) {
        let _ = writeln!(
            aero,
            "      drag_scale: {:.6}\n      magnus_scale: {:.6}",
            cfg.aero.drag_scale, cfg.aero.magnus_scale
        );
    }
    if fitted(|p| matches!(p, Parameter::DragReynolds | Parameter::MagnusReynolds)) {
        let _ = writeln!(
            aero,
            "      reynolds_exponents: [{}]",
            list(&cfg.aero.reynolds_exponents)
        );
    }
    if fitted(|p| matches!(p, Parameter::SpinDecay)) {
        let _ = writeln!(
            aero,
            "      spin_decay_rate: {:.6}",
            cfg.aero.spin_decay_rate
        );
    }
    if !aero.is_empty() {
        let _ = write!(out, "    aero:\n{aero}");
    }
    if fitted(|p| matches!(p, Parameter::Restitution | Parameter::Friction)) {
        let _ = writeln!(
            out,
            "    table:\n      restitution: {:.6}\n      friction: {:.6}",
            cfg.table.restitution, cfg.table.friction
        );
    }
    out
}

/// How the held-out flights were forecast, in a line.
fn holdout_line(h: &Holdout) -> String {
    format!(
        "held-out flights ({}), second half forecast from the first: RMS {:.1} mm -> {:.1} mm, median {:.1} mm -> {:.1} mm\n",
        h.flights,
        h.before.rms * 1e3,
        h.after.rms * 1e3,
        h.before.median * 1e3,
        h.after.median * 1e3
    )
}

/// What the user reads at the end.
fn report(c: &Calibration, held_out: Option<&Holdout>, output: &std::path::Path) -> String {
    let mut out = String::new();
    let _ = writeln!(
        out,
        "calibrated from {} flights ({} left out), {} Levenberg-Marquardt iterations",
        c.flights.len(),
        c.skipped.len(),
        c.iterations
    );
    for s in &c.skipped {
        let _ = writeln!(
            out,
            "  left out: bag {} track {}: {}",
            s.label.recording, s.label.track_id, s.reason
        );
    }
    if !c.order_trials.is_empty() {
        out.push_str(
            "polynomial orders by AIC = N ln(sigma_e) + 2k (sigma_e: RMS whitened residual):\n",
        );
        for t in &c.order_trials {
            let chosen = (t.drag_order, t.magnus_order) == c.orders;
            let _ = writeln!(
                out,
                "  C_D {} C_M {}: AIC {:>10.1}, sigma_e {:.4}, RMS position residual {:.3} mm{}",
                t.drag_order,
                t.magnus_order,
                t.aic,
                t.sigma_e,
                t.position_rms * 1e3,
                if chosen { "  <- chosen" } else { "" }
            );
        }
    }
    out.push_str("parameter                         fitted      +- std error   start\n");
    for p in &c.parameters {
        let _ = writeln!(
            out,
            "  {:<30} {:>10.5}  {:>10.5}   {:>9.5}{}",
            p.name,
            p.value,
            p.std_error,
            p.initial,
            if p.parameter.at_bound(p.value) {
                "   at the bound of its range: these flights do not determine it"
            } else {
                ""
            }
        );
    }
    let _ = writeln!(
        out,
        "RMS position residual per axis: {:.3} mm -> {:.3} mm (reduced chi-square {:.2})",
        c.position_rms_before * 1e3,
        c.position_rms * 1e3,
        c.reduced_chi_square
    );
    let [lo, mid, hi] = c.spin_parameter;
    let _ = writeln!(
        out,
        "Sp of the detections: 5 % {lo:.2}, median {mid:.2}, 95 % {hi:.2}"
    );
    if let Some(h) = held_out {
        out.push_str(&holdout_line(h));
    }
    out.push_str(&written_line(output));
    out
}

/// Where the configuration snippet went, and how to use it, in a line.
fn written_line(output: &std::path::Path) -> String {
    format!(
        "written to {} (use it with --config {})\n",
        output.display(),
        output.display()
    )
}
