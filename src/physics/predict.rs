//! A whole predicted flight: samples on a regular grid and the events on the way (bounces, net,
//! floor, a plane). The base of every later prediction (trajectory service, interception, return
//! of the racket's hit).

use super::aero::FlightModel;
use super::propagate::{
    Cursor, Event, EventKind, Flow, Observer, Outcome, Propagator, WHOLE_STEPS_TOLERANCE, Watch,
};
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
/// like RK4: a few micrometres at a 40 ms step). A step with events inside is interpolated
/// piecewise between them: from its start to the state just before the first event, from the
/// state just after it to the next, and so on to the step's end.
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
    let per_step = ((propagator.max_step() / interval) * (1.0 + WHOLE_STEPS_TOLERANCE)).floor();
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
    let flight = propagator.flight();
    // The end of the last step, with its derivative once a sample has needed it.
    let mut step_start = Knot::new(0.0, start.to_vector());
    let mut k = 0;
    while k < count {
        let last = (k + per_step).min(count);
        let recorded = recorder.events.len();
        let duration = time_of(last) - cursor.t;
        // The samples strictly inside the step are interpolated piecewise: from the step's
        // start to the first event, from each event to the next, from the last to the end.
        let mut knot = step_start;
        let outcome = propagator.advance(&mut cursor, duration, watch, &mut recorder);
        let mut j = k + 1;
        for event in &recorder.events[recorded..] {
            let mut before = Knot::new(event.t, event.before);
            while j < last && time_of(j) < event.t {
                samples.push(knot.interpolate(&mut before, flight, time_of(j)));
                j += 1;
            }
            knot = Knot::new(event.t, event.after);
        }
        let ended = match outcome {
            Outcome::Reached => None,
            Outcome::Stopped => Some(TrajectoryEnd::Plane),
            Outcome::Terminated(EventKind::Floor) => Some(TrajectoryEnd::Floor),
            Outcome::Terminated(_) => Some(TrajectoryEnd::Net),
        };
        let mut step_end = Knot::new(cursor.t, cursor.state);
        if ended.is_none() {
            while j < last {
                samples.push(knot.interpolate(&mut step_end, flight, time_of(j)));
                j += 1;
            }
        }
        samples.push(Sample {
            t: cursor.t,
            state: cursor.ball(),
        });
        if let Some(why) = ended {
            end = why;
            break;
        }
        step_start = step_end;
        k = last;
    }
    Trajectory {
        samples,
        events: recorder.events,
        end,
    }
}

/// A point of the flight: one end of an interpolated piece. Its derivative is computed when a
/// sample first needs it (with one sample per step, never).
struct Knot {
    t: f64,
    x: StateVector,
    slope: Option<StateVector>,
}

impl Knot {
    fn new(t: f64, x: StateVector) -> Self {
        Self { t, x, slope: None }
    }

    fn slope(&mut self, flight: &FlightModel) -> StateVector {
        *self.slope.get_or_insert_with(|| flight.derivative(&self.x))
    }

    /// The sample at `t` (between this knot and `to`) of the cubic Hermite interpolant of the
    /// two knots.
    fn interpolate(&mut self, to: &mut Knot, flight: &FlightModel, t: f64) -> Sample {
        let h = to.t - self.t;
        let s = if h > 0.0 { (t - self.t) / h } else { 0.0 };
        let (s2, s3) = (s * s, s * s * s);
        let x = self.x * (2.0 * s3 - 3.0 * s2 + 1.0)
            + self.slope(flight) * ((s3 - 2.0 * s2 + s) * h)
            + to.x * (3.0 * s2 - 2.0 * s3)
            + to.slope(flight) * ((s3 - s2) * h);
        Sample {
            t,
            state: BallState::from_vector(&x),
        }
    }
}
