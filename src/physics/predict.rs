//! A whole predicted flight: samples on a regular grid and the events on the way (bounces, net,
//! floor, a plane). The base of every later prediction (trajectory service, interception, return
//! of the racket's hit).

use super::propagate::{Cursor, Event, EventKind, Flow, Observer, Outcome, Propagator, Watch};
use super::state::{BallState, StateVector};

/// What to predict.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PredictOptions {
    /// How far ahead [s].
    pub horizon: f64,
    /// Spacing of the returned samples [s]. The RK4 step is the largest whole number of them
    /// that is no longer than the propagator's largest step (or the largest step that divides
    /// one, when one is longer); samples inside a step are interpolated (see [`predict`]).
    pub sample_interval: f64,
    /// Report crossings of the plane x = this value [m].
    pub plane_x: Option<f64>,
    /// End the prediction at the first crossing of `plane_x`.
    pub stop_at_plane: bool,
}

/// The state at one time of a prediction.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sample {
    /// Time since the start of the prediction [s].
    pub t: f64,
    /// The state.
    pub state: BallState,
}

/// Why a prediction ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TrajectoryEnd {
    /// The horizon was reached.
    Horizon,
    /// The ball crossed the plane and the prediction was asked to stop there.
    Plane,
    /// The ball hit the net.
    Net,
    /// The ball reached the floor.
    Floor,
}

/// A predicted flight.
#[derive(Debug, Clone, PartialEq)]
pub struct Trajectory {
    /// Samples at t = 0, every sample interval, and at the end of the prediction.
    pub samples: Vec<Sample>,
    /// Every event, in time order.
    pub events: Vec<Event>,
    /// Why the prediction ended.
    pub end: TrajectoryEnd,
}

impl Trajectory {
    /// The table bounces, in time order.
    pub fn bounces(&self) -> impl Iterator<Item = &Event> {
        self.events
            .iter()
            .filter(|e| matches!(e.kind, EventKind::TableBounce { .. }))
    }

    /// The first crossing of the watched plane.
    pub fn plane_crossing(&self) -> Option<&Event> {
        self.events
            .iter()
            .find(|e| matches!(e.kind, EventKind::Plane { .. }))
    }
}

struct Recorder {
    events: Vec<Event>,
    stop_at_plane: bool,
}

impl Observer for Recorder {
    fn on_event(&mut self, event: &Event) -> Flow {
        self.events.push(*event);
        if self.stop_at_plane && matches!(event.kind, EventKind::Plane { .. }) {
            Flow::Stop
        } else {
            Flow::Continue
        }
    }
}

/// Predicts the flight of `start` (at t = 0) over the horizon: table bounces, net, floor and the
/// optional plane.
///
/// The flight is integrated on RK4 steps of the largest whole number of sample intervals that
/// fits the propagator's largest step (one interval when it is longer), and the samples inside a
/// step are the cubic Hermite interpolant of its two ends and their derivatives (fourth order,
/// like RK4: about 1e-8 m at a 20 ms step). A step with an event inside (the interpolant would
/// cross it) is taken again, propagated to each of its samples.
pub fn predict(propagator: &Propagator, start: &BallState, options: &PredictOptions) -> Trajectory {
    let mut cursor = Cursor::new(0.0, start);
    let watch = Watch {
        plane_x: options.plane_x,
        ..Watch::FLIGHT
    };
    let mut recorder = Recorder {
        events: Vec::new(),
        stop_at_plane: options.stop_at_plane,
    };
    let interval = options.sample_interval.max(f64::MIN_POSITIVE);
    let count = (options.horizon / interval).ceil().max(0.0) as usize;
    let time_of = |k: usize| (k as f64 * interval).min(options.horizon);
    let per_step = ((propagator.max_step() / interval) * (1.0 + 1e-9)).floor();
    let per_step = if per_step >= 2.0 {
        per_step as usize
    } else {
        1
    };
    let mut samples = Vec::with_capacity(count + 1);
    samples.push(Sample {
        t: 0.0,
        state: *start,
    });
    let mut end = TrajectoryEnd::Horizon;
    // The derivative at the cursor's state, when the last step was interpolated.
    let mut slope_here = None;
    let mut k = 0;
    while k < count {
        let last = (k + per_step).min(count);
        if last - k > 1 {
            let from = cursor;
            let recorded = recorder.events.len();
            let duration = time_of(last) - cursor.t;
            let outcome = propagator.advance(&mut cursor, duration, watch, &mut recorder);
            if outcome == Outcome::Reached && recorder.events.len() == recorded {
                let flight = propagator.flight();
                let slope_from = slope_here.unwrap_or_else(|| flight.derivative(&from.state));
                let slope_to = flight.derivative(&cursor.state);
                let h = cursor.t - from.t;
                for j in k + 1..last {
                    let s = (time_of(j) - from.t) / h;
                    let state = hermite(&from.state, &slope_from, &cursor.state, &slope_to, h, s);
                    samples.push(Sample {
                        t: time_of(j),
                        state: BallState::from_vector(&state),
                    });
                }
                samples.push(Sample {
                    t: cursor.t,
                    state: cursor.ball(),
                });
                slope_here = Some(slope_to);
                k = last;
                continue;
            }
            // An event inside the step: sample by sample.
            cursor = from;
            recorder.events.truncate(recorded);
        }
        slope_here = None;
        let mut ended = None;
        for j in k + 1..=last {
            let duration = time_of(j) - cursor.t;
            let outcome = propagator.advance(&mut cursor, duration, watch, &mut recorder);
            samples.push(Sample {
                t: cursor.t,
                state: cursor.ball(),
            });
            ended = match outcome {
                Outcome::Reached => None,
                Outcome::Stopped => Some(TrajectoryEnd::Plane),
                Outcome::Terminated(EventKind::Floor) => Some(TrajectoryEnd::Floor),
                Outcome::Terminated(_) => Some(TrajectoryEnd::Net),
            };
            if ended.is_some() {
                break;
            }
        }
        if let Some(why) = ended {
            end = why;
            break;
        }
        k = last;
    }
    Trajectory {
        samples,
        events: recorder.events,
        end,
    }
}

/// The cubic Hermite interpolant at `s` in [0, 1] of a step of size `h` from `x0` (derivative
/// `f0`) to `x1` (derivative `f1`).
fn hermite(
    x0: &StateVector,
    f0: &StateVector,
    x1: &StateVector,
    f1: &StateVector,
    h: f64,
    s: f64,
) -> StateVector {
    let (s2, s3) = (s * s, s * s * s);
    x0 * (2.0 * s3 - 3.0 * s2 + 1.0)
        + f0 * ((s3 - 2.0 * s2 + s) * h)
        + x1 * (3.0 * s2 - 2.0 * s3)
        + f1 * ((s3 - s2) * h)
}
