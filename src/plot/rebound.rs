//! The racket's rebound chart, like Kawazoe & Suzuki's Fig. 19 and 20: the rebound
//! power coefficient e of the configured racket along its long axis at several impact speeds,
//! and against impact speed at the face centre and the top point, for the free racket (solid)
//! and the racket held by the configured arm (dashed).

use plotters::coord::Shift;
use plotters::element::DashedPathElement;
use plotters::prelude::*;

use super::{FONT, PlotError, draw_legend};
use crate::config::Config;
use crate::physics::RacketModel;

/// Impact speeds of the curves along the long axis [m/s] (the paper's Fig. 13 speeds and 30).
const SPEEDS: [f64; 4] = [8.0, 16.0, 24.0, 30.0];
const COLOURS: [RGBColor; 4] = [
    RGBColor(31, 119, 180),
    RGBColor(44, 160, 44),
    RGBColor(255, 127, 14),
    RGBColor(214, 39, 40),
];
/// Offset of the face centre (point D) from the centre of gravity in Kawazoe & Suzuki: e of the free
/// racket "peaks 18 mm from the centre of the face", at its centre of gravity [m].
const FACE_CENTRE_OFFSET: f64 = 0.018;
/// Points per curve.
const SAMPLES: usize = 120;

/// The size of the chart.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ChartOptions {
    /// Width [px]. Default 1600.
    pub width: u32,
    /// Height [px]. Default 700.
    pub height: u32,
}

impl Default for ChartOptions {
    fn default() -> Self {
        Self {
            width: 1600,
            height: 700,
        }
    }
}

/// One curve: points, colour, dashed or not, legend label.
struct Curve {
    points: Vec<(f64, f64)>,
    colour: RGBColor,
    dashed: bool,
    label: String,
}

/// The curves of both panels, computed from the model.
pub(crate) struct ReboundChart {
    along: Vec<Curve>,
    against_speed: Vec<Curve>,
    face: (f64, f64),
    center_of_gravity: f64,
    arm_mass: f64,
}

impl ReboundChart {
    /// Computes the curves; impacts without a contact solution leave gaps.
    pub(crate) fn new(model: &RacketModel, config: &Config) -> Self {
        let cg = config.racket.center_of_gravity_from_grip_end;
        let (min, max) = model.face_offsets();
        let e = |m: &RacketModel, speed: f64, offset: f64| {
            m.normal_impact(speed, offset)
                .ok()
                .map(|i| i.rebound_power_coefficient)
        };
        let holders = [
            (model.with_arm_mass(0.0), false, "free".to_owned()),
            (
                model.clone(),
                true,
                format!("held ({:.2} kg at the grip)", config.arm.equivalent_mass),
            ),
        ];
        let mut along = Vec::new();
        let mut against_speed = Vec::new();
        for (holder, dashed, name) in &holders {
            for (speed, colour) in SPEEDS.iter().zip(COLOURS) {
                let points = (0..=SAMPLES)
                    .filter_map(|i| {
                        let b = min + (max - min) * i as f64 / SAMPLES as f64;
                        e(holder, *speed, b).map(|e| ((cg + b) * 1e3, e))
                    })
                    .collect();
                along.push(Curve {
                    points,
                    colour,
                    dashed: *dashed,
                    label: format!("{speed:.0} m/s, {name}"),
                });
            }
            for (offset, colour, point) in [
                (
                    FACE_CENTRE_OFFSET.clamp(min, max),
                    COLOURS[1],
                    "face centre D",
                ),
                (max, COLOURS[3], "top A"),
            ] {
                let points = (0..=SAMPLES)
                    .filter_map(|i| {
                        let speed = 1.0 + 34.0 * i as f64 / SAMPLES as f64;
                        e(holder, speed, offset).map(|e| (speed, e))
                    })
                    .collect();
                against_speed.push(Curve {
                    points,
                    colour,
                    dashed: *dashed,
                    label: format!("{point}, {name}"),
                });
            }
        }
        Self {
            along,
            against_speed,
            face: ((cg + min) * 1e3, (cg + max) * 1e3),
            center_of_gravity: cg * 1e3,
            arm_mass: config.arm.equivalent_mass,
        }
    }

    /// Draws both panels.
    pub(crate) fn draw<DB: DrawingBackend>(
        &self,
        root: &DrawingArea<DB, Shift>,
    ) -> Result<(), PlotError> {
        root.fill(&WHITE)?;
        let (width, _) = root.dim_in_pixel();
        let scale = f64::from(width) / 1600.0;
        let px = |v: f64| (v * scale).round().max(1.0) as u32;
        let title = root.titled(
            &format!(
                "Rebound power coefficient e of the racket (Kawazoe & Suzuki model; arm {:.2} kg)",
                self.arm_mass
            ),
            (FONT, px(26.0)).into_font().style(FontStyle::Bold),
        )?;
        let panels = title.split_evenly((1, 2));
        let y_range = self.y_range();
        let panel_specs = [
            (
                &self.along,
                (self.face.0, self.face.1),
                "impact point from the grip end [mm]",
                "along the long axis",
            ),
            (
                &self.against_speed,
                (0.0, 36.0),
                "normal impact speed [m/s]",
                "against impact speed",
            ),
        ];
        for (panel, (curves, x_range, x_label, caption)) in panels.iter().zip(panel_specs) {
            let mut chart = ChartBuilder::on(panel)
                .caption(caption, (FONT, px(20.0)))
                .margin(px(16.0))
                .x_label_area_size(px(50.0))
                .y_label_area_size(px(60.0))
                .build_cartesian_2d(x_range.0..x_range.1, y_range.0..y_range.1)?;
            chart
                .configure_mesh()
                .x_desc(x_label)
                .y_desc("e [-]")
                .label_style((FONT, px(15.0)))
                .axis_desc_style((FONT, px(17.0)))
                .light_line_style(RGBColor(235, 235, 235))
                .draw()?;
            if caption == "along the long axis" {
                let cg = self.center_of_gravity;
                chart.draw_series([DashedPathElement::new(
                    vec![(cg, y_range.0), (cg, y_range.1)],
                    px(6.0),
                    px(6.0),
                    BLACK.mix(0.5).stroke_width(1),
                )])?;
            }
            for curve in curves.iter() {
                let style = curve.colour.stroke_width(px(3.0));
                let legend_colour = curve.colour;
                let dashed = curve.dashed;
                let lw = px(3.0);
                let series = if curve.dashed {
                    chart.draw_series([DashedPathElement::new(
                        curve.points.clone(),
                        px(10.0),
                        px(6.0),
                        style,
                    )])?
                } else {
                    chart.draw_series(LineSeries::new(curve.points.clone(), style))?
                };
                series.label(curve.label.clone()).legend(move |(x, y)| {
                    let s = legend_colour.stroke_width(lw);
                    if dashed {
                        DashedPathElement::new(vec![(x, y), (x + 24, y)], 6, 4, s).into_dyn()
                    } else {
                        PathElement::new(vec![(x, y), (x + 24, y)], s).into_dyn()
                    }
                });
            }
            draw_legend(&mut chart, SeriesLabelPosition::LowerRight, px(13.0))?;
        }
        Ok(())
    }

    /// The e axis: every curve, with a margin.
    fn y_range(&self) -> (f64, f64) {
        let (lo, hi) = self
            .along
            .iter()
            .chain(&self.against_speed)
            .flat_map(|c| c.points.iter().map(|p| p.1))
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), e| {
                (lo.min(e), hi.max(e))
            });
        if lo.is_finite() && hi.is_finite() {
            ((lo - 0.05).max(0.0), (hi + 0.05).min(1.0))
        } else {
            (0.0, 1.0)
        }
    }
}
