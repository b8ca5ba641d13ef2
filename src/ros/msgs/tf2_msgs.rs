//! Mirror of the ROS 2 package `tf2_msgs` (only `TFMessage`, the type of `/tf` and `/tf_static`).

use serde::{Deserialize, Serialize};

use super::geometry_msgs::TransformStamped;

/// `tf2_msgs/msg/TFMessage`: transforms between coordinate frames.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct TFMessage {
    /// The transforms.
    pub transforms: Vec<TransformStamped>,
}
