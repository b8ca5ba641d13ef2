//! Batch fit of one flight: the state at the first detection (position, velocity, spin) that best
//! explains every detection of the flight, through its bounces, with the physics core. The
//! offline counterpart of the filter (it sees the whole flight) and the base of calibration
//! (seed 004 eq. 8-9 fit flights this way).
//!
//! Maximum a posteriori with a weak prior on spin (`ekf.spin_prior_sigma` about 0, the filter's
//! own prior; without it a flight seen by the 150 fps camera alone leaves spin nearly
//! unobservable): minimise
//!
//! ```text
//! sum_i rho(|L_i^-1 (z_i - h(x(t_i)))|^2) + |w_0 / sigma_w|^2,   x(t_i) = flow(x_0, t_i - t_0)
//! ```
//!
//! with L_i the Cholesky factor of detection i's noise (its own covariance, else its source's, as
//! the filter takes it), h the position (and the spin when measured), rho Huber's loss on the
//! whitened residual's length (threshold [`HUBER_THRESHOLD`]), solved by Levenberg-Marquardt with
//! iteratively reweighted least squares. The Jacobian of every prediction is the propagator's
//! state-transition matrix, bounces included (the saltation terms of [`crate::physics::propagate`]).
//! The covariance of the fit is the inverse of the weighted Gauss-Newton matrix at the solution.

use nalgebra::{SMatrix, Vector3};
use thiserror::Error;

use crate::config::Config;
use crate::detection::Detection;
use crate::estimator::{Measurement, Rejection, Settings, measurement};
use crate::physics::propagate::{Cursor, Propagator, Watch};
use crate::physics::state::{BallState, SPIN, StateMatrix, StateVector};

/// Nanoseconds per second.
const NS_PER_S: f64 = 1e9;
/// Whitened residual length beyond which a detection's weight falls (Huber), in sigmas.
pub const HUBER_THRESHOLD: f64 = 3.0;
/// Largest number of Levenberg-Marquardt iterations.
const MAX_ITERATIONS: usize = 60;
/// Relative cost change at which the fit has converged.
const COST_TOLERANCE: f64 = 1e-12;

/// A fitted flight.
#[derive(Debug, Clone, PartialEq)]
pub struct FlightFit {
    /// Stamp of the first detection, the time of `start` [ns].
    pub start_stamp: i64,
    /// The fitted state at `start_stamp`.
    pub start: BallState,
    /// Its covariance.
    pub covariance: StateMatrix,
    /// Detections used, in stamp order (rejected ones left out).
    pub used: usize,
    /// Detections the filter would reject too (non-finite, bad covariance, ...), by reason.
    pub rejected: Vec<Rejection>,
    /// Detections down-weighted as outliers by the robust loss at the solution.
    pub outliers: usize,
    /// Root mean square of the whitened residuals of the inliers, per dimension [-] (about 1
    /// when the noise model is right).
    pub normalised_rms: f64,
    /// Iterations used.
    pub iterations: usize,
}

/// Why a flight cannot be fitted.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum FitError {
    /// Fewer usable detections than the three a state needs.
    #[error("a flight needs at least 3 usable detections, got {0}")]
    TooFew(usize),
    /// The initial guess is not finite.
    #[error("the initial guess has a non-finite value")]
    BadGuess,
    /// The normal equations are singular (e.g. all detections at one time).
    #[error("the detections do not determine the flight (singular normal equations)")]
    Singular,
}

/// One usable detection: time since the first [s] and its measurement.
struct Observation {
    t: f64,
    measurement: Measurement,
}

/// The weighted normal equations of one linearisation.
struct Linearised {
    normal: StateMatrix,
    gradient: StateVector,
    cost: f64,
    outliers: usize,
    inlier_squares: f64,
    inlier_dims: usize,
}

/// Fits the flight of `detections` (one ball, any order) from the guess `initial` of the state at
/// the earliest detection.
pub fn fit_flight(
    config: &Config,
    detections: &[Detection],
    initial: &BallState,
) -> Result<FlightFit, FitError> {
    let settings = Settings::new(config);
    let propagator = Propagator::new(config);
    let spin_prior = config.ekf.spin_prior_sigma;
    let mut sorted: Vec<&Detection> = detections.iter().collect();
    sorted.sort_by_key(|d| d.stamp);
    let start_stamp = sorted.first().map_or(0, |d| d.stamp);
    let mut observations = Vec::with_capacity(sorted.len());
    let mut rejected = Vec::new();
    for d in sorted {
        match measurement(&settings, d) {
            Ok(m) => observations.push(Observation {
                t: (d.stamp - start_stamp) as f64 / NS_PER_S,
                measurement: m,
            }),
            Err(why) => rejected.push(why),
        }
    }
    if observations.len() < 3 {
        return Err(FitError::TooFew(observations.len()));
    }
    let mut x = initial.to_vector();
    if x.iter().any(|v| !v.is_finite()) {
        return Err(FitError::BadGuess);
    }
    // Least squares first (a far guess would make most detections look like outliers), from
    // several spins: a wrong spin moves the bounce and can trap the fit in a local minimum, so
    // the guess is also tried with 150 and 300 rad/s of topspin and of backspin and 150 rad/s of
    // sidespin either way added, and the best start kept. Then Huber's loss from there.
    let least_squares =
        |x: &StateVector| linearise(&propagator, &observations, spin_prior, f64::INFINITY, x);
    let velocity = initial.velocity;
    let topspin_axis = Vector3::z()
        .cross(&velocity)
        .try_normalize(1e-9)
        .unwrap_or_default();
    let mut iterations = 0;
    let mut best: Option<(StateVector, f64)> = None;
    for extra in [
        Vector3::zeros(),
        topspin_axis * 150.0,
        topspin_axis * -150.0,
        topspin_axis * 300.0,
        topspin_axis * -300.0,
        Vector3::z() * 150.0,
        Vector3::z() * -150.0,
    ] {
        let mut start = x;
        for k in 0..3 {
            start[SPIN + k] += extra[k];
        }
        let (solution, at, used) = levenberg_marquardt(&least_squares, start);
        iterations += used;
        if best.is_none_or(|(_, cost)| at.cost < cost) {
            best = Some((solution, at.cost));
        }
    }
    if let Some((solution, _)) = best {
        x = solution;
    }
    let robust =
        |x: &StateVector| linearise(&propagator, &observations, spin_prior, HUBER_THRESHOLD, x);
    let (solution, current, used) = levenberg_marquardt(&robust, x);
    x = solution;
    iterations += used;
    let covariance = current.normal.try_inverse().ok_or(FitError::Singular)?;
    Ok(FlightFit {
        start_stamp,
        start: BallState::from_vector(&x),
        covariance: (covariance + covariance.transpose()) * 0.5,
        used: observations.len(),
        rejected,
        outliers: current.outliers,
        normalised_rms: (current.inlier_squares / current.inlier_dims.max(1) as f64).sqrt(),
        iterations,
    })
}

/// Minimises the cost `linearise` describes from `x`: the solution, the linearisation there and
/// the iterations used.
fn levenberg_marquardt(
    linearise: &impl Fn(&StateVector) -> Linearised,
    start: StateVector,
) -> (StateVector, Linearised, usize) {
    let mut x = start;
    let mut current = linearise(&x);
    let mut lambda = 1e-3;
    for iteration in 1..=MAX_ITERATIONS {
        let mut accepted = None;
        for _ in 0..20 {
            let mut damped = current.normal;
            for k in 0..9 {
                damped[(k, k)] += lambda * current.normal[(k, k)].max(1e-12);
            }
            let Some(step) = damped.cholesky().map(|c| c.solve(&(-current.gradient))) else {
                lambda *= 10.0;
                continue;
            };
            let candidate = x + step;
            let next = linearise(&candidate);
            if next.cost.is_finite() && next.cost <= current.cost {
                accepted = Some((candidate, next));
                break;
            }
            lambda *= 10.0;
        }
        let Some((candidate, next)) = accepted else {
            return (x, current, iteration);
        };
        let change = (current.cost - next.cost) / current.cost.max(f64::MIN_POSITIVE);
        x = candidate;
        current = next;
        lambda = (lambda / 10.0).max(1e-12);
        if change < COST_TOLERANCE {
            return (x, current, iteration);
        }
    }
    (x, current, MAX_ITERATIONS)
}

impl FlightFit {
    /// The fitted state and its covariance at `stamp` [ns] (at or after the start), through the
    /// bounces, with the fit's physics (`Propagator::new` of the fitted configuration); `None`
    /// before the start.
    pub fn state_at(
        &self,
        propagator: &Propagator,
        stamp: i64,
    ) -> Option<(BallState, StateMatrix)> {
        if stamp < self.start_stamp {
            return None;
        }
        let mut cursor = Cursor::with_jacobian(0.0, &self.start);
        let t = (stamp - self.start_stamp) as f64 / NS_PER_S;
        propagator.advance(&mut cursor, t, Watch::BOUNCES, &mut ());
        let phi = cursor
            .tangent
            .map_or(StateMatrix::identity(), |t| t.transition);
        Some((cursor.ball(), phi * self.covariance * phi.transpose()))
    }
}

/// The robust, weighted normal equations at `x`: every observation's whitened residual and
/// Jacobian from one propagation with the state-transition matrix, plus the spin prior.
fn linearise(
    propagator: &Propagator,
    observations: &[Observation],
    spin_prior: f64,
    threshold: f64,
    x: &StateVector,
) -> Linearised {
    let mut out = Linearised {
        normal: StateMatrix::zeros(),
        gradient: StateVector::zeros(),
        cost: 0.0,
        outliers: 0,
        inlier_squares: 0.0,
        inlier_dims: 0,
    };
    let mut cursor = Cursor::tracking(0.0, *x);
    for o in observations {
        let duration = o.t - cursor.t;
        propagator.advance(&mut cursor, duration, Watch::BOUNCES, &mut ());
        let phi = cursor
            .tangent
            .map_or(StateMatrix::identity(), |t| t.transition);
        let state = cursor.state;
        match &o.measurement {
            Measurement::Position { z, r } => {
                let residual = z - state.fixed_rows::<3>(0);
                let jacobian: SMatrix<f64, 3, 9> = phi.fixed_rows::<3>(0).into_owned();
                accumulate(&mut out, threshold, r, &residual, &jacobian);
            }
            Measurement::PositionSpin { z, r } => {
                let mut predicted = SMatrix::<f64, 6, 1>::zeros();
                predicted
                    .fixed_rows_mut::<3>(0)
                    .copy_from(&state.fixed_rows::<3>(0));
                predicted
                    .fixed_rows_mut::<3>(3)
                    .copy_from(&state.fixed_rows::<3>(SPIN));
                let mut jacobian = SMatrix::<f64, 6, 9>::zeros();
                jacobian
                    .fixed_rows_mut::<3>(0)
                    .copy_from(&phi.fixed_rows::<3>(0));
                jacobian
                    .fixed_rows_mut::<3>(3)
                    .copy_from(&phi.fixed_rows::<3>(SPIN));
                accumulate(&mut out, threshold, r, &(z - predicted), &jacobian);
            }
        }
    }
    // The spin prior: w_0 ~ N(0, sigma^2 I).
    if spin_prior > 0.0 {
        let information = 1.0 / (spin_prior * spin_prior);
        for k in SPIN..SPIN + 3 {
            out.normal[(k, k)] += information;
            out.gradient[k] += information * x[k];
            out.cost += information * x[k] * x[k];
        }
    }
    out
}

/// Adds one observation (noise `r`, residual z - h, Jacobian dh/dx_0) with its Huber weight.
fn accumulate<const D: usize>(
    out: &mut Linearised,
    threshold: f64,
    r: &SMatrix<f64, D, D>,
    residual: &SMatrix<f64, D, 1>,
    jacobian: &SMatrix<f64, D, 9>,
) {
    let Some(cholesky) = r.cholesky() else {
        return;
    };
    let l = cholesky.l();
    let (Some(white), Some(white_jacobian)) = (
        l.solve_lower_triangular(residual),
        l.solve_lower_triangular(jacobian),
    ) else {
        return;
    };
    let length = white.norm();
    // Huber: quadratic within the threshold, linear beyond; IRLS weight k / |r| there.
    let (weight, cost) = if length <= threshold {
        out.inlier_squares += length * length;
        out.inlier_dims += D;
        (1.0, length * length)
    } else {
        out.outliers += 1;
        (
            threshold / length,
            2.0 * threshold * length - threshold * threshold,
        )
    };
    out.normal += white_jacobian.transpose() * white_jacobian * weight;
    // d(cost)/dx_0 / 2 = -J^T r (the residual falls as h rises).
    out.gradient -= white_jacobian.transpose() * white * weight;
    out.cost += cost;
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::detection::Source;
    use nalgebra::{Matrix3, Vector3};

    /// A flight through a bounce, seen every 10 ms, with a spin-measuring detection every 30 ms.
    fn observations(truth: &BallState, propagator: &Propagator) -> Vec<Observation> {
        let mut cursor = Cursor::new(0.0, truth);
        let mut out = Vec::new();
        for k in 0..60 {
            let t = 0.01 * f64::from(k);
            let duration = t - cursor.t;
            propagator.advance(&mut cursor, duration, Watch::BOUNCES, &mut ());
            let p = cursor.state.fixed_rows::<3>(0).into_owned();
            let measurement = if k % 3 == 0 {
                let mut z = SMatrix::<f64, 6, 1>::zeros();
                z.fixed_rows_mut::<3>(0)
                    .copy_from(&(p + Vector3::new(1e-3, -2e-3, 1e-3)));
                z.fixed_rows_mut::<3>(3).copy_from(
                    &(cursor.state.fixed_rows::<3>(SPIN) + Vector3::new(5.0, -3.0, 2.0)),
                );
                let mut r = SMatrix::<f64, 6, 6>::identity() * 1e-6;
                for i in 3..6 {
                    r[(i, i)] = 144.0;
                }
                Measurement::PositionSpin { z, r }
            } else {
                Measurement::Position {
                    z: p + Vector3::new(-1e-3, 1e-3, 2e-3),
                    r: Matrix3::identity() * 4e-6,
                }
            };
            out.push(Observation { t, measurement });
        }
        out
    }

    /// A topspin ball on its way to a bounce on the robot's half, with the default physics.
    fn topspin_flight() -> (Config, Propagator, BallState) {
        let config = Config::default();
        let propagator = Propagator::new(&config);
        let truth = BallState::new(
            Vector3::new(1.2, 0.1, 0.3),
            Vector3::new(-6.0, -0.3, 1.0),
            Vector3::new(10.0, -150.0, 20.0),
        );
        (config, propagator, truth)
    }

    /// The gradient of the normal equations (J^T r from the state-transition matrix, through a
    /// bounce) equals half the finite-difference gradient of the cost.
    #[test]
    fn gradient_from_the_transition_matrix_matches_finite_differences() {
        let (_, propagator, truth) = topspin_flight();
        let obs = observations(&truth, &propagator);
        let mut x = truth.to_vector();
        x[3] += 0.02;
        x[7] += 15.0;
        let at = linearise(&propagator, &obs, 300.0, HUBER_THRESHOLD, &x);
        assert!(at.outliers > 0, "the Huber branch is checked too");
        for k in 0..9 {
            let h = if k < SPIN { 1e-6 } else { 1e-3 };
            let mut plus = x;
            plus[k] += h;
            let mut minus = x;
            minus[k] -= h;
            let fd = (linearise(&propagator, &obs, 300.0, HUBER_THRESHOLD, &plus).cost
                - linearise(&propagator, &obs, 300.0, HUBER_THRESHOLD, &minus).cost)
                / (2.0 * h);
            let analytic = 2.0 * at.gradient[k];
            assert!(
                (fd - analytic).abs() <= 1e-4 * analytic.abs().max(1.0),
                "component {k}: finite differences {fd}, analytic {analytic}"
            );
        }
    }

    fn detection(stamp: i64, position: Vector3<f64>) -> Detection {
        Detection {
            stamp,
            source: Source::Wide150Fps,
            position,
            position_covariance: None,
            spin: None,
            spin_covariance: None,
            confidence: 1.0,
        }
    }

    /// Noise-free detections of a bouncing flight give back its state, from a rough guess; a
    /// gross outlier is down-weighted and changes almost nothing.
    #[test]
    fn recovers_the_flight_through_a_bounce_and_shrugs_off_an_outlier() {
        let (config, propagator, truth) = topspin_flight();
        let mut cursor = Cursor::new(0.0, &truth);
        let mut detections = Vec::new();
        for k in 0..90 {
            let t = f64::from(k) / 150.0;
            let duration = t - cursor.t;
            propagator.advance(&mut cursor, duration, Watch::BOUNCES, &mut ());
            detections.push(detection(
                1_000_000_000 + (t * 1e9).round() as i64,
                cursor.state.fixed_rows::<3>(0).into_owned(),
            ));
        }
        let guess = BallState::new(
            truth.position + Vector3::new(0.01, -0.01, 0.005),
            truth.velocity + Vector3::new(0.2, 0.1, -0.1),
            Vector3::zeros(),
        );
        let fit = fit_flight(&config, &detections, &guess).expect("fit");
        assert!(
            (fit.start.position - truth.position).norm() < 1e-6,
            "{fit:?}"
        );
        assert!(
            (fit.start.velocity - truth.velocity).norm() < 1e-5,
            "{fit:?}"
        );
        assert!((fit.start.spin - truth.spin).norm() < 0.5, "{fit:?}");
        assert_eq!(fit.outliers, 0);

        let mut corrupted = detections.clone();
        corrupted[40].position.z += 0.3;
        let robust = fit_flight(&config, &corrupted, &guess).expect("fit");
        assert_eq!(robust.outliers, 1);
        assert!(
            (robust.start.position - truth.position).norm() < 2e-4,
            "{robust:?}"
        );
        assert!(
            (robust.start.velocity - truth.velocity).norm() < 5e-3,
            "{robust:?}"
        );
    }
}
