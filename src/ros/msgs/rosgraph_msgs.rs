//! Mirror of the ROS 2 package `rosgraph_msgs` (only `Clock`).

use serde::{Deserialize, Serialize};

use super::builtin_interfaces::Time;

/// `rosgraph_msgs/msg/Clock`: the simulated time on `/clock`, which nodes with `use_sim_time`
/// follow.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct Clock {
    /// The current time.
    pub clock: Time,
}
