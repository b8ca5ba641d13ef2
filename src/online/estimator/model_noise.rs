//! How much the flights really depart from the model, learned from the filter's innovations
//! and carried from track to track (`ekf.learn_model_noise`): a scale on each part of the
//! process noise (the white acceleration's density, the spin random walk's) and one on the
//! bounce's scatter ([`NoiseScales`]).
//!
//! The configured densities are a guess at how far real flights stray from the model: too
//! small and the filter trusts a model that is wrong (detections gated, a track split); too
//! large and it throws away what the model knows (on flights the model describes well, a
//! prediction a few times worse than the data allow). The innovations say which: for a filter
//! whose noise is right, each y ~ N(0, S) with S = H P^- H' + R, and P^- depends on the scales.
//! The filter carries D = dP^-/ds for each scale s through its predictions and updates
//! ([`crate::online::ekf::NoiseSensitivity`]), so every update gives the derivative of the
//! innovation's log-likelihood with respect to each scale, g = -1/2 tr(S^-1 (I - y y' S^-1)
//! H D H'), and its Fisher information i = 1/2 tr(S^-1 H D H' S^-1 H D H')
//! ([`crate::online::ekf::NoiseScore`]) (Mehra, "On the identification of variances and adaptive
//! Kalman filtering", IEEE TAC 1970: the innovations' likelihood as a function of the noise).
//!
//! Which innovations (`ekf.model_noise_horizon`): with a horizon h (0.1 s by default) the score
//! is that of a prediction h ahead, held from the estimate after a fused detection and scored
//! against the first newest detection at least h later (`Estimator::learn_ahead`; D then counts
//! what the scales add over the prediction). A prediction a few milliseconds ahead hardly feels
//! the process noise, and learned from each detection's own innovation (h = 0: D carried along
//! the live track) the scales came out too small for real flights (docs/estimator.md).
//!
//! Each log-scale follows a recursive Newton (Fisher scoring) step, log s += s g / I, where I is
//! the information accumulated with a fading memory of `ekf.model_noise_memory` detections,
//! starting from [`PRIOR_INFORMATION`] (the configured value counts as that much evidence). A
//! step is at most [`MAX_STEP`] in log-scale and the scales stay within [`SCALE_BOUNDS`] of the
//! configured noise. A single high-rate detection says little of either scale (its innovation is
//! mostly measurement noise); thousands do, which is why the estimate is carried from track to
//! track.

use super::LearnedModelNoise;
use crate::online::ekf::{NOISE_SCALES, NoiseScales, NoiseScore};

/// The information [1/log-scale^2] the configured scales start with: a standard deviation of 0.5
/// in log-scale (a factor of 1.65).
pub const PRIOR_INFORMATION: f64 = 4.0;

/// The largest change of a log-scale in one step.
pub const MAX_STEP: f64 = 0.05;

/// The range of each scale, relative to the configured noise: (lowest, highest).
pub const SCALE_BOUNDS: (f64, f64) = (3e-2, 1e2);

/// The learned scales and the information behind them.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct ModelNoiseLearner {
    enabled: bool,
    /// The log of each scale, in the order of [`NoiseScales::NAMES`].
    log_scales: [f64; NOISE_SCALES],
    /// The information behind each [1/log-scale^2].
    information: [f64; NOISE_SCALES],
    /// 1 - 1 / memory: the fading of old information per detection.
    fading: f64,
}

impl ModelNoiseLearner {
    /// Nothing learned yet: the configured noise (scales 1).
    pub(crate) fn new(enabled: bool, memory: u32) -> Self {
        Self {
            enabled,
            log_scales: [0.0; NOISE_SCALES],
            information: [PRIOR_INFORMATION; NOISE_SCALES],
            fading: 1.0 - 1.0 / f64::from(memory.max(1)),
        }
    }

    /// The scales to run the filter with.
    pub(crate) fn scales(&self) -> NoiseScales {
        NoiseScales::from_array(self.log_scales.map(f64::exp))
    }

    /// The information behind each scale [1/log-scale^2].
    #[cfg(test)]
    pub(crate) fn information(&self) -> [f64; NOISE_SCALES] {
        self.information
    }

    /// The scales and the sigma of each one's log.
    pub(crate) fn learned(&self) -> LearnedModelNoise {
        LearnedModelNoise {
            scales: self.scales(),
            log_sigma: self
                .information
                .map(|i| 1.0 / i.max(f64::MIN_POSITIVE).sqrt()),
        }
    }

    /// Learns from the score of one update at the current scales: one detection's fading, then
    /// the score.
    pub(crate) fn learn(&mut self, score: &NoiseScore) {
        self.learn_faded(score, self.fading);
    }

    /// One detection's fading of the information, nothing learned (a detection whose score is
    /// not the one learned from: with a horizon, the prediction's further ahead are).
    pub(crate) fn fade(&mut self) {
        self.learn_faded(&NoiseScore::default(), self.fading);
    }

    /// Learns from the score of a prediction further ahead, at the current scales, with no
    /// fading of its own (its detection has faded the information already).
    pub(crate) fn learn_ahead(&mut self, score: &NoiseScore) {
        self.learn_faded(score, 1.0);
    }

    fn learn_faded(&mut self, score: &NoiseScore, fading: f64) {
        if !self.enabled {
            return;
        }
        let scales = self.scales();
        let (low, high) = (SCALE_BOUNDS.0.ln(), SCALE_BOUNDS.1.ln());
        for (j, scale) in scales.to_array().into_iter().enumerate() {
            // d/d(log s) = s d/ds.
            let gradient = scale * score.gradient[j];
            let information = scale * scale * score.information[j];
            if !(gradient.is_finite() && information.is_finite()) {
                continue;
            }
            self.information[j] = self.information[j] * fading + information;
            let step = (gradient / self.information[j]).clamp(-MAX_STEP, MAX_STEP);
            self.log_scales[j] = (self.log_scales[j] + step).clamp(low, high);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Scores that say "less noise" move the scale down, "more" up, by the Newton step; the
    /// scores' information accumulates; nothing moves when learning is off.
    #[test]
    fn the_scales_follow_the_score() {
        let mut learner = ModelNoiseLearner::new(true, 1000);
        let less = NoiseScore {
            gradient: [-0.1, 0.0, 0.1],
            information: [0.01, 0.01, 0.01],
        };
        learner.learn(&less);
        let s = learner.scales();
        assert!(
            s.acceleration < 1.0 && s.spin == 1.0 && s.bounce > 1.0,
            "{s:?}"
        );
        // The Newton step: the gradient over the information, the prior's faded by one
        // detection plus the score's.
        let first_step = -s.acceleration.ln();
        let information = PRIOR_INFORMATION * 0.999 + 0.01;
        assert!(
            (first_step - 0.1 / information).abs() < 1e-12,
            "{first_step}"
        );
        for _ in 0..100 {
            learner.learn(&less);
        }
        // The scores' information adds to the prior's, which fades.
        let faded = PRIOR_INFORMATION * 0.999f64.powi(101);
        assert!(
            learner.information()[0] > faded + 0.1,
            "{:?}",
            learner.information()
        );
        let mut off = ModelNoiseLearner::new(false, 1000);
        off.learn(&less);
        assert_eq!(off.scales(), NoiseScales::default());
        // Bounded, and a non-finite score changes nothing.
        for _ in 0..100_000 {
            learner.learn(&less);
        }
        assert!(learner.scales().acceleration >= SCALE_BOUNDS.0 * (1.0 - 1e-12));
        let before = learner;
        learner.learn(&NoiseScore {
            gradient: [f64::NAN, f64::INFINITY, f64::NAN],
            information: [0.0; NOISE_SCALES],
        });
        assert_eq!(learner, before);
    }
}
