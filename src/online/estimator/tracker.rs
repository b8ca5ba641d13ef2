//! The tracker: which detections are the ball and which track they belong to
//! (docs/estimator.md, "The tracker"): initialisation from [`INIT_DETECTIONS`] detections,
//! Mahalanobis gating, out-of-order fusion by rolling back over a bounded history, the table's
//! edge hypotheses ([`EDGE_MARGIN`]), a refuted track re-anchored ([`REANCHOR_DISTANCE`]),
//! stamp jumps held until confirmed, and the robot's announced hit seeding the return's track.
//! Every detection is accounted for in [`Counters`]; the buffers are allocated once.

use std::collections::VecDeque;

use super::adaptation::Adaptation;
use super::camera_noise::NoiseSample;
use super::counters::{Counters, Rejection, Verdict};
use super::fusion::{EDGE_MARGIN, Fused, Fusion, Innovation, Snapshot};
use super::smoother::{self, Flown, Lesson, LessonJob, ParamEstimate, TrackRecord};
use crate::config::Config;
use crate::model::detection::{Detection, seconds_to_ns};
use crate::model::stats::chi_square_quantile;
use crate::online::ekf::{Ekf, UpdateError};
use crate::online::initial_fit as init;
use crate::online::measurement::{Measurement, MeasurementModel, claims_placeholder_spin};
use crate::physics::params::{DRAG_SCALE, MAGNUS_SCALE};
use crate::physics::racket::{RacketModel, RacketState};
use crate::physics::{BallState, FlightModel, Propagator, StateVector};

/// How far [m] a track's first estimate may be from where a refuted track's estimate had flown
/// to for it to be the same ball re-anchored (a bounce mispredicted by 1 m/s is 5 cm off after
/// 50 ms).
pub const REANCHOR_DISTANCE: f64 = 0.2;

/// Detections fitted to start a track: position and velocity need 2, a third checks them, a
/// fourth tolerates one poor detection.
pub const INIT_DETECTIONS: usize = 4;

/// Most detections re-applied when an edge ball's bounce hypothesis is tried again: 9 ms of the
/// 900 fps camera.
const EDGE_RETRY_LIMIT: usize = 8;

/// The robot's own hit, announced to the estimator: when and with what racket state it meets
/// the ball (the answer of `plan_return`, or the robot controller's command), so that the return
/// flight is tracked from its first detection.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RobotHit {
    /// Stamp of the impact [ns].
    pub stamp: i64,
    /// The racket at the impact, in the table frame.
    pub racket: RacketState,
}

/// A fused detection and the estimate just after it.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Entry {
    detection: Detection,
    measurement: Measurement,
    after: Snapshot,
}

/// A live track.
#[derive(Debug, Clone)]
pub(crate) struct Track {
    pub(crate) id: u32,
    /// The newest estimate.
    pub(crate) now: Snapshot,
    /// The estimate just before the oldest history entry.
    base: Snapshot,
    history: VecDeque<Entry>,
    consecutive_rejections: u32,
    /// The physical parameters (and their covariance) the track started from.
    param_prior: ParamEstimate,
    /// Its first estimate, from which its lesson is smoothed.
    first: Snapshot,
    /// Its fused positions after the first estimate, for its lesson (a buffer allocated once,
    /// back to the adaptation when the track ends).
    record: TrackRecord,
    /// Whether its flight can be smoothed: positions alone, the record not outgrown.
    smoothable: bool,
    /// The sum of ln f(Re) over its fused estimates, and their number.
    log_f_sum: f64,
    fused: u32,
}

impl Track {
    /// What the track's filter has learned of the physics so far: its lesson if it ended now
    /// (`flight`, the tracker's, is the model it flies: its Reynolds exponents and numbers).
    pub(crate) fn filter_lesson(&self, flight: &FlightModel) -> Lesson {
        let log_f = if self.fused == 0 {
            flight.reynolds_log_factor(self.now.speed()).0
        } else {
            self.log_f_sum / f64::from(self.fused)
        };
        Lesson {
            prior: self.param_prior,
            posterior: (self.now.ekf.theta, self.now.ekf.param_covariance()),
            started: self.first.stamp,
            ended: self.now.stamp,
            smoothed: false,
            flown: Flown {
                exponents: flight.reynolds_exponents(),
                log_f,
            },
        }
    }

    /// Counts the speed of a fused estimate in the track's mean ln f(Re).
    fn note_speed(&mut self, after: &Snapshot, flight: &FlightModel) {
        self.log_f_sum += flight.reynolds_log_factor(after.speed()).0;
        self.fused += 1;
    }
}

/// A track refuted by a run of rejected detections: its id and its last estimate.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Continuation {
    id: u32,
    last: Snapshot,
}

/// The tracker's settings.
#[derive(Debug, Clone, PartialEq)]
struct Settings {
    gate_probability: f64,
    max_rejections: u32,
    timeout: i64,
    rollback: i64,
    history_capacity: usize,
    /// Whether tracks keep their detections for a lesson (with the adaptation on).
    lessons: bool,
}

impl Settings {
    fn new(config: &Config) -> Self {
        Self {
            gate_probability: config.gating.probability,
            max_rejections: config.gating.max_consecutive_rejections.max(1),
            timeout: seconds_to_ns(config.tracking.timeout),
            rollback: seconds_to_ns(config.tracking.rollback_window),
            // 900 + 150 detections per second over the rollback window, with a wide margin.
            history_capacity: ((config.tracking.rollback_window * 2000.0).ceil() as usize)
                .clamp(16, 4096),
            lessons: config.adaptation.enabled,
        }
    }

    /// The most detections kept waiting to initialise a track.
    fn pending_limit(&self) -> usize {
        INIT_DETECTIONS.max(self.max_rejections as usize) + 8
    }

    /// The most rejected detections kept to seed a new track.
    fn rejected_run_limit(&self) -> usize {
        self.max_rejections as usize + 1
    }
}

/// A ball on the robot's half, moving toward the robot and rising, has bounced there already
/// (an incoming ball falls from the net to its bounce).
fn already_bounced(x: &StateVector) -> bool {
    x[0] < 0.0 && x[3] < 0.0 && x[5] > 0.0
}

/// A refuted estimate `before` had the ball falling where the ball, started again at `x`, rises:
/// it bounced where the estimate had it miss the table (on its edge). Near the top of a flight
/// the two may differ in sign without a bounce.
fn missed_a_bounce(before: &StateVector, x: &StateVector) -> bool {
    /// The vertical speed [m/s] beyond which falling and rising are told apart.
    const TURNING: f64 = 0.3;
    before[5] < -TURNING && x[5] > TURNING
}

/// Two detections of the same camera frame: a duplicate.
fn same_frame(a: &Detection, b: &Detection) -> bool {
    a.stamp == b.stamp && a.source == b.source
}

/// The tracker (see the module doc).
#[derive(Debug, Clone)]
pub(crate) struct Tracker {
    settings: Settings,
    /// How a detection moves an estimate.
    pub(crate) fusion: Fusion,
    /// How a detection becomes a measurement.
    pub(crate) measurement: MeasurementModel,
    /// The flight model at the configured parameters and the learned Reynolds exponents (the
    /// initial fit's).
    pub(crate) flight: FlightModel,
    /// The propagator with the table grown and shrunk by [`EDGE_MARGIN`].
    edge_alternatives: [Propagator; 2],
    /// The racket-impact model, for the robot's announced hits.
    racket: RacketModel,
    pub(crate) track: Option<Track>,
    /// Detections of a ball being initialised, sorted by stamp.
    pub(crate) pending: Vec<Detection>,
    /// The latest run of rejected detections, to seed a new track.
    rejected_run: VecDeque<Detection>,
    /// A detection that jumped more than `tracking.timeout` off the current stamps.
    held: Option<(Detection, Measurement)>,
    /// A track just refuted by a run of rejected detections.
    continuation: Option<Continuation>,
    /// The robot's next hit, and the rebound predicted from it at the first detection after it.
    expected_hit: Option<(RobotHit, Option<Snapshot>)>,
    pub(crate) next_track_id: u32,
    pub(crate) counters: Counters,
    /// The history buffer of the next track, allocated once.
    spare_history: VecDeque<Entry>,
}

impl Tracker {
    /// A tracker with `config`'s settings, its tracks fused by `fusion`.
    pub(crate) fn new(config: &Config, fusion: Fusion) -> Self {
        let settings = Settings::new(config);
        let propagator = fusion.propagator;
        Self {
            fusion,
            measurement: MeasurementModel::new(config),
            flight: FlightModel::new(config),
            edge_alternatives: [EDGE_MARGIN, -EDGE_MARGIN].map(|m| propagator.with_edge_margin(m)),
            racket: RacketModel::new(config),
            track: None,
            pending: Vec::with_capacity(settings.pending_limit()),
            rejected_run: VecDeque::with_capacity(settings.rejected_run_limit()),
            held: None,
            continuation: None,
            expected_hit: None,
            next_track_id: 1,
            counters: Counters::default(),
            spare_history: VecDeque::with_capacity(settings.history_capacity),
            settings,
        }
    }

    /// Takes `config`'s tracking, gating and measurement settings and `fusion` (the physics
    /// the tracks fly), keeping the live track.
    pub(crate) fn reconfigure(&mut self, config: &Config, fusion: Fusion) {
        let settings = Settings::new(config);
        if settings.history_capacity != self.settings.history_capacity {
            self.spare_history = VecDeque::with_capacity(settings.history_capacity);
        }
        self.settings = settings;
        self.fusion = fusion;
        self.measurement = MeasurementModel::new(config);
        self.racket = RacketModel::new(config);
    }

    /// True while a detection whose stamp jumped is held.
    pub(crate) fn holds_a_jump(&self) -> bool {
        self.held.is_some()
    }

    /// Announces the robot's next hit (see [`super::Estimator::expect_hit`]).
    pub(crate) fn expect_hit(&mut self, hit: RobotHit) {
        if self.expected_hit.is_some() {
            self.counters.hits_not_seeded += 1;
        }
        self.expected_hit = Some((hit, None));
    }

    /// Takes one detection (in arrival order); says what became of it (see the module doc).
    pub(crate) fn update(&mut self, d: &Detection, adaptation: &mut Adaptation) -> Verdict {
        self.counters.received += 1;
        if claims_placeholder_spin(d) {
            self.counters.zero_spin_ignored += 1;
        }
        let verdict = match self.measurement(d, adaptation) {
            Err(reason) => Verdict::Rejected(reason),
            Ok(measurement) => self.screen_jump(d, measurement, adaptation),
        };
        self.count(verdict);
        verdict
    }

    fn count(&mut self, verdict: Verdict) {
        match verdict {
            Verdict::Fused { .. } => self.counters.fused += 1,
            Verdict::Initializing | Verdict::Held => self.counters.initializing += 1,
            Verdict::Rejected(reason) => self.counters.rejected[reason.index()] += 1,
        }
    }

    /// A detection as a measurement with its noise as learned of its source.
    fn measurement(
        &self,
        d: &Detection,
        adaptation: &Adaptation,
    ) -> Result<Measurement, Rejection> {
        let source = self.measurement.source_index(d.source);
        Ok(self
            .measurement
            .measure(d)?
            .with_learned_noise(&adaptation.cameras.of(source)))
    }

    /// Teaches the camera-noise learner what a detection's prior `innovation` shows.
    fn learn_noise(
        &self,
        d: &Detection,
        innovation: Option<Innovation>,
        adaptation: &mut Adaptation,
    ) {
        let (Some(innovation), Ok(base)) = (innovation, self.measurement.measure(d)) else {
            return;
        };
        let (r0, spin_r0) = match base {
            Measurement::Position { r, .. } => (r, None),
            Measurement::PositionSpin { r, .. } => (
                r.fixed_view::<3, 3>(0, 0).into_owned(),
                Some(r.fixed_view::<3, 3>(3, 3).into_owned()),
            ),
        };
        let sample = NoiseSample {
            innovation,
            r0,
            spin_r0,
        };
        adaptation
            .cameras
            .learn(self.measurement.source_index(d.source), &sample);
    }

    /// The stamp the current detections run on: the track's last fused one, else the newest
    /// detection initialising one.
    fn current_stamp(&self) -> Option<i64> {
        match &self.track {
            Some(track) => Some(track.now.last_fused),
            None => self.pending.last().map(|p| p.stamp),
        }
    }

    /// Re-counts a held detection (counted as initialising when it was held) with its verdict.
    fn recount_held(&mut self, verdict: Verdict) {
        if !matches!(verdict, Verdict::Initializing | Verdict::Held) {
            self.counters.initializing = self.counters.initializing.saturating_sub(1);
            self.count(verdict);
        }
    }

    /// Holds, confirms or dismisses a jump in the stamps (see the module doc).
    fn screen_jump(
        &mut self,
        d: &Detection,
        m: Measurement,
        adaptation: &mut Adaptation,
    ) -> Verdict {
        let Some(current) = self.current_stamp() else {
            return self.process(d, m, adaptation);
        };
        let timeout = self.settings.timeout;
        // Either way: a camera whose clock restarted sends stamps from long ago, for good.
        if (d.stamp - current).abs() <= timeout {
            if d.stamp > current && self.held.take().is_some() {
                self.recount_held(Verdict::Rejected(Rejection::StampJump));
            }
            return self.process(d, m, adaptation);
        }
        match self.held.take() {
            Some((first, first_m))
                if (d.stamp - first.stamp).abs() <= timeout && !same_frame(&first, d) =>
            {
                // Confirmed: a new timeline starts with both detections.
                self.end_track(d.stamp, adaptation);
                let first_verdict = self.process(&first, first_m, adaptation);
                self.recount_held(first_verdict);
                self.process(d, m, adaptation)
            }
            superseded => {
                if superseded.is_some() {
                    self.recount_held(Verdict::Rejected(Rejection::StampJump));
                }
                self.held = Some((*d, m));
                Verdict::Held
            }
        }
    }

    fn process(&mut self, d: &Detection, m: Measurement, adaptation: &mut Adaptation) -> Verdict {
        if let Some((hit, _)) = self.expected_hit
            && d.stamp > hit.stamp
        {
            if let Some(verdict) = self.start_from_hit(&hit, d, m, adaptation) {
                self.expected_hit = None;
                return verdict;
            }
            if d.stamp - hit.stamp > self.settings.timeout {
                self.expected_hit = None;
                self.counters.hits_not_seeded += 1;
            }
        }
        let Some(track) = &self.track else {
            return self.initialise(d, adaptation);
        };
        if d.stamp - track.now.last_fused > self.settings.timeout {
            self.end_track(d.stamp, adaptation);
            return self.initialise(d, adaptation);
        }
        match self.fuse_into_track(d, m, adaptation) {
            Ok(nis) => {
                if let Some(track) = self.track.as_mut() {
                    track.consecutive_rejections = 0;
                }
                self.rejected_run.clear();
                Verdict::Fused { nis }
            }
            Err(Rejection::Gated) => self.count_gated(d, adaptation),
            Err(reason) => Verdict::Rejected(reason),
        }
    }

    /// A gated detection; a run of them ends the track and seeds a new one.
    fn count_gated(&mut self, d: &Detection, adaptation: &mut Adaptation) -> Verdict {
        if self.rejected_run.len() >= self.settings.rejected_run_limit() {
            self.rejected_run.pop_front();
        }
        self.rejected_run.push_back(*d);
        let Some(track) = self.track.as_mut() else {
            return Verdict::Rejected(Rejection::Gated);
        };
        track.consecutive_rejections += 1;
        if track.consecutive_rejections >= self.settings.max_rejections {
            let refuted = Continuation {
                id: track.id,
                last: track.now,
            };
            self.end_track(d.stamp, adaptation);
            // The rejected run is the ball after a racket hit or a new serve, or the same ball
            // where its prediction was refuted (most often at a bounce): the track it starts
            // keeps the refuted one's id if it is the same ball ([`Self::continues`]).
            self.continuation = Some(refuted);
            while let Some(seed) = self.rejected_run.pop_front() {
                self.insert_pending(&seed);
            }
            if self.pending.len() >= INIT_DETECTIONS {
                self.try_start_track(adaptation);
            }
        }
        Verdict::Rejected(Rejection::Gated)
    }

    /// Ends the live track at the detection stamped `now`: what it learned goes to the
    /// adaptation (its flight to smooth where it can be, else the filter's estimate).
    pub(crate) fn end_track(&mut self, now: i64, adaptation: &mut Adaptation) {
        self.continuation = None;
        self.pending.clear();
        let Some(mut track) = self.track.take() else {
            return;
        };
        let filter = track.filter_lesson(&self.flight);
        let mut record = std::mem::take(&mut track.record);
        let ended = if track.smoothable && record.observations.len() >= smoother::MIN_DETECTIONS {
            record.recent_bounces.extend(
                std::iter::once(&track.base)
                    .chain(track.history.iter().map(|e| &e.after))
                    .chain(std::iter::once(&track.now))
                    .map(|s| (s.stamp, s.bounces)),
            );
            Ok(LessonJob {
                fusion: self.fusion,
                base: track.first,
                record,
                filter,
            })
        } else {
            adaptation.lessons.recycle(record);
            Err(filter)
        };
        adaptation.track_ended(ended, now);
        // Keep the history's buffer for the next track: no allocation per track.
        self.spare_history = track.history;
        self.spare_history.clear();
    }

    fn insert_pending(&mut self, d: &Detection) {
        if self.pending.len() >= self.settings.pending_limit() {
            self.pending.remove(0);
        }
        let index = self.pending.partition_point(|p| p.stamp <= d.stamp);
        self.pending.insert(index, *d);
        // Keep only the detections within `tracking.timeout` of the newest.
        let newest = self.pending.last().map_or(d.stamp, |p| p.stamp);
        let span = self.settings.timeout;
        self.pending.retain(|p| newest - p.stamp <= span);
    }

    fn initialise(&mut self, d: &Detection, adaptation: &mut Adaptation) -> Verdict {
        if self.pending.iter().any(|p| same_frame(p, d)) {
            return Verdict::Rejected(Rejection::Duplicate);
        }
        self.insert_pending(d);
        if self.pending.len() >= INIT_DETECTIONS && !self.try_start_track(adaptation) {
            // Inconsistent: drop the worst-fitting detection and wait for more.
            if let Some(fit) = self.fit_pending(adaptation) {
                self.pending.remove(fit.worst);
                self.counters.rejected[Rejection::InitOutlier.index()] += 1;
                self.counters.initializing = self.counters.initializing.saturating_sub(1);
            }
        }
        Verdict::Initializing
    }

    /// The fit of the detections waiting to start a track, flown with the learned drag and
    /// Magnus scales.
    pub(crate) fn fit_pending(&self, adaptation: &Adaptation) -> Option<init::InitialFit> {
        // A rough speed from the first and last pending detections, for the timing noise.
        let (first, last) = (self.pending.first()?, self.pending.last()?);
        if first.stamp == last.stamp {
            return None;
        }
        let span = (last.stamp - first.stamp) as f64 * 1e-9;
        let speed_sq = ((last.position - first.position) / span).norm_squared();
        let weights = |d: &Detection| {
            let m = self.measurement(d, adaptation).ok()?;
            Some(match m {
                Measurement::Position { r, timing, .. } => init::Weights {
                    position_var: r.diagonal().add_scalar(timing * speed_sq),
                    spin: None,
                },
                Measurement::PositionSpin { z, r, timing } => init::Weights {
                    position_var: r
                        .fixed_view::<3, 3>(0, 0)
                        .diagonal()
                        .add_scalar(timing * speed_sq),
                    spin: Some((
                        z.fixed_rows::<3>(3).into_owned(),
                        r.fixed_view::<3, 3>(3, 3).diagonal(),
                    )),
                },
            })
        };
        let theta = adaptation.physics.global().0;
        init::fit(
            &self.pending,
            &weights,
            &self
                .flight
                .with_scales(theta[DRAG_SCALE], theta[MAGNUS_SCALE])
                .with_reynolds_exponents(adaptation.physics.exponents()),
            self.flight.gravity(),
            self.fusion.spin_prior_var,
        )
    }

    /// Starts a track from the pending detections when they fit one ballistic flight.
    fn try_start_track(&mut self, adaptation: &mut Adaptation) -> bool {
        let Some(fit) = self.fit_pending(adaptation) else {
            return false;
        };
        let gate = chi_square_quantile(self.settings.gate_probability, fit.dof.max(1));
        let speed = fit.x.fixed_rows::<3>(3).norm();
        if fit.chi_square > gate || speed > 40.0 {
            return false;
        }
        let param_prior = adaptation.physics.track_prior(fit.stamp);
        let (theta, p_theta) = param_prior;
        let mut snapshot = Snapshot::starting(
            Ekf::new(fit.x, fit.P, theta, p_theta),
            fit.stamp,
            fit.spin_measured,
        );
        snapshot.robot_half_bounces = u32::from(already_bounced(&fit.x));
        let first_seen = self.pending.first().map_or(fit.stamp, |d| d.stamp);
        let continued = self
            .continuation
            .take()
            .and_then(|c| self.continues(&c, &fit.x, fit.stamp, first_seen));
        let id = match continued {
            Some((id, before, missed)) => {
                // The same ball: its id, and the bounces it has made.
                let missed = u32::from(missed);
                snapshot.bounces = before.bounces + missed;
                snapshot.robot_half_bounces = (before.robot_half_bounces
                    + missed * u32::from(fit.x[0] < 0.0))
                .max(snapshot.robot_half_bounces);
                self.counters.reanchored += 1;
                id
            }
            None => self.new_track_id(),
        };
        self.start(id, snapshot, snapshot, param_prior, adaptation);
        self.pending.clear();
        true
    }

    /// Flies the tracks from now on with the Reynolds exponents `exponents` (the learned ones);
    /// called only as a track starts, so the live track's exponents are the tracker's.
    fn fly_with(&mut self, exponents: [f64; 2]) {
        if self.fusion.propagator.flight().reynolds_exponents() == exponents {
            return;
        }
        self.fusion.propagator = self.fusion.propagator.with_reynolds_exponents(exponents);
        self.edge_alternatives = self
            .edge_alternatives
            .map(|p| p.with_reynolds_exponents(exponents));
        self.flight = self.flight.with_reynolds_exponents(exponents);
    }

    /// A new track's id.
    fn new_track_id(&mut self) -> u32 {
        let id = self.next_track_id;
        self.next_track_id = self.next_track_id.wrapping_add(1).max(1);
        self.counters.tracks += 1;
        id
    }

    /// Starts track `id` at `now`, from its first estimate `first`.
    fn start(
        &mut self,
        id: u32,
        first: Snapshot,
        now: Snapshot,
        param_prior: ParamEstimate,
        adaptation: &mut Adaptation,
    ) {
        let smoothable = self.settings.lessons && !first.spin_measured;
        let record = if smoothable {
            adaptation.lessons.buffer()
        } else {
            TrackRecord::default()
        };
        self.fly_with(adaptation.physics.exponents());
        self.track = Some(Track {
            id,
            now,
            base: first,
            history: std::mem::take(&mut self.spare_history),
            consecutive_rejections: 0,
            param_prior,
            first,
            record,
            smoothable,
            log_f_sum: 0.0,
            fused: 0,
        });
    }

    /// Starts the return's track at `d`, a detection after the announced `hit`, from the
    /// predicted rebound of the live track's ball (predicted at the first detection after the
    /// impact, then kept); None (nothing changed but the kept rebound) when there was no live
    /// track before the impact, the hit is impossible or `d` is gated against the rebound.
    fn start_from_hit(
        &mut self,
        hit: &RobotHit,
        d: &Detection,
        m: Measurement,
        adaptation: &mut Adaptation,
    ) -> Option<Verdict> {
        let seed = match self.expected_hit.and_then(|(_, seed)| seed) {
            Some(seed) => seed,
            None => {
                let seed = self.rebound_seed(hit, adaptation)?;
                self.expected_hit = Some((*hit, Some(seed)));
                seed
            }
        };
        let mut snapshot = seed;
        let outcome = self
            .fusion
            .fuse(&self.fusion.propagator, &mut snapshot, d.stamp, &m);
        let nis = outcome.fused.ok()?.nis;
        self.learn_noise(d, outcome.innovation, adaptation);
        self.end_track(d.stamp, adaptation);
        let id = self.new_track_id();
        self.counters.seeded_by_hit += 1;
        let param_prior = adaptation.physics.track_prior(hit.stamp);
        self.start(id, seed, snapshot, param_prior, adaptation);
        self.push_entry(Entry {
            detection: *d,
            measurement: m,
            after: snapshot,
        });
        self.keep_for_lesson(d, &m);
        self.rejected_run.clear();
        Some(Verdict::Fused { nis })
    }

    /// The predicted rebound of the live track's ball at the announced `hit`, with its
    /// covariance; None when there is no live track before the impact or the hit is impossible.
    fn rebound_seed(&self, hit: &RobotHit, adaptation: &Adaptation) -> Option<Snapshot> {
        let track = self.track.as_ref()?;
        if track.now.stamp > hit.stamp {
            return None;
        }
        let mut incoming = track.now;
        self.fusion.advance(&mut incoming, hit.stamp);
        let ball = BallState::from_vector(&incoming.ekf.x);
        let after = self.racket.hit(&ball, &hit.racket).ok()?.ball;
        let covariance =
            self.racket
                .rebound_covariance(&ball, &incoming.ekf.state_covariance(), &hit.racket)?;
        let (theta, p_theta) = adaptation.physics.track_prior(hit.stamp);
        Some(Snapshot::starting(
            Ekf::new(after.to_vector(), covariance, theta, p_theta),
            hit.stamp,
            false,
        ))
    }

    /// Whether a track starting at `stamp` in state `x`, fitted to detections from
    /// `first_seen` on, is the ball of the refuted track `c`: seen again within
    /// `tracking.timeout` of its last fused detection, within [`REANCHOR_DISTANCE`] of where
    /// its estimate had flown to (horizontally, where it missed a bounce), and moving the same
    /// way along the table (a racket hit turns the ball around). Then its id and the estimate it
    /// had flown to, and whether it missed a bounce.
    fn continues(
        &self,
        c: &Continuation,
        x: &StateVector,
        stamp: i64,
        first_seen: i64,
    ) -> Option<(u32, Snapshot, bool)> {
        if first_seen - c.last.last_fused > self.settings.timeout || stamp < c.last.stamp {
            return None;
        }
        let mut flown = c.last;
        self.fusion.advance(&mut flown, stamp);
        // A bounce the estimate missed turned the ball's vertical motion around, not its path
        // over the table: then only the horizontal distance tells.
        let missed = missed_a_bounce(&flown.ekf.x, x);
        let dimensions = if missed { 2 } else { 3 };
        let apart = (flown.ekf.x.rows(0, dimensions) - x.rows(0, dimensions)).norm();
        (apart <= REANCHOR_DISTANCE && flown.ekf.x[3] * x[3] > 0.0).then_some((c.id, flown, missed))
    }

    /// Keeps the fused detection `d` (measured as `m`) in the live track's record for its
    /// lesson: positions only (a measured spin teaches directly), newer than the first estimate
    /// (an older, late one is in it only as the filter fused it), while the record has room.
    fn keep_for_lesson(&mut self, d: &Detection, m: &Measurement) {
        let Some(track) = self.track.as_mut() else {
            return;
        };
        let record = &mut track.record;
        let full = record.observations.len() >= smoother::MAX_DETECTIONS;
        if matches!(m, Measurement::PositionSpin { .. }) || full {
            track.smoothable = false;
        }
        if track.smoothable && d.stamp > track.first.stamp {
            let at = record.observations.partition_point(|(k, _)| *k <= d.stamp);
            record.observations.insert(at, (d.stamp, *m));
        }
    }

    /// Fuses a detection into the live track at its place in the history: the newest appended
    /// (an edge ball's bounce hypotheses tried again when it is gated); an older one (the
    /// cameras' latencies differ) by rolling back to the estimate before its stamp and
    /// re-applying the newer ones, when it is within `tracking.rollback_window`.
    fn fuse_into_track(
        &mut self,
        d: &Detection,
        m: Measurement,
        adaptation: &mut Adaptation,
    ) -> Result<f64, Rejection> {
        let Some(track) = &self.track else {
            return Err(Rejection::TooOld);
        };
        let late = d.stamp < track.now.stamp;
        if late
            && (track.now.stamp - d.stamp > self.settings.rollback || d.stamp < track.base.stamp)
        {
            return Err(Rejection::TooOld);
        }
        if track.history.iter().any(|e| same_frame(&e.detection, d)) {
            return Err(Rejection::Duplicate);
        }
        let index = track
            .history
            .partition_point(|e| e.detection.stamp <= d.stamp);
        let mut snapshot = match index {
            _ if !late => track.now,
            0 => track.base,
            i => track.history[i - 1].after,
        };
        let (mut result, innovation) = self.fuse(&mut snapshot, d, &m);
        if !late
            && result == Err(Rejection::Gated)
            && let Some((retried, nis)) = self.retry_edge_bounce(d, &m)
        {
            snapshot = retried;
            result = Ok(nis);
        }
        self.learn_noise(d, innovation, adaptation);
        let nis = result?;
        let entry = Entry {
            detection: *d,
            measurement: m,
            after: snapshot,
        };
        if late {
            self.insert_late(index, entry);
        } else {
            self.push_entry(entry);
        }
        self.keep_for_lesson(d, &m);
        Ok(nis)
    }

    /// Fuses a detection into a snapshot at its stamp, with the table's edge hypotheses where
    /// the ball is low over the edge; returns its NIS and its prior innovation.
    fn fuse(
        &mut self,
        snapshot: &mut Snapshot,
        d: &Detection,
        m: &Measurement,
    ) -> (Result<f64, Rejection>, Option<Innovation>) {
        let prior = *snapshot;
        let outcome = self
            .fusion
            .fuse(&self.fusion.propagator, snapshot, d.stamp, m);
        self.counters.spin_resets += u64::from(outcome.spin_reset);
        let mut result = outcome.fused;
        if self.near_table_edge(snapshot) || self.lands_near_table_edge(&prior, d.stamp) {
            // An edge ball: estimate and ball may land on either side of the table's edge. The
            // hypothesis that explains the detection best wins.
            for alternative in &self.edge_alternatives {
                let mut other = prior;
                let tried = self.fusion.fuse(alternative, &mut other, d.stamp, m);
                self.counters.spin_resets += u64::from(tried.spin_reset);
                let Ok(fused) = tried.fused else {
                    continue;
                };
                let better = match &result {
                    Ok(current) => {
                        fused.whole_nis < current.whole_nis && other.bounces != snapshot.bounces
                    }
                    Err(_) => true,
                };
                if better {
                    *snapshot = other;
                    self.counters.edge_retries += 1;
                    result = Ok(fused);
                }
            }
        }
        let result = match result {
            Ok(fused) => Ok(fused.nis),
            Err(UpdateError::Gated { .. }) => Err(Rejection::Gated),
            Err(UpdateError::NotFinite) => Err(Rejection::NonFinite),
            Err(UpdateError::NotPositiveDefinite) => Err(Rejection::BadCovariance),
        };
        (result, outcome.innovation)
    }

    /// True when the estimate is low over the table's edge, where a bounce is a close call.
    fn near_table_edge(&self, snapshot: &Snapshot) -> bool {
        let x = &snapshot.ekf.x;
        let outside = self.fusion.propagator.distance_outside_table(x[0], x[1]);
        x[2] < 0.1 && outside.abs() < EDGE_MARGIN
    }

    /// True when the estimate, low and falling, comes down to the table's height within
    /// [`EDGE_MARGIN`] of its edge before `stamp` (in a vacuum, to first order: where it would
    /// bounce). A ball that crosses a side edge fast is outside the margin at both ends of a
    /// step: 4.5 m/s sideways is 3 cm in one 150 fps frame interval.
    fn lands_near_table_edge(&self, snapshot: &Snapshot, stamp: i64) -> bool {
        let x = &snapshot.ekf.x;
        let dt = (stamp - snapshot.stamp) as f64 * 1e-9;
        let height = x[2] - self.flight.radius();
        let (vz, g) = (x[5], self.flight.gravity());
        if dt <= 0.0 || x[2] >= 0.1 || height < 0.0 || vz >= 0.0 || g <= 0.0 {
            return false;
        }
        // height + vz t - g t^2 / 2 = 0, the later root.
        let t = (vz + (vz * vz + 2.0 * g * height).sqrt()) / g;
        t <= dt
            && self
                .fusion
                .propagator
                .distance_outside_table(x[0] + x[3] * t, x[1] + x[4] * t)
                .abs()
                < EDGE_MARGIN
    }

    /// An edge ball whose kept bounce hypothesis fails a detection: the other hypotheses are
    /// tried again from before the ball came down to the table, every detection since re-applied
    /// with the table grown and shrunk by [`EDGE_MARGIN`]. The first detection after a bounce may
    /// come too soon after it to tell landing on the table from passing beside it (0.3 ms at
    /// 900 fps). Taken when the newest detection fuses and the detections re-applied fit better
    /// (lower NIS of their whole measurements in sum) than they did; the history is rewritten
    /// with it. Returns the estimate at `d` and its NIS.
    fn retry_edge_bounce(&mut self, d: &Detection, m: &Measurement) -> Option<(Snapshot, f64)> {
        let track = self.track.as_ref()?;
        if !self.near_table_edge(&track.now) {
            return None;
        }
        // From the last entry before the latest bounce, or, with no bounce since the history
        // starts, before the ball came down to the table's height.
        let contact = self.flight.radius();
        let history = &track.history;
        let before = history
            .iter()
            .rev()
            .map(|e| e.after.bounces)
            .find(|&b| b < track.now.bounces)
            .unwrap_or(track.now.bounces);
        let from = history
            .iter()
            .rposition(|e| e.after.bounces == before && e.after.ekf.x[2] > contact)?;
        let again = history.len() - from - 1;
        if again == 0 || again > EDGE_RETRY_LIMIT {
            return None;
        }
        let kept: f64 = history
            .iter()
            .skip(from + 1)
            .map(|e| e.after.whole_nis)
            .sum();
        let mut best: Option<([Snapshot; EDGE_RETRY_LIMIT], Snapshot, f64, f64)> = None;
        for alternative in &self.edge_alternatives {
            let mut snapshot = history[from].after;
            let mut afters = [snapshot; EDGE_RETRY_LIMIT];
            let mut total = 0.0;
            for (slot, entry) in afters.iter_mut().zip(history.iter().skip(from + 1)) {
                total += match self.reapply(
                    alternative,
                    &mut snapshot,
                    &entry.detection,
                    &entry.measurement,
                ) {
                    Some(f) => f.whole_nis,
                    // A detection the hypothesis cannot explain counts as at the gate.
                    None => self.whole_gate(&entry.measurement),
                };
                *slot = snapshot;
            }
            let Some(fused) = self.reapply(alternative, &mut snapshot, d, m) else {
                continue;
            };
            if total < kept && best.as_ref().is_none_or(|b| total < b.3) {
                best = Some((afters, snapshot, fused.nis, total));
            }
        }
        let (afters, snapshot, nis, _) = best?;
        let track = self.track.as_mut()?;
        for (entry, after) in track.history.iter_mut().skip(from + 1).zip(afters) {
            entry.after = after;
        }
        self.counters.edge_retries += 1;
        Some((snapshot, nis))
    }

    /// A detection re-applied to a hypothesis's snapshot (its table given by `propagator`):
    /// the snapshot moved to its stamp and, where it fits, updated with it.
    fn reapply(
        &self,
        propagator: &Propagator,
        snapshot: &mut Snapshot,
        d: &Detection,
        m: &Measurement,
    ) -> Option<Fused> {
        self.fusion
            .fuse(propagator, snapshot, d.stamp, m)
            .fused
            .ok()
    }

    /// The gate of a measurement's every dimension: what a detection a hypothesis cannot
    /// explain counts as when hypotheses are compared.
    fn whole_gate(&self, m: &Measurement) -> f64 {
        match m {
            Measurement::Position { .. } => self.fusion.gate_position,
            Measurement::PositionSpin { .. } => self.fusion.gate_position_spin,
        }
    }

    /// Inserts a late detection's `entry` at `index` of the history, re-applying the newer
    /// detections after it (one no longer in the gate is skipped).
    fn insert_late(&mut self, index: usize, entry: Entry) {
        let mut snapshot = entry.after;
        let Some(mut track) = self.track.take() else {
            return;
        };
        for entry in track.history.iter_mut().skip(index) {
            // A re-applied detection that no longer passes the gate is skipped.
            let mut next = snapshot;
            if self
                .fuse(&mut next, &entry.detection, &entry.measurement)
                .0
                .is_ok()
            {
                snapshot = next;
            } else {
                self.fusion.advance(&mut snapshot, entry.detection.stamp);
            }
            entry.after = snapshot;
        }
        let mut index = index;
        if track.history.len() >= self.settings.history_capacity
            && let Some(oldest) = track.history.pop_front()
        {
            track.base = oldest.after;
            index = index.saturating_sub(1);
        }
        track.history.insert(index, entry);
        track.now = snapshot;
        track.note_speed(&snapshot, &self.flight);
        self.track = Some(track);
        self.counters.rollbacks += 1;
    }

    /// Appends the newest fused detection to the history, dropping what is older than the
    /// rollback window.
    fn push_entry(&mut self, entry: Entry) {
        let rollback = self.settings.rollback;
        let capacity = self.settings.history_capacity;
        let Some(track) = self.track.as_mut() else {
            return;
        };
        track.note_speed(&entry.after, &self.flight);
        track.now = entry.after;
        while track.history.len() >= capacity
            || track
                .history
                .front()
                .is_some_and(|e| e.detection.stamp < entry.after.stamp - rollback)
        {
            let Some(oldest) = track.history.pop_front() else {
                break;
            };
            track.base = oldest.after;
        }
        track.history.push_back(entry);
    }
}
