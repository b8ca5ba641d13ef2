//! The offline smoother: the detections of a recording cut into flights by the estimator's own
//! tracks (the live node's association, gating and initialisation), each flight fitted as a whole
//! ([`crate::offline::batch`]), and the fitted state, with its covariance, at every detection of it.
//!
//! A detection belongs to the track it was fused into or initialised with (the initialiser's
//! first detection goes to the track its successors start). Detections the filter rejected are
//! not smoothed: they are counted, by reason.

use std::sync::atomic::{AtomicBool, Ordering};

use crate::config::Config;
use crate::model::detection::Detection;
use crate::offline::batch::{FitError, FittedState, fit_whole_flight};
use crate::online::estimator::{Counters, Estimator, Rejection, Verdict};
use crate::physics::Propagator;

/// The detections of one track.
#[derive(Debug, Clone, PartialEq)]
pub struct Flight {
    /// The estimator's track id.
    pub track_id: u32,
    /// Indices of its detections in the recording, in arrival order.
    pub members: Vec<usize>,
}

/// Cuts `detections` (in arrival order) into the estimator's tracks, in order of their start;
/// also returns what the estimator did with every detection.
pub fn split_flights(config: &Config, detections: &[Detection]) -> (Vec<Flight>, Counters) {
    let mut estimator = Estimator::new(config);
    let mut flights: Vec<Flight> = Vec::new();
    let mut waiting: Vec<usize> = Vec::new();
    // A detection whose stamp jumped, held by the estimator: it starts the next track with its
    // successors when the jump is confirmed, and is dropped when it proves a glitch.
    let mut held: Option<usize> = None;
    for (index, detection) in detections.iter().enumerate() {
        let glitches = estimator.counters().rejected(Rejection::StampJump);
        let out = estimator.handle(detection);
        if let Some(first) = held {
            if estimator.counters().rejected(Rejection::StampJump) > glitches {
                held = None;
            } else if !estimator.holds_a_jump() {
                waiting.push(first);
                held = None;
            }
        }
        let track_id = match out.verdict {
            Verdict::Rejected(_) => continue,
            Verdict::Held => {
                held = Some(index);
                continue;
            }
            Verdict::Fused { .. } | Verdict::Initializing => out.estimate.map(|e| e.track_id),
        };
        let Some(track_id) = track_id else {
            // The initialiser's first detection: it joins the track that follows it.
            waiting.push(index);
            continue;
        };
        let position = match flights.iter().rposition(|f| f.track_id == track_id) {
            Some(p) => p,
            None => {
                flights.push(Flight {
                    track_id,
                    members: Vec::new(),
                });
                flights.len() - 1
            }
        };
        let members = &mut flights[position].members;
        members.append(&mut waiting);
        members.push(index);
    }
    (flights, estimator.counters())
}

/// The smoothed state at one detection.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SmoothedState {
    /// Index of the detection in the recording.
    pub index: usize,
    /// Its stamp [ns].
    pub stamp: i64,
    /// The track (the estimator's id).
    pub track_id: u32,
    /// The fitted state there, its covariance and the bounces before it.
    pub fitted: FittedState,
    /// The detection's squared whitened residual against it (a normalised innovation squared).
    pub nis: f64,
}

/// A flight that could not be smoothed.
#[derive(Debug, Clone, PartialEq)]
pub struct Unsmoothed {
    /// The track.
    pub track_id: u32,
    /// Its detections.
    pub detections: usize,
    /// Why.
    pub error: FitError,
}

/// What the smoother did with a recording.
#[derive(Debug, Clone, PartialEq)]
pub struct Smoothing {
    /// The smoothed states, in arrival order of their detections.
    pub states: Vec<SmoothedState>,
    /// Flights fitted.
    pub flights: usize,
    /// Flights that could not be fitted.
    pub failed: Vec<Unsmoothed>,
    /// Flights left unfitted because the work was cancelled.
    pub skipped: usize,
    /// Detections marked outliers by the fits' robust loss.
    pub outliers: usize,
    /// What the estimator did with every detection (the rejected ones are not smoothed).
    pub counters: Counters,
}

/// Smooths a recording (detections in arrival order); `progress` is called with (flights done,
/// flights) after each flight. Setting `cancel` stops before the next flight: the flights not
/// fitted are counted in [`Smoothing::skipped`].
pub fn smooth(
    config: &Config,
    detections: &[Detection],
    progress: &mut dyn FnMut(usize, usize),
    cancel: &AtomicBool,
) -> Smoothing {
    let propagator = Propagator::new(config);
    let (flights, counters) = split_flights(config, detections);
    let mut out = Smoothing {
        states: Vec::new(),
        flights: 0,
        failed: Vec::new(),
        skipped: 0,
        outliers: 0,
        counters,
    };
    for (done, flight) in flights.iter().enumerate() {
        if cancel.load(Ordering::Relaxed) {
            out.skipped = flights.len() - done;
            break;
        }
        let members: Vec<Detection> = flight.members.iter().map(|&i| detections[i]).collect();
        match fit_whole_flight(config, &members) {
            Ok(fit) => {
                out.flights += 1;
                out.outliers += fit.outliers;
                let stamps: Vec<i64> = fit
                    .residuals
                    .iter()
                    .map(|&(k, _)| members[k].stamp)
                    .collect();
                let states = fit.states_at(&propagator, &stamps);
                for (&(k, nis), fitted) in fit.residuals.iter().zip(states) {
                    if let Some(fitted) = fitted {
                        out.states.push(SmoothedState {
                            index: flight.members[k],
                            stamp: members[k].stamp,
                            track_id: flight.track_id,
                            fitted,
                            nis,
                        });
                    }
                }
            }
            Err(error) => out.failed.push(Unsmoothed {
                track_id: flight.track_id,
                detections: members.len(),
                error,
            }),
        }
        progress(done + 1, flights.len());
    }
    out.states.sort_by_key(|s| s.index);
    out
}
