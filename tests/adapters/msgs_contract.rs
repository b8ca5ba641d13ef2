//! Contract between the ROS 2 interface files in `msgs/` and their serde mirrors in
//! `ttball::ros::msgs`.
//!
//! The test parses every `msgs/msg/*.msg` and `msgs/srv/*.srv` with a small parser for the ROS 2
//! interface grammar, and gets the structure of the Rust side from the types' own serde
//! implementations with `serde-reflection` (tracing through `Deserialize`, so the element type of
//! an empty `Vec` is seen too). No field list is written twice: a field renamed, retyped or moved
//! on either side fails the test. Nested types are followed down to the standard definitions of
//! `std_msgs/Header`, `builtin_interfaces/Time`, `geometry_msgs/Point` and `geometry_msgs/Vector3`.
//! A golden-bytes test pins the CDR encoding that ros2-client uses (`cdr-encoding`).

#![cfg(feature = "interface")]
// clippy.toml allows these in #[test] functions only; the helpers here are test code too.
#![allow(clippy::unwrap_used, clippy::panic, reason = "test code: fail loudly")]

use std::collections::{BTreeMap, BTreeSet};
use std::fs;
use std::path::{Path, PathBuf};

use byteorder::LittleEndian;
use serde::Deserialize;
use serde_reflection::{ContainerFormat, Format, Registry, Tracer, TracerConfig};
use ttball::ros::msgs::builtin_interfaces::Time;
use ttball::ros::msgs::geometry_msgs::{Point, Vector3};
use ttball::ros::msgs::std_msgs::Header;
use ttball::ros::msgs::ttball_msgs::msg::{
    BallDetection, BallState, InterceptPrediction, PredictedTrajectory, RobotHit,
};
use ttball::ros::msgs::ttball_msgs::srv::{
    PlanReturnRequest, PlanReturnResponse, PredictReboundRequest, PredictReboundResponse,
    PredictTrajectoryRequest, PredictTrajectoryResponse,
};

// ---------------------------------------------------------------------------------------------
// A parser for the ROS 2 interface grammar (rosidl_adapter's `.msg` / `.srv` format)
// ---------------------------------------------------------------------------------------------

/// The ROS 2 primitive types that may appear in a field or constant.
const PRIMITIVES: &[&str] = &[
    "bool", "byte", "char", "float32", "float64", "int8", "uint8", "int16", "uint16", "int32",
    "uint32", "int64", "uint64", "string", "wstring",
];

/// The base type of a field, without array suffix.
#[derive(Debug, Clone, PartialEq)]
enum BaseType {
    /// A primitive type such as `float64`; `string<=N` and `wstring<=N` carry their bound.
    Primitive { name: String, bound: Option<usize> },
    /// A message type, with its package resolved (`Type` means the current package).
    Message { package: String, name: String },
}

/// The array suffix of a field type.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Array {
    /// No suffix.
    Single,
    /// `[N]`.
    Fixed(usize),
    /// `[]`.
    Unbounded,
    /// `[<=N]`.
    Bounded(usize),
}

#[derive(Debug, Clone, PartialEq)]
struct FieldType {
    base: BaseType,
    array: Array,
}

#[derive(Debug, Clone, PartialEq)]
struct Field {
    ty: FieldType,
    name: String,
    default: Option<String>,
    /// The comment on the field's own line, if any.
    comment: Option<String>,
}

#[derive(Debug, Clone, PartialEq)]
struct Constant {
    ty: String,
    name: String,
    value: String,
    comment: Option<String>,
}

/// One message, or one half of a service, as written in its interface file.
#[derive(Debug, Clone, PartialEq)]
struct MsgSpec {
    package: String,
    name: String,
    constants: Vec<Constant>,
    fields: Vec<Field>,
}

impl MsgSpec {
    fn full_name(&self) -> String {
        format!("{}/{}", self.package, self.name)
    }
}

/// `^(?!.*__)(?!.*_$)[a-z][a-z0-9_]*$`: ROS 2 field and package names.
fn is_snake_name(s: &str) -> bool {
    s.starts_with(|c: char| c.is_ascii_lowercase())
        && s.chars()
            .all(|c| c.is_ascii_lowercase() || c.is_ascii_digit() || c == '_')
        && !s.contains("__")
        && !s.ends_with('_')
}

/// `^[A-Z]([A-Z0-9_]?[A-Z0-9]+)*$`: ROS 2 constant names.
fn is_constant_name(s: &str) -> bool {
    s.starts_with(|c: char| c.is_ascii_uppercase())
        && s.chars()
            .all(|c| c.is_ascii_uppercase() || c.is_ascii_digit() || c == '_')
        && !s.contains("__")
        && !s.ends_with('_')
}

/// `^[A-Z][A-Za-z0-9]*$`: ROS 2 message type names.
fn is_type_name(s: &str) -> bool {
    s.starts_with(|c: char| c.is_ascii_uppercase()) && s.chars().all(|c| c.is_ascii_alphanumeric())
}

fn parse_usize(s: &str, line: &str) -> Result<usize, String> {
    s.trim()
        .parse()
        .map_err(|_| format!("bad size {s:?} in {line:?}"))
}

/// Parses a type such as `float64[9]`, `string<=8`, `geometry_msgs/Point[]`, `Foo[<=3]`.
fn parse_type(s: &str, package: &str) -> Result<FieldType, String> {
    let (base, array) = match s.strip_suffix(']') {
        Some(rest) => {
            let (base, size) = rest
                .split_once('[')
                .ok_or_else(|| format!("unbalanced brackets in type {s:?}"))?;
            let array = if size.is_empty() {
                Array::Unbounded
            } else if let Some(n) = size.strip_prefix("<=") {
                Array::Bounded(parse_usize(n, s)?)
            } else {
                Array::Fixed(parse_usize(size, s)?)
            };
            (base, array)
        }
        None => (s, Array::Single),
    };
    if base.contains(['[', ']']) {
        return Err(format!("bad array suffix in type {s:?}"));
    }
    let (name, bound) = match base.split_once("<=") {
        Some((name, n)) if name == "string" || name == "wstring" => {
            (name, Some(parse_usize(n, s)?))
        }
        Some(_) => return Err(format!("only strings can be bounded: {s:?}")),
        None => (base, None),
    };
    let base = if PRIMITIVES.contains(&name) {
        BaseType::Primitive {
            name: name.to_owned(),
            bound,
        }
    } else {
        let parts: Vec<&str> = name.split('/').collect();
        let (pkg, ty) = match parts.as_slice() {
            [ty] => (package, *ty),
            [pkg, ty] => (*pkg, *ty),
            [pkg, "msg", ty] => (*pkg, *ty),
            _ => return Err(format!("bad type name {name:?}")),
        };
        if !is_snake_name(pkg) || !is_type_name(ty) {
            return Err(format!("bad type name {name:?}"));
        }
        BaseType::Message {
            package: pkg.to_owned(),
            name: ty.to_owned(),
        }
    };
    Ok(FieldType { base, array })
}

/// Splits a line at its comment: the first `#` outside a quoted string.
fn split_comment(line: &str) -> (&str, Option<&str>) {
    let mut quote = None;
    for (i, c) in line.char_indices() {
        match (c, quote) {
            ('"' | '\'', None) => quote = Some(c),
            (c, Some(q)) if c == q => quote = None,
            ('#', None) => return (&line[..i], Some(line[i + 1..].trim())),
            _ => {}
        }
    }
    (line, None)
}

/// Parses the text of a `.msg` file (or one half of a `.srv`).
///
/// Follows `rosidl_adapter.parser.parse_message_string`: a line is `type name [default]` or, when
/// the rest of the line after the type contains `=`, a constant `type NAME=value`.
fn parse_msg(package: &str, name: &str, text: &str) -> Result<MsgSpec, String> {
    let mut spec = MsgSpec {
        package: package.to_owned(),
        name: name.to_owned(),
        constants: Vec::new(),
        fields: Vec::new(),
    };
    for (number, raw) in text.lines().enumerate() {
        let raw = raw.replace('\t', " ");
        let (line, comment) = split_comment(&raw);
        let line = line.trim();
        if line.is_empty() {
            continue;
        }
        let comment = comment.filter(|c| !c.is_empty()).map(str::to_owned);
        let at = |e: String| format!("{package}/{name} line {}: {e}", number + 1);
        let (ty, rest) = line
            .split_once(' ')
            .ok_or_else(|| at(format!("expected `type name`, got {line:?}")))?;
        let rest = rest.trim();
        if let Some((cname, value)) = rest.split_once('=') {
            let (cname, value) = (cname.trim(), value.trim());
            if !PRIMITIVES.contains(&ty) {
                return Err(at(format!("constant {cname} of non-primitive type {ty}")));
            }
            if !is_constant_name(cname) || value.is_empty() {
                return Err(at(format!("bad constant {line:?}")));
            }
            if spec.constants.iter().any(|c| c.name == cname) {
                return Err(at(format!("duplicate constant {cname}")));
            }
            spec.constants.push(Constant {
                ty: ty.to_owned(),
                name: cname.to_owned(),
                value: value.to_owned(),
                comment,
            });
        } else {
            let (fname, default) = match rest.split_once(' ') {
                Some((fname, default)) => (fname, Some(default.trim().to_owned())),
                None => (rest, None),
            };
            if !is_snake_name(fname) {
                return Err(at(format!("bad field name {fname:?}")));
            }
            if spec.fields.iter().any(|f| f.name == fname) {
                return Err(at(format!("duplicate field {fname}")));
            }
            spec.fields.push(Field {
                ty: parse_type(ty, package).map_err(at)?,
                name: fname.to_owned(),
                default,
                comment,
            });
        }
    }
    Ok(spec)
}

/// Parses the text of a `.srv` file into `NameRequest` and `NameResponse`.
fn parse_srv(package: &str, name: &str, text: &str) -> Result<(MsgSpec, MsgSpec), String> {
    let lines: Vec<&str> = text.lines().collect();
    let separators: Vec<usize> = (0..lines.len())
        .filter(|&i| lines[i].trim() == "---")
        .collect();
    let [sep] = separators.as_slice() else {
        return Err(format!(
            "{package}/{name}: expected one `---` separator, found {}",
            separators.len()
        ));
    };
    let request = parse_msg(
        package,
        &format!("{name}Request"),
        &lines[..*sep].join("\n"),
    )?;
    let response = parse_msg(
        package,
        &format!("{name}Response"),
        &lines[sep + 1..].join("\n"),
    )?;
    Ok((request, response))
}

// ---------------------------------------------------------------------------------------------
// The interface definitions: msgs/ plus the standard types they use
// ---------------------------------------------------------------------------------------------

/// The standard ROS 2 types `msgs/` uses, as (package, type): their definitions are read from
/// `tests/interop/rosidl/standard/`, the files the Fast DDS peer's IDL is made from too.
const STANDARD: &[(&str, &str)] = &[
    ("builtin_interfaces", "Time"),
    ("std_msgs", "Header"),
    ("geometry_msgs", "Point"),
    ("geometry_msgs", "Vector3"),
];

const PACKAGE: &str = "ttball_msgs";

fn msgs_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("msgs")
}

/// The files of `msgs/<sub>/` ending in `.<ext>`, sorted, as (type name, path).
fn interface_files(sub: &str, ext: &str) -> Vec<(String, PathBuf)> {
    let mut files: Vec<(String, PathBuf)> = fs::read_dir(msgs_dir().join(sub))
        .unwrap()
        .map(|entry| entry.unwrap().path())
        .filter(|path| path.extension().is_some_and(|e| e == ext))
        .map(|path| {
            let stem = path.file_stem().unwrap().to_str().unwrap().to_owned();
            (stem, path)
        })
        .collect();
    files.sort();
    files
}

/// Every message and service half of `msgs/`, in file order.
fn package_specs() -> Vec<MsgSpec> {
    let mut specs = Vec::new();
    for (name, path) in interface_files("msg", "msg") {
        specs.push(parse_msg(PACKAGE, &name, &fs::read_to_string(&path).unwrap()).unwrap());
    }
    for (name, path) in interface_files("srv", "srv") {
        let (request, response) =
            parse_srv(PACKAGE, &name, &fs::read_to_string(&path).unwrap()).unwrap();
        specs.push(request);
        specs.push(response);
    }
    assert!(!specs.is_empty(), "no interface files found in msgs/");
    specs
}

/// All definitions by full name (`pkg/Type`): `specs` plus the standard ones.
fn definitions(specs: &[MsgSpec]) -> BTreeMap<String, MsgSpec> {
    let standard = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/interop/rosidl/standard");
    let mut defs: BTreeMap<String, MsgSpec> = STANDARD
        .iter()
        .map(|(pkg, name)| {
            let path = standard.join(pkg).join("msg").join(format!("{name}.msg"));
            let spec = parse_msg(pkg, name, &fs::read_to_string(path).unwrap()).unwrap();
            (spec.full_name(), spec)
        })
        .collect();
    for spec in specs {
        defs.insert(spec.full_name(), spec.clone());
    }
    defs
}

// ---------------------------------------------------------------------------------------------
// The Rust side, from serde
// ---------------------------------------------------------------------------------------------

/// Traces `T` through its `Deserialize` impl and returns the serde name of its container.
fn trace<'de, T: Deserialize<'de>>(tracer: &mut Tracer) -> String {
    match tracer.trace_simple_type::<T>().unwrap().0 {
        Format::TypeName(name) => name,
        other => panic!(
            "{} is not a named container: {other:?}",
            std::any::type_name::<T>()
        ),
    }
}

/// The mirror of every interface in `msgs/`, keyed by the ROS name (`ttball_msgs/BallDetection`,
/// `ttball_msgs/PredictTrajectoryRequest`), with the serde registry of all types reached.
///
/// This is a list of types, not of fields: adding an interface file means adding a line here.
fn rust_mirrors() -> (BTreeMap<String, String>, Registry) {
    let mut tracer = Tracer::new(TracerConfig::default());
    let mut top = BTreeMap::new();
    let mut add = |ros: &str, rust: String| {
        top.insert(format!("{PACKAGE}/{ros}"), rust);
    };
    add("BallDetection", trace::<BallDetection>(&mut tracer));
    add("BallState", trace::<BallState>(&mut tracer));
    add(
        "InterceptPrediction",
        trace::<InterceptPrediction>(&mut tracer),
    );
    add(
        "PredictedTrajectory",
        trace::<PredictedTrajectory>(&mut tracer),
    );
    add("RobotHit", trace::<RobotHit>(&mut tracer));
    add(
        "PredictTrajectoryRequest",
        trace::<PredictTrajectoryRequest>(&mut tracer),
    );
    add(
        "PredictTrajectoryResponse",
        trace::<PredictTrajectoryResponse>(&mut tracer),
    );
    add(
        "PredictReboundRequest",
        trace::<PredictReboundRequest>(&mut tracer),
    );
    add(
        "PredictReboundResponse",
        trace::<PredictReboundResponse>(&mut tracer),
    );
    add("PlanReturnRequest", trace::<PlanReturnRequest>(&mut tracer));
    add(
        "PlanReturnResponse",
        trace::<PlanReturnResponse>(&mut tracer),
    );
    (top, tracer.registry().unwrap())
}

// ---------------------------------------------------------------------------------------------
// The comparison
// ---------------------------------------------------------------------------------------------

/// The serde format a ROS 2 primitive has in the mirrors (`char` is an octet in ROS 2: `u8`).
fn primitive_format(name: &str) -> Option<Format> {
    Some(match name {
        "bool" => Format::Bool,
        "byte" | "char" | "uint8" => Format::U8,
        "int8" => Format::I8,
        "int16" => Format::I16,
        "uint16" => Format::U16,
        "int32" => Format::I32,
        "uint32" => Format::U32,
        "int64" => Format::I64,
        "uint64" => Format::U64,
        "float32" => Format::F32,
        "float64" => Format::F64,
        "string" | "wstring" => Format::Str,
        _ => return None,
    })
}

/// Compares ROS definitions with a serde registry, recursively; collects every mismatch.
struct Checker<'a> {
    defs: &'a BTreeMap<String, MsgSpec>,
    registry: &'a Registry,
    /// (ROS, Rust) pairs already checked, so that a nested type is reported once.
    checked: BTreeSet<(String, String)>,
    errors: Vec<String>,
}

impl<'a> Checker<'a> {
    fn new(defs: &'a BTreeMap<String, MsgSpec>, registry: &'a Registry) -> Self {
        Checker {
            defs,
            registry,
            checked: BTreeSet::new(),
            errors: Vec::new(),
        }
    }

    /// Checks that the serde container `rust` has the fields of the ROS type `ros` (`pkg/Type`).
    fn check_struct(&mut self, ros: &str, rust: &str) {
        if !self.checked.insert((ros.to_owned(), rust.to_owned())) {
            return;
        }
        let Some(spec) = self.defs.get(ros) else {
            self.errors.push(format!("no definition of {ros}"));
            return;
        };
        let Some(container) = self.registry.get(rust) else {
            self.errors
                .push(format!("{ros}: no Rust type named {rust} was traced"));
            return;
        };
        let ContainerFormat::Struct(rust_fields) = container else {
            self.errors
                .push(format!("{ros}: Rust {rust} is not a struct: {container:?}"));
            return;
        };
        let ros_names: Vec<&str> = spec.fields.iter().map(|f| f.name.as_str()).collect();
        let rust_names: Vec<&str> = rust_fields.iter().map(|f| f.name.as_str()).collect();
        if ros_names != rust_names {
            self.errors.push(format!(
                "{ros}: field names or order differ\n  ROS:  {ros_names:?}\n  Rust: {rust_names:?}"
            ));
            return;
        }
        for (field, rust_field) in spec.fields.iter().zip(rust_fields) {
            let at = format!("{ros}.{}", field.name);
            self.check_field(&at, &field.ty, &rust_field.value);
        }
    }

    fn check_field(&mut self, at: &str, ty: &FieldType, rust: &Format) {
        match (ty.array, rust) {
            (Array::Single, _) => self.check_base(at, &ty.base, rust),
            (Array::Fixed(n), Format::TupleArray { content, size }) if *size == n => {
                self.check_base(at, &ty.base, content);
            }
            (Array::Fixed(n), Format::Tuple(items)) if items.len() == n => {
                for item in items {
                    self.check_base(at, &ty.base, item);
                }
            }
            (Array::Unbounded | Array::Bounded(_), Format::Seq(content)) => {
                self.check_base(at, &ty.base, content);
            }
            (array, _) => self.errors.push(format!(
                "{at}: ROS {array:?} of {:?}, Rust {rust:?}",
                ty.base
            )),
        }
    }

    fn check_base(&mut self, at: &str, base: &BaseType, rust: &Format) {
        match base {
            BaseType::Primitive { name, .. } => {
                if primitive_format(name).as_ref() != Some(rust) {
                    self.errors.push(format!("{at}: ROS {name}, Rust {rust:?}"));
                }
            }
            BaseType::Message { package, name } => match rust {
                // Mirrors carry the ROS type's name (serde names carry no package).
                Format::TypeName(rust_name) if rust_name == name => {
                    self.check_struct(&format!("{package}/{name}"), rust_name);
                }
                _ => self
                    .errors
                    .push(format!("{at}: ROS {package}/{name}, Rust {rust:?}")),
            },
        }
    }
}

/// Every mismatch between `specs` and the Rust mirrors in `top` / `registry`.
fn contract_errors(
    specs: &[MsgSpec],
    top: &BTreeMap<String, String>,
    registry: &Registry,
) -> Vec<String> {
    let defs = definitions(specs);
    let mut checker = Checker::new(&defs, registry);
    for spec in specs {
        match top.get(&spec.full_name()) {
            Some(rust) => checker.check_struct(&spec.full_name(), rust),
            None => checker
                .errors
                .push(format!("{}: no Rust mirror is traced", spec.full_name())),
        }
    }
    let ros: BTreeSet<String> = specs.iter().map(MsgSpec::full_name).collect();
    for name in top.keys().filter(|name| !ros.contains(*name)) {
        checker
            .errors
            .push(format!("{name}: Rust mirror without an interface file"));
    }
    checker.errors
}

// ---------------------------------------------------------------------------------------------
// Tests
// ---------------------------------------------------------------------------------------------

#[test]
fn every_interface_file_matches_its_rust_mirror() {
    let specs = package_specs();
    let names: Vec<String> = specs.iter().map(MsgSpec::full_name).collect();
    assert_eq!(
        names,
        [
            "ttball_msgs/BallDetection",
            "ttball_msgs/BallState",
            "ttball_msgs/InterceptPrediction",
            "ttball_msgs/PredictedTrajectory",
            "ttball_msgs/RobotHit",
            "ttball_msgs/PlanReturnRequest",
            "ttball_msgs/PlanReturnResponse",
            "ttball_msgs/PredictReboundRequest",
            "ttball_msgs/PredictReboundResponse",
            "ttball_msgs/PredictTrajectoryRequest",
            "ttball_msgs/PredictTrajectoryResponse",
        ]
    );
    let (top, registry) = rust_mirrors();
    let errors = contract_errors(&specs, &top, &registry);
    assert!(errors.is_empty(), "contract broken:\n{}", errors.join("\n"));
    // The nested standard types were reached and checked too.
    for name in ["Header", "Time", "Point", "Vector3"] {
        assert!(registry.contains_key(name), "{name} not traced");
    }
}

/// The check fails when a field is moved, renamed or retyped in the `.msg` file.
#[test]
fn contract_check_catches_changes_in_the_msg_file() {
    let text = fs::read_to_string(msgs_dir().join("msg/BallDetection.msg")).unwrap();
    let (top, registry) = rust_mirrors();
    let check = |text: &str| {
        let spec = parse_msg(PACKAGE, "BallDetection", text).unwrap();
        let top: BTreeMap<String, String> = top
            .iter()
            .filter(|(name, _)| *name == "ttball_msgs/BallDetection")
            .map(|(a, b)| (a.clone(), b.clone()))
            .collect();
        contract_errors(&[spec], &top, &registry)
    };
    assert_eq!(check(&text), Vec::<String>::new());

    let has_spin = "bool has_spin ";
    let source = "uint8 source ";
    let lines: Vec<&str> = text.lines().collect();
    let i = lines.iter().position(|l| l.starts_with(has_spin)).unwrap();
    let j = lines.iter().position(|l| l.starts_with(source)).unwrap();
    let mut swapped = lines.clone();
    swapped.swap(i, j);
    let errors = check(&swapped.join("\n"));
    assert_eq!(errors.len(), 1, "{errors:?}");
    assert!(
        errors[0].contains("field names or order differ"),
        "{errors:?}"
    );

    let renamed = text.replace("uint8 source ", "uint8 origin ");
    assert_eq!(check(&renamed).len(), 1);

    let retyped = text.replace("float32 confidence", "float64 confidence");
    let errors = check(&retyped);
    assert_eq!(errors.len(), 1, "{errors:?}");
    assert!(errors[0].contains("BallDetection.confidence"), "{errors:?}");

    let resized = text.replace("float64[9] spin_covariance", "float64[6] spin_covariance");
    assert_eq!(check(&resized).len(), 1);

    let unbounded = text.replace("float64[9] spin_covariance", "float64[] spin_covariance");
    assert_eq!(check(&unbounded).len(), 1);
}

/// Stand-ins with the names of standard types, each with one thing wrong, for the test below.
#[allow(dead_code, reason = "only traced, never built")]
mod broken {
    use serde::Deserialize;

    #[derive(Deserialize)]
    pub struct Point {
        pub y: f64,
        pub x: f64,
        pub z: f64,
    }

    #[derive(Deserialize)]
    pub struct Vector3 {
        pub x: f64,
        pub y: f64,
        pub w: f64,
    }

    #[derive(Deserialize)]
    pub struct Time {
        pub sec: u32,
        pub nanosec: u32,
    }

    #[derive(Deserialize)]
    pub struct Header {
        pub stamp: Time,
        pub frame_id: String,
    }
}

/// The check fails when a Rust mirror has a field moved, renamed or retyped, also deep inside
/// (`Header` -> `Time`).
#[test]
fn contract_check_catches_changes_in_the_rust_mirror() {
    let defs = definitions(&[]);
    let errors_for = |trace_it: fn(&mut Tracer) -> String, ros: &str| {
        let mut tracer = Tracer::new(TracerConfig::default());
        let rust = trace_it(&mut tracer);
        let registry = tracer.registry().unwrap();
        let mut checker = Checker::new(&defs, &registry);
        checker.check_struct(ros, &rust);
        checker.errors
    };
    assert!(errors_for(trace::<Point>, "geometry_msgs/Point").is_empty());
    assert!(errors_for(trace::<Header>, "std_msgs/Header").is_empty());

    let errors = errors_for(trace::<broken::Point>, "geometry_msgs/Point");
    assert_eq!(errors.len(), 1, "{errors:?}");
    assert!(errors[0].contains("[\"y\", \"x\", \"z\"]"), "{errors:?}");

    let errors = errors_for(trace::<broken::Vector3>, "geometry_msgs/Vector3");
    assert_eq!(errors.len(), 1, "{errors:?}");

    let errors = errors_for(trace::<broken::Header>, "std_msgs/Header");
    assert_eq!(errors.len(), 1, "{errors:?}");
    assert!(
        errors[0].starts_with("builtin_interfaces/Time.sec: ROS int32"),
        "{errors:?}"
    );
}

/// A constant of a message, as the Rust side defines it.
#[derive(Debug, Clone, Copy, PartialEq)]
enum ConstValue {
    U8(u8),
}

impl ConstValue {
    /// Whether this is the value of the constant `ty NAME=value` as written in a `.msg` file.
    fn matches(self, ty: &str, value: &str) -> bool {
        match self {
            ConstValue::U8(v) => ty == "uint8" && value.parse::<u8>() == Ok(v),
        }
    }
}

#[test]
fn constants_match_their_rust_associated_consts() {
    let rust: &[(&str, &str, ConstValue)] = &[
        (
            "ttball_msgs/BallDetection",
            "SOURCE_UNKNOWN",
            ConstValue::U8(BallDetection::SOURCE_UNKNOWN),
        ),
        (
            "ttball_msgs/BallDetection",
            "SOURCE_WIDE_150FPS",
            ConstValue::U8(BallDetection::SOURCE_WIDE_150FPS),
        ),
        (
            "ttball_msgs/BallDetection",
            "SOURCE_HIGHSPEED_900FPS",
            ConstValue::U8(BallDetection::SOURCE_HIGHSPEED_900FPS),
        ),
        (
            "ttball_msgs/BallState",
            "STATUS_INITIALIZING",
            ConstValue::U8(BallState::STATUS_INITIALIZING),
        ),
        (
            "ttball_msgs/BallState",
            "STATUS_TRACKING",
            ConstValue::U8(BallState::STATUS_TRACKING),
        ),
        (
            "ttball_msgs/BallState",
            "STATUS_COASTING",
            ConstValue::U8(BallState::STATUS_COASTING),
        ),
        (
            "ttball_msgs/InterceptPrediction",
            "REASON_VALID",
            ConstValue::U8(InterceptPrediction::REASON_VALID),
        ),
        (
            "ttball_msgs/InterceptPrediction",
            "REASON_NET",
            ConstValue::U8(InterceptPrediction::REASON_NET),
        ),
        (
            "ttball_msgs/InterceptPrediction",
            "REASON_MISSES_TABLE",
            ConstValue::U8(InterceptPrediction::REASON_MISSES_TABLE),
        ),
        (
            "ttball_msgs/InterceptPrediction",
            "REASON_NO_BOUNCE",
            ConstValue::U8(InterceptPrediction::REASON_NO_BOUNCE),
        ),
        (
            "ttball_msgs/InterceptPrediction",
            "REASON_TWO_BOUNCES",
            ConstValue::U8(InterceptPrediction::REASON_TWO_BOUNCES),
        ),
        (
            "ttball_msgs/InterceptPrediction",
            "REASON_BEYOND_HORIZON",
            ConstValue::U8(InterceptPrediction::REASON_BEYOND_HORIZON),
        ),
    ];
    let parsed: Vec<(String, Constant)> = package_specs()
        .into_iter()
        .flat_map(|spec| {
            let owner = spec.full_name();
            spec.constants.into_iter().map(move |c| (owner.clone(), c))
        })
        .collect();
    let parsed_names: Vec<(&str, &str)> = parsed
        .iter()
        .map(|(owner, c)| (owner.as_str(), c.name.as_str()))
        .collect();
    let rust_names: Vec<(&str, &str)> = rust.iter().map(|(o, n, _)| (*o, *n)).collect();
    assert_eq!(parsed_names, rust_names, "constant names or order differ");
    for ((owner, c), (_, _, value)) in parsed.iter().zip(rust) {
        assert!(
            value.matches(&c.ty, &c.value),
            "{owner}::{}: ROS `{} {}={}`, Rust {value:?}",
            c.name,
            c.ty,
            c.name,
            c.value
        );
    }
}

/// Every field and constant carries a trailing comment, every file a header comment.
#[test]
fn every_field_and_constant_is_documented() {
    for spec in package_specs() {
        for field in &spec.fields {
            assert!(
                field.comment.is_some(),
                "{}.{} has no comment",
                spec.full_name(),
                field.name
            );
        }
        for constant in &spec.constants {
            assert!(
                constant.comment.is_some(),
                "{}::{} has no comment",
                spec.full_name(),
                constant.name
            );
        }
    }
    for (sub, ext) in [("msg", "msg"), ("srv", "srv")] {
        for (_, path) in interface_files(sub, ext) {
            let text = fs::read_to_string(&path).unwrap();
            assert!(
                text.starts_with("# "),
                "{} has no header comment",
                path.display()
            );
        }
    }
}

/// CMakeLists.txt generates every interface file, and nothing else.
#[test]
fn cmakelists_lists_every_interface_file() {
    let cmake = fs::read_to_string(msgs_dir().join("CMakeLists.txt")).unwrap();
    let listed: BTreeSet<&str> = cmake
        .split('"')
        .filter(|s| s.ends_with(".msg") || s.ends_with(".srv"))
        .collect();
    let mut present = BTreeSet::new();
    for (sub, ext) in [("msg", "msg"), ("srv", "srv")] {
        for (name, _) in interface_files(sub, ext) {
            present.insert(format!("{sub}/{name}.{ext}"));
        }
    }
    let present: BTreeSet<&str> = present.iter().map(String::as_str).collect();
    assert_eq!(listed, present);
}

/// A structure as `tests/interop/rosidl/dds_idl.py --json` writes it: fields and constants in
/// `.msg` notation.
#[derive(Debug, PartialEq, Deserialize)]
struct Described {
    fields: Vec<String>,
    constants: Vec<String>,
}

impl Described {
    fn of(spec: &MsgSpec) -> Self {
        let base = |b: &BaseType| match b {
            BaseType::Primitive { name, bound: None } => name.clone(),
            BaseType::Primitive {
                name,
                bound: Some(n),
            } => format!("{name}<={n}"),
            BaseType::Message { package, name } => format!("{package}/{name}"),
        };
        let array = |a: &Array| match a {
            Array::Single => String::new(),
            Array::Fixed(n) => format!("[{n}]"),
            Array::Unbounded => "[]".to_owned(),
            Array::Bounded(n) => format!("[<={n}]"),
        };
        Self {
            fields: spec
                .fields
                .iter()
                .map(|f| format!("{}{} {}", base(&f.ty.base), array(&f.ty.array), f.name))
                .collect(),
            constants: spec
                .constants
                .iter()
                .map(|c| format!("{} {}={}", c.ty, c.name, c.value))
                .collect(),
        }
    }
}

/// ROS 2's own interface tools read `msgs/` as this test's parser does, field for field and
/// constant for constant: `.ci/run` has rosidl_adapter translate every interface and
/// rosidl_parser parse it (`tests/interop/rosidl/dds_idl.py`, Debian's python3-rosidl) and names
/// what it read in `TTBALL_ROSIDL_JSON`; the Rust mirrors checked against this parser then agree
/// with rosidl too.
#[test]
fn the_parser_reads_msgs_as_rosidl_does() {
    let Some(path) = std::env::var_os("TTBALL_ROSIDL_JSON") else {
        assert!(
            std::env::var("CI").as_deref() != Ok("true"),
            "CI must compare msgs/ with rosidl's reading: set TTBALL_ROSIDL_JSON (see .ci/run)"
        );
        eprintln!(
            "skipped: set TTBALL_ROSIDL_JSON to what tests/interop/rosidl/dds_idl.py --json writes"
        );
        return;
    };
    let rosidl: BTreeMap<String, Described> =
        serde_json::from_str(&fs::read_to_string(path).unwrap()).unwrap();
    // rosidl names a service's halves PlanReturn_Request, this parser PlanReturnRequest.
    let rosidl: BTreeMap<String, Described> = rosidl
        .into_iter()
        .map(|(name, d)| {
            (
                name.replace("_Request", "Request")
                    .replace("_Response", "Response"),
                d,
            )
        })
        .collect();
    let ours: BTreeMap<String, Described> = package_specs()
        .iter()
        .map(|spec| (spec.full_name(), Described::of(spec)))
        .collect();
    assert_eq!(
        ours.keys().collect::<Vec<_>>(),
        rosidl.keys().collect::<Vec<_>>()
    );
    for (name, described) in &ours {
        assert_eq!(described, &rosidl[name], "{name}");
    }
}

#[test]
fn parser_understands_the_ros2_grammar() {
    let text = "\
# File-level comment.

int32 X=-5          # a constant
string NAME = 'a # b'
float64[3] fixed    # fixed array
Foo[] unbounded
other_pkg/Bar[<=4] bounded
string<=8 short_text \"hi\"  # bounded string with default
wstring[<=2] wide
uint8 answer 42
  # indented comment line
pkg/msg/Baz baz
";
    let spec = parse_msg("my_pkg", "Sample", text).unwrap();
    let constant = |ty: &str, name: &str, value: &str, comment: Option<&str>| Constant {
        ty: ty.into(),
        name: name.into(),
        value: value.into(),
        comment: comment.map(Into::into),
    };
    assert_eq!(
        spec.constants,
        [
            constant("int32", "X", "-5", Some("a constant")),
            constant("string", "NAME", "'a # b'", None),
        ]
    );
    let prim = |name: &str, bound: Option<usize>| BaseType::Primitive {
        name: name.into(),
        bound,
    };
    let message = |package: &str, name: &str| BaseType::Message {
        package: package.into(),
        name: name.into(),
    };
    // (base type, array, name, default, comment)
    type Row<'a> = (BaseType, Array, &'a str, Option<&'a str>, Option<&'a str>);
    let got: Vec<Row> = spec
        .fields
        .iter()
        .map(|f| {
            (
                f.ty.base.clone(),
                f.ty.array,
                f.name.as_str(),
                f.default.as_deref(),
                f.comment.as_deref(),
            )
        })
        .collect();
    assert_eq!(
        got,
        [
            (
                prim("float64", None),
                Array::Fixed(3),
                "fixed",
                None,
                Some("fixed array")
            ),
            (
                message("my_pkg", "Foo"),
                Array::Unbounded,
                "unbounded",
                None,
                None
            ),
            (
                message("other_pkg", "Bar"),
                Array::Bounded(4),
                "bounded",
                None,
                None
            ),
            (
                prim("string", Some(8)),
                Array::Single,
                "short_text",
                Some("\"hi\""),
                Some("bounded string with default")
            ),
            (prim("wstring", None), Array::Bounded(2), "wide", None, None),
            (
                prim("uint8", None),
                Array::Single,
                "answer",
                Some("42"),
                None
            ),
            (message("pkg", "Baz"), Array::Single, "baz", None, None),
        ]
    );

    let (request, response) =
        parse_srv("my_pkg", "Do", "int32 a  # in\n---\nbool ok  # out\n").unwrap();
    assert_eq!(request.name, "DoRequest");
    assert_eq!(request.fields.len(), 1);
    assert_eq!(request.fields[0].name, "a");
    assert_eq!(response.name, "DoResponse");
    assert_eq!(response.fields[0].name, "ok");
    let (request, response) = parse_srv("my_pkg", "Empty", "---\n").unwrap();
    assert!(request.fields.is_empty() && response.fields.is_empty());

    for bad in [
        "float64 Bad",
        "float64 bad_",
        "float64 two__underscores",
        "geometry_msgs/point x",
        "float64[ x",
        "float64[n] x",
        "int32<=3 x",
        "int32 lower=1",
        "geometry_msgs/Point P=1",
        "a/b/c/D x",
        "float64",
        "int32 x\nint32 x",
    ] {
        assert!(parse_msg("my_pkg", "Bad", bad).is_err(), "accepted {bad:?}");
    }
    assert!(parse_srv("my_pkg", "Bad", "int32 a\n").is_err());
    assert!(parse_srv("my_pkg", "Bad", "---\n---\n").is_err());
}

/// A `BallDetection` encodes to CDR as computed by hand.
///
/// `cdr_encoding::to_vec` gives the plain CDR body *without* the 4-byte encapsulation header
/// (`00 01 00 00` for CDR_LE), which the DDS layer (RustDDS / ros2-client) puts in front. CDR
/// aligns each primitive to its size relative to the start of this body, which is also how ROS 2
/// aligns after the encapsulation header. A string is a u32 length that counts the NUL, the
/// bytes, and the NUL; a fixed array is its elements with no length prefix; bool and u8 take one
/// byte.
#[test]
fn ball_detection_cdr_golden_bytes() {
    let detection = BallDetection {
        header: Header {
            stamp: Time {
                sec: 1_700_000_000,
                nanosec: 250_000_000,
            },
            frame_id: "table".into(),
        },
        position: Point {
            x: 0.5,
            y: -1.25,
            z: 0.25,
        },
        position_covariance: [0.0625, 0.0, 0.0, 0.0, 0.0625, 0.0, 0.0, 0.0, 0.0625],
        has_spin: true,
        spin: Vector3 {
            x: 0.0,
            y: -300.0,
            z: 12.5,
        },
        spin_covariance: [0.0; 9],
        source: BallDetection::SOURCE_HIGHSPEED_900FPS,
        confidence: 0.75,
    };
    const Z8: [u8; 8] = [0; 8]; // 0.0_f64
    const SIXTEENTH: [u8; 8] = [0, 0, 0, 0, 0, 0, 0xB0, 0x3F]; // 0.0625 = 0x3FB0_0000_0000_0000
    let mut expected: Vec<u8> = Vec::new();
    // 0: header.stamp.sec, i32 1_700_000_000 = 0x6553_F100
    expected.extend([0x00, 0xF1, 0x53, 0x65]);
    // 4: header.stamp.nanosec, u32 250_000_000 = 0x0EE6_B280
    expected.extend([0x80, 0xB2, 0xE6, 0x0E]);
    // 8: header.frame_id length, u32 6 = "table" + NUL
    expected.extend([6, 0, 0, 0]);
    // 12: "table\0"
    expected.extend(b"table\0");
    // 18: padding to 24 (next is an f64)
    expected.extend([0; 6]);
    // 24: position.x 0.5 = 0x3FE0_0000_0000_0000
    expected.extend([0, 0, 0, 0, 0, 0, 0xE0, 0x3F]);
    // 32: position.y -1.25 = 0xBFF4_0000_0000_0000
    expected.extend([0, 0, 0, 0, 0, 0, 0xF4, 0xBF]);
    // 40: position.z 0.25 = 0x3FD0_0000_0000_0000
    expected.extend([0, 0, 0, 0, 0, 0, 0xD0, 0x3F]);
    // 48: position_covariance, 9 f64 without length prefix
    for value in [
        SIXTEENTH, Z8, Z8, //
        Z8, SIXTEENTH, Z8, //
        Z8, Z8, SIXTEENTH,
    ] {
        expected.extend(value);
    }
    // 120: has_spin, 1 byte
    expected.push(1);
    // 121: padding to 128
    expected.extend([0; 7]);
    // 128: spin.x 0.0
    expected.extend(Z8);
    // 136: spin.y -300.0 = -(1.171875 * 2^8) = 0xC072_C000_0000_0000
    expected.extend([0, 0, 0, 0, 0, 0xC0, 0x72, 0xC0]);
    // 144: spin.z 12.5 = 1.5625 * 2^3 = 0x4029_0000_0000_0000
    expected.extend([0, 0, 0, 0, 0, 0, 0x29, 0x40]);
    // 152: spin_covariance, 9 f64 zeros
    expected.extend([0; 72]);
    // 224: source, u8 2
    expected.push(2);
    // 225: padding to 228 (next is an f32)
    expected.extend([0; 3]);
    // 228: confidence, f32 0.75 = 0x3F40_0000
    expected.extend([0x00, 0x00, 0x40, 0x3F]);
    assert_eq!(expected.len(), 232);

    let bytes = cdr_encoding::to_vec::<_, LittleEndian>(&detection).unwrap();
    assert_eq!(bytes, expected);

    let (decoded, consumed) =
        cdr_encoding::from_bytes::<BallDetection, LittleEndian>(&bytes).unwrap();
    assert_eq!(consumed, bytes.len());
    assert_eq!(decoded, detection);
}

/// Every mirror survives a CDR round trip, with sequences, strings and 81-element arrays filled.
#[test]
fn every_mirror_round_trips_through_cdr() {
    fn round_trip<T>(value: &T)
    where
        T: serde::Serialize + serde::de::DeserializeOwned + PartialEq + std::fmt::Debug,
    {
        let bytes = cdr_encoding::to_vec::<T, LittleEndian>(value).unwrap();
        let (decoded, consumed) = cdr_encoding::from_bytes::<T, LittleEndian>(&bytes).unwrap();
        assert_eq!(consumed, bytes.len());
        assert_eq!(&decoded, value);
    }
    let header = Header {
        stamp: Time::from_nanos(-1_250_000_000),
        frame_id: "table".into(),
    };
    let v = |x: f64| Vector3 {
        x,
        y: -2.0 * x,
        z: 3.0 * x,
    };
    let p = |x: f64| Point {
        x,
        y: x + 0.1,
        z: x + 0.2,
    };
    let mut covariance = [0.0; 81];
    for (i, c) in covariance.iter_mut().enumerate() {
        *c = i as f64 * 0.01;
    }
    let state = BallState {
        header: header.clone(),
        track_id: 7,
        status: BallState::STATUS_TRACKING,
        position: p(0.3),
        velocity: v(-6.0),
        spin: v(150.0),
        covariance,
        bounces: 1,
        nis: 2.5,
    };
    round_trip(&BallDetection::default());
    round_trip(&state);
    round_trip(&InterceptPrediction {
        header: header.clone(),
        track_id: 7,
        valid: true,
        intercept_stamp: Time::from_nanos(1_700_000_000_500_000_000),
        position: p(-1.5),
        velocity: v(-5.0),
        spin: v(80.0),
        covariance,
        bounce_valid: true,
        bounce_stamp: Time::from_nanos(1_700_000_000_300_000_000),
        bounce_position: p(-0.8),
        reason: InterceptPrediction::REASON_VALID,
        time_variance: 2.5e-7,
    });
    let trajectory = PredictedTrajectory {
        header: header.clone(),
        track_id: 7,
        stamps: vec![Time::from_nanos(0), Time::from_nanos(10_000_000)],
        positions: vec![p(0.0), p(0.1)],
        velocities: vec![v(-6.0), v(-5.9)],
        spins: vec![v(100.0), v(100.0)],
    };
    round_trip(&trajectory);
    round_trip(&PredictTrajectoryRequest {
        track_id: 0,
        initial: state.clone(),
        horizon: 1.0,
        dt: 0.01,
    });
    round_trip(&PredictTrajectoryResponse {
        success: true,
        message: String::new(),
        trajectory,
    });
    round_trip(&PredictReboundRequest {
        ball_position: p(-1.6),
        ball_velocity: v(-5.0),
        ball_spin: v(200.0),
        racket_velocity: v(3.0),
        racket_normal: v(0.2),
        impact_offset: 0.132,
    });
    round_trip(&PredictReboundResponse {
        success: false,
        message: "racket normal is not a unit vector".to_owned(),
        ball_velocity: v(4.0),
        ball_spin: v(-50.0),
        rebound_power_coefficient: 0.62,
        contact_time: 0.001,
        mean_force: 30.0,
        peak_force: 47.1,
        reduced_mass: 0.0781,
        wrist_force: 5.0,
        lands_on_table: true,
        landing_position: p(0.9),
    });
    round_trip(&PlanReturnRequest {
        track_id: 0,
        ball: state,
        target: p(0.9),
        flight_time: 0.0,
        net_clearance: 0.15,
        impact_offset: 0.05,
        brush_speed: -1.5,
    });
    round_trip(&PlanReturnRequest {
        track_id: 7,
        flight_time: 0.45,
        ..PlanReturnRequest::default()
    });
    round_trip(&PlanReturnResponse {
        success: true,
        message: String::new(),
        impact_stamp: Time::from_nanos(1_700_000_000_500_000_000),
        impact_position: p(-1.6),
        racket_velocity: v(3.5),
        racket_normal: v(0.25),
        ball_velocity: v(6.0),
        ball_spin: v(-80.0),
        landing_position: p(0.9),
        flight_time: 0.41,
        net_clearance: 0.15,
        landing_error: 2e-7,
        landing_covariance: [4e-4, 1e-5, 2e-5, 1e-5, 9e-4, 0.0, 2e-5, 0.0, 1e-4],
        contact_time: 0.0011,
        peak_force: 52.0,
        wrist_force: 6.5,
    });
    round_trip(&PlanReturnResponse {
        success: false,
        message: "target unreachable".to_owned(),
        ..PlanReturnResponse::default()
    });
}

/// The standard messages the node publishes besides its own (`/diagnostics`) match their ROS 2
/// definitions (as embedded in the MCAP schemas), field for field.
#[test]
fn diagnostic_msgs_mirror_matches_its_ros_definition() {
    use ttball::ros::msgs::definitions::definition;
    use ttball::ros::msgs::diagnostic_msgs::{DiagnosticArray, DiagnosticStatus};
    let specs: Vec<MsgSpec> = ["DiagnosticArray", "DiagnosticStatus", "KeyValue"]
        .iter()
        .map(|name| {
            let text = definition(&format!("diagnostic_msgs/{name}")).unwrap();
            parse_msg("diagnostic_msgs", name, text).unwrap()
        })
        .collect();
    let mut tracer = Tracer::new(TracerConfig::default());
    let mut top = BTreeMap::new();
    top.insert(
        "diagnostic_msgs/DiagnosticArray".to_owned(),
        trace::<DiagnosticArray>(&mut tracer),
    );
    top.insert(
        "diagnostic_msgs/DiagnosticStatus".to_owned(),
        trace::<DiagnosticStatus>(&mut tracer),
    );
    top.insert("diagnostic_msgs/KeyValue".to_owned(), "KeyValue".to_owned());
    let registry = tracer.registry().unwrap();
    let errors = contract_errors(&specs, &top, &registry);
    assert!(errors.is_empty(), "contract broken:\n{}", errors.join("\n"));
    assert_eq!(
        (
            DiagnosticStatus::OK,
            DiagnosticStatus::WARN,
            DiagnosticStatus::ERROR,
            DiagnosticStatus::STALE
        ),
        (0, 1, 2, 3)
    );
}
