//! Event-aware propagation of the ball state: fixed-step RK4 on the flight model
//! ([`super::aero`]), with the state-transition matrix propagated through the same RK4 stages (so
//! it is the exact derivative of the discrete map), and events found inside a step at their exact
//! time by root-finding on the RK4 map itself:
//!
//! - table contact: ball centre at z = r moving down, inside the table outline -> bounce
//!   ([`super::bounce`]);
//! - net: the centre crosses x = 0; a hit when the ball overlaps the net (0 < z + r and
//!   z - r < net height) within the posts (|y| < width / 2 + overhang), else a crossing with its
//!   clearance;
//! - floor: the centre at z = r - table height;
//! - a plane x = const (the robot's hitting plane).
//!
//! The time of an event depends on the state it was predicted from; its gradient (from
//! g(x(tau)) = 0) enters the Jacobian of every later state, as in the saltation matrix of a hybrid
//! system. Times are seconds relative to the caller's own origin.

use super::aero::{FlightMatrix, FlightModel};
use super::bounce::{BounceRegime, TableBounce};
use super::params::{ParamMatrix, ParamRow, PhysicsParams, RESTITUTION};
use super::state::{BallState, StateMatrix, StateRow, StateVector, VELOCITY};
use crate::config::Config;

/// d(state)/d(initial state) and d(time)/d(initial state) of a [`Cursor`].
///
/// The state-transition matrix is kept as a product: the transition up to the last event (`None`
/// before any: the identity) and the transition of the flight since, in its block structure
/// ([`FlightMatrix`]), so a step of flight updates 36 entries rather than 81.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Tangent {
    /// d(state after the last event)/d(initial state); `None` for the identity.
    until_event: Option<StateMatrix>,
    /// d(current state)/d(state after the last event), over free flight.
    flight: FlightMatrix,
    /// d(current time)/d(initial state) [s per state unit]; non-zero only at an event, whose time
    /// moves with the initial state.
    pub time_gradient: StateRow,
    /// The sensitivities to the physical parameters, when asked for ([`Cursor::tracking_params`]).
    params: Option<ParamTangent>,
}

/// d(state)/d(physical parameters) of a [`Cursor`] ([`super::params`]), kept like the state
/// transition: up to the last event, and over the flight since at a fixed state after it.
#[derive(Debug, Clone, Copy, PartialEq)]
struct ParamTangent {
    /// d(state after the last event)/d(parameters).
    until_event: ParamMatrix,
    /// d(current state)/d(parameters) at a fixed state after the last event.
    flight: ParamMatrix,
    /// d(current time)/d(parameters); non-zero only at an event.
    time_gradient: ParamRow,
}

impl ParamTangent {
    fn zero() -> Self {
        Self {
            until_event: ParamMatrix::zeros(),
            flight: ParamMatrix::zeros(),
            time_gradient: ParamRow::zeros(),
        }
    }
}

impl Tangent {
    fn identity() -> Self {
        Self {
            until_event: None,
            flight: FlightMatrix::identity(),
            time_gradient: StateRow::zeros(),
            params: None,
        }
    }

    /// d(current state)/d(physical parameters), when the cursor tracks them.
    pub fn params(&self) -> Option<ParamMatrix> {
        self.params
            .as_ref()
            .map(|p| self.flight.times(&p.until_event) + p.flight)
    }

    /// d(current time)/d(physical parameters), when the cursor tracks them [s per unit];
    /// non-zero only at an event.
    pub fn param_time_gradient(&self) -> Option<ParamRow> {
        self.params.as_ref().map(|p| p.time_gradient)
    }

    /// True when the current time moves with the initial state or the parameters (just after
    /// an event).
    fn time_moves(&self) -> bool {
        self.time_gradient != StateRow::zeros()
            || self
                .params
                .as_ref()
                .is_some_and(|p| p.time_gradient != ParamRow::zeros())
    }

    /// The state-transition matrix: d(current state)/d(initial state).
    pub fn transition(&self) -> StateMatrix {
        self.through(&self.flight)
    }

    /// The state-transition matrix in its block structure when the propagation met no event (the
    /// transition of free flight); `None` after an event.
    pub fn free_flight(&self) -> Option<&FlightMatrix> {
        (self.until_event.is_none() && !self.time_moves()).then_some(&self.flight)
    }

    /// `transition * p * transition'`: a covariance `p` of the initial state carried to the
    /// current state (in the flight's block structure before any event).
    pub fn carry_covariance(&self, p: &StateMatrix) -> StateMatrix {
        match &self.until_event {
            None => {
                let fp = self.flight.times(p);
                self.flight.times(&fp.transpose()).transpose()
            }
            Some(_) => {
                let transition = self.transition();
                transition * p * transition.transpose()
            }
        }
    }

    /// `flight * q * flight'`: a covariance `q` of the state just after the last event (the
    /// start, before any) carried by the flight since.
    pub fn carry_flight(&self, q: &StateMatrix) -> StateMatrix {
        let fq = self.flight.times(q);
        self.flight.times(&fq.transpose()).transpose()
    }

    /// The full transition when `flight` is the flight since the last event.
    fn through(&self, flight: &FlightMatrix) -> StateMatrix {
        match &self.until_event {
            None => flight.to_matrix(),
            Some(until_event) => flight.times(until_event),
        }
    }

    /// Restarts the flight part at an event whose full transition is `transition` (and whose
    /// full sensitivity to the parameters is `params`, when tracked).
    fn restart_at(&mut self, transition: StateMatrix, params: Option<ParamMatrix>) {
        self.until_event = Some(transition);
        self.flight = FlightMatrix::identity();
        if let (Some(p), Some(until_event)) = (self.params.as_mut(), params) {
            p.until_event = until_event;
            p.flight = ParamMatrix::zeros();
        }
    }
}

/// Where a propagation stands: the time, the state and optionally its sensitivities.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Cursor {
    /// Time [s] on the caller's axis.
    pub t: f64,
    /// State at `t`.
    pub state: StateVector,
    /// Sensitivities to the initial state, when asked for.
    pub tangent: Option<Tangent>,
}

impl Cursor {
    /// A cursor at time `t` that propagates the state only.
    pub fn new(t: f64, state: &BallState) -> Self {
        Self {
            t,
            state: state.to_vector(),
            tangent: None,
        }
    }

    /// A cursor at time `t` that also propagates the state-transition matrix (starting at I).
    pub fn with_jacobian(t: f64, state: &BallState) -> Self {
        Self {
            tangent: Some(Tangent::identity()),
            ..Self::new(t, state)
        }
    }

    /// A cursor at time `t` on a state vector that also propagates the state-transition matrix.
    pub fn tracking(t: f64, state: StateVector) -> Self {
        Self {
            t,
            state,
            tangent: Some(Tangent::identity()),
        }
    }

    /// A cursor at time `t` on a state vector that also propagates the state-transition matrix
    /// and the state's sensitivity to the physical parameters (starting at I and 0).
    pub fn tracking_params(t: f64, state: StateVector) -> Self {
        Self {
            t,
            state,
            tangent: Some(Tangent {
                params: Some(ParamTangent::zero()),
                ..Tangent::identity()
            }),
        }
    }

    /// The state as a [`BallState`].
    pub fn ball(&self) -> BallState {
        BallState::from_vector(&self.state)
    }
}

/// Which events a propagation looks for, besides the table bounce (always on).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Watch {
    /// Stop at a net hit and report net crossings.
    pub net: bool,
    /// Stop when the ball reaches the floor.
    pub floor: bool,
    /// Report crossings of the plane x = this value [m].
    pub plane_x: Option<f64>,
    /// Report a ball that passes the table's level outside its outline ([`EventKind::TableMiss`]).
    pub table_misses: bool,
}

impl Watch {
    /// Table, net and floor; no plane.
    pub const FLIGHT: Self = Self {
        net: true,
        floor: true,
        plane_x: None,
        table_misses: false,
    };
    /// Table bounces only (the filter's process model: it must not stop at a net or the floor).
    pub const BOUNCES: Self = Self {
        net: false,
        floor: false,
        plane_x: None,
        table_misses: false,
    };
}

/// What happened at an event.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum EventKind {
    /// The ball bounced on the table.
    TableBounce {
        /// Sliding or rolling impact.
        regime: BounceRegime,
    },
    /// The ball centre crossed the net plane x = 0.
    Net {
        /// Height of the ball's bottom over the net top [m]; negative below it.
        clearance: f64,
        /// True when the ball hit the net (the propagation stops there).
        hit: bool,
    },
    /// The ball reached the floor (the propagation stops there).
    Floor,
    /// The ball centre passed the table's level (z = r, moving down) outside its outline: a
    /// near miss when `distance` is small (reported only when watched).
    TableMiss {
        /// Distance of the ball centre from the outline [m].
        distance: f64,
    },
    /// The ball centre crossed the watched plane x = const.
    Plane {
        /// The plane's x [m].
        x: f64,
    },
}

impl EventKind {
    /// True when the propagation cannot go on after this event.
    pub fn is_terminal(&self) -> bool {
        matches!(self, Self::Floor | Self::Net { hit: true, .. })
    }
}

/// Sensitivities of an event to the initial state.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EventSensitivity {
    /// d(state just before the event)/d(initial state), the event time moving with it.
    pub before: StateMatrix,
    /// d(state just after the event)/d(initial state).
    pub after: StateMatrix,
    /// d(event time)/d(initial state) [s per state unit].
    pub time_gradient: StateRow,
    /// d(state just before, just after, event time)/d(physical parameters), when tracked.
    pub params: Option<EventParamSensitivity>,
}

/// Sensitivities of an event to the physical parameters.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EventParamSensitivity {
    /// d(state just before the event)/d(parameters), the event time moving with them.
    pub before: ParamMatrix,
    /// d(state just after the event)/d(parameters).
    pub after: ParamMatrix,
    /// d(event time)/d(parameters) [s per parameter unit].
    pub time_gradient: ParamRow,
}

/// One event of a propagation.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Event {
    /// What happened.
    pub kind: EventKind,
    /// When [s], on the caller's time axis.
    pub t: f64,
    /// State just before.
    pub before: StateVector,
    /// State just after (equal to `before` except at a bounce).
    pub after: StateVector,
    /// Sensitivities, when the cursor carries a tangent.
    pub sensitivity: Option<EventSensitivity>,
}

/// Whether an observer wants the propagation to go on.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Flow {
    /// Go on.
    Continue,
    /// Stop now.
    Stop,
}

/// Receives events and grid steps as a propagation runs. Both default to doing nothing.
pub trait Observer {
    /// Called at every event, after the state change.
    fn on_event(&mut self, _event: &Event) -> Flow {
        Flow::Continue
    }
    /// Called at every step of the grid.
    fn on_step(&mut self, _cursor: &Cursor) -> Flow {
        Flow::Continue
    }
}

impl Observer for () {}

/// How a propagation ended.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Outcome {
    /// The requested duration was covered.
    Reached,
    /// The observer asked to stop.
    Stopped,
    /// A terminal event (net hit, floor) ended the flight.
    Terminated(EventKind),
}

/// One step of RK4 with its sensitivities.
struct TangentStep {
    state: StateVector,
    /// d(state after the step)/d(state after the last event), at a fixed step size.
    flight: FlightMatrix,
    /// d(state after the step)/d(parameters) at a fixed state after the last event and a fixed
    /// step size, when tracked.
    params: Option<ParamMatrix>,
    /// d(state after the step)/d(step size).
    rate: StateVector,
}

impl TangentStep {
    /// d(state after the step)/d(initial state), at a fixed step size, for a cursor whose tangent
    /// was `tangent` at the step's start.
    fn transition(&self, tangent: &Tangent) -> StateMatrix {
        tangent.through(&self.flight)
    }

    /// Row `i` of [`Self::transition`].
    fn transition_row(&self, tangent: &Tangent, i: usize) -> StateRow {
        match &tangent.until_event {
            None => self.flight.row(i),
            Some(until_event) => self.flight.row(i) * until_event,
        }
    }

    /// d(state after the step)/d(parameters) at a fixed step size, for a cursor whose tangent
    /// was `tangent` at the step's start; `None` when the parameters are not tracked.
    fn param_sensitivity(&self, tangent: &Tangent) -> Option<ParamMatrix> {
        let p = tangent.params.as_ref()?;
        Some(self.flight.times(&p.until_event) + self.params?)
    }
}

#[derive(Debug, Clone, Copy, PartialEq)]
enum Surface {
    Table,
    /// The table's level outside its outline.
    TableMiss,
    Net,
    Floor,
    Plane(f64),
}

/// The root in [0, 1] of the cubic Hermite interpolant of values `g0`, `g1` and slopes `d0`,
/// `d1` at 0 and 1, the values of opposite signs (or `g1` zero): a few Newton steps from the
/// secant's root, kept inside the bracket by bisection.
fn hermite_root(g0: f64, d0: f64, g1: f64, d1: f64) -> f64 {
    let value = |s: f64| {
        let (s2, s3) = (s * s, s * s * s);
        (2.0 * s3 - 3.0 * s2 + 1.0) * g0
            + (s3 - 2.0 * s2 + s) * d0
            + (-2.0 * s3 + 3.0 * s2) * g1
            + (s3 - s2) * d1
    };
    let slope = |s: f64| {
        let s2 = s * s;
        (6.0 * s2 - 6.0 * s) * g0
            + (3.0 * s2 - 4.0 * s + 1.0) * d0
            + (-6.0 * s2 + 6.0 * s) * g1
            + (3.0 * s2 - 2.0 * s) * d1
    };
    let (mut lo, mut hi) = (0.0, 1.0);
    let mut s = if g1 != g0 { g0 / (g0 - g1) } else { 0.5 };
    for _ in 0..8 {
        let v = value(s);
        if (v > 0.0) == (g0 > 0.0) {
            lo = s;
        } else {
            hi = s;
        }
        let d = slope(s);
        let next = if d != 0.0 { s - v / d } else { 0.5 * (lo + hi) };
        s = if next > lo && next < hi {
            next
        } else {
            0.5 * (lo + hi)
        };
    }
    s.clamp(0.0, 1.0)
}

impl Surface {
    /// The state component the surface's event function depends on (x or z).
    fn axis(&self) -> usize {
        match self {
            Self::Table | Self::TableMiss | Self::Floor => 2,
            Self::Net | Self::Plane(_) => 0,
        }
    }
}

/// Largest number of root-finding iterations for one event time.
const MAX_ROOT_ITERATIONS: usize = 100;

/// An event function this close to zero [m] is at its root: 1e-15 m, some 1e-16 s of a
/// ball's flight, so that the event's time is exact to the rounding of the state and its
/// derivatives match finite differences of the propagation.
const EVENT_TOLERANCE: f64 = 1e-15;

/// Relative tolerance under which a duration counts as a whole number of steps (or a step as a
/// whole number of sample intervals): `0.02 * 3.0` is a rounding error over `0.06`.
pub(crate) const WHOLE_STEPS_TOLERANCE: f64 = 1e-9;

/// The propagator: flight model, table bounce, table geometry and the largest RK4 step.
/// Small and on the stack: a copy with other physical parameters ([`Self::with_params`]) costs
/// nothing on the heap.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Propagator {
    flight: FlightModel,
    bounce: TableBounce,
    radius: f64,
    half_length: f64,
    half_width: f64,
    net_height: f64,
    net_half_span: f64,
    floor_z: f64,
    max_step: f64,
    /// Grows (or, negative, shrinks) the table outline for bounces [m].
    edge_margin: f64,
}

impl Propagator {
    /// The propagator of the configured physics, with `prediction.step` as its largest step.
    pub fn new(config: &Config) -> Self {
        Self::with_step(config, config.prediction.step)
    }

    /// The propagator of the configured physics with another largest step [s].
    pub fn with_step(config: &Config, max_step: f64) -> Self {
        Self {
            flight: FlightModel::new(config),
            bounce: TableBounce::new(config),
            radius: config.ball.radius,
            half_length: 0.5 * config.table.length,
            half_width: 0.5 * config.table.width,
            net_height: config.table.net_height,
            net_half_span: 0.5 * config.table.width + config.table.net_overhang,
            floor_z: -config.table.height,
            max_step,
            edge_margin: 0.0,
        }
    }

    /// The same propagator with another largest step [s] (e.g. a sensitivity that needs less
    /// accuracy than the state).
    pub fn with_max_step(&self, max_step: f64) -> Self {
        Self { max_step, ..*self }
    }

    /// The same propagator with the table outline grown by `margin` [m] on every side (shrunk
    /// when negative), e.g. a table without edges for a solver that must not see the ball
    /// fall off it.
    pub fn with_edge_margin(&self, margin: f64) -> Self {
        Self {
            edge_margin: margin,
            ..*self
        }
    }

    /// The same propagator for a spin known to a variance across the flight
    /// ([`FlightModel::with_spin_variance`]).
    pub fn with_spin_variance(&self, variance: f64) -> Self {
        Self {
            flight: self.flight.with_spin_variance(variance),
            ..*self
        }
    }

    /// The same propagator with other physical parameters (drag and Magnus scales, the
    /// table's restitution and friction).
    pub fn with_params(&self, params: &PhysicsParams) -> Self {
        Self {
            flight: self
                .flight
                .with_scales(params.drag_scale, params.magnus_scale),
            bounce: self.bounce.with_table(params.restitution, params.friction),
            ..*self
        }
    }

    /// The same propagator with other Reynolds exponents (a_D, a_M)
    /// ([`FlightModel::with_reynolds_exponents`]).
    pub fn with_reynolds_exponents(&self, exponents: [f64; 2]) -> Self {
        Self {
            flight: self.flight.with_reynolds_exponents(exponents),
            ..*self
        }
    }

    /// The physical parameters it propagates with.
    pub fn params(&self) -> PhysicsParams {
        let (drag_scale, magnus_scale) = self.flight.scales();
        let (restitution, friction) = self.bounce.table();
        PhysicsParams {
            drag_scale,
            magnus_scale,
            restitution,
            friction,
        }
    }

    /// The distance of a ball centre from the table's outline in the plane [m]: negative inside.
    pub fn distance_outside_table(&self, x: f64, y: f64) -> f64 {
        (x.abs() - self.half_length).max(y.abs() - self.half_width)
    }

    /// Where a bounce in state `x` lands relative to the lines that decide what it means, the
    /// table's outline and the net's line x = 0: the distance to the nearer [m] (positive on
    /// the table), and its gradient.
    pub fn landing_margin(&self, x: &StateVector) -> (f64, StateRow) {
        let (inside, gradient) = self.outline_margin(x);
        let to_net = x[0].abs();
        if to_net < inside {
            let mut gradient = StateRow::zeros();
            gradient[0] = if x[0] < 0.0 { -1.0 } else { 1.0 };
            (to_net, gradient)
        } else {
            (inside, gradient)
        }
    }

    /// The signed distance of a ball centre in state `x` from the table's outline (as grown or
    /// shrunk by the edge margin) in the plane [m], positive inside, and its gradient.
    pub fn outline_margin(&self, x: &StateVector) -> (f64, StateRow) {
        let sign = |v: f64| if v < 0.0 { -1.0 } else { 1.0 };
        let to_end = self.half_length + self.edge_margin - x[0].abs();
        let to_side = self.half_width + self.edge_margin - x[1].abs();
        let mut gradient = StateRow::zeros();
        if to_end <= to_side {
            gradient[0] = -sign(x[0]);
            (to_end, gradient)
        } else {
            gradient[1] = -sign(x[1]);
            (to_side, gradient)
        }
    }

    /// How a net crossing in state `x` misses the net [m]: the largest of the ball's clearance
    /// over the net, its distance beyond a post and its depth under the table top (negative for
    /// a hit: all three negative), and its gradient.
    pub fn net_margin(&self, x: &StateVector) -> (f64, StateRow) {
        let clearance = x[2] - self.radius - self.net_height;
        let beside = x[1].abs() - self.net_half_span;
        let below = -(x[2] + self.radius);
        let margin = clearance.max(beside).max(below);
        let mut gradient = StateRow::zeros();
        if margin == clearance {
            gradient[2] = 1.0;
        } else if margin == beside {
            gradient[1] = if x[1] < 0.0 { -1.0 } else { 1.0 };
        } else {
            gradient[2] = -1.0;
        }
        (margin, gradient)
    }

    /// The flight model.
    pub fn flight(&self) -> &FlightModel {
        &self.flight
    }

    /// The table-bounce model.
    pub fn bounce(&self) -> &TableBounce {
        &self.bounce
    }

    /// The largest RK4 step [s].
    pub fn max_step(&self) -> f64 {
        self.max_step
    }

    /// Advances `cursor` by `duration` seconds on a uniform grid of steps no longer than the
    /// largest step (to a relative 1e-9), handling every event on the way. The observer sees each
    /// event and each grid step. A non-positive or non-finite duration does nothing. A ball that
    /// starts touching the table (0 < z <= r, inside the outline) while moving down bounces at
    /// once.
    pub fn advance(
        &self,
        cursor: &mut Cursor,
        duration: f64,
        watch: Watch,
        observer: &mut impl Observer,
    ) -> Outcome {
        if !duration.is_finite() || duration <= 0.0 {
            return Outcome::Reached;
        }
        let z = cursor.state[2];
        if z > 0.0
            && z <= self.radius
            && cursor.state[VELOCITY + 2] < 0.0
            && self.over_table(&cursor.state)
        {
            let event = self.table_bounce(cursor);
            if observer.on_event(&event) == Flow::Stop {
                return Outcome::Stopped;
            }
        }
        // A duration a rounding error over a whole number of largest steps takes that number.
        let steps = (duration / self.max_step * (1.0 - WHOLE_STEPS_TOLERANCE))
            .ceil()
            .max(1.0);
        let h = duration / steps;
        let t_start = cursor.t;
        let count = steps as u64;
        for k in 1..=count {
            let target = if k == count {
                t_start + duration
            } else {
                t_start + k as f64 * h
            };
            if let Some(outcome) = self.step_to(cursor, target, watch, observer) {
                return outcome;
            }
            if observer.on_step(cursor) == Flow::Stop {
                return Outcome::Stopped;
            }
        }
        Outcome::Reached
    }

    /// Moves the cursor to the fixed time `target`, stopping at the events on the way.
    fn step_to(
        &self,
        cursor: &mut Cursor,
        target: f64,
        watch: Watch,
        observer: &mut impl Observer,
    ) -> Option<Outcome> {
        loop {
            let h = target - cursor.t;
            if h <= 0.0 {
                cursor.t = target;
                return None;
            }
            let start = cursor.state;
            // The whole step with its sensitivities, kept unless an event cuts it short.
            let full = cursor
                .tangent
                .as_ref()
                .map(|tangent| self.rk4_tangent(&start, h, tangent));
            let end = full
                .as_ref()
                .map_or_else(|| self.rk4(&start, h), |step| step.state);
            let Some((surface, tau)) = self.first_event(&start, &end, h, watch) else {
                match full {
                    Some(step) => Self::commit_step(cursor, &step, None),
                    None => cursor.state = end,
                }
                cursor.t = target;
                return None;
            };
            let axis = surface.axis();
            self.take_step(cursor, tau, Some(axis));
            cursor.t += tau;
            let event = match surface {
                Surface::Table => {
                    cursor.state[axis] = self.radius;
                    self.table_bounce(cursor)
                }
                Surface::Net => {
                    cursor.state[axis] = 0.0;
                    let clearance = cursor.state[2] - self.radius - self.net_height;
                    let hit = self.net_margin(&cursor.state).0 < 0.0;
                    self.passing_event(cursor, EventKind::Net { clearance, hit })
                }
                Surface::TableMiss => {
                    cursor.state[axis] = self.radius;
                    let distance = self.outline_margin(&cursor.state).0.abs();
                    self.passing_event(cursor, EventKind::TableMiss { distance })
                }
                Surface::Floor => {
                    cursor.state[axis] = self.radius + self.floor_z;
                    self.passing_event(cursor, EventKind::Floor)
                }
                Surface::Plane(x) => {
                    cursor.state[axis] = x;
                    self.passing_event(cursor, EventKind::Plane { x })
                }
            };
            if event.kind.is_terminal() {
                observer.on_event(&event);
                return Some(Outcome::Terminated(event.kind));
            }
            if observer.on_event(&event) == Flow::Stop {
                return Some(Outcome::Stopped);
            }
        }
    }

    /// An event that leaves the state unchanged.
    fn passing_event(&self, cursor: &Cursor, kind: EventKind) -> Event {
        Event {
            kind,
            t: cursor.t,
            before: cursor.state,
            after: cursor.state,
            sensitivity: cursor.tangent.as_ref().map(|t| {
                let transition = t.transition();
                EventSensitivity {
                    before: transition,
                    after: transition,
                    time_gradient: t.time_gradient,
                    params: t.params().zip(t.param_time_gradient()).map(|(p, time)| {
                        EventParamSensitivity {
                            before: p,
                            after: p,
                            time_gradient: time,
                        }
                    }),
                }
            }),
        }
    }

    /// Applies a table bounce to the cursor's state (and tangent) and describes it.
    fn table_bounce(&self, cursor: &mut Cursor) -> Event {
        let before = cursor.state;
        let bounce = self.bounce.apply(&before);
        cursor.state = bounce.state;
        let sensitivity = cursor.tangent.as_mut().map(|tangent| {
            let transition_before = tangent.transition();
            let transition_after = bounce.jacobian * transition_before;
            // dx+/dtheta = J dx-/dtheta + db/dtheta (the table's columns).
            let params = tangent.params().map(|before| {
                let mut after = bounce.jacobian * before;
                let mut table = after.fixed_columns_mut::<2>(RESTITUTION);
                table += bounce.table_jacobian;
                (before, after)
            });
            tangent.restart_at(transition_after, params.map(|(_, after)| after));
            EventSensitivity {
                before: transition_before,
                after: transition_after,
                time_gradient: tangent.time_gradient,
                params: params
                    .zip(tangent.param_time_gradient())
                    .map(|((before, after), time)| EventParamSensitivity {
                        before,
                        after,
                        time_gradient: time,
                    }),
            }
        });
        Event {
            kind: EventKind::TableBounce {
                regime: bounce.regime,
            },
            t: cursor.t,
            before,
            after: bounce.state,
            sensitivity,
        }
    }

    /// True when the ball centre is over the playing surface.
    fn over_table(&self, x: &StateVector) -> bool {
        self.distance_outside_table(x[0], x[1]) <= self.edge_margin
    }

    /// The earliest event inside a step from `start` to `end` (step size `h`), with its offset
    /// from the step's start.
    fn first_event(
        &self,
        start: &StateVector,
        end: &StateVector,
        h: f64,
        watch: Watch,
    ) -> Option<(Surface, f64)> {
        let surfaces = [
            Some(Surface::Table),
            watch.net.then_some(Surface::Net),
            watch.floor.then_some(Surface::Floor),
            watch.plane_x.map(Surface::Plane),
        ];
        let mut first: Option<(Surface, f64)> = None;
        for surface in surfaces.into_iter().flatten() {
            let g0 = self.event_function(surface, start);
            let g1 = self.event_function(surface, end);
            let downward_only = matches!(surface, Surface::Table | Surface::Floor);
            let crossed = (g0 > 0.0 && g1 <= 0.0) || (!downward_only && g0 < 0.0 && g1 >= 0.0);
            if !crossed {
                continue;
            }
            let tau = self.event_time(surface, (start, end), h, (g0, g1));
            if first.is_some_and(|(_, earliest)| earliest <= tau) {
                continue;
            }
            if surface == Surface::Table && !self.over_table(&self.rk4(start, tau)) {
                if watch.table_misses {
                    first = Some((Surface::TableMiss, tau));
                }
                continue;
            }
            first = Some((surface, tau));
        }
        first
    }

    /// The signed distance of the state from a surface, zero at the event [m].
    fn event_function(&self, surface: Surface, x: &StateVector) -> f64 {
        match surface {
            Surface::Table | Surface::TableMiss => x[2] - self.radius,
            Surface::Floor => x[2] - self.radius - self.floor_z,
            Surface::Net => x[0],
            Surface::Plane(c) => x[0] - c,
        }
    }

    /// The offset tau in (0, h] where the RK4 map from `start` reaches the surface, its event
    /// function `g0` at the start and `g1` at `end`, h later: a root of the RK4 map to
    /// [`EVENT_TOLERANCE`]. The first guess is the root of the cubic Hermite interpolant of the
    /// event function over the step (its slope at either end is the velocity along the
    /// surface's axis), the next ones Newton steps on the RK4 map (its slope taken as the
    /// velocity of the state it reaches), a step that leaves the bracket replaced by the
    /// Illinois variant of regula falsi, which keeps the root bracketed.
    fn event_time(
        &self,
        surface: Surface,
        (start, end): (&StateVector, &StateVector),
        h: f64,
        (g0, g1): (f64, f64),
    ) -> f64 {
        let (mut a, mut fa, mut b, mut fb) = (0.0, g0, h, g1);
        if fb == 0.0 {
            return b;
        }
        let slope_axis = VELOCITY + surface.axis();
        let mut c = h * hermite_root(g0, start[slope_axis] * h, g1, end[slope_axis] * h);
        let mut last_side = 0i8;
        for _ in 0..MAX_ROOT_ITERATIONS {
            if !(c > a && c < b) {
                c = ((a * fb - b * fa) / (fb - fa)).clamp(a, b);
            }
            let x = self.rk4(start, c);
            let fc = self.event_function(surface, &x);
            if fc.abs() <= EVENT_TOLERANCE || c <= a || c >= b {
                return c;
            }
            if (fc > 0.0) == (fb > 0.0) {
                b = c;
                fb = fc;
                if last_side == -1 {
                    fa *= 0.5;
                }
                last_side = -1;
            } else {
                a = c;
                fa = fc;
                if last_side == 1 {
                    fb *= 0.5;
                }
                last_side = 1;
            }
            if b - a <= f64::EPSILON * h {
                break;
            }
            let slope = x[slope_axis];
            c = if slope != 0.0 {
                c - fc / slope
            } else {
                a - 1.0
            };
        }
        if fa.abs() < fb.abs() { a } else { b }
    }

    /// Moves the cursor's state (and tangent) by one RK4 step of size `h`. With `event_axis`, the
    /// step ends on a surface whose event function is that state component (see
    /// [`Self::commit_step`]).
    fn take_step(&self, cursor: &mut Cursor, h: f64, event_axis: Option<usize>) {
        match &cursor.tangent {
            None => cursor.state = self.rk4(&cursor.state, h),
            Some(tangent) => {
                let step = self.rk4_tangent(&cursor.state, h, tangent);
                Self::commit_step(cursor, &step, event_axis);
            }
        }
    }

    /// Moves a cursor with a tangent to the end of `step`. Without `event_axis` the step ended at
    /// a fixed time; with it, on a surface whose event function is that state component: the step
    /// size then depends on the initial state, and the tangent's time gradient is updated from it.
    fn commit_step(cursor: &mut Cursor, step: &TangentStep, event_axis: Option<usize>) {
        cursor.state = step.state;
        let Some(tangent) = cursor.tangent.as_mut() else {
            return;
        };
        match event_axis {
            None if !tangent.time_moves() => {
                tangent.flight = step.flight;
                if let (Some(p), Some(flight)) = (tangent.params.as_mut(), step.params) {
                    p.flight = flight;
                }
            }
            None => {
                // The step ends at a fixed time: h = target - t moves with -time_gradient.
                let transition = step.transition(tangent) - step.rate * tangent.time_gradient;
                let params = step
                    .param_sensitivity(tangent)
                    .zip(tangent.params)
                    .map(|(sensitivity, p)| sensitivity - step.rate * p.time_gradient);
                tangent.restart_at(transition, params);
                tangent.time_gradient = StateRow::zeros();
                if let Some(p) = tangent.params.as_mut() {
                    p.time_gradient = ParamRow::zeros();
                }
            }
            Some(axis) => {
                // g(x(tau)) = 0 fixes tau: dtau = -dg/dx0 / dg/dtau (and likewise for the
                // parameters).
                let dtau = -step.transition_row(tangent, axis) / step.rate[axis];
                let transition = step.transition(tangent) + step.rate * dtau;
                let params = step.param_sensitivity(tangent).map(|sensitivity| {
                    let dtau = -sensitivity.row(axis) / step.rate[axis];
                    (sensitivity + step.rate * dtau, dtau)
                });
                tangent.restart_at(transition, params.map(|(sensitivity, _)| sensitivity));
                tangent.time_gradient += dtau;
                if let (Some(p), Some((_, dtau))) = (tangent.params.as_mut(), params) {
                    p.time_gradient += dtau;
                }
            }
        }
    }

    /// One classical RK4 step of size `h`.
    pub fn rk4(&self, x: &StateVector, h: f64) -> StateVector {
        let f = &self.flight;
        let k1 = f.derivative(x);
        let k2 = f.derivative(&(x + k1 * (0.5 * h)));
        let k3 = f.derivative(&(x + k2 * (0.5 * h)));
        let k4 = f.derivative(&(x + k3 * h));
        x + (k1 + (k2 + k3) * 2.0 + k4) * (h / 6.0)
    }

    /// One RK4 step with the exact derivatives of the discrete map with respect to the initial
    /// state (pre-multiplied into the tangent's flight transition), to the step size and, when
    /// the tangent tracks them, to the physical parameters.
    fn rk4_tangent(&self, x: &StateVector, h: f64, tangent: &Tangent) -> TangentStep {
        let flight = &tangent.flight;
        let f = &self.flight;
        let half = 0.5 * h;
        let (k1, a1) = f.derivative_and_jacobian(x);
        let (k2, a2) = f.derivative_and_jacobian(&(x + k1 * half));
        let (k3, a3) = f.derivative_and_jacobian(&(x + k2 * half));
        let (k4, a4) = f.derivative_and_jacobian(&(x + k3 * h));
        let slope = (k1 + (k2 + k3) * 2.0 + k4) / 6.0;

        let p1 = a1.apply_flight(flight);
        let p2 = a2.apply_flight(&flight.add_scaled(&p1, half));
        let p3 = a3.apply_flight(&flight.add_scaled(&p2, half));
        let p4 = a4.apply_flight(&flight.add_scaled(&p3, h));
        let p23 = p2.add_scaled(&p3, 1.0);

        let d2 = a2.apply(&(k1 * 0.5));
        let d3 = a3.apply(&(k2 * 0.5 + d2 * half));
        let d4 = a4.apply(&(k3 + d3 * h));

        // The parameters' sensitivity S at a fixed state after the last event:
        // dk_i = A_i (S + c_i h dk_(i-1)) + B_i, S' = S + h/6 (dk1 + 2 dk2 + 2 dk3 + dk4).
        let params = tangent.params.as_ref().map(|p| {
            let s = &p.flight;
            let q1 = a1.apply_params(s);
            let q2 = a2.apply_params(&(s + q1 * half));
            let q3 = a3.apply_params(&(s + q2 * half));
            let q4 = a4.apply_params(&(s + q3 * h));
            s + (q1 + (q2 + q3) * 2.0 + q4) * (h / 6.0)
        });

        TangentStep {
            state: x + slope * h,
            flight: flight.add_scaled(&p1.add_scaled(&p23, 2.0).add_scaled(&p4, 1.0), h / 6.0),
            params,
            rate: slope + ((d2 + d3) * 2.0 + d4) * (h / 6.0),
        }
    }
}
