//! Every ROS 2 type name ttball publishes, subscribes, records or serves, spelled once: the
//! replay, the recorder, the node and the command-line tool all take them from here.

/// ROS 2 type of the robot's announced hits (`topics.robot_hits`).
pub const ROBOT_HIT_TYPE: &str = "ttball_msgs/msg/RobotHit";
/// ROS 2 type of `/tf_static`.
pub const TF_MESSAGE_TYPE: &str = "tf2_msgs/msg/TFMessage";
/// The type of the optional odometry output (`topics.odometry`).
pub const ODOMETRY_TYPE: &str = "nav_msgs/msg/Odometry";
/// The type of the detection topic.
pub const DETECTION_TYPE: &str = "ttball_msgs/msg/BallDetection";
/// The type of `/ball/state` and `/ball/truth`.
pub const STATE_TYPE: &str = "ttball_msgs/msg/BallState";
/// The type of `/ball/intercept` and `/ball/truth/intercept`.
pub const INTERCEPT_TYPE: &str = "ttball_msgs/msg/InterceptPrediction";
/// The type of `/ball/trajectory`.
pub const TRAJECTORY_TYPE: &str = "ttball_msgs/msg/PredictedTrajectory";
/// The type of `/ball/markers`.
pub const MARKERS_TYPE: &str = "visualization_msgs/msg/MarkerArray";
/// ROS 2 type of `/diagnostics`.
pub const DIAGNOSTICS_TYPE: &str = "diagnostic_msgs/msg/DiagnosticArray";
/// ROS 2 type of the `~/predict_trajectory` service.
pub const PREDICT_TRAJECTORY_TYPE: &str = "ttball_msgs/srv/PredictTrajectory";
/// ROS 2 type of the `~/predict_rebound` service.
pub const PREDICT_REBOUND_TYPE: &str = "ttball_msgs/srv/PredictRebound";
/// ROS 2 type of the `~/plan_return` service.
pub const PLAN_RETURN_TYPE: &str = "ttball_msgs/srv/PlanReturn";
/// ROS 2 type of `/clock`.
pub const CLOCK_TYPE: &str = "rosgraph_msgs/msg/Clock";
