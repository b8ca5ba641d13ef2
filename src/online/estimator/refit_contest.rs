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
//! At a refit both estimates of the newest stamp are held, the filter's and the refit's. Both
//! are flown on to each fused detection after it, until the first one a horizon later
//! (`ekf.model_noise_horizon`, or [`HORIZON`] without one), and the contest scores the log
//! ratio of their root mean square position misses over those detections (each weighted by the
//! inverse of its position variance's trace), l = ln(e_filter / e_refit) (each at least
//! [`MISS_FLOOR`]): positive when the refit predicted better. The scores are averaged with a
//! fading memory of [`MEMORY`] contests, and the mean's t statistic (against the scores' own
//! spread, with the effective number of contests of the fading weights) decides: the refits
//! replace the filter's estimates once it passes [`SWITCH_ON`], and no longer once it falls
//! under [`SWITCH_OFF`] (hysteresis: the choice does not flap on a mean near zero). Until the
//! flights have spoken the filter's estimates stay, and refits are computed only to be scored,
//! one contest at a time.
//!
//! Until 2026-12-04 a contest was the two misses of the single detection a horizon later, and
//! the switch waited for 50 contests: that detection's own noise (2 mm) is most of either miss.
//! On simulated play with the 150 fps camera (seeds 1-7, 0.1 s) the refits were then applied
//! from the 12th-33rd shot (21st on average), now from the 5th-26th (15th); on the 40 real
//! launcher flights t reached 1.9 and ended at -1.5, now 1.8 and -2.2 (never applied either way).
//! The shots before the switch are the filter's alone, and on seed 2 they hold most of what
//! still parts the 150 fps camera's spin at the crossing from the batch fit's
//! (docs/accuracy.md, "The refits' contest, averaged over its horizon"). A longer horizon (0.2
//! s) separated the real flights more clearly (t at most 0.5) but had fewer contests a shot and
//! switched later on four seeds of seven (up to the 56th shot).

/// Contests the score remembers (older ones fade by 1 - 1 / MEMORY each).
pub const MEMORY: f64 = 500.0;
/// The t statistic of the mean score above which the refits are applied: 3, since on the real
/// launcher flights it passes 1.8 (the contest of a single detection 0.1 s ahead 2.0) before it
/// falls to -2.2.
pub const SWITCH_ON: f64 = 3.0;
/// The t statistic under which applied refits stop.
pub const SWITCH_OFF: f64 = 0.0;
/// Effective contests (of the fading weights) before either switch: about four tracks (the
/// t statistic's own bar does the rest).
pub const MIN_CONTESTS: f64 = 20.0;
/// A miss is counted as at least this [m]: below the detections' resolution neither estimate
/// predicted better.
pub const MISS_FLOOR: f64 = 1e-5;
/// The contest's horizon without a model-noise horizon [s].
pub const HORIZON: f64 = 0.1;

use super::Snapshot;

/// A contest under way: the filter's and the refit's estimates held at the same stamp, each
/// flown on to every newer fused detection, and their misses.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) struct HeldContest {
    /// The stamp both estimates were held at [ns].
    pub(super) since: i64,
    /// The filter's estimate and the refit's, flown on to the newest detection scored.
    pub(super) filter: Snapshot,
    pub(super) refit: Snapshot,
    /// Their misses of the detections since.
    pub(super) misses: Misses,
}

impl HeldContest {
    /// The two estimates held at the filter's stamp.
    pub(super) fn new(filter: Snapshot, refit: Snapshot) -> Self {
        Self {
            since: filter.stamp,
            filter,
            refit,
            misses: Misses::default(),
        }
    }
}

/// The weighted sums of the filter's and the refit's squared misses [m^2], and of the weights.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub(super) struct Misses {
    filter_squared: f64,
    refit_squared: f64,
    weight: f64,
}

impl Misses {
    /// Adds a detection's misses [m], weighted by `weight` (the inverse of its position
    /// variance's trace); a weight that is not a positive number adds nothing.
    pub(super) fn add(&mut self, filter_miss: f64, refit_miss: f64, weight: f64) {
        if weight > 0.0 && weight.is_finite() {
            self.filter_squared += weight * filter_miss * filter_miss;
            self.refit_squared += weight * refit_miss * refit_miss;
            self.weight += weight;
        }
    }

    /// The filter's and the refit's root mean square misses so far [m] (not numbers before a
    /// detection).
    pub(super) fn root_mean_square(&self) -> (f64, f64) {
        (
            (self.filter_squared / self.weight).sqrt(),
            (self.refit_squared / self.weight).sqrt(),
        )
    }
}

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
    /// The contest under way: the filter's estimate and the refit's at the same stamp, held
    /// until a detection a horizon later.
    pub(super) held: Option<HeldContest>,
    /// Sum of the fading weights, of their squares, of the weighted scores and squared scores.
    weight: f64,
    weight_sq: f64,
    sum: f64,
    sum_sq: f64,
    contests: u64,
    applying: bool,
}

impl RefitContest {
    /// No contest yet, the refits applied from the start or not (`ekf.refits_start_applied`).
    pub(super) fn starting(applying: bool) -> Self {
        Self {
            applying,
            ..Self::default()
        }
    }

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

    /// A contest under way scores the root mean square of its detections' misses, each
    /// weighted by its own; a weight that is not a positive number adds nothing.
    #[test]
    fn a_held_contest_averages_its_detections_misses() {
        let mut misses = Misses::default();
        assert!(
            misses.root_mean_square().0.is_nan(),
            "nothing to score before a detection"
        );
        misses.add(0.003, 0.001, 1.0);
        misses.add(0.001, 0.003, 3.0);
        misses.add(1.0, 1.0, 0.0);
        misses.add(1.0, 1.0, f64::NAN);
        let (filter, refit) = misses.root_mean_square();
        approx::assert_relative_eq!(filter, ((9e-6 + 3.0 * 1e-6) / 4.0_f64).sqrt());
        approx::assert_relative_eq!(refit, ((1e-6 + 3.0 * 9e-6) / 4.0_f64).sqrt());
        let mut contest = RefitContest::default();
        contest.score(filter, refit);
        approx::assert_relative_eq!(contest.report().mean_log_ratio, (filter / refit).ln());
    }

    /// Refits applied from the start stay applied while the contest has not spoken, and stop
    /// once it turns against them.
    #[test]
    fn refits_applied_from_the_start_stop_when_they_lose() {
        // The refit's miss 1.2 or 1.6 of the filter's, alternately: worse, with a spread (a
        // constant score has none, and its t no sign).
        let worse = |i: usize| if i.is_multiple_of(2) { 0.012 } else { 0.016 };
        let mut contest = RefitContest::starting(true);
        assert!(contest.applying());
        for i in 0..10 {
            contest.score(0.01, worse(i));
        }
        assert!(
            contest.applying(),
            "too few contests: {:?}",
            contest.report()
        );
        for i in 10..40 {
            contest.score(0.01, worse(i));
        }
        let report = contest.report();
        assert!(!contest.applying() && report.t < SWITCH_OFF, "{report:?}");
        assert!(!RefitContest::starting(false).applying());
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
