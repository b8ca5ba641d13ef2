//! Mirror of the ROS 2 package `sensor_msgs` (only `CompressedImage`, a field of `Marker`).

use serde::{Deserialize, Serialize};

use super::std_msgs::Header;

/// `sensor_msgs/msg/CompressedImage`: an encoded image (ttball leaves it empty).
#[derive(Debug, Clone, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct CompressedImage {
    /// Stamp and frame of the image.
    pub header: Header,
    /// Encoding, e.g. `"png"`.
    pub format: String,
    /// The encoded bytes.
    pub data: Vec<u8>,
}
