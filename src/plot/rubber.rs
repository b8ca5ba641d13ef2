//! The rubber calibration's chart: for each measured component of the outgoing velocity and
//! spin, predicted against measured for every hit, by the starting configuration (grey) and the
//! calibrated one (held out when cross-validated), with the line of perfect prediction.

use plotters::coord::Shift;
use plotters::prelude::*;

use super::{FONT, PlotError, draw_legend};
use crate::offline::rebound_calibration::{HitPrediction, RubberCalibration};

const CALIBRATED: RGBColor = RGBColor(31, 119, 180);
const START: RGBColor = RGBColor(160, 160, 160);

/// One panel: which component, its label and unit.
struct Panel {
    spin: bool,
    axis: usize,
    label: String,
}

/// Draws the chart of `calibration` on `root`.
pub(crate) fn draw<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    calibration: &RubberCalibration,
) -> Result<(), PlotError> {
    root.fill(&WHITE)?;
    let (width, _) = root.dim_in_pixel();
    let scale = f64::from(width) / 1800.0;
    let px = |v: f64| (v * scale).round().max(1.0) as u32;
    let axes = ["x", "y", "z"];
    let mut panels: Vec<Panel> = (0..3)
        .filter(|k| calibration.measured_axes[*k])
        .map(|k| Panel {
            spin: false,
            axis: k,
            label: format!("outgoing v_{} [m/s]", axes[k]),
        })
        .collect();
    panels.extend((0..3).map(|k| Panel {
        spin: true,
        axis: k,
        label: format!("outgoing spin w_{} [rad/s]", axes[k]),
    }));
    let held_out = calibration
        .cross_validation
        .as_ref()
        .map_or(String::new(), |cv| format!(", {}-fold held out", cv.folds));
    let title = format!(
        "Racket rebound: predicted vs measured, {} hits{held_out}",
        calibration.predictions.len()
    );
    let root = root.titled(&title, (FONT, px(28.0)))?;
    let columns = panels.len().div_ceil(2);
    let areas = root.split_evenly((2, columns));
    let value = |p: &Panel, pair: &(nalgebra::Vector3<f64>, nalgebra::Vector3<f64>)| {
        if p.spin {
            pair.1[p.axis]
        } else {
            pair.0[p.axis]
        }
    };
    for (panel, area) in panels.iter().zip(areas.iter()) {
        let points =
            |pick: fn(&HitPrediction) -> &(nalgebra::Vector3<f64>, nalgebra::Vector3<f64>)| {
                calibration
                    .predictions
                    .iter()
                    .map(|h| (value(panel, &h.measured), value(panel, pick(h))))
                    .collect::<Vec<_>>()
            };
        let start = points(|h| &h.start);
        let fitted = points(|h| &h.calibrated);
        let (lo, hi) = start
            .iter()
            .chain(&fitted)
            .flat_map(|(a, b)| [*a, *b])
            .filter(|v| v.is_finite())
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| {
                (lo.min(v), hi.max(v))
            });
        let (lo, hi) = if lo < hi { (lo, hi) } else { (-1.0, 1.0) };
        let pad = 0.05 * (hi - lo);
        let range = (lo - pad)..(hi + pad);
        let mut chart = ChartBuilder::on(area)
            .margin(px(14.0))
            .x_label_area_size(px(50.0))
            .y_label_area_size(px(70.0))
            .build_cartesian_2d(range.clone(), range.clone())?;
        chart
            .configure_mesh()
            .x_desc(format!("measured {}", panel.label))
            .y_desc("predicted")
            .label_style((FONT, px(16.0)))
            .axis_desc_style((FONT, px(18.0)))
            .light_line_style(WHITE.mix(0.0))
            .draw()?;
        chart.draw_series(LineSeries::new(
            [(range.start, range.start), (range.end, range.end)],
            BLACK.mix(0.6).stroke_width(px(1.5)),
        ))?;
        let radius = px(3.0);
        chart
            .draw_series(
                start
                    .iter()
                    .map(|&(m, p)| Circle::new((m, p), radius, START.mix(0.6).filled())),
            )?
            .label("starting configuration")
            .legend(move |(x, y)| Circle::new((x + 8, y), radius, START.filled()));
        chart
            .draw_series(
                fitted
                    .iter()
                    .map(|&(m, p)| Circle::new((m, p), radius, CALIBRATED.mix(0.7).filled())),
            )?
            .label(if calibration.cross_validation.is_some() {
                "calibrated (held out)"
            } else {
                "calibrated"
            })
            .legend(move |(x, y)| Circle::new((x + 8, y), radius, CALIBRATED.filled()));
        draw_legend(&mut chart, SeriesLabelPosition::UpperLeft, px(15.0))?;
    }
    Ok(())
}
