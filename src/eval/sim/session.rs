//! A simulated session: shots in sequence (launched 0.4-1.0 s after the previous one ends, half
//! of them real rally balls by default), each flown with the physics core from its launch until
//! 30 ms after it crosses the hitting plane, observed by the cameras; every detection with the
//! true state at its stamp, all sorted by arrival time as the estimator would receive them. A
//! shot from the robot's end (`shots.from_robot_fraction`) is a drawn shot turned half around
//! the vertical through the net's centre: the table, the net and the physics are symmetric so.
//!
//! The truth of a shot is defined by one propagation from its launch ([`ShotTruth::state_at`])
//! with the truth step (0.25 ms by default), fine enough that cutting the flight into other
//! steps (frame to frame, as the cameras do) changes the state by far less than 1e-9.

use std::sync::Arc;

use nalgebra::Vector3;

use super::camera::{Camera, CameraCounts, NS_PER_S};
use super::launch::{
    GoodShot, LaunchCsvError, LaunchRecord, Rejection, ShotCheck, ShotKind, SpinKind, check_shot,
    gdm_rallies, random_launch,
};
use super::params::{Cameras, ParamError, SimParams};
use crate::config::{Config, ConfigError};
use crate::model::detection::{Detection, Source, seconds_to_ns};
use crate::model::rng::{Rng, Stream};

use crate::physics::{BallState, Cursor, Event, Outcome, Propagator, Watch};

/// The default start of a session: 1,700,000,000 s after the Unix epoch [ns] (November 2023),
/// so stamps are as large as a robot's.
pub const DEFAULT_EPOCH: i64 = 1_700_000_000_000_000_000;

/// What to simulate.
#[derive(Debug, Clone, PartialEq)]
pub struct SimOptions {
    /// Cameras, shots and truth parameters.
    pub params: SimParams,
    /// Which cameras deliver detections.
    pub cameras: Cameras,
    /// Number of shots.
    pub shots: usize,
    /// The seed: the whole session is a function of it (and of the rest of the options).
    pub seed: u64,
    /// Start of the session [ns]; the frame clocks start here (plus their random phases).
    pub epoch: i64,
}

impl Default for SimOptions {
    fn default() -> Self {
        Self {
            params: SimParams::default(),
            cameras: Cameras::WideAndHighSpeed,
            shots: 10,
            seed: 0,
            epoch: DEFAULT_EPOCH,
        }
    }
}

/// Why a session could not be simulated.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SimError {
    /// The physics configuration is invalid.
    #[error(transparent)]
    Config(#[from] ConfigError),
    /// A simulator parameter is out of range.
    #[error(transparent)]
    Params(#[from] ParamError),
    /// The embedded launch states cannot be read.
    #[error(transparent)]
    LaunchStates(#[from] LaunchCsvError),
    /// No good shot in `tries` draws.
    #[error("no good {} shot in {tries} draws (last: {last})", kind.name())]
    NoGoodShot {
        /// The kind drawn.
        kind: ShotKind,
        /// Draws made.
        tries: u32,
        /// Why the last one was rejected.
        last: Rejection,
    },
}

/// A moment of a shot's true flight.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TruthEvent {
    /// When [ns], rounded to the nanosecond.
    pub stamp: i64,
    /// When, exactly, after the launch [s].
    pub since_launch: f64,
    /// The true state just before.
    pub before: BallState,
    /// The true state just after (the same as `before` except at a bounce).
    pub after: BallState,
}

impl TruthEvent {
    /// The event of a shot launched at `launch_stamp`, turned half around when `turned`.
    fn new(launch_stamp: i64, event: &Event, turned: bool) -> Self {
        let state = |x| {
            let s = BallState::from_vector(x);
            if turned { half_turn(&s) } else { s }
        };
        Self {
            stamp: launch_stamp + seconds_to_ns(event.t),
            since_launch: event.t,
            before: state(&event.before),
            after: state(&event.after),
        }
    }
}

/// `s` turned half around the vertical through the net's centre (x, y to -x, -y; the spin, an
/// axial vector, turns with them): the same flight played from the other end.
fn half_turn(s: &BallState) -> BallState {
    let turn = |v: Vector3<f64>| Vector3::new(-v.x, -v.y, v.z);
    BallState::new(turn(s.position), turn(s.velocity), turn(s.spin))
}

/// The truth of one shot.
#[derive(Debug, Clone, PartialEq)]
pub struct ShotTruth {
    /// How it was launched.
    pub kind: ShotKind,
    /// The GDM record id of a real launch.
    pub record: Option<u64>,
    /// Launch time [ns].
    pub launch_stamp: i64,
    /// The launch state.
    pub launch: BallState,
    /// The net crossing (`before` = `after`).
    pub net: TruthEvent,
    /// The bounce on the half it flies to (the robot's, unless `from_robot`).
    pub bounce: TruthEvent,
    /// The true crossing of the hitting plane x = `intercept.plane_x` (`before` = `after`); of
    /// the opponent's plane x = -`intercept.plane_x` for a shot from the robot.
    pub intercept: TruthEvent,
    /// Played from the robot's end toward the opponent's: no interception for the robot.
    pub from_robot: bool,
    /// End of the shot [ns]: the plane crossing plus the follow time, when the robot hits it.
    pub end_stamp: i64,
    propagator: Arc<Propagator>,
}

impl ShotTruth {
    /// The true state at `stamp` [ns], propagated from the launch with the truth propagator;
    /// `None` outside [launch_stamp, end_stamp].
    pub fn state_at(&self, stamp: i64) -> Option<BallState> {
        if stamp < self.launch_stamp || stamp > self.end_stamp {
            return None;
        }
        let mut cursor = Cursor::new(0.0, &self.launch);
        let t = (stamp - self.launch_stamp) as f64 / NS_PER_S;
        match self
            .propagator
            .advance(&mut cursor, t, Watch::FLIGHT, &mut ())
        {
            Outcome::Terminated(_) => None,
            _ => Some(cursor.ball()),
        }
    }

    /// The propagator that defines the truth (the configured physics with the truth step).
    pub fn propagator(&self) -> &Propagator {
        &self.propagator
    }
}

/// One detection of the stream with its truth.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SimDetection {
    /// When it reaches the estimator [ns]: its stamp plus the camera's latency.
    pub arrival: i64,
    /// The detection as the estimator receives it.
    pub detection: Detection,
    /// Index of its shot in [`Session::shots`].
    pub shot: usize,
    /// The true state at the detection's stamp.
    pub truth: BallState,
    /// True when the detection is an outlier (displaced 5-30 cm from the ball by default).
    pub outlier: bool,
}

/// How many launch states of one kind were drawn and how many made good shots.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Acceptance {
    /// The kind.
    pub kind: ShotKind,
    /// Launch states drawn.
    pub drawn: u64,
    /// Of those, good shots (used).
    pub accepted: u64,
}

/// What one camera delivered over the session.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CameraReport {
    /// The camera.
    pub source: Source,
    /// Its counts.
    pub counts: CameraCounts,
}

/// A simulated session.
#[derive(Debug, Clone, PartialEq)]
pub struct Session {
    /// The shots, in launch order.
    pub shots: Vec<ShotTruth>,
    /// Every detection of every camera, sorted by arrival time (ties: stamp, then source code).
    pub stream: Vec<SimDetection>,
    /// Launch states drawn and accepted, per kind, in [`ShotKind::ALL`] order.
    pub acceptance: Vec<Acceptance>,
    /// Per camera, what it delivered.
    pub cameras: Vec<CameraReport>,
}

/// Draws launch states until one makes a good shot.
struct Launcher<'a> {
    truth: &'a Propagator,
    aim: Propagator,
    params: &'a SimParams,
    check: ShotCheck,
    records: Vec<LaunchRecord>,
    acceptance: Vec<Acceptance>,
}

impl Launcher<'_> {
    fn draw(
        &mut self,
        rng: &mut Rng,
    ) -> Result<(ShotKind, Option<u64>, BallState, GoodShot), SimError> {
        let shots = &self.params.shots;
        let kind = if rng.bernoulli(shots.real_fraction) {
            ShotKind::Real
        } else {
            ShotKind::from(SpinKind::ALL[rng.index(SpinKind::ALL.len())])
        };
        let slot = kind.index();
        let mut last = Rejection::NotIncoming;
        for _ in 0..shots.max_tries {
            self.acceptance[slot].drawn += 1;
            let (record, launch) = match kind.spin_kind() {
                None => {
                    let r = self.records.get(rng.index(self.records.len()));
                    let r = r.ok_or(SimError::LaunchStates(LaunchCsvError::Empty))?;
                    (Some(r.id), Ok(r.state))
                }
                Some(spin) => (
                    None,
                    random_launch(&self.aim, &shots.random, spin, shots.horizon, rng),
                ),
            };
            match launch.and_then(|s| check_shot(self.truth, &s, &self.check).map(|g| (s, g))) {
                Ok((launch, good)) => {
                    self.acceptance[slot].accepted += 1;
                    return Ok((kind, record, launch, good));
                }
                Err(why) => last = why,
            }
        }
        Err(SimError::NoGoodShot {
            kind,
            tries: shots.max_tries,
            last,
        })
    }
}

/// Simulates a session: `options.shots` good shots observed by `options.cameras`, under the
/// physics of `config` (its hitting plane `intercept.plane_x` ends each shot).
pub fn simulate(config: &Config, options: &SimOptions) -> Result<Session, SimError> {
    config.validate()?;
    let params = &options.params;
    params.validate()?;
    let truth = Arc::new(Propagator::with_step(config, params.truth_step));
    let mut launcher = Launcher {
        truth: &truth,
        aim: Propagator::with_step(config, params.aim_step),
        params,
        check: ShotCheck {
            plane_x: config.intercept.plane_x,
            horizon: params.shots.horizon,
            follow_after_plane: params.shots.follow_after_plane,
            min_plane_height: params.shots.min_plane_height,
        },
        records: gdm_rallies()?,
        acceptance: ShotKind::ALL
            .iter()
            .map(|&kind| Acceptance {
                kind,
                drawn: 0,
                accepted: 0,
            })
            .collect(),
    };
    let seed = options.seed;
    let mut launch_rng = Rng::stream(seed, Stream::Launch);
    let mut schedule_rng = Rng::stream(seed, Stream::Schedule);
    let mut clock_rng = Rng::stream(seed, Stream::Clock);
    let mut cameras = vec![Camera::new(
        &params.wide,
        options.epoch,
        &mut clock_rng,
        Rng::stream(seed, Stream::WideCamera),
        Rng::stream(seed, Stream::WideClockJitter),
    )];
    // The high-speed clock's phase is drawn either way, so the wide camera's is the same.
    let high_speed = Camera::new(
        &params.high_speed,
        options.epoch,
        &mut clock_rng,
        Rng::stream(seed, Stream::HighSpeedCamera),
        Rng::stream(seed, Stream::HighSpeedClockJitter),
    );
    if options.cameras == Cameras::WideAndHighSpeed {
        cameras.push(high_speed);
    }

    let mut shots = Vec::with_capacity(options.shots);
    let mut stream = Vec::new();
    let mut previous_end = options.epoch;
    for index in 0..options.shots {
        let gap = schedule_rng.uniform_in(params.shots.gap.min, params.shots.gap.max);
        let launch_stamp = previous_end + seconds_to_ns(gap);
        let (kind, record, launch, good) = launcher.draw(&mut launch_rng)?;
        let fraction = params.shots.from_robot_fraction;
        // Drawn only when asked for, so that sets without such shots keep their launches.
        let from_robot = fraction > 0.0 && launch_rng.bernoulli(fraction);
        let launch = if from_robot {
            half_turn(&launch)
        } else {
            launch
        };
        let end_stamp =
            launch_stamp + seconds_to_ns(good.plane.t + params.shots.follow_after_plane);
        for camera in &mut cameras {
            for (m, state) in camera.observe(&truth, launch_stamp, &launch, end_stamp) {
                stream.push(SimDetection {
                    arrival: m.arrival,
                    detection: m.detection,
                    shot: index,
                    truth: state,
                    outlier: m.outlier,
                });
            }
        }
        shots.push(ShotTruth {
            kind,
            record,
            launch_stamp,
            launch,
            net: TruthEvent::new(launch_stamp, &good.net, from_robot),
            bounce: TruthEvent::new(launch_stamp, &good.bounce, from_robot),
            intercept: TruthEvent::new(launch_stamp, &good.plane, from_robot),
            from_robot,
            end_stamp,
            propagator: Arc::clone(&truth),
        });
        previous_end = end_stamp;
    }
    stream.sort_by_key(|d| (d.arrival, d.detection.stamp, d.detection.source.0));
    Ok(Session {
        shots,
        stream,
        acceptance: launcher.acceptance,
        cameras: cameras
            .iter()
            .map(|c| CameraReport {
                source: c.params.source,
                counts: c.counts,
            })
            .collect(),
    })
}
