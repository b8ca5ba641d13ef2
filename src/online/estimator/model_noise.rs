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
//! Each scale follows a recursive Newton (Fisher scoring) step, s <- s + g / I, where I is the
//! information accumulated with a fading memory of `ekf.model_noise_memory` detections, starting
//! from [`PRIOR_INFORMATION`] (the configured value counts as that much evidence). Which
//! parameter the step is taken on is [`STEPS_ON_THE_SCALE`]:
//! - the white acceleration's and the spin walk's scales step on log s (log s += s g / I, with
//!   I on log s): they learn from a prediction every 0.1 s of track, with the heavy tail of the
//!   flights whose spin is misread, and in log-scale a step shrinks as the scale does, so the
//!   rare large scores that say "more" (bounded by [`MAX_STEP`]) hold their own against the many
//!   small ones that say "less". Stepped on s instead, the 150 fps camera's acceleration scale
//!   fell to the floor (the steps down as large as the bounded steps up) and its velocity's NEES
//!   rose to 6-7.
//! - the bounce's scale steps on s itself (the natural parameter of the variance it multiplies):
//!   it learns from one prediction a track, the one across the bounce, and on flights that
//!   follow the bounce model (the simulator's) a step on log s, which shrinks with the scale,
//!   took hundreds of tracks to fall (0.02x after 200; 0.0x after 600), while the scatter it left
//!   made the interception after the bounce 1.4-1.5x the batch fit's with both cameras. On s a
//!   step goes most of the way at once.
//!
//! Either way a step raises a scale by at most [`MAX_STEP`] in log-scale (an innovation far out
//! says "more noise" without bound) and lowers it by at most [`MAX_FALL`] (a score says "less"
//! only so far: s g >= -1/2 tr(S^-1 s H D H') >= -m/2 for an innovation of dimension m), and the
//! scales stay within [`SCALE_BOUNDS`] of the configured noise. A single high-rate detection says
//! little of any scale (its innovation is mostly measurement noise); thousands do, which is why
//! the estimate is carried from track to track.

use super::LearnedModelNoise;
use crate::online::ekf::{NOISE_SCALES, NoiseScales, NoiseScore};

/// The information the configured scales (1) start with, on the parameter each steps on (log s
/// or s: the same at s = 1): a standard deviation of 0.5 (in log-scale a factor of 1.65).
pub const PRIOR_INFORMATION: f64 = 4.0;

/// The largest rise of a log-scale in one step.
pub const MAX_STEP: f64 = 0.05;

/// The largest fall of a log-scale in one step (a factor of 0.61).
pub const MAX_FALL: f64 = 0.5;

/// The range of each scale, relative to the configured noise: (lowest, highest). On flights that
/// follow the model (the simulator's) the scales fall towards zero; a floor of 0.03 (until
/// 2026-12-03) left the filter's covariance pessimistic there.
pub const SCALE_BOUNDS: (f64, f64) = (1e-4, 1e2);

/// Whether each scale (in the order of [`NoiseScales::NAMES`]) steps on the scale itself rather
/// than on its log: the bounce's (see the module doc).
pub const STEPS_ON_THE_SCALE: [bool; NOISE_SCALES] = [false, false, true];

/// The learned scales and the information behind them.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct ModelNoiseLearner {
    enabled: bool,
    /// The log of each scale, in the order of [`NoiseScales::NAMES`].
    log_scales: [f64; NOISE_SCALES],
    /// The information behind each, on the parameter it steps on (log s or s).
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

    /// The information behind each scale, on the parameter it steps on (log s or s).
    #[cfg(test)]
    pub(crate) fn information(&self) -> [f64; NOISE_SCALES] {
        self.information
    }

    /// The scales and the sigma of each one's log.
    pub(crate) fn learned(&self) -> LearnedModelNoise {
        LearnedModelNoise {
            scales: self.scales(),
            log_sigma: std::array::from_fn(|j| {
                let sigma = 1.0 / self.information[j].max(f64::MIN_POSITIVE).sqrt();
                // sigma(log s) = sigma(s) / s.
                if STEPS_ON_THE_SCALE[j] {
                    sigma / self.log_scales[j].exp()
                } else {
                    sigma
                }
            }),
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
        // A score of zero moves no scale: only the information fades.
        if self.enabled {
            self.information = self.information.map(|i| i * self.fading);
        }
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
            let (gradient, information) = if STEPS_ON_THE_SCALE[j] {
                (score.gradient[j], score.information[j])
            } else {
                // d/d(log s) = s d/ds.
                (
                    scale * score.gradient[j],
                    scale * scale * score.information[j],
                )
            };
            if !(gradient.is_finite() && information.is_finite()) {
                continue;
            }
            self.information[j] = self.information[j] * fading + information;
            let newton = gradient / self.information[j];
            let step = if !STEPS_ON_THE_SCALE[j] {
                newton
            } else if scale + newton > 0.0 {
                (1.0 + newton / scale).ln()
            } else {
                // A step to zero or below: as far down as a step goes.
                -MAX_FALL
            };
            self.log_scales[j] =
                (self.log_scales[j] + step.clamp(-MAX_FALL, MAX_STEP)).clamp(low, high);
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
        // The Newton step, the gradient over the information (the prior's faded by one detection
        // plus the score's): on log s for the acceleration, on s for the bounce.
        let information = PRIOR_INFORMATION * 0.999 + 0.01;
        let on_the_log = -s.acceleration.ln();
        assert!(
            (on_the_log - 0.1 / information).abs() < 1e-12,
            "{on_the_log}"
        );
        let on_the_scale = s.bounce - 1.0;
        assert!(
            (on_the_scale - 0.1 / information).abs() < 1e-12,
            "{on_the_scale}"
        );
        // A step is bounded: down by MAX_FALL (a step on s to zero or below too), up by MAX_STEP.
        for g in [-100.0, 100.0] {
            let mut far = ModelNoiseLearner::new(true, 1000);
            far.learn(&NoiseScore {
                gradient: [g; NOISE_SCALES],
                information: [0.01; NOISE_SCALES],
            });
            let bound = if g < 0.0 { -MAX_FALL } else { MAX_STEP };
            for scale in far.scales().to_array() {
                assert!((scale.ln() - bound).abs() < 1e-12, "{scale} {g}");
            }
        }
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

    /// The score of a scalar innovation y ~ N(0, r) (flights with no scatter at all) where the
    /// filter predicts S = s b + r: g = 1/2 b (y^2 - S) / S^2 at y^2 = r, i = 1/2 b^2 / S^2.
    fn no_scatter_score(scales: NoiseScales) -> NoiseScore {
        let (b, r) = (10.0, 1.0);
        let score = |s: f64| {
            let big_s = s * b + r;
            (
                0.5 * b * (r - big_s) / (big_s * big_s),
                0.5 * b * b / (big_s * big_s),
            )
        };
        let [a, w, k] = scales.to_array().map(score);
        NoiseScore {
            gradient: [a.0, w.0, k.0],
            information: [a.1, w.1, k.1],
        }
    }

    /// A scale taught once a track by flights that follow the model falls most of the way
    /// within 30 tracks when it steps on the scale (the bounce's); stepped on its log (the
    /// acceleration's, given the same scores) it is still above a tenth.
    #[test]
    fn the_bounce_scale_falls_within_tens_of_tracks() {
        let mut learner = ModelNoiseLearner::new(true, 20_000);
        for _ in 0..30 {
            let score = no_scatter_score(learner.scales());
            learner.learn_ahead(&score);
        }
        let s = learner.scales();
        assert!(s.bounce < 0.01, "{s:?}");
        assert!(s.acceleration > 0.1, "{s:?}");
    }
}
