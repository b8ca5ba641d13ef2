//! The calibration chart: the fitted C_D(Sp) and C_M(Sp) with a band of two standard errors
//! against the starting (default) curves, the Sp range the flights cover shaded, and each
//! flight's RMS position residual before and after calibration.

use plotters::coord::Shift;
use plotters::element::DashedPathElement;
use plotters::prelude::*;

use super::{FONT, PlotError, draw_legend};
use crate::config::Config;
use crate::offline::calibrate::{Calibration, FlightResidual, polynomial_sigma};
use crate::physics::aero::Polynomial;

const FITTED: RGBColor = RGBColor(31, 119, 180);
const START: RGBColor = RGBColor(120, 120, 120);
const BEFORE: RGBColor = RGBColor(255, 127, 14);
/// Which residual of a flight a bar shows.
type ResidualOf = fn(&FlightResidual) -> f64;
/// Points per curve.
const SAMPLES: usize = 100;

/// Draws the chart of `calibration`, started from `start`, on `root`.
pub(crate) fn draw<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    calibration: &Calibration,
    start: &Config,
) -> Result<(), PlotError> {
    root.fill(&WHITE)?;
    let (width, _) = root.dim_in_pixel();
    let scale = f64::from(width) / 1800.0;
    let px = |v: f64| (v * scale).round().max(1.0) as u32;
    let title = root.titled(
        &format!(
            "Calibration from {} flights: RMS position residual {:.2} mm -> {:.2} mm per axis",
            calibration.flights.len(),
            calibration.position_rms_before * 1e3,
            calibration.position_rms * 1e3
        ),
        (FONT, px(26.0)).into_font().style(FontStyle::Bold),
    )?;
    let panels = title.split_evenly((1, 3));
    for (panel, drag) in panels.iter().zip([true, false]) {
        draw_coefficient(panel, calibration, start, drag, &px)?;
    }
    draw_residuals(&panels[2], calibration, &px)
}

/// The fitted and starting C_D(Sp) (`drag`) or C_M(Sp) on `panel`.
fn draw_coefficient<DB: DrawingBackend>(
    panel: &DrawingArea<DB, Shift>,
    calibration: &Calibration,
    start: &Config,
    drag: bool,
    px: &dyn Fn(f64) -> u32,
) -> Result<(), PlotError> {
    let sp_max = start.aero.spin_parameter_max.max(0.1);
    let [sp_low, _, sp_high] = calibration.spin_parameter;
    let (fitted, initial, name) = if drag {
        (
            &calibration.config.aero.drag_coefficients,
            &start.aero.drag_coefficients,
            "C_D",
        )
    } else {
        (
            &calibration.config.aero.magnus_coefficients,
            &start.aero.magnus_coefficients,
            "C_M",
        )
    };
    let curve = |c: &[f64]| -> Vec<(f64, f64)> {
        let p = Polynomial::new(c);
        (0..=SAMPLES)
            .map(|i| {
                let sp = sp_max * i as f64 / SAMPLES as f64;
                (sp, p.value(sp))
            })
            .collect()
    };
    let fitted_points = curve(fitted);
    let initial_points = curve(initial);
    let band: Vec<(f64, f64, f64)> = fitted_points
        .iter()
        .map(|&(sp, v)| {
            let s = 2.0 * polynomial_sigma(calibration, drag, sp);
            (sp, v - s, v + s)
        })
        .collect();
    let (lo, hi) = fitted_points
        .iter()
        .chain(&initial_points)
        .map(|p| p.1)
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| {
            (lo.min(v), hi.max(v))
        });
    let margin = 0.08 * (hi - lo).max(0.05);
    let y = (lo - margin)..(hi + margin);
    let mut chart = ChartBuilder::on(panel)
        .caption(format!("{name}(Sp)"), (FONT, px(20.0)))
        .margin(px(16.0))
        .x_label_area_size(px(50.0))
        .y_label_area_size(px(60.0))
        .build_cartesian_2d(0.0..sp_max, y.clone())?;
    chart
        .configure_mesh()
        .x_desc("spin parameter Sp = r |w x v| / |v|^2 [-]")
        .y_desc(format!("{name} [-]"))
        .label_style((FONT, px(15.0)))
        .axis_desc_style((FONT, px(17.0)))
        .light_line_style(RGBColor(235, 235, 235))
        .draw()?;
    chart
        .draw_series([Rectangle::new(
            [(sp_low, y.start), (sp_high, y.end)],
            RGBColor(230, 240, 250).filled(),
        )])?
        .label("Sp of 90 % of the detections")
        .legend(|(x, y)| {
            Rectangle::new(
                [(x, y - 6), (x + 24, y + 6)],
                RGBColor(230, 240, 250).filled(),
            )
        });
    let mut outline: Vec<(f64, f64)> = band.iter().map(|b| (b.0, b.2)).collect();
    outline.extend(band.iter().rev().map(|b| (b.0, b.1)));
    chart
        .draw_series([Polygon::new(outline, FITTED.mix(0.25).filled())])?
        .label("fitted +- 2 standard errors")
        .legend(|(x, y)| Rectangle::new([(x, y - 6), (x + 24, y + 6)], FITTED.mix(0.25).filled()));
    let lw = px(3.0);
    chart
        .draw_series(LineSeries::new(fitted_points, FITTED.stroke_width(lw)))?
        .label("fitted")
        .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 24, y)], FITTED.stroke_width(lw)));
    chart
        .draw_series([DashedPathElement::new(
            initial_points,
            px(10.0),
            px(6.0),
            START.stroke_width(lw),
        )])?
        .label("start (configuration)")
        .legend(move |(x, y)| {
            DashedPathElement::new(vec![(x, y), (x + 24, y)], 6, 4, START.stroke_width(lw))
        });
    draw_legend(&mut chart, SeriesLabelPosition::UpperRight, px(13.0))?;
    Ok(())
}

/// Each flight's RMS position residual before and after calibration on `panel`.
fn draw_residuals<DB: DrawingBackend>(
    panel: &DrawingArea<DB, Shift>,
    calibration: &Calibration,
    px: &dyn Fn(f64) -> u32,
) -> Result<(), PlotError> {
    let flights = &calibration.flights;
    let top = flights
        .iter()
        .map(|f| f.position_rms_before.max(f.position_rms) * 1e3)
        .fold(0.1, f64::max)
        * 1.1;
    let mut chart = ChartBuilder::on(panel)
        .caption("RMS position residual per flight", (FONT, px(20.0)))
        .margin(px(16.0))
        .x_label_area_size(px(50.0))
        .y_label_area_size(px(60.0))
        .build_cartesian_2d(0.0..(flights.len().max(1) as f64), 0.0..top)?;
    chart
        .configure_mesh()
        .x_desc("flight")
        .y_desc("per axis [mm]")
        .label_style((FONT, px(15.0)))
        .axis_desc_style((FONT, px(17.0)))
        .light_line_style(RGBColor(235, 235, 235))
        .draw()?;
    let series: [(&str, RGBColor, f64, ResidualOf); 2] = [
        ("start", BEFORE, 0.1, |f| f.position_rms_before),
        ("calibrated", FITTED, 0.5, |f| f.position_rms),
    ];
    for (label, colour, offset, value) in series {
        chart
            .draw_series(flights.iter().enumerate().map(|(i, f)| {
                let x = i as f64 + offset;
                Rectangle::new([(x, 0.0), (x + 0.4, value(f) * 1e3)], colour.filled())
            }))?
            .label(label)
            .legend(move |(x, y)| Rectangle::new([(x, y - 6), (x + 24, y + 6)], colour.filled()));
    }
    draw_legend(&mut chart, SeriesLabelPosition::UpperRight, px(13.0))?;
    Ok(())
}
