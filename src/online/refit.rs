//! The track refitted: the maximum a posteriori estimate of the state at the track's first
//! detection and of the flight's physical parameters, from every detection of the track so far,
//! relinearised at every iteration (Gauss-Newton with Levenberg-Marquardt's damping). The
//! filter linearises the flight once, at its estimate of the moment: a spin learned from the
//! curvature starts at zero, where C_M(Sp) is steep, so a fast spin is read too small and then
//! believed (docs/estimator.md, "The track refitted"). A refit sees the same detections through
//! the flight at its own solution.
//!
//! Minimise, over y = (x_0, theta) (the 9-state at the first detection and k_D, k_M, e_t, mu_t):
//!
//! ```text
//! sum_i rho(|L_i^-1 (z_i - h(x(t_i; x_0, theta)))|^2)
//!     + |w_0 / sigma_w|^2 + (theta - theta_0)' P_theta^-1 (theta - theta_0)
//! ```
//!
//! with L_i the Cholesky factor of detection i's noise, h the position (and the spin when
//! measured), rho Huber's loss on the whitened residual's length ([`HUBER_PROBABILITY`]), the
//! spin's prior that of the filter's start and the parameters' that of the track
//! (`Estimator`'s learned physics). The Jacobian of every prediction is the propagator's
//! transition matrix and its sensitivity to the parameters, [Phi, S], bounces included (the
//! saltation terms of [`crate::physics::propagate`]). The flight follows the model exactly here
//! (no process noise): the filter keeps its own covariance and takes only the refit's mean.
//!
//! Fixed-size matrices and the caller's buffer of observations: no heap allocation.

use nalgebra::{SMatrix, SVector};

use crate::model::least_squares::{Damping, damped_step};
use crate::model::stats::chi_square_quantile;
use crate::online::estimator::Rejection;
use crate::online::measurement::Measurement;
use crate::physics::params::{AUGMENTED, AugmentedMatrix, ParamCovariance};
use crate::physics::propagate::{Cursor, Propagator, Watch};
use crate::physics::state::{SPIN, StateVector};
use crate::physics::{PARAMS, ParamVector, PhysicsParams};

/// Probability of a correct detection's whitened residual within the Huber threshold (that of
/// 3 sigma in one dimension); beyond it the detection's weight falls.
pub const HUBER_PROBABILITY: f64 = 0.9973;

/// The state and the parameters together, (x, theta).
pub type AugmentedVector = SVector<f64, AUGMENTED>;

/// One usable detection, whitened: its time since the flight's start and measurement vector
/// (position, then spin when measured) with the inverse Cholesky factor of its noise.
#[derive(Debug, Clone, PartialEq)]
pub struct Observation {
    /// Index of the detection in the caller's list.
    pub index: usize,
    /// Time since the flight's first detection [s].
    pub t: f64,
    /// Measured position [m] and spin [rad/s] (zero when not measured).
    pub z: SVector<f64, 6>,
    /// L^-1, zero outside the measured dimensions: the whitened residual is `white (z - h)`.
    pub white: SMatrix<f64, 6, 6>,
    /// Measured dimensions: 3 (position) or 6 (position and spin).
    pub dims: usize,
    /// Whitened residual length where Huber's loss turns linear.
    pub threshold: f64,
}

impl Observation {
    /// The measurement `m` at `t` seconds into the flight, whitened; a covariance that is not
    /// positive definite is [`Rejection::BadCovariance`].
    pub fn new(index: usize, t: f64, m: &Measurement) -> Result<Self, Rejection> {
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
    pub fn loss(&self, length: f64, robust: bool) -> (f64, f64) {
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
pub fn measured(state: &StateVector) -> SVector<f64, 6> {
    let mut z = SVector::<f64, 6>::zeros();
    z.fixed_rows_mut::<3>(0)
        .copy_from(&state.fixed_rows::<3>(0));
    z.fixed_rows_mut::<3>(3)
        .copy_from(&state.fixed_rows::<3>(SPIN));
    z
}

/// What the refit knows before the detections.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Prior {
    /// sigma_w: the spin at the first detection ~ N(0, sigma_w^2 I) [rad/s].
    pub spin_sigma: f64,
    /// theta_0: the parameters the track started from.
    pub params: ParamVector,
    /// P_theta^-1: their information.
    pub param_information: ParamCovariance,
}

/// The weighted normal equations of the refit at one (x_0, theta).
#[derive(Debug, Clone, Copy, PartialEq)]
struct Normal {
    /// J' W J plus the priors' information.
    matrix: AugmentedMatrix,
    /// J' W r: minus half the cost's gradient.
    gradient: AugmentedVector,
    /// The robust cost, priors included.
    cost: f64,
    /// The detections' part of the cost.
    data_cost: f64,
    /// Their dimensions.
    dims: usize,
}

/// The normal equations of `observations` at `y`, flown by `propagator` with y's parameters.
fn linearise(
    propagator: &Propagator,
    observations: &[Observation],
    y: &AugmentedVector,
    prior: &Prior,
) -> Normal {
    let theta: ParamVector = y.fixed_rows::<PARAMS>(9).into_owned();
    let propagator = propagator.with_params(&PhysicsParams::from_vector(&theta));
    let mut cursor = Cursor::tracking_params(0.0, y.fixed_rows::<9>(0).into_owned());
    let mut out = Normal {
        matrix: AugmentedMatrix::zeros(),
        gradient: AugmentedVector::zeros(),
        cost: 0.0,
        data_cost: 0.0,
        dims: 0,
    };
    for o in observations {
        let duration = o.t - cursor.t;
        propagator.advance(&mut cursor, duration, Watch::BOUNCES, &mut ());
        let predicted = measured(&cursor.state);
        // H [Phi, S]: the position's and the spin's rows.
        let mut h = SMatrix::<f64, 6, AUGMENTED>::zeros();
        if let Some(tangent) = &cursor.tangent {
            let phi = tangent.transition();
            h.fixed_view_mut::<3, 9>(0, 0)
                .copy_from(&phi.fixed_rows::<3>(0));
            h.fixed_view_mut::<3, 9>(3, 0)
                .copy_from(&phi.fixed_rows::<3>(SPIN));
            if let Some(s) = tangent.params() {
                h.fixed_view_mut::<3, PARAMS>(0, 9)
                    .copy_from(&s.fixed_rows::<3>(0));
                h.fixed_view_mut::<3, PARAMS>(3, 9)
                    .copy_from(&s.fixed_rows::<3>(SPIN));
            }
        }
        let residual = o.white * (o.z - predicted);
        let jacobian = o.white * h;
        let (weight, cost) = o.loss(residual.norm(), true);
        out.matrix += jacobian.transpose() * jacobian * weight;
        out.gradient += jacobian.transpose() * residual * weight;
        out.cost += cost;
        out.data_cost += cost;
        out.dims += o.dims;
    }
    // The spin's prior: w_0 ~ N(0, sigma_w^2 I).
    if prior.spin_sigma > 0.0 {
        let information = 1.0 / (prior.spin_sigma * prior.spin_sigma);
        for k in SPIN..SPIN + 3 {
            out.matrix[(k, k)] += information;
            out.gradient[k] -= information * y[k];
            out.cost += information * y[k] * y[k];
        }
    }
    // The parameters' prior: theta ~ N(theta_0, P_theta).
    let offset = theta - prior.params;
    let pulled = prior.param_information * offset;
    let mut block = out.matrix.fixed_view_mut::<PARAMS, PARAMS>(9, 9);
    block += prior.param_information;
    let mut gradient = out.gradient.fixed_rows_mut::<PARAMS>(9);
    gradient -= pulled;
    out.cost += offset.dot(&pulled);
    out
}

/// Relative cost change at which the refit has converged.
const COST_TOLERANCE: f64 = 1e-6;

/// A solved refit.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Solution {
    /// (x_0, theta): the state at the first detection and the parameters.
    pub y: AugmentedVector,
    /// Levenberg-Marquardt iterations taken.
    pub iterations: usize,
    /// The detections' robust cost per dimension at the solution (about 1 when the flight
    /// follows the model within the detections' noise).
    pub cost_per_dimension: f64,
}

/// Refits the track's `observations` (in time order, times from its first detection) from
/// `start`, in at most `max_iterations` iterations; `None` when the start's cost is not finite.
/// The parameters stay inside [`crate::online::ekf::PARAM_BOUNDS`].
pub fn solve(
    propagator: &Propagator,
    observations: &[Observation],
    start: &AugmentedVector,
    prior: &Prior,
    max_iterations: usize,
) -> Option<Solution> {
    let mut y = bounded(start);
    let mut current = linearise(propagator, observations, &y, prior);
    if !current.cost.is_finite() {
        return None;
    }
    let mut damping = Damping::new();
    let mut iterations = 0;
    while iterations < max_iterations {
        iterations += 1;
        let taken = damping.step(|lambda| {
            let candidate =
                bounded(&(y + damped_step(&current.matrix, &current.gradient, lambda)?));
            let next = linearise(propagator, observations, &candidate, prior);
            (next.cost.is_finite() && next.cost <= current.cost).then_some((candidate, next))
        });
        let Some((candidate, next)) = taken else {
            break;
        };
        let change = (current.cost - next.cost) / current.cost.max(f64::MIN_POSITIVE);
        y = candidate;
        current = next;
        if change < COST_TOLERANCE {
            break;
        }
    }
    Some(Solution {
        y,
        iterations,
        cost_per_dimension: current.data_cost / current.dims.max(1) as f64,
    })
}

/// `y` with its parameters inside their physical box.
fn bounded(y: &AugmentedVector) -> AugmentedVector {
    let mut out = *y;
    for (k, (low, high)) in crate::online::ekf::PARAM_BOUNDS.iter().enumerate() {
        out[9 + k] = out[9 + k].clamp(*low, *high);
    }
    out
}

/// The refitted flight, walked forward in time: its state at each time asked, in ascending
/// order, with the table bounces it has made since the first detection.
pub struct Flight {
    propagator: Propagator,
    cursor: Cursor,
    bounces: crate::online::ekf::PredictReport,
}

impl Flight {
    /// The flight of the solution `y`, flown by `propagator` with y's parameters.
    pub fn new(propagator: &Propagator, y: &AugmentedVector) -> Self {
        let theta: ParamVector = y.fixed_rows::<PARAMS>(9).into_owned();
        Self {
            propagator: propagator.with_params(&PhysicsParams::from_vector(&theta)),
            cursor: Cursor::new(
                0.0,
                &crate::physics::state::BallState::from_vector(&y.fixed_rows::<9>(0).into_owned()),
            ),
            bounces: crate::online::ekf::PredictReport::default(),
        }
    }

    /// The state at `t` [s from the first detection; not before the last asked] and the table
    /// bounces before it.
    pub fn at(&mut self, t: f64) -> (StateVector, u32) {
        let duration = t - self.cursor.t;
        if duration > 0.0 {
            self.propagator.advance(
                &mut self.cursor,
                duration,
                Watch::BOUNCES,
                &mut self.bounces,
            );
        }
        (self.cursor.state, self.bounces.bounces)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::Config;
    use crate::physics::state::BallState;
    use nalgebra::{Matrix3, Vector3};

    fn augmented(state: &BallState, theta: &ParamVector) -> AugmentedVector {
        let mut y = AugmentedVector::zeros();
        y.fixed_rows_mut::<9>(0).copy_from(&state.to_vector());
        y.fixed_rows_mut::<PARAMS>(9).copy_from(theta);
        y
    }

    /// A topspin flight with a weaker Magnus force, more drag and a deader table than the
    /// configuration's, seen at 150 Hz (noise-free positions weighted as 1 mm) through its
    /// bounce: refitted from the configured parameters and half its spin (a filter's reading of
    /// a fast spin, too small), it finds the spin and the parameters; the detections' cost per
    /// dimension at the solution is about nothing.
    #[test]
    fn a_refit_from_a_spin_read_too_small_finds_the_flight_and_its_parameters() {
        let config = Config::default();
        let propagator = Propagator::new(&config);
        let truth = BallState::new(
            Vector3::new(1.2, 0.1, 0.3),
            Vector3::new(-6.0, -0.2, 1.0),
            Vector3::new(0.0, -350.0, 20.0),
        );
        let truth_params = ParamVector::new(1.1, 0.7, 0.86, 0.25);
        let mut flight = Flight::new(&propagator, &augmented(&truth, &truth_params));
        let observations: Vec<Observation> = (0..90)
            .map(|k| {
                let t = f64::from(k) / 150.0;
                let (x, _) = flight.at(t);
                let m = Measurement::Position {
                    z: x.fixed_rows::<3>(0).into_owned(),
                    r: Matrix3::identity() * 1e-6,
                    timing: 0.0,
                };
                Observation::new(k as usize, t, &m).unwrap()
            })
            .collect();
        assert_eq!(flight.at(0.6).1, 1, "the flight bounces once");
        let configured = PhysicsParams::from_config(&config).to_vector();
        let prior = Prior {
            spin_sigma: 300.0,
            params: configured,
            param_information: ParamCovariance::from_diagonal(&ParamVector::new(
                1.0 / 0.3_f64.powi(2),
                1.0 / 0.4_f64.powi(2),
                1.0 / 0.05_f64.powi(2),
                1.0 / 0.1_f64.powi(2),
            )),
        };
        let guess = BallState::new(truth.position, truth.velocity, truth.spin * 0.5);
        let solution = solve(
            &propagator,
            &observations,
            &augmented(&guess, &configured),
            &prior,
            60,
        )
        .unwrap();
        let spin = solution.y.fixed_rows::<3>(SPIN).into_owned();
        let theta = solution.y.fixed_rows::<PARAMS>(9).into_owned();
        assert!(
            (spin - truth.spin).norm() < 15.0,
            "spin {spin:?} against {:?}",
            truth.spin
        );
        assert!((theta[1] - 0.7).abs() < 0.03, "k_M {}", theta[1]);
        assert!((theta[2] - 0.86).abs() < 0.01, "e_t {}", theta[2]);
        assert!(
            solution.cost_per_dimension < 0.01,
            "{}",
            solution.cost_per_dimension
        );
        // The refitted flight where the truth is, at the last detection.
        let (x, bounces) = Flight::new(&propagator, &solution.y).at(89.0 / 150.0);
        let (truth_x, _) =
            Flight::new(&propagator, &augmented(&truth, &truth_params)).at(89.0 / 150.0);
        assert_eq!(bounces, 1);
        assert!((x - truth_x).fixed_rows::<3>(0).norm() < 1e-3);
    }
}
