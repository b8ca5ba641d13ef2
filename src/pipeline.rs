//! The node minus its transport: one `BallDetection` message in, the messages to publish out.
//! The ROS 2 node and the MCAP replay both drive this, so a replay runs exactly the code path of
//! the live node. Time comes from the messages only (the trajectory's rate limit too), so a
//! replay is deterministic.

use crate::config::Config;
use crate::estimator::{Counters, Estimator, Output, Rejection, Verdict};
use crate::msgs::convert::{
    ConvertError, detection_from_msg, intercept_msg, markers, state_from_msg, state_msg,
    trajectory_msg,
};
use crate::msgs::ttball_msgs::msg::{
    BallDetection, BallState, InterceptPrediction, PredictedTrajectory,
};
use crate::msgs::ttball_msgs::srv::{PredictTrajectoryRequest, PredictTrajectoryResponse};
use crate::msgs::visualization_msgs::MarkerArray;

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
}

/// What happened to one detection message.
#[derive(Debug, Clone, PartialEq)]
pub struct Step {
    /// The estimator's verdict, or why the message never reached it.
    pub verdict: Result<Verdict, ConvertError>,
    /// The estimator's output, when the message reached it.
    pub output: Option<Output>,
    /// The messages to publish.
    pub published: Published,
}

/// The estimator with the node's publishing rules.
#[derive(Debug, Clone)]
pub struct Pipeline {
    estimator: Estimator,
    trajectory_period: i64,
    trajectory_dt: f64,
    horizon: f64,
    last_trajectory: Option<(u32, i64)>,
}

impl Pipeline {
    /// A pipeline with the given (validated) configuration.
    pub fn new(config: &Config) -> Self {
        Self {
            estimator: Estimator::new(config),
            trajectory_period: (1e9 / config.prediction.trajectory_rate).round() as i64,
            trajectory_dt: config.prediction.trajectory_dt,
            horizon: config.prediction.horizon,
            last_trajectory: None,
        }
    }

    /// The estimator behind the pipeline.
    pub fn estimator(&self) -> &Estimator {
        &self.estimator
    }

    /// What happened to the detections so far.
    pub fn counters(&self) -> Counters {
        self.estimator.counters()
    }

    /// Handles one detection message, in arrival order.
    pub fn on_detection(&mut self, msg: &BallDetection) -> Step {
        let detection = match detection_from_msg(msg) {
            Ok(d) => d,
            Err(e) => {
                self.estimator.reject(Rejection::UnknownFrame);
                return Step {
                    verdict: Err(e),
                    output: None,
                    published: Published::default(),
                };
            }
        };
        let out = self.estimator.handle(&detection);
        let mut published = Published {
            state: out.estimate.as_ref().map(state_msg),
            intercept: out.intercept.as_ref().map(intercept_msg),
            ..Published::default()
        };
        if let (Some(estimate), Some(intercept)) = (&out.estimate, &out.intercept) {
            let due = self.last_trajectory.is_none_or(|(track, stamp)| {
                track != estimate.track_id || estimate.stamp - stamp >= self.trajectory_period
            });
            if due
                && let Some((stamp, trajectory)) = self
                    .estimator
                    .predicted_trajectory(self.trajectory_dt, self.horizon)
            {
                self.last_trajectory = Some((estimate.track_id, stamp));
                published.trajectory = Some(trajectory_msg(stamp, estimate.track_id, &trajectory));
                published.markers = Some(markers(estimate, Some(intercept), &trajectory));
            }
        }
        Step {
            verdict: Ok(out.verdict),
            output: Some(out),
            published,
        }
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
            Err(message) => PredictTrajectoryResponse {
                success: false,
                message,
                trajectory: PredictedTrajectory::default(),
            },
        }
    }

    fn answer_predict_trajectory(
        &self,
        request: &PredictTrajectoryRequest,
    ) -> Result<PredictedTrajectory, String> {
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
            return Err(format!(
                "horizon {horizon} s is out of range: give 0 < horizon <= {MAX_HORIZON} s (0 = the configured {} s)",
                self.horizon
            ));
        }
        if !(dt > 0.0 && dt <= horizon && horizon / dt <= MAX_SAMPLES) {
            return Err(format!(
                "dt {dt} s is out of range: give 0 < dt <= horizon with at most {MAX_SAMPLES} samples (0 = the configured {} s)",
                self.trajectory_dt
            ));
        }
        if request.track_id == 0 {
            let (stamp, _, start) = state_from_msg(&request.initial);
            if !start.to_vector().iter().all(|v| v.is_finite()) {
                return Err("the initial state has a non-finite value".to_owned());
            }
            let trajectory = self.estimator.predict_flight(&start, dt, horizon);
            return Ok(trajectory_msg(stamp, 0, &trajectory));
        }
        match self.estimator.estimate() {
            Some(e) if e.track_id == request.track_id => {
                let (stamp, trajectory) = self
                    .estimator
                    .predicted_trajectory(dt, horizon)
                    .ok_or_else(|| format!("track {} ended", request.track_id))?;
                Ok(trajectory_msg(stamp, e.track_id, &trajectory))
            }
            Some(e) => Err(format!(
                "track {} is not live; the live track is {} (or use track_id 0 with an initial state)",
                request.track_id, e.track_id
            )),
            None => Err(format!(
                "track {} is not live: no ball is tracked now (use track_id 0 with an initial state)",
                request.track_id
            )),
        }
    }
}

/// Longest horizon `~/predict_trajectory` accepts [s] (as `prediction.horizon`).
const MAX_HORIZON: f64 = 10.0;
/// Most samples one `~/predict_trajectory` response may hold.
const MAX_SAMPLES: f64 = 100_000.0;

#[cfg(test)]
mod tests {
    use super::*;
    use crate::detection::seconds_to_ns;
    use crate::msgs::convert::detection_to_msg;
    use crate::sim::{SimOptions, simulate};

    fn request(track_id: u32, horizon: f64, dt: f64) -> PredictTrajectoryRequest {
        let mut r = PredictTrajectoryRequest {
            track_id,
            horizon,
            dt,
            ..PredictTrajectoryRequest::default()
        };
        r.initial.header.stamp =
            crate::msgs::builtin_interfaces::Time::from_nanos(seconds_to_ns(2.0));
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
        assert!(
            !none.success && none.message.contains("no ball is tracked"),
            "{}",
            none.message
        );
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
        let other = pipeline.predict_trajectory(&request(track + 1, 0.3, 0.01));
        assert!(
            !other.success
                && other
                    .message
                    .contains(&format!("the live track is {track}"))
        );
    }

    #[test]
    fn predict_trajectory_refuses_bad_requests_with_a_reason() {
        let pipeline = Pipeline::new(&Config::default());
        for (horizon, dt, words) in [
            (-1.0, 0.01, "horizon"),
            (20.0, 0.01, "horizon"),
            (f64::NAN, 0.01, "horizon"),
            (0.5, 1.0, "dt"),
            (10.0, 1e-6, "dt"),
        ] {
            let r = pipeline.predict_trajectory(&request(0, horizon, dt));
            assert!(
                !r.success && r.message.contains(words),
                "{horizon} {dt}: {}",
                r.message
            );
            assert!(r.trajectory.stamps.is_empty());
        }
        let mut bad = request(0, 0.5, 0.01);
        bad.initial.velocity.y = f64::INFINITY;
        let r = pipeline.predict_trajectory(&bad);
        assert!(!r.success && r.message.contains("non-finite"));
    }
}
