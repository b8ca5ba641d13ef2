//! Flight of a spinning ball: the spin-parameter aerodynamic model of Isomura, Hayakawa, Asai and
//! Ariizumi (2014, eq. 1-3 and Table 3), with the corrections of docs/models.md "Flight", and
//! the coefficients' dependence on the Reynolds number (docs/models.md "Reynolds number"):
//!
//! ```text
//! dp/dt = v
//! dv/dt = -g e_z - k_D (C_D(Re, Sp) rho S_b / m) |v| v + k_M (C_M(Re, Sp) rho V_b / m) (w x v)
//! dw/dt = -lambda w                      (lambda = configured spin decay, default 0)
//! S_b = pi r^2 / 2,  V_b = 4/3 pi r^3,  Sp = r |w x v| / |v|^2,  Re = 2 r |v| / nu
//! C_D(Re, Sp) = P_D(Sp) f(Re)^a_D,  C_M(Re, Sp) = P_M(Sp) f(Re)^a_M
//! f(Re) = [(1 + (Re / Re_0)^4) / (1 + (Re / Re_max)^4)]^(1/4)
//! ```
//!
//! P_D and P_M are polynomials in Sp, evaluated at Sp clamped to [0, Sp_max]. f is 1 well below
//! Re_0, Re / Re_0 between Re_0 and Re_max, and Re_max / Re_0 well above, joined smoothly (so
//! that the field has continuous derivatives in the speed). [`FlightModel::jacobian`] is the
//! exact derivative of this field, including the dependence of C_D and C_M on Sp (zero beyond
//! its clamp) and on Re.

use nalgebra::{Matrix3, SMatrix, Vector3};

use super::params::{DRAG_SCALE, ParamMatrix};
use super::state::{SPIN, StateVector, VELOCITY};
use crate::config::Config;
pub use crate::config::MAX_POLYNOMIAL_COEFFICIENTS;

/// A polynomial sum_i c_i x^i with its coefficients lowest order first, held inline (no heap:
/// a model that holds polynomials can be copied in the per-detection path).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Polynomial {
    coefficients: [f64; MAX_POLYNOMIAL_COEFFICIENTS],
    len: usize,
}

impl Polynomial {
    /// A polynomial from its coefficients, lowest order first. At most
    /// [`MAX_POLYNOMIAL_COEFFICIENTS`] are kept (the configuration refuses longer lists).
    pub fn new(coefficients: &[f64]) -> Self {
        let len = coefficients.len().min(MAX_POLYNOMIAL_COEFFICIENTS);
        let mut kept = [0.0; MAX_POLYNOMIAL_COEFFICIENTS];
        kept[..len].copy_from_slice(&coefficients[..len]);
        Self {
            coefficients: kept,
            len,
        }
    }

    /// The coefficients, lowest order first.
    pub fn coefficients(&self) -> &[f64] {
        &self.coefficients[..self.len]
    }

    /// The value and the first derivative at `x` (Horner's scheme).
    #[inline]
    pub fn value_and_slope(&self, x: f64) -> (f64, f64) {
        let mut value = 0.0;
        let mut slope = 0.0;
        for &c in self.coefficients().iter().rev() {
            slope = slope * x + value;
            value = value * x + c;
        }
        (value, slope)
    }

    /// The value at `x` (the same as [`Self::value_and_slope`]'s, bit for bit).
    #[inline]
    pub fn value(&self, x: f64) -> f64 {
        self.coefficients()
            .iter()
            .rev()
            .fold(0.0, |value, &c| value * x + c)
    }
}

/// The aerodynamic state of the ball at one instant, for reporting and tests.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AeroForces {
    /// Spin parameter Sp = r |w x v| / |v|^2 before clamping [-].
    pub spin_parameter: f64,
    /// Reynolds number Re = 2 r |v| / nu before clamping [-].
    pub reynolds_number: f64,
    /// True when Sp exceeded Sp_max and the coefficients were evaluated at Sp_max.
    pub clamped: bool,
    /// Drag coefficient C_D at the (clamped) spin parameter and Reynolds number [-].
    pub drag_coefficient: f64,
    /// Magnus coefficient C_M at the (clamped) spin parameter and Reynolds number [-].
    pub magnus_coefficient: f64,
    /// Drag acceleration [m/s^2].
    pub drag: Vector3<f64>,
    /// Magnus acceleration [m/s^2].
    pub magnus: Vector3<f64>,
}

/// The Jacobian of the flight field d(dx/dt)/dx, kept in its block structure
/// `[[0, I, 0], [0, dv_dv, dv_dw], [0, 0, -lambda I]]` so products cost a fraction of a 9x9 product.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FlightJacobian {
    /// d(acceleration)/d(velocity) [1/s].
    pub dv_dv: Matrix3<f64>,
    /// d(acceleration)/d(spin) [m/s / rad].
    pub dv_dw: Matrix3<f64>,
    /// Spin decay rate lambda [1/s]: d(dw/dt)/dw = -lambda I.
    pub spin_decay: f64,
    /// d(acceleration)/d(k_D, k_M): the drag and Magnus accelerations at unit scale [m/s^2].
    pub dv_dscales: SMatrix<f64, 3, 2>,
}

impl FlightJacobian {
    /// The product `A m` for any matrix with 9 rows (a state vector or a state-transition matrix).
    #[inline]
    pub fn apply<const C: usize>(&self, m: &SMatrix<f64, 9, C>) -> SMatrix<f64, 9, C> {
        let mut out = SMatrix::<f64, 9, C>::zeros();
        let mv = m.fixed_rows::<3>(VELOCITY);
        let mw = m.fixed_rows::<3>(SPIN);
        out.fixed_rows_mut::<3>(0).copy_from(&mv);
        out.fixed_rows_mut::<3>(VELOCITY)
            .copy_from(&(self.dv_dv * mv + self.dv_dw * mw));
        out.fixed_rows_mut::<3>(SPIN)
            .copy_from(&(mw * -self.spin_decay));
        out
    }

    /// The full 9x9 matrix.
    pub fn to_matrix(&self) -> SMatrix<f64, 9, 9> {
        self.apply(&SMatrix::<f64, 9, 9>::identity())
    }

    /// `A m + B`, with B = d(flight field)/d(physical parameters): the rate of a state's
    /// sensitivity `m` to the parameters ([`super::PhysicsParams`] order: k_D, k_M, e_t, mu_t;
    /// the table's two do not act in flight).
    #[inline]
    pub fn apply_params(&self, m: &ParamMatrix) -> ParamMatrix {
        let mut out = self.apply(m);
        let mut forcing = out.fixed_view_mut::<3, 2>(VELOCITY, DRAG_SCALE);
        forcing += self.dv_dscales;
        out
    }

    /// The product `A m` of a matrix of free-flight structure (again of that structure).
    #[inline]
    pub fn apply_flight(&self, m: &FlightMatrix) -> FlightMatrix {
        FlightMatrix {
            position: 0.0,
            pv: m.vv,
            pw: m.vw,
            vv: self.dv_dv * m.vv,
            vw: self.dv_dv * m.vw + self.dv_dw * m.spin,
            spin: -self.spin_decay * m.spin,
        }
    }
}

/// A 9x9 matrix with the block structure of free flight,
/// `[[position I, pv, pw], [0, vv, vw], [0, 0, spin I]]`.
///
/// The state-transition matrix of a stretch of flight has it exactly (dp/dp stays I, nothing
/// feeds back into position or spin, spin decays as a scalar), and so has the flight Jacobian
/// applied to it: 36 entries and 2 scalars evolve instead of 81.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FlightMatrix {
    /// Position-position block, a multiple of I.
    pub position: f64,
    /// Position-velocity block.
    pub pv: Matrix3<f64>,
    /// Position-spin block.
    pub pw: Matrix3<f64>,
    /// Velocity-velocity block.
    pub vv: Matrix3<f64>,
    /// Velocity-spin block.
    pub vw: Matrix3<f64>,
    /// Spin-spin block, a multiple of I.
    pub spin: f64,
}

impl FlightMatrix {
    /// The identity.
    #[inline]
    pub fn identity() -> Self {
        Self {
            position: 1.0,
            pv: Matrix3::zeros(),
            pw: Matrix3::zeros(),
            vv: Matrix3::identity(),
            vw: Matrix3::zeros(),
            spin: 1.0,
        }
    }

    /// `self + other * factor`.
    #[inline]
    pub fn add_scaled(&self, other: &Self, factor: f64) -> Self {
        Self {
            position: self.position + other.position * factor,
            pv: self.pv + other.pv * factor,
            pw: self.pw + other.pw * factor,
            vv: self.vv + other.vv * factor,
            vw: self.vw + other.vw * factor,
            spin: self.spin + other.spin * factor,
        }
    }

    /// The product `self m` with any matrix of 9 rows.
    #[inline]
    pub fn times<const C: usize>(&self, m: &SMatrix<f64, 9, C>) -> SMatrix<f64, 9, C> {
        let mp = m.fixed_rows::<3>(0);
        let mv = m.fixed_rows::<3>(VELOCITY);
        let mw = m.fixed_rows::<3>(SPIN);
        let mut out = SMatrix::<f64, 9, C>::zeros();
        out.fixed_rows_mut::<3>(0)
            .copy_from(&(mp * self.position + self.pv * mv + self.pw * mw));
        out.fixed_rows_mut::<3>(VELOCITY)
            .copy_from(&(self.vv * mv + self.vw * mw));
        out.fixed_rows_mut::<3>(SPIN).copy_from(&(mw * self.spin));
        out
    }

    /// The product `m self` with any matrix of 9 columns.
    #[inline]
    pub fn premultiplied_by<const R: usize>(&self, m: &SMatrix<f64, R, 9>) -> SMatrix<f64, R, 9> {
        let mp = m.fixed_columns::<3>(0);
        let mv = m.fixed_columns::<3>(VELOCITY);
        let mw = m.fixed_columns::<3>(SPIN);
        let mut out = SMatrix::<f64, R, 9>::zeros();
        out.fixed_columns_mut::<3>(0)
            .copy_from(&(mp * self.position));
        out.fixed_columns_mut::<3>(VELOCITY)
            .copy_from(&(mp * self.pv + mv * self.vv));
        out.fixed_columns_mut::<3>(SPIN)
            .copy_from(&(mp * self.pw + mv * self.vw + mw * self.spin));
        out
    }

    /// The inverse (block back-substitution; free-flight matrices form a group), or `None` when
    /// the velocity block is singular.
    pub fn inverse(&self) -> Option<Self> {
        let vv = self.vv.try_inverse()?;
        if self.position == 0.0 || self.spin == 0.0 {
            return None;
        }
        let (position, spin) = (1.0 / self.position, 1.0 / self.spin);
        let pv_vv = self.pv * vv;
        Some(Self {
            position,
            pv: -pv_vv * position,
            pw: (pv_vv * self.vw - self.pw) * (position * spin),
            vv,
            vw: -vv * self.vw * spin,
            spin,
        })
    }

    /// Row `i` of the full matrix.
    pub fn row(&self, i: usize) -> SMatrix<f64, 1, 9> {
        let mut out = SMatrix::<f64, 1, 9>::zeros();
        match i / 3 {
            0 => {
                out[i] = self.position;
                out.fixed_columns_mut::<3>(VELOCITY)
                    .copy_from(&self.pv.row(i));
                out.fixed_columns_mut::<3>(SPIN).copy_from(&self.pw.row(i));
            }
            1 => {
                out.fixed_columns_mut::<3>(VELOCITY)
                    .copy_from(&self.vv.row(i - VELOCITY));
                out.fixed_columns_mut::<3>(SPIN)
                    .copy_from(&self.vw.row(i - VELOCITY));
            }
            _ => out[i] = self.spin,
        }
        out
    }

    /// The full 9x9 matrix.
    pub fn to_matrix(&self) -> SMatrix<f64, 9, 9> {
        self.times(&SMatrix::<f64, 9, 9>::identity())
    }
}

/// The two values of a configured pair, or `fallback` when it is not a pair (validation refuses
/// that).
fn pair(values: &[f64], fallback: (f64, f64)) -> (f64, f64) {
    match values {
        [a, b] => (*a, *b),
        _ => fallback,
    }
}

/// Below this |v|^2 [m^2/s^2] or |w x v| the spin parameter is taken as 0 (no direction defined).
const TINY: f64 = 1e-18;

/// The quantities of one state that the flight field is made of.
#[derive(Debug, Clone, Copy)]
struct Field {
    v: Vector3<f64>,
    w: Vector3<f64>,
    speed_sq: f64,
    speed: f64,
    /// w x v.
    c: Vector3<f64>,
    c_norm: f64,
    /// The spin parameter, and clamped to [0, Sp_max] as the coefficients take it.
    sp: f64,
    sp_eval: f64,
    /// The Reynolds number's factors f(Re)^a on C_D and C_M.
    reynolds_drag: f64,
    reynolds_magnus: f64,
    /// d ln f / d ln Re.
    reynolds_slope: f64,
}

/// The flight model: constants of the ball and the air folded into two factors, and the scale
/// factors on the drag and Magnus forces that the estimator adapts ([`super::PhysicsParams`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FlightModel {
    gravity: f64,
    radius: f64,
    drag_factor: f64,
    magnus_factor: f64,
    /// k_D: the drag acceleration is k_D C_D(Sp) rho S_b / m |v| v.
    drag_scale: f64,
    /// k_M: the Magnus acceleration is k_M C_M(Sp) rho V_b / m (w x v).
    magnus_scale: f64,
    drag: Polynomial,
    magnus: Polynomial,
    spin_parameter_max: f64,
    /// 2 r / nu [s/m]: the Reynolds number per m/s of speed.
    reynolds_per_speed: f64,
    /// [Re_0, Re_max].
    reynolds_range: (f64, f64),
    /// (a_D, a_M).
    reynolds_exponents: [f64; 2],
    spin_decay: f64,
    /// The variance [(rad/s)^2] of the spin across the flight that the coefficients are
    /// evaluated over ([`Self::with_spin_variance`]); 0 for a known spin.
    spin_variance: f64,
}

impl FlightModel {
    /// The same model for a spin known only to a variance `variance` [(rad/s)^2] across the
    /// flight: C_D and C_M are evaluated at the spin parameter of sqrt(|w_perp|^2 + variance),
    /// the spin's magnitude across the flight with its spread, instead of |w_perp| (the drag
    /// and the Magnus force grow or fall with the magnitude of a spin whose direction is still
    /// uncertain: at |w_perp| = 0 the plain spin parameter is the smallest the spin can give).
    /// The force's direction is still w x v.
    pub fn with_spin_variance(&self, variance: f64) -> Self {
        Self {
            spin_variance: variance.max(0.0),
            ..*self
        }
    }

    /// The model with the configured ball, air and aerodynamic coefficients.
    pub fn new(config: &Config) -> Self {
        let r = config.ball.radius;
        let m = config.ball.mass;
        let rho = config.air.density;
        let cross_section = 0.5 * std::f64::consts::PI * r * r;
        let volume = 4.0 / 3.0 * std::f64::consts::PI * r * r * r;
        Self {
            gravity: config.gravity,
            radius: r,
            drag_factor: rho * cross_section / m,
            magnus_factor: rho * volume / m,
            drag_scale: config.aero.drag_scale,
            magnus_scale: config.aero.magnus_scale,
            drag: Polynomial::new(&config.aero.drag_coefficients),
            magnus: Polynomial::new(&config.aero.magnus_coefficients),
            spin_parameter_max: config.aero.spin_parameter_max,
            reynolds_per_speed: 2.0 * r / config.air.kinematic_viscosity,
            reynolds_range: pair(&config.aero.reynolds_range, (1.0, 1.0)),
            reynolds_exponents: pair(&config.aero.reynolds_exponents, (0.0, 0.0)).into(),
            spin_decay: config.aero.spin_decay_rate,
            spin_variance: 0.0,
        }
    }

    /// The same model with other scale factors on the drag and the Magnus force [-].
    pub fn with_scales(&self, drag_scale: f64, magnus_scale: f64) -> Self {
        Self {
            drag_scale,
            magnus_scale,
            ..*self
        }
    }

    /// The scale factors (k_D, k_M) on the drag and the Magnus force [-].
    pub fn scales(&self) -> (f64, f64) {
        (self.drag_scale, self.magnus_scale)
    }

    /// rho S_b / m [1/m]: multiplied by k_D C_D |v| v it gives the drag acceleration.
    pub fn drag_factor(&self) -> f64 {
        self.drag_factor
    }

    /// rho V_b / m [-]: multiplied by k_M C_M (w x v) it gives the Magnus acceleration.
    pub fn magnus_factor(&self) -> f64 {
        self.magnus_factor
    }

    /// Ball radius [m].
    pub fn radius(&self) -> f64 {
        self.radius
    }

    /// Gravity's acceleration [m/s^2].
    pub fn gravity(&self) -> f64 {
        self.gravity
    }

    /// C_D(Re_0, Sp) = P_D(Sp), with Sp clamped to [0, Sp_max]: the drag coefficient of a ball
    /// at Re_0 or slower.
    pub fn drag_coefficient(&self, spin_parameter: f64) -> f64 {
        self.drag
            .value(spin_parameter.clamp(0.0, self.spin_parameter_max))
    }

    /// C_M(Re_0, Sp) = P_M(Sp), with Sp clamped to [0, Sp_max], likewise.
    pub fn magnus_coefficient(&self, spin_parameter: f64) -> f64 {
        self.magnus
            .value(spin_parameter.clamp(0.0, self.spin_parameter_max))
    }

    /// The Reynolds number Re = 2 r |v| / nu of a ball at `speed` [m/s].
    pub fn reynolds_number(&self, speed: f64) -> f64 {
        self.reynolds_per_speed * speed
    }

    /// The same model with other Reynolds exponents (a_D, a_M) [-].
    pub fn with_reynolds_exponents(&self, exponents: [f64; 2]) -> Self {
        Self {
            reynolds_exponents: exponents,
            ..*self
        }
    }

    /// The Reynolds exponents (a_D, a_M) [-].
    pub fn reynolds_exponents(&self) -> [f64; 2] {
        self.reynolds_exponents
    }

    /// ln f(Re) at `speed` [m/s] (see the module doc) and d ln f / d ln Re; (0, 0) for a speed
    /// that is not positive.
    #[inline]
    pub fn reynolds_log_factor(&self, speed: f64) -> (f64, f64) {
        if speed.is_nan() || speed <= 0.0 {
            return (0.0, 0.0);
        }
        let re = self.reynolds_per_speed * speed;
        let fourth = |ratio: f64| {
            let squared = ratio * ratio;
            squared * squared
        };
        let (low, high) = (
            fourth(re / self.reynolds_range.0),
            fourth(re / self.reynolds_range.1),
        );
        let log_f = 0.25 * ((1.0 + low) / (1.0 + high)).ln();
        (log_f, low / (1.0 + low) - high / (1.0 + high))
    }

    /// The factors f(Re)^a_D and f(Re)^a_M on C_D and C_M at `speed` [m/s] (see the module
    /// doc), and d ln f / d ln Re.
    #[inline]
    pub fn reynolds_factors(&self, speed: f64) -> (f64, f64, f64) {
        let [a_d, a_m] = self.reynolds_exponents;
        if a_d == 0.0 && a_m == 0.0 {
            return (1.0, 1.0, 0.0);
        }
        let (log_f, slope) = self.reynolds_log_factor(speed);
        let power = |a: f64| if a == 0.0 { 1.0 } else { (a * log_f).exp() };
        (power(a_d), power(a_m), slope)
    }

    /// Spin parameter Sp = r |w x v| / |v|^2 (0 for a ball at rest).
    pub fn spin_parameter(&self, velocity: &Vector3<f64>, spin: &Vector3<f64>) -> f64 {
        self.field_of(*velocity, *spin).sp
    }

    /// Drag and Magnus accelerations at one velocity and spin.
    pub fn forces(&self, velocity: &Vector3<f64>, spin: &Vector3<f64>) -> AeroForces {
        let field = self.field_of(*velocity, *spin);
        let cd = self.drag.value(field.sp_eval) * field.reynolds_drag;
        let cm = self.magnus.value(field.sp_eval) * field.reynolds_magnus;
        let (drag, magnus) = self.accelerations(&field, cd, cm);
        AeroForces {
            spin_parameter: field.sp,
            reynolds_number: self.reynolds_number(field.speed),
            clamped: field.sp > self.spin_parameter_max,
            drag_coefficient: cd,
            magnus_coefficient: cm,
            drag,
            magnus,
        }
    }

    /// The time derivative of the state, dx/dt.
    #[inline]
    pub fn derivative(&self, x: &StateVector) -> StateVector {
        let field = self.field(x);
        let cd = self.drag.value(field.sp_eval) * field.reynolds_drag;
        let cm = self.magnus.value(field.sp_eval) * field.reynolds_magnus;
        self.state_derivative(&field, cd, cm)
    }

    /// The field quantities of a state.
    #[inline]
    fn field(&self, x: &StateVector) -> Field {
        self.field_of(
            Vector3::new(x[VELOCITY], x[VELOCITY + 1], x[VELOCITY + 2]),
            Vector3::new(x[SPIN], x[SPIN + 1], x[SPIN + 2]),
        )
    }

    /// The velocity, spin, norms and spin parameter that the forces, the derivative and its
    /// Jacobian are made of.
    #[inline]
    fn field_of(&self, v: Vector3<f64>, w: Vector3<f64>) -> Field {
        let speed_sq = v.norm_squared();
        let c = w.cross(&v);
        let c_norm = c.norm();
        let sp = if speed_sq < TINY {
            0.0
        } else if self.spin_variance > 0.0 {
            // |w_perp| = |w x v| / |v|, with the spread.
            self.radius * (c_norm * c_norm / speed_sq + self.spin_variance).sqrt() / speed_sq.sqrt()
        } else {
            self.radius * c_norm / speed_sq
        };
        let speed = speed_sq.sqrt();
        let (reynolds_drag, reynolds_magnus, reynolds_slope) = self.reynolds_factors(speed);
        Field {
            v,
            w,
            speed_sq,
            speed,
            c,
            c_norm,
            sp,
            sp_eval: sp.clamp(0.0, self.spin_parameter_max),
            reynolds_drag,
            reynolds_magnus,
            reynolds_slope,
        }
    }

    /// The drag and Magnus accelerations from the field and the coefficients at its spin
    /// parameter.
    fn accelerations(&self, f: &Field, cd: f64, cm: f64) -> (Vector3<f64>, Vector3<f64>) {
        (
            -(self.drag_factor * self.drag_scale) * cd * f.speed * f.v,
            (self.magnus_factor * self.magnus_scale) * cm * f.c,
        )
    }

    /// dx/dt from the field and the coefficients at its spin parameter.
    #[inline]
    fn state_derivative(&self, f: &Field, cd: f64, cm: f64) -> StateVector {
        let (drag, magnus) = self.accelerations(f, cd, cm);
        let accel = drag + magnus - Vector3::new(0.0, 0.0, self.gravity);
        let spin = f.w * -self.spin_decay;
        StateVector::from_column_slice(&[
            f.v.x, f.v.y, f.v.z, accel.x, accel.y, accel.z, spin.x, spin.y, spin.z,
        ])
    }

    /// The Jacobian of [`Self::derivative`] with respect to the state.
    pub fn jacobian(&self, x: &StateVector) -> FlightJacobian {
        self.derivative_and_jacobian(x).1
    }

    /// [`Self::derivative`] and [`Self::jacobian`] together, sharing the spin parameter, the
    /// coefficients and the norms (the propagator needs both at every RK4 stage). The derivative
    /// is the same, bit for bit, as [`Self::derivative`]'s.
    pub fn derivative_and_jacobian(&self, x: &StateVector) -> (StateVector, FlightJacobian) {
        let field = self.field(x);
        let Field {
            v,
            w,
            speed_sq,
            speed,
            c,
            c_norm,
            sp,
            sp_eval,
            reynolds_drag,
            reynolds_magnus,
            reynolds_slope,
        } = field;

        // The gradients of Sp; zero where Sp is clamped or undefined.
        let (dsp_dv, dsp_dw) = if speed_sq < TINY || c_norm < TINY || sp > self.spin_parameter_max {
            (Vector3::zeros(), Vector3::zeros())
        } else {
            // d Sp = r (c_hat . d c) / |v|^2 - 2 Sp (v . d v) / |v|^2, c = w x v; with a spin
            // variance q the first term is times |w_perp| / sqrt(|w_perp|^2 + q) (and the second
            // Sp's).
            let r_over_speed_sq = self.radius / speed_sq;
            let spread = if self.spin_variance > 0.0 {
                let w_perp_sq = c_norm * c_norm / speed_sq;
                (w_perp_sq / (w_perp_sq + self.spin_variance)).sqrt()
            } else {
                1.0
            };
            let c_hat_scaled = c * (r_over_speed_sq / c_norm * spread);
            let dsp_dv = c_hat_scaled.cross(&w) - v * (sp / speed_sq * (1.0 + spread * spread));
            let dsp_dw = v.cross(&c_hat_scaled);
            (dsp_dv, dsp_dw)
        };
        let (cd, dcd) = self.drag.value_and_slope(sp_eval);
        let (cm, dcm) = self.magnus.value_and_slope(sp_eval);
        let (cd, dcd) = (cd * reynolds_drag, dcd * reynolds_drag);
        let (cm, dcm) = (cm * reynolds_magnus, dcm * reynolds_magnus);
        let dx = self.state_derivative(&field, cd, cm);

        // Drag: -k_D C_D |v| v, d(|v| v)/dv = |v| I + v v' / |v|.
        // Magnus: k_M C_M (w x v);  d(w x v)/dv = [w]x,  d(w x v)/dw = -[v]x.
        // Both coefficients move with Sp: the rank-one term (dC_D, dC_M part) is shared.
        let drag_factor = self.drag_factor * self.drag_scale;
        let magnus_factor = self.magnus_factor * self.magnus_scale;
        let drag_scale = -drag_factor * cd;
        let magnus_scale = magnus_factor * cm;
        let sp_direction = v * (-drag_factor * dcd * speed) + c * (magnus_factor * dcm);
        let mut dv_dv = sp_direction * dsp_dv.transpose() + w.cross_matrix() * magnus_scale;
        if speed >= TINY {
            let diagonal = drag_scale * speed;
            dv_dv += v * (v * (drag_scale / speed)).transpose();
            for i in 0..3 {
                dv_dv[(i, i)] += diagonal;
            }
            if reynolds_slope != 0.0 {
                // d f^a / dv = a f^a (d ln f / d ln Re) v / |v|^2.
                let [a_d, a_m] = self.reynolds_exponents;
                let re_direction = v * (drag_scale * a_d * reynolds_slope / speed)
                    + c * (magnus_scale * a_m * reynolds_slope / speed_sq);
                dv_dv += re_direction * v.transpose();
            }
        }
        let dv_dw = sp_direction * dsp_dw.transpose() - v.cross_matrix() * magnus_scale;

        let mut dv_dscales = SMatrix::<f64, 3, 2>::zeros();
        dv_dscales.set_column(0, &(v * (-self.drag_factor * cd * speed)));
        dv_dscales.set_column(1, &(c * (self.magnus_factor * cm)));
        let jacobian = FlightJacobian {
            dv_dv,
            dv_dw,
            spin_decay: self.spin_decay,
            dv_dscales,
        };
        (dx, jacobian)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;

    /// The seed's model (docs/models.md lists its values).
    fn model() -> FlightModel {
        FlightModel::new(&Config {
            aero: crate::config::AeroParams::seed_2014(),
            ..Config::default()
        })
    }

    #[test]
    fn polynomial_value_and_slope() {
        let p = Polynomial::new(&[1.0, -2.0, 3.0]);
        let (v, s) = p.value_and_slope(2.0);
        assert_relative_eq!(v, 1.0 - 4.0 + 12.0);
        assert_relative_eq!(s, -2.0 + 12.0);
    }

    /// docs/models.md lists these values of the Table 3 polynomials of Isomura et al. 2014.
    #[test]
    fn coefficients_match_the_listed_values() {
        let m = model();
        let cases_cd = [(0.1, 0.4034), (1.0, 0.6526)];
        for (sp, cd) in cases_cd {
            assert_relative_eq!(m.drag_coefficient(sp), cd, epsilon = 5e-5);
        }
        let cases_cm = [(0.1, 0.6520), (0.5, 0.2844), (1.0, 0.1824), (2.0, 0.1072)];
        for (sp, cm) in cases_cm {
            assert_relative_eq!(m.magnus_coefficient(sp), cm, epsilon = 5e-5);
        }
        // Clamped beyond Sp_max.
        assert_eq!(m.magnus_coefficient(3.5), m.magnus_coefficient(2.0));
        assert_eq!(m.drag_coefficient(-1.0), m.drag_coefficient(0.0));
    }

    #[test]
    fn factors_match_the_listed_values() {
        let m = model();
        assert_relative_eq!(m.drag_factor(), 0.27925, epsilon = 5e-6);
        assert_relative_eq!(m.magnus_factor(), 0.014893, epsilon = 5e-7);
    }

    /// The worked example of docs/models.md: v = (-8, 0, 1) m/s, w = (0, -300, 0) rad/s.
    #[test]
    fn worked_drag_and_magnus_example() {
        let f = model().forces(
            &Vector3::new(-8.0, 0.0, 1.0),
            &Vector3::new(0.0, -300.0, 0.0),
        );
        assert_relative_eq!(f.spin_parameter, 0.744, epsilon = 5e-4);
        assert_relative_eq!(f.drag, Vector3::new(10.70, 0.0, -1.34), epsilon = 5e-3);
        assert_relative_eq!(f.magnus, Vector3::new(-0.95, 0.0, -7.57), epsilon = 5e-3);
        assert!(!f.clamped);
    }

    /// Topspin on a ball moving toward -x is w along -y, and the Magnus force then points down.
    #[test]
    fn topspin_pushes_down_backspin_lifts() {
        let v = Vector3::new(-6.0, 0.0, 0.0);
        let top = model().forces(&v, &Vector3::new(0.0, -150.0, 0.0));
        let back = model().forces(&v, &Vector3::new(0.0, 150.0, 0.0));
        assert!(top.magnus.z < -1.0);
        assert!(back.magnus.z > 1.0);
    }

    /// The block-structured products (with a matrix, a row, the flight Jacobian, a scaled sum)
    /// equal the full 9x9 ones.
    #[test]
    fn flight_matrix_products_equal_the_full_ones() {
        let block = |seed: f64| Matrix3::from_fn(|i, j| (seed + (3 * i + j) as f64).sin());
        let f = FlightMatrix {
            position: 0.9,
            pv: block(1.0),
            pw: block(2.0),
            // Well conditioned, as over a stretch of flight (a near-identity velocity block).
            vv: Matrix3::identity() + Matrix3::from_fn(|i, j| 0.3 * ((i * i + 2 * j) as f64).cos()),
            vw: block(4.0),
            spin: 0.7,
        };
        let full = f.to_matrix();
        assert_eq!(full.fixed_view::<3, 3>(0, 0), Matrix3::identity() * 0.9);
        assert_eq!(full.fixed_view::<3, 3>(VELOCITY, 0), Matrix3::zeros());
        assert_eq!(full.fixed_view::<3, 3>(SPIN, VELOCITY), Matrix3::zeros());
        let m = SMatrix::<f64, 9, 9>::from_fn(|i, j| ((9 * i + j) as f64 * 0.37).cos());
        assert_relative_eq!(f.times(&m), full * m, epsilon = 1e-14);
        for i in 0..9 {
            assert_eq!(f.row(i), full.row(i));
        }
        let x = crate::physics::BallState::new(
            [0.1, 0.2, 0.3].into(),
            [-6.5, 0.1, 1.4].into(),
            [10.0, -150.0, 20.0].into(),
        )
        .to_vector();
        let a = model().jacobian(&x);
        assert_relative_eq!(
            a.apply_flight(&f).to_matrix(),
            a.to_matrix() * full,
            epsilon = 1e-12
        );
        assert_eq!(
            FlightMatrix::identity().to_matrix(),
            SMatrix::<f64, 9, 9>::identity()
        );
        assert_relative_eq!(
            f.add_scaled(&f, 0.5).to_matrix(),
            full * 1.5,
            epsilon = 1e-14
        );
        let rows = SMatrix::<f64, 4, 9>::from_fn(|i, j| ((9 * i + j) as f64 * 0.53).sin());
        assert_relative_eq!(f.premultiplied_by(&rows), rows * full, epsilon = 1e-14);
        let inverse = f.inverse().expect("invertible");
        assert_relative_eq!(
            inverse.to_matrix(),
            full.try_inverse().expect("invertible"),
            epsilon = 1e-9
        );
        assert_relative_eq!(
            inverse.times(&full),
            SMatrix::<f64, 9, 9>::identity(),
            epsilon = 1e-12
        );
        let singular = FlightMatrix {
            vv: Matrix3::zeros(),
            ..f
        };
        assert_eq!(singular.inverse(), None);
    }

    /// The propagator's fused evaluation gives the same derivative, bit for bit, and the same
    /// Jacobian as the separate ones, at rest, at clamped and at ordinary spin parameters.
    #[test]
    fn derivative_and_jacobian_together_equal_the_separate_ones() {
        let m = model();
        for (v, w) in [
            ([-6.5, 0.1, 1.4], [10.0, -150.0, 20.0]),
            ([0.0, 0.0, 0.0], [10.0, 0.0, 0.0]),
            ([0.5, 0.0, 0.0], [0.0, 900.0, 0.0]),
            ([3.0, -1.0, -2.0], [0.0, 0.0, 0.0]),
        ] {
            let x = crate::physics::BallState::new([0.1, 0.2, 0.3].into(), v.into(), w.into())
                .to_vector();
            let (dx, jacobian) = m.derivative_and_jacobian(&x);
            assert_eq!(dx, m.derivative(&x));
            assert_eq!(jacobian.to_matrix(), m.jacobian(&x).to_matrix());
        }
    }

    #[test]
    fn ball_at_rest_has_no_aero_force() {
        let f = model().forces(&Vector3::zeros(), &Vector3::new(10.0, 0.0, 0.0));
        assert_eq!(f.spin_parameter, 0.0);
        assert_eq!(f.drag, Vector3::zeros());
        assert_eq!(f.magnus, Vector3::zeros());
    }
}
