//! A track's lesson of the physics: its flight smoothed when it ends (docs/estimator.md, "The
//! lessons"). The filter is run again over the track's detections, each prediction linearised
//! along the flight the last pass smoothed to, and smoothed back (Rauch-Tung-Striebel): the
//! iterated extended Kalman smoother (Bell 1994), [`ITERATIONS`] passes. A pure function of its
//! [`LessonJob`] ([`Smoother::lesson`]): the same lesson on any thread, at any time.

use super::fusion::{Fusion, Snapshot};
use crate::online::ekf::{Ekf, ParamCovariance, position_H};
use crate::online::measurement::Measurement;
use crate::physics::params::{AUGMENTED, AugmentedMatrix, AugmentedVector};
use crate::physics::{PARAMS, ParamVector};

/// Passes of the smoothing: the first pass is the filter itself, the second one Gauss-Newton
/// step, the third has converged (on the real launcher flights a fourth or sixth moves the
/// crossing's RMS by under 0.05 mm, the learned parameters by under 0.002).
pub const ITERATIONS: usize = 2;

/// Fewest detections a track is smoothed from.
pub const MIN_DETECTIONS: usize = 8;

/// Most detections a track is smoothed from (1.4 s at 180 Hz); a longer track teaches the
/// filter's estimate.
pub const MAX_DETECTIONS: usize = 256;

/// Variance added to each parameter's in the smoother's inverse of a prediction's covariance.
const PARAM_VARIANCE_FLOOR: f64 = 1e-12;

/// The parameters' prior and posterior of a track (mean, covariance).
pub(crate) type ParamEstimate = (ParamVector, ParamCovariance);

/// What a track teaches the ball's and table's parameters.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Lesson {
    /// The parameters' prior the track started from.
    pub(crate) prior: ParamEstimate,
    /// What it learned of them.
    pub(crate) posterior: ParamEstimate,
    /// The track's first and last stamps [ns].
    pub(crate) started: i64,
    pub(crate) ended: i64,
    /// Whether the posterior is the flight smoothed (else the filter's own estimate).
    pub(crate) smoothed: bool,
    /// How the track flew, for what its scales teach of the Reynolds exponents.
    pub(crate) flown: Flown,
}

/// The Reynolds exponents a track flew with and how fast it flew: its scales k_D and k_M are
/// the ball's at f(Re) of its speeds, k_f = k_g f^(a_g - a_flown) (`adaptation.rs`).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub(crate) struct Flown {
    /// (a_D, a_M) of its propagator.
    pub(crate) exponents: [f64; 2],
    /// The mean of ln f(Re) over its fused detections.
    pub(crate) log_f: f64,
}

/// An ended track to smooth: its detections, where its filter started and what it learned.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct LessonJob {
    /// The filter's model of the flight.
    pub(crate) fusion: Fusion,
    /// The track's first estimate.
    pub(crate) base: Snapshot,
    /// Its detections after it and its last estimates' bounces.
    pub(crate) record: TrackRecord,
    /// The filter's lesson, taken when the smoothing fails.
    pub(crate) filter: Lesson,
}

/// What a track keeps for its lesson.
#[derive(Debug, Clone, Default, PartialEq)]
pub(crate) struct TrackRecord {
    /// The track's fused positions after its first estimate, in stamp order: (stamp,
    /// measurement).
    pub(crate) observations: Vec<(i64, Measurement)>,
    /// The track's last estimates' (stamp, bounces), which the smoothed pass must bounce with.
    pub(crate) recent_bounces: Vec<(i64, u32)>,
}

impl TrackRecord {
    /// Room for [`MAX_DETECTIONS`] detections.
    pub(crate) fn with_room() -> Self {
        Self {
            observations: Vec::with_capacity(MAX_DETECTIONS),
            recent_bounces: Vec::with_capacity(MAX_DETECTIONS),
        }
    }

    /// Empties it for another track.
    pub(crate) fn clear(&mut self) {
        self.observations.clear();
        self.recent_bounces.clear();
    }
}

/// One step of a pass: the estimate predicted to a detection and after it.
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
    /// Table bounces since the first estimate.
    bounces: u32,
}

/// The smoother's working buffers, allocated once.
#[derive(Debug, Clone, Default)]
pub(crate) struct Smoother {
    /// The last pass, one step per observation.
    steps: Vec<Step>,
    /// The smoothed (state, parameters) at the first estimate's stamp and each step's: the next
    /// pass's nominal.
    smoothed: Vec<(i64, AugmentedVector)>,
}

/// (x, theta) of an estimate.
fn augmented(ekf: &Ekf) -> AugmentedVector {
    let mut y = AugmentedVector::zeros();
    y.fixed_rows_mut::<9>(0).copy_from(&ekf.x);
    y.fixed_rows_mut::<PARAMS>(9).copy_from(&ekf.theta);
    y
}

impl Smoother {
    /// Room for [`MAX_DETECTIONS`] detections.
    pub(crate) fn new() -> Self {
        Self {
            steps: Vec::with_capacity(MAX_DETECTIONS),
            smoothed: Vec::with_capacity(MAX_DETECTIONS + 1),
        }
    }

    /// The track's lesson (see the module doc).
    pub(crate) fn lesson(&mut self, job: &LessonJob) -> Lesson {
        self.smoothed.clear();
        for iteration in 0..ITERATIONS {
            self.pass(job);
            if iteration + 1 < ITERATIONS {
                self.smooth_back(job);
            }
        }
        match (self.steps.last(), self.agrees(job)) {
            (Some(last), true) => Lesson {
                posterior: (last.filtered.theta, last.filtered.param_covariance()),
                smoothed: true,
                ..job.filter
            },
            _ => job.filter,
        }
    }

    /// The filter run over the job's detections from its first estimate, each prediction
    /// linearised at the last smoothed flight where it has one (at the pass's own estimate
    /// where not, as the filter does). Detections are positions, each fused once already: no
    /// gate.
    fn pass(&mut self, job: &LessonJob) {
        let fusion = &job.fusion;
        let mut snapshot = job.base;
        self.steps.clear();
        let (mut previous, mut bounces) = (snapshot.stamp, 0);
        for (stamp, m) in &job.record.observations {
            let at = self.smoothed.partition_point(|(k, _)| *k < previous);
            let nominal = match self.smoothed.get(at) {
                Some((k, y)) if *k == previous => *y,
                _ => augmented(&snapshot.ekf),
            };
            let prediction = snapshot.ekf.predict_about(
                (
                    &nominal.fixed_rows::<9>(0).into_owned(),
                    &nominal.fixed_rows::<PARAMS>(9).into_owned(),
                ),
                &fusion.propagator,
                &fusion.noise,
                (stamp - previous) as f64 * 1e-9,
            );
            bounces += prediction.report.bounces;
            snapshot.ekf = prediction.ekf;
            let predicted = (augmented(&snapshot.ekf), snapshot.ekf.P);
            if let (Measurement::Position { z, r, .. }, _) = fusion.measurement_at(&snapshot, m) {
                let gain = fusion.along_flight_gain(job.base.bounces + bounces);
                if let Ok(update) =
                    snapshot
                        .ekf
                        .update_partially(&z, &position_H(), &r, f64::INFINITY, gain)
                {
                    snapshot.ekf = update.ekf;
                }
            }
            self.steps.push(Step {
                stamp: *stamp,
                predicted,
                transition: prediction.F,
                filtered: snapshot.ekf,
                bounces,
            });
            previous = *stamp;
        }
    }

    /// The Rauch-Tung-Striebel smoother back over the last pass: the smoothed (state,
    /// parameters) at the first estimate's stamp and every step's, the next pass's nominal
    /// (none where it fails).
    fn smooth_back(&mut self, job: &LessonJob) {
        self.smoothed.clear();
        let Some(last) = self.steps.last() else {
            return;
        };
        let mut later = augmented(&last.filtered);
        if !later.iter().all(|v| v.is_finite()) {
            return;
        }
        self.smoothed.push((last.stamp, later));
        // Step k's filtered estimate with step k + 1's prediction and transition.
        for k in (0..self.steps.len()).rev() {
            let next = &self.steps[k];
            let (stamp, filtered) = match k.checked_sub(1) {
                Some(j) => (self.steps[j].stamp, &self.steps[j].filtered),
                None => (job.base.stamp, &job.base.ekf),
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
            // C (later - predicted), C = P_k Phi' P_{k+1|k}^-1: only the mean is smoothed, so
            // one solve and two products with a vector, never C itself.
            let innovation = chol.solve(&(later - next.predicted.0));
            later = augmented(filtered) + filtered.P * (next.transition.tr_mul(&innovation));
            if !later.iter().all(|v| v.is_finite()) {
                self.smoothed.clear();
                return;
            }
            self.smoothed.push((stamp, later));
        }
        self.smoothed.reverse();
    }

    /// Whether the last pass bounces on the table as the track's last estimates did, at every
    /// stamp they share, and is finite throughout.
    fn agrees(&self, job: &LessonJob) -> bool {
        let step_at = |stamp: i64| {
            let at = self.steps.partition_point(|step| step.stamp < stamp);
            self.steps.get(at).filter(|step| step.stamp == stamp)
        };
        let finite = |ekf: &Ekf| {
            ekf.x
                .iter()
                .chain(ekf.theta.iter())
                .chain(ekf.P.iter())
                .all(|v| v.is_finite())
        };
        job.record.recent_bounces.iter().all(|&(stamp, bounces)| {
            step_at(stamp).is_none_or(|step| bounces == job.base.bounces + step.bounces)
        }) && self.steps.iter().all(|s| finite(&s.filtered))
    }
}
