//! Mirror of the ROS 2 package `std_srvs` (only `Trigger`).

use serde::{Deserialize, Serialize};

/// `std_srvs/srv/Trigger` request: no fields (ROS 2's IDL gives an empty structure this one
/// placeholder byte on the wire).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct TriggerRequest {
    /// Always 0.
    pub structure_needs_at_least_one_member: u8,
}

/// `std_srvs/srv/Trigger` response.
#[derive(Debug, Clone, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct TriggerResponse {
    /// Whether the service did it.
    pub success: bool,
    /// What it did, or why not.
    pub message: String,
}
