//! Mirror of the ROS 2 package `std_msgs` (only `Header`).

use serde::{Deserialize, Serialize};

use super::builtin_interfaces::Time;

/// `std_msgs/msg/Header`: stamp and coordinate frame of the data in a message.
#[derive(Debug, Clone, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct Header {
    /// Time the data refers to [s, ns]; each message says which time that is.
    pub stamp: Time,
    /// Coordinate frame of the data; `"table"` for every ttball message.
    pub frame_id: String,
}
