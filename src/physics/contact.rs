//! Contact time, force and deformation of a ball-racket impact, and the racket plate's vibration
//! loss: Kawazoe & Suzuki (eq. 1, 7-11, 14-20; Kawazoe et al. 2010 eq. 27-37), as stated in
//! docs/models.md "Racket impact":
//!
//! ```text
//! m_e    = m M_r / (m + M_r)                        ball against the racket's reduced mass
//! T_c    = pi sqrt(m_e / K)                         half a period of the ball-rubber spring (eq. 7)
//! F_mean = V (1 + e_RB) sqrt(m_e) sqrt(K) / pi      impulse m_e (1 + e_RB) V over T_c (eq. 11)
//! F      = f(K)                                     restoring characteristic (eq. 1), configured
//! F_max  = pi/2 F_mean                              half-sine pulse (eq. 14)
//! ```
//!
//! The stiffness K of the impact is where eq. (11) meets the characteristic; [`ContactError`]
//! says so when they never meet (the transcribed eq. (1) peaks at 0.17 kgf, far below any real
//! impact, docs/models.md). The deformation of the ball-rubber system at a force f(K) is
//! X = integral of dF / K = integral f'(k) / k dk from the unloaded stiffness K_0 (f(K_0) = 0).
//!
//! Vibration loss (Kawazoe & Suzuki eq. 15-20): the half-sine pulse has the spectrum
//! S(f) = (2 F_max T_c / pi) |cos(pi f T_c) / (1 - (2 f T_c)^2)|; a plate mode of frequency f_k and
//! modal mass m_k at the impact point takes the energy S(f_k)^2 / (2 m_k), which lowers the
//! restitution to e_r = sqrt(e_RB^2 - 2 E_1 (m + M_r) / (m M_r V^2)) (eq. 18-19).

use std::f64::consts::PI;

use thiserror::Error;

use super::aero::Polynomial;

/// Largest stiffness searched for the contact [N/m] (about 1000 kgf/mm, far beyond any ball).
const MAX_STIFFNESS: f64 = 1.0e10;
/// Smallest stiffness searched when the characteristic is loaded from K = 0 [N/m].
const MIN_STIFFNESS: f64 = 1.0;
/// Ratio between successive stiffnesses of the search grid.
const SEARCH_RATIO: f64 = 1.1;
/// Bisection steps after the bracket is found (relative precision 2^-60 of a 10 % bracket).
const BISECTIONS: usize = 60;

/// The restoring characteristic F = f(K) of the ball-rubber system (Kawazoe & Suzuki eq. 1), in SI.
#[derive(Debug, Clone, PartialEq)]
pub struct RestoringCharacteristic {
    force: Polynomial,
    /// The polynomial's coefficients, lowest order first [N per (N/m)^i].
    coefficients: Vec<f64>,
    /// The unloaded stiffness K_0 where f(K_0) = 0 (0 when f(0) >= 0) [N/m].
    unloaded: f64,
}

/// Where eq. (11) meets the restoring characteristic, and what follows from it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Contact {
    /// Equivalent stiffness K of the ball-rubber system during the impact [N/m].
    pub stiffness: f64,
    /// Ball-racket contact time T_c [s].
    pub contact_time: f64,
    /// Mean normal force over the contact [N].
    pub mean_force: f64,
    /// Peak normal force of the half-sine pulse, pi/2 F_mean [N].
    pub peak_force: f64,
    /// Normal impulse on the ball, F_mean T_c [N s].
    pub impulse: f64,
    /// Deformation of ball and rubber together at the mean force [m].
    pub deformation_at_mean_force: f64,
    /// Deformation at the peak force [m]; `None` when the characteristic never reaches it.
    pub deformation_at_peak_force: Option<f64>,
}

/// Eq. (11) and the restoring characteristic do not meet.
#[derive(Debug, Clone, Copy, PartialEq, Error)]
#[error(
    "no contact solution at {impact_speed:.2} m/s: eq. (11) needs F = {slope:.4} sqrt(K) N \
     (about {needed_at_1ms:.0} N for a 1 ms contact), but the restoring characteristic \
     racket.restoring_force_vs_stiffness stays below it up to K = {MAX_STIFFNESS:.0e} N/m \
     (its force there: {force_at_max:.3e} N); configure a curve F = f(K) that reaches the forces \
     of a real impact (docs/models.md \"Racket impact\")"
)]
pub struct ContactError {
    /// Normal impact speed [m/s].
    pub impact_speed: f64,
    /// The factor A of eq. (11), F_mean = A sqrt(K) [N / sqrt(N/m)].
    pub slope: f64,
    /// The mean force eq. (11) asks for at the stiffness of a 1 ms contact [N].
    pub needed_at_1ms: f64,
    /// The characteristic's force at the largest stiffness searched [N].
    pub force_at_max: f64,
}

impl RestoringCharacteristic {
    /// The characteristic from its coefficients, lowest order first, F [N] and K [N/m].
    pub fn new(coefficients: &[f64]) -> Self {
        let force = Polynomial::new(coefficients);
        let unloaded = if force.value(0.0) >= 0.0 {
            0.0
        } else {
            rise_through_zero(|k| force.value(k), MIN_STIFFNESS).unwrap_or(f64::INFINITY)
        };
        Self {
            force,
            coefficients: coefficients.to_vec(),
            unloaded,
        }
    }

    /// The restoring force at stiffness `k` [N].
    pub fn force(&self, stiffness: f64) -> f64 {
        self.force.value(stiffness)
    }

    /// Deformation of ball and rubber when loaded from K_0 to `stiffness`:
    /// X = c1 ln(K / K_0) + sum_{i >= 2} i c_i / (i - 1) (K^(i-1) - K_0^(i-1)) [m]; infinite when
    /// c1 is not 0 and K_0 = 0 (the curve gives no finite deformation then).
    pub fn deformation(&self, stiffness: f64) -> f64 {
        let k0 = self.unloaded;
        let mut x = 0.0;
        for (i, &c) in self.coefficients.iter().enumerate().skip(1) {
            if c == 0.0 {
                continue;
            }
            if i == 1 {
                x += c * (stiffness / k0).ln();
            } else {
                let p = (i - 1) as i32;
                x += i as f64 * c / (i - 1) as f64 * (stiffness.powi(p) - k0.powi(p));
            }
        }
        x
    }

    /// Solves eq. (11) for an impact at normal speed `impact_speed` [m/s] of a ball of mass
    /// `ball_mass` against the reduced mass `reduced_mass` [kg], with the rubber's restitution
    /// `rubber_restitution`: the smallest stiffness above K_0 where f(K) = F_mean(K).
    pub fn contact(
        &self,
        impact_speed: f64,
        ball_mass: f64,
        reduced_mass: f64,
        rubber_restitution: f64,
    ) -> Result<Contact, ContactError> {
        let effective_mass = ball_mass * reduced_mass / (ball_mass + reduced_mass);
        let slope = impact_speed * (1.0 + rubber_restitution) * effective_mass.sqrt() / PI;
        let gap = |k: f64| self.force(k) - slope * k.sqrt();
        let start = self.unloaded.max(MIN_STIFFNESS);
        let no_solution = || ContactError {
            impact_speed,
            slope,
            needed_at_1ms: slope * PI * effective_mass.sqrt() / 1.0e-3,
            force_at_max: self.force(MAX_STIFFNESS),
        };
        if !start.is_finite() {
            return Err(no_solution());
        }
        let stiffness = rise_through_zero(gap, start).ok_or_else(no_solution)?;
        let mean_force = slope * stiffness.sqrt();
        let contact_time = PI * (effective_mass / stiffness).sqrt();
        let peak_force = 0.5 * PI * mean_force;
        let deformation_at_peak_force =
            rise_through_zero(|k| self.force(k) - peak_force, stiffness)
                .map(|k| self.deformation(k));
        Ok(Contact {
            stiffness,
            contact_time,
            mean_force,
            peak_force,
            impulse: mean_force * contact_time,
            deformation_at_mean_force: self.deformation(stiffness),
            deformation_at_peak_force,
        })
    }
}

/// The first stiffness from `start` where `g` rises through zero, searched on a geometric grid up
/// to [`MAX_STIFFNESS`] and bisected.
fn rise_through_zero(g: impl Fn(f64) -> f64, start: f64) -> Option<f64> {
    let (mut low, mut high) = bracket_rise(&g, start)?;
    for _ in 0..BISECTIONS {
        let mid = 0.5 * (low + high);
        if g(mid) < 0.0 {
            low = mid;
        } else {
            high = mid;
        }
    }
    Some(0.5 * (low + high))
}

/// A bracket (low, high) with g(low) < 0 <= g(high), from `start` upward on a geometric grid.
fn bracket_rise(g: impl Fn(f64) -> f64, start: f64) -> Option<(f64, f64)> {
    let mut low = start;
    if g(low) >= 0.0 {
        return Some((low, low));
    }
    while low < MAX_STIFFNESS {
        let high = low * SEARCH_RATIO;
        if g(high) >= 0.0 {
            return Some((low, high));
        }
        low = high;
    }
    None
}

/// One vibration mode of the racket plate at the impact point.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VibrationMode {
    /// Natural frequency f_k [Hz].
    pub frequency: f64,
    /// Modal mass at the impact point [kg].
    pub modal_mass: f64,
}

/// Amplitude spectrum of a half-sine force pulse of peak `peak_force` and duration
/// `contact_time` at frequency `frequency` (Kawazoe & Suzuki eq. 15; Kawazoe et al. 2010 eq. 33) [N s]. At f = 0 it
/// is the impulse 2 F_max T_c / pi.
pub fn pulse_spectrum(frequency: f64, peak_force: f64, contact_time: f64) -> f64 {
    let x = 2.0 * frequency * contact_time;
    // cos(pi x / 2) / (1 - x^2) has the limit pi / 4 at x = 1.
    let shape = if (1.0 - x * x).abs() < 1e-9 {
        PI / 4.0
    } else {
        (0.5 * PI * x).cos() / (1.0 - x * x)
    };
    2.0 * peak_force * contact_time / PI * shape.abs()
}

/// Energy the pulse leaves in the plate's modes, sum of S(f_k)^2 / (2 m_k) [J].
pub fn vibration_energy(modes: &[VibrationMode], peak_force: f64, contact_time: f64) -> f64 {
    modes
        .iter()
        .map(|m| {
            pulse_spectrum(m.frequency, peak_force, contact_time).powi(2) / (2.0 * m.modal_mass)
        })
        .fold(0.0, |total, energy| total + energy)
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;

    const KGF: f64 = 9.80665;
    const KGF_PER_MM: f64 = 9806.65;

    /// The transcribed eq. (1), converted to SI: it never reaches the forces of eq. (11).
    fn transcribed_eq1() -> RestoringCharacteristic {
        let paper = [-0.0999, 0.1098, 0.1433, -0.066];
        let si: Vec<f64> = paper
            .iter()
            .enumerate()
            .map(|(i, c)| c * KGF / KGF_PER_MM.powi(i as i32))
            .collect();
        RestoringCharacteristic::new(&si)
    }

    #[test]
    fn transcribed_eq1_has_no_contact_solution_and_says_why() {
        let c = transcribed_eq1();
        // Its unloaded stiffness, f(K_0) = 0: 0.584 kgf/mm.
        assert_relative_eq!(c.unloaded / KGF_PER_MM, 0.584, epsilon = 0.001);
        let err = c
            .contact(10.0, 0.0025, 0.0781, 0.647)
            .expect_err("no solution");
        let text = err.to_string();
        assert!(
            text.contains("racket.restoring_force_vs_stiffness"),
            "{text}"
        );
        // About 4 kgf for a 1 ms contact at 10 m/s (docs/models.md).
        assert_relative_eq!(err.needed_at_1ms / KGF, 4.1, epsilon = 0.1);
    }

    /// A pure cubic F = c K^3 is the Hertz law F = k X^1.5: X = 1.5 F / K, and eq. (11) gives
    /// K = (A / c)^(2/5) in closed form.
    #[test]
    fn hertz_cubic_meets_eq11_in_closed_form() {
        let c3 = 1e-13;
        let curve = RestoringCharacteristic::new(&[0.0, 0.0, 0.0, c3]);
        let (m, mr, e) = (0.0027, 0.08, 0.65);
        let contact = curve.contact(12.0, m, mr, e).expect("solution");
        let me = m * mr / (m + mr);
        let slope = 12.0 * (1.0 + e) * me.sqrt() / PI;
        assert_relative_eq!(
            contact.stiffness,
            (slope / c3).powf(0.4),
            max_relative = 1e-12
        );
        assert_relative_eq!(contact.impulse, me * (1.0 + e) * 12.0, max_relative = 1e-12);
        assert_relative_eq!(
            contact.deformation_at_mean_force,
            1.5 * contact.mean_force / contact.stiffness,
            max_relative = 1e-12
        );
        let peak = contact.deformation_at_peak_force.expect("reached");
        // X grows as F^(2/3).
        assert_relative_eq!(
            peak / contact.deformation_at_mean_force,
            (0.5 * PI).powf(2.0 / 3.0),
            max_relative = 1e-9
        );
    }

    #[test]
    fn half_sine_spectrum_is_the_impulse_at_zero_frequency_and_continuous_at_its_pole() {
        let (fmax, tc) = (400.0, 1e-3);
        assert_relative_eq!(pulse_spectrum(0.0, fmax, tc), 2.0 * fmax * tc / PI);
        let at = pulse_spectrum(500.0, fmax, tc);
        let near = pulse_spectrum(500.0 * (1.0 + 1e-6), fmax, tc);
        assert_relative_eq!(at, near, max_relative = 1e-5);
        // A mode far above 1 / T_c takes almost nothing.
        assert!(pulse_spectrum(20_000.0, fmax, tc) < 0.01 * pulse_spectrum(0.0, fmax, tc));
    }
}
