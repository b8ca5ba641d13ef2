//! The interception prediction: where and when the ball crosses the robot's hitting plane
//! x = plane_x moving toward the robot after exactly one bounce on the robot's half, with the 9x9
//! covariance at the crossing.
//!
//! The covariance is J P J' with J = d(state at the crossing)/d(state now), the crossing time
//! moving with the state (J = Phi + f dtau/dx, the event sensitivity of the propagation), so the
//! timing uncertainty is included: the x row is zero (the ball is on the plane by definition) and
//! the spread of the crossing time shows in y, z and the velocity; its own variance is
//! dtau/dx P dtau/dx'.

use nalgebra::Vector3;

use crate::physics::{
    BallState, Cursor, Event, EventKind, Flow, Observer, Outcome, Propagator, StateMatrix,
    StateVector, Watch,
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
}

struct Watcher {
    robot_half_bounces: u32,
    bounce: Option<PredictedBounce>,
    result: Option<Result<Event, NoIntercept>>,
}

impl Observer for Watcher {
    fn on_event(&mut self, event: &Event) -> Flow {
        match event.kind {
            EventKind::TableBounce { .. } if event.before[0] < 0.0 => {
                self.robot_half_bounces += 1;
                if self.robot_half_bounces > 1 {
                    self.result = Some(Err(NoIntercept::TwoBounces));
                    return Flow::Stop;
                }
                self.bounce = Some(PredictedBounce {
                    time: event.t,
                    position: event.before.fixed_rows::<3>(0).into_owned(),
                });
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

/// Predicts the interception from state `x` with covariance `p` (see the module doc).
pub fn predict_intercept(
    propagator: &Propagator,
    x: &StateVector,
    p: &StateMatrix,
    query: &InterceptQuery,
) -> Intercept {
    let mut watcher = Watcher {
        robot_half_bounces: u32::from(query.bounced_on_robot_half),
        bounce: None,
        result: None,
    };
    let mut cursor = Cursor::tracking(0.0, *x);
    let watch = Watch {
        plane_x: Some(query.plane_x),
        ..Watch::FLIGHT
    };
    let outcome = propagator.advance(&mut cursor, query.horizon, watch, &mut watcher);
    let crossing = match (watcher.result, outcome) {
        (Some(Ok(event)), _) => Ok(crossing_of(&event, p)),
        (Some(Err(reason)), _) => Err(reason),
        (None, Outcome::Terminated(EventKind::Floor)) => Err(NoIntercept::MissesTable),
        (None, Outcome::Terminated(_)) => Err(NoIntercept::NetHit),
        (None, _) => Err(NoIntercept::NotWithinHorizon),
    };
    Intercept {
        crossing,
        bounce: watcher.bounce,
    }
}

fn crossing_of(event: &Event, p: &StateMatrix) -> Crossing {
    let (covariance, time_sigma) = match event.sensitivity {
        Some(s) => {
            let j = s.before;
            let cov = j * p * j.transpose();
            let var_t = (s.time_gradient * p * s.time_gradient.transpose())[(0, 0)];
            ((cov + cov.transpose()) * 0.5, var_t.max(0.0).sqrt())
        }
        None => (StateMatrix::zeros(), 0.0),
    };
    Crossing {
        time: event.t,
        time_sigma,
        state: BallState::from_vector(&event.before),
        covariance,
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
