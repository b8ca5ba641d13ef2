//! Python bindings of ttball's core for controller developers: trajectory prediction, the racket
//! rebound, the return plan and the estimator, with numpy arrays in and out and every
//! configuration key reachable. A thin adapter: each function calls the core's one entry point
//! for it (`physics::predict`, `Stroke::rebound`, `Stroke::plan`, `Estimator::handle`), as the
//! ROS node's services and the replay do. Ball states are 9-vectors (position [m], velocity
//! [m/s], spin [rad/s]) in the table frame.

use std::path::PathBuf;

use nalgebra::{Matrix3, SMatrix, SVector, Vector2, Vector3};
use numpy::{
    AllowTypeChange, PyArray1, PyArrayLike1, PyArrayLike2, PyArrayMethods, PyUntypedArrayMethods,
};
use pyo3::create_exception;
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::PyDict;

use ::ttball::config::yaml;
use ::ttball::config::{Config as CoreConfig, PredictionParams};
use ::ttball::model::detection::{Detection, Source};
use ::ttball::online::estimator::{
    Estimate, Estimator as CoreEstimator, Output, Rejection, RobotHit, Verdict,
};
use ::ttball::online::intercept::Intercept;
use ::ttball::online::stroke::{Aim, Rebound, ReturnFlight, Stroke};
use ::ttball::physics::{
    BallState, EventKind, PhysicsParams, PredictOptions, Propagator, RacketState, Trajectory,
    TrajectoryEnd, predict as predict_flight,
};

create_exception!(
    ttball,
    ConfigError,
    PyValueError,
    "A configuration file or parameter ttball refuses (the message names the key and the allowed range)."
);
create_exception!(
    ttball,
    ImpactError,
    PyValueError,
    "A racket hit that cannot be predicted (a non-finite input, a normal that is not a unit vector, a racket that does not meet the ball)."
);
create_exception!(
    ttball,
    PlanError,
    PyValueError,
    "No racket command returns the ball as asked."
);

/// A fixed-size vector from an array-like of floats, or a ValueError that names it.
fn vector<const N: usize>(
    what: &str,
    values: &PyArrayLike1<'_, f64, AllowTypeChange>,
) -> PyResult<SVector<f64, N>> {
    let values = elements(values);
    if values.len() != N {
        return Err(PyValueError::new_err(format!(
            "{what} must have {N} values, not {}",
            values.len()
        )));
    }
    Ok(SVector::from_column_slice(&values))
}

/// An array's elements in row-major order, whatever its memory layout (a slice of a bigger array
/// included).
fn elements<T: numpy::Element + Copy, D: numpy::ndarray::Dimension>(
    values: &numpy::PyArrayLike<'_, T, D, AllowTypeChange>,
) -> Vec<T> {
    values.as_array().iter().copied().collect()
}

/// A ball state from a 9-vector.
fn ball_state(what: &str, values: &PyArrayLike1<'_, f64, AllowTypeChange>) -> PyResult<BallState> {
    Ok(BallState::from_vector(&vector::<9>(what, values)?))
}

/// A numpy array of the values of a matrix, row by row, shaped `rows` x `columns`.
fn matrix_array<'py, const R: usize, const C: usize>(
    py: Python<'py>,
    m: &SMatrix<f64, R, C>,
) -> PyResult<Bound<'py, PyAny>> {
    let rows: Vec<f64> = (0..R)
        .flat_map(|i| (0..C).map(move |j| m[(i, j)]))
        .collect();
    Ok(PyArray1::from_vec(py, rows).reshape([R, C])?.into_any())
}

/// A numpy array of a vector's values.
fn vector_array<'py, const N: usize>(py: Python<'py>, v: &SVector<f64, N>) -> Bound<'py, PyAny> {
    PyArray1::from_slice(py, v.as_slice()).into_any()
}

/// ttball's configuration: the default, a parameters file, and parameters set by name.
///
/// `Config(file=None, params=None)`: `file` is a ROS 2 parameters file as `ttball --config`
/// takes (e.g. `config/ttball.yaml`, or a preset of `config/presets/`); `params` a dict of dotted
/// names to values, as `-p name:=value` sets them (`{"intercept.plane_x": -1.45}`), applied after
/// the file. Every key is checked as the command line checks it; a problem raises
/// `ttball.ConfigError` naming the key and the allowed range.
#[pyclass(frozen, module = "ttball")]
struct Config {
    inner: CoreConfig,
}

#[pymethods]
impl Config {
    #[new]
    #[pyo3(signature = (file=None, params=None))]
    fn new(file: Option<PathBuf>, params: Option<&Bound<'_, PyDict>>) -> PyResult<Self> {
        let mut overrides = Vec::new();
        if let Some(params) = params {
            let json = params.py().import("json")?;
            for (name, value) in params.iter() {
                let name: String = name.extract()?;
                // JSON is YAML: the value as the parameters file would write it.
                let text: String = json.call_method1("dumps", (value,))?.extract()?;
                overrides.push(format!("{name}:={text}"));
            }
        }
        let inner = yaml::load(file.as_deref(), &overrides)
            .map_err(|e| ConfigError::new_err(e.to_string()))?;
        Ok(Self { inner })
    }

    /// The effective configuration as a ROS 2 parameters file (what `ttball config print` writes).
    fn yaml(&self) -> String {
        yaml::to_ros_params_yaml(&self.inner)
    }

    /// Every parameter's dotted name.
    fn names(&self) -> Vec<String> {
        yaml::parameter_names(&self.inner)
    }

    /// The value of the parameter `name` (a dotted name, as `names()` lists them).
    fn get<'py>(&self, py: Python<'py>, name: &str) -> PyResult<Bound<'py, PyAny>> {
        let values = self.values(py)?;
        values
            .get_item(name)?
            .ok_or_else(|| ConfigError::new_err(format!("unknown parameter `{name}`")))
    }

    /// Every parameter's value by dotted name.
    fn values<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let tree =
            serde_json::to_value(&self.inner).map_err(|e| ConfigError::new_err(e.to_string()))?;
        let json = py.import("json")?;
        let out = PyDict::new(py);
        let mut stack = vec![(String::new(), &tree)];
        while let Some((prefix, value)) = stack.pop() {
            match value {
                serde_json::Value::Object(fields) => {
                    for (key, field) in fields {
                        let name = if prefix.is_empty() {
                            key.clone()
                        } else {
                            format!("{prefix}.{key}")
                        };
                        stack.push((name, field));
                    }
                }
                leaf => {
                    out.set_item(prefix, json.call_method1("loads", (leaf.to_string(),))?)?;
                }
            }
        }
        Ok(out)
    }

    fn __repr__(&self) -> String {
        "ttball.Config(...)  # .yaml() prints it".to_owned()
    }
}

/// The configuration given, or the default.
fn config_or_default(config: Option<&Config>) -> CoreConfig {
    config.map_or_else(CoreConfig::default, |c| c.inner.clone())
}

/// A ValueError unless a prediction's horizon and spacing are sensible (at most 100,000
/// samples, as the node's `~/predict_trajectory` allows).
fn check_prediction(horizon: f64, dt: f64) -> PyResult<()> {
    if !(horizon.is_finite() && (0.0..=10.0).contains(&horizon)) {
        return Err(PyValueError::new_err(format!(
            "horizon must be in [0, 10] s, not {horizon}"
        )));
    }
    if !(dt.is_finite() && dt > 0.0 && horizon / dt <= 100_000.0) {
        return Err(PyValueError::new_err(format!(
            "dt must be positive with at most 100,000 samples over the horizon, not {dt}"
        )));
    }
    Ok(())
}

fn end_name(end: TrajectoryEnd) -> &'static str {
    match end {
        TrajectoryEnd::Horizon => "horizon",
        TrajectoryEnd::Plane => "plane",
        TrajectoryEnd::Net => "net",
        TrajectoryEnd::Floor => "floor",
    }
}

fn event_name(kind: &EventKind) -> &'static str {
    match kind {
        EventKind::TableBounce { .. } => "bounce",
        EventKind::Net { .. } => "net",
        EventKind::Floor => "floor",
        EventKind::TableMiss { .. } => "table_miss",
        EventKind::Plane { .. } => "plane",
    }
}

/// The predicted flight of a ball state: table bounces, the net, the floor and the hitting
/// plane, with the configured physics (`aero`, `ball`, `table`).
///
/// `state`: 9 values (position [m], velocity [m/s], spin [rad/s]) in the table frame.
/// `horizon` [s] and `dt` [s] default to `prediction.horizon` and `prediction.trajectory_dt`;
/// `plane_x` [m] to `intercept.plane_x`.
///
/// Returns a dict: `t` (N,) [s], `states` (N, 9), `end` ("horizon", "net", "floor"), and
/// `events`, a list of dicts with `kind` ("bounce", "net", "plane", "floor", "table_miss"), `t`,
/// `before` (9,) and `after` (9,).
#[pyfunction]
#[pyo3(signature = (state, horizon=None, dt=None, config=None, plane_x=None))]
fn predict<'py>(
    py: Python<'py>,
    state: PyArrayLike1<'py, f64, AllowTypeChange>,
    horizon: Option<f64>,
    dt: Option<f64>,
    config: Option<&Config>,
    plane_x: Option<f64>,
) -> PyResult<Bound<'py, PyDict>> {
    let config = config_or_default(config);
    let start = ball_state("state", &state)?;
    let options = PredictOptions {
        horizon: horizon.unwrap_or(config.prediction.horizon),
        sample_interval: dt.unwrap_or(config.prediction.trajectory_dt),
        plane_x: Some(plane_x.unwrap_or(config.intercept.plane_x)),
        stop_at_plane: false,
    };
    check_prediction(options.horizon, options.sample_interval)?;
    let propagator = Propagator::new(&config);
    let trajectory = py.detach(|| predict_flight(&propagator, &start, &options));
    trajectory_dict(py, &trajectory)
}

/// A predicted flight as a dict.
fn trajectory_dict<'py>(py: Python<'py>, trajectory: &Trajectory) -> PyResult<Bound<'py, PyDict>> {
    let t: Vec<f64> = trajectory.samples.iter().map(|s| s.t).collect();
    let states: Vec<f64> = trajectory
        .samples
        .iter()
        .flat_map(|s| s.state.to_vector().as_slice().to_vec())
        .collect();
    let out = PyDict::new(py);
    let n = t.len();
    out.set_item("t", PyArray1::from_vec(py, t))?;
    out.set_item("states", PyArray1::from_vec(py, states).reshape([n, 9])?)?;
    out.set_item("end", end_name(trajectory.end))?;
    let mut events = Vec::with_capacity(trajectory.events.len());
    for event in &trajectory.events {
        let e = PyDict::new(py);
        e.set_item("kind", event_name(&event.kind))?;
        e.set_item("t", event.t)?;
        e.set_item("before", vector_array(py, &event.before))?;
        e.set_item("after", vector_array(py, &event.after))?;
        events.push(e);
    }
    out.set_item("events", events)?;
    Ok(out)
}

/// The return flight as a dict.
fn return_flight_dict<'py>(py: Python<'py>, flight: &ReturnFlight) -> PyResult<Bound<'py, PyDict>> {
    let out = PyDict::new(py);
    out.set_item("outcome", flight.outcome.describe())?;
    out.set_item(
        "lands",
        matches!(
            flight.outcome,
            ::ttball::online::stroke::ReturnOutcome::Lands
        ),
    )?;
    match flight.landing {
        Some((t, state)) => {
            out.set_item("landing_time", t)?;
            out.set_item("landing", vector_array(py, &state.to_vector()))?;
        }
        None => {
            out.set_item("landing_time", py.None())?;
            out.set_item("landing", py.None())?;
        }
    }
    out.set_item("net_clearance", flight.net.map(|(_, clearance)| clearance))?;
    Ok(out)
}

/// A rebound as a dict.
fn rebound_dict<'py>(py: Python<'py>, rebound: &Rebound) -> PyResult<Bound<'py, PyDict>> {
    let hit = &rebound.hit;
    let out = PyDict::new(py);
    out.set_item("ball", vector_array(py, &hit.ball.to_vector()))?;
    out.set_item("racket_velocity", vector_array(py, &hit.racket_velocity))?;
    out.set_item("impact_speed", hit.normal.impact_speed)?;
    out.set_item("reduced_mass", hit.normal.reduced_mass)?;
    out.set_item("restitution", hit.normal.restitution)?;
    out.set_item("contact_time", hit.normal.contact.contact_time)?;
    out.set_item("mean_force", hit.normal.contact.mean_force)?;
    out.set_item("peak_force", hit.normal.contact.peak_force)?;
    out.set_item("impulse", hit.normal.contact.impulse)?;
    out.set_item("return_flight", return_flight_dict(py, &rebound.flight)?)?;
    Ok(out)
}

/// The racket's hit of a ball and the return flight to its first bounce, through the impact
/// model (`racket`, `arm`, `rubber`: reduced mass at the impact point, velocity-dependent
/// restitution, contact time and force).
///
/// `ball`: the ball's 9-vector at impact; `racket_velocity` (3,) [m/s] of the impact point;
/// `racket_normal` (3,), a unit vector from the face toward the ball; `impact_offset` [m] from the
/// racket's centre of gravity along its long axis.
///
/// Returns a dict: `ball` (9,) just after, `racket_velocity` (3,) after, `impact_speed`,
/// `reduced_mass`, `restitution`, `contact_time`, `mean_force`, `peak_force`, `impulse`, and
/// `return_flight` (`outcome`, `lands`, `landing_time`, `landing` (9,), `net_clearance`).
/// Raises `ttball.ImpactError` when the hit cannot be predicted.
#[pyfunction]
#[pyo3(signature = (ball, racket_velocity, racket_normal, impact_offset=0.0, config=None))]
fn rebound<'py>(
    py: Python<'py>,
    ball: PyArrayLike1<'py, f64, AllowTypeChange>,
    racket_velocity: PyArrayLike1<'py, f64, AllowTypeChange>,
    racket_normal: PyArrayLike1<'py, f64, AllowTypeChange>,
    impact_offset: f64,
    config: Option<&Config>,
) -> PyResult<Bound<'py, PyDict>> {
    let stroke = Stroke::new(&config_or_default(config));
    let ball = ball_state("ball", &ball)?;
    let racket = RacketState {
        velocity: vector::<3>("racket_velocity", &racket_velocity)?,
        normal: vector::<3>("racket_normal", &racket_normal)?,
        impact_offset,
    };
    let rebound = stroke
        .rebound(&ball, &racket)
        .map_err(|e| ImpactError::new_err(e.to_string()))?;
    rebound_dict(py, &rebound)
}

/// The racket command that returns a ball to a target on the opponent's half: the racket's
/// velocity and face normal at impact, solved through the impact model and the return flight.
///
/// `ball`: the ball's 9-vector at impact; `target` (2,): the landing point (x, y) [m], x > 0;
/// the third condition is `flight_time` [s] from the hit to the landing if given, else
/// `net_clearance` [m] over the net, else `stroke.net_clearance`; `impact_offset` [m];
/// `brush_speed` [m/s] of the racket along its face (topspin when positive).
///
/// Returns a dict: `racket_velocity` (3,), `racket_normal` (3,), `impact_offset`,
/// `landing_error` [m], `iterations`, and `rebound` (as `rebound()` returns it). Raises
/// `ttball.PlanError` when no command does it.
#[pyfunction]
#[pyo3(signature = (ball, target, flight_time=None, net_clearance=None, impact_offset=0.0, brush_speed=0.0, config=None))]
#[allow(
    clippy::too_many_arguments,
    reason = "the Python signature, with keyword defaults"
)]
fn plan_return<'py>(
    py: Python<'py>,
    ball: PyArrayLike1<'py, f64, AllowTypeChange>,
    target: PyArrayLike1<'py, f64, AllowTypeChange>,
    flight_time: Option<f64>,
    net_clearance: Option<f64>,
    impact_offset: f64,
    brush_speed: f64,
    config: Option<&Config>,
) -> PyResult<Bound<'py, PyDict>> {
    let stroke = Stroke::new(&config_or_default(config));
    let ball = ball_state("ball", &ball)?;
    let target: Vector2<f64> = vector::<2>("target", &target)?;
    let aim = Aim {
        target,
        condition: stroke.condition(flight_time, net_clearance),
        impact_offset,
        brush_speed,
    };
    let plan = py
        .detach(|| stroke.plan(&ball, &aim))
        .map_err(|e| PlanError::new_err(e.to_string()))?;
    let out = PyDict::new(py);
    out.set_item("racket_velocity", vector_array(py, &plan.racket.velocity))?;
    out.set_item("racket_normal", vector_array(py, &plan.racket.normal))?;
    out.set_item("impact_offset", plan.racket.impact_offset)?;
    out.set_item("landing_error", plan.landing_error)?;
    out.set_item("iterations", plan.iterations)?;
    out.set_item("rebound", rebound_dict(py, &plan.rebound)?)?;
    Ok(out)
}

fn verdict_name(verdict: Verdict) -> &'static str {
    match verdict {
        Verdict::Fused { .. } => "fused",
        Verdict::Initializing => "initializing",
        Verdict::Held => "held",
        Verdict::Rejected(reason) => reason.name(),
    }
}

/// An estimate as a dict.
fn estimate_dict<'py>(py: Python<'py>, e: &Estimate) -> PyResult<Bound<'py, PyDict>> {
    let out = PyDict::new(py);
    out.set_item("stamp", e.stamp)?;
    out.set_item("track_id", e.track_id)?;
    out.set_item("status", e.status.code())?;
    out.set_item("state", vector_array(py, &e.state.to_vector()))?;
    out.set_item("covariance", matrix_array(py, &e.covariance)?)?;
    out.set_item("bounces", e.bounces)?;
    Ok(out)
}

/// An interception as a dict.
fn intercept_dict<'py>(py: Python<'py>, stamp: i64, i: &Intercept) -> PyResult<Bound<'py, PyDict>> {
    let out = PyDict::new(py);
    out.set_item("stamp", stamp)?;
    match &i.crossing {
        Ok(c) => {
            out.set_item("valid", true)?;
            out.set_item("reason", py.None())?;
            out.set_item("time", c.time)?;
            out.set_item("time_sigma", c.time_sigma)?;
            out.set_item("state", vector_array(py, &c.state.to_vector()))?;
            out.set_item("covariance", matrix_array(py, &c.covariance)?)?;
        }
        Err(reason) => {
            out.set_item("valid", false)?;
            out.set_item("reason", reason.describe())?;
        }
    }
    match &i.bounce {
        Some(b) => {
            out.set_item("bounce_time", b.time)?;
            out.set_item("bounce_position", vector_array(py, &b.position))?;
        }
        None => {
            out.set_item("bounce_time", py.None())?;
            out.set_item("bounce_position", py.None())?;
        }
    }
    Ok(out)
}

/// An optional 3x3 covariance from an array-like of 9 values (row-major) or 3x3; all zero or
/// `None` means the configured noise of the source.
fn covariance(
    what: &str,
    values: Option<&PyArrayLike2<'_, f64, AllowTypeChange>>,
) -> PyResult<Option<Matrix3<f64>>> {
    let Some(values) = values else {
        return Ok(None);
    };
    if values.shape() != [3, 3] {
        return Err(PyValueError::new_err(format!("{what} must be 3 x 3")));
    }
    let m = Matrix3::from_row_slice(&elements(values));
    Ok((m != Matrix3::zeros()).then_some(m))
}

/// The estimator: the node's extended Kalman filter, tracker and interception, fed detections one
/// at a time in arrival order, exactly as the node and `ttball replay` feed it (its lessons run
/// inline, so that a run is deterministic).
///
/// `Estimator(config=None)`.
#[pyclass(module = "ttball")]
struct Estimator {
    inner: CoreEstimator,
    prediction: PredictionParams,
}

#[pymethods]
impl Estimator {
    #[new]
    #[pyo3(signature = (config=None))]
    fn new(config: Option<&Config>) -> Self {
        let config = config_or_default(config);
        Self {
            inner: CoreEstimator::new(&config),
            prediction: config.prediction.clone(),
        }
    }

    /// Takes one detection and returns what the node would publish after it: a dict with
    /// `verdict` ("fused", "initializing", "held" or the rejection's reason, e.g. "gated"),
    /// `estimate` (`stamp`, `track_id`, `status`, `state` (9,), `covariance` (9, 9), `bounces`)
    /// and `intercept` (`valid`, `reason`, `time` [s from the estimate], `time_sigma`, `state`
    /// (9,) and `covariance` (9, 9) at the crossing of the hitting plane, `bounce_time`,
    /// `bounce_position`), each `None` when there is none.
    ///
    /// `stamp` [ns] is the exposure time; `position` (3,) [m] in the table frame; `source` the
    /// camera's id (1: the 150 fps camera, 2: the 900 fps one, or `sources.<name>.id`); `spin`
    /// (3,) [rad/s] when the camera measured it; covariances (3, 3) or `None` for the source's
    /// configured noise.
    #[pyo3(signature = (stamp, position, source=1, spin=None, position_covariance=None, spin_covariance=None, confidence=1.0))]
    #[allow(
        clippy::too_many_arguments,
        reason = "the Python signature, with keyword defaults"
    )]
    fn handle<'py>(
        &mut self,
        py: Python<'py>,
        stamp: i64,
        position: PyArrayLike1<'py, f64, AllowTypeChange>,
        source: u8,
        spin: Option<PyArrayLike1<'py, f64, AllowTypeChange>>,
        position_covariance: Option<PyArrayLike2<'py, f64, AllowTypeChange>>,
        spin_covariance: Option<PyArrayLike2<'py, f64, AllowTypeChange>>,
        confidence: f32,
    ) -> PyResult<Bound<'py, PyDict>> {
        let detection = Detection {
            stamp,
            source: Source(source),
            position: vector::<3>("position", &position)?,
            position_covariance: covariance("position_covariance", position_covariance.as_ref())?,
            spin: spin.as_ref().map(|s| vector::<3>("spin", s)).transpose()?,
            spin_covariance: covariance("spin_covariance", spin_covariance.as_ref())?,
            confidence,
        };
        let output = self.inner.handle(&detection);
        output_dict(py, &output)
    }

    /// Takes N detections in arrival order, as N calls of `handle` would, and returns arrays:
    /// `verdict` (list of N names), `track_id` (N,) (0 without an estimate), `state` (N, 9),
    /// `covariance` (N, 9, 9), `intercept_valid` (N,), `intercept_time` (N,) [s],
    /// `intercept_state` (N, 9); NaN where there is no estimate or no valid interception.
    ///
    /// `stamps` (N,) [ns]; `positions` (N, 3) [m]; `sources` (N,) camera ids (default 1);
    /// `spins` (N, 3) [rad/s], a row of NaN where the camera measured none.
    #[pyo3(signature = (stamps, positions, sources=None, spins=None))]
    fn handle_many<'py>(
        &mut self,
        py: Python<'py>,
        stamps: PyArrayLike1<'py, i64, AllowTypeChange>,
        positions: PyArrayLike2<'py, f64, AllowTypeChange>,
        sources: Option<PyArrayLike1<'py, i64, AllowTypeChange>>,
        spins: Option<PyArrayLike2<'py, f64, AllowTypeChange>>,
    ) -> PyResult<Bound<'py, PyDict>> {
        let stamps = elements(&stamps);
        let n = stamps.len();
        let rows =
            |what: &str, a: &PyArrayLike2<'py, f64, AllowTypeChange>| -> PyResult<Vec<f64>> {
                if a.shape() != [n, 3] {
                    return Err(PyValueError::new_err(format!(
                        "{what} must be N x 3 with N = {n} (one row a stamp), not {:?}",
                        a.shape()
                    )));
                }
                Ok(elements(a))
            };
        let positions = rows("positions", &positions)?;
        let spins = spins.as_ref().map(|s| rows("spins", s)).transpose()?;
        let sources = match &sources {
            Some(s) => {
                let s = elements(s);
                if s.len() != n {
                    return Err(PyValueError::new_err(format!(
                        "sources must have N = {n} values, not {}",
                        s.len()
                    )));
                }
                s.iter()
                    .map(|&id| {
                        u8::try_from(id).map_err(|_| {
                            PyValueError::new_err(format!("source {id} is not a camera id (0-255)"))
                        })
                    })
                    .collect::<PyResult<Vec<u8>>>()?
            }
            None => vec![Source::WIDE_150FPS.0; n],
        };
        let outputs: Vec<Output> = py.detach(|| {
            (0..n)
                .map(|k| {
                    let spin = spins
                        .as_ref()
                        .map(|s| Vector3::new(s[3 * k], s[3 * k + 1], s[3 * k + 2]))
                        .filter(|s| s.iter().all(|v| !v.is_nan()));
                    self.inner.handle(&Detection {
                        stamp: stamps[k],
                        source: Source(sources[k]),
                        position: Vector3::new(
                            positions[3 * k],
                            positions[3 * k + 1],
                            positions[3 * k + 2],
                        ),
                        position_covariance: None,
                        spin,
                        spin_covariance: None,
                        confidence: 1.0,
                    })
                })
                .collect()
        });
        let mut track_id = vec![0u32; n];
        let mut state = vec![f64::NAN; 9 * n];
        let mut cov = vec![f64::NAN; 81 * n];
        let mut valid = vec![false; n];
        let mut time = vec![f64::NAN; n];
        let mut crossing = vec![f64::NAN; 9 * n];
        let mut verdicts = Vec::with_capacity(n);
        for (k, out) in outputs.iter().enumerate() {
            verdicts.push(verdict_name(out.verdict));
            if let Some(e) = &out.estimate {
                track_id[k] = e.track_id;
                state[9 * k..9 * k + 9].copy_from_slice(e.state.to_vector().as_slice());
                for i in 0..9 {
                    for j in 0..9 {
                        cov[81 * k + 9 * i + j] = e.covariance[(i, j)];
                    }
                }
            }
            if let Some(Ok(c)) = out.intercept.as_ref().map(|i| i.intercept.crossing) {
                valid[k] = true;
                time[k] = c.time;
                crossing[9 * k..9 * k + 9].copy_from_slice(c.state.to_vector().as_slice());
            }
        }
        let result = PyDict::new(py);
        result.set_item("verdict", verdicts)?;
        result.set_item("track_id", PyArray1::from_vec(py, track_id))?;
        result.set_item("state", PyArray1::from_vec(py, state).reshape([n, 9])?)?;
        result.set_item(
            "covariance",
            PyArray1::from_vec(py, cov).reshape([n, 9, 9])?,
        )?;
        result.set_item("intercept_valid", PyArray1::from_vec(py, valid))?;
        result.set_item("intercept_time", PyArray1::from_vec(py, time))?;
        result.set_item(
            "intercept_state",
            PyArray1::from_vec(py, crossing).reshape([n, 9])?,
        )?;
        Ok(result)
    }

    /// The current estimate (a dict as `handle` returns it), or `None` without a track.
    fn estimate<'py>(&self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyDict>>> {
        self.inner
            .estimate()
            .map(|e| estimate_dict(py, &e))
            .transpose()
    }

    /// The predicted flight of the tracked ball from its estimate, with the physics the estimator
    /// has learned (a dict as `ttball.predict` returns it), or `None` without a track.
    #[pyo3(signature = (horizon=None, dt=None))]
    fn predict<'py>(
        &self,
        py: Python<'py>,
        horizon: Option<f64>,
        dt: Option<f64>,
    ) -> PyResult<Option<Bound<'py, PyDict>>> {
        let horizon = horizon.unwrap_or(self.prediction.horizon);
        let dt = dt.unwrap_or(self.prediction.trajectory_dt);
        check_prediction(horizon, dt)?;
        self.inner
            .predicted_trajectory(dt, horizon)
            .map(|(_, trajectory)| trajectory_dict(py, &trajectory))
            .transpose()
    }

    /// What the estimator has learned of the physics: each parameter's value and standard
    /// deviation (`drag_scale`, `magnus_scale`, `restitution`, `friction`,
    /// `reynolds_exponent_a_D`, `reynolds_exponent_a_M`), and `tracks`.
    fn learned<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let learned = self.inner.learned_params();
        let out = PyDict::new(py);
        let values = learned.params.to_vector();
        for (k, name) in PhysicsParams::NAMES.iter().enumerate() {
            out.set_item(*name, (values[k], learned.sigma[k]))?;
        }
        for (k, name) in ::ttball::online::learned::REYNOLDS_EXPONENT_NAMES
            .iter()
            .enumerate()
        {
            out.set_item(
                format!("reynolds_exponent_{name}"),
                (learned.reynolds_exponents[k], learned.reynolds_sigma[k]),
            )?;
        }
        out.set_item("tracks", learned.tracks)?;
        Ok(out)
    }

    /// What happened to the detections so far: counts by verdict and rejections by reason.
    fn counters<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let c = self.inner.counters();
        let out = PyDict::new(py);
        out.set_item("received", c.received)?;
        out.set_item("fused", c.fused)?;
        out.set_item("initializing", c.initializing)?;
        out.set_item("tracks", c.tracks)?;
        out.set_item("rollbacks", c.rollbacks)?;
        out.set_item("seeded_by_hit", c.seeded_by_hit)?;
        out.set_item("hits_not_seeded", c.hits_not_seeded)?;
        let rejected = PyDict::new(py);
        for reason in Rejection::ALL {
            rejected.set_item(reason.name(), c.rejected(reason))?;
        }
        out.set_item("rejected", rejected)?;
        Ok(out)
    }

    /// Announces the robot's next hit, as the node's `robot/hits` topic does: the first detection
    /// after `stamp` [ns] that the predicted rebound explains starts the return's track at once
    /// (the live ball carried to the impact and hit by the racket whose impact point moves at
    /// `racket_velocity` (3,) [m/s] with face normal `racket_normal` (3,), `impact_offset` [m]).
    /// A later announcement replaces an earlier one; one that seeds nothing is counted
    /// (`counters()["hits_not_seeded"]`).
    #[pyo3(signature = (stamp, racket_velocity, racket_normal, impact_offset=0.0))]
    fn expect_hit(
        &mut self,
        stamp: i64,
        racket_velocity: PyArrayLike1<'_, f64, AllowTypeChange>,
        racket_normal: PyArrayLike1<'_, f64, AllowTypeChange>,
        impact_offset: f64,
    ) -> PyResult<()> {
        self.inner.expect_hit(RobotHit {
            stamp,
            racket: RacketState {
                velocity: vector::<3>("racket_velocity", &racket_velocity)?,
                normal: vector::<3>("racket_normal", &racket_normal)?,
                impact_offset,
            },
        });
        Ok(())
    }

    /// Ends the input: the live track's lesson is learned, as at the end of a replay.
    fn end_of_input(&mut self) {
        self.inner.end_of_input();
    }
}

/// An output as a dict.
fn output_dict<'py>(py: Python<'py>, output: &Output) -> PyResult<Bound<'py, PyDict>> {
    let out = PyDict::new(py);
    out.set_item("verdict", verdict_name(output.verdict))?;
    out.set_item(
        "estimate",
        output
            .estimate
            .as_ref()
            .map(|e| estimate_dict(py, e))
            .transpose()?,
    )?;
    out.set_item(
        "intercept",
        output
            .intercept
            .as_ref()
            .map(|i| intercept_dict(py, i.stamp, &i.intercept))
            .transpose()?,
    )?;
    Ok(out)
}

/// ttball: a table-tennis ball-state estimator. Trajectory prediction (`predict`), the racket
/// rebound (`rebound`), the return plan (`plan_return`) and the estimator (`Estimator`), on the
/// configuration `Config` gives. States are 9-vectors (position [m], velocity [m/s], spin [rad/s])
/// in the table frame (x along the table toward the opponent, z up, origin at the table's centre
/// on its surface).
#[pymodule(name = "ttball")]
fn ttball_module(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    m.add_class::<Config>()?;
    m.add_class::<Estimator>()?;
    m.add_function(wrap_pyfunction!(predict, m)?)?;
    m.add_function(wrap_pyfunction!(rebound, m)?)?;
    m.add_function(wrap_pyfunction!(plan_return, m)?)?;
    m.add("ConfigError", m.py().get_type::<ConfigError>())?;
    m.add("ImpactError", m.py().get_type::<ImpactError>())?;
    m.add("PlanError", m.py().get_type::<PlanError>())?;
    Ok(())
}
