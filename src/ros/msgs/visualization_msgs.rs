//! Mirror of the ROS 2 package `visualization_msgs` (`Marker`, `MarkerArray` and the types they
//! hold), which RViz and Foxglove draw with no plugin. Definitions as in ROS 2 Humble and later.

use serde::{Deserialize, Serialize};

use super::builtin_interfaces::Duration;
use super::geometry_msgs::{Point, Pose, Vector3};
use super::sensor_msgs::CompressedImage;
use super::std_msgs::{ColorRGBA, Header};

/// `visualization_msgs/msg/UVCoordinate`: a texture coordinate [-].
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct UVCoordinate {
    /// u [-].
    pub u: f32,
    /// v [-].
    pub v: f32,
}

/// `visualization_msgs/msg/MeshFile`: an embedded mesh (ttball leaves it empty).
#[derive(Debug, Clone, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct MeshFile {
    /// File name, for its format.
    pub filename: String,
    /// The file's bytes.
    pub data: Vec<u8>,
}

/// `visualization_msgs/msg/Marker`: one shape to draw.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct Marker {
    /// Stamp and frame.
    pub header: Header,
    /// Namespace; with `id` it names the marker.
    pub ns: String,
    /// Id within the namespace.
    pub id: i32,
    /// Shape, one of the type constants.
    #[serde(rename = "type")]
    pub type_: i32,
    /// `ADD`, `DELETE` or `DELETEALL`.
    pub action: i32,
    /// Pose of the shape [m].
    pub pose: Pose,
    /// Size [m]; for lines, `scale.x` is the width.
    pub scale: Vector3,
    /// Colour of the whole shape.
    pub color: ColorRGBA,
    /// How long the marker lives; zero is forever.
    pub lifetime: Duration,
    /// Whether the marker moves with its frame.
    pub frame_locked: bool,
    /// Points of line strips, lists and point shapes [m].
    pub points: Vec<Point>,
    /// Per-point colours (empty: `color` for all).
    pub colors: Vec<ColorRGBA>,
    /// Texture resource (unused).
    pub texture_resource: String,
    /// Texture (unused).
    pub texture: CompressedImage,
    /// Texture coordinates (unused).
    pub uv_coordinates: Vec<UVCoordinate>,
    /// Text of a `TEXT_VIEW_FACING` marker.
    pub text: String,
    /// Mesh resource (unused).
    pub mesh_resource: String,
    /// Embedded mesh (unused).
    pub mesh_file: MeshFile,
    /// Whether a mesh uses its own materials (unused).
    pub mesh_use_embedded_materials: bool,
}

impl Marker {
    /// Shape: an arrow.
    pub const ARROW: i32 = 0;
    /// Shape: a box centred at `pose`, of sizes `scale`.
    pub const CUBE: i32 = 1;
    /// Shape: a sphere at `pose`, of diameters `scale`.
    pub const SPHERE: i32 = 2;
    /// Shape: a polyline through `points`, `scale.x` wide.
    pub const LINE_STRIP: i32 = 4;
    /// Shape: a sphere at each of `points`.
    pub const SPHERE_LIST: i32 = 7;
    /// Shape: text at `pose`.
    pub const TEXT_VIEW_FACING: i32 = 9;
    /// Action: add or modify.
    pub const ADD: i32 = 0;
    /// Action: delete this marker.
    pub const DELETE: i32 = 2;
    /// Action: delete every marker of the namespace.
    pub const DELETEALL: i32 = 3;
}

/// `visualization_msgs/msg/MarkerArray`: markers published together.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct MarkerArray {
    /// The markers.
    pub markers: Vec<Marker>,
}
