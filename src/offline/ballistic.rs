//! Short ballistic least-squares fits of recorded ball positions: the measured bounce (contact
//! time and point, velocities before and after) and smoothed positions.
//!
//! Over a few frames (tens of milliseconds) a flying ball follows
//! `p(t) = p0 + v0 (t - t_ref) - g/2 (t - t_ref)^2 e_z` to within a fraction of a millimetre:
//! drag and Magnus accelerations of a few m/s^2 add about a 0.1 mm over 10 ms. Fitting position
//! and velocity with gravity known needs only two samples and is far less sensitive to noise than
//! a free quadratic. Both frames used here (the launcher's and `table`) have z up.

use nalgebra::Vector3;

/// One recorded sample: time since the start of the flight [s] and ball centre [m].
pub type Sample = (f64, Vector3<f64>);

/// Samples fitted on each side of a bounce [-].
pub const BOUNCE_FIT_SAMPLES: usize = 4;

/// How far [s] the fitted contact may lie outside the interval between the last sample before
/// and the first sample after the bounce (timing noise).
const CONTACT_TOLERANCE: f64 = 0.001;

/// A ballistic fit `p(t) = position + velocity (t - t_ref) - g/2 (t - t_ref)^2 e_z`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BallisticFit {
    /// Reference time [s].
    pub t_ref: f64,
    /// Fitted position at `t_ref` [m].
    pub position: Vector3<f64>,
    /// Fitted velocity at `t_ref` [m/s].
    pub velocity: Vector3<f64>,
    /// Gravitational acceleration [m/s^2], along -z.
    pub gravity: f64,
    /// Sum of squared residuals over the three axes [m^2].
    pub rss: f64,
    /// Samples fitted [-].
    pub count: usize,
}

impl BallisticFit {
    /// Position of the fit at time `t` [s] [m].
    pub fn position_at(&self, t: f64) -> Vector3<f64> {
        let tau = t - self.t_ref;
        self.position + self.velocity * tau - Vector3::z() * (0.5 * self.gravity * tau * tau)
    }

    /// Velocity of the fit at time `t` [s] [m/s].
    pub fn velocity_at(&self, t: f64) -> Vector3<f64> {
        self.velocity - Vector3::z() * (self.gravity * (t - self.t_ref))
    }
}

/// Fits position and velocity at `t_ref` [s] to `samples` with gravity [m/s^2] known; `None`
/// with fewer than two distinct times.
pub fn fit_ballistic(samples: &[Sample], t_ref: f64, gravity: f64) -> Option<BallisticFit> {
    let n = samples.len();
    if n < 2 {
        return None;
    }
    let count = n as f64;
    let mean_tau = samples.iter().map(|(t, _)| t - t_ref).sum::<f64>() / count;
    let sxx: f64 = samples
        .iter()
        .map(|(t, _)| (t - t_ref - mean_tau).powi(2))
        .sum();
    if sxx <= 0.0 {
        return None;
    }
    // Remove the known gravity term, then fit a straight line per axis.
    let corrected = |(t, p): &Sample| {
        let tau = t - t_ref;
        p + Vector3::z() * (0.5 * gravity * tau * tau)
    };
    let mean_p = samples.iter().map(corrected).sum::<Vector3<f64>>() / count;
    let sxy: Vector3<f64> = samples
        .iter()
        .map(|s| (corrected(s) - mean_p) * (s.0 - t_ref - mean_tau))
        .sum();
    let velocity = sxy / sxx;
    let position = mean_p - velocity * mean_tau;
    let mut fit = BallisticFit {
        t_ref,
        position,
        velocity,
        gravity,
        rss: 0.0,
        count: n,
    };
    fit.rss = samples
        .iter()
        .map(|(t, p)| (p - fit.position_at(*t)).norm_squared())
        .sum();
    Some(fit)
}

/// A bounce found in a recorded flight.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MeasuredBounce {
    /// Contact time [s]: where the fits before and after the bounce meet in height.
    pub time: f64,
    /// Ball centre at contact [m] (mean of the two fits; their heights agree by construction).
    pub position: Vector3<f64>,
    /// Velocity just before contact [m/s].
    pub velocity_before: Vector3<f64>,
    /// Velocity just after contact [m/s].
    pub velocity_after: Vector3<f64>,
    /// Index of the first sample after contact [-].
    pub first_after: usize,
    /// Samples fitted before and after contact [-].
    pub fitted: (usize, usize),
    /// RMS residual of the two fits, per axis [m].
    pub rms_residual: f64,
}

/// The table bounce of a recorded flight (z up), or `None` when the recording does not show one.
///
/// The lowest sample is the bounce when at least one later sample is higher. Up to
/// [`BOUNCE_FIT_SAMPLES`] samples on each side are fitted with [`fit_ballistic`]; the contact is
/// where the falling and the rising fits meet (equal curvature, so one linear equation). The
/// lowest sample itself is put on the side that fits better, and the contact must fall between
/// the last sample before and the first after it. At least two samples are needed on each side.
pub fn detect_bounce(samples: &[Sample], gravity: f64) -> Option<MeasuredBounce> {
    let n = samples.len();
    let lowest = (0..n).min_by(|&a, &b| samples[a].1.z.total_cmp(&samples[b].1.z))?;
    if lowest == 0 || lowest + 1 >= n || samples[lowest + 1].1.z <= samples[lowest].1.z {
        return None;
    }
    let t_ref = samples[lowest].0;
    let mut best: Option<MeasuredBounce> = None;
    for split in [lowest + 1, lowest] {
        let before = &samples[split.saturating_sub(BOUNCE_FIT_SAMPLES)..split];
        let after = &samples[split..(split + BOUNCE_FIT_SAMPLES).min(n)];
        let (Some(fb), Some(fa)) = (
            fit_ballistic(before, t_ref, gravity),
            fit_ballistic(after, t_ref, gravity),
        ) else {
            continue;
        };
        let closing = fb.velocity.z - fa.velocity.z;
        if closing >= 0.0 {
            continue;
        }
        let time = t_ref + (fa.position.z - fb.position.z) / closing;
        let (Some(last_before), Some(first_after)) = (before.last(), after.first()) else {
            continue;
        };
        if time < last_before.0 - CONTACT_TOLERANCE || time > first_after.0 + CONTACT_TOLERANCE {
            continue;
        }
        let velocity_before = fb.velocity_at(time);
        let velocity_after = fa.velocity_at(time);
        if velocity_before.z >= 0.0 || velocity_after.z <= 0.0 {
            continue;
        }
        let count = (fb.count + fa.count) as f64;
        let candidate = MeasuredBounce {
            time,
            position: (fb.position_at(time) + fa.position_at(time)) * 0.5,
            velocity_before,
            velocity_after,
            first_after: split,
            fitted: (fb.count, fa.count),
            rms_residual: ((fb.rss + fa.rss) / (3.0 * count)).sqrt(),
        };
        if best.is_none_or(|b| candidate.rms_residual < b.rms_residual) {
            best = Some(candidate);
        }
    }
    best
}

#[cfg(test)]
mod tests {
    use super::*;

    const G: f64 = 9.80665;

    /// A synthetic bounce: falling at 3 m/s onto z = 0.02 at t = 0.1 s, leaving at 2.7 m/s.
    fn bounce_samples(dt: f64, phase: f64) -> Vec<Sample> {
        let tc = 0.1;
        (0..40)
            .map(|i| {
                let t = phase + i as f64 * dt;
                let tau = t - tc;
                let (vz, vx) = if tau < 0.0 { (-3.0, 4.0) } else { (2.7, 3.0) };
                let p = Vector3::new(1.0 + vx * tau, 0.01, 0.02 + vz * tau - 0.5 * G * tau * tau);
                (t, p)
            })
            .collect()
    }

    #[test]
    fn finds_the_contact_between_frames() {
        for phase in [0.0, 0.001, 0.0027, 0.0049] {
            let b = detect_bounce(&bounce_samples(0.0056, phase), G).unwrap();
            assert!((b.time - 0.1).abs() < 1e-9, "{phase}: {b:?}");
            assert!((b.position.z - 0.02).abs() < 1e-9, "{b:?}");
            assert!((b.velocity_before.z + 3.0).abs() < 1e-9);
            assert!((b.velocity_after.z - 2.7).abs() < 1e-9);
        }
    }

    #[test]
    fn no_bounce_when_the_recording_ends_falling() {
        let samples: Vec<Sample> = bounce_samples(0.0056, 0.0)
            .into_iter()
            .filter(|(t, _)| *t < 0.099)
            .collect();
        assert!(detect_bounce(&samples, G).is_none());
    }

    #[test]
    fn the_ballistic_fit_is_exact_on_a_parabola() {
        let samples: Vec<Sample> = (0..5)
            .map(|i| {
                let t = i as f64 * 0.005;
                (t, Vector3::new(t, -2.0 * t, 1.0 + t - 0.5 * G * t * t))
            })
            .collect();
        let f = fit_ballistic(&samples, 0.01, G).unwrap();
        assert!((f.velocity_at(0.0) - Vector3::new(1.0, -2.0, 1.0)).norm() < 1e-12);
        assert!(f.rss < 1e-20);
    }
}
