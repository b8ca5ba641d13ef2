//! Mirror of the ROS 2 package `nav_msgs` (only `Odometry`).

use std::borrow::Cow;

use serde::{Deserialize, Serialize};

use super::geometry_msgs::{PoseWithCovariance, TwistWithCovariance};
use super::std_msgs::Header;

/// `nav_msgs/msg/Odometry`: a pose and twist with their covariances, which RViz and Foxglove
/// draw natively.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Odometry {
    /// Stamp and the frame of the pose.
    pub header: Header,
    /// The frame of the twist (ttball: `ball`, axes parallel to the table's). Borrowed from a
    /// constant, so building one allocates nothing.
    pub child_frame_id: Cow<'static, str>,
    /// Position (orientation: the identity, not estimated) and its covariance.
    pub pose: PoseWithCovariance,
    /// Velocity (linear) and spin (angular) with their covariance.
    pub twist: TwistWithCovariance,
}
