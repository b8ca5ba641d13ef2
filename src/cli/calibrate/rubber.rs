//! `ttball calibrate --rebound HITS.csv`: the racket's rubber fitted to recorded hits, written
//! as a configuration snippet with standard errors and cross-validated errors, plus a chart.

use std::fmt::Write as _;
use std::process::ExitCode;

use anyhow::{Context, bail};
use ttball::config::Config;
use ttball::offline::rebound_calibration::{
    GroupErrors, HitSet, RubberCalibration, RubberOptions, calibrate_rubber, rejected_by_reason,
};
use ttball::plot::ChartOptions;

use super::{CalibrateArgs, Group, display_names};
use crate::cli::{BadUsage, write_file, write_json, write_stdout};

/// Reads the hits, calibrates the rubber and writes the outputs.
pub(super) fn run(args: &CalibrateArgs, config: &Config) -> anyhow::Result<ExitCode> {
    let mut set = HitSet::default();
    for path in &args.rebound {
        let text = std::fs::read_to_string(path)
            .with_context(|| format!("cannot read {}", path.display()))?;
        let taken = set
            .add_csv(&path.display().to_string(), &text)
            .map_err(|e| BadUsage(e.to_string()))?;
        eprintln!("{}: {taken} hits", path.display());
    }
    for (reason, count) in rejected_by_reason(&set) {
        eprintln!("  {count} lines left out: {reason}");
    }
    if let Some(first) = set.rejected.first() {
        eprintln!(
            "  (first: {} line {}: {})",
            first.group, first.line, first.reason
        );
    }
    if set.hits.is_empty() {
        bail!(BadUsage(
            "no hit to calibrate from: every line was left out (see above)".into()
        ));
    }
    let all = args.fit.is_empty();
    let fit = |g: Group| all || args.fit.contains(&g);
    let options = RubberOptions {
        restitution_order: fit(Group::RubberRestitution).then_some(args.restitution_order),
        friction: fit(Group::RubberFriction),
        tangential: fit(Group::RubberTangential),
        torsional: fit(Group::RubberTorsional),
        folds: args.folds,
    };
    let calibration = calibrate_rubber(config, &set, &options)
        .map_err(|e| BadUsage(format!("cannot calibrate the rubber: {e}")))?;
    write_file(
        &args.output,
        snippet(&calibration, &display_names(&args.rebound)),
    )?;
    if let Some(path) = &args.plot {
        let options = ChartOptions {
            width: 1800,
            height: 1100,
        };
        let png = path.extension().is_some_and(|e| e == "png");
        let bytes = ttball::plot::render_rubber_calibration(&calibration, &options, png)?;
        write_file(path, bytes)?;
    }
    if let Some(path) = &args.json {
        let json = serde_json::json!({
            "parameters": calibration.parameters,
            "noise": { "velocity": calibration.noise.0, "spin": calibration.noise.1 },
            "measured_velocity_axes": calibration.measured_axes,
            "fit": calibration.fit,
            "cross_validation": calibration.cross_validation,
            "rejected": set.rejected,
            "iterations": calibration.iterations,
        });
        write_json(path, &json)?;
    }
    write_stdout(&report(&calibration, &args.output))?;
    Ok(ExitCode::SUCCESS)
}

/// "x, z" for the measured velocity axes.
fn axes(measured: [bool; 3]) -> String {
    ["x", "y", "z"]
        .iter()
        .zip(measured)
        .filter(|(_, m)| *m)
        .map(|(a, _)| *a)
        .collect::<Vec<_>>()
        .join(", ")
}

/// One line of errors: starting -> calibrated.
fn errors_line(e: &GroupErrors) -> String {
    format!(
        "{:>4} hits  velocity {:.3} -> {:.3} m/s   spin {:6.1} -> {:5.1} rad/s",
        e.calibrated.hits,
        e.start.velocity_rms,
        e.calibrated.velocity_rms,
        e.start.spin_rms,
        e.calibrated.spin_rms
    )
}

/// The configuration snippet: the fitted values, with the fit's numbers in comments.
fn snippet(c: &RubberCalibration, inputs: &[String]) -> String {
    let mut out = String::new();
    let hits = c.fit.last().map_or(0, |e| e.calibrated.hits);
    let _ = writeln!(
        out,
        "# Written by `ttball calibrate --rebound` from {hits} recorded hits in:"
    );
    for i in inputs {
        let _ = writeln!(out, "#   {i}");
    }
    let _ = writeln!(
        out,
        "# Velocity axes scored: {} (an axis 0 before and after in every hit is not measured).",
        axes(c.measured_axes)
    );
    if let Some(cv) = &c.cross_validation {
        let _ = writeln!(
            out,
            "# RMS error of the outgoing velocity and spin on held-out hits ({}-fold), starting \
             configuration -> calibrated:",
            cv.folds
        );
        for e in cv.groups.iter().chain([&cv.overall]) {
            let _ = writeln!(out, "#   {:<40} {}", e.group, errors_line(e));
        }
    }
    let _ = writeln!(
        out,
        "# Residual scatter per component: {:.3} m/s, {:.1} rad/s.",
        c.noise.0, c.noise.1
    );
    let _ = writeln!(
        out,
        "# Value +- standard error (starting value), per fitted parameter:"
    );
    for p in &c.parameters {
        let error = p
            .std_error
            .map_or_else(|| "not determined".to_owned(), |s| format!("{s:.5}"));
        let _ = writeln!(
            out,
            "#   {} = {:.5} +- {} ({:.5})",
            p.name, p.value, error, p.initial
        );
    }
    let r = &c.config.racket;
    let list = |v: &[f64]| {
        v.iter()
            .map(|x| format!("{x:.6}"))
            .collect::<Vec<_>>()
            .join(", ")
    };
    out.push_str(
        "# rubber_covariance: the fit's covariance over (rubber_restitution's coefficients,\n\
         # rubber_friction, rubber_tangential_restitution, rubber_torsional_restitution), row by\n\
         # row; rebound_scatter: the residual scatter per component (velocity m/s, spin rad/s).\n\
         # The landing covariance of a planned return includes both.\n",
    );
    out.push_str("ttball:\n  ros__parameters:\n    racket:\n");
    let _ = writeln!(
        out,
        "      rubber_restitution: [{}]\n      rubber_friction: {:.6}\n      \
         rubber_tangential_restitution: {:.6}\n      rubber_torsional_restitution: {:.6}",
        list(&r.rubber_restitution),
        r.rubber_friction,
        r.rubber_tangential_restitution,
        r.rubber_torsional_restitution
    );
    let size = r.rubber_restitution.len() + 3;
    let rows: Vec<String> = r
        .rubber_covariance
        .chunks(size)
        .map(|row| {
            row.iter()
                .map(|v| format!("{v:.6e}"))
                .collect::<Vec<_>>()
                .join(", ")
        })
        .collect();
    let _ = writeln!(
        out,
        "      rubber_covariance: [\n        {}]\n      rebound_scatter: [{:.6}, {:.6}]",
        rows.join(",\n        "),
        c.noise.0,
        c.noise.1
    );
    out
}

/// What the user reads at the end.
fn report(c: &RubberCalibration, output: &std::path::Path) -> String {
    let mut out = String::new();
    let _ = writeln!(
        out,
        "calibrated the rubber in {} Levenberg-Marquardt iterations (velocity axes scored: {})",
        c.iterations,
        axes(c.measured_axes)
    );
    out.push_str("parameter                                fitted   +- std error      start\n");
    for p in &c.parameters {
        let error = p
            .std_error
            .map_or_else(|| "not determined".to_owned(), |s| format!("{s:>10.5}"));
        let _ = writeln!(
            out,
            "  {:<36} {:>10.5}  {:>14}  {:>9.5}",
            p.name, p.value, error, p.initial
        );
    }
    if c.parameters.iter().any(|p| p.std_error.is_none()) {
        out.push_str(
            "  (not determined: no hit's prediction depends on it at the best fit; the friction \
             when every hit grips, so it is only known to exceed what the grip needs)\n",
        );
    }
    out.push_str(
        "RMS error of the outgoing velocity and spin, starting configuration -> calibrated:\n",
    );
    for e in &c.fit {
        let _ = writeln!(out, "  fitted    {:<40} {}", e.group, errors_line(e));
    }
    if let Some(cv) = &c.cross_validation {
        for e in cv.groups.iter().chain([&cv.overall]) {
            let _ = writeln!(out, "  held out  {:<40} {}", e.group, errors_line(e));
        }
    }
    out.push_str(&super::written_line(output));
    out
}
