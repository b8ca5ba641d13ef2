//! Configuration: every physical constant and tuning value of ttball, with its unit and source.
//!
//! These are plain data structs (no I/O). The shipped `config/ttball.yaml` is the same defaults as a
//! ROS 2 parameters file; a test checks that the two agree. Loading from YAML with `-p` overrides
//! lives in [`yaml`] (feature `interface`).

use serde::{Deserialize, Serialize};

/// The ball (ITTF 40+ ball by default; physics.md "Frames, units, time").
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BallParams {
    /// Ball radius [m]. ITTF 40+: 0.020 m.
    pub radius: f64,
    /// Ball mass [kg]. ITTF 40+: 2.7 g.
    pub mass: f64,
}

impl Default for BallParams {
    fn default() -> Self {
        Self {
            radius: 0.020,
            mass: 0.0027,
        }
    }
}

/// Air properties (20 °C, 1 atm).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AirParams {
    /// Air density [kg/m^3].
    pub density: f64,
    /// Kinematic viscosity [m^2/s]; used to report the Reynolds number of a flight.
    pub kinematic_viscosity: f64,
}

impl Default for AirParams {
    fn default() -> Self {
        Self {
            density: 1.20,
            kinematic_viscosity: 1.512e-5,
        }
    }
}

/// Spin-parameter aerodynamic model (Isomura et al., seed 004, Table 3; physics.md "Flight").
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AeroParams {
    /// Drag coefficient polynomial C_D(Sp) = sum_i c_i Sp^i, lowest order first [-].
    pub drag_coefficients: Vec<f64>,
    /// Magnus coefficient polynomial C_M(Sp) = sum_i c_i Sp^i, lowest order first [-].
    pub magnus_coefficients: Vec<f64>,
    /// The polynomials are evaluated at Sp clamped to [0, spin_parameter_max] [-]; the fit covers
    /// 0.1 < Sp < 2.0 and 0.5 < |v| < 10 m/s.
    pub spin_parameter_max: f64,
    /// Exponential spin decay in flight, dw/dt = -rate * w [1/s]. The seed model has none (0).
    pub spin_decay_rate: f64,
}

impl Default for AeroParams {
    fn default() -> Self {
        Self {
            drag_coefficients: vec![0.3682, 0.3591, -0.0747],
            magnus_coefficients: vec![0.8254, -1.9501, 2.2813, -1.2055, 0.2313],
            spin_parameter_max: 2.0,
            spin_decay_rate: 0.0,
        }
    }
}

/// Table geometry (ITTF) and the bounce model (Nakashima et al., ACC 2010; physics.md "Table bounce").
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TableParams {
    /// Playing surface length along x [m]. ITTF: 2.74 m.
    pub length: f64,
    /// Playing surface width along y [m]. ITTF: 1.525 m.
    pub width: f64,
    /// Height of the playing surface above the floor [m]. ITTF: 0.76 m.
    pub height: f64,
    /// Net height above the surface, at x = 0 [m]. ITTF: 0.1525 m.
    pub net_height: f64,
    /// How far the net posts stand outside each sideline [m]. ITTF: 0.1525 m.
    pub net_overhang: f64,
    /// Normal coefficient of restitution e_t of the ball on the table [-]. Published fits 0.88-0.93.
    pub restitution: f64,
    /// Coulomb friction coefficient mu_t between ball and table [-]. Published fits 0.1-0.3.
    pub friction: f64,
}

impl Default for TableParams {
    fn default() -> Self {
        Self {
            length: 2.74,
            width: 1.525,
            height: 0.76,
            net_height: 0.1525,
            net_overhang: 0.1525,
            restitution: 0.90,
            friction: 0.25,
        }
    }
}

/// Standard gravity [m/s^2].
pub const STANDARD_GRAVITY: f64 = 9.80665;

/// Numerical settings of the flight propagator.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PredictionParams {
    /// Largest RK4 step [s]; events inside a step are root-found, so this only sets accuracy.
    pub step: f64,
    /// How far ahead predictions look [s].
    pub horizon: f64,
}

impl Default for PredictionParams {
    fn default() -> Self {
        Self {
            step: 0.002,
            horizon: 1.5,
        }
    }
}

/// The whole configuration of ttball (the `ttball: ros__parameters:` block of `config/ttball.yaml`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Config {
    /// Gravitational acceleration [m/s^2], along -z of the table frame.
    pub gravity: f64,
    /// The ball.
    pub ball: BallParams,
    /// The air.
    pub air: AirParams,
    /// The aerodynamic model.
    pub aero: AeroParams,
    /// Table geometry and bounce.
    pub table: TableParams,
    /// Flight propagation settings.
    pub prediction: PredictionParams,
    // CONFIG-HELPER: further sections (racket, arm, ekf, sources, gating, tracking, intercept,
    // topics, qos, node) are added here.
}

impl Default for Config {
    fn default() -> Self {
        Self {
            gravity: STANDARD_GRAVITY,
            ball: BallParams::default(),
            air: AirParams::default(),
            aero: AeroParams::default(),
            table: TableParams::default(),
            prediction: PredictionParams::default(),
        }
    }
}
