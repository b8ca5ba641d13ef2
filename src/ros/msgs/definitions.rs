//! The ROS 2 interface definitions (`.msg` text) of every message ttball reads or writes, and the
//! `ros2msg` schema of each: its definition followed by every type it depends on, each after a
//! line of `=` and `MSG: pkg/Type`, as rosbag2 writes MCAP schemas and Foxglove reads them.
//!
//! ttball's own definitions are the files in `msgs/`; the standard ones are those of ROS 2
//! (Humble and later).

/// (name as `pkg/Type`, definition text).
const DEFINITIONS: &[(&str, &str)] = &[
    (
        "ttball_msgs/BallDetection",
        include_str!("../../../msgs/msg/BallDetection.msg"),
    ),
    (
        "ttball_msgs/BallState",
        include_str!("../../../msgs/msg/BallState.msg"),
    ),
    (
        "ttball_msgs/InterceptPrediction",
        include_str!("../../../msgs/msg/InterceptPrediction.msg"),
    ),
    (
        "ttball_msgs/PredictedTrajectory",
        include_str!("../../../msgs/msg/PredictedTrajectory.msg"),
    ),
    (
        "ttball_msgs/RobotHit",
        include_str!("../../../msgs/msg/RobotHit.msg"),
    ),
    ("builtin_interfaces/Time", "int32 sec\nuint32 nanosec\n"),
    ("builtin_interfaces/Duration", "int32 sec\nuint32 nanosec\n"),
    (
        "std_msgs/Header",
        "builtin_interfaces/Time stamp\nstring frame_id\n",
    ),
    (
        "std_msgs/ColorRGBA",
        "float32 r\nfloat32 g\nfloat32 b\nfloat32 a\n",
    ),
    ("geometry_msgs/Point", "float64 x\nfloat64 y\nfloat64 z\n"),
    ("geometry_msgs/Vector3", "float64 x\nfloat64 y\nfloat64 z\n"),
    (
        "geometry_msgs/Quaternion",
        "float64 x 0\nfloat64 y 0\nfloat64 z 0\nfloat64 w 1\n",
    ),
    (
        "geometry_msgs/Pose",
        "Point position\nQuaternion orientation\n",
    ),
    (
        "geometry_msgs/PoseWithCovariance",
        "Pose pose\nfloat64[36] covariance\n",
    ),
    ("geometry_msgs/Twist", "Vector3 linear\nVector3 angular\n"),
    (
        "geometry_msgs/TwistWithCovariance",
        "Twist twist\nfloat64[36] covariance\n",
    ),
    (
        "nav_msgs/Odometry",
        "std_msgs/Header header\nstring child_frame_id\ngeometry_msgs/PoseWithCovariance pose\ngeometry_msgs/TwistWithCovariance twist\n",
    ),
    (
        "sensor_msgs/CompressedImage",
        "std_msgs/Header header\nstring format\nuint8[] data\n",
    ),
    ("visualization_msgs/UVCoordinate", "float32 u\nfloat32 v\n"),
    (
        "visualization_msgs/MeshFile",
        "string filename\nuint8[] data\n",
    ),
    ("visualization_msgs/Marker", MARKER),
    ("visualization_msgs/MarkerArray", "Marker[] markers\n"),
    ("diagnostic_msgs/KeyValue", "string key\nstring value\n"),
    ("diagnostic_msgs/DiagnosticStatus", DIAGNOSTIC_STATUS),
    (
        "diagnostic_msgs/DiagnosticArray",
        "std_msgs/Header header\nDiagnosticStatus[] status\n",
    ),
];

const DIAGNOSTIC_STATUS: &str = "\
byte OK=0
byte WARN=1
byte ERROR=2
byte STALE=3
byte level
string name
string message
string hardware_id
KeyValue[] values
";

const MARKER: &str = "\
int32 ARROW=0
int32 CUBE=1
int32 SPHERE=2
int32 CYLINDER=3
int32 LINE_STRIP=4
int32 LINE_LIST=5
int32 CUBE_LIST=6
int32 SPHERE_LIST=7
int32 POINTS=8
int32 TEXT_VIEW_FACING=9
int32 MESH_RESOURCE=10
int32 TRIANGLE_LIST=11
int32 ADD=0
int32 MODIFY=0
int32 DELETE=2
int32 DELETEALL=3
std_msgs/Header header
string ns
int32 id
int32 type
int32 action
geometry_msgs/Pose pose
geometry_msgs/Vector3 scale
std_msgs/ColorRGBA color
builtin_interfaces/Duration lifetime
bool frame_locked
geometry_msgs/Point[] points
std_msgs/ColorRGBA[] colors
string texture_resource
sensor_msgs/CompressedImage texture
UVCoordinate[] uv_coordinates
string text
string mesh_resource
MeshFile mesh_file
bool mesh_use_embedded_materials
";

const PRIMITIVES: &[&str] = &[
    "bool", "byte", "char", "float32", "float64", "int8", "uint8", "int16", "uint16", "int32",
    "uint32", "int64", "uint64", "string", "wstring",
];

/// `pkg/msg/Type` or `pkg/Type` -> `pkg/Type`.
fn short_name(name: &str) -> String {
    let parts: Vec<&str> = name.split('/').collect();
    match parts.as_slice() {
        [package, "msg", ty] => format!("{package}/{ty}"),
        _ => name.to_string(),
    }
}

/// The definition text of a message type (`pkg/msg/Type` or `pkg/Type`).
pub fn definition(name: &str) -> Option<&'static str> {
    let key = short_name(name);
    DEFINITIONS
        .iter()
        .find(|(n, _)| *n == key)
        .map(|(_, text)| *text)
}

/// The fields `(type, name)` of a definition, or of a `ros2msg` schema's own message (the text
/// before its first `====` separator), without comments, constants or default values.
pub fn fields(text: &str) -> Vec<(String, String)> {
    text.lines()
        .take_while(|line| !line.starts_with("=="))
        .filter_map(|line| {
            let line = line.split('#').next().unwrap_or("");
            let mut words = line.split_whitespace();
            let (ty, name) = (words.next()?, words.next()?);
            // A constant: `TYPE NAME=value` or `TYPE NAME = value`.
            if name.contains('=') || words.next().is_some_and(|w| w.starts_with('=')) {
                return None;
            }
            Some((ty.to_string(), name.to_string()))
        })
        .collect()
}

/// The message types a definition's fields use, as `pkg/Type`, in order of appearance.
fn field_types(package: &str, text: &str) -> Vec<String> {
    let mut out = Vec::new();
    for (ty, _) in fields(text) {
        let ty = ty.as_str();
        let base = ty.split('[').next().unwrap_or(ty);
        let base = base.split("<=").next().unwrap_or(base);
        if PRIMITIVES.contains(&base) {
            continue;
        }
        let full = if base.contains('/') {
            short_name(base)
        } else {
            format!("{package}/{base}")
        };
        if !out.contains(&full) {
            out.push(full);
        }
    }
    out
}

/// The `ros2msg` schema of a message type: its definition, then each dependency (depth first,
/// each once) after a separator line and `MSG: pkg/Type`. `None` for an unknown type.
pub fn schema(name: &str) -> Option<String> {
    let root = short_name(name);
    schema_of(&root, definition(&root)?)
}

/// The services whose requests and responses are offered as `ros2msg` schemas (the Foxglove
/// live view's services), as (`pkg/Service`, `.srv` text).
const SERVICES: &[(&str, &str)] = &[
    (
        "ttball_msgs/PredictTrajectory",
        include_str!("../../../msgs/srv/PredictTrajectory.srv"),
    ),
    (
        "ttball_msgs/PredictRebound",
        include_str!("../../../msgs/srv/PredictRebound.srv"),
    ),
    (
        "ttball_msgs/PlanReturn",
        include_str!("../../../msgs/srv/PlanReturn.srv"),
    ),
];

/// The `ros2msg` schemas of a service's request and response (`pkg/srv/Service`): each half of
/// its `.srv` text, then the types it uses, as [`schema`] writes a message's. `None` for a
/// service other than ttball's three.
pub fn service_schemas(name: &str) -> Option<(String, String)> {
    let (package, service) = name.split_once("/srv/")?;
    let key = format!("{package}/{service}");
    let text = SERVICES.iter().find(|(n, _)| *n == key)?.1;
    let (request, response) = text.split_once("\n---\n")?;
    Some((
        schema_of(&format!("{key}_Request"), request)?,
        schema_of(&format!("{key}_Response"), response)?,
    ))
}

/// The schema of the type `root` defined by `own` (see [`schema`]).
fn schema_of(root: &str, own: &str) -> Option<String> {
    let mut text = own.to_string();
    let mut seen = vec![root.to_owned()];
    let mut stack: Vec<String> = field_types(package_of(root), own);
    stack.reverse();
    while let Some(dep) = stack.pop() {
        if seen.contains(&dep) {
            continue;
        }
        let body = definition(&dep)?;
        if !text.ends_with('\n') {
            text.push('\n');
        }
        text.push_str(&"=".repeat(80));
        text.push_str("\nMSG: ");
        text.push_str(&dep);
        text.push('\n');
        text.push_str(body);
        let mut children = field_types(package_of(&dep), body);
        children.reverse();
        stack.extend(children);
        seen.push(dep);
    }
    Some(text)
}

fn package_of(name: &str) -> &str {
    name.split('/').next().unwrap_or(name)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fields_skip_comments_constants_and_dependencies() {
        let text = "uint8 A=1 # constant\nint32 B = 2\nstd_msgs/Header header # stamp\n\
                    string<=8 name\nfloat64[9] c 0\n====\nMSG: x/Y\nint32 hidden\n";
        let f = fields(text);
        let names: Vec<&str> = f.iter().map(|(_, n)| n.as_str()).collect();
        assert_eq!(names, ["header", "name", "c"]);
        assert_eq!(f[1].0, "string<=8");
        let ours = schema("ttball_msgs/msg/BallDetection").expect("known");
        assert_eq!(fields(&ours).len(), 8);
    }

    #[test]
    fn schemas_embed_every_dependency_once() {
        let s = schema("ttball_msgs/msg/BallDetection").expect("known");
        assert!(s.starts_with(definition("ttball_msgs/BallDetection").expect("known")));
        for dep in [
            "std_msgs/Header",
            "builtin_interfaces/Time",
            "geometry_msgs/Point",
            "geometry_msgs/Vector3",
        ] {
            assert_eq!(
                s.matches(&format!("MSG: {dep}\n")).count(),
                1,
                "{dep} in {s}"
            );
        }
        let markers = schema("visualization_msgs/msg/MarkerArray").expect("known");
        for dep in [
            "visualization_msgs/Marker",
            "geometry_msgs/Pose",
            "geometry_msgs/Quaternion",
            "visualization_msgs/UVCoordinate",
            "visualization_msgs/MeshFile",
            "sensor_msgs/CompressedImage",
            "builtin_interfaces/Duration",
        ] {
            assert_eq!(
                markers.matches(&format!("MSG: {dep}\n")).count(),
                1,
                "{dep}"
            );
        }
        assert!(schema("nope/msg/Nothing").is_none());
    }
}
