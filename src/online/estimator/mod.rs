//! The estimator: one entry point, [`Estimator::handle`], takes every detection as it arrives
//! and returns the filtered state and the interception predicted from it; the ROS node and the
//! MCAP replay both call it. Behind it three parts keep their own state (docs/estimator.md): the
//! tracker (`tracker.rs`, `fusion.rs`), the adaptation (`adaptation.rs`, `camera_noise.rs`) and
//! the lessons (`lessons.rs`, `smoother.rs`). No heap allocation per detection.

mod adaptation;
mod camera_noise;
mod counters;
mod fusion;
mod lessons;
mod smoother;
mod tracker;

use crate::config::Config;
use crate::model::detection::{Detection, seconds_to_ns};
use crate::online::contact_side::with_contact_side;
use crate::online::ekf::BounceNoise;
use crate::online::intercept::{Intercept, InterceptQuery, InterceptTracker};
pub use crate::online::learned::{
    LearnedParams, LearnedSourceNoise, LearnedSummary, describe_params, describe_source_noise,
};
pub use crate::online::measurement::{MAX_RANGE, Measurement};
use crate::physics::{
    BallState, ParamVector, PhysicsParams, PredictOptions, Propagator, StateMatrix, Trajectory,
    predict,
};
use adaptation::{Adaptation, drift_density};
pub(crate) use adaptation::{
    Learned, SHAPE, ShapeCovariance, ShapeVector, configured_shape, shape_prior_variances,
};
pub use camera_noise::PRIOR_WEIGHT;
pub use camera_noise::SourceNoiseEstimate;
pub use counters::{Counters, Rejection, Verdict};
pub use fusion::{CONTACT_BAND, SPIN_ALONG_FLIGHT_GAIN, SPIN_PARAMETER_SPREAD};
use fusion::{Fusion, Snapshot};
pub use lessons::{Dropped, LESSON_DELAY, LessonCounts, MAX_PENDING, Waiting};
pub use tracker::{INIT_DETECTIONS, REANCHOR_DISTANCE, RobotHit};
use tracker::{Track, Tracker};

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

/// What an estimator has learned of the physical parameters, carried to another
/// ([`Estimator::learned_physics`], [`Estimator::adopt_learned_physics`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LearnedPhysics {
    pub(crate) params: Learned,
}

impl LearnedPhysics {
    /// The ball's and table's parameters it holds, with their uncertainty.
    pub fn params(&self) -> LearnedParams {
        let (theta, covariance) = self.params.global();
        LearnedParams::new(
            &theta,
            &covariance,
            self.params.tracks(),
            &self.params.dispersion(),
        )
        .with_reynolds(self.params.exponents(), self.params.exponent_sigmas())
    }
}

/// What the estimator needs to publish after a detection.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Publishing {
    /// An estimate this long [ns] without a fused detection is coasting.
    coast: i64,
    /// Detections further than this [ns] past the track move nothing.
    timeout: i64,
    /// The hitting plane (x = plane_x) [m] and how far ahead it is looked for [s].
    plane_x: f64,
    horizon: f64,
    /// The bounce's scatter, for a bounce ahead of the interception.
    bounce: BounceNoise,
}

impl Publishing {
    fn new(config: &Config) -> Self {
        Self {
            coast: seconds_to_ns(config.tracking.coast_after),
            timeout: seconds_to_ns(config.tracking.timeout),
            plane_x: config.intercept.plane_x,
            horizon: config.prediction.horizon,
            bounce: BounceNoise::from_config(config),
        }
    }
}

/// A flight to predict: its start, the physics it flies and how it is sampled; a plain value
/// ([`Estimator::trajectory_flight`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Flight {
    /// Time of the start [ns].
    pub stamp: i64,
    /// The ball's state at the start.
    pub start: BallState,
    propagator: Propagator,
    options: PredictOptions,
}

impl Flight {
    /// The predicted trajectory (allocates its samples).
    pub fn fly(&self) -> Trajectory {
        predict(&self.propagator, &self.start, &self.options)
    }
}

/// The estimator (see the module doc).
#[derive(Debug, Clone)]
pub struct Estimator {
    tracker: Tracker,
    adaptation: Adaptation,
    /// The interception kept up to date from detection to detection.
    intercepts: InterceptTracker,
    publishing: Publishing,
}

/// The tracks' model of the flight and of the detections, for `config`.
fn fusion_of(config: &Config) -> Fusion {
    Fusion::new(config, drift_density(config))
}

impl Estimator {
    /// An estimator with the given configuration (assumed validated); its tracks' lessons run
    /// inline ([`Self::run_lessons_on_a_worker`] to run them off the detection path).
    pub fn new(config: &Config) -> Self {
        Self {
            tracker: Tracker::new(config, fusion_of(config)),
            adaptation: Adaptation::new(config),
            intercepts: InterceptTracker::new(config.intercept.refresh.clone()),
            publishing: Publishing::new(config),
        }
    }

    /// Runs the ended tracks' lessons (their flights smoothed) on a worker thread from now on,
    /// fed over channels: off the detection path. What is learned, and from which detection on,
    /// is the same as inline; with [`Waiting::Never`] (a live node) a lesson not done when due
    /// is dropped and counted rather than waited for (`lessons.rs`). An error when the thread
    /// cannot be started (the lessons then go on inline).
    pub fn run_lessons_on_a_worker(&mut self, waiting: Waiting) -> std::io::Result<()> {
        self.adaptation.lessons.spawn_worker(waiting)
    }

    /// How long the detections have spent on the worker's lessons in all, waiting for them or
    /// smoothing the jobs it had not started (with [`Waiting::Wait`]; zero inline or with
    /// [`Waiting::Never`]): time in [`Self::handle`] that is the worker's, for timings of the
    /// detections' own work.
    pub fn lesson_wait(&self) -> std::time::Duration {
        self.adaptation.lessons.waited()
    }

    /// Takes `config`'s estimator, gating, source-noise, tracking and interception values from
    /// the next detection on, keeping the live track, what was learned of the physics and the
    /// counters (the node's `set_parameters`). `previous` is the configuration it ran with: what
    /// was learned of a source's noise starts again from the configured values when they
    /// changed. The physical parameters (ball, air, aero, table, gravity, adaptation, prediction
    /// step) are the ones it was created with: a change of those needs [`Self::reset`] or a new
    /// estimator.
    pub fn reconfigure(&mut self, previous: &Config, config: &Config) {
        let physics = |c: &Config| {
            (
                c.gravity,
                c.ball.clone(),
                c.air.clone(),
                c.aero.clone(),
                c.table.clone(),
                c.adaptation.clone(),
                c.prediction.step,
            )
        };
        let mut fusion = fusion_of(config);
        // The Reynolds exponents are the learned ones.
        let flown = self.tracker.fusion.propagator.flight().reynolds_exponents();
        fusion.propagator = fusion.propagator.with_reynolds_exponents(flown);
        if physics(previous) != physics(config) {
            // Not applied live: the physics the tracks were learning from stays.
            let kept = self.tracker.fusion;
            fusion.propagator = kept.propagator;
            fusion.noise.process.param_density = kept.noise.process.param_density;
        }
        self.tracker.reconfigure(config, fusion);
        self.intercepts
            .reconfigure(config.intercept.refresh.clone());
        self.publishing = Publishing::new(config);
        if previous.sources != config.sources {
            self.adaptation.cameras = camera_noise::NoiseLearner::new(config);
        }
    }

    /// Announces the robot's next hit: the first detection after `hit.stamp` that the predicted
    /// rebound explains (the live track's ball carried to the impact, hit by `hit.racket`, with
    /// the covariance of both and of the rubber, [`crate::physics::RacketModel::rebound_covariance`])
    /// starts the return's track at once, instead of after the initialiser's detections. A
    /// later announcement replaces an earlier one; one that seeds nothing is counted
    /// ([`Counters::hits_not_seeded`]) and the detections go their usual way.
    pub fn expect_hit(&mut self, hit: RobotHit) {
        self.tracker.expect_hit(hit);
    }

    /// Drops the tracks and what was learned (physics, noise, the lessons waiting), as a new
    /// estimator of `config` would start, keeping the counters and counting track ids on (the
    /// node's `~/reset`); a lesson worker goes on.
    pub fn reset(&mut self, config: &Config) {
        let counters = self.tracker.counters;
        let next_track_id = self.tracker.next_track_id;
        self.tracker = Tracker::new(config, fusion_of(config));
        self.tracker.counters = counters;
        self.tracker.next_track_id = next_track_id;
        self.adaptation.reset(config);
        self.intercepts = InterceptTracker::new(config.intercept.refresh.clone());
        self.publishing = Publishing::new(config);
    }

    /// The input has ended (a replayed bag, a recorded flight, a node stopping): the live track
    /// ends here and teaches what it learned, and every lesson waiting is learned. A later
    /// detection starts a new track.
    pub fn end_of_input(&mut self) {
        let now = self
            .tracker
            .track
            .as_ref()
            .map_or(i64::MIN, |t| t.now.stamp);
        self.tracker.end_track(now, &mut self.adaptation);
        self.adaptation.settle();
    }

    /// What the estimator has learned of the physical parameters, to start another estimator
    /// from ([`Self::adopt_learned_physics`]): the ball's and table's, the lessons waiting and
    /// the live track's included as far as they are known.
    pub fn learned_physics(&self) -> LearnedPhysics {
        LearnedPhysics {
            params: self.learned_with_live_track(),
        }
    }

    /// The parameters learned so far (the live track's lesson included as far as it has come),
    /// the ball's and table's and the Reynolds exponents, and their covariance, as learned
    /// (an undetermined exponent's too).
    pub(crate) fn learned_shape(&self) -> (ShapeVector, ShapeCovariance) {
        self.learned_with_live_track().estimate()
    }

    /// Starts from what another estimator (of the same configuration) learned of the physical
    /// parameters, as if its tracks had been this one's.
    pub fn adopt_learned_physics(&mut self, learned: &LearnedPhysics) {
        self.adaptation.physics = learned.params;
    }

    fn learned_with_live_track(&self) -> Learned {
        let learned = self.adaptation.physics_with_waiting_lessons();
        self.tracker.track.as_ref().map_or(learned, |track| {
            learned.absorbed(&track.filter_lesson(&self.tracker.flight))
        })
    }

    /// The live track's own physical parameters (its flight's, see [`Self::learned_params`] for
    /// the ball's and table's), if a track is live.
    pub fn track_params(&self) -> Option<LearnedParams> {
        let ekf = &self.tracker.track.as_ref()?.now.ekf;
        let flown = self.propagator().flight().reynolds_exponents();
        Some(
            LearnedParams::new(
                &ekf.theta,
                &ekf.param_covariance(),
                self.adaptation.physics.tracks() + 1,
                &ParamVector::zeros(),
            )
            .with_reynolds(flown, ([0.0; 2], [0.0; 2])),
        )
    }

    /// The physical parameters learned so far, over all tracks (the live one included as far as
    /// it has come); the configured values, with their prior uncertainty, before any track.
    pub fn learned_params(&self) -> LearnedParams {
        self.learned_physics().params()
    }

    /// What the estimator has learned of each source's noise, in the order of
    /// [`SourcesParams::all`](crate::config::SourcesParams::all).
    pub fn learned_noise(&self) -> Vec<LearnedSourceNoise> {
        self.tracker
            .measurement
            .sources()
            .iter()
            .zip(self.adaptation.cameras.all())
            .map(|(source, estimate)| LearnedSourceNoise {
                source: source.name.clone(),
                position_sigma: source.position_var.sqrt() * estimate.position_scale.sqrt(),
                stamp_sigma: estimate.timing_variance.sqrt(),
                estimate: *estimate,
            })
            .collect()
    }

    /// Everything it has learned so far ([`LearnedSummary`]).
    pub fn learned_summary(&self) -> LearnedSummary {
        LearnedSummary {
            params: self.learned_params(),
            source_noise: self.learned_noise(),
        }
    }

    /// What happened to the detections and to the tracks' lessons so far.
    pub fn counters(&self) -> Counters {
        let lessons = self.adaptation.lessons.counts();
        Counters {
            smoothed_lessons: lessons.smoothed,
            lessons_dropped: lessons.dropped,
            ..self.tracker.counters
        }
    }

    /// How many interceptions were predicted in full and how many moved to first order from the
    /// last full one (see [`crate::online::intercept::InterceptTracker`]).
    pub fn intercept_counts(&self) -> crate::online::intercept::TrackerCounts {
        self.intercepts.counts()
    }

    /// The propagator the estimator predicts with.
    pub fn propagator(&self) -> &Propagator {
        &self.tracker.fusion.propagator
    }

    /// True while a detection whose stamp jumped is held (see [`Self::update`]).
    pub fn holds_a_jump(&self) -> bool {
        self.tracker.holds_a_jump()
    }

    /// The current estimate of the tracked ball, if any.
    pub fn estimate(&self) -> Option<Estimate> {
        self.tracker
            .track
            .as_ref()
            .map(|t| self.estimate_of(t, &t.now, t.now.stamp))
    }

    /// The predicted trajectory of the tracked ball from its current estimate, sampled every
    /// `dt` seconds over `horizon` seconds (for `PredictedTrajectory`; allocates its samples):
    /// [`Self::trajectory_flight`] flown.
    pub fn predicted_trajectory(&self, dt: f64, horizon: f64) -> Option<(i64, Trajectory)> {
        let flight = self.trajectory_flight(dt, horizon)?;
        Some((flight.stamp, flight.fly()))
    }

    /// The flight [`Self::predicted_trajectory`] predicts, as a value to fly anywhere (another
    /// thread: the replay's writer). It flies the live track's own physical parameters, as its
    /// interception does, so that the two agree where the trajectory crosses the hitting plane.
    pub fn trajectory_flight(&self, dt: f64, horizon: f64) -> Option<Flight> {
        let track = self.tracker.track.as_ref()?;
        Some(Flight {
            stamp: track.now.stamp,
            start: BallState::from_vector(&track.now.ekf.x),
            propagator: self.propagator().with_params(&track.now.ekf.params()),
            options: self.flight_options(dt, horizon),
        })
    }

    /// The predicted flight of any ball state with this estimator's model and learned
    /// parameters, sampled every `dt` seconds over `horizon` seconds (events: table, net,
    /// floor, the hitting plane).
    pub fn predict_flight(&self, start: &BallState, dt: f64, horizon: f64) -> Trajectory {
        let learned = self.learned_with_live_track();
        let propagator = self
            .propagator()
            .with_params(&PhysicsParams::from_vector(&learned.global().0))
            .with_reynolds_exponents(learned.exponents());
        predict(&propagator, start, &self.flight_options(dt, horizon))
    }

    fn flight_options(&self, dt: f64, horizon: f64) -> PredictOptions {
        PredictOptions {
            horizon,
            sample_interval: dt,
            plane_x: Some(self.publishing.plane_x),
            stop_at_plane: false,
        }
    }

    /// Counts a detection that an adapter rejected before it reached the filter (e.g. its
    /// message's frame is not `table`), so that every input is accounted for in one place.
    pub fn reject(&mut self, reason: Rejection) {
        self.tracker.counters.received += 1;
        self.tracker.counters.rejected[reason.index()] += 1;
    }

    /// Takes one detection (in arrival order) and returns the estimate and interception after it:
    /// [`Self::update`], then the interception from the updated state.
    pub fn handle(&mut self, detection: &Detection) -> Output {
        let verdict = self.update(detection);
        self.output(verdict, detection.stamp)
    }

    /// Takes one detection (in arrival order) into the filter, rolling back and re-applying the
    /// newer ones when it is late, without predicting the interception; says what became of it.
    /// The lessons due by its stamp are learned first.
    ///
    /// A detection more than `tracking.timeout` before or after the current track's last fused
    /// stamp (or, with no track, the newest detection initialising one) is a jump: a new ball
    /// after a pause, a camera whose clock restarted, or a glitched stamp. It is held
    /// ([`Verdict::Held`], counted as initialising) until the next detection tells which: one
    /// within `tracking.timeout` of it confirms the jump, and both start a new track; one that
    /// carries on the current stamps shows it was a glitch, and it is counted as
    /// [`Rejection::StampJump`]. The output for a held detection is the track's estimate.
    pub fn update(&mut self, detection: &Detection) -> Verdict {
        self.adaptation.learn_due(detection.stamp);
        self.tracker.update(detection, &mut self.adaptation)
    }

    fn output(&mut self, verdict: Verdict, stamp: i64) -> Output {
        let Some(track) = &self.tracker.track else {
            return Output {
                verdict,
                estimate: self.initializing_estimate(),
                intercept: None,
            };
        };
        // A rejected detection newer than the track still moves the estimate to its time (not
        // across a jump: a held or glitched stamp leaves it where it is).
        let snapshot = if stamp > track.now.stamp
            && stamp - track.now.stamp <= self.publishing.timeout
            && !matches!(verdict, Verdict::Fused { .. })
        {
            let mut s = track.now;
            self.tracker.fusion.advance(&mut s, stamp);
            s
        } else {
            track.now
        };
        let estimate = self.estimate_of(track, &snapshot, stamp);
        let query = InterceptQuery {
            plane_x: self.publishing.plane_x,
            horizon: self.publishing.horizon,
            bounced_on_robot_half: snapshot.robot_half_bounces > 0,
            bounce_noise: self.publishing.bounce,
        };
        let intercept = self.intercepts.predict(
            &self.propagator().with_params(&snapshot.ekf.params()),
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
        let status = if now.max(snapshot.stamp) - snapshot.last_fused > self.publishing.coast {
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
        let propagator = self.propagator();
        let flight = propagator.flight();
        with_contact_side(
            &propagator
                .bounce()
                .with_table(params.restitution, params.friction),
            (flight.radius(), flight.gravity()),
            x,
            &snapshot.ekf.state_covariance(),
            propagator.distance_outside_table(x[0], x[1]) <= 0.0,
            snapshot.bounce_jump.as_ref(),
        )
    }

    /// The provisional estimate of a ball being initialised (from 2 detections on).
    fn initializing_estimate(&self) -> Option<Estimate> {
        if self.tracker.pending.len() < 2 {
            return None;
        }
        let fit = self.tracker.fit_pending(&self.adaptation)?;
        Some(Estimate {
            stamp: fit.stamp,
            track_id: self.tracker.next_track_id,
            status: TrackStatus::Initializing,
            state: BallState::from_vector(&fit.x),
            covariance: fit.P,
            bounces: 0,
            nis: 0.0,
        })
    }
}
