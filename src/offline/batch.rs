//! Batch fit of one flight: the state at the first detection (position, velocity, spin) that best
//! explains every detection of the flight, through its bounces, with the physics core. The
//! offline counterpart of the filter (it sees the whole flight), the smoother of `ttball smooth`
//! ([`crate::offline::smooth`]) and the inner problem of calibration ([`crate::offline::calibrate`]; Isomura et al. 2014
//! eq. 8-9 fit flights this way).
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
//! whitened residual's length (threshold: the [`HUBER_PROBABILITY`] quantile of the residual's
//! chi distribution, 3.76 sigma for a position, 4.48 with a spin), solved by Levenberg-Marquardt with
//! iteratively reweighted least squares. The Jacobian of every prediction is the propagator's
//! state-transition matrix, bounces included (the saltation terms of [`crate::physics::propagate`]).
//! The covariance of the fit is the inverse of the weighted Gauss-Newton matrix at the solution.

use nalgebra::{SMatrix, SVector, Vector3};
use thiserror::Error;

use crate::config::Config;
use crate::model::detection::Detection;
use crate::model::least_squares::{Damping, damped_step};
use crate::model::stats::chi_square_quantile;
use crate::offline::ballistic::fit_ballistic;
use crate::online::ekf::PredictReport;
use crate::online::estimator::Rejection;
use crate::online::measurement::{Measurement, MeasurementModel};
use crate::physics::propagate::{Cursor, Propagator, Watch};
use crate::physics::state::{BallState, SPIN, StateMatrix, StateVector};

/// Nanoseconds per second.
const NS_PER_S: f64 = 1e9;
/// Largest number of Levenberg-Marquardt iterations.
const MAX_ITERATIONS: usize = 60;
/// Relative cost change at which the fit has converged.
const COST_TOLERANCE: f64 = 1e-12;
/// Detections the first guess of a flight is fitted to ([`initial_guess`]).
const GUESS_DETECTIONS: usize = 8;

/// Probability of a correct detection's whitened residual within the Huber threshold (that of
/// 3 sigma in one dimension); beyond it the detection's weight falls.
pub const HUBER_PROBABILITY: f64 = 0.9973;

/// One usable detection, whitened: its time since the flight's start and measurement vector
/// (position, then spin when measured) with the inverse Cholesky factor of its noise.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Observation {
    /// Index of the detection in the caller's list.
    pub index: usize,
    /// Time since the flight's first detection [s].
    pub t: f64,
    /// Measured position [m] and spin [rad/s] (zero when not measured).
    z: SVector<f64, 6>,
    /// L^-1, zero outside the measured dimensions: the whitened residual is `white (z - h)`.
    white: SMatrix<f64, 6, 6>,
    /// Measured dimensions: 3 (position) or 6 (position and spin).
    pub dims: usize,
    /// Whitened residual length where Huber's loss turns linear.
    pub threshold: f64,
}

impl Observation {
    /// The measurement `m` at `t` seconds into the flight, whitened; a covariance that is not
    /// positive definite is [`Rejection::BadCovariance`].
    pub(crate) fn new(index: usize, t: f64, m: &Measurement) -> Result<Self, Rejection> {
        let (z, white, dims) = whiten(m)?;
        Ok(Self {
            index,
            t,
            z,
            white,
            dims,
            threshold: huber_threshold(dims),
        })
    }

    /// The IRLS weight and cost of this observation's whitened residual of length `length`:
    /// Huber's loss at its threshold when `robust`, else least squares.
    pub(crate) fn loss(&self, length: f64, robust: bool) -> (f64, f64) {
        huber(
            length,
            if robust {
                self.threshold
            } else {
                f64::INFINITY
            },
        )
    }
}

/// The Huber threshold of a whitened residual of `dims` dimensions: the [`HUBER_PROBABILITY`]
/// quantile of its chi distribution (3.76 sigma for a position, 4.48 with a spin).
fn huber_threshold(dims: usize) -> f64 {
    // The two sizes a measurement has, computed once.
    static THRESHOLDS: std::sync::OnceLock<[f64; 2]> = std::sync::OnceLock::new();
    let [position, with_spin] = *THRESHOLDS
        .get_or_init(|| [3, 6].map(|d| chi_square_quantile(HUBER_PROBABILITY, d).sqrt()));
    if dims == 6 { with_spin } else { position }
}

/// A measurement as (z, L^-1) padded to six dimensions, and its dimensions.
fn whiten(m: &Measurement) -> Result<(SVector<f64, 6>, SMatrix<f64, 6, 6>, usize), Rejection> {
    match m {
        Measurement::Position { z: p, r, .. } => {
            let mut z = SVector::<f64, 6>::zeros();
            let mut white = SMatrix::<f64, 6, 6>::zeros();
            z.fixed_rows_mut::<3>(0).copy_from(p);
            white
                .fixed_view_mut::<3, 3>(0, 0)
                .copy_from(&inverse_factor(r)?);
            Ok((z, white, 3))
        }
        Measurement::PositionSpin { z, r, .. } => Ok((*z, inverse_factor(r)?, 6)),
    }
}

/// L^-1 of a noise covariance R = L L^T.
fn inverse_factor<const D: usize>(r: &SMatrix<f64, D, D>) -> Result<SMatrix<f64, D, D>, Rejection> {
    r.cholesky()
        .and_then(|c| c.l().try_inverse())
        .ok_or(Rejection::BadCovariance)
}

/// Huber's loss on a whitened residual of length `length`: the IRLS weight and the cost
/// (quadratic within `threshold`, linear beyond).
fn huber(length: f64, threshold: f64) -> (f64, f64) {
    if length <= threshold {
        (1.0, length * length)
    } else {
        (
            threshold / length,
            2.0 * threshold * length - threshold * threshold,
        )
    }
}

/// What a detection measures of a state: its position and spin, as (z) of an [`Observation`].
fn measured(state: &StateVector) -> SVector<f64, 6> {
    let mut z = SVector::<f64, 6>::zeros();
    z.fixed_rows_mut::<3>(0)
        .copy_from(&state.fixed_rows::<3>(0));
    z.fixed_rows_mut::<3>(3)
        .copy_from(&state.fixed_rows::<3>(SPIN));
    z
}

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
    /// Each used detection's index in the fitted slice and its squared whitened residual at the
    /// solution (its normalised innovation squared against the smoothed state), in stamp order.
    pub residuals: Vec<(usize, f64)>,
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

/// The usable detections of one flight, in stamp order, and the rejected ones' reasons.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Observations {
    /// Stamp of the first detection [ns].
    pub start_stamp: i64,
    /// The usable detections.
    pub list: Vec<Observation>,
    /// Why the others are not usable.
    pub rejected: Vec<Rejection>,
}

impl Observations {
    /// The detections of one flight (any order) as the filter would measure them.
    pub fn new(config: &Config, detections: &[Detection]) -> Self {
        let model = MeasurementModel::new(config);
        let mut order: Vec<usize> = (0..detections.len()).collect();
        order.sort_by_key(|&i| detections[i].stamp);
        let start_stamp = order.first().map_or(0, |&i| detections[i].stamp);
        let mut list = Vec::with_capacity(order.len());
        let mut rejected = Vec::new();
        for index in order {
            let d = &detections[index];
            let t = (d.stamp - start_stamp) as f64 / NS_PER_S;
            let observation = model
                .measure(d)
                .map_err(Rejection::from)
                .and_then(|m| Observation::new(index, t, &m));
            match observation {
                Ok(o) => list.push(o),
                Err(why) => rejected.push(why),
            }
        }
        Self {
            start_stamp,
            list,
            rejected,
        }
    }
}

/// One observation's whitened residual and its Jacobian with respect to the start state.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Residual {
    /// `white (z - h(x(t)))`, zero beyond the measured dimensions.
    pub value: SVector<f64, 6>,
    /// `-d value / d x_0`, i.e. `white H Phi(t)`, when asked for.
    pub jacobian: SMatrix<f64, 6, 9>,
    /// The measured minus the predicted position, not whitened [m].
    pub miss: Vector3<f64>,
}

/// The whitened residuals of `observations` for the start state `x`, in one propagation through
/// the bounces (with the state-transition matrix when `jacobian`), into `out`.
pub(crate) fn residuals(
    propagator: &Propagator,
    observations: &[Observation],
    x: &StateVector,
    jacobian: bool,
    out: &mut Vec<Residual>,
) {
    out.clear();
    let mut cursor = if jacobian {
        Cursor::tracking(0.0, *x)
    } else {
        Cursor::new(0.0, &BallState::from_vector(x))
    };
    for o in observations {
        let duration = o.t - cursor.t;
        propagator.advance(&mut cursor, duration, Watch::BOUNCES, &mut ());
        let predicted = measured(&cursor.state);
        let mut h = SMatrix::<f64, 6, 9>::zeros();
        if let Some(tangent) = &cursor.tangent {
            let phi = tangent.transition();
            h.fixed_rows_mut::<3>(0).copy_from(&phi.fixed_rows::<3>(0));
            h.fixed_rows_mut::<3>(3)
                .copy_from(&phi.fixed_rows::<3>(SPIN));
        }
        let difference = o.z - predicted;
        out.push(Residual {
            value: o.white * difference,
            jacobian: o.white * h,
            miss: difference.fixed_rows::<3>(0).into_owned(),
        });
    }
}

/// The cost of the prior w_0 ~ N(0, sigma^2 I) on the spin of the start state `x`.
pub(crate) fn spin_prior_cost(x: &StateVector, sigma: f64) -> f64 {
    x.fixed_rows::<3>(SPIN).norm_squared() / (sigma * sigma)
}

/// The weighted normal equations of one flight at one start state.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Linearised {
    /// J^T W J.
    pub normal: StateMatrix,
    /// J^T W r: minus half the cost's gradient (a Gauss-Newton step solves `normal dx =
    /// gradient`).
    pub gradient: StateVector,
    /// The robust cost, spin prior included.
    pub cost: f64,
    /// Observations beyond their Huber threshold.
    pub outliers: usize,
    /// Sum of the inliers' squared whitened residuals.
    pub inlier_squares: f64,
    /// Their dimensions.
    pub inlier_dims: usize,
}

impl Linearised {
    /// The normal equations of `residuals` under Huber's loss (`robust`) or least squares, with
    /// the spin prior of standard deviation `spin_prior` [rad/s] on `x` (0: none).
    pub fn new(
        observations: &[Observation],
        residuals: &[Residual],
        robust: bool,
        spin_prior: f64,
        x: &StateVector,
    ) -> Self {
        let mut out = Self {
            normal: StateMatrix::zeros(),
            gradient: StateVector::zeros(),
            cost: 0.0,
            outliers: 0,
            inlier_squares: 0.0,
            inlier_dims: 0,
        };
        for (o, r) in observations.iter().zip(residuals) {
            let length = r.value.norm();
            let (weight, cost) = o.loss(length, robust);
            if weight < 1.0 {
                out.outliers += 1;
            } else {
                out.inlier_squares += length * length;
                out.inlier_dims += o.dims;
            }
            out.normal += r.jacobian.transpose() * r.jacobian * weight;
            out.gradient += r.jacobian.transpose() * r.value * weight;
            out.cost += cost;
        }
        // The spin prior: w_0 ~ N(0, sigma^2 I).
        if spin_prior > 0.0 {
            let information = 1.0 / (spin_prior * spin_prior);
            for k in SPIN..SPIN + 3 {
                out.normal[(k, k)] += information;
                out.gradient[k] -= information * x[k];
            }
            out.cost += spin_prior_cost(x, spin_prior);
        }
        out
    }
}

/// A first guess of the state at the earliest of `detections`: position and velocity of a
/// parabola through the first few (gravity only), the first measured spin or none. `None` with
/// fewer than two distinct stamps.
pub fn initial_guess(detections: &[Detection], gravity: f64) -> Option<BallState> {
    let mut sorted: Vec<&Detection> = detections
        .iter()
        .filter(|d| d.position.iter().all(|v| v.is_finite()))
        .collect();
    sorted.sort_by_key(|d| d.stamp);
    let t0 = sorted.first()?.stamp;
    let early: Vec<(f64, Vector3<f64>)> = sorted
        .iter()
        .take(GUESS_DETECTIONS)
        .map(|d| ((d.stamp - t0) as f64 / NS_PER_S, d.position))
        .collect();
    let parabola = fit_ballistic(&early, 0.0, gravity)?;
    let spin = sorted
        .iter()
        .find_map(|d| d.spin.filter(|w| w.iter().all(|v| v.is_finite())))
        .unwrap_or_default();
    let guess = BallState::new(parabola.position, parabola.velocity, spin);
    guess
        .to_vector()
        .iter()
        .all(|v| v.is_finite())
        .then_some(guess)
}

/// The spins added to a guess to start the least-squares phase from (see [`fit_flight`]).
pub(crate) fn spin_starts(velocity: &Vector3<f64>) -> [Vector3<f64>; 7] {
    let topspin_axis = Vector3::z()
        .cross(velocity)
        .try_normalize(1e-9)
        .unwrap_or_default();
    [
        Vector3::zeros(),
        topspin_axis * 150.0,
        topspin_axis * -150.0,
        topspin_axis * 300.0,
        topspin_axis * -300.0,
        Vector3::z() * 150.0,
        Vector3::z() * -150.0,
    ]
}

/// Fits the flight of `detections` (one ball, any order) from its own first guess
/// ([`initial_guess`]), with the physics of `config`.
pub fn fit_whole_flight(config: &Config, detections: &[Detection]) -> Result<FlightFit, FitError> {
    fit_from_guess(
        &Propagator::new(config),
        &Observations::new(config, detections),
        detections,
        config.gravity,
        config.ekf.spin_prior_sigma,
    )
}

/// [`fit_observations`] of `observations` (prepared from `detections`) from the first guess
/// of `detections`; too few detections for a guess is [`FitError::TooFew`].
pub(crate) fn fit_from_guess(
    propagator: &Propagator,
    observations: &Observations,
    detections: &[Detection],
    gravity: f64,
    spin_prior: f64,
) -> Result<FlightFit, FitError> {
    let guess =
        initial_guess(detections, gravity).ok_or(FitError::TooFew(observations.list.len()))?;
    fit_observations(propagator, observations, spin_prior, &guess)
}

/// Fits the flight of `detections` (one ball, any order) from the guess `initial` of the state at
/// the earliest detection, with the physics of `config`.
pub fn fit_flight(
    config: &Config,
    detections: &[Detection],
    initial: &BallState,
) -> Result<FlightFit, FitError> {
    let propagator = Propagator::new(config);
    let observations = Observations::new(config, detections);
    fit_observations(
        &propagator,
        &observations,
        config.ekf.spin_prior_sigma,
        initial,
    )
}

/// [`fit_flight`] on prepared observations with a given propagator and spin prior [rad/s].
pub(crate) fn fit_observations(
    propagator: &Propagator,
    observations: &Observations,
    spin_prior: f64,
    initial: &BallState,
) -> Result<FlightFit, FitError> {
    let list = &observations.list;
    if list.len() < 3 {
        return Err(FitError::TooFew(list.len()));
    }
    let mut x = initial.to_vector();
    if x.iter().any(|v| !v.is_finite()) {
        return Err(FitError::BadGuess);
    }
    let mut scratch = Vec::with_capacity(list.len());
    let mut linearise = |x: &StateVector, robust: bool| {
        residuals(propagator, list, x, true, &mut scratch);
        Linearised::new(list, &scratch, robust, spin_prior, x)
    };
    // Least squares first (a far guess would make most detections look like outliers), from
    // several spins: a wrong spin moves the bounce and can trap the fit in a local minimum, so
    // the guess is also tried with 150 and 300 rad/s of topspin and of backspin and 150 rad/s of
    // sidespin either way added, and the best start kept. Then Huber's loss from there.
    let mut iterations = 0;
    let mut best: Option<(StateVector, f64)> = None;
    for extra in spin_starts(&initial.velocity) {
        let mut start = x;
        for k in 0..3 {
            start[SPIN + k] += extra[k];
        }
        let (solution, at, used) = levenberg_marquardt(&mut |x| linearise(x, false), start);
        iterations += used;
        if best.is_none_or(|(_, cost)| at.cost < cost) {
            best = Some((solution, at.cost));
        }
    }
    if let Some((solution, _)) = best {
        x = solution;
    }
    let (solution, current, used) = levenberg_marquardt(&mut |x| linearise(x, true), x);
    x = solution;
    iterations += used;
    let covariance = current.normal.try_inverse().ok_or(FitError::Singular)?;
    residuals(propagator, list, &x, false, &mut scratch);
    Ok(FlightFit {
        start_stamp: observations.start_stamp,
        start: BallState::from_vector(&x),
        covariance: (covariance + covariance.transpose()) * 0.5,
        used: list.len(),
        rejected: observations.rejected.clone(),
        outliers: current.outliers,
        normalised_rms: (current.inlier_squares / current.inlier_dims.max(1) as f64).sqrt(),
        iterations,
        residuals: list
            .iter()
            .zip(&scratch)
            .map(|(o, r)| (o.index, r.value.norm_squared()))
            .collect(),
    })
}

/// Minimises the cost `linearise` describes from `x`: the solution, the linearisation there and
/// the iterations used.
fn levenberg_marquardt(
    linearise: &mut impl FnMut(&StateVector) -> Linearised,
    start: StateVector,
) -> (StateVector, Linearised, usize) {
    let mut x = start;
    let mut current = linearise(&x);
    let mut damping = Damping::new();
    for iteration in 1..=MAX_ITERATIONS {
        let taken = damping.step(|lambda| {
            let candidate = x + damped_step(&current.normal, &current.gradient, lambda)?;
            let next = linearise(&candidate);
            (next.cost.is_finite() && next.cost <= current.cost).then_some((candidate, next))
        });
        let Some((candidate, next)) = taken else {
            return (x, current, iteration);
        };
        let change = (current.cost - next.cost) / current.cost.max(f64::MIN_POSITIVE);
        x = candidate;
        current = next;
        if change < COST_TOLERANCE {
            return (x, current, iteration);
        }
    }
    (x, current, MAX_ITERATIONS)
}

/// A state of the fitted flight at one stamp.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FittedState {
    /// The state.
    pub state: BallState,
    /// Its covariance (the fit's, carried by the state-transition matrix).
    pub covariance: StateMatrix,
    /// Table bounces since the start.
    pub bounces: u32,
    /// Those on the robot's half (x < 0).
    pub robot_half_bounces: u32,
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
        self.states_at(propagator, &[stamp])
            .pop()
            .flatten()
            .map(|s| (s.state, s.covariance))
    }

    /// The fitted states at `stamps` [ns] (any order), in one walk along the flight; `None` for
    /// a stamp before the start.
    pub fn states_at(&self, propagator: &Propagator, stamps: &[i64]) -> Vec<Option<FittedState>> {
        let mut order: Vec<usize> = (0..stamps.len()).collect();
        order.sort_by_key(|&i| stamps[i]);
        let mut out = vec![None; stamps.len()];
        let mut cursor = Cursor::with_jacobian(0.0, &self.start);
        let mut bounces = PredictReport::default();
        for i in order {
            if stamps[i] < self.start_stamp {
                continue;
            }
            let t = (stamps[i] - self.start_stamp) as f64 / NS_PER_S;
            let duration = t - cursor.t;
            propagator.advance(&mut cursor, duration, Watch::BOUNCES, &mut bounces);
            let phi = cursor
                .tangent
                .map_or(StateMatrix::identity(), |t| t.transition());
            let covariance = phi * self.covariance * phi.transpose();
            out[i] = Some(FittedState {
                state: cursor.ball(),
                covariance: (covariance + covariance.transpose()) * 0.5,
                bounces: bounces.bounces,
                robot_half_bounces: bounces.robot_half_bounces,
            });
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::detection::Source;
    use nalgebra::{Matrix3, Vector3};

    /// A flight through a bounce seen every 10 ms, with a spin-measuring detection every 30 ms,
    /// each a little off the truth.
    fn detections(truth: &BallState, propagator: &Propagator) -> Vec<Detection> {
        let mut cursor = Cursor::new(0.0, truth);
        let mut out = Vec::new();
        for k in 0..60 {
            let t = 0.01 * f64::from(k);
            let duration = t - cursor.t;
            propagator.advance(&mut cursor, duration, Watch::BOUNCES, &mut ());
            let p = cursor.state.fixed_rows::<3>(0).into_owned();
            let stamp = (t * 1e9).round() as i64;
            out.push(if k % 3 == 0 {
                Detection {
                    source: Source::HIGHSPEED_900FPS,
                    position_covariance: Some(Matrix3::identity() * 1e-6),
                    spin: Some(cursor.state.fixed_rows::<3>(SPIN) + Vector3::new(5.0, -3.0, 2.0)),
                    spin_covariance: Some(Matrix3::identity() * 144.0),
                    ..detection(stamp, p + Vector3::new(1e-3, -2e-3, 1e-3))
                }
            } else {
                Detection {
                    position_covariance: Some(Matrix3::identity() * 4e-6),
                    ..detection(stamp, p + Vector3::new(-1e-3, 1e-3, 2e-3))
                }
            });
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
        let (config, propagator, truth) = topspin_flight();
        let obs = Observations::new(&config, &detections(&truth, &propagator)).list;
        assert_eq!(obs.iter().filter(|o| o.dims == 6).count(), 20);
        let mut scratch = Vec::new();
        let mut linearise = |x: &StateVector| {
            residuals(&propagator, &obs, x, true, &mut scratch);
            Linearised::new(&obs, &scratch, true, 300.0, x)
        };
        let mut x = truth.to_vector();
        x[3] += 0.02;
        x[7] += 15.0;
        let at = linearise(&x);
        assert!(at.outliers > 0, "the Huber branch is checked too");
        for k in 0..9 {
            let h = if k < SPIN { 1e-6 } else { 1e-3 };
            let mut plus = x;
            plus[k] += h;
            let mut minus = x;
            minus[k] -= h;
            let fd = (linearise(&plus).cost - linearise(&minus).cost) / (2.0 * h);
            let analytic = -2.0 * at.gradient[k];
            assert!(
                (fd - analytic).abs() <= 1e-4 * analytic.abs().max(1.0),
                "component {k}: finite differences {fd}, analytic {analytic}"
            );
        }
    }

    fn detection(stamp: i64, position: Vector3<f64>) -> Detection {
        Detection {
            stamp,
            source: Source::WIDE_150FPS,
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
            (fit.start.velocity - truth.velocity).norm() < 3e-5,
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
