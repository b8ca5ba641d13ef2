//! Mirror of the ROS 2 package `diagnostic_msgs` (`DiagnosticArray`, `DiagnosticStatus`,
//! `KeyValue`), for the node's `/diagnostics` topic, which `rqt_robot_monitor` and Foxglove's
//! diagnostics panel read.

use serde::{Deserialize, Serialize};

use super::std_msgs::Header;

/// `diagnostic_msgs/msg/KeyValue`: one named value of a status.
#[derive(Debug, Clone, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct KeyValue {
    /// What the value is, with its unit in brackets.
    pub key: String,
    /// The value, as text.
    pub value: String,
}

/// `diagnostic_msgs/msg/DiagnosticStatus`: the state of one component.
#[derive(Debug, Clone, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct DiagnosticStatus {
    /// `OK`, `WARN`, `ERROR` or `STALE` (a `byte` in ROS 2: one octet).
    pub level: u8,
    /// Component name, e.g. `"ttball: estimator"`.
    pub name: String,
    /// One line on the component's state.
    pub message: String,
    /// Hardware the component runs on; empty for software.
    pub hardware_id: String,
    /// The component's values.
    pub values: Vec<KeyValue>,
}

impl DiagnosticStatus {
    /// Everything is fine.
    pub const OK: u8 = 0;
    /// Something may be wrong.
    pub const WARN: u8 = 1;
    /// Something is wrong.
    pub const ERROR: u8 = 2;
    /// No recent data.
    pub const STALE: u8 = 3;
}

/// `diagnostic_msgs/msg/DiagnosticArray`: the statuses published at one time.
#[derive(Debug, Clone, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct DiagnosticArray {
    /// Stamp = when the statuses were collected.
    pub header: Header,
    /// One status per component.
    pub status: Vec<DiagnosticStatus>,
}
