//! Services of `ttball_msgs` (`msgs/srv/*.srv`): one request and one response struct each, field
//! for field in the same order.
//!
//! All quantities are in the `table` frame, SI units.

use serde::{Deserialize, Serialize};

use super::msg::{BallState, PredictedTrajectory};
use crate::ros::msgs::builtin_interfaces::Time;
use crate::ros::msgs::geometry_msgs::{Point, Vector3};

/// Request of `ttball_msgs/srv/PredictTrajectory`: predict the flight of a tracked ball, or of a
/// given initial state, over a horizon.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct PredictTrajectoryRequest {
    /// Track to predict from; 0 = use `initial`.
    pub track_id: u32,
    /// Initial state, used only when `track_id` is 0.
    pub initial: BallState,
    /// How far ahead to predict [s].
    pub horizon: f64,
    /// Sample interval of the returned trajectory [s].
    pub dt: f64,
}

/// Response of `ttball_msgs/srv/PredictTrajectory`.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct PredictTrajectoryResponse {
    /// True when `trajectory` holds a prediction.
    pub success: bool,
    /// Why not, when `success` is false; empty otherwise.
    pub message: String,
    /// The predicted flight, sampled every `dt` up to `horizon`.
    pub trajectory: PredictedTrajectory,
}

/// Request of `ttball_msgs/srv/PredictRebound`: predict the ball's rebound from the racket for a
/// planned stroke.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct PredictReboundRequest {
    /// Ball centre at impact [m].
    pub ball_position: Point,
    /// Ball velocity just before impact [m/s].
    pub ball_velocity: Vector3,
    /// Ball angular velocity just before impact [rad/s].
    pub ball_spin: Vector3,
    /// Velocity of the racket's impact point [m/s].
    pub racket_velocity: Vector3,
    /// Unit normal of the hitting face, pointing toward the ball (dimensionless).
    pub racket_normal: Vector3,
    /// Impact point distance from the racket's centre of gravity along its long axis [m].
    pub impact_offset: f64,
}

/// Response of `ttball_msgs/srv/PredictRebound`.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct PredictReboundResponse {
    /// True when the other fields hold a prediction.
    pub success: bool,
    /// Why not, when `success` is false; empty otherwise.
    pub message: String,
    /// Ball velocity just after impact [m/s].
    pub ball_velocity: Vector3,
    /// Ball angular velocity just after impact [rad/s].
    pub ball_spin: Vector3,
    /// Normal rebound ratio of ball and racket at the impact point (dimensionless).
    pub rebound_power_coefficient: f64,
    /// Ball-racket contact time [s].
    pub contact_time: f64,
    /// Mean normal contact force [N].
    pub mean_force: f64,
    /// Peak normal contact force (half-sine pulse) [N].
    pub peak_force: f64,
    /// Reduced mass of the racket at the impact point [kg].
    pub reduced_mass: f64,
    /// Peak force transmitted to the grip / robot wrist [N].
    pub wrist_force: f64,
    /// True when the returned ball lands on the opponent's half.
    pub lands_on_table: bool,
    /// Ball centre at that landing [m]; valid only when `lands_on_table`.
    pub landing_position: Point,
}

/// Request of `ttball_msgs/srv/PlanReturn`: plan the racket command that returns the ball to a
/// target on the opponent's half. The racket moves along its face normal, plus an optional
/// brushing speed along the face.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct PlanReturnRequest {
    /// Plan against this track's predicted interception (as on `/ball/intercept`); 0 = use
    /// `ball`.
    pub track_id: u32,
    /// Ball state just before impact, used only when `track_id` is 0.
    pub ball: BallState,
    /// Landing point of the ball centre on the opponent's half [m]; z is ignored.
    pub target: Point,
    /// Time from impact to landing [s]; 0 = not constrained (`net_clearance` is used).
    pub flight_time: f64,
    /// Height of the ball's bottom over the net top at the net [m], used when `flight_time` is 0;
    /// 0 = the configured `stroke.net_clearance`.
    pub net_clearance: f64,
    /// Impact point from the racket's centre of gravity along its long axis, toward the tip [m].
    pub impact_offset: f64,
    /// Racket speed along the face, upward in its plane (> 0 topspin, < 0 backspin) [m/s]; 0 =
    /// along the normal only.
    pub brush_speed: f64,
}

/// Response of `ttball_msgs/srv/PlanReturn`.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct PlanReturnResponse {
    /// True when the other fields hold a command.
    pub success: bool,
    /// Why not (unreachable target, bad request), when `success` is false; empty otherwise.
    pub message: String,
    /// When racket and ball meet (the interception's stamp, or `ball.header.stamp`) [s, ns].
    pub impact_stamp: Time,
    /// Ball centre at impact [m].
    pub impact_position: Point,
    /// Velocity of the racket's impact point at impact [m/s].
    pub racket_velocity: Vector3,
    /// Unit normal of the hitting face, pointing toward the ball (dimensionless).
    pub racket_normal: Vector3,
    /// Ball velocity just after impact [m/s].
    pub ball_velocity: Vector3,
    /// Ball angular velocity just after impact [rad/s].
    pub ball_spin: Vector3,
    /// Ball centre at the predicted landing on the opponent's half [m].
    pub landing_position: Point,
    /// Time from impact to that landing [s].
    pub flight_time: f64,
    /// Height of the ball's bottom over the net top at the net [m].
    pub net_clearance: f64,
    /// Distance from the predicted landing to the target [m].
    pub landing_error: f64,
    /// Row-major 3x3 over (landing x [m], landing y [m], flight time [s]): the interception's
    /// (or the given ball's) covariance through the hit and the flight, first order; zero when
    /// that covariance is zero.
    pub landing_covariance: [f64; 9],
    /// Ball-racket contact time [s].
    pub contact_time: f64,
    /// Peak normal contact force (half-sine pulse) [N].
    pub peak_force: f64,
    /// Peak force transmitted to the grip / robot wrist [N].
    pub wrist_force: f64,
}
