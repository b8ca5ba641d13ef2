//! The robot's stroke: what a hit does to the ball and where the ball goes, and the racket
//! command that sends it to a target. Pure: the racket impact of [`crate::physics::racket`], then
//! the flight of [`crate::physics::propagate`] to the first bounce.
//!
//! - [`Stroke::rebound`]: ball and racket state at impact -> the ball after the hit, contact time,
//!   forces, wrist load, and its return flight to the landing point (net clearance included).
//! - [`Stroke::plan`]: the inverse. The racket moves along its face normal n at speed s, plus an
//!   optional brushing speed along the face (upward in the face's plane); the unknowns (s, n) are
//!   solved by Levenberg-Marquardt (Newton's method when undamped) with a central-difference
//!   Jacobian so that the return, through the
//!   full rebound and flight models, lands on the target (x, y) and meets a third condition: a net
//!   clearance or a flight time. The start is the drag-free parabola through the target and the
//!   frictionless inverse of the rebound. While solving, the table is taken as unbounded and the
//!   net as transparent so that every candidate has a landing point; the solution is then flown
//!   again through the real table and net.

use nalgebra::{Matrix3, SMatrix, Vector2, Vector3};
use thiserror::Error;

use crate::config::Config;
use crate::model::least_squares::{Damping, damped_step};
use crate::physics::PhysicsParams;
use crate::physics::propagate::{
    Cursor, Event, EventKind, Flow, Observer, Outcome, Propagator, Watch,
};
use crate::physics::racket::{Hit, ImpactError, RacketModel, RacketState};
use crate::physics::state::{BallState, SPIN, StateMatrix, StateVector};

/// Landing distance to the target at which the plan is converged [m].
pub const LANDING_TOLERANCE: f64 = 1e-6;
/// Clearance [m] or flight time [s] error at which the plan is converged.
pub const CONDITION_TOLERANCE: f64 = 1e-6;
/// Largest number of iterations of a solve.
const MAX_ITERATIONS: usize = 40;
/// Table outline margin of the solver's unbounded table [m].
const UNBOUNDED_TABLE: f64 = 1.0e3;
/// What the planner's return flights watch: the first bounce on the unbounded table, the net's
/// plane crossed through a transparent net.
const UNBOUNDED_WATCH: Watch = Watch {
    net: false,
    floor: false,
    plane_x: Some(0.0),
    table_misses: false,
};

/// How the return flight ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ReturnOutcome {
    /// The ball bounces on the opponent's half (x > 0): a good return.
    Lands,
    /// The ball bounces on the robot's own half first.
    OwnHalf,
    /// The ball hits the net.
    Net,
    /// The ball misses the table and reaches the floor.
    MissesTable,
    /// The ball is still flying at the end of the horizon.
    StillFlying,
}

impl ReturnOutcome {
    /// A few words for messages.
    pub fn describe(&self) -> &'static str {
        match self {
            Self::Lands => "lands on the opponent's half",
            Self::OwnHalf => "bounces on the robot's own half",
            Self::Net => "hits the net",
            Self::MissesTable => "misses the table",
            Self::StillFlying => "is still flying at the end of the prediction horizon",
        }
    }
}

/// The flight of the returned ball up to its first bounce.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ReturnFlight {
    /// How it ended.
    pub outcome: ReturnOutcome,
    /// The first bounce on the table (time after the hit [s], state just before it).
    pub landing: Option<(f64, BallState)>,
    /// The crossing of the net plane: time after the hit [s] and the height of the ball's bottom
    /// over the net top [m].
    pub net: Option<(f64, f64)>,
}

/// A hit and the flight that follows it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Rebound {
    /// The impact.
    pub hit: Hit,
    /// The return flight.
    pub flight: ReturnFlight,
}

/// The third condition on a return, besides its landing point.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum ReturnCondition {
    /// Height of the ball's bottom over the net top when it crosses the net [m].
    NetClearance(f64),
    /// Time from the hit to the landing [s].
    FlightTime(f64),
}

/// What the controller asks for.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Aim {
    /// Landing point of the ball centre on the opponent's half (x, y) [m].
    pub target: Vector2<f64>,
    /// The third condition.
    pub condition: ReturnCondition,
    /// Impact point from the racket's centre of gravity along its long axis [m].
    pub impact_offset: f64,
    /// Racket speed along the face, upward in the face's plane (topspin when positive) [m/s].
    pub brush_speed: f64,
}

/// A racket command and what it does.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Plan {
    /// The racket at impact: velocity of the impact point, face normal, impact offset.
    pub racket: RacketState,
    /// The hit and the return flight it gives, through the real table and net.
    pub rebound: Rebound,
    /// Distance from the predicted landing point to the target [m].
    pub landing_error: f64,
    /// Levenberg-Marquardt iterations used.
    pub iterations: usize,
}

/// Why no racket command was found.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum PlanError {
    /// The target has a non-finite coordinate.
    #[error("the target has a non-finite coordinate")]
    TargetNotFinite,
    /// The target is not on the opponent's half.
    #[error(
        "target ({x:.3}, {y:.3}) m is not on the opponent's half: give 0 < x < {half_length:.3} and |y| < {half_width:.4} (table frame, metres)"
    )]
    TargetOffTable {
        /// The target's x [m].
        x: f64,
        /// The target's y [m].
        y: f64,
        /// Half the table's length [m].
        half_length: f64,
        /// Half the table's width [m].
        half_width: f64,
    },
    /// The net clearance asked for is outside 0 to 3 m.
    #[error("net clearance {0} m is out of range: give 0 to 3 m")]
    NetClearance(f64),
    /// The flight time asked for is not positive or beyond the prediction horizon.
    #[error(
        "flight time {time} s is out of range: give more than 0 and at most the prediction horizon, {horizon} s"
    )]
    FlightTime {
        /// The flight time asked for [s].
        time: f64,
        /// The prediction horizon [s].
        horizon: f64,
    },
    /// The brush speed or the impact offset is NaN or infinite.
    #[error("the brush speed or impact offset is not finite")]
    AimNotFinite,
    /// The ball is not on the robot's side of the net.
    #[error("the ball at x = {0:.3} m is not on the robot's side of the net")]
    BallBeyondNet(f64),
    /// The ball already flies to the target.
    #[error("the ball already flies to the target: no hit needed")]
    NoHitNeeded,
    /// The ball state cannot be hit (e.g. non-finite).
    #[error(transparent)]
    Impact(#[from] ImpactError),
    /// The solver found no racket command that meets the target.
    #[error(
        "target unreachable: no racket command returns the ball there ({reason}); the closest candidate landed {closest:.3} m from it"
    )]
    NoSolution {
        /// What went wrong.
        reason: &'static str,
        /// Landing distance of the best candidate [m].
        closest: f64,
    },
    /// The command meets the target through the solver's unbounded table and transparent net,
    /// but the real return does not land (e.g. a flight time too short to clear the net).
    #[error(
        "target unreachable as asked: through the real net and table, the planned return {}; give a longer flight time or a net clearance instead",
        .0.describe()
    )]
    Blocked(ReturnOutcome),
    /// The command exists but the racket would have to move too fast.
    #[error(
        "target unreachable within the racket speed limit: it needs {needed:.2} m/s, the limit (stroke.max_racket_speed) is {limit:.2} m/s; a longer flight time or a higher net clearance needs less"
    )]
    TooFast {
        /// Racket speed the command needs [m/s].
        needed: f64,
        /// The configured limit [m/s].
        limit: f64,
    },
}

/// The stroke model: racket impact, flight and the table.
#[derive(Debug, Clone, PartialEq)]
pub struct Stroke {
    racket: RacketModel,
    propagator: Propagator,
    solver_propagator: Propagator,
    horizon: f64,
    gravity: f64,
    radius: f64,
    net_height: f64,
    half_length: f64,
    half_width: f64,
    max_racket_speed: f64,
    net_clearance: f64,
}

/// Stops at the first table bounce, remembering it and the net-plane crossing.
#[derive(Default)]
struct FirstBounce {
    landing: Option<Event>,
    net_plane: Option<Event>,
}

impl Observer for FirstBounce {
    fn on_event(&mut self, event: &Event) -> Flow {
        match event.kind {
            EventKind::TableBounce { .. } => {
                self.landing = Some(*event);
                return Flow::Stop;
            }
            EventKind::Net { .. } | EventKind::Plane { .. } if self.net_plane.is_none() => {
                self.net_plane = Some(*event);
            }
            _ => {}
        }
        Flow::Continue
    }
}

impl Stroke {
    /// The stroke model of the configured ball, racket, arm, table and planner limits.
    pub fn new(config: &Config) -> Self {
        let propagator = Propagator::new(config);
        Self {
            racket: RacketModel::new(config),
            solver_propagator: propagator.with_edge_margin(UNBOUNDED_TABLE),
            propagator,
            horizon: config.prediction.horizon,
            gravity: config.gravity,
            radius: config.ball.radius,
            net_height: config.table.net_height,
            half_length: 0.5 * config.table.length,
            half_width: 0.5 * config.table.width,
            max_racket_speed: config.stroke.max_racket_speed,
            net_clearance: config.stroke.net_clearance,
        }
    }

    /// The same model with the ball's flight and the table's bounce at `params` (e.g. what the
    /// estimator learned from the rally).
    #[must_use]
    pub fn with_params(&self, params: &PhysicsParams) -> Self {
        Self {
            propagator: self.propagator.with_params(params),
            solver_propagator: self.solver_propagator.with_params(params),
            ..self.clone()
        }
    }

    /// The same model with other Reynolds exponents (a_D, a_M) [-].
    pub fn with_reynolds_exponents(&self, exponents: [f64; 2]) -> Self {
        Self {
            propagator: self.propagator.with_reynolds_exponents(exponents),
            solver_propagator: self.solver_propagator.with_reynolds_exponents(exponents),
            ..self.clone()
        }
    }

    /// The racket-impact model.
    pub fn racket(&self) -> &RacketModel {
        &self.racket
    }

    /// The third condition of a request: its flight time if it names one, else its net
    /// clearance, else the configured `stroke.net_clearance`.
    pub fn condition(
        &self,
        flight_time: Option<f64>,
        net_clearance: Option<f64>,
    ) -> ReturnCondition {
        match (flight_time, net_clearance) {
            (Some(t), _) => ReturnCondition::FlightTime(t),
            (None, Some(c)) => ReturnCondition::NetClearance(c),
            (None, None) => ReturnCondition::NetClearance(self.net_clearance),
        }
    }

    /// The hit of `ball` by `racket` and the return flight to its first bounce.
    pub fn rebound(&self, ball: &BallState, racket: &RacketState) -> Result<Rebound, ImpactError> {
        let hit = self.racket.hit(ball, racket)?;
        Ok(Rebound {
            hit,
            flight: self.return_flight(&hit.ball),
        })
    }

    /// The flight of a ball just hit, through the real table and net, to its first bounce.
    pub fn return_flight(&self, after: &BallState) -> ReturnFlight {
        let (outcome, observer) = self.first_bounce(&self.propagator, Watch::FLIGHT, after);
        let net = observer.net_plane.and_then(|e| match e.kind {
            EventKind::Net { clearance, .. } => Some((e.t, clearance)),
            _ => None,
        });
        let landing = observer
            .landing
            .map(|e| (e.t, BallState::from_vector(&e.before)));
        let outcome = match (outcome, &landing) {
            (Outcome::Stopped, Some((_, state))) if state.position.x > 0.0 => ReturnOutcome::Lands,
            (Outcome::Stopped, Some(_)) => ReturnOutcome::OwnHalf,
            (Outcome::Terminated(EventKind::Floor), _) => ReturnOutcome::MissesTable,
            (Outcome::Terminated(_), _) => ReturnOutcome::Net,
            _ => ReturnOutcome::StillFlying,
        };
        ReturnFlight {
            outcome,
            landing,
            net,
        }
    }

    /// The racket command that returns `ball` (its state just before impact) as `aim` asks.
    pub fn plan(&self, ball: &BallState, aim: &Aim) -> Result<Plan, PlanError> {
        self.check_aim(aim)?;
        if !ball.is_finite() {
            return Err(ImpactError::NotFinite { what: "ball state" }.into());
        }
        self.racket.check_on_face(aim.impact_offset)?;
        let (mut command, mut residual) = self.first_guess(ball, aim)?;
        let mut closest = residual.map_or(f64::INFINITY, |r| r.fixed_rows::<2>(0).norm());
        let mut iterations = 0;
        let mut damping = Damping::new();
        loop {
            let Some(r) = residual else {
                return Err(PlanError::NoSolution {
                    reason: "the first guess does not cross the net plane or reach the table",
                    closest,
                });
            };
            closest = closest.min(r.fixed_rows::<2>(0).norm());
            if r.fixed_rows::<2>(0).norm() <= LANDING_TOLERANCE && r[2].abs() <= CONDITION_TOLERANCE
            {
                break;
            }
            if iterations == MAX_ITERATIONS {
                return Err(PlanError::NoSolution {
                    reason: "the solve did not converge",
                    closest,
                });
            }
            iterations += 1;
            let jacobian = central_differences(&command, |c| self.residual(ball, c, aim)).ok_or(
                PlanError::NoSolution {
                    reason: "a neighbouring command does not reach the table",
                    closest,
                },
            )?;
            let accepted = levenberg_marquardt_step(&command, &jacobian, &r, &mut damping, |c| {
                self.residual(ball, c, aim)
            });
            let Some((candidate, next)) = accepted else {
                return Err(PlanError::NoSolution {
                    reason: "no step brings the landing point closer: a local minimum",
                    closest,
                });
            };
            command = candidate;
            residual = Some(next);
        }
        let racket = command.racket();
        let needed = racket.velocity.norm();
        if needed > self.max_racket_speed {
            return Err(PlanError::TooFast {
                needed,
                limit: self.max_racket_speed,
            });
        }
        let rebound = self.rebound(ball, &racket)?;
        if rebound.flight.outcome != ReturnOutcome::Lands {
            return Err(PlanError::Blocked(rebound.flight.outcome));
        }
        let landing_error = rebound.flight.landing.map_or(f64::INFINITY, |(_, s)| {
            (s.position.xy() - aim.target).norm()
        });
        Ok(Plan {
            racket,
            rebound,
            landing_error,
            iterations,
        })
    }

    fn check_aim(&self, aim: &Aim) -> Result<(), PlanError> {
        let t = aim.target;
        if !(t.x.is_finite() && t.y.is_finite()) {
            return Err(PlanError::TargetNotFinite);
        }
        if !(t.x > 0.0 && t.x < self.half_length && t.y.abs() < self.half_width) {
            return Err(PlanError::TargetOffTable {
                x: t.x,
                y: t.y,
                half_length: self.half_length,
                half_width: self.half_width,
            });
        }
        match aim.condition {
            ReturnCondition::NetClearance(c) if !(0.0..=3.0).contains(&c) => {
                Err(PlanError::NetClearance(c))
            }
            ReturnCondition::FlightTime(t) if !(t > 0.0 && t <= self.horizon) => {
                Err(PlanError::FlightTime {
                    time: t,
                    horizon: self.horizon,
                })
            }
            _ if !aim.brush_speed.is_finite() || !aim.impact_offset.is_finite() => {
                Err(PlanError::AimNotFinite)
            }
            _ => Ok(()),
        }
    }

    /// The start of the solve: the command that sends the ball off along the drag-free
    /// parabola to the target. Drag and spin make the real flight fall short of it; when it does
    /// not even reach the net, higher parabolas (more clearance) are tried, and the solve then
    /// walks down to the one asked for.
    fn first_guess(
        &self,
        ball: &BallState,
        aim: &Aim,
    ) -> Result<(Command, Option<Vector3<f64>>), PlanError> {
        let mut first = None;
        for extra in [0.0, 0.1, 0.2, 0.4, 0.8] {
            let lifted = match aim.condition {
                ReturnCondition::NetClearance(c) => Aim {
                    condition: ReturnCondition::NetClearance(c + extra),
                    ..*aim
                },
                ReturnCondition::FlightTime(_) if extra > 0.0 => break,
                ReturnCondition::FlightTime(_) => *aim,
            };
            let target_velocity = self.ballistic_guess(ball, &lifted)?;
            let (speed, normal) = self.frictionless_inverse(ball, &target_velocity, aim)?;
            let frictionless = Command {
                speed,
                normal,
                brush: aim.brush_speed,
                offset: aim.impact_offset,
            };
            // With the rubber's friction and the ball's spin the same command sends the ball
            // elsewhere: match the outgoing velocity itself first (a cheap, smooth map).
            let command = self
                .match_outgoing(ball, &target_velocity, frictionless)
                .unwrap_or(frictionless);
            let residual = self.residual(ball, &command, aim);
            if residual.is_some() {
                return Ok((command, residual));
            }
            first.get_or_insert((command, residual));
        }
        first.ok_or(PlanError::NoSolution {
            reason: "no first guess",
            closest: f64::INFINITY,
        })
    }

    /// The outgoing velocity of the drag-free parabola from the ball to the target that meets
    /// the condition.
    fn ballistic_guess(&self, ball: &BallState, aim: &Aim) -> Result<Vector3<f64>, PlanError> {
        let g = self.gravity;
        let start = ball.position;
        let to_target = aim.target - start.xy();
        let distance = to_target.norm();
        let drop = self.radius - start.z;
        let (horizontal_speed, vertical_speed) = match aim.condition {
            ReturnCondition::FlightTime(t) => (distance / t, (drop + 0.5 * g * t * t) / t),
            ReturnCondition::NetClearance(c) => {
                // The parabola through the net point (at the fraction of the way where x = 0)
                // and the landing point, both reached at horizontal speed u.
                let fraction = -start.x / (aim.target.x - start.x);
                if !(fraction > 0.0 && fraction < 1.0) {
                    return Err(PlanError::BallBeyondNet(start.x));
                }
                let d1 = fraction * distance;
                let rise = self.net_height + self.radius + c - start.z;
                let slope_gap = rise / d1 - drop / distance;
                if slope_gap <= 0.0 {
                    return Err(PlanError::NoSolution {
                        reason: "the net point lies below the straight line to the target",
                        closest: f64::INFINITY,
                    });
                }
                let u = (g * (distance - d1) / (2.0 * slope_gap)).sqrt();
                (u, drop * u / distance + 0.5 * g * distance / u)
            }
        };
        let direction = to_target / distance;
        Ok(Vector3::new(
            direction.x * horizontal_speed,
            direction.y * horizontal_speed,
            vertical_speed,
        ))
    }

    /// Racket speed and normal that turn the incoming velocity into `outgoing`, without friction:
    /// the velocity change is along n, (1 + e(V)) V with V = s - v . n the approach speed.
    fn frictionless_inverse(
        &self,
        ball: &BallState,
        outgoing: &Vector3<f64>,
        aim: &Aim,
    ) -> Result<(f64, Vector3<f64>), PlanError> {
        let change = outgoing - ball.velocity;
        let magnitude = change.norm();
        if magnitude == 0.0 {
            return Err(PlanError::NoHitNeeded);
        }
        let normal = change / magnitude;
        let mut approach = magnitude / 1.7;
        for _ in 0..20 {
            let impact = self
                .racket
                .normal_impact(approach, aim.impact_offset)
                .map_err(ImpactError::from)?;
            approach = magnitude / (1.0 + impact.rebound_power_coefficient);
        }
        Ok((approach + ball.velocity.dot(&normal), normal))
    }

    /// The flight after `racket` hits `ball` over the unbounded table with a transparent net, to
    /// its first bounce; `None` when the hit is impossible.
    fn unbounded_flight(&self, ball: &BallState, racket: &RacketState) -> Option<FirstBounce> {
        let hit = self.racket.hit(ball, racket).ok()?;
        Some(
            self.first_bounce(&self.solver_propagator, UNBOUNDED_WATCH, &hit.ball)
                .1,
        )
    }

    /// The flight of a ball just hit, over the horizon, to its first bounce (or the end).
    fn first_bounce(
        &self,
        propagator: &Propagator,
        watch: Watch,
        after: &BallState,
    ) -> (Outcome, FirstBounce) {
        let mut cursor = Cursor::new(0.0, after);
        let mut observer = FirstBounce::default();
        let outcome = propagator.advance(&mut cursor, self.horizon, watch, &mut observer);
        (outcome, observer)
    }

    /// First-order covariance of the landing of the return, over (x [m], y [m], flight time
    /// [s]), from the covariance `covariance` of the ball state just before `racket` hits it:
    /// the ball's covariance just after the hit ([`RacketModel::rebound_covariance`]: the
    /// incoming ball's, the rubber's calibrated uncertainty and the scatter of single hits)
    /// carried through the return flight, J C J^T with J = d(landing)/d(ball after the hit) by
    /// central differences (over the unbounded table, as the planner). `None` when a
    /// neighbouring state cannot be hit or does not land within the horizon.
    pub fn landing_covariance(
        &self,
        ball: &BallState,
        covariance: &StateMatrix,
        racket: &RacketState,
    ) -> Option<Matrix3<f64>> {
        let after = self.racket.hit(ball, racket).ok()?.ball;
        let after_covariance = self.racket.rebound_covariance(ball, covariance, racket)?;
        let landing = |x: &StateVector| {
            let (_, observer) = self.first_bounce(
                &self.solver_propagator,
                UNBOUNDED_WATCH,
                &BallState::from_vector(x),
            );
            observer
                .landing
                .map(|e| Vector3::new(e.before[0], e.before[1], e.t))
        };
        let x0 = after.to_vector();
        let mut jacobian = SMatrix::<f64, 3, 9>::zeros();
        for k in 0..9 {
            // 1 um, 1 um/s, 1 mrad/s: the flight is smooth far beyond these.
            let h = if k < SPIN { 1e-6 } else { 1e-3 };
            let (mut plus, mut minus) = (x0, x0);
            plus[k] += h;
            minus[k] -= h;
            jacobian.set_column(k, &((landing(&plus)? - landing(&minus)?) / (2.0 * h)));
        }
        let landing = jacobian * after_covariance * jacobian.transpose();
        Some((landing + landing.transpose()) * 0.5)
    }

    /// The command whose hit sends the ball off at `outgoing`, by Levenberg-Marquardt from
    /// `start` on the rebound alone; `None` when it does not converge.
    fn match_outgoing(
        &self,
        ball: &BallState,
        outgoing: &Vector3<f64>,
        start: Command,
    ) -> Option<Command> {
        let error = |command: &Command| {
            self.racket
                .hit(ball, &command.racket())
                .ok()
                .map(|hit| hit.ball.velocity - outgoing)
        };
        let mut command = start;
        let mut r = error(&command)?;
        let mut damping = Damping::new();
        for _ in 0..MAX_ITERATIONS {
            if r.norm() < 1e-9 {
                return Some(command);
            }
            let jacobian = central_differences(&command, |c| error(c))?;
            let (next, next_r) =
                levenberg_marquardt_step(&command, &jacobian, &r, &mut damping, |c| error(c))?;
            command = next;
            r = next_r;
        }
        None
    }

    /// (landing x - target x, landing y - target y, condition error) of a command, through the
    /// unbounded table and transparent net; `None` when the command does not make a return.
    fn residual(&self, ball: &BallState, command: &Command, aim: &Aim) -> Option<Vector3<f64>> {
        let observer = self.unbounded_flight(ball, &command.racket())?;
        let landing = observer.landing?;
        let condition = match aim.condition {
            // A ball that lands before the net plane counts the shortfall as missing height,
            // which meets the real clearance continuously (-net height) at x = 0.
            ReturnCondition::NetClearance(c) => match observer.net_plane {
                Some(net) => net.before[2] - self.radius - self.net_height - c,
                None => landing.before[0].min(0.0) - self.net_height - c,
            },
            ReturnCondition::FlightTime(t) => landing.t - t,
        };
        Some(Vector3::new(
            landing.before[0] - aim.target.x,
            landing.before[1] - aim.target.y,
            condition,
        ))
    }
}

/// d(f)/d(speed, two tilts of the normal) at `command`, by central differences.
fn central_differences(
    command: &Command,
    f: impl Fn(&Command) -> Option<Vector3<f64>>,
) -> Option<Matrix3<f64>> {
    let mut jacobian = Matrix3::zeros();
    for k in 0..3 {
        let h = if k == 0 {
            1e-6 * command.speed.abs().max(1.0)
        } else {
            1e-6
        };
        let mut delta = Vector3::zeros();
        delta[k] = h;
        let plus = f(&command.moved(&delta))?;
        let minus = f(&command.moved(&(-delta)))?;
        jacobian.set_column(k, &((plus - minus) / (2.0 * h)));
    }
    Some(jacobian)
}

/// One Levenberg-Marquardt step from `command` on f with residual `r` and Jacobian `jacobian`:
/// (J^T J + lambda diag(J^T J)) step = -J^T r, lambda moved by the one damping schedule
/// ([`Damping`]) until |f| falls below |r|.
fn levenberg_marquardt_step(
    command: &Command,
    jacobian: &Matrix3<f64>,
    r: &Vector3<f64>,
    damping: &mut Damping,
    f: impl Fn(&Command) -> Option<Vector3<f64>>,
) -> Option<(Command, Vector3<f64>)> {
    let normal = jacobian.transpose() * jacobian;
    let gradient = jacobian.transpose() * r;
    damping.step(|lambda| {
        let candidate = command.moved(&damped_step(&normal, &(-gradient), lambda)?);
        let next = f(&candidate)?;
        (next.norm() < r.norm()).then_some((candidate, next))
    })
}

/// The planner's unknowns: racket speed along the normal and the normal, with the brushing
/// speed and impact offset held.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Command {
    speed: f64,
    normal: Vector3<f64>,
    brush: f64,
    offset: f64,
}

impl Command {
    /// Unit vector in the face's plane pointing up (or along x for a horizontal face).
    fn brush_direction(normal: &Vector3<f64>) -> Vector3<f64> {
        let up = Vector3::z() - normal * normal.z;
        if up.norm() > 1e-9 {
            up.normalize()
        } else {
            (Vector3::x() - normal * normal.x).normalize()
        }
    }

    /// Two unit vectors orthogonal to the normal and to each other.
    fn tilt_axes(&self) -> (Vector3<f64>, Vector3<f64>) {
        let first = Self::brush_direction(&self.normal);
        (first, self.normal.cross(&first))
    }

    /// The command moved by (speed change, tilt along the first axis, tilt along the second).
    fn moved(&self, delta: &Vector3<f64>) -> Self {
        let (a, b) = self.tilt_axes();
        Self {
            speed: self.speed + delta[0],
            normal: (self.normal + a * delta[1] + b * delta[2]).normalize(),
            ..*self
        }
    }

    /// The racket state this command describes.
    fn racket(&self) -> RacketState {
        RacketState {
            velocity: self.normal * self.speed + Self::brush_direction(&self.normal) * self.brush,
            normal: self.normal,
            impact_offset: self.offset,
        }
    }
}
