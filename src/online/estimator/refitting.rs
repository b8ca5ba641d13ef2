//! The live track smoothed on a schedule of its own age (`ekf.refit_interval`): its fused
//! detections are kept with their measurements ([`TrackRefit`]), and every interval the filter
//! is run again over them from the estimate before the first of them, linearised along the
//! last smoothed flight rather than at its own estimates, and smoothed back (Rauch-Tung-
//! Striebel): the iterated extended Kalman smoother (Bell, "The iterated Kalman smoother as a
//! Gauss-Newton method", SIAM J. Optim. 1994), one Gauss-Newton step of the maximum a
//! posteriori flight *with the filter's process noise* per iteration. Its filtered estimates
//! (mean and covariance) replace the track's estimate and every snapshot in its history at the
//! same stamps (so that a late detection rolled back into the history meets them). Past
//! `ekf.refit_max_detections` the oldest detections leave the window, summed up in the pass's
//! estimate after them, where the next pass starts (a fixed-lag smoother): a refit's cost is
//! bounded. The schedule is the track's own stamps, so a replay refits exactly where the node
//! did.
//!
//! The same smoothing teaches the physics (`adaptation.smoothed_lessons`, on by default): when
//! a track ends, its kept detections are smoothed once more and the pass's parameters at its
//! last detection, rather than the filter's, are the track's lesson ([`Estimator::defer_lesson`],
//! [`Estimator::learn_in_idle_time`], [`Estimator::settle_lesson`]).
//! The filter's own estimate of the Magnus scale from positions alone leans low: the curvature
//! fixes the product of the Magnus scale and the spin, the bounce the spin, and an update
//! linearised at the filter's estimates moves along the tangent of that hyperbola, below it on
//! either side. A pass linearised along the smoothed flight lands on it (docs/estimator.md).

use super::refit_contest::HeldContest;
use super::*;
use crate::online::ekf::{FilterNoise, NoiseScales};
use crate::physics::ParamVector;
use crate::physics::params::{AUGMENTED, AugmentedMatrix, AugmentedVector};

/// Fewest detections a track is smoothed from.
const MIN_DETECTIONS: usize = 8;
/// Iterations (a pass forward and one back) of each smoothing. One alone is unstable; a third
/// (since 2026-12-04; the real launcher flights, where the contest keeps the refits out, print
/// the same) reads the 150 fps camera's fast spins where two left them short: its state NEES
/// on seeds 1-10 0.99-1.34 instead of up to 1.56, which let the learned dispersion's floor
/// fall ([`super::learning::DISPERSION_FLOOR`]; docs/estimator.md).
const ITERATIONS: usize = 3;
/// Iterations of the smoothing a track's lesson is taken from: the first pass is the filter
/// itself, the second one Gauss-Newton step, the third has converged (on the real launcher
/// flights a fourth or sixth moves the crossing's RMS by under 0.05 mm, the learned
/// parameters by under 0.002).
const LESSON_ITERATIONS: usize = 3;
/// The lesson's stages: its passes and the smoothings between them (the last pass is not
/// smoothed back).
const LESSON_STAGES: usize = 2 * LESSON_ITERATIONS - 1;
/// Variance added to each parameter's in the smoother's inverse of a prediction's covariance.
const PARAM_VARIANCE_FLOOR: f64 = 1e-12;
/// The kept detections' buffer, in windows: a window and the detections of the intervals until
/// the next refit slides it.
const BUFFER_WINDOWS: usize = 2;

/// What a pass guards against beyond the filter's model.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum PassModel {
    /// Nothing: a live refit, linearised along the smoothed flight, has no misread spin to
    /// guard against, so its positions take the whole gain on the spin along the flight and
    /// its coefficients are evaluated at its nominal's spin, not widened by the spin's spread
    /// (`ekf.spin_along_flight_gain`, `ekf.spin_parameter_spread`: the filter's guards against
    /// its own linearisation at a too small spin). With the filter's guards (refits every
    /// 0.05 s, seed 1) the refits' 150 fps spin at the crossing was 1.9-3.0x the batch fit's
    /// instead of 1.1-1.6x, and seed 3's state NEES 0.68 instead of 0.80 (docs/estimator.md).
    Smoothed,
    /// The filter's, its guard on the spin along the flight as the track ended
    /// ([`Estimator::guards_spin_along_flight`]): a track's lesson, which teaches the physics
    /// as the filter's own lessons did (its first pass is the filter itself).
    Filter {
        /// Whether the filter guarded the spin along the flight.
        guarded: bool,
    },
}

/// One step of the pass: the estimate predicted to a detection and after it.
#[derive(Debug, Clone, Copy)]
struct Step {
    /// The detection's stamp [ns].
    stamp: i64,
    /// Predicted mean and covariance of (state, parameters).
    predicted: (AugmentedVector, AugmentedMatrix),
    /// The transition from the step before.
    transition: AugmentedMatrix,
    /// The estimate after the detection.
    filtered: Ekf,
    /// Table bounces since the window's first estimate.
    bounces: u32,
}

/// An ended track's lesson, waiting for its smoothing ([`Estimator::defer_lesson`]).
#[derive(Debug, Clone, Copy)]
pub(super) struct PendingLesson {
    /// The parameters' prior the track started from.
    prior: (ParamVector, ParamCovariance),
    /// The track's first and last stamps [ns].
    started: i64,
    stamp: i64,
    /// What the filter learned: the lesson if the smoothing fails.
    filter: (ParamVector, ParamCovariance),
    /// The model's noise scales when the track ended, for the kept detections' phase (positions
    /// before the spin is measured).
    scales: NoiseScales,
    /// Whether the filter guarded the spin along the flight when the track ended (the stages
    /// may run after a contest has changed it).
    guarded: bool,
    /// The bounces before the kept detections' first estimate.
    base_bounces: u32,
    /// Stages run (passes and smoothings, alternately).
    stage: usize,
    /// The smoothed flight's parameters, once the last stage has run and agreed.
    posterior: Option<(ParamVector, ParamCovariance)>,
}

/// The live track's detections, kept for its smoothing, and the last smoothed flight.
#[derive(Debug, Clone)]
pub(super) struct TrackRefit {
    /// The fused detections of the window (stamps and measurements), in stamp order; allocated
    /// once.
    observations: Vec<(i64, Measurement)>,
    /// The last pass, one step per observation; allocated once.
    steps: Vec<Step>,
    /// The smoothed (state, parameters) at the window's start and each step's stamp: the next
    /// pass's nominal; allocated once.
    smoothed: Vec<(i64, AugmentedVector)>,
    /// The smoothed covariance of the newest of `smoothed` (as many as the last smoothing
    /// computed, [`first_covariance_needed`]), which a live refit's pass takes a bounce's spread
    /// at; allocated once.
    smoothed_covariance: Vec<AugmentedMatrix>,
    /// The track they belong to (0: none).
    track: u32,
    /// The track's first estimate's stamp, from which its age is counted [ns].
    start: i64,
    /// The estimate each pass starts from: the track's first, then, once the window has slid,
    /// the last pass's after the detection before the window.
    base: Option<Snapshot>,
    /// The track age of the next smoothing [ns].
    next: i64,
    /// No more smoothing of this track: a spin was measured (the filter then linearises at a
    /// measured spin).
    done: bool,
}

impl TrackRefit {
    /// The smoothed covariance at index `at` of `smoothed`, where the last smoothing computed it
    /// (the covariances are of the newest estimates).
    fn smoothed_covariance_at(&self, at: usize) -> Option<&AugmentedMatrix> {
        let first = self
            .smoothed
            .len()
            .saturating_sub(self.smoothed_covariance.len());
        at.checked_sub(first)
            .and_then(|i| self.smoothed_covariance.get(i))
    }

    /// Forgets the smoothed flight.
    fn forget_smoothed(&mut self) {
        self.smoothed.clear();
        self.smoothed_covariance.clear();
    }

    /// The last pass's step at `stamp`, if it has one.
    fn step_at(&self, stamp: i64) -> Option<&Step> {
        let at = self.steps.partition_point(|step| step.stamp < stamp);
        self.steps.get(at).filter(|step| step.stamp == stamp)
    }

    /// Whether the last pass bounces on the table as the track's `estimates` (stamp, bounces)
    /// did, at every stamp they share (its bounces counted from `base_bounces`, those before
    /// the window), and is finite throughout.
    fn pass_agrees_with(
        &self,
        mut estimates: impl Iterator<Item = (i64, u32)>,
        base_bounces: u32,
    ) -> bool {
        let agrees = |(stamp, bounces): (i64, u32)| {
            self.step_at(stamp)
                .is_none_or(|step| bounces == base_bounces + step.bounces)
        };
        let finite = |ekf: &Ekf| {
            ekf.x
                .iter()
                .chain(ekf.theta.iter())
                .chain(ekf.P.iter())
                .all(|v| v.is_finite())
        };
        estimates.all(agrees) && self.steps.iter().all(|s| finite(&s.filtered))
    }

    /// No room: a placeholder while a buffer is worked on elsewhere (allocates nothing).
    fn empty() -> Self {
        Self {
            observations: Vec::new(),
            steps: Vec::new(),
            smoothed: Vec::new(),
            smoothed_covariance: Vec::new(),
            track: 0,
            start: 0,
            base: None,
            next: 0,
            done: false,
        }
    }

    /// Room for `capacity` detections.
    pub(super) fn new(capacity: usize) -> Self {
        Self {
            observations: Vec::with_capacity(BUFFER_WINDOWS * capacity),
            steps: Vec::with_capacity(BUFFER_WINDOWS * capacity),
            smoothed: Vec::with_capacity(BUFFER_WINDOWS * capacity + 1),
            smoothed_covariance: Vec::with_capacity(BUFFER_WINDOWS * capacity + 1),
            track: 0,
            start: 0,
            base: None,
            next: 0,
            done: false,
        }
    }
}

/// (x, theta) of an estimate.
fn augmented(ekf: &Ekf) -> AugmentedVector {
    let mut y = AugmentedVector::zeros();
    y.fixed_rows_mut::<9>(0).copy_from(&ekf.x);
    y.fixed_rows_mut::<PARAMS>(9).copy_from(&ekf.theta);
    y
}

impl Estimator {
    /// Keeps the fused detection `d` (measured as `m`) of the live track for its refits.
    pub(super) fn keep_for_refit(&mut self, d: &Detection, m: &Measurement) {
        let interval = self.settings.refit_interval;
        let (Some(track), true) = (&self.track, self.settings.keeps_detections()) else {
            return;
        };
        let kept = &mut self.refit;
        if kept.track != track.id {
            kept.track = track.id;
            kept.start = track.base.stamp;
            kept.base = Some(track.base);
            kept.forget_smoothed();
            kept.next = interval;
            kept.done = false;
            kept.observations.clear();
        }
        if matches!(m, Measurement::PositionSpin { .. }) {
            kept.done = true;
        }
        let window_start = kept.base.map_or(kept.start, |b| b.stamp);
        // A detection older than the window (a late one) is in the estimate the window starts
        // from only as the filter fused it; one the buffer has no room for ends the smoothing.
        if d.stamp <= window_start || kept.done {
            return;
        }
        if kept.observations.len() >= BUFFER_WINDOWS * self.settings.refit_max {
            kept.done = true;
            return;
        }
        let at = kept.observations.partition_point(|(k, _)| *k <= d.stamp);
        kept.observations.insert(at, (d.stamp, *m));
    }

    /// Smooths the live track when its age has reached the next smoothing's (see the module
    /// doc).
    pub(super) fn refit_when_due(&mut self) {
        let interval = self.settings.refit_interval;
        let Some(track) = &self.track else {
            return;
        };
        let kept = &mut self.refit;
        if interval <= 0 || kept.track != track.id || kept.done {
            return;
        }
        let age = track.now.stamp - kept.start;
        if age < kept.next {
            return;
        }
        while kept.next <= age {
            kept.next += interval;
        }
        if kept.observations.len() < MIN_DETECTIONS {
            return;
        }
        // A refit that would neither be applied nor start a contest is not run.
        if self.refits_applied() || self.contest.held.is_none() {
            self.refit_now();
        }
    }

    /// Whether the ending track's lesson is its flight smoothed: the option on, the kept
    /// detections the track's, no spin measured, the buffer not outgrown, enough detections.
    fn lesson_due(&self) -> bool {
        let (Some(track), kept) = (self.track.as_ref(), &self.refit) else {
            return false;
        };
        self.settings.smoothed_lessons
            && kept.track == track.id
            && !kept.done
            && kept.observations.len() >= MIN_DETECTIONS
    }

    /// Hands the ending track's kept detections to its lesson (see the module doc), or returns
    /// false when the filter's estimate is to teach ([`Self::lesson_due`]). Nothing is computed
    /// here: the smoothing runs stage by stage in [`Estimator::learn_in_idle_time`] or at once
    /// when the lesson is settled.
    pub(super) fn defer_lesson(&mut self) -> bool {
        if !self.lesson_due() {
            return false;
        }
        self.settle_lesson();
        let Some(track) = self.track.as_ref() else {
            return false;
        };
        let base_bounces = self.refit.base.map_or(0, |b| b.bounces);
        self.lesson_bounces.clear();
        self.lesson_bounces.extend(
            std::iter::once(&track.base)
                .chain(track.history.iter().map(|e| &e.after))
                .chain(std::iter::once(&track.now))
                .map(|s| (s.stamp, s.bounces)),
        );
        self.lesson = Some(PendingLesson {
            prior: track.param_prior,
            started: track.started,
            stamp: track.now.stamp,
            filter: (track.now.ekf.theta, track.now.ekf.param_covariance()),
            scales: self.refit_scales(),
            guarded: self.guards_spin_along_flight(),
            base_bounces,
            stage: 0,
            posterior: None,
        });
        std::mem::swap(&mut self.refit, &mut self.lesson_refit);
        // The buffer handed back is the next track's, whatever id it last held.
        self.refit.track = 0;
        true
    }

    /// Whether an ended track's lesson has smoothing stages left to run
    /// (`adaptation.smoothed_lessons`): work for [`Self::learn_in_idle_time`].
    pub fn has_idle_work(&self) -> bool {
        self.lesson
            .as_ref()
            .is_some_and(|l| l.stage < LESSON_STAGES)
    }

    /// Runs the next stage of the pending lesson's smoothing (a pass, or a smoothing back);
    /// true while stages remain. The last stage leaves the posterior to absorb, which
    /// [`Self::settle_lesson`] absorbs: so when the stages run does not change what is learned,
    /// nor when.
    pub(super) fn advance_lesson(&mut self) -> bool {
        if !self.has_idle_work() {
            return false;
        }
        let Some(lesson) = self.lesson.as_mut() else {
            return false;
        };
        let (scales, guarded) = (lesson.scales, lesson.guarded);
        let stage = lesson.stage;
        lesson.stage += 1;
        let mut kept = std::mem::replace(&mut self.lesson_refit, TrackRefit::empty());
        if stage % 2 == 0 {
            self.pass_forward_on(&mut kept, &scales, PassModel::Filter { guarded });
        } else {
            // The last pass is not smoothed back: its estimate at the last detection is the
            // lesson. A lesson's passes take a bounce's spread at their own covariance.
            smooth_back(&mut kept, usize::MAX);
        }
        let done = stage + 1 == LESSON_STAGES;
        let posterior = done.then(|| self.lesson_posterior(&kept)).flatten();
        self.lesson_refit = kept;
        if let Some(lesson) = self.lesson.as_mut()
            && done
        {
            lesson.posterior = posterior;
        }
        !done
    }

    /// The last pass's parameters at its last detection, when it bounces where the track's
    /// estimates did and is finite.
    fn lesson_posterior(&self, kept: &TrackRefit) -> Option<(ParamVector, ParamCovariance)> {
        let lesson = self.lesson.as_ref()?;
        let last = kept.steps.last()?;
        let posterior = (last.filtered.theta, last.filtered.param_covariance());
        kept.pass_agrees_with(self.lesson_bounces.iter().copied(), lesson.base_bounces)
            .then_some(posterior)
    }

    /// Finishes the pending lesson's stages and absorbs it into the ball's and table's
    /// parameters (its flight smoothed, or the filter's estimate when the smoothing failed).
    /// Called before a track takes its prior, before another lesson, and at the input's end:
    /// points the detections decide, so a node that ran the stages in its idle time and a
    /// replay that runs them here learn the same.
    pub(super) fn settle_lesson(&mut self) {
        while self.advance_lesson() {}
        let Some(lesson) = self.lesson.take() else {
            return;
        };
        let posterior = match lesson.posterior {
            Some(smoothed) => {
                self.counters.smoothed_lessons += 1;
                smoothed
            }
            None => lesson.filter,
        };
        self.learned =
            self.learned
                .absorbed(&lesson.prior, &posterior, lesson.started, lesson.stamp);
    }

    /// One refit of the kept detections: the passes; when the filter's bounces agree, a
    /// contest held (with `ekf.refit_when_better`, none under way) and the estimates taken
    /// (without it, or while the refits win their contests); the window slid.
    fn refit_now(&mut self) {
        for _ in 0..ITERATIONS {
            self.pass_forward();
            let from = first_covariance_needed(&self.refit, self.flight.radius());
            smooth_back(&mut self.refit, from);
        }
        if self.pass_agrees() {
            if self.settings.refit_when_better {
                self.hold_contest();
            }
            if self.refits_applied() {
                self.take_pass();
                self.counters.refits += 1;
            }
        } else {
            // The pass and the filter disagree on the bounces (or the pass failed): the next
            // refit linearises afresh, at its own estimates, rather than along this flight.
            self.refit.forget_smoothed();
        }
        self.slide_window();
    }

    /// Whether a refit's estimates replace the filter's: always without `ekf.refit_when_better`,
    /// else while the refits win their contests.
    fn refits_applied(&self) -> bool {
        !self.settings.refit_when_better || self.contest.applying()
    }

    /// Whether the filter takes only `ekf.spin_along_flight_gain` of a position's gain on the
    /// spin along the flight before the first bounce: unless refits replace its estimates.
    /// The guard keeps the filter, linearised at its own uncertain spin, from growing sure of a
    /// misread spin, at the price of the information it throws away; refits, linearised along
    /// the smoothed flight, mend a misread every interval, so with them applied the guard only
    /// costs (seeds 1-3 with both cameras: the spin at the crossing 1.16-1.43x the batch fit's
    /// guarded, 1.11-1.30x unguarded), and where they lose their contest (the real launcher
    /// flights) it stays (docs/estimator.md, "The spin along the flight, partly learned").
    pub(super) fn guards_spin_along_flight(&self) -> bool {
        !(self.settings.refit_interval > 0 && self.refits_applied())
    }

    /// Holds the live track's newest estimate and the last pass's at the same stamp for their
    /// contest ([`super::refit_contest`]), unless one is under way.
    fn hold_contest(&mut self) {
        let (Some(track), None) = (self.track.as_ref(), self.contest.held) else {
            return;
        };
        if let Some(step) = self.refit.step_at(track.now.stamp) {
            let mut refitted = track.now;
            refitted.ekf = step.filtered;
            self.contest.held = Some(HeldContest::new(track.now, refitted));
        }
    }

    /// Flies the contest under way on to the newest fused detection `d` (measured as `m`),
    /// adds both estimates' position misses, and scores the contest once `d` is a horizon
    /// past its estimates.
    pub(super) fn judge_contest(&mut self, d: &Detection, m: &Measurement) {
        let Some(mut held) = self.contest.held.take() else {
            return;
        };
        // The detected position (an estimate's view of the detection, `measurement_at`, moves
        // only its covariance).
        let (z, r) = m.position();
        let miss = |ahead: &mut Snapshot| {
            self.advance_with(&self.propagator, ahead, d.stamp, None);
            (z - ahead.ekf.x.fixed_rows::<3>(0)).norm()
        };
        let (filter_miss, refit_miss) = (miss(&mut held.filter), miss(&mut held.refit));
        held.misses.add(filter_miss, refit_miss, 1.0 / r.trace());
        if d.stamp - held.since < self.settings.contest_horizon {
            self.contest.held = Some(held);
            return;
        }
        let (filter_miss, refit_miss) = held.misses.root_mean_square();
        self.contest.score(filter_miss, refit_miss);
    }

    /// Past `ekf.refit_max_detections`, the window's oldest detections leave it: the next pass
    /// starts from this pass's estimate after the last of them (their linearisation stays as
    /// this pass left it: a fixed-lag smoother).
    fn slide_window(&mut self) {
        let kept = &mut self.refit;
        let excess = kept
            .observations
            .len()
            .saturating_sub(self.settings.refit_max);
        let (Some(base), Some(last_out)) = (kept.base.as_mut(), excess.checked_sub(1)) else {
            return;
        };
        let Some(step) = kept.steps.get(last_out) else {
            return;
        };
        base.ekf = step.filtered;
        base.stamp = step.stamp;
        base.bounces += step.bounces;
        let stamp = step.stamp;
        kept.observations.drain(..excess);
        kept.steps.clear();
        // The smoothed flight before the new window's start leaves with its covariances.
        let before = kept.smoothed.partition_point(|(s, _)| *s < stamp);
        kept.smoothed.drain(..before);
        // The covariances are of the newest estimates: those of the estimates gone go too.
        let gone = kept
            .smoothed_covariance
            .len()
            .saturating_sub(kept.smoothed.len());
        kept.smoothed_covariance.drain(..gone);
    }

    /// The filter run over the kept detections from the track's first estimate, each
    /// prediction linearised at the last smoothed flight where it has one (a detection it has
    /// not seen: at the pass's own estimate, as the filter does).
    fn pass_forward(&mut self) {
        let scales = self.refit_scales();
        let mut kept = std::mem::replace(&mut self.refit, TrackRefit::empty());
        self.pass_forward_on(&mut kept, &scales, PassModel::Smoothed);
        self.refit = kept;
    }

    /// The noise scales of the kept detections' passes: those of the phase their first estimate
    /// is in (the kept detections are positions, and a measured spin ends the smoothing).
    fn refit_scales(&self) -> NoiseScales {
        let spin_measured = self.refit.base.is_some_and(|b| b.spin_measured);
        self.model_noise.scales(spin_measured)
    }

    /// [`Self::pass_forward`] over `kept`, the model's noise at `scales`, with or without the
    /// filter's guards (`model`).
    fn pass_forward_on(&self, kept: &mut TrackRefit, scales: &NoiseScales, model: PassModel) {
        let Some(mut snapshot) = kept.base else {
            return;
        };
        let mut steps = std::mem::take(&mut kept.steps);
        steps.clear();
        let (mut previous, mut bounces) = (snapshot.stamp, 0);
        let noise = match model {
            PassModel::Smoothed => FilterNoise {
                spin_spread: 0.0,
                ..self.settings.filter
            },
            PassModel::Filter { .. } => self.settings.filter,
        };
        for (stamp, m) in &kept.observations {
            let smoothed = &kept.smoothed;
            let at = smoothed.partition_point(|(k, _)| *k < previous);
            let (nominal, nominal_covariance) = match smoothed.get(at) {
                Some((k, y)) if *k == previous => (*y, kept.smoothed_covariance_at(at)),
                _ => (augmented(&snapshot.ekf), None),
            };
            // A live refit takes a bounce's spread at what the whole flight knows of the state
            // there (the last smoothing's covariance), not at its forward pass's: taken at the
            // forward covariance the spread made the 150 fps camera's spin at the crossing
            // 1.3-2.0x the batch fit's, and without any spread the refit was sure of a bounce
            // its detections did not yet fix (state NEES after the bounce up to 3.9).
            let nominal_covariance = match model {
                PassModel::Smoothed => nominal_covariance,
                PassModel::Filter { .. } => None,
            };
            let (report, transition) = snapshot.ekf.predict_about(
                (
                    &nominal.fixed_rows::<9>(0).into_owned(),
                    &nominal.fixed_rows::<PARAMS>(9).into_owned(),
                ),
                nominal_covariance,
                &self.propagator,
                &noise,
                scales,
                (stamp - previous) as f64 * 1e-9,
            );
            bounces += report.bounces;
            snapshot.bounce_jump = report.last_jump.or(snapshot.bounce_jump);
            let predicted = (augmented(&snapshot.ekf), snapshot.ekf.P);
            // Kept detections are positions (a measured spin ends the smoothing), each fused
            // once already: no gate.
            if let (Measurement::Position { z, r, .. }, _) = self.measurement_at(&snapshot, m) {
                let along_flight = match model {
                    PassModel::Smoothed => 1.0,
                    PassModel::Filter { guarded } => self
                        .settings
                        .along_flight_gain(snapshot.bounces + bounces, guarded),
                };
                let _ = snapshot.ekf.update_partially(
                    &z,
                    &position_H(),
                    &r,
                    f64::INFINITY,
                    None,
                    along_flight,
                );
            }
            steps.push(Step {
                stamp: *stamp,
                predicted,
                transition,
                filtered: snapshot.ekf,
                bounces,
            });
            previous = *stamp;
        }
        kept.steps = steps;
    }

    /// Whether the last pass bounces on the table when the track's estimates do, at every stamp
    /// they share, and is finite throughout.
    fn pass_agrees(&self) -> bool {
        let kept = &self.refit;
        let (Some(track), Some(base)) = (self.track.as_ref(), kept.base.as_ref()) else {
            return false;
        };
        let estimates = std::iter::once(&track.base)
            .chain(track.history.iter().map(|e| &e.after))
            .chain(std::iter::once(&track.now))
            .map(|s| (s.stamp, s.bounces));
        kept.pass_agrees_with(estimates, base.bounces)
    }

    /// Puts the last pass's estimates into the track's snapshots at the same stamps (the pass
    /// bounces on the table when the track's estimates do: [`Self::pass_agrees`]).
    fn take_pass(&mut self) {
        let kept = &self.refit;
        let Some(track) = self.track.as_mut() else {
            return;
        };
        let step_at = |stamp: i64| kept.step_at(stamp);
        let place = |s: &mut Snapshot| {
            if let Some(step) = step_at(s.stamp) {
                s.ekf = step.filtered;
            }
        };
        place(&mut track.base);
        for entry in track.history.iter_mut() {
            place(&mut entry.after);
        }
        place(&mut track.now);
        // The estimate held to learn the model noise from meets the pass too: the filter's
        // earlier miss is not the flight straying from the model.
        if let Some((from, _)) = self.probe.as_deref_mut().and_then(|p| p.from.as_mut()) {
            place(from);
        }
    }
}

/// Steps before the last pass's first bounce whose smoothed covariances a live refit keeps: the
/// next pass, along the new smoothed flight, may bounce a step or two earlier.
const COVARIANCE_STEPS_BEFORE_BOUNCE: usize = 3;

/// Height above its contact with the table [m] under which an estimate of the last pass keeps
/// its smoothed covariance, bounce or not (and the [`COVARIANCE_STEPS_BEFORE_BOUNCE`] before
/// it): a pass that did not bounce may where the ball came this close.
const COVARIANCE_HEIGHT: f64 = 0.05;

/// The first index of the smoothed flight (0: the window's first estimate, k + 1: step k) whose
/// covariance the next pass may read: a prediction that bounces spreads the bounce at the
/// covariance of the estimate it starts from. [`COVARIANCE_STEPS_BEFORE_BOUNCE`] before the last
/// pass's first bounce or its first estimate within [`COVARIANCE_HEIGHT`] of the table
/// (`contact_height`, the ball's centre at contact); past the end where neither is (most
/// refits, before the first bounce: their smoothing then computes no covariance). Until
/// 2026-12-04 every estimate's was computed, a 13 x 13 triple product a step.
fn first_covariance_needed(kept: &TrackRefit, contact_height: f64) -> usize {
    let heights = kept
        .base
        .iter()
        .map(|b| b.ekf.x[2])
        .chain(kept.steps.iter().map(|s| s.filtered.x[2]));
    let low = heights
        .enumerate()
        .find(|(_, z)| *z - contact_height < COVARIANCE_HEIGHT)
        .map(|(index, _)| index);
    let bounce = kept.steps.iter().position(|s| s.bounces > 0);
    low.into_iter()
        .chain(bounce)
        .min()
        .map_or(usize::MAX, |index| {
            index.saturating_sub(COVARIANCE_STEPS_BEFORE_BOUNCE)
        })
}

/// The Rauch-Tung-Striebel smoother back over the last pass: the smoothed (state, parameters)
/// at the first estimate's time and every step's, the next pass's nominal, and from the index
/// `covariances_from` on (0: all, `usize::MAX`: none) their covariances (which only a live
/// refit's pass reads, [`first_covariance_needed`]).
#[expect(non_snake_case, reason = "matrix notation")]
fn smooth_back(kept: &mut TrackRefit, covariances_from: usize) {
    let (Some(base), Some(&last)) = (kept.base, kept.steps.last()) else {
        return;
    };
    kept.forget_smoothed();
    let (mut later, mut later_covariance) = (augmented(&last.filtered), last.filtered.P);
    if !later.iter().all(|v| v.is_finite()) {
        return;
    }
    kept.smoothed.push((last.stamp, later));
    if kept.steps.len() >= covariances_from {
        kept.smoothed_covariance.push(later_covariance);
    }
    // Step k's filtered estimate with step k + 1's prediction and transition.
    for k in (0..kept.steps.len()).rev() {
        let next = &kept.steps[k];
        let (stamp, filtered) = match k.checked_sub(1) {
            Some(j) => (kept.steps[j].stamp, &kept.steps[j].filtered),
            None => (base.stamp, &base.ekf),
        };
        // Parameters held fixed (no adaptation) have no variance: a trace of it keeps the
        // prediction's covariance invertible without moving the state's gain.
        let mut predicted = next.predicted.1;
        for i in 9..AUGMENTED {
            predicted[(i, i)] += PARAM_VARIANCE_FLOOR;
        }
        let Some(chol) = predicted.cholesky() else {
            break;
        };
        // C = P_k Phi' P_{k+1|k}^-1 = (P_{k+1|k}^-1 Phi P_k)'.
        let C = chol.solve(&(next.transition * filtered.P)).transpose();
        later = augmented(filtered) + C * (later - next.predicted.0);
        if k >= covariances_from {
            // P_k|N = P_k + C (P_k+1|N - P_k+1|k) C'.
            later_covariance =
                filtered.P + C * (later_covariance - next.predicted.1) * C.transpose();
            later_covariance = (later_covariance + later_covariance.transpose()) * 0.5;
            kept.smoothed_covariance.push(later_covariance);
        }
        if !later.iter().all(|v| v.is_finite()) {
            kept.forget_smoothed();
            return;
        }
        kept.smoothed.push((stamp, later));
    }
    kept.smoothed.reverse();
    kept.smoothed_covariance.reverse();
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::physics::{BallState, PredictOptions, predict};
    use nalgebra::Vector3;

    /// A 150 fps flight with a few millimetres of noise, as detections from 1 s on.
    fn serve(config: &Config, seconds: f64) -> Vec<(Detection, BallState)> {
        let start = BallState::new(
            Vector3::new(1.6, 0.1, 0.3),
            Vector3::new(-5.0, 0.2, 1.0),
            Vector3::new(0.0, 250.0, 10.0),
        );
        let flight = predict(
            &Propagator::new(config),
            &start,
            &PredictOptions {
                horizon: seconds,
                sample_interval: 1.0 / 150.0,
                plane_x: None,
                stop_at_plane: false,
            },
        );
        crate::online::estimator::tests::detections_of(flight.samples.iter())
    }

    /// An estimator after the detections of [`serve`]'s first `seconds`.
    fn served(config: &Config, seconds: f64) -> Estimator {
        let mut estimator = Estimator::new(config);
        for (d, _) in serve(config, seconds) {
            estimator.handle(&d);
        }
        estimator
    }

    /// Refits due only after a second of track (the detections are kept, nothing refitted
    /// unless asked), the noise held as configured (so that the filter then and a pass now see
    /// the same: a pass at its own estimates is the filter exactly).
    fn keeping_detections() -> Config {
        let mut config = Config::default();
        config.ekf.refit_interval = 1.0;
        config.ekf.refit_when_better = false;
        config.ekf.learn_model_noise = false;
        config.ekf.learn_noise = false;
        config
    }

    /// [`keeping_detections`] with the filter's guards against a misread spin off, so that a
    /// live refit's pass at its own estimates is the filter ([`PassModel::Smoothed`]).
    fn without_guards() -> Config {
        let mut config = keeping_detections();
        config.ekf.spin_along_flight_gain = 1.0;
        config.ekf.spin_parameter_spread = 0.0;
        config
    }

    /// The smoothing keeps each smoothed estimate's covariance (a live refit takes a bounce's
    /// spread there): at the last step the filter's, before it no larger than the forward
    /// pass's (what the later detections add), and one for every smoothed estimate.
    #[test]
    fn the_smoothed_covariance_is_no_larger_than_the_filtered() {
        let mut estimator = served(&keeping_detections(), 0.3);
        estimator.pass_forward();
        smooth_back(&mut estimator.refit, 0);
        let kept = &estimator.refit;
        assert!(kept.smoothed.len() > 30);
        assert_eq!(kept.smoothed_covariance.len(), kept.smoothed.len());
        let last = kept.steps.last().unwrap().filtered.P;
        assert_eq!(kept.smoothed_covariance.last(), Some(&last));
        // smoothed[0] is the window's start, smoothed[k + 1] step k's.
        for (k, step) in kept.steps.iter().enumerate() {
            let gap = step.filtered.P - kept.smoothed_covariance[k + 1];
            let lowest = gap.symmetric_eigenvalues().min();
            assert!(lowest > -1e-9 * step.filtered.P.norm(), "{k}: {lowest}");
        }
        let first = &kept.steps[0].filtered.P;
        assert!(kept.smoothed_covariance[1].trace() < 0.5 * first.trace());
    }

    /// A live refit keeps the smoothed covariances only where its next pass may spread a bounce
    /// at them: none while the ball is far above the table, and from a few steps before the
    /// first bounce once the window holds one; there they are the whole smoothing's, and the
    /// next pass is the same as with every covariance kept.
    #[test]
    fn a_refit_keeps_the_smoothed_covariances_a_bounce_may_read() {
        let config = keeping_detections();
        let mut early = served(&config, 0.3);
        early.pass_forward();
        let radius = early.flight.radius();
        assert_eq!(first_covariance_needed(&early.refit, radius), usize::MAX);
        smooth_back(&mut early.refit, usize::MAX);
        assert!(early.refit.smoothed.len() > 30);
        assert!(early.refit.smoothed_covariance.is_empty());

        let mut kept = served(&config, 0.5);
        kept.pass_forward();
        let first_bounce = kept
            .refit
            .steps
            .iter()
            .position(|s| s.bounces > 0)
            .expect("the window holds the bounce");
        let from = first_covariance_needed(&kept.refit, radius);
        assert!(from > 0 && from + COVARIANCE_STEPS_BEFORE_BOUNCE <= first_bounce);
        let mut every = kept.clone();
        smooth_back(&mut every.refit, 0);
        smooth_back(&mut kept.refit, from);
        assert_eq!(kept.refit.smoothed, every.refit.smoothed);
        assert_eq!(kept.refit.smoothed_covariance_at(from - 1), None);
        for at in from..every.refit.smoothed.len() {
            assert_eq!(
                kept.refit.smoothed_covariance_at(at),
                every.refit.smoothed_covariance_at(at),
                "{at}"
            );
        }
        kept.pass_forward();
        every.pass_forward();
        assert_eq!(kept.refit.steps.len(), every.refit.steps.len());
        for (a, b) in kept.refit.steps.iter().zip(&every.refit.steps) {
            assert_eq!((a.filtered, a.bounces), (b.filtered, b.bounces));
        }
    }

    /// The filter guards the spin along the flight (`ekf.spin_along_flight_gain`) only while no
    /// refit replaces its estimates: with the refits applied always its estimates are the plain
    /// update's; without refits, or while they have not won their contest, the guard's.
    #[test]
    fn the_spin_along_the_flight_is_guarded_only_while_no_refit_is_applied() {
        let run = |config: &Config| {
            let estimator = served(config, 0.3);
            let now = estimator.track.as_ref().unwrap().now;
            assert_eq!(now.bounces, 0);
            (estimator.guards_spin_along_flight(), now.ekf.x)
        };
        // Refits applied always (due after a second: none run here).
        let applied = keeping_detections();
        assert!(applied.ekf.spin_along_flight_gain < 1.0);
        let mut plain = applied.clone();
        plain.ekf.spin_along_flight_gain = 1.0;
        let mut without = applied.clone();
        without.ekf.refit_interval = 0.0;
        let mut contested = applied.clone();
        contested.ekf.refit_when_better = true;
        let (guarded, x_applied) = run(&applied);
        assert!(!guarded);
        assert_eq!(x_applied, run(&plain).1);
        let (guarded, x_without) = run(&without);
        assert!(guarded);
        assert!(
            (x_without - x_applied).norm() > 1.0,
            "{}",
            (x_without - x_applied).norm()
        );
        assert_eq!(run(&contested), (true, x_without));
        // Contested, but started where a won contest ended (`--learned`): applied at once.
        let mut won = contested.clone();
        won.ekf.refits_start_applied = true;
        assert_eq!(run(&won), (false, x_applied));
    }

    /// A node runs the ended track's lesson in its idle time ([`Estimator::learn_in_idle_time`]),
    /// a replay when the next track starts: every output and what is learned are the same to
    /// the bit, and the lesson is the smoothed flight's.
    #[test]
    fn a_lesson_learned_in_idle_time_is_the_lesson_learned_at_once() {
        let config = Config::default();
        assert!(config.adaptation.smoothed_lessons);
        let flight = serve(&config, 0.7);
        let two_s = 2_000_000_000;
        let stream: Vec<Detection> = (0..3)
            .flat_map(|k| {
                flight.iter().map(move |(d, _)| Detection {
                    stamp: d.stamp + k * two_s,
                    ..*d
                })
            })
            .collect();
        let (mut at_once, mut idle) = (Estimator::new(&config), Estimator::new(&config));
        let mut stages = 0;
        for d in &stream {
            assert_eq!(at_once.handle(d), idle.handle(d), "at {}", d.stamp);
            while idle.has_idle_work() {
                idle.learn_in_idle_time();
                stages += 1;
            }
        }
        at_once.end_of_input();
        idle.end_of_input();
        assert_eq!(at_once.learned_summary(), idle.learned_summary());
        assert_eq!(at_once.counters(), idle.counters());
        // Two tracks ended on the next flight's detections (their stages run in idle time),
        // the third at the input's end.
        assert_eq!(stages, 2 * LESSON_STAGES);
        assert!(!idle.has_idle_work() && !idle.learn_in_idle_time());
        assert_eq!(idle.counters().smoothed_lessons, 3);
        let mut filter_lessons = config.clone();
        filter_lessons.adaptation.smoothed_lessons = false;
        let mut filter = Estimator::new(&filter_lessons);
        for d in &stream {
            filter.handle(d);
        }
        filter.end_of_input();
        assert_eq!(filter.counters().smoothed_lessons, 0);
        assert_ne!(filter.learned_params(), idle.learned_params());
    }

    /// With a window of 16 detections the track is refitted through the whole flight, the
    /// window sliding along it (its oldest detections kept in the estimate it starts from), and
    /// the estimate stays on the flight.
    #[test]
    fn the_window_slides_along_the_flight() {
        let mut config = Config::default();
        config.ekf.refit_interval = 0.05;
        config.ekf.refit_when_better = false;
        config.ekf.refit_max_detections = 16;
        let mut estimator = Estimator::new(&config);
        let detections = serve(&config, 0.7);
        for (d, _) in &detections {
            estimator.handle(d);
            assert!(estimator.refit.observations.len() <= 2 * 16);
        }
        // Refits every 50 ms of the 0.7 s track, though 16 detections are 0.1 s of it.
        let refits = estimator.counters().refits;
        assert!(refits >= 10, "{refits} refits");
        let base = estimator.refit.base.unwrap();
        assert!(
            base.stamp > detections[60].0.stamp,
            "the window starts at {}",
            base.stamp
        );
        let (last, truth) = detections.last().unwrap();
        let now = &estimator.track.as_ref().unwrap().now;
        assert_eq!(now.stamp, last.stamp);
        let miss = (now.ekf.x.fixed_rows::<3>(0) - truth.position).norm();
        assert!(miss < 3e-3, "{miss} m off the flight");
    }

    /// A refit along a flight gone wild (a nominal whose spin and Magnus scale no flight has,
    /// or one that is not a number, as a nominal the filter's bounces refuted could become
    /// refit after refit) leaves the track on its flight: a pass that fails is not taken, and a
    /// smoothing that fails is dropped, so the next pass linearises at its own estimates.
    #[test]
    fn a_refit_along_a_wild_flight_leaves_the_track_on_its_flight() {
        let config = without_guards();
        let detections = serve(&config, 0.3);
        let (last, truth) = detections.last().unwrap();
        for wild in [1e6, f64::NAN] {
            let mut estimator = Estimator::new(&config);
            for (d, _) in &detections {
                estimator.handle(d);
            }
            estimator.pass_forward();
            smooth_back(&mut estimator.refit, 0);
            assert!(estimator.refit.smoothed.len() > 30);
            let reference = estimator.clone();
            for (_, y) in estimator.refit.smoothed.iter_mut() {
                y[7] = wild;
                y[10] = -50.0;
            }
            estimator.refit_now();
            let now = estimator.track.as_ref().unwrap().now;
            assert_eq!(now.stamp, last.stamp);
            assert!(now.ekf.P.iter().all(|v| v.is_finite()));
            let miss = (now.ekf.x.fixed_rows::<3>(0) - truth.position).norm();
            assert!(miss < 3e-3, "{wild}: {miss} m off the flight");
            if wild.is_nan() {
                // The smoothing of the wild pass failed: the passes after it are a refit's
                // from no smoothed flight, one fewer, the first of them the filter itself.
                let mut fresh = reference.clone();
                fresh.refit.smoothed.clear();
                for _ in 1..ITERATIONS {
                    fresh.pass_forward();
                    smooth_back(&mut fresh.refit, 0);
                }
                let expected = fresh.refit.steps.last().unwrap().filtered.x;
                assert!((now.ekf.x - expected).norm() < 1e-9 * expected.norm());
            }
            assert!(
                estimator
                    .refit
                    .smoothed
                    .iter()
                    .all(|(_, y)| y.iter().all(|v| v.is_finite()))
            );
        }
    }

    /// A pass linearised at its own estimates (no smoothed flight yet) is the filter itself
    /// without its guards against a misread spin (the whole gain on the spin along the flight,
    /// the coefficients at the estimate's spin): the same predictions and updates, the same
    /// estimates at every stamp the track holds. So whatever a refit changes, it changes by
    /// where it linearises and by those guards.
    #[test]
    fn a_pass_at_its_own_estimates_is_the_filter() {
        let config = without_guards();
        let mut estimator = served(&config, 0.4);
        assert_eq!(estimator.counters().refits, 0);
        let kept = estimator.refit.observations.len();
        assert!(kept > 40, "{kept} detections kept");
        estimator.pass_forward();
        let track = estimator.track.as_ref().unwrap();
        let mut compared = 0;
        for snapshot in track
            .history
            .iter()
            .map(|e| &e.after)
            .chain(std::iter::once(&track.now))
        {
            let step = estimator
                .refit
                .steps
                .iter()
                .find(|s| s.stamp == snapshot.stamp)
                .unwrap();
            let x = (step.filtered.x - snapshot.ekf.x).norm() / snapshot.ekf.x.norm();
            let p = (step.filtered.P - snapshot.ekf.P).norm() / snapshot.ekf.P.norm();
            assert!(x < 1e-9 && p < 1e-9, "at {}: {x:e} {p:e}", snapshot.stamp);
            compared += 1;
        }
        assert!(compared >= 5, "{compared} estimates compared");
    }
}
