//! Configuration: every physical constant and tuning value of ttball, with its unit and source.
//!
//! These are plain data structs (no I/O) with their defaults; [`Config::validate`] checks every
//! range. The shipped `config/ttball.yaml` is the same defaults as a ROS 2 parameters file, with
//! the unit and source of every key; a test checks that the two agree. Loading from YAML with `-p`
//! overrides lives in `yaml` (feature `interface`).
//!
//! Every parameter is a ROS 2 parameter type (bool, integer, double, string or an array of one of
//! those), so the node can declare each dotted key (`table.restitution`) as a ROS 2 parameter.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

use crate::model::detection::Source;

pub mod names;
pub mod range;
mod validate;
#[cfg(feature = "interface")]
pub mod yaml;

pub use range::{CountRange, Range};
pub use validate::{ConfigError, Violation};

/// The ball (ITTF 40+ ball by default; docs/models.md "Frames, units and time").
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
    /// Kinematic viscosity [m^2/s]: the Reynolds number Re = 2 r |v| / nu of the aerodynamic
    /// coefficients (`aero.reynolds_*`).
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

/// Most coefficients an aerodynamic polynomial may have (degree 7): the flight model holds them
/// inline ([`crate::physics::aero::Polynomial`]), so validation refuses longer lists.
pub const MAX_POLYNOMIAL_COEFFICIENTS: usize = 8;

/// Spin-parameter aerodynamic model (Isomura et al. 2014, Table 3; docs/models.md "Flight").
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
    /// Scale factor k_D on the drag force of `drag_coefficients` [-]: the start of the
    /// estimator's adaptation (`adaptation.*`), 1 = the polynomial as given.
    pub drag_scale: f64,
    /// Scale factor k_M on the Magnus force of `magnus_coefficients` [-], likewise.
    pub magnus_scale: f64,
    /// [Re_0, Re_max]: the Reynolds numbers Re = 2 r |v| / nu between which the coefficients
    /// follow `reynolds_exponents` [-]; well below Re_0 they are the polynomials', well above
    /// Re_max they are held, joined smoothly ([`crate::physics::aero`]).
    pub reynolds_range: Vec<f64>,
    /// [a_D, a_M]: C_D(Re, Sp) = C_D(Sp) f(Re)^a_D and C_M(Re, Sp) = C_M(Sp) f(Re)^a_M, f(Re)
    /// = Re / Re_0 inside `reynolds_range` [-].
    pub reynolds_exponents: Vec<f64>,
}

impl Default for AeroParams {
    /// The 40 mm plastic ball: C_D(Sp) = 0.42 + 0.15 Sp, C_M(Sp) = 0.42 - 0.30 Sp + 0.07 Sp^2 at
    /// k_M = 0.70, the drag falling as Re^-0.3 and the Magnus force as Re^-0.65 above
    /// Re = 1.6e4, the spin decaying at 1 /s (see `config/ttball.yaml` for where the numbers
    /// come from).
    fn default() -> Self {
        Self {
            drag_coefficients: vec![0.42, 0.15],
            magnus_coefficients: vec![0.42, -0.30, 0.07],
            magnus_scale: 0.70,
            reynolds_range: vec![1.6e4, 9.0e4],
            reynolds_exponents: vec![-0.3, -0.65],
            spin_decay_rate: 1.0,
            ..Self::seed_2014()
        }
    }
}

impl AeroParams {
    /// The seed's polynomials (Isomura et al. 2014, Table 3), a CFD fit for an older
    /// ball: `config/presets/seed_2014.yaml`.
    pub fn seed_2014() -> Self {
        Self {
            drag_coefficients: vec![0.3682, 0.3591, -0.0747],
            magnus_coefficients: vec![0.8254, -1.9501, 2.2813, -1.2055, 0.2313],
            spin_parameter_max: 2.0,
            spin_decay_rate: 0.0,
            drag_scale: 1.0,
            magnus_scale: 1.0,
            reynolds_range: vec![1.6e4, 9.0e4],
            reynolds_exponents: vec![0.0, 0.0],
        }
    }
}

/// Table geometry (ITTF) and the bounce model (Nakashima et al., ACC 2010; docs/models.md "Table bounce").
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

/// The seed racket of Kawazoe & Suzuki (Kawazoe & Suzuki; docs/models.md "Racket impact").
///
/// Used by the racket-impact model: the reduced mass of the racket at the impact point,
/// M_r = I_G M_R / (I_G + M_R b^2), and the force transmitted to the grip.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RacketParams {
    /// Racket mass M_R including both rubbers [kg]. Seed racket: 171 g (rubbers 79.5 g).
    pub mass: f64,
    /// Distance from the grip end to the racket's centre of gravity [m]. Seed racket: 147 mm.
    pub center_of_gravity_from_grip_end: f64,
    /// Moment of inertia I_G about the centre of gravity, for rotation in the plane of the long
    /// axis and the face normal [kg m^2]. Seed racket: 2.51 g m^2; the transcription says "about
    /// the grip", but only the centre-of-gravity reading reproduces the paper's 78.1 g reduced
    /// mass at b = 0.132 m (docs/models.md).
    pub inertia_about_center_of_gravity: f64,
    /// Moment of inertia about the racket's long axis [kg m^2]. Seed racket: 0.26 g m^2.
    pub inertia_about_long_axis: f64,
    /// Area of the hitting face [m^2]. Seed racket: 185 cm^2.
    pub face_area: f64,
    /// Thickness of the rubber's sponge layer [m]. Seed racket: 1.9 mm; 0 for a pimpled
    /// rubber without sponge.
    pub sponge_thickness: f64,
    /// Where the hitting face begins along the long axis, from the grip end [m]: impact points
    /// closer to the grip are refused. The seeds give no value; 100 mm is a common handle length.
    pub face_start_from_grip_end: f64,
    /// The farthest impact point along the long axis, from the grip end [m]. Seed racket: the top
    /// point A at b = 132 mm from the centre of gravity, 279 mm from the grip end (Kawazoe & Suzuki).
    pub face_end_from_grip_end: f64,
    /// Coefficient of restitution of the ball on the clamped rubber, e_RB(V) = c0 + c1 V + ...,
    /// V the normal impact speed [m/s], lowest order first; clamped to [0, 1]. Default: the
    /// inverted rubbers of tt_rackets (source in config/ttball.yaml).
    pub rubber_restitution: Vec<f64>,
    /// Coulomb friction coefficient between ball and rubber [-]: the tangential impulse is at most
    /// this times the normal impulse (docs/models.md "Racket impact"; source in config/ttball.yaml).
    pub rubber_friction: f64,
    /// Tangential coefficient of restitution of ball on rubber, e_t [-], in [-1, 1]: where the
    /// rubber grips the ball, the contact point's tangential velocity relative to the face
    /// leaves reversed to -e_t times what it was (Garwin 1969; Cross 2002). 0: the ball leaves
    /// rolling (the seed's model); > 0: a tangentially elastic rubber returns spin beyond
    /// rolling; Coulomb friction (`rubber_friction`) still caps the impulse.
    pub rubber_tangential_restitution: f64,
    /// Torsional coefficient of restitution of ball on rubber, e_z [-], in [-1, 1]: the ball's
    /// spin about the face normal leaves as e_z times what it was (the contact patch's twist:
    /// 1 keeps it, the seed's model, which has no torque about the normal; 0 stops it; < 0 a
    /// rubber that grips the patch and twists back). An empirical coefficient of ttball's,
    /// calibrated on recorded hits (`ttball calibrate --rebound`; docs/racket.md).
    pub rubber_torsional_restitution: f64,
    /// Covariance of the rubber's calibrated constants, row-major over (rubber_restitution[0..n],
    /// rubber_friction, rubber_tangential_restitution, rubber_torsional_restitution), (n + 3)^2
    /// values; empty (default): known exactly. `ttball calibrate --rebound` writes it; the
    /// landing covariance of a planned return includes it.
    pub rubber_covariance: Vec<f64>,
    /// Scatter of single hits about the model, per component of the outgoing velocity [m/s] and
    /// spin [rad/s] (what the calibration leaves unexplained: rubber, ball and measurement); the
    /// landing covariance of a planned return includes it. Default [0, 0].
    pub rebound_scatter: Vec<f64>,
    /// Restoring characteristic of the ball-rubber system, F = f(K) = c0 + c1 K + c2 K^2 + ...
    /// with F [N] and K = dF/dX [N/m], lowest order first (Kawazoe & Suzuki eq. (1) is this curve in kgf
    /// and kgf/mm: multiply c_i by 9.80665 / 9806.65^i). Default and source in
    /// config/ttball.yaml.
    pub restoring_force_vs_stiffness: Vec<f64>,
    /// Natural frequencies of the racket plate's modes counted in the vibration loss [Hz]
    /// (Kawazoe & Suzuki eq. 14-20). Empty (default): no vibration loss, as the seed concludes it is
    /// negligible.
    pub vibration_mode_frequencies: Vec<f64>,
    /// Modal mass of each of those modes at the impact point [kg] (1 / squared mass-normalised
    /// mode shape there), one per frequency.
    pub vibration_mode_masses: Vec<f64>,
}

impl Default for RacketParams {
    fn default() -> Self {
        Self {
            mass: 0.171,
            center_of_gravity_from_grip_end: 0.147,
            inertia_about_center_of_gravity: 2.51e-3,
            inertia_about_long_axis: 0.26e-3,
            face_area: 0.0185,
            sponge_thickness: 0.0019,
            face_start_from_grip_end: 0.10,
            face_end_from_grip_end: 0.279,
            rubber_restitution: vec![0.897019, -0.021778],
            rubber_friction: 0.604901,
            rubber_tangential_restitution: 0.678499,
            rubber_torsional_restitution: -0.173825,
            rubber_covariance: DEFAULT_RUBBER_COVARIANCE.to_vec(),
            rebound_scatter: vec![0.235568, 12.480061],
            restoring_force_vs_stiffness: vec![0.0, 0.0, 0.0, HERTZ_RESTORING_CUBIC],
            vibration_mode_frequencies: Vec::new(),
            vibration_mode_masses: Vec::new(),
        }
    }
}

/// Covariance of the default rubber's calibrated constants, row by row over (e_RB's two
/// coefficients, friction, tangential and torsional restitution), as `ttball calibrate
/// --rebound` wrote it (source in config/ttball.yaml).
#[rustfmt::skip]
const DEFAULT_RUBBER_COVARIANCE: [f64; 25] = [
    3.367062e-5, -4.269639e-6, -1.822356e-6, 0.0, 0.0,
    -4.269639e-6, 5.647390e-7, 1.775451e-7, 0.0, 0.0,
    -1.822356e-6, 1.775451e-7, 2.456105e-6, 0.0, 0.0,
    0.0, 0.0, 0.0, 6.396476e-6, 0.0,
    0.0, 0.0, 0.0, 0.0, 3.052353e-4,
];

/// Default restoring characteristic F = c3 K^3 [N per (N/m)^3]: the Hertz contact law
/// F = k X^{3/2} written as F = f(K) (K = dF/dX gives F = 8 K^3 / (27 k^2)), with k set to
/// reproduce a published contact time (source in config/ttball.yaml).
pub const HERTZ_RESTORING_CUBIC: f64 = 2.3834e-12;

/// What holds the racket (Kawazoe & Suzuki eq. 5-6; Kawazoe et al. 2010 eq. 23-26).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ArmParams {
    /// Equivalent mass M_H of the arm or robot wrist, lumped at the grip [kg]. Human arm: about
    /// 1.0 kg (0.97 kg for a 60 kg, 170 cm player, Kawazoe & Suzuki). A robot sets its wrist's effective
    /// mass at the grip; a large value approximates a rigidly held racket, 0 a free racket.
    pub equivalent_mass: f64,
    /// Where that mass is attached: the hand's or the wrist flange's distance from the grip end
    /// [m] (L_H of Kawazoe et al. 2010 eq. 24-26).
    pub grip_from_grip_end: f64,
}

impl Default for ArmParams {
    fn default() -> Self {
        Self {
            equivalent_mass: 1.0,
            grip_from_grip_end: 0.05,
        }
    }
}

/// The racket command planner (`ttball aim`, `~/plan_return`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StrokeParams {
    /// Largest speed of the racket's impact point the planner may command [m/s].
    pub max_racket_speed: f64,
    /// Height of the ball's bottom over the net top when the request asks for neither a
    /// clearance nor a flight time [m].
    pub net_clearance: f64,
}

impl Default for StrokeParams {
    fn default() -> Self {
        Self {
            max_racket_speed: 8.0,
            net_clearance: 0.15,
        }
    }
}

/// Largest RK4 step the configuration accepts [s]: `prediction.step` and the simulator's
/// `aim_step` are validated against it.
pub const MAX_STEP: f64 = 0.05;

/// Numerical settings of the flight propagator and of the published trajectory.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PredictionParams {
    /// Largest RK4 step [s]; events inside a step are root-found, so this only sets accuracy and
    /// cost (RK4 error after 0.8 s of flight: 2e-6 m at 40 ms, 1.3e-7 m at 20 ms, 8e-9 m at 10 ms).
    pub step: f64,
    /// How far ahead predictions look [s].
    pub horizon: f64,
    /// Publishing rate of the predicted trajectory on `topics.trajectory` [Hz]; the trajectory is
    /// recomputed this often, not for every detection, off the detections that predict the
    /// interception in full where it can (see [`crate::ros::pipeline`]).
    pub trajectory_rate: f64,
    /// Time between two samples of the published trajectory [s]; horizon / trajectory_dt samples.
    pub trajectory_dt: f64,
}

impl Default for PredictionParams {
    fn default() -> Self {
        Self {
            step: 0.04,
            horizon: 1.5,
            trajectory_rate: 50.0,
            trajectory_dt: 0.01,
        }
    }
}

/// Where the robot hits the ball.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct InterceptParams {
    /// The robot's hitting plane is x = plane_x in the table frame [m]. Default: 0.23 m behind the
    /// robot's baseline (x = -1.37 m), where an incoming ball has bounced and is near its apex.
    pub plane_x: f64,
    /// When the interception after a detection is predicted in full again rather than moved to
    /// first order from the last full prediction.
    pub refresh: RefreshParams,
}

impl Default for InterceptParams {
    fn default() -> Self {
        Self {
            plane_x: -1.6,
            refresh: RefreshParams::default(),
        }
    }
}

/// Limits of the first-order interception update (see `intercept::InterceptTracker`): a drift
/// past one of them and past half the state's own standard deviation, the age past `max_age`,
/// an event or a change of branch, and the interception is predicted in full.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RefreshParams {
    /// Longest time between two full predictions [s]; 0 predicts in full after every detection.
    pub max_age: f64,
    /// Largest drift of the estimated position from the last full prediction's flight [m].
    pub position: f64,
    /// Largest drift of the estimated velocity [m/s].
    pub velocity: f64,
    /// Largest drift of the estimated spin [rad/s].
    pub spin: f64,
}

impl Default for RefreshParams {
    fn default() -> Self {
        Self {
            max_age: 0.1,
            position: 0.01,
            velocity: 0.05,
            spin: 3.0,
        }
    }
}

/// Measurement noise and latency of one kind of camera source.
///
/// The EKF uses these sigmas for a detection whose own covariance is all zero (isotropic,
/// uncorrelated noise R = sigma^2 I per measured block).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SourceParams {
    /// The `BallDetection.source` code of this camera's detections: `SOURCE_WIDE_150FPS` (1),
    /// `SOURCE_HIGHSPEED_900FPS` (2), or an id of the camera pipeline's choosing for more
    /// cameras (3-255). `unknown` has `SOURCE_UNKNOWN` (0), and also takes the detections of
    /// every id no source has.
    pub id: u8,
    /// Standard deviation of one position measurement, per axis [m].
    pub position_sigma: f64,
    /// Standard deviation of one spin measurement, per axis [rad/s]; 0 means the source does not
    /// measure spin, and spin values in its detections are ignored.
    pub spin_sigma: f64,
    /// Nominal latency from exposure to the detection's arrival [s]; the simulator delays the
    /// detections of this source by it.
    pub latency: f64,
    /// Standard deviation of a detection's stamp about its true exposure time [s]: it moves the
    /// measured position along the flight by the velocity times as much (millisecond stamps:
    /// 0.29 ms; a jittered exposure clock: more). 0: exact stamps. The estimator learns the
    /// timing and position noise each source really has, starting here.
    pub stamp_sigma: f64,
    /// Frames per second the source delivers while it sees the ball [Hz]: the node's
    /// `/diagnostics` warns when its stamps show another rate and reports it STALE when it falls
    /// silent while the other sources deliver. 0: no expectation (a setup without this camera).
    pub frame_rate: f64,
}

/// Measurement noise per camera source (docs/models.md "Cameras"), each matched
/// to detections by its `id`. The two cameras of the seed setup and `unknown` are always there;
/// more cameras are added by name (`sources.side_camera.id: 3`, ...).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SourcesParams {
    /// The 150 fps camera that sees the whole table; position only.
    pub wide_150fps: SourceParams,
    /// The 900 fps camera with a narrow view; measures spin from marks on the ball.
    pub highspeed_900fps: SourceParams,
    /// Detections whose source is not one of the others.
    pub unknown: SourceParams,
    /// More cameras, by name (the key under `sources`).
    #[serde(flatten)]
    pub more: BTreeMap<String, SourceParams>,
}

/// The name of the source every unconfigured id falls back to.
pub const UNKNOWN_SOURCE: &str = "unknown";

impl SourcesParams {
    /// Every source by name, in their index order ([`SourceIndex`]): `unknown` (index 0),
    /// `wide_150fps`, `highspeed_900fps`, then the others by name.
    pub fn all(&self) -> Vec<(&str, &SourceParams)> {
        let mut all = vec![
            (UNKNOWN_SOURCE, &self.unknown),
            ("wide_150fps", &self.wide_150fps),
            ("highspeed_900fps", &self.highspeed_900fps),
        ];
        all.extend(self.more.iter().map(|(name, p)| (name.as_str(), p)));
        all
    }

    /// The source of that name (`sources.<name>`), to change.
    pub fn by_name_mut(&mut self, name: &str) -> Option<&mut SourceParams> {
        match name {
            UNKNOWN_SOURCE => Some(&mut self.unknown),
            "wide_150fps" => Some(&mut self.wide_150fps),
            "highspeed_900fps" => Some(&mut self.highspeed_900fps),
            _ => self.more.get_mut(name),
        }
    }

    /// Each detection source's place in [`SourcesParams::all`].
    pub fn index(&self) -> SourceIndex {
        let mut of_id = [0u8; 256];
        // Later sources cannot share an id (`Config::validate`); `unknown` is the fallback.
        for (i, (_, p)) in self.all().iter().enumerate().skip(1).rev() {
            of_id[usize::from(p.id)] = u8::try_from(i).unwrap_or(0);
        }
        SourceIndex { of_id }
    }
}

/// Where a detection's source sits in per-source arrays ordered as [`SourcesParams::all`]:
/// the source configured with its id, else `unknown` (0).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SourceIndex {
    of_id: [u8; 256],
}

impl SourceIndex {
    /// The index of `source`'s configuration.
    pub fn of(&self, source: Source) -> usize {
        usize::from(self.of_id[usize::from(source.0)])
    }
}

impl Default for SourcesParams {
    fn default() -> Self {
        Self {
            // Stereo triangulation of a 40 mm ball over the whole table: a few mm. Latency about
            // one frame period (6.7 ms) plus detection.
            wide_150fps: SourceParams {
                id: Source::WIDE_150FPS.0,
                position_sigma: 0.002,
                spin_sigma: 0.0,
                latency: 0.008,
                stamp_sigma: 0.0,
                frame_rate: 150.0,
            },
            // Narrow view, so finer pixels; spin from the marks on the ball.
            highspeed_900fps: SourceParams {
                id: Source::HIGHSPEED_900FPS.0,
                position_sigma: 0.001,
                spin_sigma: 12.0,
                latency: 0.004,
                stamp_sigma: 0.0,
                frame_rate: 900.0,
            },
            // Conservative: worse than either known camera.
            unknown: SourceParams {
                id: Source::UNKNOWN.0,
                position_sigma: 0.005,
                spin_sigma: 30.0,
                latency: 0.008,
                stamp_sigma: 0.0,
                frame_rate: 0.0,
            },
            more: BTreeMap::new(),
        }
    }
}

/// The extended Kalman filter's noise: what the physics leaves out, what a new track does not
/// know, and what a detection is worth (docs/estimator.md, "The filter").
///
/// Process noise over a step dt, per axis (white-acceleration model plus spin random walk):
/// Q_pp = q_a dt^3 / 3, Q_pv = q_a dt^2 / 2, Q_vv = q_a dt, Q_ww = q_w dt.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct EkfParams {
    /// q_a: the power spectral density of the white acceleration the flight model leaves out
    /// [m^2/s^3], > 0. The velocity wanders by sqrt(q_a t): 0.045 m/s over 1 s at the default.
    /// Source: the white-noise acceleration model (Bar-Shalom, Li & Kirubarajan, "Estimation
    /// with Applications to Tracking and Navigation", 2001, sec. 6.2); its size is a tuning
    /// value, small because 1 rad/s of spin changes the acceleration by only about 5 mm/s^2.
    pub acceleration_noise_density: f64,
    /// q_w: the power spectral density of the spin's random walk [(rad/s)^2/s], >= 0. The
    /// flight model keeps the spin constant (docs/models.md); this lets the estimate drift by
    /// sqrt(q_w t) rad/s. Tuning value.
    pub spin_noise_density: f64,
    /// The prior standard deviation of a new track's spin about zero, per axis [rad/s], > 0,
    /// unless a camera measured it. 300 covers 600 rad/s at 2 sigma; real rally balls reach
    /// 363 rad/s (Google DeepMind's initial ball states, docs/references.md).
    pub spin_prior_sigma: f64,
    /// Detections with a confidence below this are ignored [-], in [0, 1]; 0 accepts all. The
    /// detector's own scale.
    pub min_confidence: f64,
    /// sigma_i: the scatter of one table bounce about the impulse model, its tangential impulse
    /// per unit mass per axis [m/s], in [0, 5]; it moves the velocity and, through the shell's
    /// inertia, the spin by 3/(2r) per m/s. Published fits of the friction range 0.1-0.3
    /// (Nakashima et al. 2010, docs/models.md): a spread of that size at 2-4 m/s of slip.
    pub bounce_impulse_sigma: f64,
    /// sigma_e: the scatter of one bounce's restitution about the table's [-], in [0, 0.5].
    /// Published fits range 0.88-0.93 (Nakashima et al. 2010).
    pub bounce_restitution_sigma: f64,
    /// The extra position noise of a detection of a ball at the table (its centre within
    /// [`CONTACT_BAND`](crate::online::estimator::CONTACT_BAND) of its contact height) [m], in
    /// [0, 0.05], added in quadrature to its source's: a ball touching the surface merges with
    /// its reflection and shadow in the image. A few millimetres: a fraction of the ball's
    /// radius.
    pub contact_position_sigma: f64,
}

impl Default for EkfParams {
    fn default() -> Self {
        Self {
            acceleration_noise_density: 0.002,
            spin_noise_density: 10.0,
            spin_prior_sigma: 300.0,
            min_confidence: 0.0,
            bounce_impulse_sigma: 0.1,
            bounce_restitution_sigma: 0.01,
            contact_position_sigma: 0.003,
        }
    }
}

/// The physical parameters the estimator learns online and carries from track to track, in
/// the order of [`PhysicsParams::NAMES`](crate::physics::PhysicsParams::NAMES): the scale
/// factors k_D and k_M on the drag and Magnus forces and the table's restitution e_t and
/// friction mu_t, starting from `aero.drag_scale`, `aero.magnus_scale`, `table.restitution` and
/// `table.friction` (a two-level model: each flight its own parameters about the ball's and
/// table's; docs/estimator.md, "The adaptation").
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AdaptationParams {
    /// Learn the parameters (false: they stay at their configured values).
    pub enabled: bool,
    /// The prior standard deviation of each parameter about its configured value [-], four
    /// values in [0, 1] (k_D, k_M, e_t, mu_t); 0 keeps that one fixed. Wide enough for the
    /// spread of published values: drag coefficients 0.40-0.65, Magnus scales of 0.6-1.0 of
    /// the spin-parameter polynomial on real flights, restitution 0.88-0.93, friction 0.1-0.3
    /// (docs/models.md).
    pub sigma: Vec<f64>,
    /// How much one flight's parameters scatter about the ball's and table's [-], four values
    /// in [0, 1] (k_D, k_M, e_t, mu_t): its spin axis, the seam it flies on, the part of the
    /// table it hits. Each flight's filter learns its own parameters about the shared ones.
    pub flight_sigma: Vec<f64>,
    /// How far each parameter may drift in an hour, as a fraction of its prior standard
    /// deviation [-], in [0, 100]: a random walk of variance (drift sigma)^2 t / 3600 s, capped
    /// at the prior variance (after a long pause the estimator is back at its prior).
    pub drift_per_hour: f64,
    /// The prior standard deviation of the Reynolds exponents (a_D, a_M) about their
    /// configured values (`aero.reynolds_exponents`) [-], two values in [0, 2]; 0 keeps one
    /// fixed. The flights' scales at different speeds teach them (docs/estimator.md).
    pub reynolds_sigma: Vec<f64>,
}

impl Default for AdaptationParams {
    fn default() -> Self {
        Self {
            enabled: true,
            sigma: vec![0.15, 0.4, 0.03, 0.1],
            flight_sigma: vec![0.03, 0.1, 0.02, 0.0],
            drift_per_hour: 0.5,
            reynolds_sigma: vec![0.0, 0.3],
        }
    }
}

impl AdaptationParams {
    /// The value of `values` (`sigma` or `flight_sigma`) for parameter `index` (0 where the
    /// list is short: validation requires four).
    pub fn of(values: &[f64], index: usize) -> f64 {
        values.get(index).copied().unwrap_or(0.0)
    }
}

/// Outlier rejection: Mahalanobis gating of each detection against the predicted measurement.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GatingParams {
    /// Probability that a correct detection passes the gate [-]; the threshold on the squared
    /// Mahalanobis distance is the chi-square quantile of this probability for the measurement's
    /// dimension. 0.9999: a good detection is lost once in 10,000 (at 0.9973, "3 sigma", one
    /// in eight of the 50 ms windows after a bounce seen at 900 fps would lose one).
    pub probability: f64,
    /// After this many detections in a row fail the gate the track is restarted from new
    /// detections [-]; the ball has left the model (e.g. an unseen racket hit).
    pub max_consecutive_rejections: u32,
}

impl Default for GatingParams {
    fn default() -> Self {
        Self {
            probability: 0.9999,
            max_consecutive_rejections: 5,
        }
    }
}

/// Track life cycle and out-of-order handling.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TrackingParams {
    /// A gap between detections longer than this starts a new track [s] (15 frames at 150 fps).
    /// A stamp this far off the track's, either way, is held until the next detection confirms
    /// the jump or shows a glitch (see `Estimator::update`).
    pub timeout: f64,
    /// Out-of-order detections older than this behind the newest fused one are dropped and
    /// counted [s]; newer ones are fused by rolling the filter back. Covers the latency difference
    /// of the two cameras (8 ms vs 4 ms) with margin. At most `timeout`.
    pub rollback_window: f64,
    /// The state is reported as COASTING when no detection was fused for this long [s]
    /// (3 frames at 150 fps).
    pub coast_after: f64,
}

impl Default for TrackingParams {
    fn default() -> Self {
        Self {
            timeout: 0.1,
            rollback_window: 0.030,
            coast_after: 0.02,
        }
    }
}

/// The ROS 2 node.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct NodeParams {
    /// Node name (letters, digits, underscores; not starting with a digit).
    pub name: String,
    /// Node namespace: empty (the root namespace) or an absolute namespace such as "/robot1".
    pub namespace: String,
    /// Capacity of the estimator's detection queue [detections]: before each detection the
    /// estimator thread takes every sample DDS holds into it; when full, the oldest detection is
    /// dropped and counted. 256 is about 0.25 s of both cameras (150 + 900 detections per
    /// second).
    pub queue_capacity: u32,
    /// How the node's services (`~/predict_trajectory`, `~/predict_rebound`, `~/plan_return`)
    /// frame requests and replies on DDS: `enhanced` (RPC over DDS enhanced mapping:
    /// rmw_fastrtps, ROS 2's default, and rmw_connextdds), `cyclone` (rmw_cyclonedds) or `basic`
    /// (RPC over DDS basic mapping). Topics need no choice.
    pub service_mapping: ServiceMapping,
    /// Use only the loopback interface (127.0.0.1) for DDS, as ROS 2's `ROS_LOCALHOST_ONLY=1` or
    /// `ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`, which also turn this on.
    pub localhost_only: bool,
    /// IP address of the one network interface DDS may use, e.g. "192.168.1.20"; empty = all.
    pub interface_address: String,
    /// Period of the `/diagnostics` messages [s]. ROS 2's diagnostic_updater publishes at 1 Hz.
    pub diagnostics_period: f64,
    /// CPUs the node's threads run on, as `taskset -c` takes them: e.g. "1", "2,3" or "0-1".
    /// Every thread of the node, RustDDS's included, then runs there; on one core, handing a
    /// detection from thread to thread wakes no other core (docs/performance.md).
    /// Empty: wherever the operating system puts them. ([`NodeParams::cpu_list`] reads it.) One
    /// CPU may be given as a bare number (`-p node.cpus:=1`).
    #[serde(deserialize_with = "text_or_number")]
    pub cpus: String,
    /// How long a camera source with a frame rate (`sources.*.frame_rate`) may stay silent while
    /// the others deliver before `/diagnostics` reports it STALE [s].
    pub source_stale_after: f64,
}

impl NodeParams {
    /// The CPUs of [`NodeParams::cpus`], ascending and without repeats; empty for any.
    pub fn cpu_list(&self) -> Result<Vec<u32>, &'static str> {
        const SYNTAX: &str = "give CPU numbers and ranges as `taskset -c` takes them, e.g. \"1\", \"2,3\" or \"0-1\", or \"\" for any";
        let number = |text: &str| text.trim().parse::<u32>().map_err(|_| SYNTAX);
        let mut cpus = Vec::new();
        for item in self.cpus.split(',').filter(|item| !item.trim().is_empty()) {
            let (first, last) = match item.split_once('-') {
                Some((first, last)) => (number(first)?, number(last)?),
                None => (number(item)?, number(item)?),
            };
            if first > last {
                return Err("a range must go up, e.g. \"2-3\"");
            }
            if last >= MAX_CPUS {
                return Err(
                    "CPU numbers go up to 1023 (`nproc --all` says how many this machine has)",
                );
            }
            cpus.extend(first..=last);
        }
        cpus.sort_unstable();
        cpus.dedup();
        Ok(cpus)
    }
}

/// A string, or a whole number taken as its digits.
fn text_or_number<'de, D: serde::Deserializer<'de>>(input: D) -> Result<String, D::Error> {
    #[derive(Deserialize)]
    #[serde(untagged)]
    enum TextOrNumber {
        Text(String),
        Number(u64),
    }
    Ok(match TextOrNumber::deserialize(input)? {
        TextOrNumber::Text(text) => text,
        TextOrNumber::Number(number) => number.to_string(),
    })
}

/// CPU numbers [`NodeParams::cpus`] may name: the size of Linux's `cpu_set_t`.
const MAX_CPUS: u32 = 1024;

/// The request/reply framing of ROS 2 services on DDS (it differs between RMW implementations).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ServiceMapping {
    /// Enhanced mapping of the OMG RPC over DDS specification (rmw_fastrtps, rmw_connextdds).
    Enhanced,
    /// rmw_cyclonedds' mapping: a 16-byte request id in front of every payload.
    Cyclone,
    /// Basic mapping of the OMG RPC over DDS specification.
    Basic,
}

impl Default for NodeParams {
    fn default() -> Self {
        Self {
            name: "ttball".to_owned(),
            namespace: String::new(),
            queue_capacity: 256,
            service_mapping: ServiceMapping::Enhanced,
            localhost_only: false,
            interface_address: String::new(),
            diagnostics_period: 1.0,
            cpus: String::new(),
            source_stale_after: 3.0,
        }
    }
}

/// ROS 2 topic names: relative ones (`ball/state`) are in the node's namespace
/// (`node.namespace`), private ones (`~/x`) in the node's own; [`Config::topics`] resolves them.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TopicsParams {
    /// Input: ball detections from the cameras.
    pub detections: String,
    /// Output: the estimated ball state (position, velocity, spin, covariance, status).
    pub state: String,
    /// Output: the predicted crossing of the hitting plane `intercept.plane_x`.
    pub intercept: String,
    /// Output: the predicted trajectory, sampled every `prediction.trajectory_dt`.
    pub trajectory: String,
    /// Output: RViz markers of the state and prediction.
    pub markers: String,
    /// Output: diagnostic_msgs status (rates, latencies, drop counters); the ROS convention.
    pub diagnostics: String,
    /// Input (simulation and replay): the true ball state, for error statistics.
    pub truth: String,
    /// Output of `ttball smooth`: the batch-fitted (smoothed) state at every detection.
    pub smoothed: String,
    /// Output (optional): the state as `nav_msgs/Odometry` (pose = position, twist = velocity
    /// and spin, with their covariances), for tools that draw covariances natively; empty: off.
    pub odometry: String,
    /// Input: the robot's own hits announced (`ttball_msgs/RobotHit`), so the return is tracked
    /// from its first detection.
    pub robot_hits: String,
}

impl Default for TopicsParams {
    fn default() -> Self {
        Self {
            detections: "ball/detections".to_owned(),
            state: "ball/state".to_owned(),
            intercept: "ball/intercept".to_owned(),
            trajectory: "ball/trajectory".to_owned(),
            markers: "ball/markers".to_owned(),
            diagnostics: "/diagnostics".to_owned(),
            truth: "ball/truth".to_owned(),
            smoothed: "ball/smoothed".to_owned(),
            odometry: String::new(),
            robot_hits: "robot/hits".to_owned(),
        }
    }
}

/// Coordinate frames (tf2): detections may come in any frame a static transform on
/// `/tf_static` connects to `table`; the node can publish the table's own pose.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FramesParams {
    /// The name of the table frame: the frame the estimator works in (origin at the centre of
    /// the playing surface, x along the table towards the opponent, y to the robot's left,
    /// z up), the frame of every output, and the frame `/tf_static` must connect a detection's
    /// frame to.
    pub table_frame: String,
    /// The frame the node publishes the `table` frame's pose in, on `/tf_static` (e.g.
    /// `world`, so that the robot's TF tree has the table); empty: none.
    pub table_parent: String,
    /// The `table` frame's pose in `table_parent`: x, y, z [m], then the rotation as a
    /// quaternion x, y, z, w [-].
    pub table_pose: Vec<f64>,
}

impl Default for FramesParams {
    fn default() -> Self {
        Self {
            table_frame: "table".to_owned(),
            table_parent: String::new(),
            table_pose: vec![0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0],
        }
    }
}

/// Quality of service of the ROS 2 topics (keep-last history depths; REP 2003).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct QosParams {
    /// History depth of the detections subscription (best effort, volatile) [messages].
    pub detections_depth: u32,
    /// History depth of every output publisher (reliable) [messages].
    pub outputs_depth: u32,
}

impl Default for QosParams {
    fn default() -> Self {
        Self {
            detections_depth: 10,
            outputs_depth: 10,
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
    /// The racket (impact model).
    pub racket: RacketParams,
    /// The arm or robot wrist holding the racket.
    pub arm: ArmParams,
    /// The racket command planner.
    pub stroke: StrokeParams,
    /// Flight propagation and trajectory publishing.
    pub prediction: PredictionParams,
    /// The robot's hitting plane.
    pub intercept: InterceptParams,
    /// Measurement noise per camera source.
    pub sources: SourcesParams,
    /// The extended Kalman filter.
    pub ekf: EkfParams,
    /// The physical parameters learned online.
    pub adaptation: AdaptationParams,
    /// Outlier gating.
    pub gating: GatingParams,
    /// Track life cycle and out-of-order detections.
    pub tracking: TrackingParams,
    /// The ROS 2 node.
    pub node: NodeParams,
    /// ROS 2 topic names.
    pub topics: TopicsParams,
    /// Coordinate frames (tf2).
    pub frames: FramesParams,
    /// ROS 2 quality of service.
    pub qos: QosParams,
    /// ROS 2's `use_sim_time`: the node's clock (the stamps of `/diagnostics`) follows `/clock`
    /// instead of the system clock. The estimator itself runs on the detections' stamps either way.
    pub use_sim_time: bool,
}

impl Config {
    /// The topic names resolved in the node's namespace (`node.namespace`, `node.name`):
    /// absolute, as ROS 2 names them on the wire.
    pub fn resolved_topics(&self) -> TopicsParams {
        let resolve = |name: &str| names::resolve(name, &self.node.namespace, &self.node.name);
        let t = &self.topics;
        TopicsParams {
            detections: resolve(&t.detections),
            state: resolve(&t.state),
            intercept: resolve(&t.intercept),
            trajectory: resolve(&t.trajectory),
            markers: resolve(&t.markers),
            diagnostics: resolve(&t.diagnostics),
            truth: resolve(&t.truth),
            smoothed: resolve(&t.smoothed),
            odometry: if t.odometry.is_empty() {
                String::new()
            } else {
                resolve(&t.odometry)
            },
            robot_hits: resolve(&t.robot_hits),
        }
    }

    /// The node's fully qualified name (`/ttball`, `/robot1/ttball`).
    pub fn node_fqn(&self) -> String {
        names::fully_qualified_node_name(&self.node.namespace, &self.node.name)
    }
}

impl Default for Config {
    fn default() -> Self {
        Self {
            gravity: STANDARD_GRAVITY,
            ball: BallParams::default(),
            air: AirParams::default(),
            aero: AeroParams::default(),
            table: TableParams::default(),
            racket: RacketParams::default(),
            arm: ArmParams::default(),
            stroke: StrokeParams::default(),
            prediction: PredictionParams::default(),
            intercept: InterceptParams::default(),
            sources: SourcesParams::default(),
            ekf: EkfParams::default(),
            adaptation: AdaptationParams::default(),
            gating: GatingParams::default(),
            tracking: TrackingParams::default(),
            node: NodeParams::default(),
            topics: TopicsParams::default(),
            frames: FramesParams::default(),
            qos: QosParams::default(),
            use_sim_time: false,
        }
    }
}
