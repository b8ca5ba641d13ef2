//! Messages of `ttball_msgs` (`msgs/msg/*.msg`), field for field in the same order.
//!
//! All quantities are in the `table` frame, SI units. Covariances are row-major.

use serde::{Deserialize, Serialize};
use serde_big_array::BigArray;

use crate::ros::msgs::builtin_interfaces::Time;
use crate::ros::msgs::geometry_msgs::{Point, Vector3};
use crate::ros::msgs::std_msgs::Header;

/// `ttball_msgs/msg/BallDetection`: one 3D ball detection from a camera system (estimator input).
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct BallDetection {
    /// `stamp` = exposure time, `frame_id` = `"table"`.
    pub header: Header,
    /// Ball centre [m].
    pub position: Point,
    /// Covariance of `position`, row-major 3x3 [m^2]; all zero = use the configured noise of
    /// this `source`.
    pub position_covariance: [f64; 9],
    /// True when the camera measured the spin.
    pub has_spin: bool,
    /// Angular velocity [rad/s], valid only when `has_spin`.
    pub spin: Vector3,
    /// Covariance of `spin`, row-major 3x3 [(rad/s)^2]; all zero = configured default.
    pub spin_covariance: [f64; 9],
    /// Camera system that made the detection, one of `SOURCE_*`.
    pub source: u8,
    /// Detector score in [0, 1] (dimensionless).
    pub confidence: f32,
}

impl BallDetection {
    /// `source`: not stated; the estimator uses the default noise.
    pub const SOURCE_UNKNOWN: u8 = 0;
    /// `source`: wide-view 150 fps camera system (position only).
    pub const SOURCE_WIDE_150FPS: u8 = 1;
    /// `source`: narrow-view 900 fps camera system (position and spin).
    pub const SOURCE_HIGHSPEED_900FPS: u8 = 2;
}

/// `ttball_msgs/msg/BallState`: filtered state of one tracked ball (estimator output).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct BallState {
    /// `stamp` = time of the estimate (the detection's stamp), `frame_id` = `"table"`.
    pub header: Header,
    /// Track identifier; a new id for every new ball.
    pub track_id: u32,
    /// Track status, one of `STATUS_*`.
    pub status: u8,
    /// Ball centre [m].
    pub position: Point,
    /// Ball velocity [m/s].
    pub velocity: Vector3,
    /// Angular velocity [rad/s].
    pub spin: Vector3,
    /// Row-major 9x9 covariance over (position, velocity, spin)
    /// [m^2, (m/s)^2, (rad/s)^2 blocks on the diagonal].
    #[serde(with = "BigArray")]
    pub covariance: [f64; 81],
    /// Table bounces since the track started (count).
    pub bounces: u32,
    /// Normalised innovation squared of the last update (dimensionless).
    pub nis: f64,
}

impl BallState {
    /// `status`: track started, state not yet converged.
    pub const STATUS_INITIALIZING: u8 = 1;
    /// `status`: state updated by recent detections.
    pub const STATUS_TRACKING: u8 = 2;
    /// `status`: no recent detection; state predicted by the flight model only.
    pub const STATUS_COASTING: u8 = 3;
}

impl Default for BallState {
    fn default() -> Self {
        Self {
            header: Header::default(),
            track_id: 0,
            status: 0,
            position: Point::default(),
            velocity: Vector3::default(),
            spin: Vector3::default(),
            covariance: [0.0; 81],
            bounces: 0,
            nis: 0.0,
        }
    }
}

/// `ttball_msgs/msg/InterceptPrediction`: predicted crossing of the robot's hitting plane.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct InterceptPrediction {
    /// `stamp` = time of the state it was predicted from, `frame_id` = `"table"`.
    pub header: Header,
    /// Track the prediction was made for ([`BallState::track_id`]).
    pub track_id: u32,
    /// False when the ball will not reach the plane after one bounce on the robot's half.
    pub valid: bool,
    /// When the ball crosses the plane [s, ns].
    pub intercept_stamp: Time,
    /// Where the ball centre crosses the plane [m].
    pub position: Point,
    /// Velocity at the crossing [m/s].
    pub velocity: Vector3,
    /// Angular velocity at the crossing [rad/s].
    pub spin: Vector3,
    /// Row-major 9x9 covariance at the crossing over (position, velocity, spin), timing
    /// uncertainty included [m^2, (m/s)^2, (rad/s)^2 blocks on the diagonal].
    #[serde(with = "BigArray")]
    pub covariance: [f64; 81],
    /// True when the bounce on the robot's half below is predicted.
    pub bounce_valid: bool,
    /// When the ball bounces on the robot's half [s, ns]; valid only when `bounce_valid`.
    pub bounce_stamp: Time,
    /// Ball centre at that bounce [m]; valid only when `bounce_valid`.
    pub bounce_position: Point,
    /// Why `valid` is false (`REASON_*`; [`Self::REASON_VALID`] when valid).
    pub reason: u8,
    /// Variance of the crossing time [s^2].
    pub time_variance: f64,
}

impl InterceptPrediction {
    /// `reason`: the ball crosses the plane after one bounce on the robot's half.
    pub const REASON_VALID: u8 = 0;
    /// `reason`: the ball will hit the net.
    pub const REASON_NET: u8 = 1;
    /// `reason`: the ball will miss the table.
    pub const REASON_MISSES_TABLE: u8 = 2;
    /// `reason`: the ball will reach the plane without bouncing on the robot's half.
    pub const REASON_NO_BOUNCE: u8 = 3;
    /// `reason`: the ball will bounce twice on the robot's half.
    pub const REASON_TWO_BOUNCES: u8 = 4;
    /// `reason`: the ball will not reach the plane within the prediction horizon.
    pub const REASON_BEYOND_HORIZON: u8 = 5;
}

impl Default for InterceptPrediction {
    fn default() -> Self {
        Self {
            header: Header::default(),
            track_id: 0,
            valid: false,
            intercept_stamp: Time::default(),
            position: Point::default(),
            velocity: Vector3::default(),
            spin: Vector3::default(),
            covariance: [0.0; 81],
            bounce_valid: false,
            bounce_stamp: Time::default(),
            bounce_position: Point::default(),
            reason: Self::REASON_VALID,
            time_variance: 0.0,
        }
    }
}

/// `ttball_msgs/msg/PredictedTrajectory`: a predicted flight sampled in time (bounces included).
///
/// All vectors have the same length; element `i` is the state at `stamps[i]`.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct PredictedTrajectory {
    /// `stamp` = time of the initial state, `frame_id` = `"table"`.
    pub header: Header,
    /// Track the prediction was made for (0 = from a given initial state).
    pub track_id: u32,
    /// Sample times [s, ns].
    pub stamps: Vec<Time>,
    /// Ball centre at each sample [m].
    pub positions: Vec<Point>,
    /// Velocity at each sample [m/s].
    pub velocities: Vec<Vector3>,
    /// Angular velocity at each sample [rad/s].
    pub spins: Vec<Vector3>,
}

/// `ttball_msgs/msg/RobotHit`: the robot's own hit, announced (estimator input): the racket's
/// state at the impact, so that the return's track starts from the predicted rebound.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct RobotHit {
    /// `stamp` = the impact time, `frame_id` = the table frame or one `/tf_static` connects to it.
    pub header: Header,
    /// Velocity of the racket's impact point at impact [m/s].
    pub racket_velocity: Vector3,
    /// Unit normal of the hitting face, pointing toward the ball.
    pub racket_normal: Vector3,
    /// Impact point from the racket's centre of gravity along its long axis, toward the tip [m].
    pub impact_offset: f64,
}
