//! Range checks of the configuration: [`Config::validate`] reports every value that makes no
//! physical or numerical sense, each with its dotted key, the value and the allowed range in words.
//!
//! Upper bounds are generous: they exist to catch a value given in the wrong unit (a ball radius
//! of 20 meant as millimetres), not to second-guess an unusual setup.

use thiserror::Error;

use super::{Config, MAX_POLYNOMIAL_COEFFICIENTS, SourceParams};
use crate::config::range::{CountRange, Range};

/// One configuration value outside its allowed range. `key` is the dotted parameter name, as in
/// the ROS 2 parameters file (`table.restitution`, `aero.drag_coefficients[2]`).
#[derive(Debug, Clone, PartialEq, Error)]
pub enum Violation {
    /// A real value is NaN or infinite; never valid.
    #[error("`{key}` = {value} is not a finite number: NaN and infinity are never valid")]
    NotFinite {
        /// Dotted key of the value.
        key: String,
        /// The offending value.
        value: f64,
    },
    /// A real value is outside its range.
    #[error("`{key}` = {value} is out of range: it must be {allowed}")]
    OutOfRange {
        /// Dotted key of the value.
        key: String,
        /// The offending value (in the key's unit).
        value: f64,
        /// The allowed range; it says itself in words.
        allowed: Range,
    },
    /// A count (integer) is outside its range.
    #[error("`{key}` = {value} is out of range: it must be {allowed}")]
    CountOutOfRange {
        /// Dotted key of the value.
        key: String,
        /// The offending count.
        value: u64,
        /// The allowed range; it says itself in words.
        allowed: CountRange,
    },
    /// A list that needs at least one element is empty.
    #[error("`{key}` is an empty list: it must hold at least one {element}")]
    EmptyList {
        /// Dotted key of the list.
        key: String,
        /// What one element of the list is.
        element: &'static str,
    },
    /// A ROS 2 name (topic, node name, namespace) is malformed.
    #[error("`{key}` = {value:?} is not a valid {kind}: {reason}")]
    BadName {
        /// Dotted key of the name.
        key: String,
        /// The offending name.
        value: String,
        /// What the name names ("topic name", "node name", "namespace").
        kind: &'static str,
        /// What is wrong with it, and what is expected.
        reason: &'static str,
    },
    /// A value exceeds another value that bounds it.
    #[error("`{key}` = {value} must not exceed `{limit_key}` = {limit}: {reason}")]
    Exceeds {
        /// Dotted key of the value.
        key: String,
        /// The offending value.
        value: f64,
        /// Dotted key of the bounding value.
        limit_key: String,
        /// The bounding value.
        limit: f64,
        /// Why the one must not exceed the other.
        reason: &'static str,
    },
    /// A list holds more elements than the model takes.
    #[error("`{key}` has {len} elements: at most {max} are taken")]
    TooLong {
        /// Dotted key of the list.
        key: String,
        /// Its length.
        len: usize,
        /// The most it may hold.
        max: usize,
    },
    /// Two camera sources have the same id, so detections could not tell them apart.
    #[error(
        "`{key}` = {id} is also `{other_key}`: each camera source needs its own id (the BallDetection.source its detections carry; 3-255 are free)"
    )]
    SharedId {
        /// Dotted key of the later source's id.
        key: String,
        /// The id.
        id: u8,
        /// Dotted key of the earlier source's id.
        other_key: String,
    },
    /// A list does not have the shape its key needs.
    #[error("`{key}` {reason}")]
    Malformed {
        /// Dotted key of the list.
        key: String,
        /// What is wrong, and what to give.
        reason: String,
    },
    /// Two lists that pair up element by element have different lengths.
    #[error(
        "`{key}` has {len} elements but `{other_key}` has {other_len}: give one per element of `{other_key}`"
    )]
    LengthMismatch {
        /// Dotted key of the list.
        key: String,
        /// Its length.
        len: usize,
        /// Dotted key of the list it pairs with.
        other_key: String,
        /// That list's length.
        other_len: usize,
    },
}

impl Violation {
    /// The dotted key of the offending value (with an `[index]` suffix for a list element).
    pub fn key(&self) -> &str {
        match self {
            Self::NotFinite { key, .. }
            | Self::OutOfRange { key, .. }
            | Self::CountOutOfRange { key, .. }
            | Self::EmptyList { key, .. }
            | Self::BadName { key, .. }
            | Self::Exceeds { key, .. }
            | Self::TooLong { key, .. }
            | Self::SharedId { key, .. }
            | Self::LengthMismatch { key, .. }
            | Self::Malformed { key, .. } => key,
        }
    }
}

/// Errors of the configuration's core layer.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum ConfigError {
    /// One or more values are out of range; all of them are listed.
    #[error("invalid configuration:{}", bullet_list(.violations))]
    Invalid {
        /// Every violation found, in the order of the configuration's keys.
        violations: Vec<Violation>,
    },
}

fn bullet_list(violations: &[Violation]) -> String {
    violations.iter().map(|v| format!("\n  - {v}")).collect()
}

/// Collects violations, and the rule each key is checked against.
#[derive(Default)]
struct Checker {
    violations: Vec<Violation>,
    rules: Vec<(String, String)>,
    ranges: Vec<(String, Range)>,
    count_ranges: Vec<(String, CountRange)>,
}

impl Checker {
    /// Records the rule `key` is checked against (a list's elements under the list's key).
    fn rule(&mut self, key: &str, allowed: &str) {
        let key = key.split_once('[').map_or(key, |(list, _)| list);
        match self.rules.iter_mut().find(|(k, _)| k == key) {
            Some((_, rule)) if rule != allowed && allowed != "a finite number" => {
                allowed.clone_into(rule);
            }
            Some(_) => {}
            None => self.rules.push((key.to_owned(), allowed.to_owned())),
        }
    }

    /// Records `allowed` as the rule of `key`, replacing what the checks recorded.
    fn rule_is(&mut self, key: &str, allowed: &str) {
        match self.rules.iter_mut().find(|(k, _)| k == key) {
            Some((_, rule)) => allowed.clone_into(rule),
            None => self.rules.push((key.to_owned(), allowed.to_owned())),
        }
    }

    /// `value` inside `allowed`; NaN and infinity never are.
    fn real(&mut self, key: &str, value: f64, allowed: Range) {
        self.rule(key, &allowed.to_string());
        if !key.contains('[') {
            self.ranges.push((key.to_owned(), allowed));
        }
        if !value.is_finite() {
            self.violations.push(Violation::NotFinite {
                key: key.to_owned(),
                value,
            });
        } else if !allowed.contains(value) {
            self.violations.push(Violation::OutOfRange {
                key: key.to_owned(),
                value,
                allowed,
            });
        }
    }

    fn fail(&mut self, key: &str, reason: String) {
        self.violations.push(Violation::Malformed {
            key: key.to_owned(),
            reason,
        });
    }

    fn positive(&mut self, key: &str, value: f64) {
        self.real(key, value, Range::greater_than(0.0));
    }

    fn non_negative(&mut self, key: &str, value: f64) {
        self.real(key, value, Range::at_least(0.0));
    }

    fn count(&mut self, key: &str, value: u32, allowed: CountRange) {
        self.count_rule(key, allowed);
        if !allowed.contains(u64::from(value)) {
            self.violations.push(Violation::CountOutOfRange {
                key: key.to_owned(),
                value: u64::from(value),
                allowed,
            });
        }
    }

    /// Records the range a count is held to (checked here or where it is parsed).
    fn count_rule(&mut self, key: &str, allowed: CountRange) {
        self.rule(key, &allowed.to_string());
        self.count_ranges.push((key.to_owned(), allowed));
    }

    fn polynomial(&mut self, key: &str, coefficients: &[f64]) {
        self.rule(key, "1 to 8 finite coefficients, lowest order first");
        if coefficients.is_empty() {
            self.violations.push(Violation::EmptyList {
                key: key.to_owned(),
                element: "polynomial coefficient (lowest order first)",
            });
        }
        if coefficients.len() > MAX_POLYNOMIAL_COEFFICIENTS {
            self.violations.push(Violation::TooLong {
                key: key.to_owned(),
                len: coefficients.len(),
                max: MAX_POLYNOMIAL_COEFFICIENTS,
            });
        }
        for (i, &c) in coefficients.iter().enumerate() {
            self.real(&format!("{key}[{i}]"), c, Range::any());
        }
    }

    /// `value <= limit`, checked only when neither value was already reported (no cascades).
    fn at_most(
        &mut self,
        key: &str,
        value: f64,
        limit_key: &str,
        limit: f64,
        reason: &'static str,
    ) {
        let reported = self
            .violations
            .iter()
            .any(|v| v.key() == key || v.key() == limit_key);
        if !reported && value > limit {
            self.violations.push(Violation::Exceeds {
                key: key.to_owned(),
                value,
                limit_key: limit_key.to_owned(),
                limit,
                reason,
            });
        }
    }

    fn same_length(&mut self, key: &str, len: usize, other_key: &str, other_len: usize) {
        if len != other_len {
            self.violations.push(Violation::LengthMismatch {
                key: key.to_owned(),
                len,
                other_key: other_key.to_owned(),
                other_len,
            });
        }
    }

    fn name(&mut self, key: &str, value: &str, kind: &'static str, problem: Option<&'static str>) {
        self.rule(key, kind);
        if let Some(reason) = problem {
            self.violations.push(Violation::BadName {
                key: key.to_owned(),
                value: value.to_owned(),
                kind,
                reason,
            });
        }
    }

    fn source(&mut self, key: &str, source: &SourceParams) {
        // Parsed as a byte (`config::yaml`), unique among the sources (checked above).
        self.count_rule(
            &format!("{key}.id"),
            CountRange::between(0, 255)
                .note("each source's own: the BallDetection.source of its detections"),
        );
        self.real(
            &format!("{key}.stamp_sigma"),
            source.stamp_sigma,
            Range::between(0.0, 0.1).note("seconds"),
        );
        self.real(
            &format!("{key}.position_sigma"),
            source.position_sigma,
            Range::greater_than(0.0).at_most(1.0).note("metres"),
        );
        self.real(
            &format!("{key}.spin_sigma"),
            source.spin_sigma,
            Range::between(0.0, 1000.0)
                .low_meaning("spin not measured")
                .note("rad/s"),
        );
        self.real(
            &format!("{key}.latency"),
            source.latency,
            Range::between(0.0, 1.0).note("seconds"),
        );
        self.real(
            &format!("{key}.frame_rate"),
            source.frame_rate,
            Range::between(0.0, 100_000.0)
                .low_meaning("no expectation")
                .note("Hz"),
        );
    }
}

use super::names::token_problem;

/// Why `name` is not a valid ROS 2 node name, if it is not.
fn node_name_problem(name: &str) -> Option<&'static str> {
    if name.is_empty() {
        Some("it must not be empty")
    } else if name.contains('/') {
        Some("it must not contain '/'; put the namespace in `node.namespace`")
    } else {
        token_problem(name)
    }
}

/// Why `frame` is not a valid tf2 frame id, if it is not (tf2 refuses a leading '/').
fn frame_problem(frame: &str) -> Option<&'static str> {
    if frame.is_empty() {
        Some("it must not be empty; e.g. \"table\"")
    } else if frame.starts_with('/') {
        Some("tf2 frame ids must not start with '/'")
    } else if frame.chars().any(char::is_whitespace) {
        Some("it must not contain white space")
    } else {
        None
    }
}

/// Why `namespace` is not a valid ROS 2 namespace, if it is not.
fn namespace_problem(namespace: &str) -> Option<&'static str> {
    if namespace.is_empty() || namespace == "/" {
        return None;
    }
    match namespace.strip_prefix('/') {
        None => Some("it must be empty or absolute (start with '/'), e.g. \"/robot1\""),
        Some(rest) => token_problem(rest),
    }
}

impl Config {
    /// Checks every value's range and the consistency between values; returns all violations
    /// at once in [`ConfigError::Invalid`].
    pub fn validate(&self) -> Result<(), ConfigError> {
        let c = self.check();
        if c.violations.is_empty() {
            Ok(())
        } else {
            Err(ConfigError::Invalid {
                violations: c.violations,
            })
        }
    }

    /// The rule each checked key is held to, in words (`"from 0 to 1"`), in the order of the
    /// checks; what the node's parameter descriptors give as `additional_constraints`.
    pub fn rules(&self) -> Vec<(String, String)> {
        self.check().rules
    }

    /// The range each checked real value is held to, by dotted key: where the node's parameter
    /// descriptors take their `floating_point_range` from.
    pub fn ranges(&self) -> Vec<(String, Range)> {
        self.check().ranges
    }

    /// The range each checked count is held to, by dotted key: where the node's parameter
    /// descriptors take their `integer_range` from.
    pub fn count_ranges(&self) -> Vec<(String, CountRange)> {
        self.check().count_ranges
    }

    fn check(&self) -> Checker {
        let mut c = Checker::default();
        self.check_flight(&mut c);
        self.check_racket(&mut c);
        self.check_racket_dynamics(&mut c);
        self.check_prediction(&mut c);
        self.check_estimator(&mut c);
        self.check_node(&mut c);
        c
    }

    /// Gravity, the ball, the air, the flight model and the table.
    fn check_flight(&self, c: &mut Checker) {
        c.real(
            "gravity",
            self.gravity,
            Range::greater_than(0.0)
                .at_most(30.0)
                .note("m/s^2; Earth: 9.81"),
        );

        let b = &self.ball;
        c.real(
            "ball.radius",
            b.radius,
            Range::greater_than(0.0)
                .at_most(0.1)
                .note("metres; ITTF 40+: 0.020"),
        );
        c.real(
            "ball.mass",
            b.mass,
            Range::greater_than(0.0)
                .at_most(0.1)
                .note("kilograms; ITTF 40+: 0.0027"),
        );

        let a = &self.air;
        c.real(
            "air.density",
            a.density,
            Range::between(0.0, 10.0)
                .low_meaning("no air")
                .note("kg/m^3; 1.20 at 20 °C"),
        );
        c.positive("air.kinematic_viscosity", a.kinematic_viscosity);

        let ae = &self.aero;
        c.polynomial("aero.drag_coefficients", &ae.drag_coefficients);
        c.polynomial("aero.magnus_coefficients", &ae.magnus_coefficients);
        c.positive("aero.spin_parameter_max", ae.spin_parameter_max);
        c.rule(
            "aero.reynolds_range",
            "[Re_0, Re_max], 0 < Re_0 <= Re_max, finite",
        );
        if !matches!(ae.reynolds_range[..], [lo, hi] if lo > 0.0 && lo <= hi && hi.is_finite()) {
            c.fail(
                "aero.reynolds_range",
                format!(
                    "is {:?}: give [Re_0, Re_max] with 0 < Re_0 <= Re_max (e.g. [1.6e4, 9.0e4])",
                    ae.reynolds_range
                ),
            );
        }
        c.rule("aero.reynolds_exponents", "[a_D, a_M], each in [-3, 3]");
        if ae.reynolds_exponents.len() != 2
            || !ae
                .reynolds_exponents
                .iter()
                .all(|a| (-3.0..=3.0).contains(a))
        {
            c.fail(
                "aero.reynolds_exponents",
                format!(
                    "is {:?}: give [drag exponent, Magnus exponent], each in [-3, 3] ([0, 0]: \
                     coefficients of Sp alone)",
                    ae.reynolds_exponents
                ),
            );
        }
        c.non_negative("aero.spin_decay_rate", ae.spin_decay_rate);
        for (key, value) in [
            ("aero.drag_scale", ae.drag_scale),
            ("aero.magnus_scale", ae.magnus_scale),
        ] {
            c.real(
                key,
                value,
                Range::between(0.0, 5.0).note("a factor on the configured polynomial's force"),
            );
        }

        let t = &self.table;
        for (key, value) in [("table.length", t.length), ("table.width", t.width)] {
            c.real(
                key,
                value,
                Range::greater_than(0.0).at_most(10.0).note("metres"),
            );
        }
        c.real(
            "table.net_height",
            t.net_height,
            Range::between(0.0, 10.0)
                .low_meaning("a table without a net")
                .note("metres"),
        );
        c.real(
            "table.height",
            t.height,
            Range::between(0.0, 10.0).note("metres"),
        );
        c.real(
            "table.net_overhang",
            t.net_overhang,
            Range::between(0.0, 10.0).note("metres"),
        );
        c.real(
            "table.restitution",
            t.restitution,
            Range::greater_than(0.0)
                .at_most(1.0)
                .note("a bounce cannot add energy"),
        );
        c.real(
            "table.friction",
            t.friction,
            Range::between(0.0, 2.0).note("published fits: 0.1 to 0.3"),
        );
    }

    /// The racket and its rubber.
    fn check_racket(&self, c: &mut Checker) {
        let r = &self.racket;
        c.real(
            "racket.mass",
            r.mass,
            Range::greater_than(0.0).at_most(2.0).note("kilograms"),
        );
        c.real(
            "racket.center_of_gravity_from_grip_end",
            r.center_of_gravity_from_grip_end,
            Range::greater_than(0.0).at_most(1.0).note("metres"),
        );
        for (key, value) in [
            (
                "racket.inertia_about_center_of_gravity",
                r.inertia_about_center_of_gravity,
            ),
            ("racket.inertia_about_long_axis", r.inertia_about_long_axis),
        ] {
            c.real(
                key,
                value,
                Range::greater_than(0.0).at_most(1.0).note("kg m^2"),
            );
        }
        c.real(
            "racket.face_area",
            r.face_area,
            Range::greater_than(0.0).at_most(1.0).note("m^2"),
        );
        c.real(
            "racket.sponge_thickness",
            r.sponge_thickness,
            Range::between(0.0, 0.01).note("metres; ITTF allows 4 mm of rubber"),
        );
        c.real(
            "racket.face_start_from_grip_end",
            r.face_start_from_grip_end,
            Range::between(0.0, 1.0).note("metres"),
        );
        c.real(
            "racket.face_end_from_grip_end",
            r.face_end_from_grip_end,
            Range::greater_than(0.0).at_most(1.0).note("metres"),
        );
        c.at_most(
            "racket.face_start_from_grip_end",
            r.face_start_from_grip_end,
            "racket.face_end_from_grip_end",
            r.face_end_from_grip_end,
            "the face starts before it ends",
        );
        c.polynomial("racket.rubber_restitution", &r.rubber_restitution);
        c.real(
            "racket.rubber_friction",
            r.rubber_friction,
            Range::between(0.0, 5.0),
        );
        c.real(
            "racket.rubber_tangential_restitution",
            r.rubber_tangential_restitution,
            Range::between(-1.0, 1.0),
        );
        c.real(
            "racket.rubber_torsional_restitution",
            r.rubber_torsional_restitution,
            Range::between(-1.0, 1.0),
        );
        let rubber = r.rubber_restitution.len() + 3;
        c.rule(
            "racket.rubber_covariance",
            "empty, or a symmetric (n + 3) x (n + 3) covariance row by row, n the restitution coefficients",
        );
        c.rule(
            "racket.rebound_scatter",
            "[velocity m/s, spin rad/s], both 0 or greater",
        );
        if !(r.rubber_covariance.is_empty() || r.rubber_covariance.len() == rubber * rubber) {
            c.fail(
                "racket.rubber_covariance",
                format!(
                    "has {} values: give none, or the {rubber} x {rubber} = {} of a covariance over rubber_restitution's {} coefficients, rubber_friction, rubber_tangential_restitution and rubber_torsional_restitution, row by row",
                    r.rubber_covariance.len(),
                    rubber * rubber,
                    r.rubber_restitution.len()
                ),
            );
        } else if !r.rubber_covariance.is_empty() {
            let at = |i: usize, j: usize| r.rubber_covariance[i * rubber + j];
            let symmetric = (0..rubber).all(|i| {
                at(i, i) >= 0.0
                    && (0..rubber).all(|j| {
                        at(i, j).is_finite()
                            && (at(i, j) - at(j, i)).abs()
                                <= 1e-9 * (at(i, i) * at(j, j)).sqrt().max(1e-300)
                    })
            });
            if !symmetric {
                c.fail(
                    "racket.rubber_covariance",
                    "is not a covariance: give finite values, a symmetric matrix, non-negative variances on its diagonal".to_owned(),
                );
            }
        }
        if r.rebound_scatter.len() != 2
            || r.rebound_scatter
                .iter()
                .any(|v| !(v.is_finite() && *v >= 0.0))
        {
            c.fail(
                "racket.rebound_scatter",
                format!(
                    "is {:?}: give [velocity m/s, spin rad/s], both finite and >= 0",
                    r.rebound_scatter
                ),
            );
        }
    }

    /// The racket's restoring force and vibration, the arm and the stroke.
    fn check_racket_dynamics(&self, c: &mut Checker) {
        let r = &self.racket;
        c.polynomial(
            "racket.restoring_force_vs_stiffness",
            &r.restoring_force_vs_stiffness,
        );
        for (i, &f) in r.vibration_mode_frequencies.iter().enumerate() {
            c.real(
                &format!("racket.vibration_mode_frequencies[{i}]"),
                f,
                Range::greater_than(0.0).at_most(1.0e5).note("Hz"),
            );
        }
        for (i, &m) in r.vibration_mode_masses.iter().enumerate() {
            c.real(
                &format!("racket.vibration_mode_masses[{i}]"),
                m,
                Range::greater_than(0.0).at_most(10.0).note("kilograms"),
            );
        }
        c.same_length(
            "racket.vibration_mode_masses",
            r.vibration_mode_masses.len(),
            "racket.vibration_mode_frequencies",
            r.vibration_mode_frequencies.len(),
        );
        c.real(
            "arm.equivalent_mass",
            self.arm.equivalent_mass,
            Range::between(0.0, 1000.0)
                .low_meaning("a free racket")
                .note("kilograms"),
        );
        c.real(
            "arm.grip_from_grip_end",
            self.arm.grip_from_grip_end,
            Range::between(0.0, 1.0).note("metres"),
        );
        c.at_most(
            "arm.grip_from_grip_end",
            self.arm.grip_from_grip_end,
            "racket.center_of_gravity_from_grip_end",
            r.center_of_gravity_from_grip_end,
            "the grip is between the grip end and the centre of gravity",
        );
        let s = &self.stroke;
        c.real(
            "stroke.max_racket_speed",
            s.max_racket_speed,
            Range::greater_than(0.0).at_most(100.0).note("m/s"),
        );
        c.real(
            "stroke.net_clearance",
            s.net_clearance,
            Range::between(0.0, 3.0).note("metres"),
        );
    }

    /// The prediction, the interception and the camera sources.
    fn check_prediction(&self, c: &mut Checker) {
        let p = &self.prediction;
        c.real(
            "prediction.step",
            p.step,
            Range::greater_than(0.0)
                .at_most(super::MAX_STEP)
                .note("seconds"),
        );
        c.real(
            "prediction.horizon",
            p.horizon,
            Range::greater_than(0.0).at_most(10.0).note("seconds"),
        );
        c.real(
            "prediction.trajectory_rate",
            p.trajectory_rate,
            Range::greater_than(0.0).at_most(1000.0).note("Hz"),
        );
        c.positive("prediction.trajectory_dt", p.trajectory_dt);
        c.at_most(
            "prediction.trajectory_dt",
            p.trajectory_dt,
            "prediction.horizon",
            p.horizon,
            "a trajectory needs at least one sample after its start",
        );

        c.real("intercept.plane_x", self.intercept.plane_x, Range::at_least(-3.0).less_than(0.0).note("metres; on the robot's side, behind or over the table; the robot's baseline is at -1.37"));

        let r = &self.intercept.refresh;
        c.real(
            "intercept.refresh.max_age",
            r.max_age,
            Range::between(0.0, 1.0).note("seconds; 0 predicts in full after every detection"),
        );
        c.non_negative("intercept.refresh.position", r.position);
        c.non_negative("intercept.refresh.velocity", r.velocity);
        c.non_negative("intercept.refresh.spin", r.spin);

        // In the configuration's order: the seed setup's two cameras, `unknown`, the others.
        let mut sources = self.sources.all();
        sources[..3].rotate_left(1);
        for (i, (name, source)) in sources.iter().enumerate() {
            let key = format!("sources.{name}");
            if self.sources.more.contains_key(*name)
                && let Some(reason) = token_problem(name)
            {
                c.violations.push(Violation::BadName {
                    key: key.clone(),
                    value: (*name).to_owned(),
                    kind: "source name",
                    reason,
                });
            }
            c.source(&key, source);
            if let Some((other, _)) = sources[..i].iter().find(|(_, s)| s.id == source.id) {
                c.violations.push(Violation::SharedId {
                    key: format!("{key}.id"),
                    id: source.id,
                    other_key: format!("sources.{other}.id"),
                });
            }
        }
    }

    /// The filter, the adaptation, the gating and the tracking.
    fn check_estimator(&self, c: &mut Checker) {
        let e = &self.ekf;
        c.positive(
            "ekf.acceleration_noise_density",
            e.acceleration_noise_density,
        );
        c.non_negative("ekf.spin_noise_density", e.spin_noise_density);
        c.positive("ekf.spin_prior_sigma", e.spin_prior_sigma);
        c.real(
            "ekf.min_confidence",
            e.min_confidence,
            Range::between(0.0, 1.0),
        );
        c.real(
            "ekf.bounce_impulse_sigma",
            e.bounce_impulse_sigma,
            Range::between(0.0, 5.0).note("m/s"),
        );
        c.real(
            "ekf.bounce_restitution_sigma",
            e.bounce_restitution_sigma,
            Range::between(0.0, 0.5),
        );
        c.real(
            "ekf.contact_position_sigma",
            e.contact_position_sigma,
            Range::between(0.0, 0.05).note("m"),
        );

        let ad = &self.adaptation;
        for (key, values) in [
            ("adaptation.sigma", &ad.sigma),
            ("adaptation.flight_sigma", &ad.flight_sigma),
        ] {
            c.rule(
                key,
                "four values in [0, 1]: drag_scale, magnus_scale, restitution, friction",
            );
            if values.len() != 4 || !values.iter().all(|v| (0.0..=1.0).contains(v)) {
                c.fail(
                    key,
                    format!(
                        "is {values:?}: give four values in [0, 1] (drag_scale, magnus_scale, \
                         restitution, friction)"
                    ),
                );
            }
        }
        c.rule(
            "adaptation.reynolds_sigma",
            "two values in [0, 2]: a_D, a_M",
        );
        if ad.reynolds_sigma.len() != 2
            || !ad.reynolds_sigma.iter().all(|v| (0.0..=2.0).contains(v))
        {
            c.fail(
                "adaptation.reynolds_sigma",
                format!(
                    "is {:?}: give two values in [0, 2] (a_D, a_M)",
                    ad.reynolds_sigma
                ),
            );
        }
        c.real(
            "adaptation.drift_per_hour",
            ad.drift_per_hour,
            Range::between(0.0, 100.0).note("a fraction of each prior sigma per hour"),
        );

        c.real(
            "gating.probability",
            self.gating.probability,
            Range::greater_than(0.0).less_than(1.0),
        );
        c.count(
            "gating.max_consecutive_rejections",
            self.gating.max_consecutive_rejections,
            CountRange::at_least(1),
        );

        let tr = &self.tracking;
        c.positive("tracking.timeout", tr.timeout);
        c.non_negative("tracking.rollback_window", tr.rollback_window);
        c.positive("tracking.coast_after", tr.coast_after);
        c.at_most(
            "tracking.rollback_window",
            tr.rollback_window,
            "tracking.timeout",
            tr.timeout,
            "a stamp further off than the timeout is a jump, not a late detection",
        );
        c.at_most(
            "tracking.coast_after",
            tr.coast_after,
            "tracking.timeout",
            tr.timeout,
            "a track coasts before it times out",
        );
    }

    /// The node, its topics, frames and QoS.
    fn check_node(&self, c: &mut Checker) {
        let n = &self.node;
        c.name(
            "node.name",
            &n.name,
            "node name",
            node_name_problem(&n.name),
        );
        c.name(
            "node.namespace",
            &n.namespace,
            "namespace",
            namespace_problem(&n.namespace),
        );
        c.count(
            "node.queue_capacity",
            n.queue_capacity,
            CountRange::at_least(1),
        );
        c.name(
            "node.interface_address",
            &n.interface_address,
            "IP address",
            (!n.interface_address.is_empty()
                && n.interface_address.parse::<std::net::IpAddr>().is_err())
            .then_some("give the address of one of this machine's interfaces, e.g. \"192.168.1.20\", or \"\" for all"),
        );
        c.name("node.cpus", &n.cpus, "CPU list", n.cpu_list().err());
        c.real(
            "node.source_stale_after",
            n.source_stale_after,
            Range::between(0.1, 3600.0).note("seconds"),
        );
        c.real(
            "node.diagnostics_period",
            n.diagnostics_period,
            Range::between(0.01, 60.0).note("seconds"),
        );

        let tp = &self.topics;
        for (key, value) in [
            ("topics.detections", &tp.detections),
            ("topics.state", &tp.state),
            ("topics.intercept", &tp.intercept),
            ("topics.trajectory", &tp.trajectory),
            ("topics.markers", &tp.markers),
            ("topics.diagnostics", &tp.diagnostics),
            ("topics.truth", &tp.truth),
            ("topics.smoothed", &tp.smoothed),
            ("topics.robot_hits", &tp.robot_hits),
        ] {
            c.name(key, value, "topic name", super::names::name_problem(value));
        }
        c.name(
            "topics.odometry",
            &tp.odometry,
            "topic name, or \"\" for none",
            (!tp.odometry.is_empty())
                .then(|| super::names::name_problem(&tp.odometry))
                .flatten(),
        );

        let f = &self.frames;
        c.name(
            "frames.table_frame",
            &f.table_frame,
            "frame name",
            frame_problem(&f.table_frame),
        );
        c.name(
            "frames.table_parent",
            &f.table_parent,
            "frame name",
            (!f.table_parent.is_empty() && f.table_parent.trim_start_matches('/') == f.table_frame)
                .then_some("the table cannot be its own parent; give the frame the table is placed in, e.g. \"world\", or \"\" for none")
                .or_else(|| {
                    let parent = f.table_parent.trim_start_matches('/');
                    (!parent.is_empty()).then(|| frame_problem(parent)).flatten()
                }),
        );
        let pose = &f.table_pose;
        if pose.len() != 7 {
            c.violations.push(Violation::LengthMismatch {
                key: "frames.table_pose".to_owned(),
                len: pose.len(),
                other_key: "x, y, z, qx, qy, qz, qw".to_owned(),
                other_len: 7,
            });
        } else {
            for (i, v) in pose.iter().enumerate() {
                c.real(&format!("frames.table_pose[{i}]"), *v, Range::any());
            }
            let q: f64 = pose[3..].iter().map(|v| v * v).sum();
            c.real(
                "frames.table_pose[3..7]",
                q,
                Range::greater_than(1e-12).named("a non-zero quaternion"),
            );
        }
        c.rule_is(
            "frames.table_pose",
            "7 finite values: x, y, z [m], then a non-zero quaternion x, y, z, w",
        );

        c.count(
            "qos.detections_depth",
            self.qos.detections_depth,
            CountRange::at_least(1),
        );
        c.count(
            "qos.outputs_depth",
            self.qos.outputs_depth,
            CountRange::at_least(1),
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn violations(config: &Config) -> Vec<Violation> {
        match config.validate() {
            Ok(()) => Vec::new(),
            Err(ConfigError::Invalid { violations }) => violations,
        }
    }

    fn keys(config: &Config) -> Vec<String> {
        violations(config)
            .iter()
            .map(|v| v.key().to_owned())
            .collect()
    }

    /// The adaptation's two lists hold four values in [0, 1] each, and say so when they do
    /// not.
    #[test]
    fn the_adaptation_lists_hold_four_values_in_range() {
        let mut c = Config::default();
        assert!(violations(&c).is_empty());
        c.adaptation.sigma = vec![0.1, 0.2, 0.3];
        c.adaptation.flight_sigma = vec![0.1, 1.5, 0.0, 0.0];
        assert_eq!(keys(&c), ["adaptation.sigma", "adaptation.flight_sigma"]);
        let text = violations(&c)[0].to_string();
        assert!(text.contains("four values in [0, 1]"), "{text}");
    }

    #[test]
    fn racket_arm_and_stroke_keys_are_checked() {
        let mut c = Config::default();
        c.racket.vibration_mode_frequencies = vec![400.0, -1.0];
        c.racket.vibration_mode_masses = vec![0.05];
        c.racket.rubber_friction = -0.1;
        c.racket.restoring_force_vs_stiffness.clear();
        c.racket.face_start_from_grip_end = 0.3;
        c.arm.equivalent_mass = 0.0;
        c.arm.grip_from_grip_end = 0.2;
        c.stroke.max_racket_speed = 0.0;
        assert_eq!(
            keys(&c),
            [
                "racket.face_start_from_grip_end",
                "racket.rubber_friction",
                "racket.restoring_force_vs_stiffness",
                "racket.vibration_mode_frequencies[1]",
                "racket.vibration_mode_masses",
                "arm.grip_from_grip_end",
                "stroke.max_racket_speed",
            ]
        );
        let text = c.validate().expect_err("invalid").to_string();
        assert!(
            text.contains("`racket.vibration_mode_masses` has 1 elements but `racket.vibration_mode_frequencies` has 2"),
            "{text}"
        );
    }

    #[test]
    fn node_cpus_are_a_taskset_cpu_list() {
        let mut c = Config::default();
        let mut list = |text: &str| {
            c.node.cpus = text.to_owned();
            c.node.cpu_list()
        };
        assert_eq!(list(""), Ok(vec![]));
        assert_eq!(list("1"), Ok(vec![1]));
        assert_eq!(list(" 3, 0-1 ,1"), Ok(vec![0, 1, 3]));
        assert_eq!(list("1023"), Ok(vec![1023]));
        for bad in ["1024", "3-2", "x", "1-", "-1", "1;2"] {
            assert!(list(bad).is_err(), "{bad:?}");
        }
        c.node.cpus = "2-1".to_owned();
        assert_eq!(keys(&c), ["node.cpus"]);
        let text = c.validate().expect_err("invalid").to_string();
        assert!(
            text.contains("`node.cpus` = \"2-1\" is not a valid CPU list: a range must go up"),
            "{text}"
        );
    }

    #[test]
    fn frame_names_are_tf2_frame_ids() {
        let mut c = Config::default();
        for (frame, parent, bad) in [
            ("tt_table", "world", &[][..]),
            ("tt_table", "/world", &[]),
            ("", "", &["frames.table_frame"]),
            ("/table", "", &["frames.table_frame"]),
            ("my table", "", &["frames.table_frame"]),
            ("tt_table", "tt_table", &["frames.table_parent"]),
            ("table", "/table", &["frames.table_parent"]),
            ("table", "the world", &["frames.table_parent"]),
        ] {
            c.frames.table_frame = frame.to_owned();
            c.frames.table_parent = parent.to_owned();
            assert_eq!(keys(&c), bad, "{frame:?} in {parent:?}");
        }
        c.frames.table_frame = "/table".to_owned();
        let text = c.validate().expect_err("invalid").to_string();
        assert!(
            text.contains("tf2 frame ids must not start with '/'"),
            "{text}"
        );
    }

    /// The range in `prediction.step`'s message is written out (a `&'static str`): it must say
    /// the limit the check uses.
    #[test]
    fn step_message_states_the_limit_checked() {
        let mut c = Config::default();
        c.prediction.step = crate::config::MAX_STEP * 1.01;
        let text = c.validate().expect_err("invalid").to_string();
        let limit = crate::config::MAX_STEP;
        assert!(
            text.contains(&format!("at most {limit} (seconds)")),
            "{text}"
        );
        c.prediction.step = crate::config::MAX_STEP;
        assert_eq!(c.validate(), Ok(()));
    }

    #[test]
    fn defaults_are_valid() {
        assert_eq!(Config::default().validate(), Ok(()));
    }

    #[test]
    fn every_violation_is_reported_at_once() {
        let mut c = Config::default();
        c.table.restitution = 1.5;
        c.table.friction = -0.1;
        c.ball.mass = f64::NAN;
        c.prediction.step = 0.1;
        c.gating.probability = 1.0;
        c.gating.max_consecutive_rejections = 0;
        c.topics.state = "ball//state".to_owned();
        c.aero.drag_coefficients.clear();
        c.aero.magnus_coefficients[1] = f64::INFINITY;
        c.intercept.plane_x = 0.0;
        assert_eq!(
            keys(&c),
            [
                "ball.mass",
                "aero.drag_coefficients",
                "aero.magnus_coefficients[1]",
                "table.restitution",
                "table.friction",
                "prediction.step",
                "intercept.plane_x",
                "gating.probability",
                "gating.max_consecutive_rejections",
                "topics.state",
            ]
        );
    }

    #[test]
    fn messages_name_key_value_and_range() {
        let mut c = Config::default();
        c.table.restitution = 1.5;
        c.ball.mass = f64::NAN;
        c.gating.max_consecutive_rejections = 0;
        let text = c.validate().map_err(|e| e.to_string()).unwrap_err();
        assert!(text.contains(
            "`table.restitution` = 1.5 is out of range: it must be greater than 0 and at most 1"
        ));
        assert!(text.contains("`ball.mass` = NaN is not a finite number"));
        assert!(text.contains(
            "`gating.max_consecutive_rejections` = 0 is out of range: it must be at least 1"
        ));
    }

    #[test]
    fn range_boundaries() {
        let mut c = Config::default();
        c.table.restitution = 1.0;
        c.table.friction = 0.0;
        c.prediction.step = 0.05;
        c.intercept.plane_x = -3.0;
        c.gating.max_consecutive_rejections = 1;
        c.air.density = 0.0;
        assert_eq!(c.validate(), Ok(()));

        c.table.restitution = 0.0;
        c.intercept.plane_x = -3.0001;
        c.gating.probability = 0.0;
        c.prediction.horizon = 0.0;
        assert_eq!(
            keys(&c),
            [
                "table.restitution",
                "prediction.horizon",
                "intercept.plane_x",
                "gating.probability"
            ]
        );
    }

    #[test]
    fn infinities_are_rejected_even_where_unbounded() {
        let mut c = Config::default();
        c.tracking.timeout = f64::INFINITY;
        c.ekf.acceleration_noise_density = f64::NEG_INFINITY;
        assert!(matches!(
            violations(&c).as_slice(),
            [Violation::NotFinite { .. }, Violation::NotFinite { .. }]
        ));
    }

    #[test]
    fn consistency_between_keys() {
        let mut c = Config::default();
        c.tracking.coast_after = 0.2;
        c.tracking.rollback_window = 0.5;
        c.prediction.trajectory_dt = 2.0;
        let v = violations(&c);
        assert_eq!(
            v,
            [
                Violation::Exceeds {
                    key: "prediction.trajectory_dt".to_owned(),
                    value: 2.0,
                    limit_key: "prediction.horizon".to_owned(),
                    limit: 1.5,
                    reason: "a trajectory needs at least one sample after its start",
                },
                Violation::Exceeds {
                    key: "tracking.rollback_window".to_owned(),
                    value: 0.5,
                    limit_key: "tracking.timeout".to_owned(),
                    limit: 0.1,
                    reason: "a stamp further off than the timeout is a jump, not a late detection",
                },
                Violation::Exceeds {
                    key: "tracking.coast_after".to_owned(),
                    value: 0.2,
                    limit_key: "tracking.timeout".to_owned(),
                    limit: 0.1,
                    reason: "a track coasts before it times out",
                },
            ]
        );
    }

    #[test]
    fn ros_names() {
        use crate::config::names::name_problem;
        for good in ["/a", "/ball/state", "/_x/y_2", "a", "ball/state", "~/x"] {
            assert_eq!(name_problem(good), None, "{good}");
        }
        for bad in ["", "/", "/a/", "//a", "/a//b", "/a b", "/2d", "/a/~b"] {
            assert!(name_problem(bad).is_some(), "{bad}");
        }
        assert_eq!(node_name_problem("ttball_2"), None);
        for bad in ["", "/ttball", "2ttball", "tt-ball"] {
            assert!(node_name_problem(bad).is_some(), "{bad}");
        }
        for good in ["", "/", "/robot1", "/a/b"] {
            assert_eq!(namespace_problem(good), None, "{good}");
        }
        for bad in ["robot1", "/robot1/", "/1robot"] {
            assert!(namespace_problem(bad).is_some(), "{bad}");
        }
    }

    #[test]
    fn source_sigmas() {
        let mut c = Config::default();
        c.sources.unknown.position_sigma = 0.0;
        c.sources.highspeed_900fps.spin_sigma = -1.0;
        c.sources.wide_150fps.latency = -0.001;
        assert_eq!(
            keys(&c),
            [
                "sources.wide_150fps.latency",
                "sources.highspeed_900fps.spin_sigma",
                "sources.unknown.position_sigma",
            ]
        );
    }
}
