//! The tables README.md and `docs/` quote, printed exactly as those files hold them
//! (`ttball evaluate --readme`, `ttball evaluate --doc-table NAME`); `cargo test` checks that
//! the files hold what these print, so that a change of numbers is a reviewed decision.

use std::path::PathBuf;

use anyhow::Context;
use clap::ValueEnum;
use ttball::config::Config;
use ttball::config::yaml::{Layer, load_layers};
use ttball::eval::real::{RealEvalOptions, RealReport, evaluate_flights};
use ttball::eval::sets::{SETTLE_FLIGHTS, run_set, standard_sets};
use ttball::eval::sim::{Cameras, SimOptions, simulate};
use ttball::eval::{BatchPhysics, EvalReport, efficiency, evaluate_learning};
use ttball::offline::rebound_calibration::{
    CrossValidation, HitSet, ReboundErrors, RubberCalibration, RubberOptions, calibrate_rubber,
};
use ttball::physics::PhysicsParams;

use super::super::import::CsvFrame;
use super::{launcher_flights, settled_lead, triple};

/// A table of `docs/`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum DocTable {
    /// docs/accuracy.md: the filter against the batch fit on simulated play (seed 1, 200 shots,
    /// both camera setups; about 1 minute).
    Efficiency,
    /// docs/accuracy.md: the harder sets (seed 1, 60 shots per set).
    Sets,
    /// docs/real_flights.md: the real launcher flights by spin kind.
    RealFlights,
    /// docs/real_flights.md: the real launcher flights under other configurations.
    RealConfigurations,
    /// docs/racket.md: the rubbers on the real rebounds of tt_rackets, held out (about 1 minute).
    Rubbers,
}

/// The table `table` of `docs/`, as Markdown, from the configuration of `layers`.
pub(super) fn doc_table(table: DocTable, layers: &[Layer]) -> anyhow::Result<String> {
    let config = load_layers(layers, None)?;
    match table {
        DocTable::Efficiency => efficiency_doc_table(&config),
        DocTable::Sets => sets_doc_table(&config),
        DocTable::RealFlights => real_flights_table(&config),
        DocTable::RealConfigurations => real_configurations_table(&config, layers),
        DocTable::Rubbers => rubbers_table(layers),
    }
}

/// Simulated play, seed 1, 200 shots, seen by `cameras`: the session and `config` with the
/// simulated cameras' noise.
fn simulated_play(
    config: &Config,
    cameras: Cameras,
) -> anyhow::Result<(Config, ttball::eval::sim::Session)> {
    let mut config = config.clone();
    let options = SimOptions {
        cameras,
        shots: 200,
        seed: 1,
        ..SimOptions::default()
    };
    options.params.configure_estimator(&mut config);
    let session = simulate(&config, &options).context("cannot simulate the session")?;
    Ok((config, session))
}

/// What `f` gives at each of [`LEADS`](ttball::eval::LEADS) (300, 200, 100 ms), in the tables'
/// order: 100, 200, 300 ms.
fn by_ascending_lead<T>(leads: &[T], f: impl Fn(&T) -> f64) -> [f64; 3] {
    [f(&leads[2]), f(&leads[1]), f(&leads[0])]
}

/// The efficiency table of docs/accuracy.md: the filter's errors over the batch fit's flying the
/// physics the estimator had learned, for both camera setups.
fn efficiency_doc_table(config: &Config) -> anyhow::Result<String> {
    let mut columns = Vec::new();
    for cameras in [Cameras::WideAndHighSpeed, Cameras::WideOnly] {
        let (config, session) = simulated_play(config, cameras)?;
        let learned = efficiency(&config, &session)
            .into_iter()
            .find(|e| e.physics == BatchPhysics::Learned)
            .context("the efficiency with the learned physics")?;
        let leads = |f: &dyn Fn(&ttball::eval::LeadEfficiency) -> f64| {
            triple(by_ascending_lead(&learned.leads, f), 1.0, 2)
        };
        columns.push([
            leads(&|l| l.position.median_ratio),
            leads(&|l| l.position.ratio),
            format!("{:.2}", learned.velocity_at_age.ratio),
            format!("{:.2}", learned.spin_before_bounce.ratio),
        ]);
    }
    let rows = [
        "interception at 100 / 200 / 300 ms lead, median ratio",
        "interception at 100 / 200 / 300 ms lead, RMS ratio",
        "velocity after 100 ms of track, RMS ratio",
        "spin across v just before the bounce, RMS ratio",
    ];
    let mut text = String::from(
        "| filter / batch fit, seed 1, 200 shots | 150 + 900 fps | 150 fps alone |\n|---|---|---|\n",
    );
    for (i, row) in rows.iter().enumerate() {
        text.push_str(&format!(
            "| {row} | {} | {} |\n",
            columns[0][i], columns[1][i]
        ));
    }
    Ok(text)
}

/// The harder sets' table of docs/accuracy.md: tracks, the interception against the same filter
/// given the true physics, and what was learned.
fn sets_doc_table(config: &Config) -> anyhow::Result<String> {
    let mut text = format!(
        "| set, seed 1, 60 shots | one track per flight | no good detection gated < 50 ms after \
         the bounce | interception after {SETTLE_FLIGHTS} flights, 200 ms lead: median / RMS [mm] \
         (x the true physics') | 100 ms lead | learned {}, error [%] |\n|---|---|---|---|---|---|\n",
        PhysicsParams::NAMES.join(" / ")
    );
    for set in standard_sets() {
        let r = run_set(config, &set, 60, 1)
            .with_context(|| format!("cannot simulate the set {}", set.name))?;
        let leads: Vec<String> = r.settled.iter().map(|l| settled_lead(l, 0)).collect();
        let errors: Vec<String> = r
            .learned_errors()
            .iter()
            .map(|e| {
                // Rounded first, so that a small negative error reads +0.0, not -0.0.
                let percent = (e * 1000.0).round() / 10.0 + 0.0;
                format!("{percent:+.1}")
            })
            .collect();
        text.push_str(&format!(
            "| {} | {:.1} % | {:.1} % | {} | {} |\n",
            set.name,
            r.single_track_fraction() * 100.0,
            r.clean_bounce_fraction() * 100.0,
            leads.join(" | "),
            errors.join(" / ")
        ));
    }
    Ok(text)
}

/// The real launcher flights' crossing error by spin kind and overall, at each lead, the main
/// table of docs/real_flights.md (run from the repository's root).
fn real_flights_table(config: &Config) -> anyhow::Result<String> {
    let report = real_flights(config, &launcher_files(), true)?;
    let mut text = String::from(
        "| flights scored | lead | crossing RMS / median [mm] | time RMS [ms] | NEES per dimension \
         |\n|---|---|---|---|---|\n",
    );
    for g in &report.groups {
        let name = g.spin_kind.map_or("all", |k| k.name());
        let bold = if g.spin_kind.is_none() { "**" } else { "" };
        for (i, l) in g.leads.iter().enumerate() {
            let flights = if i == 0 {
                format!("{bold}{name} ({}){bold}", g.scored)
            } else {
                format!("{bold}{name}{bold}")
            };
            text.push_str(&format!(
                "| {flights} | {:.0} ms | {bold}{:.1} / {:.1}{bold} | {:.1} | {:.2} |\n",
                l.lead * 1e3,
                l.position_error.rms * 1e3,
                l.position_error.median * 1e3,
                l.time_error.rms * 1e3,
                l.crossing_nees
            ));
        }
    }
    Ok(text)
}

/// The real launcher flights' crossing error under other configurations, the table of
/// docs/real_flights.md (run from the repository's root).
fn real_configurations_table(config: &Config, layers: &[Layer]) -> anyhow::Result<String> {
    let files = launcher_files();
    let mut with_seed = layers.to_vec();
    with_seed.push(Layer::File(PathBuf::from("config/presets/seed_2014.yaml")));
    let seed = load_layers(&with_seed, None)
        .context("the seed's preset is read from the repository's root")?;
    let mut without_adaptation = config.clone();
    without_adaptation.adaptation.enabled = false;
    let rows: [(&str, &Config, bool); 4] = [
        ("the default", config, true),
        ("each flight alone (`--each-alone`)", config, false),
        (
            "the seed's polynomials (`--config config/presets/seed_2014.yaml`)",
            &seed,
            true,
        ),
        (
            "without the adaptation (`-p adaptation.enabled:=false`)",
            &without_adaptation,
            true,
        ),
    ];
    let mut text = String::from(
        "| configuration | crossing RMS / median at 200 ms lead [mm] | at 100 ms lead |\n|---|---|---|\n",
    );
    for (name, config, carry_over) in rows {
        let report = real_flights(config, &files, carry_over)?;
        let all = report.overall().context("no real flight was scored")?;
        let leads: Vec<String> = all
            .leads
            .iter()
            .map(|l| {
                format!(
                    "{:.1} / {:.1}",
                    l.position_error.rms * 1e3,
                    l.position_error.median * 1e3
                )
            })
            .collect();
        text.push_str(&format!("| {name} | {} |\n", leads.join(" | ")));
    }
    Ok(text)
}

/// The inverted rubbers of tt_rackets by class, in the table's order, and the long pips.
const INVERTED_CLASSES: [(&str, &[&str]); 2] = [
    ("inverted offensive", &["01", "03", "09"]),
    ("inverted allround", &["02", "04"]),
];
const LONG_PIPS: &str = "05";
/// What a racket's or a class's calibration is to reach, and the default rubber (velocity
/// [m/s], spin [rad/s]).
const CALIBRATION_TARGET: (f64, f64) = (0.35, 25.0);
const DEFAULT_RUBBER_TARGET: (f64, f64) = (0.40, 30.0);

/// The rubbers' held-out errors on the real rebounds of tt_rackets, the table of docs/racket.md
/// (run from the repository's root): each racket's hits predicted by the seed's rubber, by a
/// calibration on the racket alone, on its class and on all five inverted rubbers (the
/// default), 5-fold cross-validated; a miss of the target in bold.
fn rubbers_table(layers: &[Layer]) -> anyhow::Result<String> {
    let mut with_seed = layers.to_vec();
    with_seed.push(Layer::File(PathBuf::from(
        "config/presets/rubber_sriver_seed.yaml",
    )));
    let seed = load_layers(&with_seed, None)
        .context("the seed's rubber is read from the repository's root")?;
    let calibrated = |rackets: &[&str]| -> anyhow::Result<RubberCalibration> {
        let mut hits = HitSet::default();
        for racket in rackets {
            let path = format!("tests/data/tt_rackets/test/racket_{racket}.csv");
            let text = std::fs::read_to_string(&path)
                .with_context(|| format!("{path} is read from the repository's root"))?;
            hits.add_csv(racket, &text)?;
        }
        Ok(calibrate_rubber(&seed, &hits, &RubberOptions::default())?)
    };
    let rms = |e: &ReboundErrors| (e.velocity_rms, e.spin_rms);
    let held_out = |c: &RubberCalibration, racket: &str| -> anyhow::Result<(f64, f64)> {
        let cv = cross_validation(c)?;
        let e = cv
            .groups
            .iter()
            .find(|g| g.group == racket)
            .context("a racket without its held-out errors")?;
        Ok(rms(&e.calibrated))
    };
    let cell = |(v, w): (f64, f64), (tv, tw): (f64, f64)| {
        let bold = |miss: bool, text: String| if miss { format!("**{text}**") } else { text };
        format!(
            "{} / {}",
            bold(v > tv, format!("{v:.3}")),
            bold(w > tw, format!("{w:.1}"))
        )
    };
    let inverted: Vec<&str> = INVERTED_CLASSES
        .iter()
        .flat_map(|(_, r)| r.iter().copied())
        .collect();
    let default = calibrated(&inverted)?;
    let mut text = String::from(
        "| racket (rubber) | seed's rubber: velocity / spin | calibrated on the racket | class \
         preset | default (all five inverted) |\n|---|---|---|---|---|\n",
    );
    let (mut sum, mut hits) = ((0.0, 0.0), 0.0);
    for (class, rackets) in INVERTED_CLASSES {
        let preset = calibrated(rackets)?;
        for racket in rackets {
            let own = calibrated(&[racket])?;
            let start = rms(&cross_validation(&own)?.overall.start);
            let alone = held_out(&own, racket)?;
            let n = own.predictions.len() as f64;
            sum = (sum.0 + alone.0 * alone.0 * n, sum.1 + alone.1 * alone.1 * n);
            hits += n;
            text.push_str(&format!(
                "| {racket} ({class}) | {:.2} / {:.0} | {} | {} | {} |\n",
                start.0,
                start.1,
                cell(alone, CALIBRATION_TARGET),
                cell(held_out(&preset, racket)?, CALIBRATION_TARGET),
                cell(held_out(&default, racket)?, DEFAULT_RUBBER_TARGET),
            ));
        }
    }
    let overall = &cross_validation(&default)?.overall;
    let start = rms(&overall.start);
    text.push_str(&format!(
        "| all five inverted | {:.2} / {:.0} | {} | | {} |\n",
        start.0,
        start.1,
        cell(
            ((sum.0 / hits).sqrt(), (sum.1 / hits).sqrt()),
            CALIBRATION_TARGET
        ),
        cell(rms(&overall.calibrated), DEFAULT_RUBBER_TARGET),
    ));
    let pips = calibrated(&[LONG_PIPS])?;
    let start = rms(&cross_validation(&pips)?.overall.start);
    let (v, w) = held_out(&pips, LONG_PIPS)?;
    text.push_str(&format!(
        "| {LONG_PIPS} (long pips) | {:.2} / {:.0} | {v:.3} / {w:.1} | (its own class) | |\n",
        start.0, start.1,
    ));
    Ok(text)
}

/// A rubber calibration's held-out errors.
fn cross_validation(c: &RubberCalibration) -> anyhow::Result<&CrossValidation> {
    c.cross_validation
        .as_ref()
        .context("a calibration without its cross-validation")
}

/// The real launcher flights' files in the repository.
fn launcher_files() -> Vec<PathBuf> {
    ["backspin", "no_spin", "topspin"]
        .iter()
        .map(|kind| PathBuf::from(format!("tests/data/mpi_launcher/mn5008_{kind}.csv")))
        .collect()
}

/// The real launcher flights of `files` through `config`'s estimator, each from what the ones
/// before it taught (`carry_over`) or from the configuration.
fn real_flights(
    config: &Config,
    files: &[PathBuf],
    carry_over: bool,
) -> anyhow::Result<RealReport> {
    let (launcher, config) = launcher_flights(config, files, CsvFrame::Launcher)
        .context("the real launcher flights are read from the repository's root")?;
    let options = RealEvalOptions {
        carry_over,
        ..RealEvalOptions::default()
    };
    Ok(evaluate_flights(&config, &launcher.flights, &options))
}

/// The accuracy tables of README.md (see `--readme`), as Markdown.
pub(super) fn readme_tables(config: &Config) -> anyhow::Result<String> {
    let mut reports = Vec::new();
    for cameras in [Cameras::WideAndHighSpeed, Cameras::WideOnly] {
        let (config, session) = simulated_play(config, cameras)?;
        reports.push(evaluate_learning(&config, &session).0);
    }
    let by_lead = |r: &EvalReport, f: &dyn Fn(&ttball::eval::LeadReport) -> f64| {
        by_ascending_lead(&r.leads, f)
    };
    let column = |r: &EvalReport| {
        [
            triple(by_lead(r, &|l| l.position_error.rms), 1e3, 1),
            triple(by_lead(r, &|l| l.position_error.median), 1e3, 1),
            format!("{:.2}", r.velocity_error.rms),
            format!(
                "{:.2} ({:.2} / {:.2})",
                r.state_nees, r.bounce_nees[0], r.bounce_nees[1]
            ),
            triple(by_lead(r, &|l| l.position_nees), 1.0, 2),
            format!("{} of {}", r.single_track_shots, r.shots),
        ]
    };
    let (both, wide) = (column(&reports[0]), column(&reports[1]));
    let rows = [
        (
            "interception position RMS at 100 / 200 / 300 ms lead [mm]",
            "3 at 100 ms",
        ),
        (
            "interception position median at 100 / 200 / 300 ms lead [mm]",
            "- / 3 / 40",
        ),
        ("velocity after 100 ms of track, RMS [m/s]", "0.05"),
        (
            "state NEES per dimension (before / after the bounce)",
            "0.7-1.5",
        ),
        (
            "interception NEES per dimension at 100 / 200 / 300 ms",
            "0.7-1.5",
        ),
        ("shots tracked as one track", "all"),
    ];
    let mut text = String::from(
        "| simulated play, seed 1, 200 shots | 150 + 900 fps | 150 fps alone | target |\n\
         |---|---|---|---|\n",
    );
    for (i, (name, target)) in rows.iter().enumerate() {
        text.push_str(&format!(
            "| {name} | {} | {} | {target} |\n",
            both[i], wide[i]
        ));
    }
    let r = &reports[0];
    text.push_str(&format!(
        "| velocity / spin where the 900 fps camera sees the ball, RMS | {:.2} m/s / {:.1} \
         rad/s | - | 0.05 m/s / 15 rad/s |\n",
        r.velocity_error_high_speed.rms, r.spin_error_high_speed.rms
    ));

    let real = real_flights(config, &launcher_files(), true)?;
    let all = real.overall().context("no real flight was scored")?;
    let tracks: u64 = real.flights.iter().map(|f| f.counters.tracks).sum();
    let gated = real
        .flights
        .iter()
        .filter(|f| f.gated_after_bounce > 0)
        .count();
    text.push_str(&format!(
        "\n| real launcher flights, {} ({} crossings measured) | crossing error RMS / median \
         [mm] | NEES per dimension | target |\n|---|---|---|---|\n",
        real.flights.len(),
        all.scored
    ));
    for (l, target) in all.leads.iter().zip(["15 mm RMS", "10 mm RMS"]) {
        text.push_str(&format!(
            "| {:.0} ms lead | {:.1} / {:.1} | {:.2} | {target} |\n",
            l.lead * 1e3,
            l.position_error.rms * 1e3,
            l.position_error.median * 1e3,
            l.crossing_nees
        ));
    }
    text.push_str(&format!(
        "| tracks; flights with a detection gated within 50 ms after the bounce | {tracks}; \
         {gated} | | one a flight; none |\n"
    ));
    Ok(text)
}
