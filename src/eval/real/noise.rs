//! The position noise of recorded flights, from the residuals of a local polynomial fit.
//!
//! Around every sample, a quadratic in time is fitted per axis to the [`WINDOW`] samples centred
//! on it (about 35 ms at 180 Hz, over which the flight's third derivative changes the position by
//! hundredths of a millimetre). The residual at the centre, divided by sqrt(1 - h) where h is the
//! fit's leverage of the centre sample, has the variance of the measurement noise. Windows that
//! contain the bounce (within [`BOUNCE_MARGIN`]) or a gap (span over [`MAX_WINDOW_SPAN`]) are
//! skipped. Reported per axis: RMS, a robust sigma (1.4826 median absolute deviation), the RMS
//! without outliers beyond 5 robust sigmas, and the outliers; and the same split along and across
//! the local direction of flight, which separates timing noise (it acts along the flight) from
//! position noise.

use nalgebra::{Matrix3, Vector3};

use crate::offline::ballistic::{Sample, detect_bounce};

/// Samples per local fit [-] (odd; the residual of the centre sample is used).
pub const WINDOW: usize = 7;
/// Windows spanning longer than this are skipped (a gap of missed frames) [s].
pub const MAX_WINDOW_SPAN: f64 = 0.045;
/// Windows reaching within this of a bounce are skipped [s].
pub const BOUNCE_MARGIN: f64 = 0.003;
/// Residuals beyond this many robust sigmas are counted as outliers [-].
pub const OUTLIER_SIGMAS: f64 = 5.0;

/// Noise statistics of one component.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct AxisNoise {
    /// Residuals [-].
    pub count: usize,
    /// RMS of all residuals [m].
    pub rms: f64,
    /// 1.4826 times the median absolute residual: the sigma of the Gaussian core [m].
    pub robust_sigma: f64,
    /// RMS of the residuals within [`OUTLIER_SIGMAS`] robust sigmas [m].
    pub inlier_rms: f64,
    /// Residuals beyond [`OUTLIER_SIGMAS`] robust sigmas [-].
    pub outliers: usize,
    /// Largest absolute residual [m].
    pub max: f64,
}

impl AxisNoise {
    fn of(values: &[f64]) -> Self {
        if values.is_empty() {
            return Self::default();
        }
        let mut abs: Vec<f64> = values.iter().map(|v| v.abs()).collect();
        abs.sort_by(f64::total_cmp);
        let robust_sigma = 1.4826 * abs[abs.len() / 2];
        let rms = |v: &[f64]| (v.iter().map(|x| x * x).sum::<f64>() / v.len().max(1) as f64).sqrt();
        let limit = OUTLIER_SIGMAS * robust_sigma;
        let inliers: Vec<f64> = abs.iter().copied().filter(|v| *v <= limit).collect();
        Self {
            count: values.len(),
            rms: rms(values),
            robust_sigma,
            inlier_rms: rms(&inliers),
            outliers: values.len() - inliers.len(),
            max: abs.last().copied().unwrap_or(0.0),
        }
    }
}

/// The noise of a set of flights.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct NoiseEstimate {
    /// Per axis of the flights' frame (x, y, z).
    pub axes: [AxisNoise; 3],
    /// Along the local direction of flight.
    pub along: AxisNoise,
    /// Across it (both perpendicular components, pooled).
    pub across: AxisNoise,
}

impl NoiseEstimate {
    /// The root of the mean inlier variance over the three axes [m]: an isotropic sigma with
    /// the data's total variance.
    pub fn isotropic_sigma(&self) -> f64 {
        (self.axes.iter().map(|a| a.inlier_rms.powi(2)).sum::<f64>() / 3.0).sqrt()
    }

    /// The `position_sigma` to configure for these detections [m]: the largest inlier RMS of
    /// the three axes. The estimator's R is isotropic (sigma^2 I), so it must cover the noisiest
    /// axis or the gate rejects good detections along it; outliers are left to the gate.
    pub fn recommended_sigma(&self) -> f64 {
        self.axes.iter().map(|a| a.inlier_rms).fold(0.0, f64::max)
    }
}

/// Time scale of the local fit's polynomial [s]: keeps its normal matrix well conditioned.
const TIME_SCALE: f64 = 0.01;

/// Estimates the noise of recorded flights, each given by its samples (see the module doc);
/// `gravity` [m/s^2] is used to find their bounces.
pub fn estimate_noise<'a>(
    flights: impl IntoIterator<Item = &'a [Sample]>,
    gravity: f64,
) -> NoiseEstimate {
    let mut axes: [Vec<f64>; 3] = Default::default();
    let mut along = Vec::new();
    let mut across = Vec::new();
    for samples in flights {
        let bounce = detect_bounce(samples, gravity).map(|b| b.time);
        for window in samples.windows(WINDOW) {
            let (Some(first), Some(last)) = (window.first(), window.last()) else {
                continue;
            };
            if last.0 - first.0 > MAX_WINDOW_SPAN
                || bounce.is_some_and(|t| t > first.0 - BOUNCE_MARGIN && t < last.0 + BOUNCE_MARGIN)
            {
                continue;
            }
            let Some((residual, velocity)) = centre_residual(window) else {
                continue;
            };
            for (axis, values) in axes.iter_mut().enumerate() {
                values.push(residual[axis]);
            }
            let direction = velocity.try_normalize(1e-9).unwrap_or_else(Vector3::x);
            let a = residual.dot(&direction);
            along.push(a);
            let perpendicular = residual - direction * a;
            // Two components across: pool them as two values of the same variance.
            let norm = perpendicular.norm() / std::f64::consts::SQRT_2;
            across.extend([norm, -norm]);
        }
    }
    NoiseEstimate {
        axes: [
            AxisNoise::of(&axes[0]),
            AxisNoise::of(&axes[1]),
            AxisNoise::of(&axes[2]),
        ],
        along: AxisNoise::of(&along),
        across: AxisNoise::of(&across),
    }
}

/// The standardised residual of the centre sample of a quadratic fit, and the fit's velocity
/// there.
fn centre_residual(window: &[Sample]) -> Option<(Vector3<f64>, Vector3<f64>)> {
    let centre = window.get(window.len() / 2)?;
    let basis = |t: f64| {
        let s = (t - centre.0) / TIME_SCALE;
        Vector3::new(1.0, s, s * s)
    };
    let mut normal = Matrix3::zeros();
    for (t, _) in window {
        let b = basis(*t);
        normal += b * b.transpose();
    }
    let inverse = normal.try_inverse()?;
    let b0 = basis(centre.0);
    let leverage = (b0.transpose() * inverse * b0)[(0, 0)];
    if leverage >= 1.0 {
        return None;
    }
    let mut residual = Vector3::zeros();
    let mut velocity = Vector3::zeros();
    for axis in 0..3 {
        let rhs: Vector3<f64> = window.iter().map(|(t, p)| basis(*t) * p[axis]).sum();
        let coefficients = inverse * rhs;
        residual[axis] = (centre.1[axis] - coefficients.dot(&b0)) / (1.0 - leverage).sqrt();
        velocity[axis] = coefficients[1] / TIME_SCALE;
    }
    Some((residual, velocity))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn recovers_the_noise_of_a_smooth_flight() {
        // A parabola with uniform noise of sigma 1 mm on y only (a fixed LCG).
        let mut state: u64 = 12345;
        let mut uniform = move || {
            state = state
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1_442_695_040_888_963_407);
            (state >> 11) as f64 / (1u64 << 53) as f64 - 0.5
        };
        let sigma = 0.001;
        let samples: Vec<Sample> = (0..2000)
            .map(|i| {
                let t = i as f64 * 0.0056;
                let noise = uniform() * sigma * 12f64.sqrt();
                (t, Vector3::new(1.0 - 4.0 * t, noise, 0.3 + t - 4.9 * t * t))
            })
            .collect();
        let n = estimate_noise([samples.as_slice()], 9.81);
        assert!(n.axes[0].rms < 1e-9 && n.axes[2].rms < 1e-9, "{n:?}");
        assert!((n.axes[1].rms / sigma - 1.0).abs() < 0.05, "{n:?}");
        assert_eq!(n.axes[1].outliers, 0);
    }
}
