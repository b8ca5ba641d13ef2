//! The node's ROS 2 parameters, as rclcpp serves them (rcl_interfaces: `list_parameters`,
//! `get_parameters`, `get_parameter_types`, `describe_parameters`, `set_parameters`,
//! `set_parameters_atomically`, and `/parameter_events`): every configuration key is declared
//! under its dotted name (`table.restitution`) with its type, its description (the comment above
//! it in `config/ttball.yaml`, unit included), the rule it is checked against
//! (`additional_constraints`, and a numeric range where the rule is an interval), and read-only
//! unless it can change between detections ([`is_live`]).
//!
//! A set is checked as the configuration is loaded (type, then [`Config::validate`] of the
//! whole): a refused value is answered with the reason and changes nothing. No DDS here: the node
//! serves these answers (`services`) and applies the changed configuration to its
//! pipeline ([`crate::ros::pipeline::Pipeline::reconfigure`]).

use std::collections::HashMap;

use ros2_client::parameters::raw::{
    FloatingPointRange, IntegerRange, Parameter, ParameterDescriptor, ParameterEvent,
    ParameterType, ParameterValue, SetParametersResult,
};
use ros2_client::rcl_interfaces::ListParametersResult;
use serde_norway::Value;

use crate::config::yaml;
use crate::config::{Config, CountRange, Range, UNKNOWN_SOURCE};

/// Sections (and single keys) whose parameters take effect between detections (`use_sim_time`:
/// from the next stamp of the node's own messages, as in rclcpp); the others are read-only, as
/// they shape what the node was built with (its physics and what it learned of it, its DDS
/// entities, the propagator's step).
const LIVE: [&str; 11] = [
    "use_sim_time",
    "ekf.",
    "gating.",
    "sources.",
    "intercept.",
    "tracking.",
    "racket.",
    "arm.",
    "stroke.",
    "prediction.horizon",
    "prediction.trajectory_",
];

/// Whether the parameter `name` may be set on the running node. A source's `id` may not: the
/// node's per-source diagnostics are laid out by id when it starts.
pub fn is_live(name: &str) -> bool {
    LIVE.iter().any(|prefix| name.starts_with(prefix))
        && !(name.starts_with("sources.") && name.ends_with(".id"))
}

/// A configuration accepted by a set, and the event that reports it.
#[derive(Debug, Clone)]
pub struct Change {
    /// The configuration before.
    pub previous: Config,
    /// The parameters that changed, with their new values (`changed_parameters` of the event).
    pub changed: Vec<Parameter>,
}

/// The node's parameters: the configuration it runs with, and how each key is declared.
pub struct Parameters {
    config: Config,
    /// Declared names in the configuration's order, with their ROS 2 types.
    declared: Vec<(String, u8)>,
    descriptions: HashMap<String, String>,
    rules: HashMap<String, String>,
    ranges: HashMap<String, Range>,
    count_ranges: HashMap<String, CountRange>,
}

impl Parameters {
    /// The parameters of a node running `config` (validated).
    pub fn new(config: &Config) -> Self {
        let declared = match serde_norway::to_value(config) {
            Ok(value) => {
                let mut out = Vec::new();
                leaves(&value, "", &mut |name, leaf| {
                    out.push((name, type_of(leaf)))
                });
                out
            }
            Err(_) => Vec::new(),
        };
        Self {
            config: config.clone(),
            declared,
            descriptions: yaml::descriptions(),
            rules: config.rules().into_iter().collect(),
            ranges: config.ranges().into_iter().collect(),
            count_ranges: config.count_ranges().into_iter().collect(),
        }
    }

    /// The configuration as the parameters stand.
    pub fn config(&self) -> &Config {
        &self.config
    }

    /// Every declared name, in the configuration's order.
    pub fn names(&self) -> impl Iterator<Item = &str> {
        self.declared.iter().map(|(name, _)| name.as_str())
    }

    fn declared_type(&self, name: &str) -> Option<u8> {
        self.declared
            .iter()
            .find(|(n, _)| n == name)
            .map(|(_, t)| *t)
    }

    /// `list_parameters`: rclcpp's rules. Without prefixes, the names with fewer than `depth`
    /// dots (`depth` 0: all); with prefixes, the names equal to one or under `prefix.` within
    /// `depth` further levels. `prefixes` of the result: the listed names' sections.
    pub fn list(&self, prefixes: &[String], depth: u64) -> ListParametersResult {
        let within = |rest: &str| depth == 0 || (rest.matches('.').count() as u64) < depth;
        let mut result = ListParametersResult {
            names: Vec::new(),
            prefixes: Vec::new(),
        };
        for name in self.names() {
            let listed = if prefixes.is_empty() {
                within(name)
            } else {
                prefixes.iter().any(|prefix| {
                    name == prefix
                        || name
                            .strip_prefix(prefix.as_str())
                            .and_then(|rest| rest.strip_prefix('.'))
                            .is_some_and(&within)
                })
            };
            if listed {
                result.names.push(name.to_owned());
                if let Some((section, _)) = name.rsplit_once('.')
                    && !result.prefixes.iter().any(|p| p == section)
                {
                    result.prefixes.push(section.to_owned());
                }
            }
        }
        result
    }

    /// `get_parameters`: each value, `NOT_SET` for a name not declared.
    pub fn get(&self, names: &[String]) -> Vec<ParameterValue> {
        let tree = serde_norway::to_value(&self.config).unwrap_or(Value::Null);
        names
            .iter()
            .map(
                |name| match (self.declared_type(name), lookup(&tree, name)) {
                    (Some(ptype), Some(leaf)) => to_parameter_value(leaf, ptype),
                    _ => not_set(),
                },
            )
            .collect()
    }

    /// `get_parameter_types`: each type, `NOT_SET` for a name not declared.
    pub fn get_types(&self, names: &[String]) -> Vec<u8> {
        names
            .iter()
            .map(|name| self.declared_type(name).unwrap_or(ParameterType::NOT_SET))
            .collect()
    }

    /// `describe_parameters`: each descriptor; a name not declared gets an empty one of type
    /// `NOT_SET`, as rclcpp answers when undeclared parameters are allowed (it refuses the
    /// request otherwise; an answer per name is more use to a caller).
    pub fn describe(&self, names: &[String]) -> Vec<ParameterDescriptor> {
        names
            .iter()
            .map(|name| {
                let rule = self.rules.get(name.as_str()).map_or("", String::as_str);
                let ptype = self.declared_type(name);
                let (floating_point_range, integer_range) = match ptype {
                    Some(ParameterType::DOUBLE) => (self.float_range(name).into_iter().collect(), Vec::new()),
                    Some(ParameterType::INTEGER) => (Vec::new(), self.integer_range(name).into_iter().collect()),
                    _ => (Vec::new(), Vec::new()),
                };
                ParameterDescriptor {
                    name: name.clone(),
                    r#type: ptype.unwrap_or(ParameterType::NOT_SET),
                    description: self.description(name),
                    additional_constraints: match (ptype, is_live(name)) {
                        (None, _) => String::new(),
                        (Some(_), true) => rule.to_owned(),
                        (Some(_), false) => {
                            let restart = "read-only: takes effect when the node starts (-p NAME:=VALUE or a params file)";
                            if rule.is_empty() {
                                restart.to_owned()
                            } else {
                                format!("{rule}; {restart}")
                            }
                        }
                    },
                    read_only: ptype.is_some() && !is_live(name),
                    dynamic_typing: false,
                    floating_point_range,
                    integer_range,
                }
            })
            .collect()
    }

    /// The closed interval a real parameter is checked against, if its range is closed.
    fn float_range(&self, name: &str) -> Option<FloatingPointRange> {
        let (from_value, to_value) = self.ranges.get(name)?.closed()?;
        Some(FloatingPointRange {
            from_value,
            to_value,
            step: 0.0,
        })
    }

    /// The interval a count parameter is checked against.
    fn integer_range(&self, name: &str) -> Option<IntegerRange> {
        let (from, to) = self.count_ranges.get(name)?.interval();
        Some(IntegerRange {
            from_value: i64::from(from),
            to_value: i64::from(to),
            step: 1,
        })
    }

    /// A parameter's description: the shipped file's comment, and for a camera source added
    /// by name, the same key's of `sources.unknown`.
    fn description(&self, name: &str) -> String {
        let shipped = self.descriptions.get(name).cloned();
        shipped
            .or_else(|| {
                let (source, key) = name.strip_prefix("sources.")?.split_once('.')?;
                if key == "id" {
                    return Some(format!(
                        "The BallDetection.source of camera source `{source}`'s detections [-]."
                    ));
                }
                let unknown = self
                    .descriptions
                    .get(&format!("sources.{UNKNOWN_SOURCE}.{key}"))?;
                Some(format!("{unknown} (camera source `{source}`)"))
            })
            .unwrap_or_default()
    }

    /// `set_parameters`: each parameter set on its own, in order (each checked against the
    /// configuration as the ones before it left it); one result per parameter, and the change
    /// if any was accepted.
    pub fn set(&mut self, parameters: &[Parameter]) -> (Vec<SetParametersResult>, Option<Change>) {
        let previous = self.config.clone();
        let mut changed = Vec::new();
        let results = parameters
            .iter()
            .map(|p| match self.checked(std::slice::from_ref(p)) {
                Ok(config) => {
                    self.config = config;
                    changed.push(p.clone());
                    accepted()
                }
                Err(why) => refused(&why),
            })
            .collect();
        let change = (!changed.is_empty()).then_some(Change { previous, changed });
        (results, change)
    }

    /// `set_parameters_atomically`: all or none, the configuration checked as a whole.
    pub fn set_atomically(
        &mut self,
        parameters: &[Parameter],
    ) -> (SetParametersResult, Option<Change>) {
        match self.checked(parameters) {
            Ok(config) => {
                let previous = std::mem::replace(&mut self.config, config);
                let change = (!parameters.is_empty()).then(|| Change {
                    previous,
                    changed: parameters.to_vec(),
                });
                (accepted(), change)
            }
            Err(why) => (refused(&why), None),
        }
    }

    /// The configuration with `parameters` set, or why not.
    fn checked(&self, parameters: &[Parameter]) -> Result<Config, Refusal> {
        let mut values = Vec::with_capacity(parameters.len());
        for p in parameters {
            let Some(declared) = self.declared_type(&p.name) else {
                return Err(Refusal::NotDeclared {
                    name: p.name.clone(),
                });
            };
            if !is_live(&p.name) {
                return Err(Refusal::ReadOnly {
                    name: p.name.clone(),
                });
            }
            values.push((p.name.clone(), to_yaml(&p.name, &p.value, declared)?));
        }
        yaml::with_values(&self.config, &values).map_err(Refusal::Invalid)
    }

    /// The event that announces every parameter (`new_parameters`), when the node starts.
    pub fn declared_event(
        &self,
        stamp: ros2_client::builtin_interfaces::Time,
        node: &str,
    ) -> ParameterEvent {
        let names: Vec<String> = self.names().map(str::to_owned).collect();
        let values = self.get(&names);
        ParameterEvent {
            stamp,
            node: node.to_owned(),
            new_parameters: names
                .into_iter()
                .zip(values)
                .map(|(name, value)| Parameter { name, value })
                .collect(),
            changed_parameters: Vec::new(),
            deleted_parameters: Vec::new(),
        }
    }
}

/// The event that reports `change`.
pub fn change_event(
    change: &Change,
    stamp: ros2_client::builtin_interfaces::Time,
    node: &str,
) -> ParameterEvent {
    ParameterEvent {
        stamp,
        node: node.to_owned(),
        new_parameters: Vec::new(),
        changed_parameters: change.changed.clone(),
        deleted_parameters: Vec::new(),
    }
}

fn accepted() -> SetParametersResult {
    SetParametersResult {
        successful: true,
        reason: String::new(),
    }
}

fn refused(why: &Refusal) -> SetParametersResult {
    SetParametersResult {
        successful: false,
        reason: why.to_string(),
    }
}

/// Why a parameter change is refused; its `Display` is the `reason` the caller gets.
#[derive(Debug, thiserror::Error)]
pub enum Refusal {
    /// No parameter has this name.
    #[error("parameter '{name}' is not declared: `ros2 param list` shows the node's parameters")]
    NotDeclared {
        /// The name.
        name: String,
    },
    /// The parameter takes effect only when the node starts.
    #[error(
        "parameter '{name}' is read-only: it takes effect when the node starts; restart it with -p {name}:=VALUE"
    )]
    ReadOnly {
        /// The name.
        name: String,
    },
    /// A parameter cannot be unset.
    #[error("parameter '{name}' cannot be unset: every parameter of ttball has a value")]
    Unset {
        /// The name.
        name: String,
    },
    /// The value is of another type than the parameter's.
    #[error("parameter '{name}' is {declared}, not {found}")]
    WrongType {
        /// The name.
        name: String,
        /// The parameter's type, in words ("a double").
        declared: &'static str,
        /// The value's type, in words.
        found: &'static str,
    },
    /// The configuration with the new values is not valid.
    #[error(transparent)]
    Invalid(yaml::LoadError),
}

/// Calls `f(dotted name, leaf)` for every leaf under `value`.
fn leaves(value: &Value, prefix: &str, f: &mut dyn FnMut(String, &Value)) {
    match value {
        Value::Mapping(map) => {
            for (k, v) in map {
                let key = k.as_str().unwrap_or_default();
                let name = if prefix.is_empty() {
                    key.to_owned()
                } else {
                    format!("{prefix}.{key}")
                };
                leaves(v, &name, f);
            }
        }
        leaf => f(prefix.to_owned(), leaf),
    }
}

fn lookup<'a>(tree: &'a Value, name: &str) -> Option<&'a Value> {
    name.split('.').try_fold(tree, |node, key| node.get(key))
}

/// The ROS 2 type of a configuration value (every list of the configuration is of reals).
fn type_of(leaf: &Value) -> u8 {
    match leaf {
        Value::Bool(_) => ParameterType::BOOL,
        Value::Number(n) if n.is_f64() => ParameterType::DOUBLE,
        Value::Number(_) => ParameterType::INTEGER,
        Value::String(_) => ParameterType::STRING,
        Value::Sequence(_) => ParameterType::DOUBLE_ARRAY,
        _ => ParameterType::NOT_SET,
    }
}

fn not_set() -> ParameterValue {
    empty_value(ParameterType::NOT_SET)
}

/// A value of type `ptype` with every field zero or empty.
pub(crate) fn empty_value(ptype: u8) -> ParameterValue {
    ParameterValue {
        ptype,
        boolean_value: false,
        int_value: 0,
        double_value: 0.0,
        string_value: String::new(),
        byte_array: Vec::new(),
        bool_array: Vec::new(),
        int_array: Vec::new(),
        double_array: Vec::new(),
        string_array: Vec::new(),
    }
}

fn to_parameter_value(leaf: &Value, ptype: u8) -> ParameterValue {
    let mut value = empty_value(ptype);
    match ptype {
        ParameterType::BOOL => value.boolean_value = leaf.as_bool().unwrap_or_default(),
        ParameterType::INTEGER => value.int_value = leaf.as_i64().unwrap_or_default(),
        ParameterType::DOUBLE => value.double_value = leaf.as_f64().unwrap_or_default(),
        ParameterType::STRING => value.string_value = leaf.as_str().unwrap_or_default().to_owned(),
        ParameterType::DOUBLE_ARRAY => {
            value.double_array = leaf
                .as_sequence()
                .map(|items| items.iter().filter_map(Value::as_f64).collect())
                .unwrap_or_default();
        }
        _ => {}
    }
    value
}

/// A value set on parameter `name` of type `declared` as the configuration's YAML, or why it is
/// refused. An integer is taken for a real (`ros2 param set /ttball intercept.plane_x -1`).
fn to_yaml(name: &str, value: &ParameterValue, declared: u8) -> Result<Value, Refusal> {
    let real = |x: f64| Value::Number(x.into());
    match (declared, value.ptype) {
        (ParameterType::BOOL, ParameterType::BOOL) => Ok(Value::Bool(value.boolean_value)),
        (ParameterType::INTEGER, ParameterType::INTEGER) => {
            Ok(Value::Number(value.int_value.into()))
        }
        (ParameterType::DOUBLE, ParameterType::DOUBLE) => Ok(real(value.double_value)),
        (ParameterType::DOUBLE, ParameterType::INTEGER) => Ok(real(value.int_value as f64)),
        (ParameterType::STRING, ParameterType::STRING) => {
            Ok(Value::String(value.string_value.clone()))
        }
        (ParameterType::DOUBLE_ARRAY, ParameterType::DOUBLE_ARRAY) => Ok(Value::Sequence(
            value.double_array.iter().map(|x| real(*x)).collect(),
        )),
        (ParameterType::DOUBLE_ARRAY, ParameterType::INTEGER_ARRAY) => Ok(Value::Sequence(
            value.int_array.iter().map(|x| real(*x as f64)).collect(),
        )),
        (_, ParameterType::NOT_SET) => Err(Refusal::Unset {
            name: name.to_owned(),
        }),
        (declared, found) => Err(Refusal::WrongType {
            name: name.to_owned(),
            declared: type_name(declared),
            found: type_name(found),
        }),
    }
}

fn type_name(ptype: u8) -> &'static str {
    match ptype {
        ParameterType::BOOL => "a bool",
        ParameterType::INTEGER => "an integer",
        ParameterType::DOUBLE => "a double",
        ParameterType::STRING => "a string",
        ParameterType::BYTE_ARRAY => "a byte array",
        ParameterType::BOOL_ARRAY => "a bool array",
        ParameterType::INTEGER_ARRAY => "an integer array",
        ParameterType::DOUBLE_ARRAY => "a double array",
        ParameterType::STRING_ARRAY => "a string array",
        _ => "not set",
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn double(x: f64) -> ParameterValue {
        ParameterValue {
            double_value: x,
            ..empty_value(ParameterType::DOUBLE)
        }
    }

    fn param(name: &str, value: ParameterValue) -> Parameter {
        Parameter {
            name: name.to_owned(),
            value,
        }
    }

    #[test]
    fn every_key_is_declared_with_its_type_and_value() {
        let p = Parameters::new(&Config::default());
        let names: Vec<&str> = p.names().collect();
        assert_eq!(names, yaml::parameter_names(&Config::default()));
        let asked = [
            "table.restitution",
            "gating.max_consecutive_rejections",
            "node.name",
            "aero.drag_coefficients",
            "use_sim_time",
            "nope",
        ]
        .map(str::to_owned);
        assert_eq!(p.get_types(&asked), [3, 2, 4, 8, 1, 0]);
        let values = p.get(&asked);
        assert_eq!(values[0].double_value, 0.9);
        assert_eq!(values[1].int_value, 5);
        assert_eq!(values[2].string_value, "ttball");
        assert_eq!(values[3].double_array, [0.42, 0.15]);
        assert!(!values[4].boolean_value);
        assert_eq!(values[5].ptype, ParameterType::NOT_SET);
        let d = p.describe(&asked);
        assert!(
            d[0].read_only && d[0].description.contains("[-]"),
            "{:?}",
            d[0]
        );
        assert!(!d[1].read_only);
        assert_eq!(
            (
                d[1].integer_range[0].from_value,
                d[1].integer_range[0].to_value
            ),
            (1, i64::from(u32::MAX))
        );
        // A count with both limits: a source's id (parsed as a byte).
        let counts = p.describe(&["sources.wide_150fps.id".to_owned()]);
        let interval =
            |d: &ParameterDescriptor| (d.integer_range[0].from_value, d.integer_range[0].to_value);
        assert_eq!(interval(&counts[0]), (0, 255));
        assert!(
            counts[0]
                .additional_constraints
                .starts_with("between 0 and 255"),
            "{:?}",
            counts[0]
        );
        assert!(d[2].read_only);
        assert_eq!(d[5].r#type, ParameterType::NOT_SET);
        let sigma = &p.describe(&["sources.wide_150fps.stamp_sigma".to_owned()])[0];
        assert_eq!(
            (
                sigma.floating_point_range[0].from_value,
                sigma.floating_point_range[0].to_value
            ),
            (0.0, 0.1)
        );
    }

    #[test]
    fn list_follows_rclcpp() {
        let p = Parameters::new(&Config::default());
        let top = p.list(&[], 1);
        assert_eq!(top.names, ["gravity", "use_sim_time"]);
        let intercept = p.list(&["intercept".to_owned()], 1);
        assert_eq!(intercept.names, ["intercept.plane_x"]);
        let intercept = p.list(&["intercept".to_owned()], 0);
        assert!(
            intercept
                .names
                .contains(&"intercept.refresh.max_age".to_owned())
        );
        assert!(intercept.prefixes.contains(&"intercept.refresh".to_owned()));
        assert_eq!(p.list(&[], 0).names.len(), p.names().count());
    }

    /// `use_sim_time` may be switched on the running node, as in rclcpp; the node's other
    /// top-level keys may not.
    #[test]
    fn use_sim_time_is_live() {
        let mut p = Parameters::new(&Config::default());
        let on = ParameterValue {
            boolean_value: true,
            ..empty_value(ParameterType::BOOL)
        };
        let (results, change) = p.set(&[param("use_sim_time", on)]);
        assert!(results[0].successful, "{}", results[0].reason);
        assert!(p.config().use_sim_time);
        assert!(change.is_some());
        let described = p.describe(&["use_sim_time".to_owned(), "gravity".to_owned()]);
        assert!(!described[0].read_only);
        assert!(described[1].read_only);
    }

    #[test]
    fn sets_are_checked_and_refusals_change_nothing() {
        let mut p = Parameters::new(&Config::default());
        let (results, change) = p.set(&[
            param("intercept.plane_x", double(-1.45)),
            param("table.restitution", double(0.8)),
            param("gating.probability", double(2.0)),
            param("gating.max_consecutive_rejections", double(5.0)),
            param("nope", double(1.0)),
            param(
                "tracking.timeout",
                ParameterValue {
                    int_value: 1,
                    ..empty_value(ParameterType::INTEGER)
                },
            ),
        ]);
        let ok: Vec<bool> = results.iter().map(|r| r.successful).collect();
        assert_eq!(ok, [true, false, false, false, false, true]);
        // Why each was refused, as a variant; the reason the caller gets is its text.
        let why = |name: &str, value: ParameterValue| {
            Parameters::new(&Config::default())
                .checked(&[param(name, value)])
                .unwrap_err()
        };
        assert!(matches!(
            why("table.restitution", double(0.8)),
            Refusal::ReadOnly { name } if name == "table.restitution"
        ));
        assert!(matches!(
            why("gating.probability", double(2.0)),
            Refusal::Invalid(_)
        ));
        assert!(matches!(
            why("gating.max_consecutive_rejections", double(5.0)),
            Refusal::WrongType {
                declared: "an integer",
                found: "a double",
                ..
            }
        ));
        assert!(matches!(
            why("nope", double(1.0)),
            Refusal::NotDeclared { name } if name == "nope"
        ));
        assert_eq!(
            results[1].reason,
            why("table.restitution", double(0.8)).to_string()
        );
        assert!(
            results[1].reason.contains("read-only"),
            "{}",
            results[1].reason
        );
        assert!(
            results[2].reason.contains("gating.probability"),
            "{}",
            results[2].reason
        );
        assert!(
            results[3].reason.contains("is an integer, not a double"),
            "{}",
            results[3].reason
        );
        assert!(
            results[4].reason.contains("not declared"),
            "{}",
            results[4].reason
        );
        assert_eq!(p.config().intercept.plane_x, -1.45);
        assert_eq!(p.config().tracking.timeout, 1.0);
        let change = change.unwrap();
        assert_eq!(change.previous, Config::default());
        assert_eq!(change.changed.len(), 2);

        // Atomically: one bad value refuses all.
        let before = p.config().clone();
        let (result, change) = p.set_atomically(&[
            param("intercept.plane_x", double(-1.3)),
            param("tracking.coast_after", double(5.0)),
        ]);
        assert!(!result.successful && change.is_none(), "{result:?}");
        assert!(
            result.reason.contains("tracking.coast_after"),
            "{}",
            result.reason
        );
        assert_eq!(p.config(), &before);
        let (result, change) = p.set_atomically(&[param("intercept.plane_x", double(-1.3))]);
        assert!(result.successful && change.is_some());
        assert_eq!(p.config().intercept.plane_x, -1.3);
    }
}
