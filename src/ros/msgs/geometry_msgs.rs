//! Mirror of the ROS 2 package `geometry_msgs` (only `Point`, `Vector3`, `Quaternion`, `Pose`).

use serde::{Deserialize, Serialize};

/// `geometry_msgs/msg/Point`: a position [m].
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct Point {
    /// x coordinate [m].
    pub x: f64,
    /// y coordinate [m].
    pub y: f64,
    /// z coordinate [m].
    pub z: f64,
}

/// `geometry_msgs/msg/Vector3`: a free vector; its unit is given by the field that holds it
/// (m/s for a velocity, rad/s for a spin).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct Vector3 {
    /// x component [unit of the field holding it].
    pub x: f64,
    /// y component [unit of the field holding it].
    pub y: f64,
    /// z component [unit of the field holding it].
    pub z: f64,
}

/// `geometry_msgs/msg/Quaternion`: an orientation (x, y, z, w) [-]; the identity is w = 1.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Quaternion {
    /// x [-].
    pub x: f64,
    /// y [-].
    pub y: f64,
    /// z [-].
    pub z: f64,
    /// w [-].
    pub w: f64,
}

impl Default for Quaternion {
    /// The identity, as the ROS 2 definition's default values.
    fn default() -> Self {
        Self {
            x: 0.0,
            y: 0.0,
            z: 0.0,
            w: 1.0,
        }
    }
}

/// `geometry_msgs/msg/Pose`: a position [m] and an orientation.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct Pose {
    /// Position [m].
    pub position: Point,
    /// Orientation.
    pub orientation: Quaternion,
}

/// `geometry_msgs/msg/Transform`: the pose of a child frame in its parent.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct Transform {
    /// The child frame's origin in the parent frame [m].
    pub translation: Vector3,
    /// The child frame's orientation in the parent frame.
    pub rotation: Quaternion,
}

/// `geometry_msgs/msg/TransformStamped`: a transform from `header.frame_id` (the parent) to
/// `child_frame_id`.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct TransformStamped {
    /// Stamp and parent frame.
    pub header: super::std_msgs::Header,
    /// The child frame.
    pub child_frame_id: String,
    /// The child frame's pose in the parent.
    pub transform: Transform,
}

/// `geometry_msgs/msg/PoseWithCovariance`: a pose with the row-major 6x6 covariance of (x, y, z,
/// rotation about x, y, z).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct PoseWithCovariance {
    /// The pose.
    pub pose: Pose,
    /// Row-major 6x6 covariance [m^2, rad^2].
    #[serde(with = "serde_big_array::BigArray")]
    pub covariance: [f64; 36],
}

/// `geometry_msgs/msg/Twist`: linear and angular velocity.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct Twist {
    /// Linear velocity [m/s].
    pub linear: Vector3,
    /// Angular velocity [rad/s].
    pub angular: Vector3,
}

/// `geometry_msgs/msg/TwistWithCovariance`: a twist with the row-major 6x6 covariance of
/// (linear, angular).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct TwistWithCovariance {
    /// The twist.
    pub twist: Twist,
    /// Row-major 6x6 covariance [(m/s)^2, (rad/s)^2].
    #[serde(with = "serde_big_array::BigArray")]
    pub covariance: [f64; 36],
}
