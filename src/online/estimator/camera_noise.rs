//! The measurement noise each camera source really has, learned from the filter's prior
//! innovations (docs/estimator.md, "The adaptation"): R = s R_0 + tau v v' and s_w R_w, from
//! E[y y'] = H P^- H' + R across the flight (s), along it (tau) and of the spin (s_w), each
//! sample limited to [`SAMPLE_LIMIT`] times the estimate, averaged over [`MEMORY`] detections
//! from the configured values weighted as [`PRIOR_WEIGHT`]. A detection whose prediction is less
//! certain than its noise teaches nothing.

use nalgebra::Matrix3;

use super::fusion::Innovation;
use crate::config::Config;
use crate::online::measurement::Measurement;

/// How many detections of a source the learned noise averages over (older ones fade): some
/// seconds of either camera, long enough that a sample's own noise averages out, short enough
/// to follow a camera recalibrated during a session.
pub const MEMORY: f64 = 2000.0;
/// The configured noise counts as this many detections when the learning starts.
pub const PRIOR_WEIGHT: f64 = 20.0;
/// A sample is cut to this many times the current estimate of its variance.
pub const SAMPLE_LIMIT: f64 = 9.0;
/// Below this speed [m/s] the flight has no direction: the whole position innovation counts
/// as noise across it.
const MIN_SPEED: f64 = 0.5;

/// The learned noise of one source.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SourceNoiseEstimate {
    /// s: the scale on the position covariance [-].
    pub position_scale: f64,
    /// tau: the variance of the stamps' timing [s^2].
    pub timing_variance: f64,
    /// s_w: the scale on the spin covariance [-].
    pub spin_scale: f64,
    /// Detections (plus the prior's weight) behind the estimate, at most the memory [-].
    pub weight: f64,
    /// Spin measurements behind `spin_scale` (plus the prior's weight) [-].
    pub spin_weight: f64,
}

impl SourceNoiseEstimate {
    fn prior(stamp_sigma: f64) -> Self {
        Self {
            position_scale: 1.0,
            timing_variance: stamp_sigma * stamp_sigma,
            spin_scale: 1.0,
            weight: PRIOR_WEIGHT,
            spin_weight: PRIOR_WEIGHT,
        }
    }
}

/// What one detection shows of its camera's noise: its prior innovation
/// ([`Innovation`]) and the camera's own covariances before the learned scales, R_0 of the
/// position [m^2] and of the spin [(rad/s)^2] when measured.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct NoiseSample {
    pub(crate) innovation: Innovation,
    pub(crate) r0: Matrix3<f64>,
    pub(crate) spin_r0: Option<Matrix3<f64>>,
}

/// The learned noise of every source, in the order of
/// [`SourcesParams::all`](crate::config::SourcesParams::all) (indexed by
/// [`SourceIndex::of`](crate::config::SourceIndex::of)).
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct NoiseLearner {
    sources: Vec<SourceNoiseEstimate>,
}

impl NoiseLearner {
    pub(crate) fn new(config: &Config) -> Self {
        Self {
            sources: config
                .sources
                .all()
                .into_iter()
                .map(|(_, p)| SourceNoiseEstimate::prior(p.stamp_sigma))
                .collect(),
        }
    }

    /// The current estimate for the source at `index`.
    pub(crate) fn of(&self, index: usize) -> SourceNoiseEstimate {
        self.sources[index]
    }

    /// Every source's estimate, in index order.
    pub(crate) fn all(&self) -> &[SourceNoiseEstimate] {
        &self.sources
    }

    /// Learns from one detection of the source at `index`.
    pub(crate) fn learn(&mut self, index: usize, observed: &NoiseSample) {
        let memory = MEMORY;
        let Some(e) = self.sources.get_mut(index) else {
            return;
        };
        let (i, r0) = (&observed.innovation, &observed.r0);
        let speed = i.velocity.norm();
        let (across, along) = if speed >= MIN_SPEED {
            let u = i.velocity / speed;
            (Matrix3::identity() - u * u.transpose(), Some(u))
        } else {
            (Matrix3::identity(), None)
        };
        let r0_across = (across * r0 * across).trace();
        let hph_across = (across * i.hph * across).trace();
        // Only where the prediction is sharper than the noise: a sample is the difference of
        // the innovation and the prediction's variance, and where the prediction dominates
        // (a new track, after a bounce) that difference is mostly the prediction's error.
        if r0_across <= 0.0 || hph_across > e.position_scale * r0_across {
            return;
        }
        e.weight = (e.weight + 1.0).min(memory);
        let y_c = across * i.y;
        let sample = ((y_c.norm_squared() - hph_across) / r0_across).max(0.0);
        let scale = e.position_scale;
        e.position_scale += (sample.min(SAMPLE_LIMIT * scale) - scale) / e.weight;
        e.position_scale = e.position_scale.max(1e-3);
        if let Some(u) = along {
            let y_a = u.dot(&i.y);
            let position_along = e.position_scale * u.dot(&(r0 * u));
            let timing_along = e.timing_variance * speed * speed;
            let excess = y_a * y_a - u.dot(&(i.hph * u)) - position_along;
            let limit = SAMPLE_LIMIT * (position_along + timing_along);
            let sample = excess.min(limit) / (speed * speed);
            e.timing_variance += (sample - e.timing_variance) / e.weight;
            e.timing_variance = e.timing_variance.max(0.0);
        }
        if let (Some((y_w, hph_w)), Some(r0_w)) = (i.spin, observed.spin_r0) {
            let r0 = r0_w.trace();
            if r0 > 0.0 && hph_w.trace() <= e.spin_scale * r0 {
                e.spin_weight = (e.spin_weight + 1.0).min(memory);
                let sample = ((y_w.norm_squared() - hph_w.trace()) / r0).max(0.0);
                let scale = e.spin_scale;
                e.spin_scale += (sample.min(SAMPLE_LIMIT * scale) - scale) / e.spin_weight;
                e.spin_scale = e.spin_scale.max(1e-3);
            }
        }
    }
}

impl Measurement {
    /// The measurement with its noise as the estimator has learned its source's
    /// ([`SourceNoiseEstimate`]): its position and spin covariances scaled, its timing noise set.
    pub(crate) fn with_learned_noise(mut self, noise: &SourceNoiseEstimate) -> Self {
        match &mut self {
            Self::Position { r, timing, .. } => {
                *r *= noise.position_scale;
                *timing = noise.timing_variance;
            }
            Self::PositionSpin { r, timing, .. } => {
                let mut position = r.fixed_view_mut::<3, 3>(0, 0);
                position *= noise.position_scale;
                let mut spin = r.fixed_view_mut::<3, 3>(3, 3);
                spin *= noise.spin_scale;
                *timing = noise.timing_variance;
            }
        }
        self
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::rng::Rng;
    use nalgebra::Vector3;

    /// Innovations of a source whose noise is twice (in sigma) the configured, with stamps off
    /// by 1 ms (sigma) at 8 m/s, over a prior of a fifth of the noise: the learner finds the
    /// scale (4) and the timing variance (1e-6 s^2) within a few percent.
    #[test]
    fn finds_the_scale_and_the_timing_noise() {
        let config = Config::default();
        let mut learner = NoiseLearner::new(&config);
        let mut rng = Rng::new(7);
        let r0 = Matrix3::identity() * 4e-6;
        let hph = Matrix3::identity() * 4e-6 / 5.0;
        let velocity = Vector3::new(-8.0, 0.5, 1.0);
        let u = velocity.normalize();
        for _ in 0..20_000 {
            let noise = rng.normal3() * 4e-3 + u * (velocity.norm() * 1e-3 * rng.normal());
            let prior = rng.normal3() * (4e-6f64 / 5.0).sqrt();
            let sample = NoiseSample {
                innovation: Innovation {
                    y: noise + prior,
                    hph,
                    velocity,
                    spin: None,
                },
                r0,
                spin_r0: None,
            };
            learner.learn(1, &sample);
        }
        let e = learner.of(1);
        assert!((e.position_scale - 4.0).abs() < 0.1, "{e:?}");
        assert!((e.timing_variance - 1.0e-6).abs() < 0.05e-6, "{e:?}");
        // The other sources learned nothing.
        assert_eq!(learner.of(2).position_scale, 1.0);
    }

    /// A detection whose prediction is less certain than its noise (a new track, a bounce)
    /// teaches nothing: its innovation is mostly the prediction's error.
    #[test]
    fn an_uncertain_prediction_teaches_nothing() {
        let config = Config::default();
        let mut learner = NoiseLearner::new(&config);
        let sample = NoiseSample {
            innovation: Innovation {
                y: Vector3::new(0.01, 0.01, 0.01),
                hph: Matrix3::identity() * 1e-4,
                velocity: Vector3::new(-5.0, 0.0, 0.0),
                spin: None,
            },
            r0: Matrix3::identity() * 4e-6,
            spin_r0: None,
        };
        learner.learn(1, &sample);
        assert_eq!(learner, NoiseLearner::new(&config));
    }
}
