//! The YAML configuration: the shipped `config/ttball.yaml` against the defaults, layering of file
//! and `-p` overrides, and the messages of every kind of error.
#![cfg(feature = "interface")]
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    clippy::panic,
    reason = "test helpers outside #[test] functions"
)]

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

use serde_norway::Value;
use ttball::config::Config;
use ttball::config::yaml::{self, Layer, LoadError, Origin, Problem};

const NO_OVERRIDES: &[&str] = &[];

fn shipped() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("config/ttball.yaml")
}

fn load_text(text: &str, overrides: &[&str]) -> Result<Config, LoadError> {
    yaml::load_str(text, Path::new("my.yaml"), overrides)
}

fn params(body: &str) -> String {
    let indented: String = body.lines().map(|l| format!("    {l}\n")).collect();
    format!("ttball:\n  ros__parameters:\n{indented}")
}

/// The error message of a configuration that must fail.
fn error(text: &str, overrides: &[&str]) -> String {
    match load_text(text, overrides) {
        Ok(_) => panic!("expected an error for {text:?} {overrides:?}"),
        Err(e) => e.to_string(),
    }
}

fn problems(text: &str, overrides: &[&str]) -> Vec<Problem> {
    match load_text(text, overrides) {
        Err(LoadError::Rejected { problems }) => problems,
        other => panic!("expected rejected problems, got {other:?}"),
    }
}

/// Dotted leaf keys of a value (lists are leaves).
fn leaf_keys(value: &Value, prefix: &str, out: &mut BTreeSet<String>) {
    match value {
        Value::Mapping(map) => {
            for (k, v) in map {
                let k = k.as_str().expect("string keys");
                let name = if prefix.is_empty() {
                    k.to_owned()
                } else {
                    format!("{prefix}.{k}")
                };
                leaf_keys(v, &name, out);
            }
        }
        _ => {
            out.insert(prefix.to_owned());
        }
    }
}

#[test]
fn shipped_file_is_exactly_the_defaults() {
    let config = yaml::load(Some(&shipped()), NO_OVERRIDES).unwrap();
    assert_eq!(config, Config::default());
}

#[test]
fn shipped_file_lists_every_key() {
    let text = std::fs::read_to_string(shipped()).unwrap();
    let document: Value = serde_norway::from_str(&text).unwrap();
    let mut file_keys = BTreeSet::new();
    leaf_keys(&document["ttball"]["ros__parameters"], "", &mut file_keys);

    let mut default_keys = BTreeSet::new();
    leaf_keys(
        &serde_norway::to_value(Config::default()).unwrap(),
        "",
        &mut default_keys,
    );
    assert_eq!(file_keys, default_keys);

    let names: BTreeSet<String> = yaml::parameter_names(&Config::default())
        .into_iter()
        .collect();
    assert_eq!(names, default_keys);
}

/// Every key line of the shipped file has a comment (inline, or on the line(s) just above);
/// the continuation lines of a list written over several lines belong to its key.
#[test]
fn shipped_file_comments_every_key() {
    let text = std::fs::read_to_string(shipped()).unwrap();
    let mut previous = "";
    let mut open_lists = 0_i32;
    for (i, line) in text.lines().enumerate() {
        let trimmed = line.trim();
        if !trimmed.is_empty() && !trimmed.starts_with('#') {
            assert!(
                open_lists > 0 || trimmed.contains(" # ") || previous.starts_with('#'),
                "line {}: `{trimmed}` has no comment",
                i + 1
            );
            let code = trimmed.split(" # ").next().unwrap_or(trimmed);
            open_lists += code.matches('[').count() as i32 - code.matches(']').count() as i32;
        }
        if !trimmed.is_empty() {
            previous = trimmed;
        }
    }
}

/// Every parameter is a ROS 2 parameter type: bool, integer, double, string, or a list of one
/// of those (no maps in lists, no nulls).
#[test]
fn every_parameter_is_a_ros2_type() {
    fn check(value: &Value, key: &str) {
        match value {
            Value::Mapping(map) => {
                for (k, v) in map {
                    check(v, &format!("{key}.{}", k.as_str().unwrap()));
                }
            }
            Value::Bool(_) | Value::Number(_) | Value::String(_) => {}
            Value::Sequence(items) => {
                let kinds: BTreeSet<&str> = items
                    .iter()
                    .map(|v| match v {
                        Value::Bool(_) => "bool",
                        Value::Number(n) if n.is_f64() => "double",
                        Value::Number(_) => "integer",
                        Value::String(_) => "string",
                        other => panic!("{key}: list element {other:?} is not a ROS 2 scalar"),
                    })
                    .collect();
                assert!(kinds.len() <= 1, "{key}: mixed list {kinds:?}");
            }
            other => panic!("{key}: {other:?} is not a ROS 2 parameter type"),
        }
    }
    check(&serde_norway::to_value(Config::default()).unwrap(), "");
}

#[test]
fn partial_file_keeps_other_defaults() {
    let config = load_text(
        &params("table:\n  restitution: 0.92\nintercept:\n  plane_x: -1.45"),
        NO_OVERRIDES,
    )
    .unwrap();
    let mut expected = Config::default();
    expected.table.restitution = 0.92;
    expected.intercept.plane_x = -1.45;
    assert_eq!(config, expected);
}

#[test]
fn node_keys_and_dotted_keys() {
    for node in ["ttball", "/ttball", "\"/**\"", "\"/**/ttball\"", "\"/*\""] {
        let text = format!("{node}:\n  ros__parameters:\n    table.friction: 0.2\n");
        let config = load_text(&text, NO_OVERRIDES).unwrap();
        assert_eq!(config.table.friction, 0.2, "{node}");
    }
    assert_eq!(load_text("", NO_OVERRIDES).unwrap(), Config::default());
}

/// rcl's rules: sections of other nodes are ignored, every section that applies is applied in
/// the file's order, namespaces may be nested keys, and the node is the one the layers name.
#[test]
fn params_file_sections_apply_as_rcl_applies_them() {
    let text = "\
/camera_driver:
  ros__parameters:
    exposure: 3
\"/**\":
  ros__parameters:
    table.friction: 0.1
    intercept.plane_x: -1.3
/robot1/ttball:
  ros__parameters:
    table.friction: 0.2
robot1:
  ttball:
    ros__parameters:
      table:
        restitution: 0.85
  other:
    ros__parameters:
      gravity: 1.0
/robot2/ttball:
  ros__parameters:
    gravity: 2.0
";
    // In the root namespace only the wildcard applies.
    let root = load_text(text, NO_OVERRIDES).unwrap();
    assert_eq!((root.table.friction, root.intercept.plane_x), (0.1, -1.3));
    assert_eq!((root.table.restitution, root.gravity), (0.9, 9.80665));
    // Renamed into /robot1 by a later layer: the file is read again for that node.
    let robot1 = load_text(text, &["node.namespace:=/robot1"]).unwrap();
    assert_eq!(
        (robot1.table.friction, robot1.intercept.plane_x),
        (0.2, -1.3)
    );
    assert_eq!((robot1.table.restitution, robot1.gravity), (0.85, 9.80665));
    // As the remaps name the node.
    let path = std::env::temp_dir().join(format!("ttball-sections-{}.yaml", std::process::id()));
    std::fs::write(&path, text).unwrap();
    let layers = [
        Layer::File(path.clone()),
        Layer::Param("other:gravity:=5.0".to_owned()),
        Layer::Param("ttball:gating.max_consecutive_rejections:=7".to_owned()),
        Layer::Param("/robot2/ttball:tracking.timeout:=0.3".to_owned()),
    ];
    let robot2 = yaml::load_layers(&layers, Some("/robot2/ttball")).unwrap();
    assert_eq!((robot2.gravity, robot2.table.friction), (2.0, 0.1));
    assert_eq!(
        (
            robot2.gating.max_consecutive_rejections,
            robot2.tracking.timeout
        ),
        (7, 0.3)
    );
    // Files and overrides apply in the order given.
    let layers = [
        Layer::Param("table.friction:=0.3".to_owned()),
        Layer::File(path.clone()),
        Layer::Param("intercept.plane_x:=-1.2".to_owned()),
    ];
    let ordered = yaml::load_layers(&layers, None).unwrap();
    assert_eq!(
        (ordered.table.friction, ordered.intercept.plane_x),
        (0.1, -1.2)
    );
    std::fs::remove_file(&path).unwrap();
}

/// What `ros2 param dump /robot1/ttball` writes loads back.
#[test]
fn ros2_param_dump_output_loads_back() {
    let text = "\
/robot1/ttball:
  ros__parameters:
    ekf:
      acceleration_noise_density: 2.5
    intercept:
      plane_x: -1.4
    topics:
      state: ball/state
    use_sim_time: true
";
    let config = load_text(text, &["node.namespace:=/robot1"]).unwrap();
    assert_eq!(config.ekf.acceleration_noise_density, 2.5);
    assert_eq!(config.intercept.plane_x, -1.4);
    assert!(config.use_sim_time);
}

#[test]
fn integer_for_a_real_is_accepted() {
    let config = load_text(&params("gravity: 10"), &["tracking.timeout:=1"]).unwrap();
    assert_eq!(config.gravity, 10.0);
    assert_eq!(config.tracking.timeout, 1.0);
}

#[test]
fn overrides_apply_after_the_file() {
    let config = load_text(
        &params("intercept:\n  plane_x: -1.5"),
        &[
            "intercept.plane_x:=-1.45",
            "gating.max_consecutive_rejections:=6",
            "topics.state:=/robot/ball_state",
            "aero.drag_coefficients:=[0.5, 0.1]",
            "node.namespace:=/robot1",
        ],
    )
    .unwrap();
    assert_eq!(config.intercept.plane_x, -1.45);
    assert_eq!(config.gating.max_consecutive_rejections, 6);
    assert_eq!(config.topics.state, "/robot/ball_state");
    assert_eq!(config.aero.drag_coefficients, [0.5, 0.1]);
    assert_eq!(config.node.namespace, "/robot1");

    // The last override of a key wins; no file at all is fine.
    let config = yaml::load(None, &["table.friction:=0.1", "table.friction:=0.3"]).unwrap();
    assert_eq!(config.table.friction, 0.3);
}

#[test]
fn unknown_key_names_the_key_the_line_and_a_suggestion() {
    let text = params("table:\n  length: 2.74\n  restitutoin: 0.9");
    let message = error(&text, NO_OVERRIDES);
    assert!(
        message.contains(
            "my.yaml:5: unknown parameter `table.restitutoin`; did you mean `table.restitution`?"
        ),
        "{message}"
    );

    let p = problems(&params("tabel:\n  friction: 0.2"), NO_OVERRIDES);
    assert_eq!(
        p,
        [Problem::UnknownKey {
            key: "tabel.friction".to_owned(),
            origin: Origin::File {
                path: PathBuf::from("my.yaml"),
                line: Some(4),
            },
            suggestion: Some("table.friction".to_owned()),
        }]
    );

    let message = error(&params("nonsense: 1"), NO_OVERRIDES);
    assert!(
        message.contains("unknown parameter `nonsense`; `ttball config print` lists every"),
        "{message}"
    );
}

#[test]
fn wrong_type_names_the_key_and_the_expected_type() {
    let message = error(&params("table:\n  restitution: high"), NO_OVERRIDES);
    assert!(
        message.contains(
            "my.yaml:4: `table.restitution` must be a real number (default 0.9), but is the \
             string \"high\""
        ),
        "{message}"
    );
    let message = error(
        &params("gating:\n  max_consecutive_rejections: 4.5"),
        NO_OVERRIDES,
    );
    assert!(
        message.contains(
            "`gating.max_consecutive_rejections` must be a whole number from 0 to 4294967295 (default 5)"
        ),
        "{message}"
    );
    let message = error(
        &params("gating:\n  max_consecutive_rejections: -4"),
        NO_OVERRIDES,
    );
    assert!(message.contains("`gating.max_consecutive_rejections` must be a whole number"));
    let message = error(&params("table: 0.9"), NO_OVERRIDES);
    assert!(
        message.contains("`table` must be a section of parameters (a map), but is the real number"),
        "{message}"
    );
    let message = error(&params("table:\n  restitution:\n    x: 1"), NO_OVERRIDES);
    assert!(
        message.contains("`table.restitution` must be a real number (default 0.9), but is a map"),
        "{message}"
    );
    let message = error(&params("topics:\n  state: 5"), NO_OVERRIDES);
    assert!(
        message.contains("`topics.state` must be a string (default \"ball/state\")"),
        "{message}"
    );
    let message = error(
        &params("aero:\n  drag_coefficients: [0.3, a]"),
        NO_OVERRIDES,
    );
    assert!(
        message.contains("`aero.drag_coefficients` must be a list of real numbers"),
        "{message}"
    );
    let message = error(&params("table:\n  friction:"), NO_OVERRIDES);
    assert!(
        message.contains("`table.friction` must be a real number (default 0.25), but is empty"),
        "{message}"
    );
}

#[test]
fn out_of_range_names_the_key_value_range_and_where() {
    let message = error(
        &params("table:\n  restitution: 1.5"),
        &["tracking.timeout:=-1.0"],
    );
    assert!(
        message.contains(
            "my.yaml:4: `table.restitution` = 1.5 is out of range: it must be greater than 0 \
             and at most 1"
        ),
        "{message}"
    );
    assert!(
        message.contains(
            "-p tracking.timeout:=-1.0: `tracking.timeout` = -1 is out of range: it must be \
             greater than 0"
        ),
        "{message}"
    );
    let message = error("", &["prediction.horizon:=0.005"]);
    assert!(
        message.contains(
            "-p prediction.horizon:=0.005: `prediction.trajectory_dt` = 0.01 must not exceed \
             `prediction.horizon` = 0.005"
        ),
        "{message}"
    );
    let message = error("", &["aero.magnus_coefficients:=[1.0, .nan]"]);
    assert!(
        message.contains("`aero.magnus_coefficients[1]` = NaN is not a finite number"),
        "{message}"
    );
}

#[test]
fn all_problems_are_reported_at_once() {
    let p = problems(
        &params("tabel:\n  friction: 0.2\ntable:\n  restitution: 2.0\n  friction: x"),
        &["nonsense:=1", "gating.probability:=1.0", "bad"],
    );
    let summary: Vec<String> = p.iter().map(ToString::to_string).collect();
    assert_eq!(p.len(), 6, "{summary:#?}");
    let keys = [
        "`tabel.friction`",
        "`table.friction`",
        "`nonsense`",
        "-p bad:",
        "`table.restitution` = 2",
        "`gating.probability` = 1",
    ];
    for (line, key) in summary.iter().zip(keys) {
        assert!(line.contains(key), "{line} lacks {key}");
    }
}

#[test]
fn bad_overrides_say_what_is_expected() {
    let message = error("", &["intercept.plane_x=-1.45"]);
    assert!(
        message.contains("-p intercept.plane_x=-1.45: expected NAME:=VALUE"),
        "{message}"
    );
    let message = error("", &[":=1"]);
    assert!(message.contains("the parameter name before `:=` is empty"));
    let message = error("", &["nonsense:=1"]);
    assert!(
        message.contains("-p nonsense:=1: unknown parameter `nonsense`"),
        "{message}"
    );
    let message = error("", &["intercept.planex:=-1.45"]);
    assert!(
        message.contains("unknown parameter `intercept.planex`; did you mean `intercept.plane_x`?"),
        "{message}"
    );
    let message = error("", &["table.restitution:=[1"]);
    assert!(
        message.contains("-p table.restitution:=[1: the value `[1` is not a YAML scalar"),
        "{message}"
    );
}

#[test]
fn file_layout_errors_say_what_is_expected() {
    let message = error("table:\n  restitution: 0.9\n", NO_OVERRIDES);
    assert!(
        message.contains(
            "my.yaml:1: unexpected top-level key `table` (the parameters must be nested under \
             the node name, e.g. `ttball:`, and `ros__parameters:`)"
        ),
        "{message}"
    );
    let message = error("ros__parameters:\n  a: 1\n", NO_OVERRIDES);
    assert!(message.contains("unexpected top-level key `ros__parameters`"));
    assert!(message.contains("starts with the node name `ttball:`"));
    let message = error("ttball:\n  parameters:\n    a: 1\n", NO_OVERRIDES);
    assert!(
        message.contains("my.yaml:2: unexpected key `parameters` under `ttball`"),
        "{message}"
    );
    let message = error("- 1\n- 2\n", NO_OVERRIDES);
    assert!(message.contains("found a list, but a ROS 2 parameters file starts with"));
}

#[test]
fn syntax_and_missing_file_errors() {
    let message = error("ttball:\n  ros__parameters:\n   a: [1\n", NO_OVERRIDES);
    assert!(message.starts_with("my.yaml: not valid YAML:"), "{message}");
    assert!(message.contains("line"), "{message}");

    let missing = Path::new("/nonexistent/ttball.yaml");
    let err = yaml::load(Some(missing), NO_OVERRIDES).unwrap_err();
    assert!(matches!(err, LoadError::NotFound { .. }));
    assert!(
        err.to_string()
            .contains("configuration file `/nonexistent/ttball.yaml` does not exist"),
        "{err}"
    );
}

#[test]
fn printed_configuration_round_trips() {
    let printed = yaml::to_ros_params_yaml(&Config::default());
    assert!(printed.starts_with("ttball:\n  ros__parameters:\n    gravity: 9.80665\n"));
    assert!(printed.contains("\n    intercept:\n      plane_x: -1.6\n"));
    assert!(printed.contains("      equivalent_mass: 1.0\n"));
    assert!(printed.contains("      namespace: \"\"\n"));
    assert_eq!(
        load_text(&printed, NO_OVERRIDES).unwrap(),
        Config::default()
    );

    let mut changed = Config {
        gravity: 10.0,
        ..Config::default()
    };
    changed.air.kinematic_viscosity = 1e-7;
    changed.aero.drag_coefficients = vec![1.0, 0.0, -2.5e-9];
    changed.node.name = "ttball_left".to_owned();
    changed.node.namespace = "/robot1".to_owned();
    changed.qos.outputs_depth = 1;
    let printed = yaml::to_ros_params_yaml(&changed);
    assert!(printed.contains("gravity: 10.0\n"), "{printed}");
    assert_eq!(load_text(&printed, NO_OVERRIDES).unwrap(), changed);
    // Reals re-parse as reals (a ROS 2 double parameter), never as integers.
    // A file that renames the node names it by the wildcard, so that it finds the node.
    assert!(printed.starts_with("\"/**\":\n"), "{printed}");
    let document: Value = serde_norway::from_str(&printed).unwrap();
    assert!(document["/**"]["ros__parameters"]["gravity"].is_f64());
    assert!(document["/**"]["ros__parameters"]["aero"]["drag_coefficients"][1].is_f64());
}

/// Every number of the configuration, set to NaN, infinity or a value far out of any range, is
/// refused with a problem naming its key (or, for the last, accepted as valid): nothing slips
/// through to a running node.
#[test]
fn every_number_out_of_range_is_named_with_its_key() {
    let defaults = serde_norway::to_value(Config::default()).unwrap();
    let mut keys = BTreeSet::new();
    leaf_keys(&defaults, "", &mut keys);
    let mut checked = 0;
    for key in keys {
        let value = key.split('.').fold(&defaults, |v, part| &v[part]);
        let is_real =
            value.as_f64().is_some() && value.as_i64().is_none() && value.as_u64().is_none();
        let is_integer = value.as_i64().is_some() || value.as_u64().is_some();
        if !(is_real || is_integer) {
            continue;
        }
        let bad: &[&str] = if is_real {
            &[".nan", ".inf", "-.inf", "-1e300", "1e300"]
        } else {
            &["-1", "99999999999999999999"]
        };
        for v in bad {
            let setting = format!("{key}:={v}");
            match load_text("", &[setting.as_str()]) {
                // Far-out finite values may be valid for a key without that bound; a non-finite
                // one never is.
                Ok(_) => assert!(
                    !v.contains("nan") && !v.contains("inf"),
                    "{setting} was accepted"
                ),
                Err(LoadError::Rejected { problems }) => {
                    let text: Vec<String> = problems.iter().map(ToString::to_string).collect();
                    assert!(
                        text.iter()
                            .any(|t| t.contains(&format!("`{key}")) || t.contains(&setting)),
                        "{setting}: {text:?}"
                    );
                }
                Err(other) => assert!(other.to_string().contains(&key), "{setting}: {other}"),
            }
            checked += 1;
        }
    }
    eprintln!("{checked} values tried");
    assert!(checked > 100, "{checked} values tried");
}

/// `node.cpus` is a `taskset -c` list; one CPU may be a bare number, as `-p node.cpus:=1` gives.
#[test]
fn node_cpus_take_a_number_or_a_cpu_list() {
    let cpus = |text: &str, overrides: &[&str]| {
        load_text(text, overrides).unwrap().node.cpu_list().unwrap()
    };
    assert_eq!(cpus("", &["node.cpus:=1"]), [1]);
    assert_eq!(cpus("", &["node.cpus:=\"0-1\""]), [0, 1]);
    assert_eq!(cpus(&params("node:\n  cpus: \"2,3\""), &[]), [2, 3]);
    assert_eq!(cpus(&params("node:\n  cpus: 3"), &[]), [3]);
    let text = error("", &["node.cpus:=\"1,x\""]);
    assert!(text.contains("is not a valid CPU list"), "{text}");
    assert!(text.contains("taskset -c"), "{text}");
}

/// Every parameter has a description for its ROS 2 descriptor, and the rule it is checked
/// against where it has one.
#[test]
fn every_parameter_is_described() {
    let descriptions = yaml::descriptions();
    let config = Config::default();
    for name in yaml::parameter_names(&config) {
        let text = descriptions.get(&name).map_or("", String::as_str);
        assert!(text.len() > 10, "{name}: {text:?}");
    }
    assert!(
        descriptions["table.restitution"].contains("[-]"),
        "{}",
        descriptions["table.restitution"]
    );
    let rules = config.rules();
    let rule = |key: &str| {
        rules
            .iter()
            .find(|(k, _)| k == key)
            .map(|(_, r)| r.as_str())
    };
    assert_eq!(
        rule("gravity"),
        Some("greater than 0 and at most 30 (m/s^2; Earth: 9.81)")
    );
    assert_eq!(
        rule("aero.drag_coefficients"),
        Some("1 to 8 finite coefficients, lowest order first")
    );
    assert_eq!(rule("topics.state"), Some("topic name"));
}

/// More cameras are added by name with their own id: in a params file (keys not given from
/// `unknown`'s defaults), by `-p`, printed and loaded back; a misspelt source, a shared id and an
/// id beyond a `uint8` are each refused saying what to do.
#[test]
fn camera_sources_are_added_by_name_and_id() {
    let text = params(
        "sources:\n  side_camera:\n    id: 3\n    position_sigma: 0.004\n    frame_rate: 120.0\n",
    );
    let config = load_text(&text, &["sources.ceiling.id:=7"]).unwrap();
    let side = &config.sources.more["side_camera"];
    assert_eq!(
        (side.id, side.position_sigma, side.frame_rate),
        (3, 0.004, 120.0)
    );
    assert_eq!(
        side.spin_sigma,
        Config::default().sources.unknown.spin_sigma
    );
    assert_eq!(config.sources.more["ceiling"].id, 7);
    let names: Vec<&str> = config.sources.all().iter().map(|(n, _)| *n).collect();
    assert_eq!(
        names,
        [
            "unknown",
            "wide_150fps",
            "highspeed_900fps",
            "ceiling",
            "side_camera"
        ]
    );
    let printed = yaml::to_ros_params_yaml(&config);
    assert!(
        printed.contains("      side_camera:\n        id: 3\n"),
        "{printed}"
    );
    assert_eq!(load_text(&printed, NO_OVERRIDES).unwrap(), config);
    assert!(yaml::parameter_names(&config).contains(&"sources.ceiling.frame_rate".to_owned()));

    let typo = error(
        &params("sources:\n  wide_150fsp:\n    position_sigma: 0.004\n"),
        NO_OVERRIDES,
    );
    assert!(
        typo.contains("1 problem")
            && typo.contains("`sources.wide_150fsp` is not a source; to add a camera, set `sources.wide_150fsp.id`")
            && typo.contains("did you mean `sources.wide_150fps`?"),
        "{typo}"
    );
    let shared = error(&text, &["sources.side_camera.id:=2"]);
    assert!(
        shared.contains("`sources.side_camera.id` = 2 is also `sources.highspeed_900fps.id`"),
        "{shared}"
    );
    let wide = error(&text, &["sources.side_camera.id:=256"]);
    assert!(
        wide.contains("1 problem") && wide.contains("a whole number from 0 to 255"),
        "{wide}"
    );
}
