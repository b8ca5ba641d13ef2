//! Mirror of the ROS 2 package `std_msgs` (only `Header` and `ColorRGBA`).

use std::borrow::Cow;

use serde::{Deserialize, Serialize};

use super::builtin_interfaces::Time;

/// `std_msgs/msg/Header`: stamp and coordinate frame of the data in a message.
#[derive(Debug, Clone, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct Header {
    /// Time the data refers to [s, ns]; each message says which time that is.
    pub stamp: Time,
    /// Coordinate frame of the data; the table frame (`frames.table_frame`, `"table"` by
    /// default) for every ttball output. The default is borrowed from a constant, so building a
    /// message allocates nothing (a `string` on the wire either way).
    pub frame_id: Cow<'static, str>,
}

/// `std_msgs/msg/ColorRGBA`: a colour, each channel in [0, 1].
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct ColorRGBA {
    /// Red [0, 1].
    pub r: f32,
    /// Green [0, 1].
    pub g: f32,
    /// Blue [0, 1].
    pub b: f32,
    /// Opacity [0, 1].
    pub a: f32,
}
