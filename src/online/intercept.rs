//! The interception prediction: where and when the ball crosses the robot's hitting plane
//! x = plane_x moving toward the robot after exactly one bounce on the robot's half, with the 9x9
//! covariance at the crossing.
//!
//! The covariance is J P J' with J = d(state at the crossing)/d(state now), the crossing time
//! moving with the state (J = Phi + f dtau/dx, the event sensitivity of the propagation), so the
//! timing uncertainty is included: the x row is zero (the ball is on the plane by definition) and
//! the spread of the crossing time shows in y, z and the velocity; its own variance is
//! dtau/dx P dtau/dx'. A bounce still ahead adds what the filter adds at a bounce
//! ([`crate::online::ekf`]): its scatter and its outcome's spread beyond the linearisation (the
//! bounce map over sigma points at the bounce), as J_b Q J_b' with J_b the crossing's sensitivity
//! to the state just after the bounce (docs/estimator.md, "Interception").
//!
//! [`InterceptTracker`] keeps the interception up to date detection by detection: between full
//! predictions it flies the last full prediction's start state along (its "anchor") and moves the
//! crossing to first order in the estimate's drift from it, d = x - anchor: crossing state
//! y + J d, time tau + dtau/dx d, covariance J P J' (plus the full prediction's bounce spread),
//! where J, the crossing's sensitivity to the anchor, is carried along by the inverse of the
//! anchor's own flight transition (J_now = J_then Phi^-1; free-flight transitions form a group,
//! [`crate::physics::FlightMatrix`]).
//! It predicts in full again at any event on the anchor's way (a bounce, the net, the plane, a near
//! miss of the table), when the drift could change a branch of the prediction (each branch point
//! recorded as a margin with its gradient: a bounce's sliding/rolling regime, where it lands
//! against the table's edge and the net line, how the ball passes the net or misses the table, the
//! crossing or the bounce coming due), when the drift exceeds its limits, and when the last full
//! prediction is older than its age limit (`intercept.refresh`, [`RefreshParams`]).

use nalgebra::{SMatrix, SVector, Vector2, Vector3};

use crate::config::RefreshParams;
use crate::online::bounce_spread::{bounce_inputs_at_event, bounce_spread};
use crate::online::ekf::{BounceNoise, bounce_scatter};
use crate::physics::params::{FRICTION, RESTITUTION, with_known_params};
use crate::physics::{
    AUGMENTED, AugmentedMatrix, BallState, Cursor, Event, EventKind, EventSensitivity, Flow,
    Observer, Outcome, PARAMS, ParamMatrix, ParamRow, ParamVector, Propagator, StateMatrix,
    StateRow, StateVector, Watch,
};

/// Why there is no valid interception.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum NoIntercept {
    /// The ball will hit the net.
    NetHit,
    /// The ball will reach the floor without a valid crossing (it misses the table).
    MissesTable,
    /// The ball will cross the plane without bouncing on the robot's half.
    NoBounce,
    /// The ball will bounce twice on the robot's half before the plane.
    TwoBounces,
    /// The ball will not reach the plane within the horizon (or moves away from the robot).
    NotWithinHorizon,
}

impl NoIntercept {
    /// A short explanation for logs.
    pub fn describe(self) -> &'static str {
        match self {
            Self::NetHit => "the ball will hit the net",
            Self::MissesTable => "the ball will miss the table",
            Self::NoBounce => "the ball will reach the plane without bouncing on the robot's half",
            Self::TwoBounces => "the ball will bounce twice on the robot's half",
            Self::NotWithinHorizon => "the ball will not reach the plane within the horizon",
        }
    }
}

/// The predicted crossing of the hitting plane.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Crossing {
    /// Time from now to the crossing [s].
    pub time: f64,
    /// Standard deviation of that time [s].
    pub time_sigma: f64,
    /// State at the crossing.
    pub state: BallState,
    /// Covariance of the state at the crossing, timing uncertainty included.
    pub covariance: StateMatrix,
}

impl Crossing {
    /// The crossing point's error from `point` in the plane (y, z) normalised by its predicted
    /// covariance, per dimension (the NEES: about 1 when the covariance is honest); `None` when
    /// that covariance is singular.
    pub fn point_nees(&self, point: &Vector3<f64>) -> Option<f64> {
        let error = Vector2::new(
            self.state.position.y - point.y,
            self.state.position.z - point.z,
        );
        let covariance = self.covariance.fixed_view::<2, 2>(1, 1).into_owned();
        let chol = covariance.cholesky()?;
        Some(error.dot(&chol.solve(&error)) / 2.0)
    }
}

/// The predicted bounce on the robot's half.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PredictedBounce {
    /// Time from now to the bounce [s].
    pub time: f64,
    /// Ball centre at the bounce [m].
    pub position: Vector3<f64>,
}

/// The interception prediction.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Intercept {
    /// The crossing, or why there is none.
    pub crossing: Result<Crossing, NoIntercept>,
    /// The bounce on the robot's half before the crossing, when there is one ahead.
    pub bounce: Option<PredictedBounce>,
}

/// What the caller knows about the ball now.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct InterceptQuery {
    /// The hitting plane's x [m].
    pub plane_x: f64,
    /// How far ahead to look [s].
    pub horizon: f64,
    /// The ball has already bounced on the robot's half since it crossed the net.
    pub bounced_on_robot_half: bool,
    /// The scatter of a bounce ahead, and whether its outcome's spread beyond the
    /// linearisation is found by sigma points: both enter the crossing's covariance.
    pub bounce_noise: BounceNoise,
}

/// d(an event's position and time)/d(the state predicted from), and d/d(the parameters) when
/// they are uncertain.
#[derive(Debug, Clone, Copy, PartialEq)]
struct BounceSensitivity {
    position: SMatrix<f64, 3, 9>,
    time: StateRow,
    params: Option<(SMatrix<f64, 3, PARAMS>, ParamRow)>,
}

/// d(state at the crossing)/d(state) and d(crossing time)/d(state), and d/d(the parameters)
/// when they are uncertain.
#[derive(Debug, Clone, Copy, PartialEq)]
struct CrossingSensitivity {
    state: StateMatrix,
    time: StateRow,
    params: Option<(ParamMatrix, ParamRow)>,
    /// What the bounce ahead adds to the crossing's covariance beyond J P J' (its scatter and
    /// its outcome's spread beyond the linearisation, carried to the crossing), and to its
    /// time's variance.
    bounce_spread: Option<(StateMatrix, f64)>,
}

impl CrossingSensitivity {
    /// d(state at the crossing)/d(state, parameters).
    fn augmented_state(&self) -> SMatrix<f64, 9, AUGMENTED> {
        let mut j = SMatrix::<f64, 9, AUGMENTED>::zeros();
        j.fixed_columns_mut::<9>(0).copy_from(&self.state);
        if let Some((params, _)) = &self.params {
            j.fixed_columns_mut::<PARAMS>(9).copy_from(params);
        }
        j
    }

    /// d(crossing time)/d(state, parameters).
    fn augmented_time(&self) -> SMatrix<f64, 1, AUGMENTED> {
        let mut j = SMatrix::<f64, 1, AUGMENTED>::zeros();
        j.fixed_columns_mut::<9>(0).copy_from(&self.time);
        if let Some((_, time)) = &self.params {
            j.fixed_columns_mut::<PARAMS>(9).copy_from(time);
        }
        j
    }
}

/// Most branch points a prediction may meet and still be moved to first order.
const MAX_BRANCHES: usize = 8;

/// The branch points of a prediction: at each, a margin whose sign decided the branch (a
/// bounce's regime, where it lands, how the ball passes the net) and its gradient with respect
/// to the state predicted from.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Branches {
    margins: [f64; MAX_BRANCHES],
    gradients: SMatrix<f64, MAX_BRANCHES, 9>,
    /// The margins' gradients with respect to the parameters (zero when they are known).
    param_gradients: SMatrix<f64, MAX_BRANCHES, PARAMS>,
    count: usize,
    /// More than [`MAX_BRANCHES`], or one without its gradient.
    overflow: bool,
}

impl Branches {
    fn new() -> Self {
        Self {
            margins: [0.0; MAX_BRANCHES],
            gradients: SMatrix::zeros(),
            param_gradients: SMatrix::zeros(),
            count: 0,
            overflow: false,
        }
    }

    /// Records a margin of the event state whose gradient there is `gradient` (and whose own
    /// gradient with respect to the parameters, at a fixed event state, is `direct`).
    fn record(&mut self, event: &Event, (margin, gradient): (f64, StateRow), direct: ParamRow) {
        match event.sensitivity {
            Some(s) if self.count < MAX_BRANCHES => {
                self.margins[self.count] = margin;
                self.gradients.set_row(self.count, &(gradient * s.before));
                let through_state = s.params.map_or(ParamRow::zeros(), |p| gradient * p.before);
                self.param_gradients
                    .set_row(self.count, &(through_state + direct));
                self.count += 1;
            }
            _ => self.overflow = true,
        }
    }

    /// True when a drift of the state and the parameters keeps every branch: each margin moves
    /// by at most half of itself (to first order).
    fn kept_by(&self, drift: &StateVector, param_drift: &ParamVector) -> bool {
        let moved = self.gradients * drift + self.param_gradients * param_drift;
        !self.overflow && (0..self.count).all(|i| moved[i].abs() <= 0.5 * self.margins[i].abs())
    }
}

struct Watcher<'a> {
    propagator: &'a Propagator,
    robot_half_bounces: u32,
    bounce: Option<(PredictedBounce, Option<BounceSensitivity>)>,
    /// The robot-half bounce's states just before and after, its time and sensitivities.
    bounce_event: Option<(StateVector, StateVector, f64, EventSensitivity)>,
    result: Option<Result<Event, NoIntercept>>,
    branches: Branches,
}

impl Observer for Watcher<'_> {
    fn on_event(&mut self, event: &Event) -> Flow {
        let none = ParamRow::zeros();
        match event.kind {
            EventKind::TableBounce { .. } => {
                let p = self.propagator;
                // The regime margin mu (1 + e) |v_z| - 2/5 |u| moves with the table's two.
                let (e, mu) = p.bounce().table();
                let vz = event.before[5].abs();
                let mut direct = ParamRow::zeros();
                direct[RESTITUTION] = mu * vz;
                direct[FRICTION] = (1.0 + e) * vz;
                self.branches
                    .record(event, p.bounce().regime_margin(&event.before), direct);
                self.branches
                    .record(event, p.landing_margin(&event.before), none);
            }
            EventKind::Net { .. } => {
                self.branches
                    .record(event, self.propagator.net_margin(&event.before), none);
            }
            EventKind::TableMiss { .. } => {
                self.branches
                    .record(event, self.propagator.outline_margin(&event.before), none);
            }
            _ => {}
        }
        match event.kind {
            EventKind::TableBounce { .. } if event.before[0] < 0.0 => {
                self.robot_half_bounces += 1;
                if self.robot_half_bounces > 1 {
                    self.result = Some(Err(NoIntercept::TwoBounces));
                    return Flow::Stop;
                }
                let bounce = PredictedBounce {
                    time: event.t,
                    position: event.before.fixed_rows::<3>(0).into_owned(),
                };
                let sensitivity = event.sensitivity.map(|s| BounceSensitivity {
                    position: s.before.fixed_rows::<3>(0).into_owned(),
                    time: s.time_gradient,
                    params: s
                        .params
                        .map(|p| (p.before.fixed_rows::<3>(0).into_owned(), p.time_gradient)),
                });
                self.bounce = Some((bounce, sensitivity));
                self.bounce_event = event
                    .sensitivity
                    .map(|s| (event.before, event.after, event.t, s));
            }
            EventKind::Plane { .. } if event.before[3] < 0.0 => {
                self.result = Some(if self.robot_half_bounces == 1 {
                    Ok(*event)
                } else {
                    Err(NoIntercept::NoBounce)
                });
                return Flow::Stop;
            }
            EventKind::Net { hit: true, .. } => self.result = Some(Err(NoIntercept::NetHit)),
            EventKind::Floor => self.result = Some(Err(NoIntercept::MissesTable)),
            _ => {}
        }
        Flow::Continue
    }
}

/// Predicts the interception from state `x` with covariance `p`, the propagator's parameters
/// known exactly (see the module doc).
pub fn predict_intercept(
    propagator: &Propagator,
    x: &StateVector,
    p: &StateMatrix,
    query: &InterceptQuery,
) -> Intercept {
    predict_in_full(propagator, x, &with_known_params(p), query).0
}

/// Predicts the interception from state `x` and the propagator's parameters, with the covariance
/// `p` of both: the parameters' uncertainty enters the crossing's covariance through the
/// crossing's sensitivity to them.
pub fn predict_intercept_augmented(
    propagator: &Propagator,
    x: &StateVector,
    p: &AugmentedMatrix,
    query: &InterceptQuery,
) -> Intercept {
    predict_in_full(propagator, x, p, query).0
}

/// True when the parameters in `p` are uncertain (their sensitivities are then carried).
fn params_uncertain(p: &AugmentedMatrix) -> bool {
    p.fixed_view::<PARAMS, PARAMS>(9, 9)
        .iter()
        .any(|v| *v != 0.0)
}

/// Sensitivities of a predicted interception to the state it was predicted from.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Sensitivity {
    crossing: Option<CrossingSensitivity>,
    bounce: Option<BounceSensitivity>,
    branches: Branches,
}

fn predict_in_full(
    propagator: &Propagator,
    x: &StateVector,
    p: &AugmentedMatrix,
    query: &InterceptQuery,
) -> (Intercept, Sensitivity) {
    let mut watcher = Watcher {
        propagator,
        branches: Branches::new(),
        robot_half_bounces: u32::from(query.bounced_on_robot_half),
        bounce: None,
        bounce_event: None,
        result: None,
    };
    let mut cursor = if params_uncertain(p) {
        Cursor::tracking_params(0.0, *x)
    } else {
        Cursor::tracking(0.0, *x)
    };
    let watch = Watch {
        plane_x: Some(query.plane_x),
        table_misses: true,
        ..Watch::FLIGHT
    };
    let outcome = propagator.advance(&mut cursor, query.horizon, watch, &mut watcher);
    let crossing = match (watcher.result, outcome) {
        (Some(Ok(event)), _) => Ok(event),
        (Some(Err(reason)), _) => Err(reason),
        (None, Outcome::Terminated(EventKind::Floor)) => Err(NoIntercept::MissesTable),
        (None, Outcome::Terminated(_)) => Err(NoIntercept::NetHit),
        (None, _) => Err(NoIntercept::NotWithinHorizon),
    };
    let crossing_sensitivity = crossing.ok().and_then(|event| {
        event.sensitivity.map(|s| CrossingSensitivity {
            state: s.before,
            time: s.time_gradient,
            params: s.params.map(|p| (p.before, p.time_gradient)),
            bounce_spread: watcher.bounce_event.as_ref().and_then(|bounce| {
                bounce_spread_at_crossing(propagator, p, query, bounce, event.t)
            }),
        })
    });
    let intercept = Intercept {
        crossing: crossing.map(|event| {
            crossing_with(
                event.t,
                BallState::from_vector(&event.before),
                crossing_sensitivity.as_ref(),
                p,
            )
        }),
        bounce: watcher.bounce.map(|(bounce, _)| bounce),
    };
    let sensitivity = Sensitivity {
        crossing: crossing_sensitivity,
        bounce: watcher.bounce.and_then(|(_, s)| s),
        branches: watcher.branches,
    };
    (intercept, sensitivity)
}

/// Records the first crossing of the plane toward the robot.
struct PlaneCrossing(Option<Event>);

impl Observer for PlaneCrossing {
    fn on_event(&mut self, event: &Event) -> Flow {
        match event.kind {
            EventKind::Plane { .. } if event.before[3] < 0.0 => {
                self.0 = Some(*event);
                Flow::Stop
            }
            EventKind::TableBounce { .. } => Flow::Stop,
            _ => Flow::Continue,
        }
    }
}

/// What a bounce ahead adds to the crossing's covariance beyond J P J': its scatter at the
/// configured sigmas and its outcome's spread beyond the linearisation
/// ([`crate::online::bounce_spread`]), both in the state just after it, carried to the
/// crossing by the flight from the bounce (its own tangent); with the crossing time's variance.
/// `None` when nothing is added.
fn bounce_spread_at_crossing(
    propagator: &Propagator,
    p: &AugmentedMatrix,
    query: &InterceptQuery,
    (before, after, t_bounce, sensitivity): &(StateVector, StateVector, f64, EventSensitivity),
    t_crossing: f64,
) -> Option<(StateMatrix, f64)> {
    let inputs = bounce_inputs_at_event(sensitivity, p);
    let q = bounce_scatter(propagator, &query.bounce_noise, before)
        + bounce_spread(propagator, before, after, &inputs);
    if q == StateMatrix::zeros() {
        return None;
    }
    // A little past the crossing's time, so that the plane is met whatever the rounding; in one
    // step, or in the prediction's own where one step meets something else first.
    let duration = (t_crossing - t_bounce) * 1.01 + 1e-3;
    let s = [duration, propagator.max_step()]
        .into_iter()
        .find_map(|step| plane_sensitivity(propagator, after, duration, query.plane_x, step))?;
    let added = s.before * q * s.before.transpose();
    let added_time = (s.time_gradient * q * s.time_gradient.transpose())[(0, 0)];
    Some(((added + added.transpose()) * 0.5, added_time.max(0.0)))
}

/// d(state at the crossing of x = `plane_x`)/d(`start`), the crossing time moving, from a flight
/// of at most `duration` seconds in steps of at most `step`; `None` when the flight meets a bounce
/// or nothing first. One step over a smooth flight of a few tenths of a second is enough for a
/// sensitivity (the crossing's spread within 1 % of the prediction's 20 ms steps,
/// `tests::one_step_carries_the_bounce_spread_as_the_prediction_s_steps_do`).
fn plane_sensitivity(
    propagator: &Propagator,
    start: &StateVector,
    duration: f64,
    plane_x: f64,
    step: f64,
) -> Option<EventSensitivity> {
    let mut cursor = Cursor::tracking(0.0, *start);
    let watch = Watch {
        plane_x: Some(plane_x),
        ..Watch::FLIGHT
    };
    let mut crossing = PlaneCrossing(None);
    propagator
        .with_max_step(step)
        .advance(&mut cursor, duration, watch, &mut crossing);
    crossing.0?.sensitivity
}

/// A crossing at `time` in `state`, its covariance from the sensitivities and `p`.
fn crossing_with(
    time: f64,
    state: BallState,
    sensitivity: Option<&CrossingSensitivity>,
    p: &AugmentedMatrix,
) -> Crossing {
    let (covariance, time_sigma) = match sensitivity {
        Some(s) if s.params.is_some() => {
            let j = s.augmented_state();
            let t = s.augmented_time();
            let cov = j * p * j.transpose();
            let var_t = (t * p * t.transpose())[(0, 0)];
            ((cov + cov.transpose()) * 0.5, var_t.max(0.0).sqrt())
        }
        Some(s) => {
            let p = p.fixed_view::<9, 9>(0, 0);
            let cov = s.state * p * s.state.transpose();
            let var_t = (s.time * p * s.time.transpose())[(0, 0)];
            ((cov + cov.transpose()) * 0.5, var_t.max(0.0).sqrt())
        }
        None => (StateMatrix::zeros(), 0.0),
    };
    let (covariance, time_sigma) = match sensitivity.and_then(|s| s.bounce_spread) {
        Some((added, added_time)) => (
            covariance + added,
            (time_sigma * time_sigma + added_time).sqrt(),
        ),
        None => (covariance, time_sigma),
    };
    Crossing {
        time,
        time_sigma,
        state,
        covariance,
    }
}

/// The share of its own standard deviation a state's or a parameter's drift from the anchor may
/// reach before the interception is predicted in full again, where that is more than the
/// configured limit: the moved interception's error is of second order in the drift, the
/// covariance's own linearisation of first order in the standard deviation.
const RELATIVE_REFRESH: f64 = 0.5;

/// True when a drift of the state from the anchor is within the limits: each block's within
/// the configured limit or [`RELATIVE_REFRESH`] of its standard deviation in `p`.
fn within_limits(limits: &RefreshParams, drift: &StateVector, p: &AugmentedMatrix) -> bool {
    let within = |i: usize, limit: f64| {
        let sigma = (p.fixed_view::<3, 3>(i, i).trace() / 3.0).max(0.0).sqrt();
        drift.fixed_rows::<3>(i).norm() <= limit.max(RELATIVE_REFRESH * sigma)
    };
    within(0, limits.position) && within(3, limits.velocity) && within(6, limits.spin)
}

/// How many interceptions a tracker predicted in full and how many it moved.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct TrackerCounts {
    /// Predicted in full.
    pub full: u64,
    /// Moved to first order from the last full prediction.
    pub moved: u64,
}

/// How far each physical parameter (k_D, k_M, e_t, mu_t) may move from the last full
/// prediction's before the interception is predicted in full again (the moved interception
/// follows them to first order; the crossing moves by about 0.1 m per unit of the Magnus scale
/// at 0.3 s ahead).
const PARAM_REFRESH: [f64; PARAMS] = [0.005, 0.01, 0.003, 0.005];

/// The last full prediction, its start state flown to the latest stamp.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Anchor {
    track_id: u32,
    query: InterceptQuery,
    /// The physical parameters it was predicted with.
    params: ParamVector,
    /// Stamp of `flown` [ns].
    stamp: i64,
    /// The full prediction's start state, flown to `stamp`.
    flown: StateVector,
    /// Time from the full prediction's start to `stamp` [s].
    elapsed: f64,
    /// The full prediction (times from its start).
    base: Intercept,
    /// Its sensitivities to `flown`.
    sensitivity: Sensitivity,
}

/// Observes whether a propagation met any event.
struct AnyEvent(bool);

impl Observer for AnyEvent {
    fn on_event(&mut self, _event: &Event) -> Flow {
        self.0 = true;
        Flow::Stop
    }
}

impl Anchor {
    /// The anchor flown on by `dt` seconds, its sensitivities carried along; `None` when the
    /// flight meets an event (the last full prediction's events are then at hand).
    fn flown_on(&self, propagator: &Propagator, dt: f64, stamp: i64) -> Option<Self> {
        let tracks_params = self
            .sensitivity
            .crossing
            .is_some_and(|c| c.params.is_some());
        let mut cursor = if tracks_params {
            Cursor::tracking_params(0.0, self.flown)
        } else {
            Cursor::tracking(0.0, self.flown)
        };
        let watch = Watch {
            plane_x: Some(self.query.plane_x),
            table_misses: true,
            ..Watch::FLIGHT
        };
        let mut event = AnyEvent(false);
        propagator.advance(&mut cursor, dt, watch, &mut event);
        if event.0 {
            return None;
        }
        let tangent = cursor.tangent?;
        let back = tangent.free_flight()?.inverse()?;
        // The flight's own sensitivity to the parameters, S: a quantity g(start, theta) of the
        // start flown to x = phi(start, theta) moves with theta at a fixed x by
        // dg/dtheta - (dg/dx) S, dg/dx being the sensitivity carried back.
        let flight_params = tangent.params();
        let crossing = self.sensitivity.crossing.map(|s| {
            let state = back.premultiplied_by(&s.state);
            let time = back.premultiplied_by(&s.time);
            CrossingSensitivity {
                state,
                time,
                params: s.params.map(|(p, t)| {
                    (
                        at_fixed_state(&state, &p, &flight_params),
                        at_fixed_state(&time, &t, &flight_params),
                    )
                }),
                bounce_spread: s.bounce_spread,
            }
        });
        let bounce = self.sensitivity.bounce.map(|s| {
            let position = back.premultiplied_by(&s.position);
            let time = back.premultiplied_by(&s.time);
            BounceSensitivity {
                position,
                time,
                params: s.params.map(|(p, t)| {
                    (
                        at_fixed_state(&position, &p, &flight_params),
                        at_fixed_state(&time, &t, &flight_params),
                    )
                }),
            }
        });
        let mut branches = self.sensitivity.branches;
        branches.gradients = back.premultiplied_by(&branches.gradients);
        if let Some(flight) = flight_params {
            branches.param_gradients -= branches.gradients * flight;
        }
        Some(Self {
            stamp,
            flown: cursor.state,
            elapsed: self.elapsed + dt,
            sensitivity: Sensitivity {
                crossing,
                bounce,
                branches,
            },
            ..*self
        })
    }

    /// The interception from `x` and parameters `theta` (covariance `p`) at the anchor's
    /// stamp, to first order in their drift from the anchor's; `None` when a sensitivity is
    /// missing or the crossing or the bounce comes so soon that the drift could move it into the
    /// past (an event ahead is a branch too).
    fn moved_to(
        &self,
        x: &StateVector,
        theta: &ParamVector,
        p: &AugmentedMatrix,
    ) -> Option<Intercept> {
        let drift = x - self.flown;
        let param_drift = theta - self.params;
        let ahead = |time: f64, gradient: &StateRow, by_params: f64| {
            let ahead = time - self.elapsed;
            let moved = gradient.dot(&drift.transpose()) + by_params;
            (moved.abs() <= 0.5 * ahead).then_some(ahead + moved)
        };
        let crossing = match self.base.crossing {
            Ok(c) => {
                let s = self.sensitivity.crossing?;
                let (state_by_params, time_by_params) = moved_by(&s.params, &param_drift);
                let state = BallState::from_vector(
                    &(c.state.to_vector() + s.state * drift + state_by_params),
                );
                let time = ahead(c.time, &s.time, time_by_params)?;
                Ok(crossing_with(time, state, Some(&s), p))
            }
            Err(reason) => Err(reason),
        };
        let bounce = match (self.base.bounce, self.sensitivity.bounce) {
            (Some(b), Some(s)) => {
                let (position_by_params, time_by_params) = moved_by(&s.params, &param_drift);
                Some(PredictedBounce {
                    time: ahead(b.time, &s.time, time_by_params)?,
                    position: b.position + s.position * drift + position_by_params,
                })
            }
            (None, _) => None,
            (Some(_), None) => return None,
        };
        Some(Intercept { crossing, bounce })
    }
}

/// How far a drift of the parameters moves an event's quantity and its time, to first order,
/// given their sensitivities to the parameters (nothing when those are not carried).
fn moved_by<const R: usize>(
    params: &Option<(SMatrix<f64, R, PARAMS>, ParamRow)>,
    drift: &ParamVector,
) -> (SVector<f64, R>, f64) {
    params.map_or((SVector::zeros(), 0.0), |(p, t)| {
        (p * drift, t.dot(&drift.transpose()))
    })
}

/// d(g)/d(theta) at a fixed flown state x = phi(start, theta), for a quantity g(start, theta)
/// whose sensitivities are `on_x` (carried back to x) and `on_theta` (at a fixed start), the
/// flight from the start to x having sensitivity `flight` to theta: dg/dtheta - (dg/dx) S.
fn at_fixed_state<const R: usize>(
    on_x: &SMatrix<f64, R, 9>,
    on_theta: &SMatrix<f64, R, PARAMS>,
    flight: &Option<ParamMatrix>,
) -> SMatrix<f64, R, PARAMS> {
    match flight {
        Some(s) => on_theta - on_x * s,
        None => *on_theta,
    }
}

/// Keeps the interception of one track up to date from call to call (see the module doc); the
/// calls' stamps must not go back (a call that does predicts in full).
#[derive(Debug, Clone, PartialEq)]
pub struct InterceptTracker {
    refresh: RefreshParams,
    anchor: Option<Anchor>,
    counts: TrackerCounts,
}

impl InterceptTracker {
    /// A tracker that predicts in full as `refresh` says.
    pub fn new(refresh: RefreshParams) -> Self {
        Self {
            refresh,
            anchor: None,
            counts: TrackerCounts::default(),
        }
    }

    /// Predicts as `refresh` says from now on, in full the next time (the plane or horizon may
    /// have changed too).
    pub fn reconfigure(&mut self, refresh: RefreshParams) {
        self.refresh = refresh;
        self.anchor = None;
    }

    /// How many interceptions were predicted in full and how many moved.
    pub fn counts(&self) -> TrackerCounts {
        self.counts
    }

    /// The interception of track `track_id` from state `x` and the propagator's parameters,
    /// with covariance `p` over both, at `stamp` [ns].
    pub fn predict(
        &mut self,
        propagator: &Propagator,
        track_id: u32,
        stamp: i64,
        x: &StateVector,
        p: &AugmentedMatrix,
        query: &InterceptQuery,
    ) -> Intercept {
        if let Some(intercept) = self.move_anchor(propagator, track_id, stamp, x, p, query) {
            self.counts.moved += 1;
            return intercept;
        }
        let (base, sensitivity) = predict_in_full(propagator, x, p, query);
        self.counts.full += 1;
        self.anchor = (self.refresh.max_age > 0.0).then_some(Anchor {
            track_id,
            query: *query,
            params: propagator.params().to_vector(),
            stamp,
            flown: *x,
            elapsed: 0.0,
            base,
            sensitivity,
        });
        base
    }

    fn move_anchor(
        &mut self,
        propagator: &Propagator,
        track_id: u32,
        stamp: i64,
        x: &StateVector,
        p: &AugmentedMatrix,
        query: &InterceptQuery,
    ) -> Option<Intercept> {
        let anchor = self.anchor.as_ref()?;
        // The same question but for the bounce's scatter, which a learned scale moves a little
        // at every detection: the moved interception keeps the full one's until the next.
        let same_query = InterceptQuery {
            bounce_noise: anchor.query.bounce_noise,
            ..*query
        } == anchor.query;
        if anchor.track_id != track_id || !same_query || stamp < anchor.stamp {
            return None;
        }
        let theta = propagator.params().to_vector();
        let param_drift = theta - anchor.params;
        let param_limit =
            |i: usize| PARAM_REFRESH[i].max(RELATIVE_REFRESH * p[(9 + i, 9 + i)].max(0.0).sqrt());
        if (0..PARAMS).any(|i| param_drift[i].abs() > param_limit(i)) {
            return None;
        }
        let dt = (stamp - anchor.stamp) as f64 * 1e-9;
        if anchor.elapsed + dt > self.refresh.max_age {
            return None;
        }
        if dt > 0.0 {
            // The anchor flies on with its own parameters.
            let anchor_propagator =
                propagator.with_params(&crate::physics::PhysicsParams::from_vector(&anchor.params));
            let flown = anchor.flown_on(&anchor_propagator, dt, stamp)?;
            self.anchor = Some(flown);
        }
        let anchor = self.anchor.as_ref()?;
        let drift = x - anchor.flown;
        if !within_limits(&self.refresh, &drift, p)
            || !anchor.sensitivity.branches.kept_by(&drift, &param_drift)
        {
            return None;
        }
        anchor.moved_to(x, &theta, p)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::Config;

    fn query() -> InterceptQuery {
        InterceptQuery {
            plane_x: -1.6,
            horizon: 1.5,
            bounced_on_robot_half: false,
            bounce_noise: BounceNoise::default(),
        }
    }

    fn shot(p: [f64; 3], v: [f64; 3], w: [f64; 3]) -> StateVector {
        BallState::new(p.into(), v.into(), w.into()).to_vector()
    }

    #[test]
    fn a_good_shot_crosses_after_one_bounce_with_timing_in_the_covariance() {
        let propagator = Propagator::new(&Config::default());
        let x = shot([1.3, 0.0, 0.30], [-4.5, 0.0, 1.6], [0.0, 0.0, 0.0]);
        let p = StateMatrix::identity() * 1e-4;
        let result = predict_intercept(&propagator, &x, &p, &query());
        let crossing = result.crossing.expect("valid");
        assert!((crossing.state.position.x + 1.6).abs() < 1e-12);
        let bounce = result.bounce.expect("bounce");
        assert!(bounce.position.x < 0.0 && bounce.time < crossing.time);
        // No spread along x on the plane; time spread shows in the other components.
        assert!(crossing.covariance[(0, 0)].abs() < 1e-15);
        assert!(crossing.covariance[(2, 2)] > 1e-5);
        assert!(crossing.time_sigma > 1e-4);
    }

    fn refresh() -> RefreshParams {
        RefreshParams {
            max_age: 0.1,
            position: 0.01,
            velocity: 0.05,
            spin: 10.0,
        }
    }

    const MS: i64 = 1_000_000;

    #[test]
    fn a_tracker_that_always_refreshes_equals_the_full_prediction() {
        let propagator = Propagator::new(&Config::default());
        let x = shot([1.3, 0.0, 0.30], [-4.5, 0.0, 1.6], [0.0, -50.0, 0.0]);
        let p = StateMatrix::identity() * 1e-4;
        let always = RefreshParams {
            max_age: 0.0,
            ..RefreshParams::default()
        };
        let mut tracker = InterceptTracker::new(always);
        for k in 0..3 {
            let got = tracker.predict(&propagator, 1, k * MS, &x, &with_known_params(&p), &query());
            assert_eq!(got, predict_intercept(&propagator, &x, &p, &query()));
        }
        assert_eq!(tracker.counts(), TrackerCounts { full: 3, moved: 0 });
    }

    /// Along the ball's own flight (no drift) the moved interception is the full one: the same
    /// crossing, its time counting down, the covariance carried by the inverse transitions.
    #[test]
    fn along_its_own_flight_the_moved_interception_is_the_full_one() {
        let propagator = Propagator::new(&Config::default());
        let start = shot([1.2, 0.1, 0.3], [-5.0, -0.3, 1.2], [10.0, -60.0, 20.0]);
        let mut cursor = Cursor::tracking(0.0, start);
        let p0 = StateMatrix::identity() * 1e-4;
        let mut tracker = InterceptTracker::new(refresh());
        let step = 10 * MS / 9; // 900 fps
        for k in 0..60 {
            let dt = (k * step) as f64 * 1e-9 - cursor.t;
            propagator.advance(&mut cursor, dt, Watch::BOUNCES, &mut ());
            let phi = cursor.tangent.expect("tangent").transition();
            let p = phi * p0 * phi.transpose();
            let got = tracker.predict(
                &propagator,
                1,
                k * step,
                &cursor.state,
                &with_known_params(&p),
                &query(),
            );
            let full = predict_intercept(&propagator, &cursor.state, &p, &query());
            let (got_c, full_c) = (got.crossing.expect("moved"), full.crossing.expect("full"));
            // The anchor flies in other RK4 steps than the full prediction: their error, in the
            // decaying spin too, is about 1e-6 of its rad/s.
            let state_error = (got_c.state.to_vector() - full_c.state.to_vector()).norm();
            assert!(state_error < 1e-5, "{k}: {state_error}");
            assert!((got_c.time - full_c.time).abs() < 1e-8);
            assert!((got_c.time_sigma - full_c.time_sigma).abs() < 1e-6 * full_c.time_sigma);
            let cov_error = (got_c.covariance - full_c.covariance).norm();
            assert!(cov_error < 1e-5 * full_c.covariance.norm());
            let (got_b, full_b) = (got.bounce.expect("bounce"), full.bounce.expect("bounce"));
            assert!((got_b.position - full_b.position).norm() < 1e-7);
            assert!((got_b.time - full_b.time).abs() < 1e-8);
        }
        // One full prediction (the age limit is 0.1 s), the rest moved.
        assert_eq!(tracker.counts(), TrackerCounts { full: 1, moved: 59 });
    }

    /// A drift within the limits that would turn the bounce from sliding to rolling (or back) is
    /// a change of branch: the interception is predicted in full.
    #[test]
    fn a_drift_that_changes_the_bounce_regime_predicts_in_full() {
        let propagator = Propagator::new(&Config::default());
        let regime = |x: &StateVector| {
            let options = crate::physics::PredictOptions {
                horizon: 1.0,
                sample_interval: 0.1,
                plane_x: None,
                stop_at_plane: false,
            };
            crate::physics::predict(&propagator, &BallState::from_vector(x), &options)
                .bounces()
                .next()
                .map(|e| e.kind)
        };
        let p = StateMatrix::identity() * 1e-4;
        // Topspin just short of rolling out of the robot-half bounce: find the boundary.
        let base = shot([-0.16, 0.0, 0.30], [-4.2, -0.13, -2.5], [-7.5, -6.0, -8.5]);
        let flipped = (0..200)
            .map(|i| {
                let mut x = base;
                x[7] += 0.25 * f64::from(i);
                x
            })
            .find(|x| regime(x) != regime(&base))
            .expect("a regime change within 50 rad/s");
        let mut before = flipped;
        before[7] -= 1.0;
        assert_ne!(regime(&before), regime(&flipped));
        let mut tracker = InterceptTracker::new(refresh());
        tracker.predict(&propagator, 1, 0, &before, &with_known_params(&p), &query());
        let got = tracker.predict(
            &propagator,
            1,
            0,
            &flipped,
            &with_known_params(&p),
            &query(),
        );
        assert_eq!(got, predict_intercept(&propagator, &flipped, &p, &query()));
        assert_eq!(tracker.counts().full, 2);
        // Far from the boundary the same drift is moved.
        let mut tracker = InterceptTracker::new(refresh());
        tracker.predict(&propagator, 1, 0, &base, &with_known_params(&p), &query());
        let mut drifted = base;
        drifted[7] -= 1.0;
        tracker.predict(
            &propagator,
            1,
            0,
            &drifted,
            &with_known_params(&p),
            &query(),
        );
        assert_eq!(tracker.counts(), TrackerCounts { full: 1, moved: 1 });
    }

    /// Another track, an earlier stamp, a drift past a limit, an old anchor: in full.
    #[test]
    fn the_limits_predict_in_full() {
        let propagator = Propagator::new(&Config::default());
        let x = shot([1.2, 0.1, 0.3], [-5.0, -0.3, 1.2], [10.0, -60.0, 20.0]);
        let p = StateMatrix::identity() * 1e-4;
        let nudge = |i: usize, by: f64| {
            let mut y = x;
            y[i] += by;
            y
        };
        let cases: [(u32, i64, StateVector); 6] = [
            (2, 0, x),
            (1, -MS, x),
            (1, 0, nudge(0, 0.011)),
            (1, 0, nudge(3, 0.051)),
            (1, 0, nudge(7, 10.1)),
            (1, 101 * MS, x),
        ];
        for (track, stamp, y) in cases {
            let mut tracker = InterceptTracker::new(refresh());
            tracker.predict(&propagator, 1, 0, &x, &with_known_params(&p), &query());
            tracker.predict(
                &propagator,
                track,
                stamp,
                &y,
                &with_known_params(&p),
                &query(),
            );
            assert_eq!(tracker.counts().full, 2, "track {track} stamp {stamp}");
        }
        // Within every limit: moved.
        let mut tracker = InterceptTracker::new(refresh());
        tracker.predict(&propagator, 1, 0, &x, &with_known_params(&p), &query());
        tracker.predict(
            &propagator,
            1,
            MS,
            &nudge(3, 0.01),
            &with_known_params(&p),
            &query(),
        );
        assert_eq!(tracker.counts(), TrackerCounts { full: 1, moved: 1 });
    }

    /// With the Magnus scale uncertain (and the state known), the crossing's covariance is
    /// (dc/dk_M) sigma^2 (dc/dk_M)', dc/dk_M from central differences of full predictions, and
    /// its time sigma likewise.
    #[test]
    fn uncertain_parameters_enter_the_crossing_covariance() {
        let propagator = Propagator::new(&Config::default());
        let x = shot([1.3, 0.0, 0.30], [-5.0, 0.1, 1.4], [0.0, -150.0, 20.0]);
        let sigma = 0.1;
        let mut p = AugmentedMatrix::zeros();
        p[(
            9 + crate::physics::params::MAGNUS_SCALE,
            9 + crate::physics::params::MAGNUS_SCALE,
        )] = sigma * sigma;
        let got = predict_intercept_augmented(&propagator, &x, &p, &query())
            .crossing
            .expect("valid");
        let at = |k_m: f64| {
            let params = crate::physics::PhysicsParams {
                magnus_scale: k_m,
                ..propagator.params()
            };
            let q = propagator.with_params(&params);
            predict_intercept(&q, &x, &StateMatrix::zeros(), &query())
                .crossing
                .expect("valid")
        };
        let (h, k_m) = (1e-5, propagator.params().magnus_scale);
        let (plus, minus) = (at(k_m + h), at(k_m - h));
        let dc = (plus.state.to_vector() - minus.state.to_vector()) / (2.0 * h);
        let dt = (plus.time - minus.time) / (2.0 * h);
        let expected = dc * dc.transpose() * (sigma * sigma);
        assert!(
            (got.covariance - expected).norm() < 1e-5 * expected.norm(),
            "{} vs {}",
            got.covariance,
            expected
        );
        assert!((got.time_sigma - dt.abs() * sigma).abs() < 1e-5 * got.time_sigma);
        assert!(
            got.covariance[(2, 2)] > 1e-6,
            "the Magnus scale moves the crossing's z"
        );
    }

    /// Along its own flight, with the parameters drifting a little (as the filter learns
    /// them), the moved interception follows the full one to first order.
    #[test]
    fn the_moved_interception_follows_the_parameters() {
        let base = Propagator::new(&Config::default());
        let start = shot([1.2, 0.1, 0.3], [-5.0, -0.3, 1.2], [10.0, -60.0, 20.0]);
        let mut p = with_known_params(&(StateMatrix::identity() * 1e-4));
        for i in 9..AUGMENTED {
            p[(i, i)] = 1e-4;
        }
        let mut tracker = InterceptTracker::new(refresh());
        let mut cursor = Cursor::tracking(0.0, start);
        let step = 10 * MS / 9;
        let (mut worst, mut worst_time) = (0.0f64, 0.0f64);
        for k in 0..60 {
            let dt = (k * step) as f64 * 1e-9 - cursor.t;
            base.advance(&mut cursor, dt, Watch::BOUNCES, &mut ());
            let drift = 1e-4 * k as f64;
            let params = crate::physics::PhysicsParams {
                drag_scale: 1.0 + drift,
                magnus_scale: 1.0 - 2.0 * drift,
                restitution: 0.9 + 0.2 * drift,
                friction: 0.25 - drift,
            };
            let propagator = base.with_params(&params);
            let got = tracker.predict(&propagator, 1, k * step, &cursor.state, &p, &query());
            let full = predict_intercept_augmented(&propagator, &cursor.state, &p, &query());
            let (g, f) = (got.crossing.expect("moved"), full.crossing.expect("full"));
            worst = worst.max((g.state.position - f.state.position).norm());
            worst_time = worst_time.max((g.time - f.time).abs());
        }
        assert!(worst < 3e-4, "worst {worst}");
        assert!(worst_time < 5e-5, "worst {worst_time} s");
        assert!(tracker.counts().moved > 40, "{:?}", tracker.counts());
    }

    #[test]
    fn one_step_carries_the_bounce_spread_as_the_prediction_s_steps_do() {
        let propagator = Propagator::new(&Config::default());
        // Just after bounces of top, back and side spin, 0.1-0.3 s before the plane.
        for (v, w) in [
            ([-6.0, 0.3, 2.5], [0.0, -300.0, 0.0]),
            ([-4.0, -0.5, 2.0], [0.0, 150.0, 0.0]),
            ([-8.0, 1.0, 3.0], [100.0, -50.0, 250.0]),
        ] {
            let start = shot([-0.4, 0.0, 0.02], v, w);
            let sensitivity = |step: f64| {
                plane_sensitivity(&propagator, &start, 0.6, -1.6, step).expect("crossing")
            };
            let (fine, one) = (sensitivity(0.02), sensitivity(0.6));
            let mut q = StateMatrix::zeros();
            for i in 3..9 {
                q[(i, i)] = if i < 6 { 0.05 * 0.05 } else { 20.0 * 20.0 };
            }
            let (a, b) = (
                fine.before * q * fine.before.transpose(),
                one.before * q * one.before.transpose(),
            );
            for i in 1..3 {
                let ratio = b[(i, i)] / a[(i, i)];
                assert!((ratio - 1.0).abs() < 0.01, "{v:?} {w:?} [{i}]: {ratio}");
            }
        }
    }

    #[test]
    fn invalid_crossings_say_why() {
        let propagator = Propagator::new(&Config::default());
        let p = StateMatrix::identity() * 1e-4;
        let net = shot([1.0, 0.0, 0.10], [-6.0, 0.0, 0.0], [0.0; 3]);
        assert_eq!(
            predict_intercept(&propagator, &net, &p, &query()).crossing,
            Err(NoIntercept::NetHit)
        );
        let long = shot([1.3, 0.0, 0.40], [-12.0, 0.0, 1.5], [0.0, 200.0, 0.0]);
        assert_eq!(
            predict_intercept(&propagator, &long, &p, &query()).crossing,
            Err(NoIntercept::NoBounce)
        );
        let twice = shot([-0.2, 0.0, 0.45], [-1.0, 0.1, -1.0], [0.0, -60.0, 0.0]);
        assert_eq!(
            predict_intercept(&propagator, &twice, &p, &query()).crossing,
            Err(NoIntercept::TwoBounces)
        );
        let away = shot([-1.0, 0.0, 0.3], [3.0, 0.0, 1.0], [0.0; 3]);
        let q = InterceptQuery {
            horizon: 0.3,
            ..query()
        };
        assert_eq!(
            predict_intercept(&propagator, &away, &p, &q).crossing,
            Err(NoIntercept::NotWithinHorizon)
        );
    }
}
