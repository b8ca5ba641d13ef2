//! The figure, on any plotters backend: a title, the top view (x-y, equal scale) and side view
//! (x-z) of the table sharing their x axis, speed, spin and position uncertainty over time, and
//! a legend of every layer drawn.

use std::ops::Range;

use nalgebra::Vector3;
use plotters::coord::Shift;
use plotters::coord::ranged1d::{AsRangedCoord, ValueFormatter};
use plotters::coord::types::RangedCoordf64;
use plotters::element::DashedPathElement;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};

use super::data::{PlotData, PlotEstimate, PlotTrajectory, Selection};
use super::{FONT, PlotError};
use crate::model::detection::Source;
use crate::online::estimator::TrackStatus;

const WIDE: RGBColor = RGBColor(31, 119, 180);
const HIGH_SPEED: RGBColor = RGBColor(255, 127, 14);
const UNKNOWN: RGBColor = RGBColor(127, 127, 127);
const REJECTED: RGBColor = RGBColor(214, 39, 40);
const TRACK: RGBColor = RGBColor(0, 0, 0);
const TRUTH: RGBColor = RGBColor(44, 160, 44);
const PREDICTED: RGBColor = RGBColor(148, 103, 189);
const CROSSING_EARLY: RGBColor = RGBColor(240, 170, 220);
const CROSSING_LATE: RGBColor = RGBColor(150, 0, 110);
const BOUNCE_EARLY: RGBColor = RGBColor(225, 195, 160);
const BOUNCE_LATE: RGBColor = RGBColor(120, 70, 20);
const TABLE_FILL: RGBColor = RGBColor(216, 229, 242);
const TABLE_EDGE: RGBColor = RGBColor(40, 75, 120);
const NET: RGBColor = RGBColor(50, 50, 50);
const PLANE: RGBColor = RGBColor(0, 150, 160);
const COASTING: RGBColor = RGBColor(235, 235, 235);
const GRID: RGBColor = RGBColor(228, 228, 228);
const TEXT_GREY: RGBColor = RGBColor(90, 90, 90);
const AXIS: [RGBColor; 3] = [
    RGBColor(214, 39, 40),
    RGBColor(44, 160, 44),
    RGBColor(31, 119, 180),
];

/// Gap between truth samples that breaks the truth line (between shots) [ns].
const TRUTH_GAP: i64 = 20_000_000;
/// Positions beyond these are not drawn (a stray detection must not squash the table) [m].
const WORLD: [(f64, f64); 3] = [(-4.5, 4.5), (-3.0, 3.0), (-0.9, 3.0)];

/// Everything one figure needs: the selected data, the clock and the titles.
pub(crate) struct Figure {
    data: PlotData,
    origin: i64,
    title: String,
    subtitle: String,
    predictions: usize,
    scale: f64,
}

impl Figure {
    /// A figure of already selected data.
    pub(crate) fn new(
        data: PlotData,
        selection: &Selection,
        origin: i64,
        title: Option<String>,
        predictions: usize,
        (width, height): (u32, u32),
    ) -> Self {
        let title = title.unwrap_or_else(|| default_title(&data, selection, origin));
        let subtitle = summary(&data);
        Self {
            data,
            origin,
            title,
            subtitle,
            predictions,
            scale: (f64::from(width) / 1600.0).min(f64::from(height) / 1000.0),
        }
    }

    /// A length of the 1600x1000 layout at this figure's size [px].
    fn px(&self, v: impl Into<f64>) -> i32 {
        (v.into() * self.scale).round().max(1.0) as i32
    }

    /// A font size of the 1600x1000 layout at this figure's size [px].
    fn font(&self, size: f64) -> FontDesc<'static> {
        (FONT, size * self.scale).into_font()
    }

    /// The bold face at a font size of the 1600x1000 layout (`FontDesc::style` would keep the
    /// regular face's glyphs on the bitmap backend).
    fn bold(&self, size: f64) -> FontDesc<'static> {
        FontDesc::new(FontFamily::from(FONT), size * self.scale, FontStyle::Bold)
    }

    /// Seconds since the time origin of a stamp [ns].
    fn t(&self, stamp: i64) -> f64 {
        (stamp - self.origin) as f64 * 1e-9
    }
}

fn default_title(data: &PlotData, selection: &Selection, origin: i64) -> String {
    let mut ids: Vec<u32> = data.estimates.iter().map(|e| e.track_id).collect();
    ids.sort_unstable();
    ids.dedup();
    let what = match (selection.track, ids.as_slice()) {
        (Some(id), _) | (None, &[id]) => format!("Track {id}"),
        (None, []) => "Detections".to_string(),
        (None, many) if many.len() <= 6 => format!(
            "Tracks {}",
            many.iter()
                .map(u32::to_string)
                .collect::<Vec<_>>()
                .join(", ")
        ),
        (None, many) => format!("{} tracks", many.len()),
    };
    match stamp_span(data) {
        Some((a, b)) => {
            let t = |s: i64| (s - origin) as f64 * 1e-9;
            format!(
                "{what}: t = {:.3} s to {:.3} s ({:.0} ms)",
                t(a),
                t(b),
                (b - a) as f64 * 1e-6
            )
        }
        None => what,
    }
}

/// The plots' three groups of cameras: the seed setup's two (by their own source) and every
/// other source as [`Source::UNKNOWN`].
fn camera_group(s: Source) -> Source {
    if s == Source::WIDE_150FPS || s == Source::HIGHSPEED_900FPS {
        s
    } else {
        Source::UNKNOWN
    }
}

fn summary(data: &PlotData) -> String {
    let count = |s: Source| {
        data.detections
            .iter()
            .filter(|d| camera_group(d.source) == s)
            .count()
    };
    let rejected = data.detections.iter().filter(|d| d.rejected).count();
    let mut parts = vec![format!(
        "{} detections ({} at 150 fps, {} at 900 fps{}, {} rejected)",
        data.detections.len(),
        count(Source::WIDE_150FPS),
        count(Source::HIGHSPEED_900FPS),
        match count(Source::UNKNOWN) {
            0 => String::new(),
            n => format!(", {n} other or unknown camera"),
        },
        rejected
    )];
    parts.push(format!("{} estimates", data.estimates.len()));
    if !data.intercepts.is_empty() {
        let valid = data.intercepts.iter().filter(|i| i.is_valid()).count();
        parts.push(format!(
            "{} interception predictions ({} valid)",
            data.intercepts.len(),
            valid
        ));
    }
    if !data.truth.is_empty() {
        parts.push("truth dashed".to_string());
    }
    parts.push("t = 0 at the first stamp of the recording".to_string());
    parts.join("  ·  ")
}

/// First and last stamp of the detections and estimates [ns].
fn stamp_span(data: &PlotData) -> Option<(i64, i64)> {
    let stamps = data
        .detections
        .iter()
        .map(|d| d.stamp)
        .chain(data.estimates.iter().map(|e| e.stamp));
    stamps.fold(None, |acc, s| match acc {
        None => Some((s, s)),
        Some((a, b)) => Some((a.min(s), b.max(s))),
    })
}

/// A closed interval that grows to hold values.
#[derive(Debug, Clone, Copy)]
struct Span {
    lo: f64,
    hi: f64,
}

impl Span {
    fn new() -> Self {
        Self {
            lo: f64::INFINITY,
            hi: f64::NEG_INFINITY,
        }
    }

    fn add(&mut self, v: f64) {
        if v.is_finite() {
            self.lo = self.lo.min(v);
            self.hi = self.hi.max(v);
        }
    }

    /// Padded by `pad` on each side, or `fallback` when empty.
    fn padded(self, pad: f64, fallback: (f64, f64)) -> Self {
        if self.lo > self.hi {
            return Self {
                lo: fallback.0,
                hi: fallback.1,
            };
        }
        let pad = pad.max(1e-9);
        Self {
            lo: self.lo - pad,
            hi: self.hi + pad,
        }
    }

    fn width(self) -> f64 {
        self.hi - self.lo
    }

    /// Grown about its centre to `width`.
    fn widened(self, width: f64) -> Self {
        let c = 0.5 * (self.lo + self.hi);
        Self {
            lo: c - 0.5 * width,
            hi: c + 0.5 * width,
        }
    }

    fn range(self) -> Range<f64> {
        self.lo..self.hi
    }

    fn contains(self, v: f64) -> bool {
        v >= self.lo && v <= self.hi
    }
}

/// A layer's symbol in a legend or key.
#[derive(Debug, Clone, Copy)]
enum Glyph {
    Dot(RGBColor),
    Cross(RGBColor),
    Line(RGBColor),
    Dashed(RGBColor),
    Square(RGBColor),
    Triangle(RGBColor),
    Table,
    Band(RGBColor),
}

/// Draws the whole figure.
pub(crate) fn draw<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    fig: &Figure,
) -> Result<(), PlotError> {
    root.fill(&WHITE)?;
    let (width, height) = root.dim_in_pixel();
    let legend = legend_entries(fig);
    let rows = legend_rows(root, fig, &legend, width as i32)?;
    let header_h = fig.px(78);
    let legend_h = fig.px(16) + fig.px(30) * rows.len() as i32;
    let (header, rest) = root.split_vertically(header_h);
    let (body, footer) = rest.split_vertically((height as i32 - header_h - legend_h).max(1));
    draw_header(&header, fig)?;
    draw_legend(&footer, fig, &rows)?;

    let (left, right) = body.split_horizontally((0.6 * f64::from(width)).round() as i32);
    draw_views(&left, fig)?;
    let panels = right.split_evenly((3, 1));
    if let [speed, spin, sigma] = panels.as_slice() {
        draw_speed(speed, fig)?;
        draw_spin(spin, fig)?;
        draw_sigma(sigma, fig)?;
    }
    Ok(())
}

fn draw_header<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    fig: &Figure,
) -> Result<(), PlotError> {
    let (w, _) = area.dim_in_pixel();
    let center = Pos::new(HPos::Center, VPos::Top);
    let title = fig.bold(30.0).color(&BLACK).pos(center);
    area.draw(&Text::new(
        fig.title.clone(),
        (w as i32 / 2, fig.px(12)),
        title,
    ))?;
    let sub = fig.font(17.0).color(&TEXT_GREY).pos(center);
    area.draw(&Text::new(
        fig.subtitle.clone(),
        (w as i32 / 2, fig.px(50)),
        sub,
    ))?;
    Ok(())
}

// ---------------------------------------------------------------- panels and their frames

/// Panel frame sizes of the 1600x1000 layout [px].
const STRIP: f64 = 32.0;
const MARGIN_LEFT: f64 = 8.0;
const MARGIN_RIGHT: f64 = 24.0;
const MARGIN_TOP: f64 = 4.0;
const MARGIN_BOTTOM: f64 = 6.0;
const X_LABELS: f64 = 50.0;
const Y_LABELS: f64 = 78.0;

/// Splits a panel into its title strip (title left, key right) and its chart area.
fn panel<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    fig: &Figure,
    title: &str,
    keys: &[(String, Glyph)],
) -> Result<DrawingArea<DB, Shift>, PlotError> {
    let (strip, chart) = area.split_vertically(fig.px(STRIP));
    let (w, h) = strip.dim_in_pixel();
    let y = h as i32 / 2 + fig.px(4);
    let left = fig
        .bold(19.0)
        .color(&BLACK)
        .pos(Pos::new(HPos::Left, VPos::Center));
    strip.draw(&Text::new(
        title.to_string(),
        (fig.px(MARGIN_LEFT + Y_LABELS), y),
        left,
    ))?;
    let style = fig
        .font(15.0)
        .color(&BLACK)
        .pos(Pos::new(HPos::Left, VPos::Center));
    let mut x = w as i32 - fig.px(MARGIN_RIGHT);
    for (label, glyph) in keys.iter().rev() {
        let (tw, _) = strip.estimate_text_size(label, &style)?;
        x -= tw as i32;
        strip.draw(&Text::new(label.clone(), (x, y), style.clone()))?;
        draw_glyph(&strip, fig, *glyph, (x - fig.px(21), y))?;
        x -= fig.px(52);
    }
    Ok(chart)
}

/// The plotting area's size of a chart area [px].
fn plot_size(fig: &Figure, area: (u32, u32)) -> (f64, f64) {
    let w = f64::from(area.0)
        - f64::from(fig.px(MARGIN_LEFT) + fig.px(MARGIN_RIGHT) + fig.px(Y_LABELS));
    let h = f64::from(area.1)
        - f64::from(fig.px(MARGIN_TOP) + fig.px(MARGIN_BOTTOM) + fig.px(X_LABELS));
    (w.max(10.0), h.max(10.0))
}

type Chart<'a, DB, Y> = ChartContext<'a, DB, Cartesian2d<RangedCoordf64, Y>>;

fn chart_on<'a, DB: DrawingBackend, Y: Ranged<ValueType = f64>>(
    area: &'a DrawingArea<DB, Shift>,
    fig: &Figure,
    x: Range<f64>,
    y: impl AsRangedCoord<CoordDescType = Y, Value = f64>,
) -> Result<Chart<'a, DB, Y>, PlotError> {
    Ok(ChartBuilder::on(area)
        .margin_left(fig.px(MARGIN_LEFT))
        .margin_right(fig.px(MARGIN_RIGHT))
        .margin_top(fig.px(MARGIN_TOP))
        .margin_bottom(fig.px(MARGIN_BOTTOM))
        .x_label_area_size(fig.px(X_LABELS))
        .y_label_area_size(fig.px(Y_LABELS))
        .build_cartesian_2d(x, y)?)
}

fn draw_mesh<DB: DrawingBackend, Y: Ranged<ValueType = f64> + ValueFormatter<f64>>(
    chart: &mut Chart<'_, DB, Y>,
    fig: &Figure,
    (x_desc, y_desc): (&str, &str),
) -> Result<(), PlotError> {
    let format = |v: &f64| format_tick(*v);
    chart
        .configure_mesh()
        .x_desc(x_desc)
        .y_desc(y_desc)
        .x_labels(9)
        .y_labels(6)
        .x_label_formatter(&format)
        .y_label_formatter(&format)
        .label_style(fig.font(15.0))
        .axis_desc_style(fig.font(16.0))
        .bold_line_style(GRID.stroke_width(1))
        .light_line_style(WHITE.mix(0.0))
        .axis_style(TEXT_GREY.stroke_width(1))
        .draw()?;
    Ok(())
}

/// A tick label without trailing noise: "-1.5", "0", "0.25".
fn format_tick(v: f64) -> String {
    let s = format!("{:.3}", v);
    let s = s.trim_end_matches('0').trim_end_matches('.');
    if s == "-0" {
        "0".to_string()
    } else {
        s.to_string()
    }
}

// ---------------------------------------------------------------- top and side view

/// Which plane a spatial panel shows.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum View {
    Top,
    Side,
}

impl View {
    fn project(self, p: &Vector3<f64>) -> (f64, f64) {
        match self {
            View::Top => (p.x, p.y),
            View::Side => (p.x, p.z),
        }
    }
}

fn finite(p: &Vector3<f64>) -> bool {
    p.iter().all(|v| v.is_finite())
}

fn in_world(p: &Vector3<f64>) -> bool {
    finite(p) && (0..3).all(|i| p[i] >= WORLD[i].0 && p[i] <= WORLD[i].1)
}

/// The extent of the scene and the data along x, y and z [m].
fn spatial_spans(fig: &Figure) -> [Span; 3] {
    let d = &fig.data;
    let s = &d.scene;
    let mut spans = [Span::new(); 3];
    let mut add = |p: &Vector3<f64>| {
        if in_world(p) {
            for (i, span) in spans.iter_mut().enumerate() {
                span.add(p[i]);
            }
        }
    };
    let (hl, hw) = (0.5 * s.table_length, 0.5 * s.table_width + s.net_overhang);
    add(&Vector3::new(-hl, -hw, -0.03));
    add(&Vector3::new(hl, hw, s.net_height + 0.1));
    add(&Vector3::new(s.plane_x, 0.0, 0.0));
    d.detections.iter().for_each(|x| add(&x.position));
    d.estimates.iter().for_each(|x| add(&x.position));
    d.truth.iter().for_each(|x| add(&x.position));
    for i in &d.intercepts {
        if let Some(c) = &i.crossing {
            add(&c.position);
        }
        if let Some(b) = &i.bounce {
            add(b);
        }
    }
    let [x, y, z] = spans;
    [
        x.padded(0.12, (-2.0, 2.0)),
        y.padded(0.12, (-1.0, 1.0)),
        z.padded(0.06, (-0.1, 0.6)),
    ]
}

/// Top view above, side view below, sharing x; the top view at equal scale.
fn draw_views<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    fig: &Figure,
) -> Result<(), PlotError> {
    let [x, y, z] = spatial_spans(fig);
    let (w, h) = area.dim_in_pixel();
    let frame = f64::from(fig.px(STRIP) + fig.px(MARGIN_TOP) + fig.px(MARGIN_BOTTOM))
        + f64::from(fig.px(X_LABELS));
    let (plot_w, _) = plot_size(fig, (w, h));
    // The top view's height that shows x and y at the same scale, within 38-62 % of the column.
    let wanted = plot_w * y.width() / x.width() + frame;
    let top_h = wanted
        .clamp(0.38 * f64::from(h), 0.62 * f64::from(h))
        .round() as i32;
    let (top, side) = area.split_vertically(top_h);
    let (pw, ph) = plot_size(fig, (w, (top_h - fig.px(STRIP)).max(1) as u32));
    let (x, y) = if pw / x.width() > ph / y.width() {
        (x.widened(y.width() * pw / ph), y)
    } else {
        (x, y.widened(x.width() * ph / pw))
    };
    draw_view(&top, fig, View::Top, x, y)?;
    draw_view(&side, fig, View::Side, x, z)?;
    Ok(())
}

fn draw_view<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    fig: &Figure,
    view: View,
    xs: Span,
    ys: Span,
) -> Result<(), PlotError> {
    let title = match view {
        View::Top => "Top view (x-y, equal scale), robot on the left",
        View::Side => "Side view (x-z)",
    };
    let chart_area = panel(area, fig, title, &[])?;
    let mut chart = chart_on(&chart_area, fig, xs.range(), ys.range())?;
    let y_desc = match view {
        View::Top => "y [m]",
        View::Side => "z [m]",
    };
    draw_mesh(&mut chart, fig, ("x [m]", y_desc))?;

    draw_scene(&mut chart, fig, view, ys)?;
    let inside = |p: &Vector3<f64>| {
        let (a, b) = view.project(p);
        finite(p) && xs.contains(a) && ys.contains(b)
    };
    draw_measured(&mut chart, fig, view, &inside)?;
    draw_predicted(&mut chart, fig, view, &inside)?;
    Ok(())
}

/// The table, the net and the hitting plane.
fn draw_scene<DB: DrawingBackend>(
    chart: &mut Chart<'_, DB, RangedCoordf64>,
    fig: &Figure,
    view: View,
    ys: Span,
) -> Result<(), PlotError> {
    let s = &fig.data.scene;
    let (hl, hw) = (0.5 * s.table_length, 0.5 * s.table_width);
    let post = hw + s.net_overhang;
    let edge = TABLE_EDGE.stroke_width(fig.px(2.0) as u32);
    match view {
        View::Top => {
            chart.draw_series([
                Rectangle::new([(-hl, -hw), (hl, hw)], TABLE_FILL.filled()),
                Rectangle::new([(-hl, -hw), (hl, hw)], edge),
            ])?;
            chart.draw_series([
                PathElement::new(vec![(-hl, 0.0), (hl, 0.0)], TABLE_EDGE.mix(0.6)),
                PathElement::new(
                    vec![(0.0, -post), (0.0, post)],
                    NET.stroke_width(fig.px(4.0) as u32),
                ),
            ])?;
        }
        View::Side => {
            chart.draw_series([Rectangle::new(
                [(-hl, -0.025), (hl, 0.0)],
                TABLE_EDGE.filled(),
            )])?;
            chart.draw_series([PathElement::new(
                vec![(0.0, 0.0), (0.0, s.net_height)],
                NET.stroke_width(fig.px(4.0) as u32),
            )])?;
        }
    }
    chart.draw_series([DashedPathElement::new(
        vec![(s.plane_x, ys.lo), (s.plane_x, ys.hi)],
        f64::from(fig.px(10.0)),
        f64::from(fig.px(6.0)),
        PLANE.stroke_width(fig.px(2.0) as u32),
    )])?;
    Ok(())
}

/// The true flight, the detections and the filtered track.
fn draw_measured<DB: DrawingBackend>(
    chart: &mut Chart<'_, DB, RangedCoordf64>,
    fig: &Figure,
    view: View,
    inside: &dyn Fn(&Vector3<f64>) -> bool,
) -> Result<(), PlotError> {
    let d = &fig.data;
    // Truth, dashed, broken between shots.
    let mut truth: Vec<_> = d.truth.iter().filter(|t| inside(&t.position)).collect();
    truth.sort_by_key(|t| t.stamp);
    for run in truth.chunk_by(|a, b| b.stamp - a.stamp <= TRUTH_GAP) {
        let points: Vec<(f64, f64)> = run.iter().map(|t| view.project(&t.position)).collect();
        chart.draw_series([DashedPathElement::new(
            points,
            f64::from(fig.px(9.0)),
            f64::from(fig.px(5.0)),
            TRUTH.stroke_width(fig.px(2.0) as u32),
        )])?;
    }

    // Detections by camera, rejected ones as crosses.
    let r = fig.px(2.6);
    for (source, colour) in [
        (Source::WIDE_150FPS, WIDE),
        (Source::HIGHSPEED_900FPS, HIGH_SPEED),
        (Source::UNKNOWN, UNKNOWN),
    ] {
        chart.draw_series(
            d.detections
                .iter()
                .filter(|x| camera_group(x.source) == source && !x.rejected && inside(&x.position))
                .map(|x| Circle::new(view.project(&x.position), r, colour.mix(0.75).filled())),
        )?;
    }
    chart.draw_series(
        d.detections
            .iter()
            .filter(|x| x.rejected && inside(&x.position))
            .map(|x| {
                Cross::new(
                    view.project(&x.position),
                    fig.px(5.0),
                    REJECTED.stroke_width(fig.px(2.0) as u32),
                )
            }),
    )?;

    // The filtered track(s).
    for run in track_runs(&d.estimates) {
        let points: Vec<(f64, f64)> = run
            .iter()
            .filter(|e| inside(&e.position))
            .map(|e| view.project(&e.position))
            .collect();
        chart.draw_series([PathElement::new(
            points,
            TRACK.stroke_width(fig.px(2.0) as u32),
        )])?;
    }
    Ok(())
}

/// The predicted flights, bounces and crossings.
fn draw_predicted<DB: DrawingBackend>(
    chart: &mut Chart<'_, DB, RangedCoordf64>,
    fig: &Figure,
    view: View,
    inside: &dyn Fn(&Vector3<f64>) -> bool,
) -> Result<(), PlotError> {
    let d = &fig.data;
    // Predicted flights over the track, later ones darker.
    let shown = chosen_trajectories(&d.trajectories, fig.predictions);
    let n = shown.len();
    for (k, tr) in shown.iter().enumerate() {
        let alpha = 0.35 + 0.65 * (k + 1) as f64 / n as f64;
        let style = PREDICTED.mix(alpha).stroke_width(fig.px(2.0) as u32);
        if let Some(start) = tr.positions.first().filter(|p| inside(p)) {
            let dot = Circle::new(
                view.project(start),
                fig.px(4.0),
                PREDICTED.mix(alpha).filled(),
            );
            chart.draw_series([dot])?;
        }
        for run in tr
            .positions
            .split(|p| !inside(p))
            .filter(|run| run.len() > 1)
        {
            let points: Vec<(f64, f64)> = run.iter().map(|p| view.project(p)).collect();
            chart.draw_series([PathElement::new(points, style)])?;
        }
    }

    // Predicted bounces and crossings, later predictions darker (drawn last, on top).
    let (first, last) = stamp_span(d).unwrap_or((0, 1));
    let age = |stamp: i64| ((stamp - first) as f64 / (last - first).max(1) as f64).clamp(0.0, 1.0);
    let mut intercepts: Vec<_> = d.intercepts.iter().collect();
    intercepts.sort_by_key(|i| i.stamp);
    chart.draw_series(intercepts.iter().filter_map(|i| {
        let b = i.bounce.filter(|b| inside(b))?;
        let colour = blend(BOUNCE_EARLY, BOUNCE_LATE, age(i.stamp));
        Some(TriangleMarker::new(
            view.project(&b),
            fig.px(5.0),
            colour.filled(),
        ))
    }))?;
    let half = fig.px(3.5);
    chart.draw_series(intercepts.iter().filter_map(|i| {
        let c = i.crossing.filter(|c| inside(&c.position))?;
        let colour = blend(CROSSING_EARLY, CROSSING_LATE, age(i.stamp));
        Some(
            EmptyElement::at(view.project(&c.position))
                + Rectangle::new([(-half, -half), (half, half)], colour.filled()),
        )
    }))?;
    Ok(())
}

/// Up to `count` flights, evenly spread over time, always with the last.
fn chosen_trajectories(all: &[PlotTrajectory], count: usize) -> Vec<&PlotTrajectory> {
    let mut sorted: Vec<&PlotTrajectory> = all.iter().collect();
    sorted.sort_by_key(|t| (t.stamp, t.track_id));
    let n = sorted.len();
    if count == 0 || n == 0 {
        return Vec::new();
    }
    if n <= count {
        return sorted;
    }
    let mut picked: Vec<usize> = (1..=count).map(|k| k * (n - 1) / count).collect();
    picked.dedup();
    picked
        .into_iter()
        .filter_map(|k| sorted.get(k).copied())
        .collect()
}

/// The estimates sorted by (track, stamp), one run per track.
fn track_runs(estimates: &[PlotEstimate]) -> Vec<Vec<&PlotEstimate>> {
    let mut sorted: Vec<&PlotEstimate> = estimates.iter().collect();
    sorted.sort_by_key(|e| (e.track_id, e.stamp));
    sorted
        .chunk_by(|a, b| a.track_id == b.track_id)
        .map(<[_]>::to_vec)
        .collect()
}

fn blend(a: RGBColor, b: RGBColor, f: f64) -> RGBColor {
    let mix = |x: u8, y: u8| (f64::from(x) + (f64::from(y) - f64::from(x)) * f).round() as u8;
    RGBColor(mix(a.0, b.0), mix(a.1, b.1), mix(a.2, b.2))
}

// ---------------------------------------------------------------- over time

/// The selection's time axis [s since the origin].
fn time_span(fig: &Figure) -> Span {
    let mut span = Span::new();
    if let Some((a, b)) = stamp_span(&fig.data) {
        span.add(fig.t(a));
        span.add(fig.t(b));
    }
    let pad = 0.02 * span.width().max(0.01);
    span.padded(pad, (0.0, 1.0))
}

/// Shades the runs of coasting estimates.
fn shade_coasting<DB: DrawingBackend, Y: Ranged<ValueType = f64>>(
    chart: &mut Chart<'_, DB, Y>,
    fig: &Figure,
    (lo, hi): (f64, f64),
) -> Result<(), PlotError> {
    for run in track_runs(&fig.data.estimates) {
        for coast in run
            .chunk_by(|a, b| a.status == b.status)
            .filter(|c| c.first().is_some_and(|e| e.status == TrackStatus::Coasting))
        {
            if let (Some(a), Some(b)) = (coast.first(), coast.last()) {
                chart.draw_series([Rectangle::new(
                    [(fig.t(a.stamp), lo), (fig.t(b.stamp), hi)],
                    COASTING.filled(),
                )])?;
            }
        }
    }
    Ok(())
}

/// One line per track of `value(estimate)`.
fn estimate_lines<DB: DrawingBackend, Y: Ranged<ValueType = f64>>(
    chart: &mut Chart<'_, DB, Y>,
    fig: &Figure,
    colour: RGBColor,
    value: impl Fn(&PlotEstimate) -> f64,
) -> Result<(), PlotError> {
    for run in track_runs(&fig.data.estimates) {
        let points: Vec<(f64, f64)> = run
            .iter()
            .map(|e| (fig.t(e.stamp), value(e)))
            .filter(|(_, v)| v.is_finite())
            .collect();
        chart.draw_series([PathElement::new(
            points,
            colour.stroke_width(fig.px(2.0) as u32),
        )])?;
    }
    Ok(())
}

/// The truth's `value`, dashed, broken between shots.
fn truth_lines<DB: DrawingBackend, Y: Ranged<ValueType = f64>>(
    chart: &mut Chart<'_, DB, Y>,
    fig: &Figure,
    colour: RGBColor,
    value: impl Fn(&super::data::PlotTruth) -> f64,
) -> Result<(), PlotError> {
    let mut truth: Vec<_> = fig.data.truth.iter().collect();
    truth.sort_by_key(|t| t.stamp);
    for run in truth.chunk_by(|a, b| b.stamp - a.stamp <= TRUTH_GAP) {
        let points: Vec<(f64, f64)> = run
            .iter()
            .map(|t| (fig.t(t.stamp), value(t)))
            .filter(|(_, v)| v.is_finite())
            .collect();
        chart.draw_series([DashedPathElement::new(
            points,
            f64::from(fig.px(8.0)),
            f64::from(fig.px(5.0)),
            colour.stroke_width(fig.px(2.0) as u32),
        )])?;
    }
    Ok(())
}

fn draw_speed<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    fig: &Figure,
) -> Result<(), PlotError> {
    let d = &fig.data;
    let mut keys = vec![("estimate".to_string(), Glyph::Line(TRACK))];
    if !d.truth.is_empty() {
        keys.push(("truth".to_string(), Glyph::Dashed(TRUTH)));
    }
    let chart_area = panel(area, fig, "Speed |v|", &keys)?;
    let mut span = Span::new();
    span.add(0.0);
    d.estimates.iter().for_each(|e| span.add(e.velocity.norm()));
    d.truth.iter().for_each(|t| span.add(t.velocity.norm()));
    let ys = Span {
        lo: 0.0,
        hi: (span.hi * 1.1).max(1.0),
    };
    let mut chart = chart_on(&chart_area, fig, time_span(fig).range(), ys.range())?;
    draw_mesh(&mut chart, fig, ("t [s]", "|v| [m/s]"))?;
    shade_coasting(&mut chart, fig, (ys.lo, ys.hi))?;
    truth_lines(&mut chart, fig, TRUTH, |t| t.velocity.norm())?;
    estimate_lines(&mut chart, fig, TRACK, |e| e.velocity.norm())?;
    Ok(())
}

fn component_keys(fig: &Figure, symbol: &str) -> Vec<(String, Glyph)> {
    let mut keys: Vec<(String, Glyph)> = ["x", "y", "z"]
        .iter()
        .zip(AXIS)
        .map(|(axis, c)| (format!("{symbol}{axis}"), Glyph::Line(c)))
        .collect();
    if !fig.data.truth.is_empty() {
        keys.push(("truth".to_string(), Glyph::Dashed(TEXT_GREY)));
    }
    keys
}

fn draw_spin<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    fig: &Figure,
) -> Result<(), PlotError> {
    let d = &fig.data;
    let chart_area = panel(area, fig, "Spin ω", &component_keys(fig, "ω"))?;
    let mut span = Span::new();
    span.add(0.0);
    for e in &d.estimates {
        e.spin.iter().for_each(|v| span.add(*v));
    }
    for t in &d.truth {
        t.spin.iter().for_each(|v| span.add(*v));
    }
    let ys = span.padded(0.08 * span.width().max(10.0), (-100.0, 100.0));
    let mut chart = chart_on(&chart_area, fig, time_span(fig).range(), ys.range())?;
    draw_mesh(&mut chart, fig, ("t [s]", "ω [rad/s]"))?;
    shade_coasting(&mut chart, fig, (ys.lo, ys.hi))?;
    for (i, c) in AXIS.iter().enumerate() {
        truth_lines(&mut chart, fig, *c, |t| t.spin[i])?;
    }
    for (i, c) in AXIS.iter().enumerate() {
        estimate_lines(&mut chart, fig, *c, |e| e.spin[i])?;
    }
    Ok(())
}

fn draw_sigma<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    fig: &Figure,
) -> Result<(), PlotError> {
    let d = &fig.data;
    let mut keys = component_keys(fig, "σ");
    keys.retain(|(label, _)| label != "truth");
    let chart_area = panel(area, fig, "Position uncertainty (1 σ)", &keys)?;
    let mut span = Span::new();
    for e in &d.estimates {
        e.position_sigma
            .iter()
            .filter(|v| **v > 0.0)
            .for_each(|v| span.add(v * 1e3));
    }
    let (lo, hi) = if span.lo > span.hi {
        (0.1, 10.0)
    } else {
        let lo = (span.lo * 0.7).max(1e-3);
        (lo, (span.hi * 1.4).max(lo * 10.0))
    };
    let y = (lo..hi).log_scale().with_key_points(log_ticks(lo, hi));
    let mut chart = chart_on(&chart_area, fig, time_span(fig).range(), y)?;
    draw_mesh(&mut chart, fig, ("t [s]", "σ [mm] (log)"))?;
    shade_coasting(&mut chart, fig, (lo, hi))?;
    for (i, c) in AXIS.iter().enumerate() {
        estimate_lines(&mut chart, fig, *c, |e| {
            (e.position_sigma[i] * 1e3).clamp(lo, hi)
        })?;
    }
    Ok(())
}

/// Ticks at 1, 2 and 5 times the powers of ten in [lo, hi] (only the powers over many decades).
fn log_ticks(lo: f64, hi: f64) -> Vec<f64> {
    let (a, b) = (lo.log10().floor() as i32, hi.log10().ceil() as i32);
    let ticks = |mantissas: &[f64]| -> Vec<f64> {
        (a..=b)
            .flat_map(|k| mantissas.iter().map(move |m| m * 10f64.powi(k)))
            .filter(|v| (lo..=hi).contains(v))
            .collect()
    };
    let dense = ticks(&[1.0, 2.0, 5.0]);
    if dense.len() <= 8 {
        dense
    } else {
        ticks(&[1.0])
    }
}

// ---------------------------------------------------------------- legend

fn legend_entries(fig: &Figure) -> Vec<(String, Glyph)> {
    let d = &fig.data;
    let has = |s: Source| {
        d.detections
            .iter()
            .any(|x| camera_group(x.source) == s && !x.rejected)
    };
    let mut out = Vec::new();
    let mut push = |label: &str, glyph: Glyph| out.push((label.to_string(), glyph));
    if has(Source::WIDE_150FPS) {
        push("150 fps detection", Glyph::Dot(WIDE));
    }
    if has(Source::HIGHSPEED_900FPS) {
        push("900 fps detection", Glyph::Dot(HIGH_SPEED));
    }
    if has(Source::UNKNOWN) {
        push("detection, other camera", Glyph::Dot(UNKNOWN));
    }
    if d.detections.iter().any(|x| x.rejected) {
        push("rejected detection", Glyph::Cross(REJECTED));
    }
    if !d.estimates.is_empty() {
        push("filtered track", Glyph::Line(TRACK));
    }
    if !d.trajectories.is_empty() && fig.predictions > 0 {
        push(
            "predicted flight from • (later: darker)",
            Glyph::Line(PREDICTED),
        );
    }
    if d.intercepts.iter().any(|i| i.crossing.is_some()) {
        push(
            "predicted crossing (later: darker)",
            Glyph::Square(CROSSING_LATE),
        );
    }
    if d.intercepts.iter().any(|i| i.bounce.is_some()) {
        push(
            "predicted bounce (later: darker)",
            Glyph::Triangle(BOUNCE_LATE),
        );
    }
    if !d.truth.is_empty() {
        push("truth", Glyph::Dashed(TRUTH));
    }
    push("table and net", Glyph::Table);
    let plane = format!("hitting plane x = {:.2} m", d.scene.plane_x);
    out.push((plane, Glyph::Dashed(PLANE)));
    if d.estimates
        .iter()
        .any(|e| e.status == TrackStatus::Coasting)
    {
        out.push(("coasting".to_string(), Glyph::Band(COASTING)));
    }
    out
}

/// One legend row: its entries with their x offsets [px], and its width [px].
struct Row {
    entries: Vec<(i32, String, Glyph)>,
    width: i32,
}

fn legend_style(fig: &Figure) -> TextStyle<'static> {
    fig.font(16.0)
        .color(&BLACK)
        .pos(Pos::new(HPos::Left, VPos::Center))
}

/// Lays the entries out in centred rows no wider than the figure.
fn legend_rows<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    fig: &Figure,
    entries: &[(String, Glyph)],
    width: i32,
) -> Result<Vec<Row>, PlotError> {
    let style = legend_style(fig);
    let (glyph_w, gap) = (fig.px(34), fig.px(26));
    let usable = width - 2 * fig.px(20);
    let mut rows: Vec<Row> = Vec::new();
    let mut row = Row {
        entries: Vec::new(),
        width: 0,
    };
    for (label, glyph) in entries {
        let (tw, _) = area.estimate_text_size(label, &style)?;
        let w = glyph_w + tw as i32;
        let x = if row.entries.is_empty() {
            0
        } else {
            row.width + gap
        };
        if !row.entries.is_empty() && x + w > usable {
            rows.push(row);
            row = Row {
                entries: vec![(0, label.clone(), *glyph)],
                width: w,
            };
        } else {
            row.entries.push((x, label.clone(), *glyph));
            row.width = x + w;
        }
    }
    if !row.entries.is_empty() {
        rows.push(row);
    }
    Ok(rows)
}

fn draw_legend<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    fig: &Figure,
    rows: &[Row],
) -> Result<(), PlotError> {
    let (w, h) = area.dim_in_pixel();
    area.draw(&PathElement::new(
        vec![(fig.px(20), 1), (w as i32 - fig.px(20), 1)],
        GRID.stroke_width(1),
    ))?;
    let style = legend_style(fig);
    let row_h = fig.px(30);
    let top = (h as i32 - row_h * rows.len() as i32) / 2;
    for (k, row) in rows.iter().enumerate() {
        let y = top + row_h * k as i32 + row_h / 2;
        let left = (w as i32 - row.width) / 2;
        for (x, label, glyph) in &row.entries {
            draw_glyph(area, fig, *glyph, (left + x + fig.px(12), y))?;
            area.draw(&Text::new(
                label.clone(),
                (left + x + fig.px(34), y),
                style.clone(),
            ))?;
        }
    }
    Ok(())
}

/// A legend symbol centred at `(x, y)` [px], about 24 px wide.
fn draw_glyph<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    fig: &Figure,
    glyph: Glyph,
    (x, y): (i32, i32),
) -> Result<(), PlotError> {
    let half = fig.px(12);
    let width = fig.px(2.0) as u32;
    match glyph {
        Glyph::Dot(c) => area.draw(&Circle::new((x, y), fig.px(4.0), c.filled()))?,
        Glyph::Cross(c) => area.draw(&Cross::new((x, y), fig.px(5.0), c.stroke_width(width)))?,
        Glyph::Line(c) => area.draw(&PathElement::new(
            vec![(x - half, y), (x + half, y)],
            c.stroke_width(fig.px(3.0) as u32),
        ))?,
        Glyph::Dashed(c) => area.draw(&DashedPathElement::new(
            vec![(x - half, y), (x + half, y)],
            f64::from(fig.px(7.0)),
            f64::from(fig.px(4.0)),
            c.stroke_width(fig.px(3.0) as u32),
        ))?,
        Glyph::Square(c) => {
            let s = fig.px(4.5);
            area.draw(&Rectangle::new(
                [(x - s, y - s), (x + s, y + s)],
                c.filled(),
            ))?
        }
        Glyph::Triangle(c) => area.draw(&TriangleMarker::new((x, y), fig.px(6.0), c.filled()))?,
        Glyph::Table => {
            let (a, b) = ((x - half, y - fig.px(7.0)), (x + half, y + fig.px(7.0)));
            area.draw(&Rectangle::new([a, b], TABLE_FILL.filled()))?;
            area.draw(&Rectangle::new([a, b], TABLE_EDGE.stroke_width(width)))?;
            area.draw(&PathElement::new(
                vec![(x, a.1 - fig.px(2.0)), (x, b.1 + fig.px(2.0))],
                NET.stroke_width(fig.px(3.0) as u32),
            ))?;
        }
        Glyph::Band(c) => {
            let (a, b) = ((x - half, y - fig.px(8.0)), (x + half, y + fig.px(8.0)));
            area.draw(&Rectangle::new([a, b], c.filled()))?;
            area.draw(&Rectangle::new([a, b], GRID.stroke_width(1)))?;
        }
    }
    Ok(())
}
