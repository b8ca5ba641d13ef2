//! Mirror of the ROS 2 package `geometry_msgs` (only `Point` and `Vector3`).

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
