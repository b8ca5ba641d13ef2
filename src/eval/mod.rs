//! Accuracy of the estimator on a simulated session, against the simulator's truth: the numbers
//! of the accuracy tables (README.md, docs/accuracy.md).
//!
//! The session's detections go through [`Estimator::handle`] in arrival order, exactly as the
//! node would see them. Reported, over the shots:
//! - velocity and spin error after 100 ms of track (spin split into the part perpendicular to
//!   the velocity, the only part observable from the flight's curvature, and the part along it);
//! - velocity and spin error where the 900 fps camera sees the ball (its estimates after its
//!   first 10 ms);
//! - interception position (in the plane) and time error at leads of 300, 200 and 100 ms before
//!   the true crossing, and the fraction of shots with a valid prediction at each lead;
//! - NEES per dimension of the state (9 dimensions) and of the interception position (2).
//!
//! Estimates within [`BOUNCE_WINDOW`] of the true bounce are scored on their own.

use nalgebra::{Vector2, Vector3};

use crate::config::Config;
use crate::eval::sim::Session;
use crate::model::detection::{Detection, Source, seconds_to_ns};
use crate::model::stats::ErrorStats;
use crate::offline::batch::{FittedState, fit_whole_flight};
use crate::online::ekf::BounceNoise;
use crate::online::estimator::{
    Counters, Estimate, Estimator, LearnedParams, Output, Rejection, TrackStatus, Verdict,
};
use crate::online::intercept::{InterceptQuery, predict_intercept};
use crate::physics::{BallState, PhysicsParams, Propagator};

pub mod real;
pub mod sets;
pub mod sim;

/// The leads before the true crossing at which interceptions are scored [s].
pub const LEADS: [f64; 3] = [0.3, 0.2, 0.1];
/// Track age at which velocity and spin are scored [s].
pub const TRACK_AGE: f64 = 0.1;
/// Time the 900 fps camera must have seen the ball before its spin errors count [s].
pub const HIGH_SPEED_SETTLE: f64 = 0.01;
/// Estimates this close to the true bounce [s] are scored apart: a bounce-time mismatch of a
/// tenth of a millisecond (0.3 mm of height) puts one of estimate and truth before the bounce
/// and the other after it, a velocity error of twice the vertical speed for that instant.
pub const BOUNCE_WINDOW: f64 = 0.002;
/// A good detection gated this soon after the true bounce [s] counts against the bounce
/// model's uncertainty ([`EvalReport::gated_after_bounce_shots`]).
pub const AFTER_BOUNCE: f64 = 0.05;

/// Interception accuracy at one lead.
#[derive(Debug, Clone, Copy, PartialEq, Default, serde::Serialize)]
pub struct LeadReport {
    /// Time before the true crossing [s].
    pub lead: f64,
    /// Shots scored.
    pub shots: usize,
    /// Fraction of them with a valid prediction [-].
    pub valid_fraction: f64,
    /// Distance in the plane between predicted and true crossing points [m].
    pub position_error: ErrorStats,
    /// Predicted minus true crossing time [s].
    pub time_error: ErrorStats,
    /// Mean NEES per dimension of the crossing point (y, z) [-].
    pub position_nees: f64,
}

/// The accuracy of one evaluation.
#[derive(Debug, Clone, PartialEq, Default, serde::Serialize)]
pub struct EvalReport {
    /// Shots in the session.
    pub shots: usize,
    /// Detections handled.
    pub detections: usize,
    /// Velocity error after 100 ms of track [m/s].
    pub velocity_error: ErrorStats,
    /// Spin error after 100 ms of track [rad/s].
    pub spin_error: ErrorStats,
    /// The part of that spin error perpendicular to the velocity [rad/s].
    pub spin_error_perpendicular: ErrorStats,
    /// The part of that spin error along the velocity [rad/s].
    pub spin_error_parallel: ErrorStats,
    /// Spin error of the estimates where the 900 fps camera sees the ball [rad/s].
    pub spin_error_high_speed: ErrorStats,
    /// Velocity error of the estimates where the 900 fps camera sees the ball [m/s].
    pub velocity_error_high_speed: ErrorStats,
    /// Velocity error of the estimates within [`BOUNCE_WINDOW`] of the true bounce, which the
    /// other statistics leave out [m/s].
    pub velocity_error_at_bounce: ErrorStats,
    /// Mean NEES per dimension of the 9-state.
    pub state_nees: f64,
    /// Mean NEES per dimension of the position, velocity and spin blocks on their own.
    pub block_nees: [f64; 3],
    /// Mean NEES per dimension of the 9-state before and after the bounce on the robot's half.
    pub bounce_nees: [f64; 2],
    /// Interception accuracy at each of [`LEADS`].
    pub leads: Vec<LeadReport>,
    /// Shots whose fused detections (outliers aside) all went to one track [-].
    pub single_track_shots: usize,
    /// Shots with a good detection (not an outlier) gated within [`AFTER_BOUNCE`] after the
    /// true bounce [-].
    pub gated_after_bounce_shots: usize,
    /// Good detections (not outliers) that were gated [-].
    pub gated_good_detections: usize,
    /// What the estimator did with the detections.
    #[serde(skip)]
    pub counters: Counters,
}

/// The truth of one shot that the scores need.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ShotTruth {
    /// When the ball bounces on the robot's half [ns].
    pub bounce_stamp: i64,
    /// When it crosses the hitting plane [ns].
    pub intercept_stamp: i64,
    /// Where it crosses the hitting plane [m].
    pub intercept_position: Vector3<f64>,
    /// Its spin there [rad/s].
    pub intercept_spin: Vector3<f64>,
    /// It flies toward the robot (else from the robot's end, its interception not scored).
    pub toward_robot: bool,
}

impl ShotTruth {
    /// Whether `stamp` [ns] is within [`BOUNCE_WINDOW`] of the bounce, where an estimate's
    /// velocity is the one before or the one after it by a hair of timing.
    pub fn at_bounce(&self, stamp: i64) -> bool {
        (stamp - self.bounce_stamp).abs() <= seconds_to_ns(BOUNCE_WINDOW)
    }
}

impl From<&crate::eval::sim::ShotTruth> for ShotTruth {
    fn from(shot: &crate::eval::sim::ShotTruth) -> Self {
        Self {
            bounce_stamp: shot.bounce.stamp,
            intercept_stamp: shot.intercept.stamp,
            intercept_position: shot.intercept.before.position,
            intercept_spin: shot.intercept.before.spin,
            toward_robot: !shot.from_robot,
        }
    }
}

/// What was kept of one shot while the session ran.
#[derive(Debug, Clone, Default)]
struct ShotRecord {
    /// The tracks its good detections were fused into.
    tracks: Vec<u32>,
    /// A good detection was gated soon after the bounce.
    gated_after_bounce: bool,
    track_start: Option<i64>,
    scored_at_age: bool,
    high_speed_start: Option<i64>,
    /// The output of the latest estimate before each lead's time, with the number of
    /// detections scored when it came out.
    at_lead: [Option<(usize, Output)>; 3],
    /// The estimate scored after [`TRACK_AGE`] of track, with the number of detections scored
    /// when it came out.
    at_age: Option<(usize, Estimate)>,
    /// The last estimate at a detection's stamp before the shot's bounce (and
    /// [`BOUNCE_WINDOW`] from it), likewise.
    before_bounce: Option<(usize, Estimate)>,
}

/// Scores the estimator's outputs one detection at a time against the truth.
#[derive(Debug, Clone, Default)]
pub struct Scorer {
    shots: Vec<ShotTruth>,
    records: Vec<ShotRecord>,
    detections: usize,
    velocity: Vec<f64>,
    spin: Vec<f64>,
    spin_perp: Vec<f64>,
    spin_par: Vec<f64>,
    spin_fast: Vec<f64>,
    velocity_fast: Vec<f64>,
    velocity_bounce: Vec<f64>,
    nees_sum: f64,
    block_sum: [f64; 3],
    bounce_sum: [(f64, usize); 2],
    nees_count: usize,
    gated_good: usize,
}

impl Scorer {
    /// A scorer for these shots (indexed as the `shot` of [`Scorer::score`]).
    pub fn new(shots: Vec<ShotTruth>) -> Self {
        Self {
            records: vec![ShotRecord::default(); shots.len()],
            shots,
            ..Self::default()
        }
    }

    /// Adds a shot (for shots told one at a time, as a bag tells them); its index for
    /// [`Scorer::score`].
    pub fn add_shot(&mut self, shot: ShotTruth) -> usize {
        self.shots.push(shot);
        self.records.push(ShotRecord::default());
        self.shots.len() - 1
    }

    /// Scores the output of one detection of shot `shot`, whose true state at the detection's
    /// stamp is `truth`; `outlier` marks a detection that is not the ball.
    pub fn score(
        &mut self,
        shot: usize,
        detection: &Detection,
        truth: &BallState,
        outlier: bool,
        out: &Output,
    ) {
        self.detections += 1;
        let (Some(truth_shot), Some(record)) = (self.shots.get(shot), self.records.get_mut(shot))
        else {
            return;
        };
        if !outlier {
            if out.verdict == Verdict::Rejected(Rejection::Gated) {
                self.gated_good += 1;
                let since_bounce = detection.stamp - truth_shot.bounce_stamp;
                if (0..=seconds_to_ns(AFTER_BOUNCE)).contains(&since_bounce) {
                    record.gated_after_bounce = true;
                }
            }
            // The track a fused detection went to.
            if let (Verdict::Fused { .. }, Some(e)) = (out.verdict, out.estimate)
                && !record.tracks.contains(&e.track_id)
            {
                record.tracks.push(e.track_id);
            }
        }
        let Some(estimate) = out
            .estimate
            .filter(|e| e.status != TrackStatus::Initializing)
        else {
            return;
        };
        // The interception scored at a lead is the latest of a track that took this shot's
        // detections (not the previous ball's, still flying when this one is launched).
        let own_track = truth_shot.toward_robot && record.tracks.contains(&estimate.track_id);
        for (slot, lead) in LEADS.iter().enumerate() {
            let deadline = truth_shot.intercept_stamp - seconds_to_ns(*lead);
            if own_track && estimate.stamp <= deadline {
                record.at_lead[slot] = Some((self.detections, *out));
            }
        }
        // State errors only where the estimate is at the detection's own stamp (its truth).
        if estimate.stamp != detection.stamp || outlier {
            return;
        }
        let start = *record.track_start.get_or_insert(estimate.stamp);
        let error = estimate.state.to_vector() - truth.to_vector();
        if truth_shot.at_bounce(detection.stamp) {
            self.velocity_bounce
                .push((estimate.state.velocity - truth.velocity).norm());
            return;
        }
        if let Some(chol) = estimate.covariance.cholesky() {
            let nees = error.dot(&chol.solve(&error)) / 9.0;
            self.nees_sum += nees;
            self.nees_count += 1;
            let side =
                &mut self.bounce_sum[usize::from(detection.stamp >= truth_shot.bounce_stamp)];
            side.0 += nees;
            side.1 += 1;
            for (block, sum) in self.block_sum.iter_mut().enumerate() {
                let e = error.fixed_rows::<3>(3 * block).into_owned();
                let p = estimate
                    .covariance
                    .fixed_view::<3, 3>(3 * block, 3 * block)
                    .into_owned();
                if let Some(c) = p.cholesky() {
                    *sum += e.dot(&c.solve(&e)) / 3.0;
                }
            }
        }
        let spin_error: Vector3<f64> = estimate.state.spin - truth.spin;
        if detection.stamp < truth_shot.bounce_stamp {
            record.before_bounce = Some((self.detections, estimate));
        }
        if !record.scored_at_age && estimate.stamp - start >= seconds_to_ns(TRACK_AGE) {
            record.scored_at_age = true;
            record.at_age = Some((self.detections, estimate));
            self.velocity
                .push((estimate.state.velocity - truth.velocity).norm());
            let along = truth.velocity.normalize();
            let parallel = spin_error.dot(&along);
            self.spin.push(spin_error.norm());
            self.spin_par.push(parallel);
            self.spin_perp.push((spin_error - along * parallel).norm());
        }
        if detection.source == Source::HIGHSPEED_900FPS {
            let first = *record.high_speed_start.get_or_insert(detection.stamp);
            if detection.stamp - first >= seconds_to_ns(HIGH_SPEED_SETTLE) {
                self.spin_fast.push(spin_error.norm());
                self.velocity_fast
                    .push((estimate.state.velocity - truth.velocity).norm());
            }
        }
    }

    /// The report, with the estimator's counters.
    pub fn report(&self, counters: Counters) -> EvalReport {
        let leads = LEADS
            .iter()
            .enumerate()
            .map(|(slot, &lead)| self.lead_report(slot, lead))
            .collect();
        let n = self.nees_count.max(1) as f64;
        EvalReport {
            shots: self.shots.len(),
            detections: self.detections,
            velocity_error: ErrorStats::of(&self.velocity),
            spin_error: ErrorStats::of(&self.spin),
            spin_error_perpendicular: ErrorStats::of(&self.spin_perp),
            spin_error_parallel: ErrorStats::of(&self.spin_par),
            spin_error_high_speed: ErrorStats::of(&self.spin_fast),
            velocity_error_high_speed: ErrorStats::of(&self.velocity_fast),
            velocity_error_at_bounce: ErrorStats::of(&self.velocity_bounce),
            state_nees: if self.nees_count > 0 {
                self.nees_sum / n
            } else {
                f64::NAN
            },
            block_nees: self.block_sum.map(|b| b / n),
            bounce_nees: self.bounce_sum.map(|(sum, k)| sum / k.max(1) as f64),
            leads,
            single_track_shots: self.records.iter().filter(|r| r.tracks.len() == 1).count(),
            gated_after_bounce_shots: self.records.iter().filter(|r| r.gated_after_bounce).count(),
            gated_good_detections: self.gated_good,
            counters,
        }
    }

    /// The interception errors at each of [`LEADS`] over the shots from `first` on (after the
    /// estimator has seen `first` flights): distance in the plane [m].
    pub fn lead_errors_from(&self, first: usize) -> Vec<Vec<f64>> {
        (0..LEADS.len())
            .map(|slot| {
                self.shots
                    .iter()
                    .zip(&self.records)
                    .skip(first)
                    .filter_map(|(shot, record)| {
                        let crossing = record.at_lead[slot]
                            .and_then(|(_, out)| out.intercept)
                            .and_then(|i| i.intercept.crossing.ok())?;
                        let truth = shot.intercept_position;
                        Some(
                            Vector2::new(
                                crossing.state.position.y - truth.y,
                                crossing.state.position.z - truth.z,
                            )
                            .norm(),
                        )
                    })
                    .collect()
            })
            .collect()
    }

    fn lead_report(&self, slot: usize, lead: f64) -> LeadReport {
        let mut position = Vec::new();
        let mut time = Vec::new();
        let mut nees = Vec::new();
        let mut valid = 0usize;
        for (shot, record) in self.shots.iter().zip(&self.records) {
            let Some((stamp, crossing)) = record.at_lead[slot]
                .and_then(|(_, out)| out.intercept)
                .and_then(|i| i.intercept.crossing.ok().map(|c| (i.stamp, c)))
            else {
                continue;
            };
            valid += 1;
            let truth = shot.intercept_position;
            let error = Vector2::new(
                crossing.state.position.y - truth.y,
                crossing.state.position.z - truth.z,
            );
            position.push(error.norm());
            let predicted = stamp as f64 * 1e-9 + crossing.time;
            time.push(predicted - shot.intercept_stamp as f64 * 1e-9);
            nees.extend(crossing.point_nees(&truth));
        }
        let shots = self.shots.iter().filter(|s| s.toward_robot).count();
        LeadReport {
            lead,
            shots,
            valid_fraction: if shots > 0 {
                valid as f64 / shots as f64
            } else {
                0.0
            },
            position_error: ErrorStats::of(&position),
            time_error: ErrorStats::of(&time),
            position_nees: if nees.is_empty() {
                f64::NAN
            } else {
                nees.iter().sum::<f64>() / nees.len() as f64
            },
        }
    }
}

/// Runs the estimator over a simulated session in arrival order and scores it.
pub fn evaluate(config: &Config, session: &Session) -> EvalReport {
    run(config, session).report()
}

/// What the estimator had learned at the end of a session.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Learning {
    /// The physical parameters and their flight-to-flight dispersion.
    pub params: LearnedParams,
}

/// [`evaluate`], with what the estimator had learned at the end.
pub fn evaluate_learning(config: &Config, session: &Session) -> (EvalReport, Learning) {
    let run = run(config, session);
    (
        run.report(),
        Learning {
            params: run.learned,
        },
    )
}

/// The estimator run over a session, scored.
pub(crate) struct Run {
    pub(crate) scorer: Scorer,
    pub(crate) counters: Counters,
    /// The physical parameters it had learned at the end.
    pub(crate) learned: LearnedParams,
    /// The physical parameters it had learned when each shot's first detection came.
    pub(crate) physics_at_start: Vec<Option<LearnedParams>>,
}

impl Run {
    fn report(&self) -> EvalReport {
        self.scorer.report(self.counters)
    }
}

pub(crate) fn run(config: &Config, session: &Session) -> Run {
    let mut estimator = Estimator::new(config);
    let mut scorer = Scorer::new(session.shots.iter().map(ShotTruth::from).collect());
    let mut physics_at_start = vec![None; session.shots.len()];
    for sim in &session.stream {
        if let Some(slot @ None) = physics_at_start.get_mut(sim.shot) {
            *slot = Some(estimator.learned_params());
        }
        let out = estimator.handle(&sim.detection);
        scorer.score(sim.shot, &sim.detection, &sim.truth, sim.outlier, &out);
    }
    estimator.end_of_input();
    Run {
        scorer,
        counters: estimator.counters(),
        learned: estimator.learned_params(),
        physics_at_start,
    }
}

/// One quantity's error, the online filter's against the batch fit's over the same detections
/// at the same stamps, over the shots where both have an estimate.
#[derive(Debug, Clone, Copy, PartialEq, Default, serde::Serialize)]
pub struct Comparison {
    /// Shots where both have an estimate.
    pub shots: usize,
    /// The filter's error.
    pub online: ErrorStats,
    /// The batch fit's error.
    pub batch: ErrorStats,
    /// Ratio of the RMS errors, online / batch.
    pub ratio: f64,
    /// Ratio of the median errors.
    pub median_ratio: f64,
}

impl Comparison {
    fn of(online: &[f64], batch: &[f64]) -> Self {
        let (online, batch) = (ErrorStats::of(online), ErrorStats::of(batch));
        Self {
            shots: online.count,
            online,
            batch,
            ratio: online.rms / batch.rms,
            median_ratio: online.median / batch.median,
        }
    }
}

/// The online filter against the batch fit at one lead before the crossing.
#[derive(Debug, Clone, Copy, PartialEq, Default, serde::Serialize)]
pub struct LeadEfficiency {
    /// Time before the true crossing [s].
    pub lead: f64,
    /// Distance in the plane of the predicted crossing from the true one [m].
    pub position: Comparison,
    /// The predicted spin at the crossing against the true one [rad/s].
    pub spin: Comparison,
}

/// Which physics the batch fit flies.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub enum BatchPhysics {
    /// The configuration's (in a simulation of the configured physics, the truth: more than
    /// the filter knows).
    Configured,
    /// What the estimator had learned of the physics when the shot's first detection came (the
    /// same knowledge the filter starts the shot with).
    Learned,
    /// The simulation's own physics where it is not the configuration's (the harder sets,
    /// [`sets`]): the best a fit of a flight that follows the model can do.
    True,
}

/// The filter's efficiency: its errors divided by the batch fit's on the same detections.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Efficiency {
    /// The batch fit's physics.
    pub physics: BatchPhysics,
    /// The interception at each of [`LEADS`].
    pub leads: Vec<LeadEfficiency>,
    /// The velocity after [`TRACK_AGE`] of track [m/s].
    pub velocity_at_age: Comparison,
    /// The spin perpendicular to the velocity just before the bounce on the robot's half
    /// [rad/s].
    pub spin_before_bounce: Comparison,
}

/// The filter's efficiency ([`Efficiency`]), against the batch fit ([`crate::offline::batch`]) of the
/// same detections (all of the shot's that had arrived when the filter published, outliers
/// included) at the same stamps, with the configured physics and with the physics the estimator
/// had learned when the shot began. At each of [`LEADS`] the interception the filter published
/// last before that lead is compared with the one predicted from the fitted state at the same
/// stamp. The fit is the maximum a posteriori estimate of a flight that follows the model
/// exactly given everything the filter had seen, so a ratio measures what the filter's
/// recursion and its noise model (linearisation, process noise, the bounce's scatter, the
/// flight-to-flight dispersion of the parameters, gating, initialisation) cost.
pub fn efficiency(config: &Config, session: &Session) -> [Efficiency; 2] {
    let run = run(config, session);
    // The session flies the configured physics.
    [BatchPhysics::Configured, BatchPhysics::Learned]
        .map(|physics| efficiency_of(&run, config, session, physics, config))
}

/// The filter's efficiency on a session simulated with other physics than `config`'s (that of
/// `truth`, a harder set's configuration): against the batch fit with the physics the estimator
/// had learned when each shot began (its Reynolds exponents included) and with the true
/// physics, the filter running on `config`.
pub fn efficiency_with_truth(
    config: &Config,
    session: &Session,
    truth: &Config,
) -> [Efficiency; 2] {
    let run = run(config, session);
    [BatchPhysics::Learned, BatchPhysics::True]
        .map(|physics| efficiency_of(&run, config, session, physics, truth))
}

/// The filter's crossing at one lead (`slot` of [`LEADS`]) against the batch fit's of the same
/// detections (`fitted`: the fit of a shot's detections among the first `arrived`, at a stamp).
fn lead_efficiency(
    run: &Run,
    config: &Config,
    slot: usize,
    lead: f64,
    fitted: &dyn Fn(usize, usize, i64) -> Option<(FittedState, Propagator)>,
) -> LeadEfficiency {
    let query = |bounced| InterceptQuery {
        plane_x: config.intercept.plane_x,
        horizon: config.prediction.horizon,
        bounced_on_robot_half: bounced,
        bounce_noise: BounceNoise::default(),
    };
    let (mut online, mut batch) = (Vec::new(), Vec::new());
    let (mut online_spin, mut batch_spin) = (Vec::new(), Vec::new());
    for (index, (truth, record)) in run.scorer.shots.iter().zip(&run.scorer.records).enumerate() {
        let Some((arrived, published)) = record.at_lead[slot] else {
            continue;
        };
        let Some(estimate) = published.intercept else {
            continue;
        };
        let Ok(online_crossing) = estimate.intercept.crossing else {
            continue;
        };
        let Some((fitted, propagator)) = fitted(index, arrived, estimate.stamp) else {
            continue;
        };
        let predicted = predict_intercept(
            &propagator,
            &fitted.state.to_vector(),
            &fitted.covariance,
            &query(fitted.robot_half_bounces > 0),
        );
        let Ok(batch_crossing) = predicted.crossing else {
            continue;
        };
        let miss = |p: &Vector3<f64>| {
            Vector2::new(
                p.y - truth.intercept_position.y,
                p.z - truth.intercept_position.z,
            )
            .norm()
        };
        online.push(miss(&online_crossing.state.position));
        batch.push(miss(&batch_crossing.state.position));
        online_spin.push((online_crossing.state.spin - truth.intercept_spin).norm());
        batch_spin.push((batch_crossing.state.spin - truth.intercept_spin).norm());
    }
    LeadEfficiency {
        lead,
        position: Comparison::of(&online, &batch),
        spin: Comparison::of(&online_spin, &batch_spin),
    }
}

/// One line of [`efficiency`]: the filter's `run` of `session` against the batch fit flying
/// `physics` (the physics of `truth`, the session's own configuration, for
/// [`BatchPhysics::True`]).
fn efficiency_of(
    run: &Run,
    config: &Config,
    session: &Session,
    physics: BatchPhysics,
    truth: &Config,
) -> Efficiency {
    let physics_of = |index: usize| -> Config {
        let mut c = config.clone();
        match physics {
            BatchPhysics::Configured => {}
            BatchPhysics::Learned => {
                if let Some(Some(learned)) = run.physics_at_start.get(index) {
                    learned.apply_to(&mut c);
                }
            }
            BatchPhysics::True => {
                PhysicsParams::from_config(truth).apply_to(&mut c);
                c.aero.reynolds_exponents = truth.aero.reynolds_exponents.clone();
            }
        }
        c
    };
    // The batch fit of the shot's detections among the first `arrived`, at `stamp`.
    let fitted = |index: usize, arrived: usize, stamp: i64| {
        let c = physics_of(index);
        let seen: Vec<Detection> = session.stream[..arrived]
            .iter()
            .filter(|d| d.shot == index)
            .map(|d| d.detection)
            .collect();
        let propagator = Propagator::new(&c);
        let state = fit_whole_flight(&c, &seen)
            .ok()?
            .states_at(&propagator, &[stamp])
            .pop()
            .flatten()?;
        Some((state, propagator))
    };
    let leads = LEADS
        .iter()
        .enumerate()
        .map(|(slot, &lead)| lead_efficiency(run, config, slot, lead, &fitted))
        .collect();
    // A state error of the filter's estimate and of the fit at the estimate's stamp.
    let state_errors = |pick: &dyn Fn(&ShotRecord) -> Option<(usize, Estimate)>,
                        error: &dyn Fn(&BallState, &BallState) -> f64| {
        let (mut online, mut batch) = (Vec::new(), Vec::new());
        for (index, record) in run.scorer.records.iter().enumerate() {
            let Some((arrived, estimate)) = pick(record) else {
                continue;
            };
            let Some(truth) = session
                .shots
                .get(index)
                .and_then(|s| s.state_at(estimate.stamp))
            else {
                continue;
            };
            let Some((fitted, _)) = fitted(index, arrived, estimate.stamp) else {
                continue;
            };
            online.push(error(&estimate.state, &truth));
            batch.push(error(&fitted.state, &truth));
        }
        Comparison::of(&online, &batch)
    };
    let velocity = |e: &BallState, t: &BallState| (e.velocity - t.velocity).norm();
    let spin_across = |e: &BallState, t: &BallState| {
        let along = t.velocity.normalize();
        let error = e.spin - t.spin;
        (error - along * error.dot(&along)).norm()
    };
    Efficiency {
        physics,
        leads,
        velocity_at_age: state_errors(&|r| r.at_age, &velocity),
        spin_before_bounce: state_errors(&|r| r.before_bounce, &spin_across),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::online::estimator::InterceptEstimate;
    use crate::online::intercept::{Crossing, Intercept};
    use crate::physics::StateMatrix;

    /// The output after a detection at `stamp` whose estimate is of track `track_id`, with a
    /// valid crossing at y = `y`.
    fn output(verdict: Verdict, track_id: u32, stamp: i64, y: f64) -> Output {
        let state = BallState::new(
            Vector3::new(-1.6, y, 0.2),
            Vector3::new(-5.0, 0.0, 0.0),
            Vector3::zeros(),
        );
        Output {
            verdict,
            estimate: Some(Estimate {
                stamp,
                track_id,
                status: TrackStatus::Tracking,
                state,
                covariance: StateMatrix::identity() * 1e-4,
                bounces: 0,
                nis: 1.0,
            }),
            intercept: Some(InterceptEstimate {
                stamp,
                track_id,
                intercept: Intercept {
                    crossing: Ok(Crossing {
                        time: 0.4,
                        time_sigma: 1e-3,
                        state,
                        covariance: StateMatrix::identity() * 1e-4,
                    }),
                    bounce: None,
                },
            }),
        }
    }

    /// A new ball launched while the previous one still flies: until one of its detections is
    /// fused, the estimator's output is the previous ball's track, whose interception is not
    /// this shot's (it crosses elsewhere, earlier) and must not be scored as its prediction.
    #[test]
    fn a_lead_is_scored_only_from_a_track_that_took_the_shot_s_detections() {
        let truth = ShotTruth {
            bounce_stamp: 800_000_000,
            intercept_stamp: 1_000_000_000,
            intercept_position: Vector3::new(-1.6, 0.0, 0.2),
            intercept_spin: Vector3::zeros(),
            toward_robot: true,
        };
        let detection = |stamp: i64| Detection {
            stamp,
            source: Source::WIDE_150FPS,
            position: Vector3::new(1.0, 0.0, 0.3),
            position_covariance: None,
            spin: None,
            spin_covariance: None,
            confidence: 1.0,
        };
        let state = BallState::new(
            Vector3::new(1.0, 0.0, 0.3),
            Vector3::zeros(),
            Vector3::zeros(),
        );
        let mut scorer = Scorer::new(vec![truth]);
        // The previous ball's track (7), 1.2 m off, while the new shot initialises.
        let previous = output(Verdict::Initializing, 7, 500_000_000, 1.2);
        scorer.score(0, &detection(500_000_000), &state, false, &previous);
        let report = scorer.report(Counters::default());
        assert!(
            report.leads.iter().all(|l| l.valid_fraction == 0.0),
            "{report:?}"
        );
        // The shot's own track (8): scored.
        let own = output(Verdict::Fused { nis: 1.0 }, 8, 600_000_000, 0.01);
        scorer.score(0, &detection(600_000_000), &state, false, &own);
        let report = scorer.report(Counters::default());
        let at_300 = &report.leads[0];
        assert_eq!(at_300.valid_fraction, 1.0);
        assert!(
            (at_300.position_error.median - 0.01).abs() < 1e-9,
            "{at_300:?}"
        );
    }
}
