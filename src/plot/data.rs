//! What a figure shows, gathered by the caller: the detections, estimates, interception
//! predictions, predicted flights and (optionally) the truth of a replayed or simulated stream,
//! with the table and hitting plane of the configuration; and the [`Selection`] of one track or
//! time window to draw. Positions are in the `table` frame, stamps in integer nanoseconds.

use nalgebra::Vector3;

use super::PlotError;
use crate::config::Config;
use crate::model::detection::{Detection, Source, seconds_to_ns};
use crate::online::estimator::{Estimate, InterceptEstimate, Output, TrackStatus, Verdict};
use crate::physics::{BallState, Trajectory};

/// One detection as the estimator received it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PlotDetection {
    /// Exposure time [ns].
    pub stamp: i64,
    /// Ball centre [m].
    pub position: Vector3<f64>,
    /// The camera system.
    pub source: Source,
    /// True when the estimator did not use it (rejected for any reason).
    pub rejected: bool,
}

impl PlotDetection {
    /// A detection and whether the estimator rejected it.
    pub fn new(detection: &Detection, rejected: bool) -> Self {
        Self {
            stamp: detection.stamp,
            position: detection.position,
            source: detection.source,
            rejected,
        }
    }
}

/// One filtered state of a track.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PlotEstimate {
    /// Time of the estimate [ns].
    pub stamp: i64,
    /// The track.
    pub track_id: u32,
    /// Track status.
    pub status: TrackStatus,
    /// Ball centre [m].
    pub position: Vector3<f64>,
    /// Velocity [m/s].
    pub velocity: Vector3<f64>,
    /// Angular velocity [rad/s].
    pub spin: Vector3<f64>,
    /// Standard deviation of each position component, from the covariance's diagonal [m].
    pub position_sigma: Vector3<f64>,
}

impl From<&Estimate> for PlotEstimate {
    fn from(e: &Estimate) -> Self {
        let sigma = |i: usize| e.covariance[(i, i)].max(0.0).sqrt();
        Self {
            stamp: e.stamp,
            track_id: e.track_id,
            status: e.status,
            position: e.state.position,
            velocity: e.state.velocity,
            spin: e.state.spin,
            position_sigma: Vector3::new(sigma(0), sigma(1), sigma(2)),
        }
    }
}

/// A predicted crossing of the hitting plane.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PlotCrossing {
    /// When the ball is predicted to cross the plane [ns].
    pub stamp: i64,
    /// Where it is predicted to cross [m].
    pub position: Vector3<f64>,
}

/// The interception prediction made from one estimate.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PlotIntercept {
    /// Time of the estimate it was predicted from [ns].
    pub stamp: i64,
    /// The track.
    pub track_id: u32,
    /// The crossing; `None` when the prediction was invalid (net, misses the table, ...).
    pub crossing: Option<PlotCrossing>,
    /// The predicted bounce on the robot's half [m], when one is ahead.
    pub bounce: Option<Vector3<f64>>,
}

impl PlotIntercept {
    /// True when the prediction has a valid crossing.
    pub fn is_valid(&self) -> bool {
        self.crossing.is_some()
    }
}

impl From<&InterceptEstimate> for PlotIntercept {
    fn from(i: &InterceptEstimate) -> Self {
        let at = |t: f64| i.stamp + seconds_to_ns(t);
        Self {
            stamp: i.stamp,
            track_id: i.track_id,
            crossing: i.intercept.crossing.as_ref().ok().map(|c| PlotCrossing {
                stamp: at(c.time),
                position: c.state.position,
            }),
            bounce: i.intercept.bounce.map(|b| b.position),
        }
    }
}

/// A predicted flight of the ball centre.
#[derive(Debug, Clone, PartialEq)]
pub struct PlotTrajectory {
    /// Time of the estimate it starts from [ns].
    pub stamp: i64,
    /// The track.
    pub track_id: u32,
    /// Ball centre along the flight, in time order [m].
    pub positions: Vec<Vector3<f64>>,
}

impl PlotTrajectory {
    /// The positions of a predicted [`Trajectory`] that starts at `stamp` [ns].
    pub fn new(stamp: i64, track_id: u32, trajectory: &Trajectory) -> Self {
        Self {
            stamp,
            track_id,
            positions: trajectory
                .samples
                .iter()
                .map(|s| s.state.position)
                .collect(),
        }
    }
}

/// The true state at one time (simulation, or a reference system).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PlotTruth {
    /// Time [ns].
    pub stamp: i64,
    /// Ball centre [m].
    pub position: Vector3<f64>,
    /// Velocity [m/s].
    pub velocity: Vector3<f64>,
    /// Angular velocity [rad/s].
    pub spin: Vector3<f64>,
}

impl PlotTruth {
    /// The true `state` at `stamp` [ns].
    pub fn new(stamp: i64, state: &BallState) -> Self {
        Self {
            stamp,
            position: state.position,
            velocity: state.velocity,
            spin: state.spin,
        }
    }
}

/// The fixed scene: table and hitting plane.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Scene {
    /// Playing surface length along x [m]; the surface is centred on the origin at z = 0.
    pub table_length: f64,
    /// Playing surface width along y [m].
    pub table_width: f64,
    /// Net height above the surface, at x = 0 [m].
    pub net_height: f64,
    /// How far the net posts stand outside each sideline [m].
    pub net_overhang: f64,
    /// The robot's hitting plane x [m].
    pub plane_x: f64,
}

impl Scene {
    /// The table and hitting plane of a configuration.
    pub fn new(config: &Config) -> Self {
        Self {
            table_length: config.table.length,
            table_width: config.table.width,
            net_height: config.table.net_height,
            net_overhang: config.table.net_overhang,
            plane_x: config.intercept.plane_x,
        }
    }
}

/// Everything a figure can show. Owned and plain: fill it from `Estimator::handle`'s outputs
/// ([`PlotData::record`]), a replay or a simulation.
#[derive(Debug, Clone, PartialEq)]
pub struct PlotData {
    /// Table and hitting plane.
    pub scene: Scene,
    /// Every detection, in any order.
    pub detections: Vec<PlotDetection>,
    /// Filtered states, in any order.
    pub estimates: Vec<PlotEstimate>,
    /// Interception predictions, in any order.
    pub intercepts: Vec<PlotIntercept>,
    /// Predicted flights, in any order.
    pub trajectories: Vec<PlotTrajectory>,
    /// The truth, when known (empty otherwise), in any order.
    pub truth: Vec<PlotTruth>,
}

/// One track's extent in the data.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TrackSpan {
    /// The track.
    pub track_id: u32,
    /// Stamp of its first estimate [ns].
    pub first: i64,
    /// Stamp of its last estimate [ns].
    pub last: i64,
    /// Number of its estimates.
    pub estimates: usize,
}

impl TrackSpan {
    /// Duration from the first to the last estimate [s].
    pub fn duration(&self) -> f64 {
        (self.last - self.first) as f64 * 1e-9
    }
}

impl PlotData {
    /// Empty data over the table and hitting plane of `config`.
    pub fn new(config: &Config) -> Self {
        Self {
            scene: Scene::new(config),
            detections: Vec::new(),
            estimates: Vec::new(),
            intercepts: Vec::new(),
            trajectories: Vec::new(),
            truth: Vec::new(),
        }
    }

    /// Records one detection and what `Estimator::handle` returned for it.
    pub fn record(&mut self, detection: &Detection, output: &Output) {
        let rejected = matches!(output.verdict, Verdict::Rejected(_) | Verdict::Held);
        self.detections
            .push(PlotDetection::new(detection, rejected));
        if let Some(e) = &output.estimate {
            self.estimates.push(e.into());
        }
        if let Some(i) = &output.intercept {
            self.intercepts.push(i.into());
        }
    }

    /// The tracks with estimates, ordered by their first estimate (then id).
    pub fn tracks(&self) -> Vec<TrackSpan> {
        let mut spans: Vec<TrackSpan> = Vec::new();
        for e in &self.estimates {
            match spans.iter_mut().find(|s| s.track_id == e.track_id) {
                Some(s) => {
                    s.first = s.first.min(e.stamp);
                    s.last = s.last.max(e.stamp);
                    s.estimates += 1;
                }
                None => spans.push(TrackSpan {
                    track_id: e.track_id,
                    first: e.stamp,
                    last: e.stamp,
                    estimates: 1,
                }),
            }
        }
        spans.sort_by_key(|s| (s.first, s.track_id));
        spans
    }

    /// The earliest stamp of any item [ns], or `None` when there is no data.
    pub fn first_stamp(&self) -> Option<i64> {
        let d = self.detections.iter().map(|d| d.stamp);
        let e = self.estimates.iter().map(|e| e.stamp);
        let t = self.truth.iter().map(|t| t.stamp);
        d.chain(e).chain(t).min()
    }

    /// The part of the data that `selection` picks, with the same scene. A track selection keeps
    /// that track's estimates, predictions and flights, and the detections and truth from
    /// [`Selection::TRACK_LEAD`] before its first estimate (but after the previous track's last)
    /// to its last estimate. Errors when the track is unknown, the window is reversed, or nothing
    /// (no detection and no estimate) is left.
    pub fn select(&self, selection: &Selection) -> Result<PlotData, PlotError> {
        let (mut start, mut end) = (i64::MIN, i64::MAX);
        if let Some((a, b)) = selection.window {
            if a > b {
                return Err(PlotError::InvalidWindow { start: a, end: b });
            }
            (start, end) = (a, b);
        }
        if let Some(id) = selection.track {
            let tracks = self.tracks();
            let Some(k) = tracks.iter().position(|s| s.track_id == id) else {
                return Err(PlotError::UnknownTrack {
                    track_id: id,
                    known: tracks.iter().map(|s| s.track_id).collect(),
                });
            };
            let span = tracks[k];
            let mut lead = span.first.saturating_sub(Selection::TRACK_LEAD);
            let previous_end = tracks[..k].iter().map(|s| s.last).max();
            if let Some(p) = previous_end.filter(|p| *p < span.first) {
                lead = lead.max(p.saturating_add(1));
            }
            start = start.max(lead);
            end = end.min(span.last);
        }
        let in_span = |stamp: i64| stamp >= start && stamp <= end;
        let of_track = |id: u32| selection.track.is_none_or(|t| t == id);
        let picked = PlotData {
            scene: self.scene,
            detections: self
                .detections
                .iter()
                .filter(|d| in_span(d.stamp))
                .copied()
                .collect(),
            estimates: self
                .estimates
                .iter()
                .filter(|e| of_track(e.track_id) && in_span(e.stamp))
                .copied()
                .collect(),
            intercepts: self
                .intercepts
                .iter()
                .filter(|i| of_track(i.track_id) && in_span(i.stamp))
                .copied()
                .collect(),
            trajectories: self
                .trajectories
                .iter()
                .filter(|t| of_track(t.track_id) && in_span(t.stamp))
                .cloned()
                .collect(),
            truth: self
                .truth
                .iter()
                .filter(|t| in_span(t.stamp))
                .copied()
                .collect(),
        };
        if picked.detections.is_empty() && picked.estimates.is_empty() {
            return Err(PlotError::EmptySelection {
                selection: selection.describe(),
            });
        }
        Ok(picked)
    }
}

/// Which part of the data to draw: one track, a time window, both (the track inside the window)
/// or everything.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Selection {
    /// Only this track's estimates, predictions and flights (and the detections and truth of
    /// its time span).
    pub track: Option<u32>,
    /// Only items stamped in [start, end] [ns], both ends included.
    pub window: Option<(i64, i64)>,
}

impl Selection {
    /// How far before a track's first estimate its detections are shown [ns] (50 ms: the
    /// detections its initialisation used).
    pub const TRACK_LEAD: i64 = 50_000_000;

    /// Everything.
    pub fn all() -> Self {
        Self::default()
    }

    /// One track.
    pub fn track(track_id: u32) -> Self {
        Self {
            track: Some(track_id),
            window: None,
        }
    }

    /// Everything stamped in [start, end] [ns].
    pub fn window(start: i64, end: i64) -> Self {
        Self {
            track: None,
            window: Some((start, end)),
        }
    }

    /// A short description for titles and errors.
    pub fn describe(&self) -> String {
        let window = self.window.map(|(a, b)| format!("stamps {a}..={b} ns"));
        match (self.track, window) {
            (Some(t), Some(w)) => format!("track {t} within {w}"),
            (Some(t), None) => format!("track {t}"),
            (None, Some(w)) => w,
            (None, None) => "everything".to_string(),
        }
    }
}
