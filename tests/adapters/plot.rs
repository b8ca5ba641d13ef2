//! Figures of a simulated session run through the estimator: every layer is in the SVG, the PNG
//! decodes to the requested size, selections pick what they say, an empty selection is an error,
//! and the same input gives the same bytes. Writes `target/plot-test/track.{svg,png}` to look at.
#![cfg(feature = "plot")]
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    clippy::panic,
    reason = "test code: fail loudly"
)]

use std::path::PathBuf;
use std::sync::OnceLock;

use ttball::config::Config;
use ttball::eval::sim::{SimOptions, simulate};
use ttball::online::estimator::Estimator;
use ttball::plot::{
    PlotData, PlotError, PlotOptions, PlotTrajectory, PlotTruth, Selection, render_png, render_svg,
};

/// A predicted flight is kept every this many detections.
const TRAJECTORY_EVERY: usize = 25;

/// Three simulated shots (both cameras), every detection through `Estimator::handle` in arrival
/// order, with the truth at each detection and a predicted flight every 25 detections.
fn data() -> &'static PlotData {
    static DATA: OnceLock<PlotData> = OnceLock::new();
    DATA.get_or_init(|| {
        let config = Config::default();
        let session = simulate(
            &config,
            &SimOptions {
                shots: 3,
                seed: 7,
                ..SimOptions::default()
            },
        )
        .expect("the session simulates");
        let mut estimator = Estimator::new(&config);
        let mut data = PlotData::new(&config);
        for (k, sim) in session.stream.iter().enumerate() {
            let output = estimator.handle(&sim.detection);
            data.record(&sim.detection, &output);
            data.truth
                .push(PlotTruth::new(sim.detection.stamp, &sim.truth));
            if k % TRAJECTORY_EVERY != 0 {
                continue;
            }
            if let (Some(e), Some((stamp, trajectory))) = (
                output.estimate,
                estimator.predicted_trajectory(0.01, config.prediction.horizon),
            ) {
                data.trajectories
                    .push(PlotTrajectory::new(stamp, e.track_id, &trajectory));
            }
        }
        data
    })
}

/// The track with the most estimates.
fn main_track() -> u32 {
    data()
        .tracks()
        .iter()
        .max_by_key(|t| t.estimates)
        .expect("at least one track")
        .track_id
}

fn count(haystack: &str, needle: &str) -> usize {
    haystack.matches(needle).count()
}

fn out_dir() -> PathBuf {
    let tmp = PathBuf::from(env!("CARGO_TARGET_TMPDIR"));
    let dir = tmp
        .parent()
        .map_or(tmp.clone(), |p| p.to_path_buf())
        .join("plot-test");
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// Width and height from the IHDR chunk, which must follow the 8-byte signature.
fn png_size(bytes: &[u8]) -> (u32, u32) {
    assert_eq!(&bytes[..8], b"\x89PNG\r\n\x1a\n", "PNG signature");
    assert_eq!(&bytes[12..16], b"IHDR");
    let be = |b: &[u8]| u32::from_be_bytes([b[0], b[1], b[2], b[3]]);
    (be(&bytes[16..20]), be(&bytes[20..24]))
}

#[test]
fn tracks_are_listed_in_time_order_with_their_spans() {
    let tracks = data().tracks();
    assert!(!tracks.is_empty());
    for t in &tracks {
        assert!(t.first <= t.last);
        assert!(t.estimates > 0);
        let n = data()
            .estimates
            .iter()
            .filter(|e| e.track_id == t.track_id)
            .count();
        assert_eq!(n, t.estimates);
    }
    assert!(tracks.windows(2).all(|w| w[0].first <= w[1].first));
    let total: usize = tracks.iter().map(|t| t.estimates).sum();
    assert_eq!(total, data().estimates.len());
    // A simulated shot lasts about a second; its main track covers a good part of it.
    let main = tracks.iter().find(|t| t.track_id == main_track()).unwrap();
    assert!(main.duration() > 0.3 && main.duration() < 2.0, "{main:?}");
}

#[test]
fn a_track_selection_keeps_that_track_and_the_detections_of_its_span() {
    let id = main_track();
    let span = data()
        .tracks()
        .into_iter()
        .find(|t| t.track_id == id)
        .unwrap();
    let picked = data().select(&Selection::track(id)).unwrap();
    assert!(picked.estimates.iter().all(|e| e.track_id == id));
    assert_eq!(picked.estimates.len(), span.estimates);
    assert!(picked.intercepts.iter().all(|i| i.track_id == id));
    assert!(!picked.trajectories.is_empty());
    assert!(picked.trajectories.iter().all(|t| t.track_id == id));
    let lead = span.first - Selection::TRACK_LEAD;
    assert!(!picked.detections.is_empty());
    assert!(
        picked
            .detections
            .iter()
            .all(|d| d.stamp >= lead && d.stamp <= span.last)
    );
    assert!(picked.detections.len() < data().detections.len());
    assert!(!picked.truth.is_empty());

    // A window of 100 ms in the middle of the track.
    let mid = (span.first + span.last) / 2;
    let window = data()
        .select(&Selection::window(mid, mid + 100_000_000))
        .unwrap();
    assert!(!window.estimates.is_empty());
    assert!(
        window
            .detections
            .iter()
            .all(|d| (mid..=mid + 100_000_000).contains(&d.stamp))
    );
    assert!(window.estimates.len() < picked.estimates.len());
}

#[test]
fn the_svg_has_every_layer_axis_and_legend_entry() {
    let svg = render_svg(
        data(),
        &Selection::track(main_track()),
        &PlotOptions::default(),
    )
    .unwrap();
    assert!(svg.starts_with("<svg"), "{}", &svg[..80.min(svg.len())]);
    assert!(svg.trim_end().ends_with("</svg>"));
    assert_eq!(count(&svg, "<svg"), 1);
    assert_eq!(count(&svg, "<text"), count(&svg, "</text>"));
    assert!(svg.contains(r#"width="1600""#) && svg.contains(r#"height="1000""#));
    for text in [
        "150 fps detection",
        "900 fps detection",
        "filtered track",
        "predicted flight",
        "predicted crossing",
        "predicted bounce",
        "truth",
        "table and net",
        "hitting plane x = -1.60 m",
        "Top view",
        "Side view",
        "x [m]",
        "y [m]",
        "z [m]",
        "t [s]",
        "|v| [m/s]",
        "ω [rad/s]",
        "σ [mm] (log)",
        &format!("Track {}", main_track()),
    ] {
        assert!(svg.contains(text), "the SVG lacks {text:?}");
    }
    // Track, truth, predicted flights and the time series are lines; detections are circles.
    assert!(
        count(&svg, "<polyline") > 20,
        "{}",
        count(&svg, "<polyline")
    );
    assert!(count(&svg, "<circle") > 100, "{}", count(&svg, "<circle"));
    // Rejected detections would be in the legend only when there are some.
    let rejected = data()
        .select(&Selection::track(main_track()))
        .unwrap()
        .detections
        .iter()
        .any(|d| d.rejected);
    assert_eq!(svg.contains("rejected detection"), rejected);
}

#[test]
fn the_png_decodes_to_the_requested_size() {
    let options = PlotOptions {
        width: 1200,
        height: 750,
        ..PlotOptions::default()
    };
    let bytes = render_png(data(), &Selection::track(main_track()), &options).unwrap();
    assert_eq!(png_size(&bytes), (1200, 750));
    let decoder = png::Decoder::new(std::io::Cursor::new(bytes.as_slice()));
    let mut reader = decoder.read_info().unwrap();
    let mut pixels = vec![0; reader.output_buffer_size().unwrap()];
    let info = reader.next_frame(&mut pixels).unwrap();
    assert_eq!((info.width, info.height), (1200, 750));
    assert_eq!(info.color_type, png::ColorType::Rgb);
    let pixels = &pixels[..info.buffer_size()];
    // Mostly white paper with ink on it: some dark (text, track) and some coloured pixels.
    let px: Vec<&[u8]> = pixels.chunks(3).collect();
    let white = px.iter().filter(|p| p.iter().all(|c| *c == 255)).count();
    let dark = px.iter().filter(|p| p.iter().all(|c| *c < 80)).count();
    let orange = px
        .iter()
        .filter(|p| p[0] > 200 && p[1] > 90 && p[1] < 170 && p[2] < 80)
        .count();
    let n = px.len();
    assert!(
        white > n / 2 && white < n * 97 / 100,
        "white {white} of {n}"
    );
    assert!(dark > n / 200, "dark {dark} of {n}");
    assert!(orange > 100, "900 fps detections: {orange} orange pixels");
}

#[test]
fn an_empty_or_impossible_selection_is_an_error_not_a_panic() {
    let options = PlotOptions::default();
    let before = data().first_stamp().unwrap() - 10_000_000_000;
    let empty = Selection::window(before, before + 1_000_000);
    assert!(matches!(
        render_svg(data(), &empty, &options),
        Err(PlotError::EmptySelection { .. })
    ));
    assert!(matches!(
        render_png(data(), &empty, &options),
        Err(PlotError::EmptySelection { .. })
    ));
    let nothing = PlotData::new(&Config::default());
    let err = render_svg(&nothing, &Selection::all(), &options).unwrap_err();
    assert!(err.to_string().contains("nothing to plot"), "{err}");
    assert!(matches!(
        render_svg(data(), &Selection::track(9999), &options),
        Err(PlotError::UnknownTrack { track_id: 9999, .. })
    ));
    assert!(matches!(
        render_svg(data(), &Selection::window(10, 5), &options),
        Err(PlotError::InvalidWindow { start: 10, end: 5 })
    ));
    let tiny = PlotOptions {
        width: 100,
        height: 100,
        ..PlotOptions::default()
    };
    let err = render_png(data(), &Selection::all(), &tiny).unwrap_err();
    assert_eq!(
        err,
        PlotError::BadSize {
            width: 100,
            height: 100
        }
    );
    assert!(err.to_string().contains("800x500"), "{err}");
}

#[test]
fn detections_alone_and_odd_values_still_draw() {
    // No estimates, a non-finite and a far-away detection: drawn without them, no panic.
    let mut data = PlotData::new(&Config::default());
    data.detections = self::data().detections[..40].to_vec();
    data.detections[3].position.x = f64::NAN;
    data.detections[4].position.y = 1e6;
    let svg = render_svg(&data, &Selection::all(), &PlotOptions::default()).unwrap();
    assert!(svg.contains("Detections"));
    assert!(!svg.contains("NaN"));
    assert!(!svg.contains("filtered track"));
}

#[test]
fn the_smallest_and_a_square_figure_draw() {
    let selection = Selection::track(main_track());
    for (width, height) in [ttball::plot::MIN_SIZE, (1000, 1000)] {
        let options = PlotOptions {
            width,
            height,
            ..PlotOptions::default()
        };
        let png = render_png(data(), &selection, &options).unwrap();
        assert_eq!(png_size(&png), (width, height));
        std::fs::write(out_dir().join(format!("track-{width}x{height}.png")), &png).unwrap();
    }
}

#[test]
fn rendering_is_deterministic() {
    let selection = Selection::track(main_track());
    let options = PlotOptions {
        width: 800,
        height: 500,
        ..PlotOptions::default()
    };
    let a = render_svg(data(), &selection, &options).unwrap();
    let b = render_svg(data(), &selection, &options).unwrap();
    assert_eq!(a, b);
    let a = render_png(data(), &selection, &options).unwrap();
    let b = render_png(data(), &selection, &options).unwrap();
    assert_eq!(a, b);
}

#[test]
fn writes_the_figures_of_one_simulated_track() {
    let dir = out_dir();
    let selection = Selection::track(main_track());
    let options = PlotOptions::default();
    let svg = render_svg(data(), &selection, &options).unwrap();
    let png = render_png(data(), &selection, &options).unwrap();
    std::fs::write(dir.join("track.svg"), &svg).unwrap();
    std::fs::write(dir.join("track.png"), &png).unwrap();
    let all = render_png(data(), &Selection::all(), &options).unwrap();
    std::fs::write(dir.join("session.png"), &all).unwrap();
    assert_eq!(png_size(&png), (1600, 1000));
    assert_eq!(png_size(&all), (1600, 1000));
}
