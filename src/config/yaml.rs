//! Loading the configuration from a ROS 2 parameters file and `-p NAME:=VALUE` overrides, and
//! printing it back as one.
//!
//! The file format is the one rclcpp reads:
//!
//! ```yaml
//! ttball:              # or /ttball, /robot1/ttball, /**, /**/ttball, or nested namespaces
//!   ros__parameters:
//!     table:
//!       restitution: 0.9   # nested maps join into the dotted name `table.restitution`
//! ```
//!
//! A file's sections are matched against the node's fully qualified name as rclcpp matches them
//! ([`super::names::node_key_matches`]); sections of other nodes are ignored, and every section
//! that applies is applied in the file's order. Layers, each overriding the one before:
//! [`Config::default`], then the files and `-p` overrides in the order given ([`load_layers`];
//! `-p node:NAME:=VALUE` applies to that node only). The result is checked
//! strictly: an unknown key (with a "did you mean" suggestion), a value of the wrong type and a
//! value out of range ([`Config::validate`]) are all reported at once, each naming its dotted key
//! and where it was set.

use std::collections::HashMap;
use std::fmt;
use std::path::{Path, PathBuf};

use serde_norway::Value;
use thiserror::Error;

use super::names::token_problem;
use super::{Config, ConfigError, UNKNOWN_SOURCE, Violation};

/// The node name `ttball config print` writes at the top of a parameters file.
pub const NODE_KEY: &str = "ttball";

/// The key under the node name that holds the parameters (rclcpp).
pub const ROS_PARAMETERS: &str = "ros__parameters";

/// Where a parameter's value was set.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Origin {
    /// A parameters file.
    File {
        /// The file, as given.
        path: PathBuf,
        /// 1-based line of the key, when it could be found.
        line: Option<usize>,
    },
    /// A `-p NAME:=VALUE` override.
    Override {
        /// The override as given (`NAME:=VALUE`).
        arg: String,
    },
    /// A parameter set on the running node (rcl_interfaces `set_parameters`).
    Set {
        /// The parameter's name.
        name: String,
    },
}

impl fmt::Display for Origin {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::File {
                path,
                line: Some(line),
            } => write!(f, "{}:{line}", path.display()),
            Self::File { path, line: None } => write!(f, "{}", path.display()),
            Self::Override { arg } => write!(f, "-p {arg}"),
            Self::Set { name } => write!(f, "set {name}"),
        }
    }
}

/// One problem in a configuration. Loading collects all of them before it fails.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum Problem {
    /// The file is not laid out as a ROS 2 parameters file.
    #[error("{origin}: {message}")]
    Layout {
        /// Where.
        origin: Origin,
        /// What is wrong and what is expected.
        message: String,
    },
    /// A key that the configuration does not have.
    #[error(
        "{origin}: unknown parameter `{key}`; {}",
        match .suggestion {
            Some(s) => format!("did you mean `{s}`?"),
            None => "`ttball config print` lists every parameter".to_owned(),
        }
    )]
    UnknownKey {
        /// The full dotted key, as written.
        key: String,
        /// Where it was written.
        origin: Origin,
        /// The closest known key, if one is close.
        suggestion: Option<String>,
    },
    /// A value of the wrong type.
    #[error("{origin}: `{key}` must be {expected}, but is {found}")]
    WrongType {
        /// The full dotted key.
        key: String,
        /// Where the value was set.
        origin: Origin,
        /// The expected type, with the default value as an example.
        expected: String,
        /// What was found.
        found: String,
    },
    /// A `-p` argument that is not `NAME:=VALUE`.
    #[error("-p {arg}: {reason}")]
    BadOverride {
        /// The argument as given.
        arg: String,
        /// What is wrong and what is expected.
        reason: String,
    },
    /// A value out of range ([`Config::validate`]).
    #[error(
        "{}{violation}",
        match .origin {
            Some(origin) => format!("{origin}: "),
            None => String::new(),
        }
    )]
    OutOfRange {
        /// The range check that failed.
        violation: Violation,
        /// Where the offending value was set; `None` for a default.
        origin: Option<Origin>,
    },
}

/// Why a configuration could not be loaded.
#[derive(Debug, Error)]
pub enum LoadError {
    /// The configuration file does not exist.
    #[error(
        "configuration file `{}` does not exist; check the path \
         (`ttball config print > FILE` writes the defaults to start from)",
        .path.display()
    )]
    NotFound {
        /// The path as given.
        path: PathBuf,
    },
    /// The configuration file could not be read.
    #[error("cannot read configuration file `{}`: {error}", .path.display())]
    Read {
        /// The path as given.
        path: PathBuf,
        /// The I/O error (in the message, not its source: said once in a chain).
        error: std::io::Error,
    },
    /// The configuration file is not valid YAML.
    #[error("{}: not valid YAML: {message}", .path.display())]
    Syntax {
        /// The path as given.
        path: PathBuf,
        /// 1-based line of the error, when known.
        line: Option<usize>,
        /// The YAML parser's message (with line and column).
        message: String,
    },
    /// The configuration has problems: unknown keys, wrong types, values out of range.
    #[error(
        "the configuration has {} problem{}:{}",
        .problems.len(),
        if .problems.len() == 1 { "" } else { "s" },
        .problems.iter().map(|p| format!("\n  - {p}")).collect::<String>()
    )]
    Rejected {
        /// Every problem found.
        problems: Vec<Problem>,
    },
    /// The default configuration could not be turned into YAML (a bug).
    #[error("internal error: cannot serialise the default configuration: {message}")]
    Internal {
        /// The serialiser's message.
        message: String,
    },
}

/// One layer of the configuration ([`load_layers`]).
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Layer {
    /// A ROS 2 parameters file (`--config`, `--params-file`).
    File(PathBuf),
    /// A `NAME:=VALUE` override (`-p`), the value parsed as YAML; `node:NAME:=VALUE` applies only
    /// to that node.
    Param(String),
}

/// How the first line of a learned configuration file (`--learned`) begins, before who wrote
/// it: "# Written by WHO: what the estimator learned; ...".
pub const LEARNED_FILE_START: &str = "# Written by ";

/// What that first line says after who wrote it.
pub const LEARNED_FILE_MARK: &str = ": what the estimator learned";

/// Whether the file at `path` is a learned configuration (its first line,
/// [`LEARNED_FILE_START`] and [`LEARNED_FILE_MARK`]);
/// false when it cannot be read.
pub fn is_learned_file(path: &Path) -> bool {
    use std::io::BufRead;
    let Ok(file) = std::fs::File::open(path) else {
        return false;
    };
    let mut first = String::new();
    std::io::BufReader::new(file).read_line(&mut first).is_ok()
        && first.starts_with(LEARNED_FILE_START)
        && first.contains(LEARNED_FILE_MARK)
}

/// `layers` without the learned configuration files among them ([`is_learned_file`]): the
/// configuration a run's own learning is told apart from. A learned file compared against a
/// configuration that holds an earlier one would drop every value learned then and not moved
/// since (a camera that sent nothing this run).
pub fn without_learned_files(layers: &[Layer]) -> Vec<Layer> {
    layers
        .iter()
        .filter(|layer| !matches!(layer, Layer::File(path) if is_learned_file(path)))
        .cloned()
        .collect()
}

/// Loads the configuration: defaults, then `file` if given, then `overrides` (`NAME:=VALUE`,
/// the value parsed as YAML), then [`Config::validate`]; the file's sections that apply to the
/// node the configuration names (`node.namespace`, `node.name`).
///
/// ```no_run
/// # use std::path::Path;
/// let config = ttball::config::yaml::load(
///     Some(Path::new("config/ttball.yaml")),
///     &["intercept.plane_x:=-1.45"],
/// )?;
/// assert_eq!(config.intercept.plane_x, -1.45);
/// # Ok::<(), ttball::config::yaml::LoadError>(())
/// ```
pub fn load<S: AsRef<str>>(file: Option<&Path>, overrides: &[S]) -> Result<Config, LoadError> {
    let layers: Vec<Layer> = file
        .map(|path| Layer::File(path.to_owned()))
        .into_iter()
        .chain(
            overrides
                .iter()
                .map(|o| Layer::Param(o.as_ref().to_owned())),
        )
        .collect();
    load_layers(&layers, None)
}

/// Loads the configuration from `layers` in order, each overriding the ones before, then
/// [`Config::validate`]. Files' sections and `node:NAME:=VALUE` overrides apply when they name
/// the node `node_fqn` (its fully qualified name, e.g. `/robot1/ttball`, as remaps make it);
/// `None`: the node the configuration itself names (`node.namespace`, `node.name`; found in a
/// second pass when the layers rename it).
pub fn load_layers(layers: &[Layer], node_fqn: Option<&str>) -> Result<Config, LoadError> {
    let mut sources = Vec::with_capacity(layers.len());
    for layer in layers {
        sources.push(match layer {
            Layer::File(path) => Source::Text {
                text: read_file(path)?,
                path: path.clone(),
            },
            Layer::Param(arg) => Source::Param(arg.clone()),
        });
    }
    load_sources(&sources, node_fqn)
}

/// Like [`load`], with the file's contents given as `text`; `path` only names it in messages.
pub fn load_str<S: AsRef<str>>(
    text: &str,
    path: &Path,
    overrides: &[S],
) -> Result<Config, LoadError> {
    let sources: Vec<Source> = std::iter::once(Source::Text {
        text: text.to_owned(),
        path: path.to_owned(),
    })
    .chain(
        overrides
            .iter()
            .map(|o| Source::Param(o.as_ref().to_owned())),
    )
    .collect();
    load_sources(&sources, None)
}

/// `config` with the parameters `values` set (dotted names, YAML values), type-checked and
/// validated as a whole: what the node's `set_parameters` does. Every problem is reported.
pub fn with_values(config: &Config, values: &[(String, Value)]) -> Result<Config, LoadError> {
    let mut loader = Loader::new(config)?;
    for (name, value) in values {
        let origin = Origin::Set { name: name.clone() };
        for entry in entries_of(name, value, &origin) {
            loader.apply(entry);
        }
    }
    loader.finish()
}

fn read_file(path: &Path) -> Result<String, LoadError> {
    std::fs::read_to_string(path).map_err(|source| {
        if source.kind() == std::io::ErrorKind::NotFound {
            LoadError::NotFound {
                path: path.to_owned(),
            }
        } else {
            LoadError::Read {
                path: path.to_owned(),
                error: source,
            }
        }
    })
}

/// A layer's contents.
enum Source {
    Text { text: String, path: PathBuf },
    Param(String),
}

fn load_sources(sources: &[Source], node_fqn: Option<&str>) -> Result<Config, LoadError> {
    let default_fqn = Config::default().node_fqn();
    let fqn = node_fqn.unwrap_or(&default_fqn);
    let config = load_sources_for(sources, fqn)?;
    match node_fqn {
        // The layers named the node otherwise: load again with the sections of that node.
        None if config.node_fqn() != fqn => load_sources_for(sources, &config.node_fqn()),
        _ => Ok(config),
    }
}

fn load_sources_for(sources: &[Source], node_fqn: &str) -> Result<Config, LoadError> {
    let mut loader = Loader::new(&Config::default())?;
    for source in sources {
        match source {
            Source::Text { text, path } => {
                let document: Value =
                    serde_norway::from_str(text).map_err(|e| LoadError::Syntax {
                        path: path.to_owned(),
                        line: e.location().map(|l| l.line()),
                        message: e.to_string(),
                    })?;
                for entry in file_entries(&document, text, path, node_fqn, &mut loader.problems) {
                    loader.apply(entry);
                }
            }
            Source::Param(arg) => match parse_override(arg, node_fqn) {
                Ok(Some(entry)) => {
                    for e in entries_of_entry(&entry) {
                        loader.apply(e);
                    }
                }
                // For another node.
                Ok(None) => {}
                Err(reason) => loader.problems.push(Problem::BadOverride {
                    arg: arg.clone(),
                    reason,
                }),
            },
        }
    }
    loader.finish()
}

/// The leaf entries under an override's value (a map value sets every key under it).
fn entries_of_entry(entry: &Entry) -> Vec<Entry> {
    let mut entries = Vec::new();
    flatten(&entry.value, &entry.key, &mut |key, value| {
        entries.push(Entry {
            key,
            value: value.clone(),
            origin: entry.origin.clone(),
        });
    });
    entries
}

fn entries_of(name: &str, value: &Value, origin: &Origin) -> Vec<Entry> {
    entries_of_entry(&Entry {
        key: name.split('.').map(str::to_owned).collect(),
        value: value.clone(),
        origin: origin.clone(),
    })
}

/// The configuration as a ROS 2 parameters file (`ttball: ros__parameters: ...`, or `"/**":` when
/// it renames the node), every parameter listed; real numbers always carry a decimal point or exponent so they load back as doubles.
/// [`load_str`] of the result gives `config` back.
pub fn to_ros_params_yaml(config: &Config) -> String {
    match serde_norway::to_value(config) {
        Ok(params) => {
            let mut out = String::new();
            out.push_str(section_key(config));
            out.push_str(":\n  ");
            out.push_str(ROS_PARAMETERS);
            out.push_str(":\n");
            emit_mapping(&mut out, &params, 4);
            out
        }
        // Not reachable for plain data; written so that it cannot load as a configuration.
        Err(e) => format!("@ cannot serialise the configuration: {e}\n"),
    }
}

/// The section a parameters file for `config`'s node is headed by: the node's name, or the
/// wildcard for a node renamed (its sections are matched against the name before a file
/// renames it, so such a file is found by the wildcard only).
fn section_key(config: &Config) -> &'static str {
    if config.node_fqn() == Config::default().node_fqn() {
        NODE_KEY
    } else {
        "\"/**\""
    }
}

/// The parameters of `changed` that differ from `base`'s, as a ROS 2 parameters file (headed
/// like [`to_ros_params_yaml`]'s): layered over `base` (`--config`), it gives `changed`.
pub fn changed_params_yaml(base: &Config, changed: &Config) -> String {
    match (
        serde_norway::to_value(base),
        serde_norway::to_value(changed),
    ) {
        (Ok(base_value), Ok(changed_value)) => {
            let mut out = String::new();
            out.push_str(section_key(changed));
            out.push_str(":\n  ");
            out.push_str(ROS_PARAMETERS);
            out.push_str(":\n");
            emit_mapping(&mut out, &difference(&base_value, &changed_value), 4);
            out
        }
        (Err(e), _) | (_, Err(e)) => format!("@ cannot serialise the configuration: {e}\n"),
    }
}

/// The leaves of `changed` whose values differ from `base`'s, in `changed`'s order (sections
/// with nothing changed left out).
fn difference(base: &Value, changed: &Value) -> Value {
    let (Value::Mapping(base), Value::Mapping(changed)) = (base, changed) else {
        return changed.clone();
    };
    let mut out = serde_norway::Mapping::new();
    for (key, value) in changed {
        match (base.get(key), value) {
            (Some(was), _) if was == value => {}
            (Some(was @ Value::Mapping(_)), Value::Mapping(_)) => {
                let inner = difference(was, value);
                if inner.as_mapping().is_some_and(|m| !m.is_empty()) {
                    out.insert(key.clone(), inner);
                }
            }
            _ => {
                out.insert(key.clone(), value.clone());
            }
        }
    }
    Value::Mapping(out)
}

/// Every parameter's dotted name (`table.restitution`), in the order of the configuration;
/// these are the names of the ROS 2 parameters and of `-p` overrides.
pub fn parameter_names(config: &Config) -> Vec<String> {
    let mut names = Vec::new();
    if let Ok(value) = serde_norway::to_value(config) {
        collect_names(&value, "", false, &mut names);
    }
    names
}

fn collect_names(value: &Value, prefix: &str, with_sections: bool, out: &mut Vec<String>) {
    if let Value::Mapping(map) = value {
        for (k, v) in map {
            let key = key_text(k);
            let name = if prefix.is_empty() {
                key
            } else {
                format!("{prefix}.{key}")
            };
            if v.is_mapping() {
                if with_sections {
                    out.push(name.clone());
                }
                collect_names(v, &name, with_sections, out);
            } else {
                out.push(name);
            }
        }
    }
}

/// The shipped `config/ttball.yaml`: every parameter with its default, unit and source.
pub const SHIPPED: &str = include_str!("../../config/ttball.yaml");

/// Every parameter's (and section's) description: the comment above its key in the shipped
/// `config/ttball.yaml`, joined into one paragraph, by dotted name. What the node's parameter
/// descriptors say of each.
pub fn descriptions() -> HashMap<String, String> {
    let mut out = HashMap::new();
    let mut stack: Vec<(usize, String)> = Vec::new();
    let mut comment: Vec<&str> = Vec::new();
    for line in SHIPPED.lines() {
        let trimmed = line.trim_start();
        if trimmed.is_empty() {
            comment.clear();
            continue;
        }
        if let Some(text) = trimmed.strip_prefix('#') {
            comment.push(text.trim());
            continue;
        }
        let Some(key) = leading_key(trimmed) else {
            comment.clear();
            continue;
        };
        let indent = line.len() - trimmed.len();
        while stack.last().is_some_and(|(i, _)| *i >= indent) {
            stack.pop();
        }
        stack.push((indent, key));
        // The node name and `ros__parameters` come first.
        if stack.len() > 2 && !comment.is_empty() {
            let name: Vec<&str> = stack[2..].iter().map(|(_, k)| k.as_str()).collect();
            out.insert(name.join("."), comment.join(" "));
        }
        comment.clear();
    }
    out
}

/// One value to apply: its dotted key split into segments, where it was written.
struct Entry {
    key: Vec<String>,
    value: Value,
    origin: Origin,
}

struct Loader {
    defaults: Value,
    merged: Value,
    known: Vec<String>,
    set_at: HashMap<String, Origin>,
    problems: Vec<Problem>,
    /// Camera sources the layers added (`sources.<name>`), with where each was first named.
    new_sources: Vec<(String, Origin)>,
    /// Every key a layer gave a value to, valid or not.
    given: std::collections::HashSet<String>,
}

impl Loader {
    /// A loader whose values start from `base`.
    fn new(base: &Config) -> Result<Self, LoadError> {
        let internal = |e: serde_norway::Error| LoadError::Internal {
            message: e.to_string(),
        };
        let defaults = serde_norway::to_value(Config::default()).map_err(internal)?;
        let merged = serde_norway::to_value(base).map_err(internal)?;
        let mut known = Vec::new();
        collect_names(&defaults, "", true, &mut known);
        Ok(Self {
            merged,
            defaults,
            known,
            set_at: HashMap::new(),
            problems: Vec::new(),
            new_sources: Vec::new(),
            given: std::collections::HashSet::new(),
        })
    }

    /// A camera source named for the first time (`sources.<name>.<key>`) is added, starting
    /// from the default `unknown` source's values; its `id` must then be set (checked in
    /// [`Loader::finish`]). A source the base configuration has is taken as it is.
    fn declare_source(&mut self, key: &[String], origin: &Origin) {
        let [section, name, ..] = key else {
            return;
        };
        if section != "sources" || token_problem(name).is_some() {
            return;
        }
        let name = Value::String(name.clone());
        let in_base = self
            .merged
            .get("sources")
            .and_then(|s| s.get(&name))
            .cloned();
        let (Some(Value::Mapping(defaults)), Some(Value::Mapping(merged))) = (
            self.defaults.get_mut("sources"),
            self.merged.get_mut("sources"),
        ) else {
            return;
        };
        if defaults.contains_key(&name) {
            return;
        }
        let Some(template) = in_base.or_else(|| defaults.get(UNKNOWN_SOURCE).cloned()) else {
            return;
        };
        if !merged.contains_key(&name) {
            self.new_sources
                .push((format!("sources.{}", key[1]), origin.clone()));
            merged.insert(name.clone(), template.clone());
        }
        defaults.insert(name, template);
    }

    /// Applies one value if its key exists and its type fits; records a problem otherwise.
    fn apply(&mut self, entry: Entry) {
        self.declare_source(&entry.key, &entry.origin);
        let dotted = entry.key.join(".");
        self.given.insert(dotted.clone());
        let mut node = &self.defaults;
        for (depth, segment) in entry.key.iter().enumerate() {
            match node {
                Value::Mapping(map) => match map.get(segment.as_str()) {
                    Some(child) => node = child,
                    None => {
                        let suggestion = suggest(&dotted, &self.known);
                        self.problems.push(Problem::UnknownKey {
                            key: dotted,
                            origin: entry.origin,
                            suggestion,
                        });
                        return;
                    }
                },
                leaf => {
                    self.problems.push(Problem::WrongType {
                        key: entry.key[..depth].join("."),
                        origin: entry.origin,
                        expected: describe_expected(leaf),
                        found: "a map".to_owned(),
                    });
                    return;
                }
            }
        }
        match (node, &entry.value) {
            // An empty section (`table:` with every key commented out) sets nothing.
            (Value::Mapping(_), Value::Null) => {}
            (Value::Mapping(_), found) => self.problems.push(Problem::WrongType {
                key: if dotted.is_empty() {
                    ROS_PARAMETERS.to_owned()
                } else {
                    dotted
                },
                origin: entry.origin,
                expected: "a section of parameters (a map)".to_owned(),
                found: describe_found(found),
            }),
            (leaf, value) => {
                // Probe the type by deserialising the defaults with only this value changed.
                let mut probe = self.defaults.clone();
                set(&mut probe, &entry.key, value.clone());
                if serde_norway::from_value::<Config>(probe).is_ok() {
                    set(&mut self.merged, &entry.key, entry.value);
                    self.set_at.insert(dotted, entry.origin);
                } else {
                    let expected = if dotted.starts_with("sources.") && dotted.ends_with(".id") {
                        "a whole number from 0 to 255 (a BallDetection.source)".to_owned()
                    } else {
                        describe_expected(leaf)
                    };
                    self.problems.push(Problem::WrongType {
                        key: dotted,
                        origin: entry.origin,
                        expected,
                        found: describe_found(value),
                    });
                }
            }
        }
    }

    fn finish(mut self) -> Result<Config, LoadError> {
        let mut not_sources = Vec::new();
        for (source, origin) in std::mem::take(&mut self.new_sources) {
            if !self.given.contains(&format!("{source}.id")) {
                not_sources.push(format!("{source}.id"));
                let known: Vec<String> = self
                    .known
                    .iter()
                    .filter(|k| k.starts_with("sources.") && k.matches('.').count() == 1)
                    .cloned()
                    .collect();
                self.problems.push(Problem::Layout {
                    origin,
                    message: format!(
                        "`{source}` is not a source; to add a camera, set `{source}.id` to the BallDetection.source its detections carry (3-255){}",
                        match suggest(&source, &known) {
                            Some(s) => format!(", or did you mean `{s}`?"),
                            None => String::new(),
                        }
                    ),
                });
            }
        }
        match serde_norway::from_value::<Config>(self.merged) {
            Ok(config) => {
                if let Err(ConfigError::Invalid { violations }) = config.validate() {
                    // A misspelt source is reported as such, not for the id it never had, and a
                    // value of the wrong type not again for the default left in its place.
                    let wrong_type: Vec<String> = self
                        .problems
                        .iter()
                        .filter_map(|p| match p {
                            Problem::WrongType { key, .. } => Some(key.clone()),
                            _ => None,
                        })
                        .collect();
                    for violation in violations
                        .into_iter()
                        .filter(|v| !not_sources.iter().chain(&wrong_type).any(|k| k == v.key()))
                    {
                        let key = violation.key();
                        let key = key.split_once('[').map_or(key, |(k, _)| k);
                        let mut origin = self.set_at.get(key).cloned();
                        if let Violation::Exceeds { limit_key, .. } = &violation {
                            // A default exceeded by a limit that was set: point at the limit.
                            origin = origin.or_else(|| self.set_at.get(limit_key).cloned());
                        }
                        self.problems
                            .push(Problem::OutOfRange { violation, origin });
                    }
                }
                if self.problems.is_empty() {
                    Ok(config)
                } else {
                    Err(LoadError::Rejected {
                        problems: self.problems,
                    })
                }
            }
            // Every value was type-checked on its own, so this is not expected.
            Err(e) => Err(LoadError::Internal {
                message: e.to_string(),
            }),
        }
    }
}

/// Sets `root[key[0]][key[1]]... = value`; the path exists (checked against the defaults).
fn set(root: &mut Value, key: &[String], value: Value) {
    let mut node = root;
    for segment in key {
        match node.get_mut(segment.as_str()) {
            Some(child) => node = child,
            None => return,
        }
    }
    *node = value;
}

/// The closest known dotted key to `key`, if it is close enough to be a likely typo; failing
/// that, a known key with the same last segment (a parameter put in the wrong section).
fn suggest(key: &str, known: &[String]) -> Option<String> {
    let best = known
        .iter()
        .map(|k| (strsim::normalized_damerau_levenshtein(key, k), k))
        .max_by(|a, b| a.0.total_cmp(&b.0));
    if let Some((score, k)) = best
        && score >= 0.7
    {
        return Some(k.clone());
    }
    let last = key.rsplit('.').next().unwrap_or(key);
    known
        .iter()
        .find(|k| k.rsplit('.').next() == Some(last))
        .cloned()
}

fn describe_expected(default: &Value) -> String {
    match default {
        Value::Bool(_) => "true or false".to_owned(),
        Value::Number(n) if n.is_f64() => {
            format!(
                "a real number (default {})",
                format_float(n.as_f64().unwrap_or(0.0))
            )
        }
        Value::Number(n) => format!("a whole number from 0 to {} (default {n})", u32::MAX),
        Value::String(s) => format!("a string (default {})", quote(s)),
        Value::Sequence(_) => format!("a list of real numbers (default {})", scalar(default)),
        Value::Mapping(_) => "a section of parameters (a map)".to_owned(),
        Value::Null | Value::Tagged(_) => "a value".to_owned(),
    }
}

fn describe_found(value: &Value) -> String {
    match value {
        Value::Null => "empty (no value)".to_owned(),
        Value::Bool(b) => format!("the boolean `{b}`"),
        Value::Number(n) if n.is_f64() => format!("the real number `{n}`"),
        Value::Number(n) => format!("the integer `{n}`"),
        Value::String(s) => format!("the string {}", quote(s)),
        Value::Sequence(_) => "a list".to_owned(),
        Value::Mapping(_) => "a map".to_owned(),
        Value::Tagged(t) => format!("a value tagged `{}`", t.tag),
    }
}

fn key_text(key: &Value) -> String {
    match key {
        Value::String(s) => s.clone(),
        Value::Number(n) => n.to_string(),
        Value::Bool(b) => b.to_string(),
        Value::Null => "~".to_owned(),
        other => describe_found(other),
    }
}

/// Calls `f(dotted key segments, value)` for every non-map value under `value` (and for a null
/// one); keys with dots are split, as rclcpp joins nested keys with dots.
fn flatten(value: &Value, prefix: &[String], f: &mut dyn FnMut(Vec<String>, &Value)) {
    match value {
        Value::Mapping(map) => {
            for (k, v) in map {
                let mut key = prefix.to_vec();
                key.extend(key_text(k).split('.').map(str::to_owned));
                flatten(v, &key, f);
            }
        }
        other => f(prefix.to_vec(), other),
    }
}

/// The parameter entries of a file's sections that apply to the node `node_fqn`, in the file's
/// order, after checking its ROS 2 layout. A section is a node key (nested keys join with `/`
/// into a namespace, as rcl's parser joins them) holding `ros__parameters`.
fn file_entries(
    document: &Value,
    text: &str,
    path: &Path,
    node_fqn: &str,
    problems: &mut Vec<Problem>,
) -> Vec<Entry> {
    let at = |yaml_path: &[String]| Origin::File {
        path: path.to_owned(),
        line: find_line(text, yaml_path),
    };
    let expected = "a ROS 2 parameters file starts with the node name `ttball:` (or its fully \
                    qualified name such as `/robot1/ttball:`, or a wildcard `/**:`), then \
                    `ros__parameters:` indented under it, then the parameters indented under that";
    let mut entries = Vec::new();
    let nodes = match document {
        // An empty file sets nothing.
        Value::Null => return entries,
        Value::Mapping(nodes) => nodes,
        other => {
            problems.push(Problem::Layout {
                origin: at(&[]),
                message: format!("found {}, but {expected}", describe_found(other)),
            });
            return entries;
        }
    };
    let sections: Vec<String> = match serde_norway::to_value(Config::default()) {
        Ok(Value::Mapping(m)) => m.keys().map(key_text).collect(),
        _ => Vec::new(),
    };
    // A parameter section written at the top, not under a node: the common mistake.
    for node_key in nodes.keys() {
        let name = key_text(node_key);
        if sections.contains(&name) || name == ROS_PARAMETERS {
            problems.push(Problem::Layout {
                origin: at(std::slice::from_ref(&name)),
                message: format!(
                    "unexpected top-level key `{name}` (the parameters must be nested under the \
                     node name, e.g. `ttball:`, and `ros__parameters:`): {expected}"
                ),
            });
        }
    }
    let mut stack: Vec<(Vec<String>, &Value)> = nodes
        .iter()
        .map(|(k, v)| (vec![key_text(k)], v))
        .filter(|(k, _)| !sections.contains(&k[0]) && k[0] != ROS_PARAMETERS)
        .collect();
    // Depth first, in the file's order.
    stack.reverse();
    while let Some((yaml_path, node)) = stack.pop() {
        let node_key = yaml_path.join("/");
        let Some(node_map) = node.as_mapping() else {
            problems.push(Problem::Layout {
                origin: at(&yaml_path),
                message: format!(
                    "`{node_key}` holds {}, but {expected}",
                    describe_found(node)
                ),
            });
            continue;
        };
        let Some(params) = node_map.get(ROS_PARAMETERS) else {
            // A namespace: its children are nodes or further namespaces. A child holding plain
            // values is parameters without `ros__parameters` above them.
            let first = stack.len();
            for (k, v) in node_map {
                let mut child = yaml_path.clone();
                child.push(key_text(k));
                let plain = v
                    .as_mapping()
                    .is_none_or(|m| m.values().all(|value| !value.is_mapping()));
                if plain {
                    problems.push(Problem::Layout {
                        origin: at(&child),
                        message: format!(
                            "unexpected key `{}` under `{node_key}`: only `{ROS_PARAMETERS}` \
                             may follow the node name; {expected}",
                            key_text(k)
                        ),
                    });
                } else {
                    stack.push((child, v));
                }
            }
            stack[first..].reverse();
            continue;
        };
        for inner_key in node_map.keys() {
            let inner = key_text(inner_key);
            if inner != ROS_PARAMETERS {
                let mut inner_path = yaml_path.clone();
                inner_path.push(inner.clone());
                problems.push(Problem::Layout {
                    origin: at(&inner_path),
                    message: format!(
                        "unexpected key `{inner}` under `{node_key}`: only `{ROS_PARAMETERS}` \
                         may follow the node name; {expected}"
                    ),
                });
            }
        }
        if super::names::node_key_matches(&node_key, node_fqn) {
            let mut inner_path = yaml_path.clone();
            inner_path.push(ROS_PARAMETERS.to_owned());
            collect_file_entries(params, &inner_path, &[], &at, &mut entries);
        }
    }
    entries
}

/// Entries under `value`, tracking the keys as written (`yaml_path`, for line numbers) and the
/// dotted key segments (`key`).
fn collect_file_entries(
    value: &Value,
    yaml_path: &[String],
    key: &[String],
    at: &dyn Fn(&[String]) -> Origin,
    out: &mut Vec<Entry>,
) {
    match value {
        Value::Mapping(map) => {
            for (k, v) in map {
                let text = key_text(k);
                let mut yaml_path = yaml_path.to_vec();
                yaml_path.push(text.clone());
                let mut key = key.to_vec();
                key.extend(text.split('.').map(str::to_owned));
                collect_file_entries(v, &yaml_path, &key, at, out);
            }
        }
        other => out.push(Entry {
            key: key.to_vec(),
            value: other.clone(),
            origin: at(yaml_path),
        }),
    }
}

/// The 1-based line of the key at `yaml_path` in block-style YAML, or of its deepest ancestor
/// found (for keys inside a flow-style `{...}` map).
fn find_line(text: &str, yaml_path: &[String]) -> Option<usize> {
    let mut stack: Vec<(usize, String)> = Vec::new();
    let mut best: Option<(usize, usize)> = None; // (depth, line)
    for (index, line) in text.lines().enumerate() {
        let trimmed = line.trim_start();
        if trimmed.is_empty() || trimmed.starts_with('#') || trimmed.starts_with("- ") {
            continue;
        }
        let indent = line.len() - trimmed.len();
        let Some(key) = leading_key(trimmed) else {
            continue;
        };
        while stack.last().is_some_and(|(i, _)| *i >= indent) {
            stack.pop();
        }
        stack.push((indent, key));
        let depth = stack.len();
        if depth <= yaml_path.len()
            && stack.iter().zip(yaml_path).all(|((_, k), p)| k == p)
            && best.is_none_or(|(d, _)| depth > d)
        {
            best = Some((depth, index + 1));
            if depth == yaml_path.len() {
                break;
            }
        }
    }
    best.map(|(_, line)| line)
}

/// The key of a `key: ...` line (plain or quoted), if the line starts with one.
fn leading_key(line: &str) -> Option<String> {
    if let Some(quote) = line.chars().next().filter(|c| *c == '"' || *c == '\'') {
        let rest = &line[1..];
        let end = rest.find(quote)?;
        return rest[end + 1..]
            .trim_start()
            .starts_with(':')
            .then(|| rest[..end].to_owned());
    }
    let bytes = line.as_bytes();
    let colon = (0..bytes.len()).find(|&i| {
        bytes[i] == b':' && bytes.get(i + 1).is_none_or(|b| *b == b' ' || *b == b'\t')
    })?;
    let key = line[..colon].trim_end();
    (!key.is_empty() && !key.contains(" #")).then(|| key.to_owned())
}

/// Parses `NAME:=VALUE` (ROS 2 `-p` syntax; `node:NAME:=VALUE` for one node only: `None` when
/// that is not the node `node_fqn`); the value is a YAML scalar or flow sequence. The error is
/// the reason the argument is malformed.
fn parse_override(arg: &str, node_fqn: &str) -> Result<Option<Entry>, String> {
    let Some((name, value)) = arg.split_once(":=") else {
        return Err(
            "expected NAME:=VALUE with a dotted parameter name, e.g. `-p intercept.plane_x:=-1.45`"
                .to_owned(),
        );
    };
    let name = match name.trim().rsplit_once(':') {
        Some((node, name)) => {
            let own_name = node_fqn.rsplit('/').next().unwrap_or(node_fqn);
            if node != own_name && !super::names::node_key_matches(node, node_fqn) {
                return Ok(None);
            }
            name
        }
        None => name.trim(),
    };
    if name.is_empty() {
        return Err(
            "the parameter name before `:=` is empty; e.g. `-p intercept.plane_x:=-1.45`"
                .to_owned(),
        );
    }
    let value: Value = serde_norway::from_str(value).map_err(|e| {
        format!(
            "the value `{value}` is not a YAML scalar or list ({e}); quote strings that contain \
             YAML syntax"
        )
    })?;
    Ok(Some(Entry {
        key: name.split('.').map(str::to_owned).collect(),
        value,
        origin: Origin::Override {
            arg: arg.to_owned(),
        },
    }))
}

fn emit_mapping(out: &mut String, value: &Value, indent: usize) {
    let Value::Mapping(map) = value else {
        return;
    };
    for (k, v) in map {
        out.push_str(&" ".repeat(indent));
        out.push_str(&key_text(k));
        out.push(':');
        match v {
            Value::Mapping(m) if !m.is_empty() => {
                out.push('\n');
                emit_mapping(out, v, indent + 2);
            }
            _ => {
                out.push(' ');
                out.push_str(&scalar(v));
                out.push('\n');
            }
        }
    }
}

/// A value in flow style: reals keep a decimal point, strings are double-quoted.
fn scalar(value: &Value) -> String {
    match value {
        Value::Null => "~".to_owned(),
        Value::Bool(b) => b.to_string(),
        Value::Number(n) => match n.as_f64() {
            Some(f) if n.is_f64() => format_float(f),
            _ => n.to_string(),
        },
        Value::String(s) => quote(s),
        Value::Sequence(items) => {
            let items: Vec<String> = items.iter().map(scalar).collect();
            format!("[{}]", items.join(", "))
        }
        Value::Mapping(map) => {
            let items: Vec<String> = map
                .iter()
                .map(|(k, v)| format!("{}: {}", key_text(k), scalar(v)))
                .collect();
            format!("{{{}}}", items.join(", "))
        }
        Value::Tagged(t) => format!("{} {}", t.tag, scalar(&t.value)),
    }
}

/// The shortest representation that parses back to `f` and that YAML 1.1 and 1.2 parsers (and
/// rclcpp) read as a double: `1.0`, `0.0027`, `1.512e-5`, `1.0e-7`, `1.0e+20`.
fn format_float(f: f64) -> String {
    if f.is_nan() {
        return ".nan".to_owned();
    }
    if f.is_infinite() {
        return if f > 0.0 { ".inf" } else { "-.inf" }.to_owned();
    }
    let s = format!("{f:?}");
    match s.split_once('e') {
        Some((mantissa, exponent)) => {
            let mantissa = if mantissa.contains('.') {
                mantissa.to_owned()
            } else {
                format!("{mantissa}.0")
            };
            let exponent = if exponent.starts_with('-') {
                exponent.to_owned()
            } else {
                format!("+{exponent}")
            };
            format!("{mantissa}e{exponent}")
        }
        None => s,
    }
}

/// A YAML double-quoted string.
fn quote(s: &str) -> String {
    let mut out = String::with_capacity(s.len() + 2);
    out.push('"');
    for c in s.chars() {
        match c {
            '"' => out.push_str("\\\""),
            '\\' => out.push_str("\\\\"),
            '\n' => out.push_str("\\n"),
            '\t' => out.push_str("\\t"),
            c if c.is_control() => out.push_str(&format!("\\u{:04x}", u32::from(c))),
            c => out.push(c),
        }
    }
    out.push('"');
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn floats_keep_a_point_and_round_trip() {
        for (f, text) in [
            (1.0, "1.0"),
            (-1.6, "-1.6"),
            (0.0027, "0.0027"),
            (1.512e-5, "1.512e-5"),
            (1e-7, "1.0e-7"),
            (1e20, "1.0e+20"),
            (2.5e300, "2.5e+300"),
        ] {
            assert_eq!(format_float(f), text);
            let back: f64 = serde_norway::from_str(text).unwrap();
            assert_eq!(back, f, "{text}");
        }
    }

    /// A learned file is told by its first line: its layers leave, every other layer stays in
    /// its order (a file that cannot be read as well: loading it says why).
    #[test]
    fn learned_files_are_told_by_their_first_line() {
        let dir = std::env::temp_dir().join(format!("ttball-learned-mark-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let write = |name: &str, text: &str| {
            let path = dir.join(name);
            std::fs::write(&path, text).unwrap();
            path
        };
        let learned = write(
            "learned.yaml",
            &format!(
                "{LEARNED_FILE_START}`ttball replay --learned` from a.mcap{LEARNED_FILE_MARK}; ...\n"
            ),
        );
        let own = write(
            "robot.yaml",
            "# what the estimator learned is not in here\n",
        );
        let quoted = write(
            "notes.yaml",
            &format!("# Copied from a file that said{LEARNED_FILE_MARK}\n"),
        );
        let missing = dir.join("missing.yaml");
        assert!(is_learned_file(&learned));
        assert!(!is_learned_file(&own) && !is_learned_file(&quoted));
        assert!(!is_learned_file(&missing));
        let layers = vec![
            Layer::File(own.clone()),
            Layer::File(learned),
            Layer::Param("aero.drag_scale:=0.9".into()),
            Layer::File(missing.clone()),
        ];
        assert_eq!(
            without_learned_files(&layers),
            vec![
                Layer::File(own),
                Layer::Param("aero.drag_scale:=0.9".into()),
                Layer::File(missing),
            ]
        );
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// The changed parameters alone, loaded over the defaults, give the changed configuration;
    /// nothing changed loads as the defaults.
    #[test]
    fn changed_parameters_load_back_over_their_base() {
        let base = Config::default();
        let mut changed = base.clone();
        changed.aero.drag_scale = 0.93;
        changed.table.friction = 0.31;
        changed.sources.wide_150fps.position_sigma = 0.00074;
        changed.gating.max_consecutive_rejections = 7;
        let text = changed_params_yaml(&base, &changed);
        assert!(
            !text.contains("length") && !text.contains("topics") && text.contains("drag_scale"),
            "{text}"
        );
        let loaded = load_str::<&str>(&text, Path::new("changed.yaml"), &[]).unwrap();
        assert_eq!(loaded, changed);
        // A file for a renamed node is headed by the wildcard, as `to_ros_params_yaml`'s is.
        let mut renamed = base.clone();
        renamed.node.name = "left_robot".to_owned();
        let mut renamed_changed = renamed.clone();
        renamed_changed.aero.drag_scale = 0.93;
        assert!(changed_params_yaml(&renamed, &renamed_changed).starts_with("\"/**\":\n"));
        let nothing = changed_params_yaml(&base, &base);
        assert_eq!(
            load_str::<&str>(&nothing, Path::new("nothing.yaml"), &[]).unwrap(),
            base,
            "{nothing}"
        );
    }

    #[test]
    fn quoted_strings_round_trip() {
        for s in ["", "/ball/state", "a\"b\\c", "true", "1.5", "~", "x\ny"] {
            let back: String = serde_norway::from_str(&quote(s)).unwrap();
            assert_eq!(back, s);
        }
    }

    #[test]
    fn lines_of_keys() {
        let text = "ttball:\n  ros__parameters:\n    # comment\n    table:\n      length: 2.0\n      \
                    restitution: 0.9\n    ball: {radius: 0.02}\n\"/**\":\n  ros__parameters:\n    gravity: 9.8\n";
        let path = |p: &[&str]| p.iter().map(|s| (*s).to_owned()).collect::<Vec<_>>();
        assert_eq!(
            find_line(
                text,
                &path(&["ttball", "ros__parameters", "table", "restitution"])
            ),
            Some(6)
        );
        assert_eq!(
            find_line(
                text,
                &path(&["ttball", "ros__parameters", "ball", "radius"])
            ),
            Some(7)
        );
        assert_eq!(
            find_line(text, &path(&["/**", "ros__parameters", "gravity"])),
            Some(10)
        );
    }

    #[test]
    fn suggestions() {
        let known: Vec<String> = [
            "table",
            "table.restitution",
            "table.friction",
            "ball.radius",
        ]
        .iter()
        .map(|s| (*s).to_owned())
        .collect();
        assert_eq!(
            suggest("table.restitutoin", &known).as_deref(),
            Some("table.restitution")
        );
        assert_eq!(suggest("tabel", &known).as_deref(), Some("table"));
        assert_eq!(
            suggest("ball.restitution", &known).as_deref(),
            Some("table.restitution")
        );
        assert_eq!(suggest("nonsense", &known), None);
    }
}
