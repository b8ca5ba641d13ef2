//! A whole predicted flight: samples on a regular grid and the events on the way (bounces, net,
//! floor, a plane). The base of every later prediction (trajectory service, interception, return
//! of the racket's hit).

use super::propagate::{Cursor, Event, EventKind, Flow, Observer, Outcome, Propagator, Watch};
use super::state::BallState;

/// What to predict.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PredictOptions {
    /// How far ahead [s].
    pub horizon: f64,
    /// Spacing of the returned samples [s]; the RK4 step is the largest step that divides it and
    /// is no longer than the propagator's largest step.
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
    let mut samples = Vec::with_capacity(count + 1);
    samples.push(Sample {
        t: 0.0,
        state: *start,
    });
    let mut end = TrajectoryEnd::Horizon;
    for k in 1..=count {
        let target = (k as f64 * interval).min(options.horizon);
        let duration = target - cursor.t;
        let outcome = propagator.advance(&mut cursor, duration, watch, &mut recorder);
        samples.push(Sample {
            t: cursor.t,
            state: cursor.ball(),
        });
        match outcome {
            Outcome::Reached => {}
            Outcome::Stopped => {
                end = TrajectoryEnd::Plane;
                break;
            }
            Outcome::Terminated(EventKind::Floor) => {
                end = TrajectoryEnd::Floor;
                break;
            }
            Outcome::Terminated(_) => {
                end = TrajectoryEnd::Net;
                break;
            }
        }
    }
    Trajectory {
        samples,
        events: recorder.events,
        end,
    }
}
