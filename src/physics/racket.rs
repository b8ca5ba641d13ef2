//! The racket impact: Kawazoe & Suzuki and Kawazoe et al. 2010, as stated in
//! docs/models.md "Racket impact", in the racket's frame at the impact point.
//!
//! Normal direction (unit normal n of the face, toward the ball; V = -(v - V_R) . n > 0 the normal
//! approach speed of the ball relative to the racket's impact point):
//!
//! ```text
//! M_r  = I_GH M / (I_GH + M c^2)          reduced mass at the impact point (000 eq. 3, 5-6;
//!                                         001 eq. 21, 23-26): M = M_R + M_H, c and I_GH about the
//!                                         centre of gravity of racket and arm (M_H = 0: free racket)
//! e_RB = clamp(0.77 - 0.0123 V, 0, 1)     ball on the clamped rubber (000 eq. 2), configured
//! e    = (e_r - m/M_r) / (1 + m/M_r)      rebound power coefficient (000 eq. 13; 001 eq. 39),
//!                                         e_r = e_RB without the plate's vibration loss
//! v_n' = -e v_n                           relative normal velocity after (001 eq. 38, 40, 41)
//! ```
//!
//! Contact time, forces and deformation come from [`super::contact`]. Tangentially, the
//! shell-friction impulse of the table bounce ([`super::bounce`]) in the face's plane with the
//! rubber's friction coefficient: slip u = v_t - V_R,t - r (w x n), Coulomb impulse mu m (1 + e) V
//! against it, capped where the rubber grips the ball: there the contact point leaves with
//! -e_t u (the tangential restitution of Garwin 1969 and Cross 2002; e_t = 0 rolls, the seed's
//! model), an impulse of (1 + e_t) 2/5 m u for a thin shell (I = 2/3 m r^2). About the normal,
//! the spin leaves as e_z times what came in (`rubber_torsional_restitution`; 1 keeps it, the
//! seed's model; ttball's empirical coefficient, calibrated on recorded hits). The racket's
//! tangential response is neglected (the impulse is a few per cent of its momentum).
//!
//! Force on the grip (the robot's wrist), Kawazoe et al. 2010 eq. 10-14: S_1 = chi S_0 with
//! chi = (M_R a b / J - 1) / (1 + (M_R / M_H)(1 - M_R b^2 / J)), a the impact point and b the
//! racket's centre of gravity from the grip, J = I_G + M_R b^2 the racket's inertia about the grip.
//! Shock acceleration of the grip, eq. 42: A = S_0 (1 / M - c X / I_GH), X the grip's distance
//! from the combined centre of gravity (M_H A = |chi| S_0: the same physics seen twice).

use nalgebra::Vector3;
use thiserror::Error;

use super::aero::Polynomial;
use super::bounce::{BounceRegime, ROLLING_ALPHA};
use super::contact::vibration_energy;
use super::contact::{Contact, ContactError, RestoringCharacteristic, VibrationMode};
use super::state::{BallState, SPIN, StateMatrix, StateVector, VELOCITY};
use crate::config::Config;

/// How far the face normal's length may be from 1 before a hit is refused.
pub const NORMAL_TOLERANCE: f64 = 1e-3;

/// The racket at the instant of impact, in the `table` frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RacketState {
    /// Velocity of the racket's impact point [m/s].
    pub velocity: Vector3<f64>,
    /// Unit normal of the hitting face, pointing toward the ball.
    pub normal: Vector3<f64>,
    /// Impact point from the racket's centre of gravity along its long axis, toward the tip [m].
    pub impact_offset: f64,
}

/// The normal impact: masses, restitution, contact.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NormalImpact {
    /// Normal approach speed of the ball relative to the racket's impact point, V [m/s].
    pub impact_speed: f64,
    /// Reduced mass of the racket (and arm) at the impact point, M_r [kg].
    pub reduced_mass: f64,
    /// Ball-rubber coefficient of restitution at this speed, e_RB [-].
    pub rubber_restitution: f64,
    /// Ball-racket restitution after the plate's vibration loss, e_r (= e_RB without it) [-].
    pub restitution: f64,
    /// Rebound power coefficient e: relative normal speed after / before [-].
    pub rebound_power_coefficient: f64,
    /// Energy left in the racket plate's vibration [J] (0 without modes).
    pub vibration_energy: f64,
    /// Contact time, forces and deformation.
    pub contact: Contact,
}

/// The load on what holds the racket (Kawazoe et al. 2010 eq. 10-14, 42).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WristLoad {
    /// Ratio chi of the grip force to the impact force, eq. 14 (0 for a free racket) [-].
    pub transmission: f64,
    /// Peak force transmitted to the grip / robot wrist, |chi| F_max [N].
    pub peak_force: f64,
    /// Peak shock acceleration of the grip, eq. 42 at F_max [m/s^2].
    pub peak_acceleration: f64,
}

/// One hit of the ball by the racket.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Hit {
    /// The ball just after the impact (position unchanged).
    pub ball: BallState,
    /// Velocity of the racket's impact point just after the impact [m/s].
    pub racket_velocity: Vector3<f64>,
    /// The normal impact.
    pub normal: NormalImpact,
    /// Whether the ball slid on the rubber throughout, or the rubber gripped it (`Rolling`: it
    /// leaves rolling, or with its contact point's slip reversed by `rubber_tangential_restitution`).
    pub regime: BounceRegime,
    /// The load on the grip.
    pub wrist: WristLoad,
}

/// Why a hit cannot be predicted.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum ImpactError {
    /// A value of the ball or racket state is NaN or infinite.
    #[error("the {what} has a non-finite value")]
    NotFinite {
        /// Which input.
        what: &'static str,
    },
    /// The face normal is not a unit vector.
    #[error(
        "the racket normal has length {length:.6}: give a unit vector pointing from the face toward the ball"
    )]
    NotUnitNormal {
        /// Its length.
        length: f64,
    },
    /// The ball does not move toward the face.
    #[error(
        "the ball does not approach the face: its velocity relative to the racket along the normal is {relative_normal_speed:+.3} m/s (it must be negative; is the normal pointing toward the ball?)"
    )]
    NotApproaching {
        /// (v - V_R) . n [m/s].
        relative_normal_speed: f64,
    },
    /// The impact point is not on the face.
    #[error(
        "impact offset {offset:+.4} m is off the face: the face spans {min:+.4} to {max:+.4} m from the centre of gravity (racket.face_start_from_grip_end, racket.face_end_from_grip_end)"
    )]
    OffFace {
        /// The offset asked for [m].
        offset: f64,
        /// Smallest offset on the face [m].
        min: f64,
        /// Largest offset on the face [m].
        max: f64,
    },
    /// The contact cannot be solved with the configured restoring characteristic.
    #[error(transparent)]
    Contact(#[from] ContactError),
}

/// The racket-impact model of the configured ball, racket and arm.
#[derive(Debug, Clone, PartialEq)]
pub struct RacketModel {
    ball_mass: f64,
    ball_radius: f64,
    racket_mass: f64,
    center_of_gravity: f64,
    inertia: f64,
    arm_mass: f64,
    grip: f64,
    face_start: f64,
    face_end: f64,
    rubber_restitution: Polynomial,
    friction: f64,
    tangential_restitution: f64,
    torsional_restitution: f64,
    rubber_covariance: Vec<f64>,
    rebound_scatter: (f64, f64),
    characteristic: RestoringCharacteristic,
    modes: Vec<VibrationMode>,
}

impl RacketModel {
    /// The model of the configured ball, racket and arm.
    pub fn new(config: &Config) -> Self {
        let r = &config.racket;
        Self {
            ball_mass: config.ball.mass,
            ball_radius: config.ball.radius,
            racket_mass: r.mass,
            center_of_gravity: r.center_of_gravity_from_grip_end,
            inertia: r.inertia_about_center_of_gravity,
            arm_mass: config.arm.equivalent_mass,
            grip: config.arm.grip_from_grip_end,
            face_start: r.face_start_from_grip_end,
            face_end: r.face_end_from_grip_end,
            rubber_restitution: Polynomial::new(&r.rubber_restitution),
            friction: r.rubber_friction,
            tangential_restitution: r.rubber_tangential_restitution,
            torsional_restitution: r.rubber_torsional_restitution,
            rubber_covariance: r.rubber_covariance.clone(),
            rebound_scatter: (
                r.rebound_scatter.first().copied().unwrap_or(0.0),
                r.rebound_scatter.get(1).copied().unwrap_or(0.0),
            ),
            characteristic: RestoringCharacteristic::new(&r.restoring_force_vs_stiffness),
            modes: r
                .vibration_mode_frequencies
                .iter()
                .zip(&r.vibration_mode_masses)
                .map(|(&frequency, &modal_mass)| VibrationMode {
                    frequency,
                    modal_mass,
                })
                .collect(),
        }
    }

    /// The same model with another equivalent mass at the grip [kg] (0: a free racket).
    pub fn with_arm_mass(&self, arm_mass: f64) -> Self {
        Self {
            arm_mass,
            ..self.clone()
        }
    }

    /// The rubber's constants in the order of `racket.rubber_covariance`: the restitution
    /// polynomial's coefficients, friction, tangential and torsional restitution.
    pub fn rubber_parameters(&self) -> Vec<f64> {
        let mut out = self.rubber_restitution.coefficients().to_vec();
        out.extend([
            self.friction,
            self.tangential_restitution,
            self.torsional_restitution,
        ]);
        out
    }

    /// The same model with the rubber's constants `parameters`, in the order of
    /// [`Self::rubber_parameters`]; None when it has another length.
    pub fn with_rubber_parameters(&self, parameters: &[f64]) -> Option<Self> {
        let n = parameters.len().checked_sub(3)?;
        if n != self.rubber_restitution.coefficients().len() {
            return None;
        }
        Some(Self {
            rubber_restitution: Polynomial::new(&parameters[..n]),
            friction: parameters[n],
            tangential_restitution: parameters[n + 1],
            torsional_restitution: parameters[n + 2],
            ..self.clone()
        })
    }

    /// Covariance of the rubber's constants (row-major over [`Self::rubber_parameters`]); empty
    /// when they are known exactly.
    pub fn rubber_covariance(&self) -> &[f64] {
        &self.rubber_covariance
    }

    /// Scatter of single hits about the model per component: outgoing velocity [m/s], spin
    /// [rad/s].
    pub fn rebound_scatter(&self) -> (f64, f64) {
        self.rebound_scatter
    }

    /// Whether the rubber's constants or single hits carry uncertainty.
    pub fn is_uncertain(&self) -> bool {
        self.rubber_covariance.iter().any(|v| *v != 0.0)
            || self.rebound_scatter.0 > 0.0
            || self.rebound_scatter.1 > 0.0
    }

    /// The ball's mass [kg].
    pub fn ball_mass(&self) -> f64 {
        self.ball_mass
    }

    /// The impact offsets on the face, from the centre of gravity [m].
    pub fn face_offsets(&self) -> (f64, f64) {
        (
            self.face_start - self.center_of_gravity,
            self.face_end - self.center_of_gravity,
        )
    }

    /// Refuses an impact point off the face.
    pub fn check_on_face(&self, offset: f64) -> Result<(), ImpactError> {
        let (min, max) = self.face_offsets();
        if (min..=max).contains(&offset) {
            Ok(())
        } else {
            Err(ImpactError::OffFace { offset, min, max })
        }
    }

    /// Shift of the centre of gravity toward the grip when the arm's mass is added, Delta G
    /// (Kawazoe et al. 2010 eq. 26) [m].
    fn center_shift(&self) -> f64 {
        (self.center_of_gravity - self.grip) * self.arm_mass / (self.racket_mass + self.arm_mass)
    }

    /// Inertia of racket and arm about their common centre of gravity, I_GH (Kawazoe & Suzuki eq. 6;
    /// Kawazoe et al. 2010 eq. 25) [kg m^2].
    fn combined_inertia(&self) -> f64 {
        let shift = self.center_shift();
        self.inertia
            + self.racket_mass * shift * shift
            + self.arm_mass * (self.center_of_gravity - self.grip - shift).powi(2)
    }

    /// Reduced mass of racket and arm at the impact point `offset` [m] from the racket's centre
    /// of gravity (Kawazoe & Suzuki eq. 3, 5; Kawazoe et al. 2010 eq. 21, 23-24) [kg].
    pub fn reduced_mass(&self, offset: f64) -> f64 {
        let total = self.racket_mass + self.arm_mass;
        let inertia = self.combined_inertia();
        let c = offset + self.center_shift();
        inertia * total / (inertia + total * c * c)
    }

    /// Ball-rubber coefficient of restitution at normal impact speed `speed` [m/s], e_RB
    /// (Kawazoe & Suzuki eq. 2), clamped to [0, 1].
    pub fn rubber_restitution(&self, speed: f64) -> f64 {
        self.rubber_restitution.value(speed).clamp(0.0, 1.0)
    }

    /// The normal impact at approach speed `speed` [m/s] on the point `offset` [m].
    pub fn normal_impact(&self, speed: f64, offset: f64) -> Result<NormalImpact, ContactError> {
        let m = self.ball_mass;
        let reduced_mass = self.reduced_mass(offset);
        let rubber_restitution = self.rubber_restitution(speed);
        let contact = self
            .characteristic
            .contact(speed, m, reduced_mass, rubber_restitution)?;
        let vibration = vibration_energy(&self.modes, contact.peak_force, contact.contact_time);
        let restitution = if vibration > 0.0 {
            // Kawazoe & Suzuki eq. 18-19: the rubber's and the plate's losses together.
            let loss = 2.0 * vibration * (m + reduced_mass) / (m * reduced_mass * speed * speed);
            (rubber_restitution.powi(2) - loss).max(0.0).sqrt()
        } else {
            rubber_restitution
        };
        Ok(NormalImpact {
            impact_speed: speed,
            reduced_mass,
            rubber_restitution,
            restitution,
            rebound_power_coefficient: rebound_power_coefficient(restitution, m / reduced_mass),
            vibration_energy: vibration,
            contact,
        })
    }

    /// The load on the grip for an impact on `offset` [m] with peak force `peak_force` [N].
    pub fn wrist_load(&self, offset: f64, peak_force: f64) -> WristLoad {
        let a = self.center_of_gravity + offset - self.grip;
        let b = self.center_of_gravity - self.grip;
        let j = self.inertia + self.racket_mass * b * b;
        let transmission = if self.arm_mass > 0.0 {
            (self.racket_mass * a * b / j - 1.0)
                / (1.0 + self.racket_mass / self.arm_mass * (1.0 - self.racket_mass * b * b / j))
        } else {
            0.0
        };
        let total = self.racket_mass + self.arm_mass;
        let c = offset + self.center_shift();
        let grip_from_center = b - self.center_shift();
        let acceleration =
            peak_force * (1.0 / total - c * grip_from_center / self.combined_inertia());
        WristLoad {
            transmission,
            peak_force: transmission.abs() * peak_force,
            peak_acceleration: acceleration.abs(),
        }
    }

    /// The ball and racket just after `racket` hits `ball`.
    pub fn hit(&self, ball: &BallState, racket: &RacketState) -> Result<Hit, ImpactError> {
        let (n, speed) = self.approach(ball, racket)?;
        let normal = self.normal_impact(speed, racket.impact_offset)?;
        let (outgoing, regime, normal_change) =
            self.outgoing(ball, racket, &n, speed, normal.rebound_power_coefficient);
        let racket_velocity =
            racket.velocity - n * (self.ball_mass / normal.reduced_mass * normal_change);
        Ok(Hit {
            ball: outgoing,
            racket_velocity,
            normal,
            regime,
            wrist: self.wrist_load(racket.impact_offset, normal.contact.peak_force),
        })
    }

    /// The ball just after `racket` hits `ball`, as [`Self::hit`] finds it, without the contact's
    /// time, force and the wrist's load where no vibration mode needs them (calibration evaluates
    /// thousands of hits).
    pub fn rebound(
        &self,
        ball: &BallState,
        racket: &RacketState,
    ) -> Result<BallState, ImpactError> {
        let (n, speed) = self.approach(ball, racket)?;
        let e = if self.modes.is_empty() {
            let mass_ratio = self.ball_mass / self.reduced_mass(racket.impact_offset);
            rebound_power_coefficient(self.rubber_restitution(speed), mass_ratio)
        } else {
            self.normal_impact(speed, racket.impact_offset)?
                .rebound_power_coefficient
        };
        Ok(self.outgoing(ball, racket, &n, speed, e).0)
    }

    /// First-order covariance of the ball just after `racket` hits `ball`, whose state has the
    /// covariance `covariance`: J P J^T with J = d(after)/d(before) by central differences, plus
    /// the rubber's calibrated uncertainty (`racket.rubber_covariance`, carried the same way) and
    /// the scatter of single hits about the model (`racket.rebound_scatter`). None when a
    /// neighbouring state cannot be hit.
    pub fn rebound_covariance(
        &self,
        ball: &BallState,
        covariance: &StateMatrix,
        racket: &RacketState,
    ) -> Option<StateMatrix> {
        let after = |model: &Self, x: &StateVector| {
            model
                .rebound(&BallState::from_vector(x), racket)
                .ok()
                .map(|b| b.to_vector())
        };
        let x0 = ball.to_vector();
        let mut by_ball = StateMatrix::zeros();
        for k in 0..9 {
            // 1 um, 1 um/s, 1 mrad/s: the hit is smooth far beyond these (but at the switch
            // between sliding and gripping).
            let h = if k < SPIN { 1e-6 } else { 1e-3 };
            let (mut plus, mut minus) = (x0, x0);
            plus[k] += h;
            minus[k] -= h;
            by_ball.set_column(
                k,
                &((after(self, &plus)? - after(self, &minus)?) / (2.0 * h)),
            );
        }
        let mut out = by_ball * covariance * by_ball.transpose();
        if self.rubber_covariance.iter().any(|v| *v != 0.0) {
            let theta = self.rubber_parameters();
            let n = theta.len();
            let mut by_rubber = nalgebra::DMatrix::zeros(9, n);
            for k in 0..n {
                let h = 1e-6;
                let (mut plus, mut minus) = (theta.clone(), theta.clone());
                plus[k] += h;
                minus[k] -= h;
                let column = (after(&self.with_rubber_parameters(&plus)?, &x0)?
                    - after(&self.with_rubber_parameters(&minus)?, &x0)?)
                    / (2.0 * h);
                by_rubber.set_column(k, &column);
            }
            let sigma = nalgebra::DMatrix::from_row_slice(n, n, &self.rubber_covariance);
            let added = &by_rubber * sigma * by_rubber.transpose();
            out += StateMatrix::from_iterator(added.iter().copied());
        }
        let (velocity, spin) = self.rebound_scatter;
        for k in 0..3 {
            out[(VELOCITY + k, VELOCITY + k)] += velocity * velocity;
            out[(SPIN + k, SPIN + k)] += spin * spin;
        }
        Some((out + out.transpose()) * 0.5)
    }

    /// Checks a hit's inputs: the face's unit normal and the ball's normal approach speed.
    fn approach(
        &self,
        ball: &BallState,
        racket: &RacketState,
    ) -> Result<(Vector3<f64>, f64), ImpactError> {
        if !ball.is_finite() {
            return Err(ImpactError::NotFinite { what: "ball state" });
        }
        let racket_finite = racket
            .velocity
            .iter()
            .chain(racket.normal.iter())
            .all(|v| v.is_finite())
            && racket.impact_offset.is_finite();
        if !racket_finite {
            return Err(ImpactError::NotFinite {
                what: "racket state",
            });
        }
        let length = racket.normal.norm();
        if (length - 1.0).abs() > NORMAL_TOLERANCE {
            return Err(ImpactError::NotUnitNormal { length });
        }
        self.check_on_face(racket.impact_offset)?;
        let n = racket.normal / length;
        let relative_normal_speed = (ball.velocity - racket.velocity).dot(&n);
        if relative_normal_speed >= 0.0 {
            return Err(ImpactError::NotApproaching {
                relative_normal_speed,
            });
        }
        Ok((n, -relative_normal_speed))
    }

    /// The ball after an impact at normal speed `speed` with rebound power coefficient `e` on
    /// the face of normal `n`: the outgoing state, the tangential regime and the normal velocity
    /// change.
    fn outgoing(
        &self,
        ball: &BallState,
        racket: &RacketState,
        n: &Vector3<f64>,
        speed: f64,
        e: f64,
    ) -> (BallState, BounceRegime, f64) {
        // Normal velocity change of the ball: the impulse per unit ball mass.
        let normal_change = (1.0 + e) * speed;
        let r = self.ball_radius;
        let relative = ball.velocity - racket.velocity;
        let slip = relative + n * speed - r * ball.spin.cross(n);
        let slip_speed = slip.norm();
        let sliding_alpha = if slip_speed > 0.0 {
            self.friction * normal_change / slip_speed
        } else {
            f64::INFINITY
        };
        // Where the rubber grips: the contact point's slip reversed to -e_t u.
        let gripping_alpha = (1.0 + self.tangential_restitution) * ROLLING_ALPHA;
        let (regime, alpha) = if sliding_alpha >= gripping_alpha {
            (BounceRegime::Rolling, gripping_alpha)
        } else {
            (BounceRegime::Sliding, sliding_alpha)
        };
        let tangential_change = -alpha * slip;
        let velocity = ball.velocity + n * normal_change + tangential_change;
        // The tangential impulse turns the spin in the face's plane only; about the normal the
        // contact patch's twist leaves e_z times what came in.
        let mut spin = ball.spin - 1.5 / r * n.cross(&tangential_change);
        if self.torsional_restitution != 1.0 {
            spin += n * ((self.torsional_restitution - 1.0) * ball.spin.dot(n));
        }
        (
            BallState::new(ball.position, velocity, spin),
            regime,
            normal_change,
        )
    }
}

/// The rebound power coefficient e = (e_r - m/M_r) / (1 + m/M_r) of a ball on a racket of
/// restitution `restitution` and mass ratio `mass_ratio` = m / M_r (Kawazoe & Suzuki eq. 13; Kawazoe et al. 2010
/// eq. 39).
pub fn rebound_power_coefficient(restitution: f64, mass_ratio: f64) -> f64 {
    (restitution - mass_ratio) / (1.0 + mass_ratio)
}
