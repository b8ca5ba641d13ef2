//! The estimator: one entry point, [`Estimator::handle`], that takes every detection as it
//! arrives and returns the filtered state and the interception prediction. The ROS node and the
//! MCAP replay both call it, so a replay runs exactly the code path of the live node.
//!
//! - Zero added latency: each detection is processed on arrival. A detection older than the
//!   newest fused one (the two cameras have different latencies) is fused by rolling back to the
//!   estimate before its stamp and re-applying the newer detections, from a bounded history
//!   (`tracking.rollback_window`); an older one is dropped and counted.
//! - Gating by the Mahalanobis distance at `gating.probability`; a run of
//!   `gating.max_consecutive_rejections` rejections, or a gap longer than `tracking.timeout`,
//!   ends the track, and the next detections start a new one with a new track id.
//! - Initialisation from the first `ekf.init_detections` detections (`init.rs`). A track that
//!   starts on the robot's half with the ball rising toward the robot (a restart after a run of
//!   rejections, or a late first sight) counts the bounce it must already have made.
//! - A detection whose stamp jumps beyond `tracking.timeout` is held until the next one confirms
//!   the jump (a new ball, a restarted clock: a new track) or shows a glitch
//!   ([`Rejection::StampJump`]); see [`Estimator::update`]. Every rejected detection is counted
//!   by reason ([`Counters`]); the rules are tabled in docs/estimator.md ("Bad input").
//!
//! No heap allocation per detection: the history and buffers are allocated once.

mod counters;
mod history;
mod init;
mod jumps;
mod learned_config;
mod learning;
mod model_noise;
mod noise;
mod refit_contest;
mod refitting;
mod tracking;

use std::collections::VecDeque;

use nalgebra::{Matrix3, Matrix6, SVector};

use crate::config::{Config, REFIT_MAX_DETECTIONS};
use crate::model::detection::{Detection, seconds_to_ns};
use crate::model::stats::chi_square_quantile;
use crate::online::contact_side::with_contact_side;
use crate::online::ekf::{
    BounceNoise, Ekf, FilterNoise, Fused, NOISE_SCALES, NoiseCarry, NoiseScore, NoiseSensitivity,
    ParamCovariance, ProcessNoise, UpdateError, position_H, position_spin_H,
};
use crate::online::intercept::{Intercept, InterceptQuery, InterceptTracker};
pub use crate::online::measurement::{MAX_RANGE, Measurement};
use crate::online::measurement::{MeasurementModel, claims_placeholder_spin};
use crate::physics::racket::{RacketModel, RacketState};
use crate::physics::{
    BallState, FlightModel, PARAMS, ParamVector, PhysicsParams, PredictOptions, Propagator,
    StateMatrix, StateVector, Trajectory, predict,
};
pub use counters::{Counters, Rejection, Verdict};
pub use learned_config::{
    LearnedSummary, describe_model_noise, describe_params, describe_refit_contest,
    describe_source_noise,
};
use learning::Learned;
use model_noise::ModelNoiseLearner;
pub use model_noise::{LEARNED_SCALE_NAMES, LEARNED_SCALES};
use noise::NoiseLearner;
pub use noise::SourceNoiseEstimate;
pub use refit_contest::RefitContestScore;

/// Track status, with the codes of `BallState.msg`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TrackStatus {
    /// Collecting the first detections of a new ball.
    Initializing,
    /// Detections are being fused.
    Tracking,
    /// No detection fused for longer than `tracking.coast_after`: the estimate is a prediction.
    Coasting,
}

impl TrackStatus {
    /// The `STATUS_*` code of `BallState.msg`.
    pub fn code(self) -> u8 {
        match self {
            Self::Initializing => 1,
            Self::Tracking => 2,
            Self::Coasting => 3,
        }
    }
}

/// The filtered state of the tracked ball.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Estimate {
    /// Time of the estimate [ns].
    pub stamp: i64,
    /// The track.
    pub track_id: u32,
    /// Track status.
    pub status: TrackStatus,
    /// The state.
    pub state: BallState,
    /// Its covariance over (position, velocity, spin).
    pub covariance: StateMatrix,
    /// Table bounces since the track started.
    pub bounces: u32,
    /// NIS of the last fused update.
    pub nis: f64,
}

/// The interception prediction made from an estimate.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct InterceptEstimate {
    /// Time of the estimate it was predicted from [ns].
    pub stamp: i64,
    /// The track.
    pub track_id: u32,
    /// The prediction (times relative to `stamp`).
    pub intercept: Intercept,
}

/// Everything [`Estimator::handle`] returns for one detection.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Output {
    /// What happened to the detection.
    pub verdict: Verdict,
    /// The estimate after it, when there is a ball.
    pub estimate: Option<Estimate>,
    /// The interception prediction from that estimate, when a track exists.
    pub intercept: Option<InterceptEstimate>,
}

/// The configuration as the estimator uses it.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Settings {
    /// What the filter's prediction adds to the physics.
    filter: FilterNoise,
    /// The extra position variance of a detection of a ball at the table [m^2].
    contact_var: f64,
    /// The adaptation's prior: the configured parameters, and their variances (zero for those
    /// not adapted).
    param_prior: ParamVector,
    param_prior_var: ParamVector,
    /// The flight-to-flight dispersion of the parameters (variances).
    param_dispersion: ParamVector,
    gate_position: f64,
    gate_position_spin: f64,
    /// The fraction of the gain a position applies to the spin along the flight before the
    /// first bounce (`ekf.spin_along_flight_gain`).
    spin_along_flight_gain: f64,
    gate_probability: f64,
    /// Every source's noise, in the order of [`SourcesParams::all`].
    /// How a detection becomes a measurement (its source's noise, the confidence floor).
    pub(crate) measurement: MeasurementModel,
    /// Each detection's source's place in `sources`.
    init_count: usize,
    init_span: i64,
    spin_prior_var: f64,
    max_rejections: u32,
    timeout: i64,
    rollback: i64,
    coast: i64,
    plane_x: f64,
    horizon: f64,
    gravity: f64,
    /// The learned model noise's horizon [ns]; 0 for each detection's own innovation.
    model_noise_horizon: i64,
    /// How often the track is refitted [ns of track]; 0 never.
    refit_interval: i64,
    /// Refits replace the filter's estimates only while they predict the flight better
    /// ([`refit_contest`]).
    refit_when_better: bool,
    /// The horizon the refits and the filter are contested at [ns].
    contest_horizon: i64,
    /// Whether the refits are applied before their contest has spoken.
    refits_start_applied: bool,
    /// The most detections a refit runs over (its window).
    refit_max: usize,
    /// A track teaches its flight smoothed when it ends (`adaptation.smoothed_lessons`, with
    /// the adaptation on).
    smoothed_lessons: bool,
}

/// The prior variances of the learned physical parameters (`adaptation.*_sigma` squared; zero,
/// not adapted, without the adaptation).
pub(crate) fn param_prior_variances(config: &Config) -> ParamVector {
    let adaptation = &config.adaptation;
    let sigmas = ParamVector::new(
        adaptation.drag_scale_sigma,
        adaptation.magnus_scale_sigma,
        adaptation.restitution_sigma,
        adaptation.friction_sigma,
    ) * if adaptation.enabled { 1.0 } else { 0.0 };
    sigmas.component_mul(&sigmas)
}

impl Settings {
    /// Whether a track's fused detections are kept: for its refits or its smoothed lesson.
    fn keeps_detections(&self) -> bool {
        self.refit_interval > 0 || self.smoothed_lessons
    }

    /// The most detections kept waiting to initialise a track (the buffer's length, not its
    /// allocation: a cloned estimator's buffers are allocated to their contents only).
    fn pending_limit(&self) -> usize {
        self.init_count.max(self.max_rejections as usize) + 8
    }

    /// The fraction of a position's gain on the spin along the flight after `bounces` bounces
    /// of the track, `guarded` or not ([`Estimator::guards_spin_along_flight`]):
    /// `ekf.spin_along_flight_gain` before the first (positions see that spin only through the
    /// turning flight's sideways force), the whole gain after it or unguarded.
    fn along_flight_gain(&self, bounces: u32, guarded: bool) -> f64 {
        if bounces == 0 && guarded {
            self.spin_along_flight_gain
        } else {
            1.0
        }
    }

    /// The most rejected detections kept to seed a new track.
    fn rejected_run_limit(&self) -> usize {
        self.max_rejections as usize + 1
    }

    pub(crate) fn new(config: &Config) -> Self {
        let p = config.gating.probability;
        let adaptation = &config.adaptation;
        let param_prior_var = param_prior_variances(config);
        Self {
            filter: FilterNoise {
                process: ProcessNoise {
                    acceleration_density: config.ekf.acceleration_noise_density,
                    spin_density: config.ekf.spin_noise_density,
                    param_density: param_prior_var
                        * (adaptation.drift_per_hour * adaptation.drift_per_hour / 3600.0),
                },
                bounce: BounceNoise::from_config(config),
                spin_spread: config.ekf.spin_parameter_spread,
            },
            contact_var: config.ekf.contact_position_sigma * config.ekf.contact_position_sigma,
            param_prior: PhysicsParams::from_config(config).to_vector(),
            param_prior_var,
            param_dispersion: {
                let d = ParamVector::new(
                    adaptation.drag_scale_flight_sigma,
                    adaptation.magnus_scale_flight_sigma,
                    adaptation.restitution_flight_sigma,
                    adaptation.friction_flight_sigma,
                );
                d.component_mul(&d)
            },
            gate_position: chi_square_quantile(p, 3),
            gate_position_spin: chi_square_quantile(p, 6),
            spin_along_flight_gain: config.ekf.spin_along_flight_gain,
            gate_probability: p,
            measurement: MeasurementModel::new(config),
            init_count: config.ekf.init_detections.max(3) as usize,
            init_span: seconds_to_ns(config.ekf.init_max_span),
            spin_prior_var: config.ekf.spin_prior_sigma * config.ekf.spin_prior_sigma,
            max_rejections: config.gating.max_consecutive_rejections.max(1),
            timeout: seconds_to_ns(config.tracking.timeout),
            rollback: seconds_to_ns(config.tracking.rollback_window),
            coast: seconds_to_ns(config.tracking.coast_after),
            plane_x: config.intercept.plane_x,
            horizon: config.prediction.horizon,
            refit_interval: seconds_to_ns(config.ekf.refit_interval),
            refit_when_better: config.ekf.refit_when_better,
            refits_start_applied: config.ekf.refits_start_applied,
            contest_horizon: seconds_to_ns(if config.ekf.model_noise_horizon > 0.0 {
                config.ekf.model_noise_horizon
            } else {
                refit_contest::HORIZON
            }),
            refit_max: REFIT_MAX_DETECTIONS.clamp(config.ekf.refit_max_detections) as usize,
            smoothed_lessons: config.adaptation.enabled && config.adaptation.smoothed_lessons,
            gravity: config.gravity,
            model_noise_horizon: seconds_to_ns(config.ekf.model_noise_horizon),
        }
    }
}

impl Measurement {
    /// The measurement with its noise as the estimator has learned its source's
    /// ([`noise::SourceNoiseEstimate`]): its position and spin covariances scaled, its timing
    /// noise set.
    fn with_learned_noise(mut self, noise: &SourceNoiseEstimate) -> Self {
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

/// A ball on the robot's half, moving toward the robot and rising, has bounced there already
/// (an incoming ball falls from the net to its bounce).
fn already_bounced(x: &crate::physics::StateVector) -> bool {
    x[0] < 0.0 && x[3] < 0.0 && x[5] > 0.0
}

/// Two detections of the same camera frame: a duplicate.
fn same_frame(a: &Detection, b: &Detection) -> bool {
    a.stamp == b.stamp && a.source == b.source
}

/// The estimate at one time, with what the track knows at that time.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Snapshot {
    ekf: Ekf,
    stamp: i64,
    bounces: u32,
    robot_half_bounces: u32,
    last_fused: i64,
    /// The NIS of the last fused update.
    nis: f64,
    /// That detection's whole measurement's NIS ([`Fused::whole_nis`]).
    whole_nis: f64,
    /// The state change of the last bounce the filter flew the estimate through.
    bounce_jump: Option<StateVector>,
    /// Whether the track's spin has been measured (a spin camera's detection fused, or fitted
    /// at the start): the phase whose white acceleration's scale predictions from it fly with
    /// ([`model_noise`]).
    spin_measured: bool,
}

impl Snapshot {
    /// Records the detection at `stamp` just fused into it.
    fn record(&mut self, stamp: i64, fused: &Fused) {
        self.last_fused = stamp;
        self.nis = fused.nis;
        self.whole_nis = fused.whole_nis;
    }
}

/// An estimate held to be predicted `ekf.model_noise_horizon` ahead and scored against the
/// detection there: what the model noise is learned from with a horizon. The score counts what
/// the scales add over the horizon and what they had added to the held estimate's covariance
/// (the live track's sensitivity, held with it): at 900 fps the held covariance is mostly the
/// white acceleration's doing, and a score that took it as given could not tell a scale too
/// large (its predictions 0.1 s ahead less wrong than they claimed, NIS 2.4 of 3) from one
/// right.
#[derive(Debug, Clone, Copy)]
struct HorizonProbe {
    /// The estimate it predicts from and the covariance's sensitivity to the scales there; None
    /// until the live track's next fused detection.
    from: Option<(Snapshot, NoiseSensitivity)>,
}

impl HorizonProbe {
    fn for_config(config: &Config) -> Option<Box<Self>> {
        (config.ekf.learn_model_noise && config.ekf.model_noise_horizon > 0.0)
            .then(|| Box::new(Self { from: None }))
    }
}

/// The live track's sensitivity to the noise scales, carried when the model noise is learned.
fn live_sensitivity(config: &Config) -> Option<Box<NoiseSensitivity>> {
    config
        .ekf
        .learn_model_noise
        .then(|| Box::new([StateMatrix::zeros(); NOISE_SCALES]))
}

/// A fused detection and the estimate just after it.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Entry {
    detection: Detection,
    measurement: Measurement,
    after: Snapshot,
}

#[derive(Debug, Clone)]
struct Track {
    id: u32,
    now: Snapshot,
    /// The estimate just before the oldest history entry.
    base: Snapshot,
    history: VecDeque<Entry>,
    consecutive_rejections: u32,
    /// The physical parameters (and their covariance) the track started from.
    param_prior: (ParamVector, ParamCovariance),
    /// When it started [ns].
    started: i64,
}

/// The estimator (see the module doc).
#[derive(Debug, Clone)]
pub struct Estimator {
    settings: Settings,
    propagator: Propagator,
    flight: FlightModel,
    track: Option<Track>,
    /// Detections of a ball being initialised, sorted by stamp.
    pending: Vec<Detection>,
    /// The latest run of rejected detections, to seed a new track.
    rejected_run: VecDeque<Detection>,
    next_track_id: u32,
    counters: Counters,
    history_capacity: usize,
    /// The history buffer of the next track, allocated once.
    spare_history: VecDeque<Entry>,
    /// The propagator with the table grown and shrunk by [`EDGE_MARGIN`].
    edge_alternatives: [Propagator; 2],
    /// A detection that jumped more than `tracking.timeout` off the current stamps, held until
    /// the next detection confirms the jump or shows it was a glitch (see [`Self::update`]).
    held: Option<(Detection, Measurement)>,
    /// The interception kept up to date from detection to detection.
    intercepts: InterceptTracker,
    /// A track just refuted by a run of rejected detections, whose id the next track keeps
    /// when it is the same ball.
    continuation: Option<Continuation>,
    /// What the estimator has learned of each source's noise.
    noise: NoiseLearner,
    /// The prior innovation of the detection `fuse` just fused (or gated), for the noise.
    innovation: Option<noise::Innovation>,
    /// What the estimator has learned of how far the flights stray from the model.
    model_noise: ModelNoiseLearner,
    /// The score of the noise scales of the detection `fuse` just fused, and whether its
    /// prediction started after the track's spin was measured (without a model-noise horizon).
    score: Option<(NoiseScore, bool)>,
    /// How the live track's covariance depends on the noise scales, when they are learned:
    /// carried along the track's newest detections (a late one, fused by rolling back, neither
    /// moves it nor teaches the scales), allocated once.
    sensitivity: Option<Box<NoiseSensitivity>>,
    /// The prediction held to learn the model noise from, with a horizon
    /// (`ekf.model_noise_horizon`), allocated once.
    probe: Option<Box<HorizonProbe>>,
    /// What the estimator knows of the physical parameters between tracks.
    learned: Learned,
    /// The racket-impact model, for the robot's announced hits.
    racket: RacketModel,
    /// The robot's next hit, announced ([`Self::expect_hit`]), and the rebound predicted from it
    /// at the first detection after its impact (kept for the detections after it until one fits
    /// or `tracking.timeout` has passed since the impact).
    expected_hit: Option<(RobotHit, Option<Snapshot>)>,
    /// The live track's detections for its refits, and the last smoothed flight.
    refit: refitting::TrackRefit,
    /// Whether the refits predict the flights better than the filter.
    contest: refit_contest::RefitContest,
    /// The buffer of the ended track whose lesson is pending, swapped with `refit`.
    lesson_refit: refitting::TrackRefit,
    /// The pending lesson of an ended track ([`Self::learn_in_idle_time`]).
    lesson: Option<refitting::PendingLesson>,
    /// The ended track's estimates' (stamp, bounces), for its lesson's check; allocated once.
    lesson_bounces: Vec<(i64, u32)>,
}

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

/// What the estimator has learned of one source's noise ([`Estimator::learned_noise`]).
#[derive(Debug, Clone, PartialEq)]
pub struct LearnedSourceNoise {
    /// The source's configuration key (`sources.*`).
    pub source: String,
    /// Its position sigma [m]: the configured one times the learned scale's square root.
    pub position_sigma: f64,
    /// The sigma of its stamps' timing [s].
    pub stamp_sigma: f64,
    /// The estimate behind them.
    pub estimate: SourceNoiseEstimate,
}

impl LearnedSourceNoise {
    /// Whether its detections have taught anything yet (beyond the configured prior's weight).
    pub fn has_learned(&self) -> bool {
        self.estimate.weight > noise::PRIOR_WEIGHT
    }
}

/// What the estimator has learned of how far the flights stray from its model
/// ([`Estimator::learned_model_noise`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LearnedModelNoise {
    /// The scales on the configured noise [-], the acceleration's before the track's spin is
    /// measured.
    pub scales: crate::online::ekf::NoiseScales,
    /// The scale on the white acceleration's configured density once the spin is measured [-].
    pub spin_measured_acceleration: f64,
    /// The standard deviation of the log of each scale (from the information behind it), in
    /// the order of [`LEARNED_SCALE_NAMES`].
    pub log_sigma: [f64; LEARNED_SCALES],
}

impl LearnedModelNoise {
    /// Each learned scale with its name and the standard deviation of its log, in the order of
    /// [`LEARNED_SCALE_NAMES`].
    pub fn named(&self) -> [(&'static str, f64, f64); LEARNED_SCALES] {
        let [acceleration, spin, bounce] = self.scales.to_array();
        let scales = [acceleration, spin, bounce, self.spin_measured_acceleration];
        std::array::from_fn(|j| (LEARNED_SCALE_NAMES[j], scales[j], self.log_sigma[j]))
    }
}

/// What an estimator has learned of the physical parameters, carried to another
/// ([`Estimator::learned_physics`], [`Estimator::adopt_learned_physics`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LearnedPhysics {
    params: Learned,
    model_noise: ModelNoiseLearner,
    /// The refits' contest with the filter (no contest under way).
    refit_contest: refit_contest::RefitContest,
}

impl LearnedPhysics {
    /// Whether the live refits predict the flights better than the filter, as contested.
    pub fn refit_contest(&self) -> RefitContestScore {
        self.refit_contest.report()
    }

    /// How far the flights stray from the model, as learned.
    pub fn model_noise(&self) -> LearnedModelNoise {
        self.model_noise.learned()
    }

    /// The ball's and table's parameters it holds, with their uncertainty.
    pub fn params(&self) -> LearnedParams {
        let (theta, covariance) = self.params.global();
        LearnedParams::new(
            &theta,
            &covariance,
            self.params.tracks(),
            &self.params.dispersion(),
        )
    }
}

/// The physical parameters the estimator has learned ([`Estimator::learned_params`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LearnedParams {
    /// The estimate (of the live track, else as the last track left it).
    pub params: PhysicsParams,
    /// Standard deviation of each parameter, in the order of [`PhysicsParams::NAMES`] [-].
    pub sigma: [f64; PARAMS],
    /// Tracks that have contributed, the live one included.
    pub tracks: u64,
    /// How much each parameter scatters from flight to flight about these [-] (the dispersion's
    /// standard deviation, as learned; zero for a single flight's own parameters).
    pub flight_sigma: [f64; PARAMS],
}

impl LearnedParams {
    /// Parameters `theta` of covariance `covariance`, learned over `tracks` tracks, with a
    /// flight-to-flight dispersion of variances `dispersion`.
    fn new(
        theta: &ParamVector,
        covariance: &ParamCovariance,
        tracks: u64,
        dispersion: &ParamVector,
    ) -> Self {
        Self {
            params: PhysicsParams::from_vector(theta),
            sigma: std::array::from_fn(|i| covariance[(i, i)].max(0.0).sqrt()),
            tracks,
            flight_sigma: std::array::from_fn(|i| dispersion[i].max(0.0).sqrt()),
        }
    }
}

impl Track {
    /// `learned` updated with what this track has learned of the physics so far.
    fn taught(&self, learned: &Learned) -> Learned {
        learned.absorbed(
            &self.param_prior,
            &(self.now.ekf.theta, self.now.ekf.param_covariance()),
            self.started,
            self.now.stamp,
        )
    }
}

/// A track refuted by a run of rejected detections: its id and its last estimate.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Continuation {
    id: u32,
    last: Snapshot,
}

/// The entries of a track's history: 900 + 150 detections per second over the rollback window,
/// with a wide margin.
fn history_capacity(config: &Config) -> usize {
    ((config.tracking.rollback_window * 2000.0).ceil() as usize).clamp(16, 4096)
}

/// How far [m] a track's first estimate may be from where a refuted track's estimate had flown
/// to for it to be the same ball re-anchored (a bounce mispredicted by 1 m/s is 5 cm off after
/// 50 ms).
pub const REANCHOR_DISTANCE: f64 = 0.2;

/// How close to its contact height [m] a ball is "at the table": a spin measured there that
/// contradicts the estimate's may be of the other side of the bounce and is not used (1.5 cm is
/// 5 ms of a ball falling at 3 m/s).
const BOUNCE_SPIN_MARGIN: f64 = 0.015;

/// How close to its contact height [m] a ball is in contact with the table in the camera's
/// eyes: its detections there get the extra noise `ekf.contact_position_sigma` (one ball
/// diameter: the ball's image meets its reflection and shadow on the surface; on the real
/// launcher flights a frame 3.6 cm above the contact height sat 6 mm off the flight).
pub const CONTACT_BAND: f64 = 0.04;

/// How far from the table's edge [m] a detection is also fused with the table grown and shrunk
/// by as much, and the better fit kept (the estimate's position is uncertain by millimetres; the
/// edge is sharp).
const EDGE_MARGIN: f64 = 0.02;

/// Most detections re-applied when an edge ball's bounce hypothesis is tried again
/// (`retry_edge_bounce`): 9 ms of the 900 fps camera.
const EDGE_RETRY_LIMIT: usize = 8;

/// Most detections re-applied when a bounce is tried again with the spin before it forgotten
/// (`retry_bounce_forgetting_spin`): the rollback window's 30 ms of both cameras.
const BOUNCE_RETRY_LIMIT: usize = 48;

/// How unlikely a bounce hypothesis finds the positions since the bounce: each innovation's NIS
/// plus the log-determinant of its covariance (twice the negative log-likelihood, up to a
/// constant), a detection the hypothesis gates counted at the gate.
#[derive(Debug, Clone, Copy)]
struct HypothesisCost {
    /// Over the detections fused since the bounce.
    since: f64,
    /// Over those and the detection being judged.
    with_d: f64,
    /// Whether the hypothesis fuses the detection being judged.
    fuses_d: bool,
}

/// How much more likely [twice the log-likelihood ratio] the positions since a bounce must be
/// with the spin before it forgotten than as they were for the bounce to be taken again: the
/// chi-square quantile of 3 degrees of freedom (the spin's, freed) at 0.999, a likelihood-ratio
/// test. On the real launcher flights a detection 7 mm off the flight 20 ms after a bounce,
/// which a spin forgotten explained better by 6.4, was taken at no margin, and the next five
/// detections refuted the track.
const BOUNCE_RETRY_EVIDENCE: f64 = 16.27;

impl Estimator {
    /// An estimator with the given configuration (assumed validated).
    pub fn new(config: &Config) -> Self {
        let settings = Settings::new(config);
        let history_capacity = history_capacity(config);
        let propagator = Propagator::new(config);
        Self {
            flight: FlightModel::new(config),
            track: None,
            pending: Vec::with_capacity(settings.pending_limit()),
            rejected_run: VecDeque::with_capacity(settings.rejected_run_limit()),
            next_track_id: 1,
            counters: Counters::default(),
            history_capacity,
            spare_history: VecDeque::with_capacity(history_capacity),
            edge_alternatives: [EDGE_MARGIN, -EDGE_MARGIN].map(|m| propagator.with_edge_margin(m)),
            held: None,
            intercepts: InterceptTracker::new(config.intercept.refresh.clone()),
            continuation: None,
            noise: NoiseLearner::new(config),
            innovation: None,
            model_noise: ModelNoiseLearner::new(&config.ekf),
            score: None,
            sensitivity: live_sensitivity(config),
            probe: HorizonProbe::for_config(config),
            learned: Learned::new(
                settings.param_prior,
                settings.param_prior_var,
                settings.filter.process.param_density,
                settings.param_dispersion,
                config.adaptation.learn_dispersion,
            ),
            racket: RacketModel::new(config),
            expected_hit: None,
            refit: refitting::TrackRefit::new(if settings.keeps_detections() {
                settings.refit_max
            } else {
                0
            }),
            lesson_refit: refitting::TrackRefit::new(if settings.smoothed_lessons {
                settings.refit_max
            } else {
                0
            }),
            contest: refit_contest::RefitContest::starting(settings.refits_start_applied),
            lesson: None,
            lesson_bounces: Vec::with_capacity(history_capacity + 2),
            propagator,
            settings,
        }
    }

    /// Takes `config`'s estimator, gating, source-noise, tracking and interception values from
    /// the next detection on, keeping the live track, what was learned of the physics and the
    /// counters (the node's `set_parameters`). `previous` is the configuration it ran with: what
    /// was learned of a source's noise starts again from the configured values when they
    /// changed, as does the learned model noise when its settings did. The physical parameters
    /// (ball, air, aero, table, gravity, adaptation, prediction step) are the ones it was
    /// created with: a change of those needs [`Self::reset`] or a new estimator.
    pub fn reconfigure(&mut self, previous: &Config, config: &Config) {
        let physics = |c: &Config| {
            (
                c.gravity,
                c.ball.clone(),
                c.air.clone(),
                c.aero.clone(),
                c.table.clone(),
                c.adaptation.clone(),
            )
        };
        let mut settings = Settings::new(config);
        if physics(previous) != physics(config) {
            // Not applied live: the physics the tracks were learning from stays.
            let old = Settings::new(previous);
            settings.param_prior = old.param_prior;
            settings.param_prior_var = old.param_prior_var;
            settings.param_dispersion = old.param_dispersion;
            settings.filter.process.param_density = old.filter.process.param_density;
            settings.gravity = old.gravity;
        }
        self.settings = settings;
        self.intercepts
            .reconfigure(config.intercept.refresh.clone());
        if previous.sources != config.sources
            || previous.ekf.learn_noise != config.ekf.learn_noise
            || previous.ekf.noise_memory != config.ekf.noise_memory
        {
            self.noise = NoiseLearner::new(config);
        }
        if previous.ekf.learn_model_noise != config.ekf.learn_model_noise
            || previous.ekf.model_noise_memory != config.ekf.model_noise_memory
            || previous.ekf.model_noise_horizon != config.ekf.model_noise_horizon
            || previous.ekf.spin_measured_acceleration_noise_density
                != config.ekf.spin_measured_acceleration_noise_density
        {
            self.model_noise = ModelNoiseLearner::new(&config.ekf);
            self.sensitivity = live_sensitivity(config);
            self.probe = HorizonProbe::for_config(config);
        }
        let history_capacity = history_capacity(config);
        if history_capacity != self.history_capacity {
            self.history_capacity = history_capacity;
            self.spare_history = VecDeque::with_capacity(history_capacity);
        }
        self.racket = RacketModel::new(config);
    }

    /// Announces the robot's next hit: the first detection after `hit.stamp` that the predicted
    /// rebound explains (the live track's ball carried to the impact, hit by `hit.racket`, with
    /// the covariance of both and of the rubber, [`RacketModel::rebound_covariance`]) starts the
    /// return's track at once, instead of after the initialiser's detections. A later
    /// announcement replaces an earlier one; one that seeds nothing is counted
    /// ([`Counters::hits_not_seeded`]) and the detections go their usual way.
    pub fn expect_hit(&mut self, hit: RobotHit) {
        if self.expected_hit.is_some() {
            self.counters.hits_not_seeded += 1;
        }
        self.expected_hit = Some((hit, None));
    }

    /// Drops the tracks and what was learned (physics, noise), as a new estimator of `config`
    /// would start, keeping the counters and counting track ids on (the node's `~/reset`).
    pub fn reset(&mut self, config: &Config) {
        let counters = self.counters();
        let next_track_id = self.next_track_id;
        *self = Self::new(config);
        self.counters = counters;
        self.next_track_id = next_track_id;
    }

    /// The input has ended (a replayed bag, a recorded flight, a node stopping): the live track
    /// ends here and teaches what it learned (its flight smoothed, `adaptation.smoothed_lessons`),
    /// as when a track ends for a gap. A later detection starts a new track.
    pub fn end_of_input(&mut self) {
        self.end_track();
        self.settle_lesson();
    }

    /// Runs one stage (a pass or a smoothing back over the ended track's detections, about 6
    /// us per detection) of the pending lesson; true while stages remain. A node calls it when
    /// no detection waits, so that the smoothing is off the detections' path; what is learned,
    /// and when it takes effect (the next track's start), are the same whether or not it is
    /// called (a replay never does).
    pub fn learn_in_idle_time(&mut self) -> bool {
        self.advance_lesson()
    }

    /// What the estimator has learned of the physical parameters, to start another estimator
    /// from ([`Self::adopt_learned_physics`]): the ball's and table's, the live track's lesson
    /// included.
    pub fn learned_physics(&self) -> LearnedPhysics {
        LearnedPhysics {
            params: self.learned_with_live_track(),
            model_noise: self.model_noise,
            refit_contest: self.contest.without_held(),
        }
    }

    /// The ball's and table's parameters learned so far (the live track's lesson included as
    /// far as it has come) and their covariance.
    pub(crate) fn learned_global(&self) -> (ParamVector, ParamCovariance) {
        self.learned_with_live_track().global()
    }

    /// Starts from what another estimator (of the same configuration) learned of the physical
    /// parameters, of how far the flights stray from the model and of whether its refits
    /// predict them better than the filter, as if its tracks had been this one's.
    pub fn adopt_learned_physics(&mut self, learned: &LearnedPhysics) {
        self.learned = learned.params;
        self.model_noise = learned.model_noise;
        self.contest = learned.refit_contest;
    }

    fn learned_with_live_track(&self) -> Learned {
        self.track
            .as_ref()
            .map_or(self.learned, |track| track.taught(&self.learned))
    }

    /// The live track's own physical parameters (its flight's, see [`Self::learned_params`] for
    /// the ball's and table's), if a track is live.
    pub fn track_params(&self) -> Option<LearnedParams> {
        let ekf = &self.track.as_ref()?.now.ekf;
        Some(LearnedParams::new(
            &ekf.theta,
            &ekf.param_covariance(),
            self.learned.tracks() + 1,
            &ParamVector::zeros(),
        ))
    }

    /// The physical parameters learned so far, over all tracks (the live one included as far as
    /// it has come); the configured values, with their prior uncertainty, before any track.
    pub fn learned_params(&self) -> LearnedParams {
        self.learned_physics().params()
    }

    /// The propagator at a snapshot's parameters.
    fn propagator_of(&self, snapshot: &Snapshot) -> Propagator {
        self.propagator.with_params(&snapshot.ekf.params())
    }

    /// What happened to the detections so far.
    pub fn counters(&self) -> Counters {
        self.counters
    }

    /// How many interceptions were predicted in full and how many moved to first order from the
    /// last full one (see [`crate::online::intercept::InterceptTracker`]).
    pub fn intercept_counts(&self) -> crate::online::intercept::TrackerCounts {
        self.intercepts.counts()
    }

    /// The propagator the estimator predicts with.
    pub fn propagator(&self) -> &Propagator {
        &self.propagator
    }

    /// The current estimate of the tracked ball, if any.
    pub fn estimate(&self) -> Option<Estimate> {
        self.track
            .as_ref()
            .map(|t| self.estimate_of(t, &t.now, t.now.stamp))
    }

    /// The predicted trajectory of the tracked ball from its current estimate, sampled every
    /// `dt` seconds over `horizon` seconds (for `PredictedTrajectory`; allocates its samples).
    pub fn predicted_trajectory(&self, dt: f64, horizon: f64) -> Option<(i64, Trajectory)> {
        let track = self.track.as_ref()?;
        let start = BallState::from_vector(&track.now.ekf.x);
        Some((track.now.stamp, self.predict_flight(&start, dt, horizon)))
    }

    /// The predicted flight of any ball state with this estimator's model and learned
    /// parameters, sampled every `dt` seconds over `horizon` seconds (events: table, net,
    /// floor, the hitting plane).
    pub fn predict_flight(&self, start: &BallState, dt: f64, horizon: f64) -> Trajectory {
        let options = PredictOptions {
            horizon,
            sample_interval: dt,
            plane_x: Some(self.settings.plane_x),
            stop_at_plane: false,
        };
        let propagator = self.propagator.with_params(&self.learned_params().params);
        predict(&propagator, start, &options)
    }

    /// Counts a detection that an adapter rejected before it reached the filter (e.g. its
    /// message's frame is not `table`), so that every input is accounted for in one place.
    pub fn reject(&mut self, reason: Rejection) {
        self.counters.received += 1;
        self.counters.rejected[reason.index()] += 1;
    }

    /// Takes one detection (in arrival order) and returns the estimate and interception after it:
    /// [`Self::update`], then the interception from the updated state.
    pub fn handle(&mut self, detection: &Detection) -> Output {
        let verdict = self.update(detection);
        self.output(verdict, detection.stamp)
    }

    /// Takes one detection (in arrival order) into the filter, rolling back and re-applying the
    /// newer ones when it is late, without predicting the interception; says what became of it.
    ///
    /// A detection more than `tracking.timeout` before or after the current track's last fused
    /// stamp (or, with no track, the newest detection initialising one) is a jump: a new ball
    /// after a pause, a camera whose clock restarted, or a glitched stamp. It is held ([`Verdict::Held`],
    /// counted as initialising) until the next detection tells which: one within `tracking.timeout` of it
    /// confirms the jump, and both start a new track; one that carries on the current stamps
    /// shows it was a glitch, and it is counted as [`Rejection::StampJump`]. So one bad stamp
    /// never ends a track or stalls the initialiser. The output for a held detection is the
    /// track's estimate, not moved to its stamp.
    pub fn update(&mut self, detection: &Detection) -> Verdict {
        self.counters.received += 1;
        if claims_placeholder_spin(detection) {
            self.counters.zero_spin_ignored += 1;
        }
        let verdict = match self.measurement(detection) {
            Err(reason) => Verdict::Rejected(reason),
            Ok(measurement) => self.screen_jump(detection, measurement),
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

    fn output(&mut self, verdict: Verdict, stamp: i64) -> Output {
        let Some(track) = &self.track else {
            return Output {
                verdict,
                estimate: self.initializing_estimate(),
                intercept: None,
            };
        };
        // A rejected detection newer than the track still moves the estimate to its time (not
        // across a jump: a held or glitched stamp leaves it where it is).
        let snapshot = if stamp > track.now.stamp
            && stamp - track.now.stamp <= self.settings.timeout
            && !matches!(verdict, Verdict::Fused { .. })
        {
            let mut s = track.now;
            self.advance(&mut s, stamp);
            s
        } else {
            track.now
        };
        let estimate = self.estimate_of(track, &snapshot, stamp);
        let query = InterceptQuery {
            plane_x: self.settings.plane_x,
            horizon: self.settings.horizon,
            bounced_on_robot_half: snapshot.robot_half_bounces > 0,
            bounce_noise: self
                .settings
                .filter
                .bounce
                .scaled(self.model_noise.scales(snapshot.spin_measured).bounce),
        };
        let intercept = self.intercepts.predict(
            &self.propagator_of(&snapshot),
            track.id,
            snapshot.stamp,
            &snapshot.ekf.x,
            &snapshot.ekf.P,
            &query,
        );
        Output {
            verdict,
            estimate: Some(estimate),
            intercept: Some(InterceptEstimate {
                stamp: snapshot.stamp,
                track_id: track.id,
                intercept,
            }),
        }
    }

    fn estimate_of(&self, track: &Track, snapshot: &Snapshot, now: i64) -> Estimate {
        let status = if now.max(snapshot.stamp) - snapshot.last_fused > self.settings.coast {
            TrackStatus::Coasting
        } else {
            TrackStatus::Tracking
        };
        Estimate {
            stamp: snapshot.stamp,
            track_id: track.id,
            status,
            state: BallState::from_vector(&snapshot.ekf.x),
            covariance: self.published_covariance(snapshot),
            bounces: snapshot.bounces,
            nis: snapshot.nis,
        }
    }

    /// The covariance an estimate publishes: the filter's, widened near a table contact by the
    /// chance that the ball is on its other side ([`with_contact_side`]).
    fn published_covariance(&self, snapshot: &Snapshot) -> StateMatrix {
        let (x, params) = (&snapshot.ekf.x, snapshot.ekf.params());
        let flight = self.propagator.flight();
        with_contact_side(
            &self
                .propagator
                .bounce()
                .with_table(params.restitution, params.friction),
            (flight.radius(), flight.gravity()),
            x,
            &snapshot.ekf.state_covariance(),
            self.propagator.distance_outside_table(x[0], x[1]) <= 0.0,
            snapshot.bounce_jump.as_ref(),
        )
    }

    /// The provisional estimate of a ball being initialised (from 2 detections on).
    fn initializing_estimate(&self) -> Option<Estimate> {
        if self.pending.len() < 2 {
            return None;
        }
        let fit = self.fit_pending()?;
        Some(Estimate {
            stamp: fit.stamp,
            track_id: self.next_track_id,
            status: TrackStatus::Initializing,
            state: BallState::from_vector(&fit.x),
            covariance: fit.P,
            bounces: 0,
            nis: 0.0,
        })
    }

    /// Checks a detection and turns it into a measurement with its noise, as learned of its
    /// source.
    fn measurement(&self, d: &Detection) -> Result<Measurement, Rejection> {
        let source = self.settings.measurement.source_index(d.source);
        Ok(self
            .settings
            .measurement
            .measure(d)?
            .with_learned_noise(&self.noise.of(source)))
    }

    /// Learns the noise of a detection's source from the innovation of its first fusion (the
    /// one `fuse` left), if any.
    fn learn_noise(&mut self, d: &Detection) {
        if let (Some(innovation), Ok(base)) =
            (self.innovation.take(), self.settings.measurement.measure(d))
        {
            let (r0, spin_r0) = match base {
                Measurement::Position { r, .. } => (r, None),
                Measurement::PositionSpin { r, .. } => (
                    r.fixed_view::<3, 3>(0, 0).into_owned(),
                    Some(r.fixed_view::<3, 3>(3, 3).into_owned()),
                ),
            };
            let innovation = noise::Innovation {
                r0,
                spin: innovation
                    .spin
                    .zip(spin_r0)
                    .map(|((y, hph, _), r0)| (y, hph, r0)),
                ..innovation
            };
            self.noise.learn(
                self.settings.measurement.source_index(d.source),
                &innovation,
            );
        }
        // Only without a horizon (with one the scales learn from the probe's predictions, and
        // the updates score nothing).
        if let Some((score, spin_measured)) = self.score.take() {
            self.model_noise.learn(&score, spin_measured);
        }
    }

    /// What the estimator has learned of how far the flights stray from its model: the scales on
    /// its configured process noise and bounce scatter.
    pub fn learned_model_noise(&self) -> LearnedModelNoise {
        self.model_noise.learned()
    }

    /// Whether the live refits (`ekf.refit_interval`) predict the flights better than the
    /// filter, as far as the contests so far tell (`ekf.refit_when_better`).
    pub fn refit_contest(&self) -> RefitContestScore {
        self.contest.report()
    }

    /// What the estimator has learned of each source's noise, in the order of
    /// [`SourcesParams::all`](crate::config::SourcesParams::all).
    pub fn learned_noise(&self) -> Vec<LearnedSourceNoise> {
        self.settings
            .measurement
            .sources()
            .iter()
            .zip(self.noise.all())
            .map(|(source, estimate)| LearnedSourceNoise {
                source: source.name.clone(),
                position_sigma: source.position_var.sqrt() * estimate.position_scale.sqrt(),
                stamp_sigma: estimate.timing_variance.sqrt(),
                estimate: *estimate,
            })
            .collect()
    }

    fn process(&mut self, d: &Detection, m: Measurement) -> Verdict {
        if let Some((hit, _)) = self.expected_hit
            && d.stamp > hit.stamp
        {
            if let Some(verdict) = self.start_from_hit(&hit, d, m) {
                self.expected_hit = None;
                return verdict;
            }
            if d.stamp - hit.stamp > self.settings.timeout {
                self.expected_hit = None;
                self.counters.hits_not_seeded += 1;
            }
        }
        let Some(track) = &self.track else {
            return self.initialise(d);
        };
        if d.stamp - track.now.last_fused > self.settings.timeout {
            self.end_track();
            return self.initialise(d);
        }
        let result = if d.stamp >= track.now.stamp {
            self.fuse_newest(d, m)
        } else {
            self.fuse_late(d, m)
        };
        match result {
            Ok(nis) => {
                if let Some(track) = self.track.as_mut() {
                    track.consecutive_rejections = 0;
                }
                self.rejected_run.clear();
                Verdict::Fused { nis }
            }
            Err(Rejection::Gated) => self.count_gated(d),
            Err(reason) => Verdict::Rejected(reason),
        }
    }

    /// A gated detection; a run of them ends the track and seeds a new one.
    fn count_gated(&mut self, d: &Detection) -> Verdict {
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
            self.end_track();
            // The rejected run is the ball after a racket hit or a new serve, or the same ball
            // where its prediction was refuted (most often at a bounce): the track it starts
            // keeps the refuted one's id if it is the same ball ([`Self::continues`]).
            self.continuation = Some(refuted);
            while let Some(seed) = self.rejected_run.pop_front() {
                self.insert_pending(&seed);
            }
            if self.pending.len() >= self.settings.init_count {
                self.try_start_track();
            }
        }
        Verdict::Rejected(Rejection::Gated)
    }

    fn end_track(&mut self) {
        self.continuation = None;
        // What the track learned of the physics carries over to the next: its flight smoothed
        // (pending until settled) where it can be, else the filter's estimate.
        let deferred = self.defer_lesson();
        if let Some(track) = self.track.take() {
            if !deferred {
                self.learned = track.taught(&self.learned);
            }
            // Keep the history's buffer for the next track: no allocation per track.
            self.spare_history = track.history;
            self.spare_history.clear();
        }
        self.pending.clear();
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::detection::Source;
    use crate::physics::predict::Sample;
    use nalgebra::Vector3;

    /// A 150 fps serve with a millimetre of noise whose frames put one detection 0.1-0.4 ms
    /// before the table bounce, as detections from 1 s on with their truth.
    fn serve_framed_at_the_bounce(config: &Config) -> Vec<(Detection, BallState)> {
        const FINE: usize = 20;
        let start = BallState::new(
            Vector3::new(1.6, 0.1, 0.3),
            Vector3::new(-5.0, 0.2, 1.0),
            Vector3::new(0.0, 250.0, 10.0),
        );
        let fine = predict(
            &Propagator::new(config),
            &start,
            &PredictOptions {
                horizon: 0.6,
                sample_interval: 1.0 / (150.0 * FINE as f64),
                plane_x: None,
                stop_at_plane: false,
            },
        );
        let bounce = fine
            .samples
            .windows(2)
            .position(|w| w[0].state.velocity.z < 0.0 && w[1].state.velocity.z > 0.0)
            .expect("the serve bounces");
        detections_of(fine.samples.iter().skip(bounce % FINE).step_by(FINE))
    }

    /// A flight's samples as 150 fps detections from 1 s on, with a millimetre of deterministic
    /// noise, each with its truth.
    pub(super) fn detections_of<'a>(
        samples: impl Iterator<Item = &'a Sample>,
    ) -> Vec<(Detection, BallState)> {
        samples
            .enumerate()
            .map(|(k, sample)| {
                let k = k as f64;
                let noise = Vector3::new((1.7 * k).sin(), (2.3 * k).cos(), (0.9 * k).sin()) * 1e-3;
                let detection = Detection {
                    stamp: 1_000_000_000 + (sample.t * 1e9).round() as i64,
                    source: Source::WIDE_150FPS,
                    position: sample.state.position + noise,
                    position_covariance: None,
                    spin: None,
                    spin_covariance: None,
                    confidence: 0.9,
                };
                (detection, sample.state)
            })
            .collect()
    }

    /// The published covariance is the filter's, but at the estimate a fraction of a
    /// millisecond from the table contact, which is widened by the other side's jump in
    /// vertical velocity (`online::contact_side`); the means are the filter's everywhere.
    #[test]
    fn an_estimate_at_the_contact_publishes_its_other_side() {
        let config = Config::default();
        let mut estimator = Estimator::new(&config);
        let mut widened = Vec::new();
        for (detection, truth) in serve_framed_at_the_bounce(&config) {
            let _ = estimator.handle(&detection);
            let (Some(published), Some(track)) = (estimator.estimate(), &estimator.track) else {
                continue;
            };
            assert_eq!(published.state.to_vector(), track.now.ekf.x);
            let filter = track.now.ekf.state_covariance();
            if published.covariance != filter {
                widened.push((
                    truth.position.z - config.ball.radius,
                    published.covariance[(5, 5)] / filter[(5, 5)],
                ));
            }
        }
        // Only the estimate by the contact (the truth within a couple of millimetres of it),
        // its vertical velocity's variance by orders of magnitude.
        assert_eq!(widened.len(), 1, "{widened:?}");
        let (height, ratio) = widened[0];
        assert!(height.abs() < 0.002 && ratio > 100.0, "{widened:?}");
    }
}
