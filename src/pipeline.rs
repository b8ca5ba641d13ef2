//! The node minus its transport: one `BallDetection` message in, the messages to publish out.
//! The ROS 2 node and the MCAP replay both drive this, so a replay runs exactly the code path of
//! the live node. Time comes from the messages only (the trajectory's rate limit too), so a
//! replay is deterministic.

use crate::config::Config;
use crate::estimator::{Counters, Estimator, Output, Rejection, Verdict};
use crate::msgs::convert::{
    ConvertError, detection_from_msg, intercept_msg, markers, state_msg, trajectory_msg,
};
use crate::msgs::ttball_msgs::msg::{
    BallDetection, BallState, InterceptPrediction, PredictedTrajectory,
};
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
}
