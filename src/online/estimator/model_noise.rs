//! How much the flights really depart from the model, learned from the filter's innovations
//! and carried from track to track (`ekf.learn_model_noise`): a scale on each part of the
//! process noise (the white acceleration's density, the spin random walk's) and one on the
//! bounce's scatter ([`NoiseScales`]).
//!
//! The white acceleration's scale is learned apart for the two phases of a track
//! ([`LEARNED_SCALES`]): before its spin has been measured and after (a spin camera's detection
//! fused, `Snapshot::spin_measured`). The white acceleration stands for what the model misses,
//! and what it misses most is the Magnus force of a spin it has only inferred from the
//! flight's curvature; once the spin camera measures it, the model misses far less. One scale
//! for both phases is held up by the first (with both cameras it settled at 0.008x, and the
//! estimates after the bounce, all seen by the spin camera, were pessimistic: state NEES 0.54).
//! A prediction is flown with the scale of the phase it starts in (a prediction never fuses a
//! detection, so it stays in it), and learns that scale alone. Carried along the live track (no
//! horizon), the sensitivity to the acceleration's scale restarts at zero when the track's
//! spin is first measured: the phase's scale has added nothing to the covariance before.
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
//! against the first newest detection at least h later (`Estimator::learn_ahead`; D is carried
//! along the live track, held with the estimate and carried through the prediction, so it counts
//! what the scales added to the held estimate's covariance and what they add over the
//! prediction). A prediction a few milliseconds ahead hardly feels the process noise, and
//! learned from each detection's own innovation (h = 0) the scales came out too small for real
//! flights (docs/estimator.md).
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
//! When a scale stepped on its log moves, the information behind it is re-evaluated at the new
//! scale ([`information_kept`]): gathered while the scale made much of the innovations'
//! covariance, it would otherwise outweigh for hundreds of tracks what they say once it makes
//! little of it.
//!
//! Either way a step raises a scale by at most [`MAX_STEP`] in log-scale (an innovation far out
//! says "more noise" without bound) and lowers it by at most [`MAX_FALL`] (a score says "less"
//! only so far: s g >= -1/2 tr(S^-1 s H D H') >= -m/2 for an innovation of dimension m), and the
//! scales stay within [`SCALE_BOUNDS`] of the configured noise. A single high-rate detection says
//! little of any scale (its innovation is mostly measurement noise); thousands do, which is why
//! the estimate is carried from track to track.

use super::LearnedModelNoise;
use crate::config::EkfParams;
use crate::online::ekf::{NOISE_SCALES, NoiseScales, NoiseScore};

/// How many scales are learned: the filter's [`NoiseScales`], and the white acceleration's
/// once the spin has been measured.
pub const LEARNED_SCALES: usize = NOISE_SCALES + 1;

/// The names of the learned scales, in the order of [`LearnedModelNoise::log_sigma`]: the
/// filter's ([`NoiseScales::NAMES`], the acceleration's before the spin is measured), then the
/// acceleration's after.
pub const LEARNED_SCALE_NAMES: [&str; LEARNED_SCALES] = [
    NoiseScales::NAMES[0],
    NoiseScales::NAMES[1],
    NoiseScales::NAMES[2],
    "spin-measured acceleration",
];

/// Where the white acceleration's scale once the spin is measured is kept among the learned
/// scales (after the filter's own, [`LEARNED_SCALE_NAMES`]).
const SPIN_MEASURED_ACCELERATION: usize = NOISE_SCALES;

/// Where each of the filter's scales is learned, in the order of [`NoiseScales::NAMES`], for a
/// prediction that starts before the spin is measured (`false`) and after (`true`).
const fn learned_index(spin_measured: bool) -> [usize; NOISE_SCALES] {
    if spin_measured {
        [SPIN_MEASURED_ACCELERATION, 1, 2]
    } else {
        [0, 1, 2]
    }
}

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
pub const STEPS_ON_THE_SCALE: [bool; LEARNED_SCALES] = [false, false, true, false];

/// The learned scales and the information behind them.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct ModelNoiseLearner {
    enabled: bool,
    /// The log of each scale, in the order of [`LEARNED_SCALE_NAMES`].
    log_scales: [f64; LEARNED_SCALES],
    /// The information behind each, on the parameter it steps on (log s or s).
    information: [f64; LEARNED_SCALES],
    /// 1 - 1 / memory: the fading of old information per detection.
    fading: f64,
    /// The configured white acceleration's density once the spin is measured over the one
    /// before: the scales are the filter's, on `ekf.acceleration_noise_density`, and the
    /// phase's starts at this ratio.
    spin_measured_ratio: f64,
}

impl ModelNoiseLearner {
    /// Nothing learned yet: the configured noise of `ekf` (`learn_model_noise`,
    /// `model_noise_memory`, the acceleration's densities).
    pub(crate) fn new(ekf: &EkfParams) -> Self {
        let spin_measured_ratio =
            ekf.spin_measured_acceleration_noise_density / ekf.acceleration_noise_density;
        let spin_measured_ratio = if spin_measured_ratio.is_finite() && spin_measured_ratio > 0.0 {
            spin_measured_ratio
        } else {
            1.0
        };
        let mut log_scales = [0.0; LEARNED_SCALES];
        log_scales[SPIN_MEASURED_ACCELERATION] = spin_measured_ratio.ln();
        Self {
            enabled: ekf.learn_model_noise,
            log_scales,
            information: [PRIOR_INFORMATION; LEARNED_SCALES],
            fading: 1.0 - 1.0 / f64::from(ekf.model_noise_memory.max(1)),
            spin_measured_ratio,
        }
    }

    /// The scales to run the filter with, for a prediction that starts before the track's spin
    /// is measured or after.
    pub(crate) fn scales(&self, spin_measured: bool) -> NoiseScales {
        NoiseScales::from_array(learned_index(spin_measured).map(|j| self.log_scales[j].exp()))
    }

    /// The information behind each scale, on the parameter it steps on (log s or s).
    #[cfg(test)]
    pub(crate) fn information(&self) -> [f64; LEARNED_SCALES] {
        self.information
    }

    /// The scales and the sigma of each one's log.
    pub(crate) fn learned(&self) -> LearnedModelNoise {
        LearnedModelNoise {
            scales: self.scales(false),
            spin_measured_acceleration: self.scales(true).acceleration / self.spin_measured_ratio,
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

    /// Learns from the score of one update at the current scales, its prediction started before
    /// the track's spin was measured or after: one detection's fading, then the score.
    pub(crate) fn learn(&mut self, score: &NoiseScore, spin_measured: bool) {
        self.fade();
        self.learn_ahead(score, spin_measured);
    }

    /// One detection's fading of the information, nothing learned (a detection whose score is
    /// not the one learned from: with a horizon, the prediction's further ahead are).
    pub(crate) fn fade(&mut self) {
        // A score of zero moves no scale: only the information fades.
        if self.enabled {
            self.information = self.information.map(|i| i * self.fading);
        }
    }

    /// Learns from the score of a prediction further ahead, at the current scales, started before
    /// the track's spin was measured or after, with no fading of its own (its detection has
    /// faded the information already).
    pub(crate) fn learn_ahead(&mut self, score: &NoiseScore, spin_measured: bool) {
        if !self.enabled {
            return;
        }
        let scales = self.scales(spin_measured);
        let (low, high) = (SCALE_BOUNDS.0.ln(), SCALE_BOUNDS.1.ln());
        let learned = learned_index(spin_measured);
        for (i, scale) in scales.to_array().into_iter().enumerate() {
            let j = learned[i];
            let (gradient, information) = if STEPS_ON_THE_SCALE[j] {
                (score.gradient[i], score.information[i])
            } else {
                // d/d(log s) = s d/ds.
                (
                    scale * score.gradient[i],
                    scale * scale * score.information[i],
                )
            };
            if !(gradient.is_finite() && information.is_finite()) {
                continue;
            }
            self.information[j] += information;
            let newton = gradient / self.information[j];
            let step = if !STEPS_ON_THE_SCALE[j] {
                newton
            } else if scale + newton > 0.0 {
                (1.0 + newton / scale).ln()
            } else {
                // A step to zero or below: as far down as a step goes.
                -MAX_FALL
            };
            let before = self.log_scales[j];
            self.log_scales[j] =
                (self.log_scales[j] + step.clamp(-MAX_FALL, MAX_STEP)).clamp(low, high);
            if !STEPS_ON_THE_SCALE[j] {
                let moved = (self.log_scales[j] - before).exp();
                self.information[j] *= information_kept(scale * score.share[i], moved);
            }
        }
    }
}

/// The factor on the information behind a scale stepped on its log when the scale moves by a
/// factor `k`, for innovations of which the scale makes a fraction `f` of the covariance: the
/// information at the new scale, of an innovation whose covariance is S = s A + B with s A = f S
/// (the newest score's fraction standing for the older ones'). The information 1/2 tr((S^-1
/// dS/d log s)^2) is m/2 f^2 and the fraction at k s is f' = f k / (1 + f (k - 1)): a factor
/// (f' / f)^2.
///
/// Without it, the information a scale gathered while it made much of S outweighs, for hundreds
/// of tracks, the little the innovations say once it makes little of S: a scale whose flights
/// need none of it fell from 1 to 0.008 over 200 shots and was still falling, and with both
/// cameras the estimates after the bounce were pessimistic (state NEES 0.53). The bounce's scale,
/// stepped on s, keeps its information as gathered: there a smaller scale that makes most of S
/// would have more of it (m/2 (f / s)^2), which slowed its fall (0.24x after 30 tracks of the
/// unit test below instead of under 0.01x).
fn information_kept(f: f64, k: f64) -> f64 {
    if !(f > 0.0 && f.is_finite() && k.is_finite()) {
        return 1.0;
    }
    let f = f.min(1.0);
    let ratio = k / (1.0 + f * (k - 1.0));
    ratio * ratio
}

#[cfg(test)]
mod tests {
    use super::*;

    fn learner_with_memory(memory: u32) -> ModelNoiseLearner {
        ModelNoiseLearner::new(&EkfParams {
            learn_model_noise: true,
            model_noise_memory: memory,
            ..EkfParams::default()
        })
    }

    /// Scores that say "less noise" move the scale down, "more" up, by the Newton step; the
    /// scores' information accumulates; nothing moves when learning is off.
    #[test]
    fn the_scales_follow_the_score() {
        let mut learner = learner_with_memory(1000);
        let less = NoiseScore {
            gradient: [-0.1, 0.0, 0.1],
            information: [0.01, 0.01, 0.01],
            share: [0.0; NOISE_SCALES],
        };
        learner.learn(&less, false);
        let s = learner.scales(false);
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
            let mut far = learner_with_memory(1000);
            far.learn(
                &NoiseScore {
                    gradient: [g; NOISE_SCALES],
                    information: [0.01; NOISE_SCALES],
                    share: [0.0; NOISE_SCALES],
                },
                false,
            );
            let bound = if g < 0.0 { -MAX_FALL } else { MAX_STEP };
            for scale in far.scales(false).to_array() {
                assert!((scale.ln() - bound).abs() < 1e-12, "{scale} {g}");
            }
        }
        for _ in 0..100 {
            learner.learn(&less, false);
        }
        // The scores' information adds to the prior's, which fades.
        let faded = PRIOR_INFORMATION * 0.999f64.powi(101);
        assert!(
            learner.information()[0] > faded + 0.1,
            "{:?}",
            learner.information()
        );
        let mut off = ModelNoiseLearner::new(&EkfParams {
            learn_model_noise: false,
            ..EkfParams::default()
        });
        off.learn(&less, false);
        assert_eq!(off.scales(false), NoiseScales::default());
        // Bounded, and a non-finite score changes nothing (but the detection's fading).
        for _ in 0..100_000 {
            learner.learn(&less, false);
        }
        assert!(learner.scales(false).acceleration >= SCALE_BOUNDS.0 * (1.0 - 1e-12));
        let before = learner;
        learner.learn_ahead(
            &NoiseScore {
                gradient: [f64::NAN, f64::INFINITY, f64::NAN],
                information: [0.0; NOISE_SCALES],
                share: [0.0; NOISE_SCALES],
            },
            false,
        );
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
                b / big_s,
            )
        };
        let [a, w, k] = scales.to_array().map(score);
        NoiseScore {
            gradient: [a.0, w.0, k.0],
            information: [a.1, w.1, k.1],
            share: [a.2, w.2, k.2],
        }
    }

    /// A scale taught once a track by flights that follow the model falls most of the way
    /// within 30 tracks when it steps on the scale (the bounce's); stepped on its log (the
    /// acceleration's, given the same scores) it is still above a tenth, and goes on falling.
    #[test]
    fn the_bounce_scale_falls_within_tens_of_tracks() {
        let mut learner = learner_with_memory(20_000);
        for _ in 0..30 {
            let score = no_scatter_score(learner.scales(false));
            learner.learn_ahead(&score, false);
        }
        let s = learner.scales(false);
        assert!(s.bounce < 0.01, "{s:?}");
        assert!(s.acceleration > 0.1, "{s:?}");
        // Stepped on its log, the scale's information is re-evaluated as it falls
        // (`information_kept`): after 1000 tracks it is at 0.010x, where with the information kept
        // as gathered it would be at 0.043x.
        for _ in 30..1000 {
            let score = no_scatter_score(learner.scales(false));
            learner.learn_ahead(&score, false);
        }
        let s = learner.scales(false);
        assert!(s.acceleration < 0.02, "{s:?}");
    }

    /// The information kept when a scale moves is the information of the same innovation at
    /// the new scale, for S = s a + b: 1/2 (s a / S)^2 on log s.
    #[test]
    fn the_information_kept_is_the_information_at_the_new_scale() {
        let (a, b) = (3.0, 2.0);
        let information = |s: f64| 0.5 * (s * a / (s * a + b)).powi(2);
        for (s, k) in [(1.0, 0.5), (0.01, 0.1), (5.0, 2.0), (0.3, 1.0)] {
            let f = s * a / (s * a + b);
            let kept = information(s) * information_kept(f, k);
            assert!((kept - information(k * s)).abs() < 1e-12 * information(s).max(1e-300));
        }
        assert_eq!(information_kept(0.0, 0.5), 1.0);
        assert_eq!(information_kept(f64::NAN, 0.5), 1.0);
    }

    /// The white acceleration's scale is learned apart before and after the spin is measured:
    /// a score of one phase moves its own scale and leaves the other's; the spin walk's and the
    /// bounce's scales are shared. Every scale's information fades with each detection.
    #[test]
    fn the_acceleration_is_learned_per_phase() {
        let mut learner = learner_with_memory(1000);
        let less = NoiseScore {
            gradient: [-0.1, -0.1, 0.0],
            information: [0.01, 0.01, 0.01],
            share: [0.0; NOISE_SCALES],
        };
        learner.learn(&less, true);
        let (before, after) = (learner.scales(false), learner.scales(true));
        assert_eq!(before.acceleration, 1.0);
        assert!(after.acceleration < 1.0, "{after:?}");
        assert!(before.spin < 1.0 && before.spin == after.spin, "{before:?}");
        assert_eq!(before.bounce, after.bounce);
        let learned = learner.learned();
        assert_eq!(learned.scales, before);
        assert_eq!(learned.spin_measured_acceleration, after.acceleration);
        let information = learner.information();
        assert_eq!(information[0], PRIOR_INFORMATION * 0.999);
        assert!(
            information[SPIN_MEASURED_ACCELERATION] > information[0],
            "{information:?}"
        );
        learner.learn(&less, false);
        assert!(learner.scales(false).acceleration < 1.0);
        assert_eq!(learner.scales(true).acceleration, after.acceleration);
    }
}
