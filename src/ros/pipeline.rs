//! The node minus its transport: one `BallDetection` message in, the messages to publish out,
//! and the answers of the node's services (`~/predict_trajectory`, `~/predict_rebound`,
//! `~/plan_return`). The ROS 2 node and the MCAP replay both drive this, so a replay runs exactly
//! the code path of the live node. Time comes from the messages only (the trajectory's rate limit
//! too), so a replay is deterministic.
//!
//! The trajectory, which no other output needs, is kept off the detections that predict their
//! interception in full: when it comes due on one, it waits for the next detection whose
//! interception is moved, at most two periods. The two longest computations of a detection then
//! never add up.

use nalgebra::Vector2;

use crate::config::Config;
use crate::model::detection::Detection;
use crate::model::frames::{FrameError, Frames};
use crate::online::estimator::{
    Counters, Estimate, Estimator, Flight, InterceptEstimate, Output, Rejection, Verdict, Waiting,
};
use crate::online::stroke::{Aim, PlanError, Stroke};
use crate::physics::{self, StateMatrix};
use crate::ros::msgs::builtin_interfaces::Time;
use crate::ros::msgs::convert::{
    ConvertError, add_static_transforms, detection_from_msg_in, intercept_msg, markers,
    odometry_msg, offset, plan_response, rebound_request, rebound_response, robot_hit_from_msg_in,
    state_from_msg, state_msg, trajectory_msg,
};
use crate::ros::msgs::nav_msgs::Odometry;
use crate::ros::msgs::tf2_msgs::TFMessage;
use crate::ros::msgs::ttball_msgs::msg::{
    BallDetection, BallState, InterceptPrediction, PredictedTrajectory, RobotHit,
};
use crate::ros::msgs::ttball_msgs::srv::{
    PlanReturnRequest, PlanReturnResponse, PredictReboundRequest, PredictReboundResponse,
    PredictTrajectoryRequest, PredictTrajectoryResponse,
};
use crate::ros::msgs::visualization_msgs::MarkerArray;

/// The messages to publish after one detection.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Published {
    /// `/ball/state`.
    pub state: Option<BallState>,
    /// `/ball/intercept`.
    pub intercept: Option<InterceptPrediction>,
    /// `/ball/trajectory`, at most `prediction.trajectory_rate` times per second.
    pub trajectory: Option<PredictedTrajectory>,
    /// `/ball/markers`, with each trajectory.
    pub markers: Option<MarkerArray>,
    /// `topics.odometry`, with each state, when that topic is set.
    pub odometry: Option<Odometry>,
}

/// A trajectory due after a detection: the flight to predict and what its messages say.
#[derive(Debug, Clone, PartialEq)]
pub struct DueTrajectory {
    flight: Flight,
    estimate: Estimate,
    intercept: InterceptEstimate,
    frame: String,
    table: crate::config::TableParams,
}

impl DueTrajectory {
    /// Predicts the trajectory and adds `/ball/trajectory` and `/ball/markers` to `published`.
    pub fn publish_into(&self, published: &mut Published) {
        let trajectory = self.flight.fly();
        let (estimate, frame) = (&self.estimate, self.frame.as_str());
        published.trajectory = Some(trajectory_msg(
            self.flight.stamp,
            estimate.track_id,
            &trajectory,
            frame,
        ));
        published.markers = Some(markers(
            estimate,
            Some(&self.intercept),
            &trajectory,
            &self.table,
            frame,
        ));
    }
}

/// What happened to one detection message.
#[derive(Debug, Clone, PartialEq)]
pub struct Step {
    /// The estimator's verdict, or why the message never reached it.
    pub verdict: Result<Verdict, ConvertError>,
    /// The detection as the estimator took it (in the table frame), when the message reached it.
    pub detection: Option<Detection>,
    /// The estimator's output, when the message reached it.
    pub output: Option<Output>,
    /// The messages to publish.
    pub published: Published,
}

/// The estimator with the node's publishing rules, and the stroke model its racket services
/// answer with.
#[derive(Debug, Clone)]
pub struct Pipeline {
    estimator: Estimator,
    stroke: Stroke,
    trajectory_period: i64,
    trajectory_dt: f64,
    horizon: f64,
    /// The track whose trajectory is being published and the stamp from which its next one is
    /// due [ns].
    next_trajectory: Option<(u32, i64)>,
    /// The interception last published on `/ball/intercept`.
    last_intercept: Option<InterceptEstimate>,
    /// The estimate and interception whose trajectory is due, from the last detection.
    due_trajectory: Option<(Estimate, InterceptEstimate)>,
    /// The static transforms from `/tf_static` that bring detections in other frames into
    /// `table`.
    frames: Frames,
    /// Whether the state is published as odometry too (`topics.odometry` set).
    odometry: bool,
    /// The table the markers draw.
    table: crate::config::TableParams,
}

impl Pipeline {
    /// A pipeline with the given (validated) configuration.
    pub fn new(config: &Config) -> Self {
        Self {
            estimator: Estimator::new(config),
            stroke: Stroke::new(config),
            trajectory_period: (1e9 / config.prediction.trajectory_rate).round() as i64,
            trajectory_dt: config.prediction.trajectory_dt,
            horizon: config.prediction.horizon,
            next_trajectory: None,
            last_intercept: None,
            due_trajectory: None,
            frames: Frames::new(&config.frames.table_frame),
            odometry: !config.topics.odometry.is_empty(),
            table: config.table.clone(),
        }
    }

    /// Takes the static transforms of a `/tf_static` message (tf2_msgs/TFMessage): detections in
    /// a frame they connect to `table` are brought into it. Returns the transforms refused, with
    /// why.
    pub fn on_static_transforms(&mut self, msg: &TFMessage) -> Vec<FrameError> {
        add_static_transforms(&mut self.frames, msg)
    }

    /// The estimator behind the pipeline.
    pub fn estimator(&self) -> &Estimator {
        &self.estimator
    }

    /// Takes `config`'s live values from the next detection on (see
    /// [`Estimator::reconfigure`]; also the racket, arm and stroke of the services and the
    /// trajectory's rate, spacing and horizon); `previous` is the configuration it ran with.
    pub fn reconfigure(&mut self, previous: &Config, config: &Config) {
        self.estimator.reconfigure(previous, config);
        self.stroke = Stroke::new(config);
        self.trajectory_period = (1e9 / config.prediction.trajectory_rate).round() as i64;
        self.trajectory_dt = config.prediction.trajectory_dt;
        self.horizon = config.prediction.horizon;
    }

    /// Runs the ended tracks' lessons on a worker thread (see
    /// [`Estimator::run_lessons_on_a_worker`]).
    pub fn run_lessons_on_a_worker(&mut self, waiting: Waiting) -> std::io::Result<()> {
        self.estimator.run_lessons_on_a_worker(waiting)
    }

    /// [`Estimator::lesson_wait`].
    pub fn lesson_wait(&self) -> std::time::Duration {
        self.estimator.lesson_wait()
    }

    /// The input has ended: the live track teaches what it learned (see
    /// [`Estimator::end_of_input`]).
    pub fn end_of_input(&mut self) {
        self.estimator.end_of_input();
    }

    /// Drops the tracks and everything learned, keeping the counters (see [`Estimator::reset`]).
    pub fn reset(&mut self, config: &Config) {
        self.estimator.reset(config);
        self.stroke = Stroke::new(config);
        self.next_trajectory = None;
        self.last_intercept = None;
        self.due_trajectory = None;
    }

    /// What happened to the detections so far.
    pub fn counters(&self) -> Counters {
        self.estimator.counters()
    }

    /// Handles one announced robot hit (`topics.robot_hits`): the first detection after its
    /// impact that the predicted rebound explains starts the return's track
    /// ([`Estimator::expect_hit`]). A message in an unknown frame or with a face normal that is
    /// not a unit vector is refused with why.
    pub fn on_robot_hit(&mut self, msg: &RobotHit) -> Result<(), ConvertError> {
        let hit = robot_hit_from_msg_in(msg, &self.frames)?;
        self.estimator.expect_hit(hit);
        Ok(())
    }

    /// Handles one detection message, in arrival order: [`Self::handle_detection`], then
    /// [`Self::add_due_trajectory`].
    pub fn on_detection(&mut self, msg: &BallDetection) -> Step {
        let mut step = self.handle_detection(msg);
        self.add_due_trajectory(&mut step.published);
        step
    }

    /// The detection's own work: the message converted, the estimator's update and the
    /// interception, and the messages that publish them (`/ball/state`, `/ball/intercept`,
    /// odometry). When the trajectory is due after it, [`Self::add_due_trajectory`] adds it:
    /// the node publishes the detection's own messages first, so that the trajectory (a 1.5 s
    /// flight predicted at most 50 times a second) never delays them.
    pub fn handle_detection(&mut self, msg: &BallDetection) -> Step {
        self.due_trajectory = None;
        let detection = match detection_from_msg_in(msg, &self.frames) {
            Ok(d) => d,
            Err(e) => {
                self.estimator.reject(Rejection::UnknownFrame);
                return Step {
                    verdict: Err(e),
                    detection: None,
                    output: None,
                    published: Published::default(),
                };
            }
        };
        let full_before = self.estimator.intercept_counts().full;
        let out = self.estimator.handle(&detection);
        let predicted_in_full = self.estimator.intercept_counts().full > full_before;
        if let (Some(estimate), Some(intercept)) = (&out.estimate, &out.intercept)
            && self.trajectory_due(estimate, predicted_in_full)
        {
            self.due_trajectory = Some((*estimate, *intercept));
        }
        let frame = self.frames.fixed();
        if out.intercept.is_some() {
            self.last_intercept = out.intercept;
        }
        let published = Published {
            state: out.estimate.as_ref().map(|e| state_msg(e, frame)),
            intercept: out.intercept.as_ref().map(|i| intercept_msg(i, frame)),
            odometry: out
                .estimate
                .as_ref()
                .filter(|_| self.odometry)
                .map(|e| odometry_msg(e, frame)),
            ..Published::default()
        };
        Step {
            verdict: Ok(out.verdict),
            detection: Some(detection),
            output: Some(out),
            published,
        }
    }

    /// Adds `/ball/trajectory` and `/ball/markers` to `published` when the trajectory is due
    /// after the last detection ([`Self::handle_detection`]); true when it did.
    pub fn add_due_trajectory(&mut self, published: &mut Published) -> bool {
        self.take_due_trajectory()
            .map(|due| due.publish_into(published))
            .is_some()
    }

    /// The trajectory due after the last detection ([`Self::handle_detection`]), as a value to
    /// predict and publish anywhere ([`DueTrajectory::publish_into`]; the replay does it on its
    /// writing thread): what [`Self::add_due_trajectory`] does in two steps.
    pub fn take_due_trajectory(&mut self) -> Option<DueTrajectory> {
        let (estimate, intercept) = self.due_trajectory.take()?;
        Some(DueTrajectory {
            flight: self
                .estimator
                .trajectory_flight(self.trajectory_dt, self.horizon)?,
            estimate,
            intercept,
            frame: self.frames.fixed().to_owned(),
            table: self.table.clone(),
        })
    }

    /// True when the trajectory is to be published after the detection that gave `estimate`, the
    /// next one then scheduled. Trajectories come due on a grid of `prediction.trajectory_rate`'s
    /// period from a track's first estimate; one due is published on the first detection whose
    /// interception was moved rather than `predicted_in_full`, or on any two periods late, and the
    /// next comes due at the first grid point after it.
    fn trajectory_due(&mut self, estimate: &Estimate, predicted_in_full: bool) -> bool {
        let period = self.trajectory_period.max(1);
        let due = match self.next_trajectory {
            Some((track, due)) if track == estimate.track_id => due,
            _ => estimate.stamp,
        };
        let late = estimate.stamp - due;
        let publish = late >= 0 && (!predicted_in_full || late >= 2 * period);
        let next = if publish {
            due + (late / period + 1) * period
        } else {
            due
        };
        self.next_trajectory = Some((estimate.track_id, next));
        publish
    }

    /// Answers `~/predict_trajectory`: the predicted flight of the live track (`track_id` its id)
    /// or of the request's `initial` state (`track_id` 0). A zero `horizon` or `dt` takes the
    /// configured `prediction.horizon` / `prediction.trajectory_dt`. Never fails silently: a
    /// request that cannot be answered gets `success = false` and a message saying why.
    pub fn predict_trajectory(
        &self,
        request: &PredictTrajectoryRequest,
    ) -> PredictTrajectoryResponse {
        match self.answer_predict_trajectory(request) {
            Ok(trajectory) => PredictTrajectoryResponse {
                success: true,
                message: String::new(),
                trajectory,
            },
            Err(e) => PredictTrajectoryResponse {
                success: false,
                message: e.to_string(),
                trajectory: PredictedTrajectory::default(),
            },
        }
    }

    fn answer_predict_trajectory(
        &self,
        request: &PredictTrajectoryRequest,
    ) -> Result<PredictedTrajectory, ServiceError> {
        let horizon = if request.horizon == 0.0 {
            self.horizon
        } else {
            request.horizon
        };
        let dt = if request.dt == 0.0 {
            self.trajectory_dt
        } else {
            request.dt
        };
        if !(horizon > 0.0 && horizon <= MAX_HORIZON) {
            return Err(ServiceError::Horizon {
                horizon,
                configured: self.horizon,
            });
        }
        if !(dt > 0.0 && dt <= horizon && horizon / dt <= MAX_SAMPLES) {
            return Err(ServiceError::Step {
                dt,
                configured: self.trajectory_dt,
            });
        }
        if request.track_id == 0 {
            let (stamp, _, start) = state_from_msg(&request.initial);
            if !start.to_vector().iter().all(|v| v.is_finite()) {
                return Err(ServiceError::NonFiniteState);
            }
            let trajectory = self.estimator.predict_flight(&start, dt, horizon);
            return Ok(trajectory_msg(stamp, 0, &trajectory, self.frames.fixed()));
        }
        let live = self.live_track(request.track_id, "an initial state")?;
        let (stamp, trajectory) =
            self.estimator
                .predicted_trajectory(dt, horizon)
                .ok_or(ServiceError::TrackEnded {
                    track_id: request.track_id,
                })?;
        Ok(trajectory_msg(
            stamp,
            live,
            &trajectory,
            self.frames.fixed(),
        ))
    }

    /// The stroke model flying the physics the estimator learned so far (the configured physics
    /// before any flight).
    fn learned_stroke(&self) -> Stroke {
        let learned = self.estimator.learned_params();
        self.stroke
            .with_params(&learned.params)
            .with_reynolds_exponents(learned.reynolds_exponents)
    }

    /// `track_id` when it is the live track's id; otherwise why not, pointing at track 0 and
    /// `alternative` (what the request gives instead of a track).
    fn live_track(&self, track_id: u32, alternative: &'static str) -> Result<u32, ServiceError> {
        match self.estimator.estimate() {
            Some(e) if e.track_id == track_id => Ok(track_id),
            Some(e) => Err(ServiceError::NotLive {
                track_id,
                live: e.track_id,
                alternative,
            }),
            None => Err(ServiceError::NothingTracked {
                track_id,
                alternative,
            }),
        }
    }

    /// Answers `~/predict_rebound`: the hit of the request's ball by its racket and the return
    /// flight to the first bounce. A return that does not land on the opponent's half is still a
    /// prediction (`success` true, `lands_on_table` false) with a message saying what the ball
    /// does; a hit that cannot be predicted (non-unit normal, impact point off the face, ball not
    /// approaching the face, non-finite value) gets `success = false` and the reason.
    pub fn predict_rebound(&self, request: &PredictReboundRequest) -> PredictReboundResponse {
        let (ball, racket) = rebound_request(request);
        match self.learned_stroke().rebound(&ball, &racket) {
            Ok(rebound) => rebound_response(&rebound),
            Err(e) => PredictReboundResponse {
                success: false,
                message: e.to_string(),
                ..PredictReboundResponse::default()
            },
        }
    }

    /// Answers `~/plan_return`: the racket command that returns the ball to `target` on the
    /// opponent's half, from the live track's interception (`track_id` its id, the same
    /// prediction as the last `/ball/intercept`) or from the request's `ball` (`track_id` 0).
    /// The third condition is the flight time when it is not 0, else the net clearance (0 = the
    /// configured `stroke.net_clearance`). A request that cannot be answered (no such live track,
    /// no valid interception, target off the opponent's half, impact point off the face,
    /// unreachable target, racket too fast) gets `success = false` and a message saying why.
    pub fn plan_return(&self, request: &PlanReturnRequest) -> PlanReturnResponse {
        match self.answer_plan_return(request) {
            Ok(response) => response,
            Err(e) => PlanReturnResponse {
                success: false,
                message: e.to_string(),
                ..PlanReturnResponse::default()
            },
        }
    }

    fn answer_plan_return(
        &self,
        request: &PlanReturnRequest,
    ) -> Result<PlanReturnResponse, ServiceError> {
        let (impact_stamp, ball, covariance) = if request.track_id == 0 {
            let (_, _, ball) = state_from_msg(&request.ball);
            let covariance = StateMatrix::from_row_slice(&request.ball.covariance);
            if covariance.iter().any(|v| !v.is_finite()) {
                return Err(ServiceError::NonFiniteCovariance);
            }
            (request.ball.header.stamp, ball, covariance)
        } else {
            self.interception(request.track_id)?
        };
        // 0 = not given, as PlanReturn.srv says.
        let given = |v: f64| (v != 0.0).then_some(v);
        let stroke = self.learned_stroke();
        let condition = stroke.condition(given(request.flight_time), given(request.net_clearance));
        let aim = Aim {
            target: Vector2::new(request.target.x, request.target.y),
            condition,
            impact_offset: request.impact_offset,
            brush_speed: request.brush_speed,
        };
        let plan = stroke.plan(&ball, &aim)?;
        let landing_covariance =
            if covariance.iter().all(|v| *v == 0.0) && !stroke.racket().is_uncertain() {
                None
            } else {
                stroke.landing_covariance(&ball, &covariance, &plan.racket)
            };
        Ok(plan_response(impact_stamp, &plan, &landing_covariance))
    }

    /// The stamp, ball state and covariance of the live track's predicted interception, when `track_id` is
    /// the live track and its interception is valid.
    fn interception(
        &self,
        track_id: u32,
    ) -> Result<(Time, physics::BallState, StateMatrix), ServiceError> {
        self.live_track(track_id, "a ball state")?;
        let intercept = self
            .last_intercept
            .filter(|i| i.track_id == track_id)
            .ok_or(ServiceError::NoInterceptionYet { track_id })?;
        match intercept.intercept.crossing {
            Ok(crossing) => Ok((
                offset(intercept.stamp, crossing.time),
                crossing.state,
                crossing.covariance,
            )),
            Err(why) => Err(ServiceError::NoValidInterception { track_id, why }),
        }
    }
}

/// Why a service request (`~/predict_trajectory`, `~/plan_return`) is refused; its `Display` is
/// the response's `message`.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ServiceError {
    /// The horizon asked for is out of range.
    #[error(
        "horizon {horizon} s is out of range: give 0 < horizon <= {} s (0 = the configured {configured} s)",
        MAX_HORIZON
    )]
    Horizon {
        /// The horizon asked for [s].
        horizon: f64,
        /// The configured horizon [s].
        configured: f64,
    },
    /// The sample step asked for is out of range.
    #[error(
        "dt {dt} s is out of range: give 0 < dt <= horizon with at most {} samples (0 = the configured {configured} s)",
        MAX_SAMPLES
    )]
    Step {
        /// The step asked for [s].
        dt: f64,
        /// The configured step [s].
        configured: f64,
    },
    /// The request's state has a NaN or infinite value.
    #[error("the initial state has a non-finite value")]
    NonFiniteState,
    /// The request's covariance has a NaN or infinite value.
    #[error("the ball's covariance has a non-finite value")]
    NonFiniteCovariance,
    /// The track ended while the request was answered.
    #[error("track {track_id} ended")]
    TrackEnded {
        /// The track asked for.
        track_id: u32,
    },
    /// Another track is live.
    #[error(
        "track {track_id} is not live; the live track is {live} (or use track_id 0 with {alternative})"
    )]
    NotLive {
        /// The track asked for.
        track_id: u32,
        /// The live track.
        live: u32,
        /// What the request can give instead of a track.
        alternative: &'static str,
    },
    /// No ball is tracked.
    #[error(
        "track {track_id} is not live: no ball is tracked now (use track_id 0 with {alternative})"
    )]
    NothingTracked {
        /// The track asked for.
        track_id: u32,
        /// What the request can give instead of a track.
        alternative: &'static str,
    },
    /// The live track has not predicted an interception yet.
    #[error("track {track_id} has no interception prediction yet")]
    NoInterceptionYet {
        /// The track asked for.
        track_id: u32,
    },
    /// The live track's interception is not valid.
    #[error(
        "track {track_id} has no valid interception: {} (use track_id 0 with a ball state)",
        .why.describe()
    )]
    NoValidInterception {
        /// The track asked for.
        track_id: u32,
        /// Why its interception is not valid.
        why: crate::online::intercept::NoIntercept,
    },
    /// No racket command answers the request.
    #[error(transparent)]
    Plan(#[from] PlanError),
}

/// Longest horizon `~/predict_trajectory` accepts [s] (as `prediction.horizon`).
const MAX_HORIZON: f64 = 10.0;
/// Most samples one `~/predict_trajectory` response may hold.
const MAX_SAMPLES: f64 = 100_000.0;

#[cfg(test)]
mod tests {
    use super::*;
    use crate::eval::sim::{SimOptions, simulate};
    use crate::model::detection::seconds_to_ns;
    use crate::physics::PhysicsParams;
    use crate::physics::racket::ImpactError;
    use crate::ros::msgs::convert::detection_to_msg;
    use crate::ros::msgs::geometry_msgs::{Point, Vector3};

    fn request(track_id: u32, horizon: f64, dt: f64) -> PredictTrajectoryRequest {
        let mut r = PredictTrajectoryRequest {
            track_id,
            horizon,
            dt,
            ..PredictTrajectoryRequest::default()
        };
        r.initial.header.stamp =
            crate::ros::msgs::builtin_interfaces::Time::from_nanos(seconds_to_ns(2.0));
        r.initial.position.x = 1.0;
        r.initial.position.z = 0.3;
        r.initial.velocity.x = -5.0;
        r.initial.velocity.z = 1.0;
        r.initial.spin.y = -50.0;
        r
    }

    #[test]
    fn predict_trajectory_from_a_state_and_from_the_live_track() {
        let config = Config::default();
        let mut pipeline = Pipeline::new(&config);
        // From a given state: samples every dt from its stamp, the configured defaults for 0.
        let r = pipeline.predict_trajectory(&request(0, 0.5, 0.01));
        assert!(r.success, "{}", r.message);
        assert_eq!(r.trajectory.stamps.len(), 51);
        assert_eq!(r.trajectory.header.stamp.to_nanos(), seconds_to_ns(2.0));
        assert_eq!(r.trajectory.positions[0].x, 1.0);
        let defaults = pipeline.predict_trajectory(&request(0, 0.0, 0.0));
        let p = &config.prediction;
        assert!(defaults.success);
        assert_eq!(
            defaults,
            pipeline.predict_trajectory(&request(0, p.horizon, p.trajectory_dt))
        );
        // No track yet.
        let none = pipeline.predict_trajectory(&request(1, 0.5, 0.01));
        let why = pipeline
            .answer_predict_trajectory(&request(1, 0.5, 0.01))
            .unwrap_err();
        assert!(
            matches!(why, ServiceError::NothingTracked { track_id: 1, .. }),
            "{why}"
        );
        assert!(!none.success && none.message == why.to_string());
        // A live track: its id gives the same prediction as the published trajectory's model.
        let options = SimOptions {
            shots: 1,
            ..SimOptions::default()
        };
        let session = simulate(&config, &options).expect("simulated");
        let mut live = None;
        for d in session.stream.iter().take(60) {
            let step = pipeline.on_detection(&detection_to_msg(&d.detection));
            if let Some(e) = step.output.and_then(|o| o.estimate) {
                live = Some(e.track_id);
            }
        }
        let track = live.expect("a track after 60 detections");
        let r = pipeline.predict_trajectory(&request(track, 0.3, 0.01));
        assert!(r.success, "{}", r.message);
        assert_eq!(r.trajectory.track_id, track);
        let other = pipeline.answer_predict_trajectory(&request(track + 1, 0.3, 0.01));
        assert_eq!(
            other,
            Err(ServiceError::NotLive {
                track_id: track + 1,
                live: track,
                alternative: "an initial state"
            })
        );
    }

    /// Trajectories come on the rate's grid from each track's first estimate, one per slot, kept
    /// off the detections that predicted their interception in full unless two periods late.
    #[test]
    fn trajectories_keep_their_rate_and_keep_off_full_predictions() {
        let config = Config::default();
        let period = seconds_to_ns(1.0 / config.prediction.trajectory_rate);
        let mut pipeline = Pipeline::new(&config);
        let options = SimOptions {
            shots: 4,
            ..SimOptions::default()
        };
        let session = simulate(&config, &options).expect("simulated");
        let (mut published, mut deferred, mut full_and_published) = (0, 0, 0);
        // Per track: its first estimate's stamp and the grid slots published in.
        let mut tracks: std::collections::BTreeMap<u32, (i64, Vec<i64>)> = Default::default();
        for d in &session.stream {
            let full_before = pipeline.estimator().intercept_counts().full;
            let step = pipeline.on_detection(&detection_to_msg(&d.detection));
            let full = pipeline.estimator().intercept_counts().full > full_before;
            let Some(estimate) = step.output.and_then(|o| o.intercept.and(o.estimate)) else {
                continue;
            };
            let (first, slots) = tracks
                .entry(estimate.track_id)
                .or_insert((estimate.stamp, Vec::new()));
            let slot = (estimate.stamp - *first) / period;
            if step.published.trajectory.is_some() {
                published += 1;
                if full {
                    full_and_published += 1;
                    assert!(
                        slots.last().is_none_or(|&last| slot >= last + 2),
                        "published with a full prediction less than two periods late"
                    );
                }
                assert!(
                    slots.last().is_none_or(|&last| slot > last),
                    "two in a slot"
                );
                slots.push(slot);
            } else if full && slots.last().is_none_or(|&last| slot > last) {
                deferred += 1;
            }
        }
        assert!(deferred > 0 && published > 20, "{deferred} {published}");
        assert!(
            full_and_published * 10 < published,
            "{full_and_published} {published}"
        );
        // Each due at most two periods late: the first within slot 2, the next within two slots
        // after the one after, and few slots go without.
        for (first, slots) in tracks.values() {
            assert!(slots.first().is_some_and(|&s| s <= 2), "track from {first}");
            assert!(slots.windows(2).all(|w| w[1] - w[0] <= 3), "{slots:?}");
            let span = slots.last().map_or(0, |&last| last + 1);
            assert!(slots.len() as i64 * 4 >= span * 3, "{slots:?}");
        }
    }

    /// The node's two steps: a detection's own messages never carry the trajectory, and the
    /// trajectory added after them is the one, and the only one, `on_detection` gives.
    #[test]
    fn the_due_trajectory_comes_after_the_detections_own_messages() {
        let config = Config::default();
        let (mut whole, mut split) = (Pipeline::new(&config), Pipeline::new(&config));
        let options = SimOptions {
            shots: 2,
            ..SimOptions::default()
        };
        let session = simulate(&config, &options).expect("simulated");
        let mut trajectories = 0;
        for d in &session.stream {
            let msg = detection_to_msg(&d.detection);
            let expected = whole.on_detection(&msg);
            let mut step = split.handle_detection(&msg);
            assert!(step.published.trajectory.is_none() && step.published.markers.is_none());
            let added = split.add_due_trajectory(&mut step.published);
            assert_eq!(added, expected.published.trajectory.is_some());
            assert!(
                !split.add_due_trajectory(&mut step.published),
                "added twice"
            );
            assert_eq!(step, expected);
            trajectories += usize::from(added);
        }
        assert!(trajectories > 10, "{trajectories}");
    }

    #[test]
    fn predict_trajectory_refuses_bad_requests_with_a_reason() {
        let pipeline = Pipeline::new(&Config::default());
        for (horizon, dt, horizon_refused) in [
            (-1.0, 0.01, true),
            (20.0, 0.01, true),
            (f64::NAN, 0.01, true),
            (0.5, 1.0, false),
            (10.0, 1e-6, false),
        ] {
            let why = pipeline
                .answer_predict_trajectory(&request(0, horizon, dt))
                .unwrap_err();
            if horizon_refused {
                assert!(matches!(why, ServiceError::Horizon { .. }), "{why}");
            } else {
                assert!(matches!(why, ServiceError::Step { .. }), "{why}");
            }
            let r = pipeline.predict_trajectory(&request(0, horizon, dt));
            assert!(!r.success && r.message == why.to_string());
            assert!(r.trajectory.stamps.is_empty());
        }
        let mut bad = request(0, 0.5, 0.01);
        bad.initial.velocity.y = f64::INFINITY;
        assert_eq!(
            pipeline.answer_predict_trajectory(&bad),
            Err(ServiceError::NonFiniteState)
        );
    }

    /// The ball of the racket tests (tests/core/racket.rs), just before impact, at 2 s.
    fn ball() -> BallState {
        let mut b = BallState::default();
        b.header.stamp = crate::ros::msgs::builtin_interfaces::Time::from_nanos(seconds_to_ns(2.0));
        b.header.frame_id = "table".into();
        b.position = Point {
            x: -1.6,
            y: 0.1,
            z: 0.25,
        };
        b.velocity = Vector3 {
            x: -5.0,
            y: 0.4,
            z: -1.0,
        };
        b.spin = Vector3 {
            x: 20.0,
            y: -150.0,
            z: 30.0,
        };
        b
    }

    fn plan_request(x: f64, y: f64) -> PlanReturnRequest {
        PlanReturnRequest {
            track_id: 0,
            ball: ball(),
            target: Point { x, y, z: 0.0 },
            ..PlanReturnRequest::default()
        }
    }

    /// `~/predict_rebound` for `ball` hit by the racket of a `~/plan_return` answer.
    fn rebound_request(
        ball: &BallState,
        plan: &PlanReturnResponse,
        offset: f64,
    ) -> PredictReboundRequest {
        PredictReboundRequest {
            ball_position: ball.position,
            ball_velocity: ball.velocity,
            ball_spin: ball.spin,
            racket_velocity: plan.racket_velocity,
            racket_normal: plan.racket_normal,
            impact_offset: offset,
        }
    }

    fn distance(a: &Point, b: &Point) -> f64 {
        (a.x - b.x).hypot(a.y - b.y)
    }

    #[test]
    fn plan_return_and_predict_rebound_from_a_given_state() {
        let config = Config::default();
        let pipeline = Pipeline::new(&config);
        let requests = [
            plan_request(0.9, 0.3),
            PlanReturnRequest {
                flight_time: 0.6,
                ..plan_request(0.6, 0.0)
            },
            PlanReturnRequest {
                net_clearance: 0.1,
                impact_offset: 0.06,
                brush_speed: 2.0,
                ..plan_request(1.0, 0.5)
            },
        ];
        for request in &requests {
            let plan = pipeline.plan_return(request);
            assert!(
                plan.success && plan.message.is_empty(),
                "{request:?}: {}",
                plan.message
            );
            assert_eq!(plan.impact_stamp, request.ball.header.stamp);
            assert_eq!(plan.impact_position, request.ball.position);
            assert!(plan.landing_error < 1e-3, "{}", plan.landing_error);
            // The same distance, to rounding (the landing is computed in another order).
            let landing_error = distance(&plan.landing_position, &request.target);
            assert!((landing_error - plan.landing_error).abs() < 1e-15);
            if request.flight_time != 0.0 {
                assert!((plan.flight_time - request.flight_time).abs() < 1e-3);
            } else {
                assert!(
                    (plan.net_clearance
                        - if request.net_clearance == 0.0 {
                            config.stroke.net_clearance
                        } else {
                            request.net_clearance
                        })
                    .abs()
                        < 1e-3
                );
            }
            assert!(plan.contact_time > 0.0 && plan.peak_force > 0.0 && plan.wrist_force > 0.0);
            // The planned command through ~/predict_rebound lands within 1 mm of the target.
            let rebound = pipeline.predict_rebound(&rebound_request(
                &request.ball,
                &plan,
                request.impact_offset,
            ));
            assert!(
                rebound.success && rebound.message.is_empty(),
                "{}",
                rebound.message
            );
            assert!(rebound.lands_on_table);
            let miss = distance(&rebound.landing_position, &request.target);
            assert!(miss < 1e-3, "{request:?}: missed by {miss} m");
            assert_eq!(rebound.landing_position, plan.landing_position);
            assert_eq!(
                (rebound.ball_velocity, rebound.ball_spin),
                (plan.ball_velocity, plan.ball_spin)
            );
            assert_eq!(
                (
                    rebound.contact_time,
                    rebound.peak_force,
                    rebound.wrist_force
                ),
                (plan.contact_time, plan.peak_force, plan.wrist_force)
            );
            assert!(rebound.mean_force > 0.0 && rebound.mean_force < rebound.peak_force);
            assert!(
                rebound.rebound_power_coefficient > 0.0 && rebound.rebound_power_coefficient < 1.0
            );
            assert!(rebound.reduced_mass > 0.0);
        }
        // No condition: the configured net clearance.
        let configured = PlanReturnRequest {
            net_clearance: config.stroke.net_clearance,
            ..requests[0].clone()
        };
        assert_eq!(
            pipeline.plan_return(&requests[0]),
            pipeline.plan_return(&configured)
        );
    }

    #[test]
    fn racket_services_fly_the_physics_learned_from_the_rally() {
        let config = Config::default();
        let mut pipeline = Pipeline::new(&config);
        let options = SimOptions {
            shots: 3,
            ..SimOptions::default()
        };
        for d in &simulate(&config, &options).expect("simulated").stream {
            pipeline.on_detection(&detection_to_msg(&d.detection));
        }
        let learned_all = pipeline.estimator().learned_params();
        let learned = learned_all.params;
        assert_ne!(
            learned,
            PhysicsParams::from_config(&config),
            "nothing learned"
        );
        // The same answers as a pipeline configured with the learned values.
        let mut taught = config.clone();
        taught.aero.drag_scale = learned.drag_scale;
        taught.aero.magnus_scale = learned.magnus_scale;
        taught.table.restitution = learned.restitution;
        taught.table.friction = learned.friction;
        taught.aero.reynolds_exponents = learned_all.reynolds_exponents.to_vec();
        let configured = Pipeline::new(&taught);
        let request = plan_request(0.9, 0.3);
        let plan = pipeline.plan_return(&request);
        assert!(plan.success, "{}", plan.message);
        assert_eq!(plan, configured.plan_return(&request));
        let rebound = rebound_request(&request.ball, &plan, request.impact_offset);
        assert_eq!(
            pipeline.predict_rebound(&rebound),
            configured.predict_rebound(&rebound)
        );
        assert_eq!(
            pipeline.predict_trajectory(&self::request(0, 0.5, 0.01)),
            configured.predict_trajectory(&self::request(0, 0.5, 0.01))
        );
        // And not the configured physics' answer.
        assert_ne!(Pipeline::new(&config).plan_return(&request), plan);
    }

    #[test]
    fn racket_services_refuse_bad_requests_with_a_reason() {
        let pipeline = Pipeline::new(&Config::default());
        let good = pipeline.plan_return(&plan_request(0.9, 0.3));
        let rebound = |change: &dyn Fn(&mut PredictReboundRequest)| {
            let mut request = rebound_request(&ball(), &good, 0.0);
            change(&mut request);
            pipeline.predict_rebound(&request)
        };
        let off_face = rebound(&|r| r.impact_offset = 0.3);
        let not_unit = rebound(&|r| r.racket_normal.x *= 2.0);
        let not_finite = rebound(&|r| r.ball_spin.z = f64::NAN);
        for (r, words) in [
            (&off_face, "off the face"),
            (&not_unit, "unit vector"),
            (&not_finite, "non-finite"),
        ] {
            assert!(!r.success && r.message.contains(words), "{words}: {r:?}");
            assert!(!r.lands_on_table);
        }
        // A racket at rest returns the ball short: a prediction, with what happens.
        let short = rebound(&|r| {
            r.racket_velocity = Vector3::default();
            r.racket_normal = Vector3 {
                x: 1.0,
                y: 0.0,
                z: 0.0,
            };
        });
        assert!(short.success && !short.lands_on_table, "{short:?}");
        assert!(
            short.message.starts_with("the returned ball "),
            "{}",
            short.message
        );
        assert_eq!(short.landing_position, Point::default());
        assert!(short.contact_time > 0.0);

        let plan = |change: &dyn Fn(&mut PlanReturnRequest)| {
            let mut request = plan_request(0.9, 0.3);
            change(&mut request);
            let why = pipeline.answer_plan_return(&request).unwrap_err();
            (pipeline.plan_return(&request), why)
        };
        type Expected = fn(&ServiceError) -> bool;
        let refusals: [(_, Expected); 6] = [
            (plan(&|r| r.impact_offset = 0.3), |e| {
                matches!(
                    e,
                    ServiceError::Plan(PlanError::Impact(ImpactError::OffFace { .. }))
                )
            }),
            (plan(&|r| r.target.x = -0.5), |e| {
                matches!(e, ServiceError::Plan(PlanError::TargetOffTable { .. }))
            }),
            (plan(&|r| r.flight_time = -1.0), |e| {
                matches!(e, ServiceError::Plan(PlanError::FlightTime { .. }))
            }),
            (plan(&|r| r.net_clearance = 5.0), |e| {
                matches!(e, ServiceError::Plan(PlanError::NetClearance(_)))
            }),
            (plan(&|r| r.ball.velocity.x = f64::INFINITY), |e| {
                matches!(
                    e,
                    ServiceError::Plan(PlanError::Impact(ImpactError::NotFinite { .. }))
                )
            }),
            (plan(&|r| r.track_id = 5), |e| {
                matches!(e, ServiceError::NothingTracked { track_id: 5, .. })
            }),
        ];
        for ((r, why), expected) in refusals {
            assert!(expected(&why), "{why}");
            assert!(!r.success && r.message == why.to_string(), "{r:?}");
            assert_eq!(
                r,
                PlanReturnResponse {
                    success: false,
                    message: r.message.clone(),
                    ..PlanReturnResponse::default()
                }
            );
        }
    }

    #[test]
    fn plan_return_from_the_live_tracks_interception() {
        let config = Config::default();
        let mut pipeline = Pipeline::new(&config);
        let options = SimOptions {
            shots: 1,
            ..SimOptions::default()
        };
        let session = simulate(&config, &options).expect("simulated");
        let mut detections = session.stream.iter().enumerate();
        // Past the start of the track, up to a valid interception as /ball/intercept publishes it.
        let intercept = detections
            .by_ref()
            .find_map(|(n, d)| {
                let step = pipeline.on_detection(&detection_to_msg(&d.detection));
                step.published.intercept.filter(|i| i.valid && n >= 60)
            })
            .expect("a valid interception");
        let track = intercept.track_id;
        let request = PlanReturnRequest {
            track_id: track,
            ..plan_request(0.9, -0.2)
        };
        let plan = pipeline.plan_return(&request);
        assert!(plan.success, "{}", plan.message);
        assert_eq!(plan.impact_stamp, intercept.intercept_stamp);
        assert_eq!(plan.impact_position, intercept.position);
        // The same as planning from the published interception given as the ball.
        let mut given = request.clone();
        given.track_id = 0;
        given.ball.header.stamp = intercept.intercept_stamp;
        given.ball.position = intercept.position;
        given.ball.velocity = intercept.velocity;
        given.ball.spin = intercept.spin;
        given.ball.covariance = intercept.covariance;
        assert_eq!(pipeline.plan_return(&given), plan);
        // The interception's uncertainty carried to the landing: a positive variance of x, y
        // and the flight time, a symmetric matrix; without the ball's covariance only the
        // rubber's own (its calibration's covariance and scatter), none with a rubber known
        // exactly.
        let c = plan.landing_covariance;
        assert!(c[0] > 0.0 && c[4] > 0.0 && c[8] > 0.0, "{c:?}");
        assert_eq!((c[1], c[2], c[5]), (c[3], c[6], c[7]));
        given.ball.covariance = [0.0; 81];
        let rubber_only = pipeline.plan_return(&given).landing_covariance;
        assert!(
            rubber_only[0] > 0.0 && rubber_only[0] < c[0],
            "{rubber_only:?}"
        );
        let mut exact = config.clone();
        exact.racket.rubber_covariance.clear();
        exact.racket.rebound_scatter = vec![0.0, 0.0];
        let plan_exact = Pipeline::new(&exact).plan_return(&given);
        assert!(plan_exact.success, "{}", plan_exact.message);
        assert_eq!(plan_exact.landing_covariance, [0.0; 9]);
        let rebound = pipeline.predict_rebound(&rebound_request(&given.ball, &plan, 0.0));
        assert!(rebound.lands_on_table);
        assert!(distance(&rebound.landing_position, &request.target) < 1e-3);
        // Another track id is refused.
        let other = pipeline.plan_return(&PlanReturnRequest {
            track_id: track + 1,
            ..request.clone()
        });
        assert!(
            !other.success
                && other
                    .message
                    .contains(&format!("the live track is {track}")),
            "{}",
            other.message
        );
        // Once the ball has passed the hitting plane the interception is no longer valid.
        detections
            .find_map(|(_, d)| {
                let step = pipeline.on_detection(&detection_to_msg(&d.detection));
                step.published
                    .intercept
                    .filter(|i| !i.valid && i.track_id == track)
            })
            .expect("an invalid interception of the same track");
        let r = pipeline.plan_return(&request);
        assert!(
            !r.success && r.message.contains("no valid interception"),
            "{}",
            r.message
        );
    }

    /// A detection in a camera frame that `/tf_static` connects to `table` is the same
    /// detection as in `table`; without the transform it is refused with the reason.
    #[test]
    fn detections_in_a_connected_frame_are_brought_into_table() {
        use crate::ros::msgs::geometry_msgs::{Quaternion, Transform, TransformStamped};
        use crate::ros::msgs::std_msgs::Header;
        let config = Config::default();
        let options = SimOptions {
            shots: 1,
            ..SimOptions::default()
        };
        let session = simulate(&config, &options).expect("simulated");
        // camera_link: in world, 2.5 m above and 3 m behind the table's centre, turned a
        // quarter about z; the table at the origin of world.
        let h = std::f64::consts::FRAC_1_SQRT_2;
        let stamped = |parent: &str, child: &str, t: [f64; 3], q: [f64; 4]| TransformStamped {
            header: Header {
                frame_id: parent.to_owned().into(),
                ..Header::default()
            },
            child_frame_id: child.to_owned(),
            transform: Transform {
                translation: Vector3 {
                    x: t[0],
                    y: t[1],
                    z: t[2],
                },
                rotation: Quaternion {
                    x: q[0],
                    y: q[1],
                    z: q[2],
                    w: q[3],
                },
            },
        };
        let tf = TFMessage {
            transforms: vec![
                stamped("world", "table", [0.0; 3], [0.0, 0.0, 0.0, 1.0]),
                stamped("world", "camera_link", [-3.0, 0.0, 2.5], [0.0, 0.0, h, h]),
            ],
        };
        let mut in_table = Pipeline::new(&config);
        let mut in_camera = Pipeline::new(&config);
        let mut frames = Frames::new("table");
        assert!(add_static_transforms(&mut frames, &tf).is_empty());
        let to_camera = frames.to_fixed("camera_link").expect("connected").inverse();
        // Before the transform arrives: refused, saying why.
        let first = &session.stream[0].detection;
        let mut msg = detection_to_msg(first);
        msg.header.frame_id = "camera_link".into();
        let refused = in_camera.on_detection(&msg);
        assert!(matches!(
            refused.verdict,
            Err(ConvertError::UnknownFrame { .. })
        ));
        assert!(in_camera.on_static_transforms(&tf).is_empty());
        in_camera.reset(&config);
        for d in session.stream.iter().take(200) {
            let a = in_table.on_detection(&detection_to_msg(&d.detection));
            let mut camera = d.detection;
            camera.position = to_camera.point(&d.detection.position);
            camera.spin = d.detection.spin.map(|w| to_camera.vector(&w));
            camera.spin_covariance = d
                .detection
                .spin_covariance
                .map(|c| to_camera.covariance(&c));
            camera.position_covariance = d
                .detection
                .position_covariance
                .map(|c| to_camera.covariance(&c));
            let mut msg = detection_to_msg(&camera);
            msg.header.frame_id = "camera_link".into();
            let b = in_camera.on_detection(&msg);
            assert_eq!(
                std::mem::discriminant(&a.verdict),
                std::mem::discriminant(&b.verdict)
            );
            if let (Some(x), Some(y)) = (
                a.output.and_then(|o| o.estimate),
                b.output.and_then(|o| o.estimate),
            ) {
                assert!((x.state.position - y.state.position).norm() < 1e-9);
                assert!((x.state.spin - y.state.spin).norm() < 1e-6);
            }
        }
    }

    /// With `frames.table_frame` renamed, detections in that frame are taken as they are,
    /// every output is stamped in it, and detections in `table` are refused until `/tf_static`
    /// says where `table` is; the estimates are those of the default name.
    #[test]
    fn a_renamed_table_frame_names_inputs_and_outputs() {
        let config = Config::default();
        let mut renamed_config = config.clone();
        renamed_config.frames.table_frame = "tt_table".to_owned();
        let options = SimOptions {
            shots: 1,
            ..SimOptions::default()
        };
        let session = simulate(&config, &options).expect("simulated");
        let mut default = Pipeline::new(&config);
        let mut renamed = Pipeline::new(&renamed_config);
        let refused = renamed.on_detection(&detection_to_msg(&session.stream[0].detection));
        assert_eq!(
            refused.verdict,
            Err(ConvertError::UnknownFrame {
                frame: "table".into(),
                table: "tt_table".into()
            })
        );
        renamed.reset(&renamed_config);
        let (mut states, mut trajectories) = (0, 0);
        for d in session.stream.iter().take(300) {
            let msg = detection_to_msg(&d.detection);
            let a = default.on_detection(&msg);
            let mut msg = msg;
            msg.header.frame_id = "tt_table".into();
            let b = renamed.on_detection(&msg);
            assert_eq!(a.output, b.output);
            let p = b.published;
            if let Some(state) = &p.state {
                assert_eq!(state.header.frame_id, "tt_table");
                states += 1;
            }
            if let Some(i) = &p.intercept {
                assert_eq!(i.header.frame_id, "tt_table");
            }
            if let (Some(t), Some(m)) = (&p.trajectory, &p.markers) {
                assert_eq!(t.header.frame_id, "tt_table");
                assert!(m.markers.iter().all(|m| m.header.frame_id == "tt_table"));
                trajectories += 1;
            }
        }
        assert!(states > 100 && trajectories > 0, "{states} {trajectories}");
    }

    /// With `topics.odometry` set, every state is also published as odometry: the same
    /// position, velocity and spin, the covariance's blocks; by default none is.
    #[test]
    fn odometry_mirrors_the_state_when_asked_for() {
        let mut config = Config::default();
        let options = SimOptions {
            shots: 1,
            ..SimOptions::default()
        };
        let session = simulate(&config, &options).expect("simulated");
        let mut plain = Pipeline::new(&config);
        config.topics.odometry = "ball/odometry".to_owned();
        let mut with = Pipeline::new(&config);
        let mut seen = 0;
        for d in session.stream.iter().take(150) {
            let msg = detection_to_msg(&d.detection);
            assert!(plain.on_detection(&msg).published.odometry.is_none());
            let p = with.on_detection(&msg).published;
            let (Some(state), Some(odometry)) = (p.state, p.odometry) else {
                continue;
            };
            seen += 1;
            assert_eq!(odometry.header, state.header);
            assert_eq!(odometry.child_frame_id, "ball");
            assert_eq!(odometry.pose.pose.position, state.position);
            assert_eq!(odometry.twist.twist.linear, state.velocity);
            assert_eq!(odometry.twist.twist.angular, state.spin);
            for (i, j) in [(0, 0), (1, 2), (2, 1)] {
                assert_eq!(
                    odometry.pose.covariance[6 * i + j],
                    state.covariance[9 * i + j]
                );
            }
            for (i, j) in [(0, 0), (2, 4), (5, 5), (4, 1)] {
                assert_eq!(
                    odometry.twist.covariance[6 * i + j],
                    state.covariance[9 * (3 + i) + 3 + j]
                );
            }
        }
        assert!(seen > 100, "{seen} states");
        assert!(crate::ros::msgs::definitions::schema("nav_msgs/msg/Odometry").is_some());
    }
}
