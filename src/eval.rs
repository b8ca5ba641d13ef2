//! Accuracy of the estimator on a simulated session, against the simulator's truth: the numbers
//! of the README's accuracy table.
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

use nalgebra::{Matrix2, Vector2, Vector3};

use crate::config::Config;
use crate::detection::Source;
use crate::estimator::{Counters, Estimator, Output, TrackStatus};
use crate::sim::Session;

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

/// Root mean square, median and count of a set of errors.
#[derive(Debug, Clone, Copy, PartialEq, Default, serde::Serialize)]
pub struct ErrorStats {
    /// Number of values.
    pub count: usize,
    /// Root mean square.
    pub rms: f64,
    /// Median of the absolute values.
    pub median: f64,
    /// 95th percentile of the absolute values.
    pub p95: f64,
}

impl ErrorStats {
    /// The statistics of `values` (absolute values for the median and percentile).
    pub fn of(values: &[f64]) -> Self {
        if values.is_empty() {
            return Self::default();
        }
        let mut sorted: Vec<f64> = values.iter().map(|v| v.abs()).collect();
        sorted.sort_by(f64::total_cmp);
        let at = |q: f64| sorted[((sorted.len() - 1) as f64 * q).round() as usize];
        Self {
            count: values.len(),
            rms: (values.iter().map(|v| v * v).sum::<f64>() / values.len() as f64).sqrt(),
            median: at(0.5),
            p95: at(0.95),
        }
    }
}

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
    /// What the estimator did with the detections.
    #[serde(skip)]
    pub counters: Counters,
}

/// What was kept of one shot while the session ran.
#[derive(Debug, Clone, Default)]
struct ShotRecord {
    track_start: Option<i64>,
    scored_at_age: bool,
    high_speed_start: Option<i64>,
    /// (estimate stamp, output) of the latest estimate before each lead's time.
    at_lead: [Option<Output>; 3],
}

/// Runs the estimator over the session and scores it.
pub fn evaluate(config: &Config, session: &Session) -> EvalReport {
    let mut estimator = Estimator::new(config);
    let mut records = vec![ShotRecord::default(); session.shots.len()];
    let mut velocity = Vec::new();
    let mut spin = Vec::new();
    let mut spin_perp = Vec::new();
    let mut spin_par = Vec::new();
    let mut spin_fast = Vec::new();
    let mut velocity_fast = Vec::new();
    let mut velocity_bounce = Vec::new();
    let mut nees_sum = 0.0;
    let mut block_sum = [0.0; 3];
    let mut bounce_sum = [(0.0, 0usize); 2];
    let mut nees_count = 0usize;

    for sim in &session.stream {
        let out = estimator.handle(&sim.detection);
        let Some(shot) = session.shots.get(sim.shot) else {
            continue;
        };
        let record = &mut records[sim.shot];
        let Some(estimate) = out
            .estimate
            .filter(|e| e.status != TrackStatus::Initializing)
        else {
            continue;
        };
        for (slot, lead) in LEADS.iter().enumerate() {
            let deadline = shot.intercept.stamp - (lead * 1e9).round() as i64;
            if estimate.stamp <= deadline {
                record.at_lead[slot] = Some(out);
            }
        }
        // State errors only where the estimate is at the detection's own stamp (its truth).
        if estimate.stamp != sim.detection.stamp || sim.outlier {
            continue;
        }
        let start = *record.track_start.get_or_insert(estimate.stamp);
        let error = estimate.state.to_vector() - sim.truth.to_vector();
        if (sim.detection.stamp - shot.bounce.stamp).abs() <= (BOUNCE_WINDOW * 1e9) as i64 {
            velocity_bounce.push((estimate.state.velocity - sim.truth.velocity).norm());
            continue;
        }
        if let Some(chol) = estimate.covariance.cholesky() {
            let nees = error.dot(&chol.solve(&error)) / 9.0;
            nees_sum += nees;
            nees_count += 1;
            let side = &mut bounce_sum[usize::from(sim.detection.stamp >= shot.bounce.stamp)];
            side.0 += nees;
            side.1 += 1;
            for (block, sum) in block_sum.iter_mut().enumerate() {
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
        let spin_error: Vector3<f64> = estimate.state.spin - sim.truth.spin;
        if !record.scored_at_age && estimate.stamp - start >= (TRACK_AGE * 1e9) as i64 {
            record.scored_at_age = true;
            velocity.push((estimate.state.velocity - sim.truth.velocity).norm());
            let along = sim.truth.velocity.normalize();
            let parallel = spin_error.dot(&along);
            spin.push(spin_error.norm());
            spin_par.push(parallel);
            spin_perp.push((spin_error - along * parallel).norm());
        }
        if sim.detection.source == Source::HighSpeed900Fps {
            let first = *record.high_speed_start.get_or_insert(sim.detection.stamp);
            if sim.detection.stamp - first >= (HIGH_SPEED_SETTLE * 1e9) as i64 {
                spin_fast.push(spin_error.norm());
                velocity_fast.push((estimate.state.velocity - sim.truth.velocity).norm());
            }
        }
    }

    let leads = LEADS
        .iter()
        .enumerate()
        .map(|(slot, &lead)| lead_report(session, &records, slot, lead))
        .collect();
    EvalReport {
        shots: session.shots.len(),
        detections: session.stream.len(),
        velocity_error: ErrorStats::of(&velocity),
        spin_error: ErrorStats::of(&spin),
        spin_error_perpendicular: ErrorStats::of(&spin_perp),
        spin_error_parallel: ErrorStats::of(&spin_par),
        spin_error_high_speed: ErrorStats::of(&spin_fast),
        velocity_error_high_speed: ErrorStats::of(&velocity_fast),
        velocity_error_at_bounce: ErrorStats::of(&velocity_bounce),
        state_nees: if nees_count > 0 {
            nees_sum / nees_count as f64
        } else {
            f64::NAN
        },
        block_nees: block_sum.map(|b| b / nees_count.max(1) as f64),
        bounce_nees: bounce_sum.map(|(sum, n)| sum / n.max(1) as f64),
        leads,
        counters: estimator.counters(),
    }
}

fn lead_report(session: &Session, records: &[ShotRecord], slot: usize, lead: f64) -> LeadReport {
    let mut position = Vec::new();
    let mut time = Vec::new();
    let mut nees = Vec::new();
    let mut valid = 0usize;
    for (shot, record) in session.shots.iter().zip(records) {
        let Some(crossing) = record.at_lead[slot]
            .and_then(|out| out.intercept)
            .and_then(|i| i.intercept.crossing.ok().map(|c| (i.stamp, c)))
        else {
            continue;
        };
        let (stamp, crossing) = crossing;
        valid += 1;
        let truth = shot.intercept.before.position;
        let error = Vector2::new(
            crossing.state.position.y - truth.y,
            crossing.state.position.z - truth.z,
        );
        position.push(error.norm());
        let predicted = stamp as f64 * 1e-9 + crossing.time;
        time.push(predicted - shot.intercept.stamp as f64 * 1e-9);
        let cov = Matrix2::new(
            crossing.covariance[(1, 1)],
            crossing.covariance[(1, 2)],
            crossing.covariance[(2, 1)],
            crossing.covariance[(2, 2)],
        );
        if let Some(chol) = cov.cholesky() {
            nees.push(error.dot(&chol.solve(&error)) / 2.0);
        }
    }
    let shots = session.shots.len();
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
