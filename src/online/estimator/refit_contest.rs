//! Whether the live track's refits ([`super::refitting`]) predict the flight better than the
//! filter whose estimates they would replace, learned from the detections themselves
//! (`ekf.refit_when_better`).
//!
//! A refit relinearises the track along the flight its detections smooth to. On flights that
//! follow the model (the simulator's) its estimates predict the flight ahead better than the
//! filter's, which learns a fast spin from curvature linearised at its own, too small, estimate;
//! on the real launcher flights, whose shape departs from the model's, they predict it worse
//! (docs/estimator.md, "The track refitted"). Which holds for the flights at hand is for those
//! flights to say, as they say how far they stray from the model (the learned model noise,
//! [`super::model_noise`]): a predictive contest between the two estimates, each judged by
//! data it had not seen (Dawid, "the prequential approach", JRSS A 1984; docs/references.md).
//!
//! At a refit both estimates of the newest stamp are held, the filter's and the refit's. At the
//! track's first fused detection a horizon later (`ekf.model_noise_horizon`, or [`HORIZON`]
//! without one), both are predicted to it and the log ratio of their position misses,
//! l = ln(|e_filter| / |e_refit|) (each at least [`MISS_FLOOR`]), is scored: positive when the
//! refit predicted better. The scores are averaged with a fading memory of [`MEMORY`] contests,
//! and the mean's t statistic (against the scores' own spread, with the effective number of
//! contests of the fading weights) decides: the refits replace the filter's estimates once it
//! passes [`SWITCH_ON`], and no longer once it falls under [`SWITCH_OFF`] (hysteresis: the choice
//! does not flap on a mean near zero). Until the flights have spoken the filter's estimates stay,
//! and refits are computed only to be scored, one contest at a time.
//!
//! Measured (docs/accuracy.md, "The refits contested"), refits every 0.1 s: on the 40 real
//! launcher flights 119 contests, t at most 2.0 (after 60) and -1.7 at the end: never applied;
//! on simulated play, whose flights follow the model, applied from the 60th contest (about the
//! 12th shot) and t = 4.4-7.1 after 200 shots.

/// Contests the score remembers (older ones fade by 1 - 1 / MEMORY each).
pub const MEMORY: f64 = 500.0;
/// The t statistic of the mean score above which the refits are applied: 3, since on the real
/// launcher flights it passed 2 once (after 60 contests) before it fell to -1.7; simulated
/// play passes 3 within the first 60 contests.
pub const SWITCH_ON: f64 = 3.0;
/// The t statistic under which applied refits stop.
pub const SWITCH_OFF: f64 = 0.0;
/// Effective contests (of the fading weights) before either switch: about ten tracks.
pub const MIN_CONTESTS: f64 = 50.0;
/// A miss is counted as at least this [m]: below the detections' resolution neither estimate
/// predicted better.
pub const MISS_FLOOR: f64 = 1e-5;
/// The contest's horizon without a model-noise horizon [s].
pub const HORIZON: f64 = 0.1;

use super::Snapshot;

/// The contest's score so far.
#[derive(Debug, Clone, Copy, PartialEq, Default, serde::Serialize)]
pub struct RefitContestScore {
    /// Contests scored.
    pub contests: u64,
    /// The fading mean of ln(|filter's miss| / |refit's miss|): positive, the refits predicted
    /// better.
    pub mean_log_ratio: f64,
    /// That mean over its standard error.
    pub t: f64,
    /// Whether the refits replace the filter's estimates.
    pub applying: bool,
}

/// The contest's fading sums and its decision, and the estimates of the contest under way.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub(super) struct RefitContest {
    /// The filter's estimate and the refit's at the same stamp, held until a detection a
    /// horizon later scores them.
    pub(super) held: Option<(Snapshot, Snapshot)>,
    /// Sum of the fading weights, of their squares, of the weighted scores and squared scores.
    weight: f64,
    weight_sq: f64,
    sum: f64,
    sum_sq: f64,
    contests: u64,
    applying: bool,
}

impl RefitContest {
    /// The score alone, no contest under way: what another estimator starts from.
    pub(super) fn without_held(&self) -> Self {
        Self {
            held: None,
            ..*self
        }
    }

    /// Whether the refits replace the filter's estimates.
    pub(super) fn applying(&self) -> bool {
        self.applying
    }

    /// Scores one contest: the filter's and the refit's position misses a horizon ahead [m].
    pub(super) fn score(&mut self, filter_miss: f64, refit_miss: f64) {
        if !(filter_miss.is_finite() && refit_miss.is_finite()) {
            return;
        }
        let l = (filter_miss.max(MISS_FLOOR) / refit_miss.max(MISS_FLOOR)).ln();
        if !l.is_finite() {
            return;
        }
        let fade = 1.0 - 1.0 / MEMORY;
        self.weight = self.weight * fade + 1.0;
        self.weight_sq = self.weight_sq * fade * fade + 1.0;
        self.sum = self.sum * fade + l;
        self.sum_sq = self.sum_sq * fade + l * l;
        self.contests += 1;
        let effective = self.weight * self.weight / self.weight_sq;
        if effective < MIN_CONTESTS {
            return;
        }
        let t = self.t();
        if t > SWITCH_ON {
            self.applying = true;
        } else if t < SWITCH_OFF {
            self.applying = false;
        }
    }

    /// The mean score over its standard error (0 before two contests).
    fn t(&self) -> f64 {
        if self.weight_sq <= 0.0 {
            return 0.0;
        }
        let effective = self.weight * self.weight / self.weight_sq;
        if effective <= 1.0 {
            return 0.0;
        }
        let mean = self.sum / self.weight;
        let variance =
            (self.sum_sq / self.weight - mean * mean).max(0.0) * effective / (effective - 1.0);
        let error = (variance / effective).sqrt();
        if error > 0.0 { mean / error } else { 0.0 }
    }

    /// The score so far.
    pub(super) fn report(&self) -> RefitContestScore {
        RefitContestScore {
            contests: self.contests,
            mean_log_ratio: if self.weight > 0.0 {
                self.sum / self.weight
            } else {
                0.0
            },
            t: self.t(),
            applying: self.applying,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Refits that predict better switch on only once enough contests say so, and off again
    /// only when the mean turns against them; a mean near zero moves nothing.
    #[test]
    fn the_refits_are_applied_while_they_predict_better() {
        let mut contest = RefitContest::default();
        // The refit's miss 0.8 or 1.25 of the filter's, alternately: no winner.
        for i in 0..400 {
            let ratio = if i % 2 == 0 { 0.8 } else { 1.25 };
            contest.score(0.01, 0.01 * ratio);
        }
        assert!(!contest.applying(), "{:?}", contest.report());
        // Better in three contests of four, worse in one.
        let mut switched = None;
        for i in 0..400 {
            let ratio = if i % 4 == 3 { 1.25 } else { 0.8 };
            contest.score(0.01, 0.01 * ratio);
            if contest.applying() && switched.is_none() {
                switched = Some(i);
            }
        }
        let at = switched.expect("switched on");
        assert!(at > 5, "switched at the {at}th contest");
        let report = contest.report();
        assert!(
            report.t > SWITCH_ON && report.mean_log_ratio > 0.0,
            "{report:?}"
        );
        // Worse from then on: off again.
        for _ in 0..400 {
            contest.score(0.01, 0.015);
        }
        assert!(!contest.applying(), "{:?}", contest.report());
        assert_eq!(contest.report().contests, 1200);
    }

    /// Misses under the floor count as equal; a miss that is not a number scores nothing.
    #[test]
    fn tiny_or_invalid_misses_say_nothing() {
        let mut contest = RefitContest::default();
        for _ in 0..100 {
            contest.score(1e-7, 1e-9);
            contest.score(f64::NAN, 0.01);
            contest.score(0.01, f64::INFINITY);
        }
        let report = contest.report();
        assert_eq!(report.mean_log_ratio, 0.0);
        assert!(!report.applying);
        assert_eq!(report.contests, 100);
    }
}
