//! Pictures of what the estimator saw (feature `plot`): one figure per track or time window with
//! the top view (x-y) and side view (x-z) of the table (detections by camera, rejected ones,
//! the filtered track, predicted flights, predicted crossings of the hitting plane and bounces,
//! the truth when known), speed, spin and position uncertainty over time, and a legend.
//!
//! Pure rendering: the caller gathers [`PlotData`] (e.g. with [`PlotData::record`] around
//! `Estimator::handle`) and writes the returned bytes. [`render_svg`] and [`render_png`] use
//! plotters' SVG and bitmap backends with the DejaVu Sans font compiled in (crate `dejavu`), so
//! nothing needs to be installed and the output is the same on every machine.

mod calibration;
mod data;
mod rebound;
mod render;
mod rubber;

use std::sync::OnceLock;

use plotters::coord::Shift;
use plotters::prelude::*;
use plotters::style::{FontStyle, register_font};

use crate::config::Config;
use crate::physics::RacketModel;

pub use rebound::ChartOptions;

pub use data::{
    PlotCrossing, PlotData, PlotDetection, PlotEstimate, PlotIntercept, PlotTrajectory, PlotTruth,
    Scene, Selection, TrackSpan,
};

/// The font family the figures use; the bundled DejaVu Sans is registered under this name.
const FONT: &str = "sans-serif";

/// Draws a chart's legend in a light framed box at `position`, its labels `font_px` high.
fn draw_legend<'a, DB: DrawingBackend + 'a, CT: CoordTranslate>(
    chart: &mut ChartContext<'a, DB, CT>,
    position: SeriesLabelPosition,
    font_px: u32,
) -> Result<(), DrawingAreaErrorKind<DB::ErrorType>> {
    chart
        .configure_series_labels()
        .position(position)
        .label_font((FONT, font_px))
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK.mix(0.3))
        .draw()
}

/// Smallest figure, width x height [px]: below it the labels are too small to read.
pub const MIN_SIZE: (u32, u32) = (800, 500);
/// Largest figure, width x height [px] (a PNG buffer of 192 MB).
pub const MAX_SIZE: (u32, u32) = (8000, 8000);

/// Why a figure could not be drawn.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum PlotError {
    /// The selection picked no detection and no estimate.
    #[error("nothing to plot: the selection ({selection}) contains no detection and no estimate")]
    EmptySelection {
        /// The selection, described.
        selection: String,
    },
    /// The selected track has no estimate in the data.
    #[error("track {track_id} is not in the data (tracks: {known:?})")]
    UnknownTrack {
        /// The track asked for.
        track_id: u32,
        /// The tracks there are.
        known: Vec<u32>,
    },
    /// The time window ends before it starts.
    #[error("the time window starts at {start} ns, after its end at {end} ns")]
    InvalidWindow {
        /// Start [ns].
        start: i64,
        /// End [ns].
        end: i64,
    },
    /// The figure size is outside [`MIN_SIZE`]..=[`MAX_SIZE`].
    #[error(
        "figure size {width}x{height} px is outside {}x{} to {}x{} px",
        MIN_SIZE.0, MIN_SIZE.1, MAX_SIZE.0, MAX_SIZE.1
    )]
    BadSize {
        /// Width [px].
        width: u32,
        /// Height [px].
        height: u32,
    },
    /// The bundled font could not be parsed.
    #[error("the bundled DejaVu Sans font could not be loaded")]
    Font,
    /// The drawing backend failed.
    #[error("drawing failed: {0}")]
    Drawing(String),
    /// The PNG encoder failed.
    #[error("PNG encoding failed: {0}")]
    Png(String),
}

impl<E: std::error::Error + Send + Sync> From<DrawingAreaErrorKind<E>> for PlotError {
    fn from(e: DrawingAreaErrorKind<E>) -> Self {
        Self::Drawing(e.to_string())
    }
}

/// How to draw a figure.
#[derive(Debug, Clone, PartialEq)]
pub struct PlotOptions {
    /// Figure width [px]. Default 1600.
    pub width: u32,
    /// Figure height [px]. Default 1000.
    pub height: u32,
    /// How many predicted flights to draw, evenly spread over the selection and always including
    /// the last. Default 3.
    pub predictions: usize,
    /// The zero of the time axes [ns]; `None`: the first stamp of the whole data (not only of
    /// the selection), so figures of one recording share their clock.
    pub time_origin: Option<i64>,
    /// The title; `None`: the track (or window) and its time span.
    pub title: Option<String>,
}

impl Default for PlotOptions {
    fn default() -> Self {
        Self {
            width: 1600,
            height: 1000,
            predictions: 3,
            time_origin: None,
            title: None,
        }
    }
}

/// The figure of `selection` as an SVG document.
pub fn render_svg(
    data: &PlotData,
    selection: &Selection,
    options: &PlotOptions,
) -> Result<String, PlotError> {
    let figure = prepare(data, selection, options)?;
    let mut svg = String::new();
    {
        let root =
            SVGBackend::with_string(&mut svg, (options.width, options.height)).into_drawing_area();
        render::draw(&root, &figure)?;
        root.present()?;
    }
    Ok(svg)
}

/// The figure of `selection` as an encoded PNG image (8-bit RGB).
pub fn render_png(
    data: &PlotData,
    selection: &Selection,
    options: &PlotOptions,
) -> Result<Vec<u8>, PlotError> {
    let figure = prepare(data, selection, options)?;
    encode_png((options.width, options.height), |root| {
        render::draw(root, &figure)
    })
}

/// The racket's rebound chart (e along the long axis and against impact speed, free and held;
/// like Kawazoe & Suzuki Fig. 19 and 20) as an SVG document.
pub fn render_rebound_chart_svg(
    model: &RacketModel,
    config: &Config,
    options: &ChartOptions,
) -> Result<String, PlotError> {
    check_size(options.width, options.height)?;
    register_fonts()?;
    let chart = rebound::ReboundChart::new(model, config);
    let mut svg = String::new();
    {
        let root =
            SVGBackend::with_string(&mut svg, (options.width, options.height)).into_drawing_area();
        chart.draw(&root)?;
        root.present()?;
    }
    Ok(svg)
}

/// The racket's rebound chart as an encoded PNG image (8-bit RGB).
pub fn render_rebound_chart_png(
    model: &RacketModel,
    config: &Config,
    options: &ChartOptions,
) -> Result<Vec<u8>, PlotError> {
    check_size(options.width, options.height)?;
    register_fonts()?;
    let chart = rebound::ReboundChart::new(model, config);
    encode_png((options.width, options.height), |root| chart.draw(root))
}

/// The calibration chart (fitted C_D(Sp) and C_M(Sp) against the starting curves, the Sp range
/// of the data, residuals per flight) as an SVG document.
pub fn render_calibration_svg(
    calibration: &crate::offline::calibrate::Calibration,
    start: &Config,
    options: &ChartOptions,
) -> Result<String, PlotError> {
    check_size(options.width, options.height)?;
    register_fonts()?;
    let mut svg = String::new();
    {
        let root =
            SVGBackend::with_string(&mut svg, (options.width, options.height)).into_drawing_area();
        calibration::draw(&root, calibration, start)?;
        root.present()?;
    }
    Ok(svg)
}

/// The calibration chart as an encoded PNG image (8-bit RGB).
pub fn render_calibration_png(
    calibration: &crate::offline::calibrate::Calibration,
    start: &Config,
    options: &ChartOptions,
) -> Result<Vec<u8>, PlotError> {
    check_size(options.width, options.height)?;
    register_fonts()?;
    encode_png((options.width, options.height), |root| {
        calibration::draw(root, calibration, start)
    })
}

/// The rubber calibration's chart (predicted against measured outgoing velocity and spin, by
/// the starting and the calibrated configuration) as an SVG document or a PNG image (`png`).
pub fn render_rubber_calibration(
    calibration: &crate::offline::rebound_calibration::RubberCalibration,
    options: &ChartOptions,
    png: bool,
) -> Result<Vec<u8>, PlotError> {
    check_size(options.width, options.height)?;
    register_fonts()?;
    if png {
        return encode_png((options.width, options.height), |root| {
            rubber::draw(root, calibration)
        });
    }
    let mut svg = String::new();
    {
        let root =
            SVGBackend::with_string(&mut svg, (options.width, options.height)).into_drawing_area();
        rubber::draw(&root, calibration)?;
        root.present()?;
    }
    Ok(svg.into_bytes())
}

/// Draws on an RGB bitmap of `size` and encodes it as PNG.
fn encode_png(
    (width, height): (u32, u32),
    draw: impl FnOnce(&DrawingArea<BitMapBackend<'_>, Shift>) -> Result<(), PlotError>,
) -> Result<Vec<u8>, PlotError> {
    let mut pixels = vec![0u8; width as usize * height as usize * 3];
    {
        let root = BitMapBackend::with_buffer(&mut pixels, (width, height)).into_drawing_area();
        draw(&root)?;
        root.present()?;
    }
    let png_error = |e: png::EncodingError| PlotError::Png(e.to_string());
    let mut bytes = Vec::new();
    let mut encoder = png::Encoder::new(&mut bytes, width, height);
    encoder.set_color(png::ColorType::Rgb);
    encoder.set_depth(png::BitDepth::Eight);
    let mut writer = encoder.write_header().map_err(png_error)?;
    writer.write_image_data(&pixels).map_err(png_error)?;
    writer.finish().map_err(png_error)?;
    Ok(bytes)
}

/// Refuses figure sizes outside [`MIN_SIZE`]..[`MAX_SIZE`].
fn check_size(width: u32, height: u32) -> Result<(), PlotError> {
    if !(MIN_SIZE.0..=MAX_SIZE.0).contains(&width) || !(MIN_SIZE.1..=MAX_SIZE.1).contains(&height) {
        return Err(PlotError::BadSize { width, height });
    }
    Ok(())
}

/// Checks the size, registers the font, selects the data and writes the titles.
fn prepare(
    data: &PlotData,
    selection: &Selection,
    options: &PlotOptions,
) -> Result<render::Figure, PlotError> {
    let (width, height) = (options.width, options.height);
    check_size(width, height)?;
    register_fonts()?;
    let selected = data.select(selection)?;
    let origin = options
        .time_origin
        .or_else(|| data.first_stamp())
        .unwrap_or(0);
    Ok(render::Figure::new(
        selected,
        selection,
        origin,
        options.title.clone(),
        options.predictions,
        (width, height),
    ))
}

/// Registers the bundled DejaVu Sans (regular and bold) as [`FONT`], once per process.
fn register_fonts() -> Result<(), PlotError> {
    static REGISTERED: OnceLock<bool> = OnceLock::new();
    let ok = *REGISTERED.get_or_init(|| {
        register_font(FONT, FontStyle::Normal, dejavu::sans::regular()).is_ok()
            && register_font(FONT, FontStyle::Bold, dejavu::sans::bold()).is_ok()
    });
    if ok { Ok(()) } else { Err(PlotError::Font) }
}
