//! Levenberg-Marquardt, once for every least-squares fit of ttball (Marquardt 1963, with his
//! scaling of the damping by the diagonal of the normal matrix):
//!
//! - [`Damping`]: the one damping schedule: a step solves (A + lambda diag(A)) d = -g; lambda
//!   starts at 1e-3, is raised tenfold while a step fails (the system is singular or the cost does
//!   not fall) and lowered tenfold after a step is taken. The batch fit
//!   ([`crate::offline::batch`]), the flight calibration ([`crate::offline::calibrate`], whose
//!   damped system is a Schur complement) and the return planner ([`crate::online::stroke`]) build
//!   their own normal equations and take their steps through it.
//! - [`damped_step`]: that damped system solved for a fixed-size problem, on the stack (the
//!   batch fit's 9 states, the planner's 3 unknowns).
//! - [`minimise`]: a dense problem of a few parameters whose residuals come from a model one can
//!   only evaluate (the racket impact, [`crate::offline::rebound_calibration`]): its Jacobian by
//!   central differences, and the parameters' covariance at the minimum, (J^T J)^-1 times the
//!   reduced chi-square.

use nalgebra::{DMatrix, DVector, SMatrix, SVector};
use thiserror::Error;

/// Marquardt's damping schedule (module docs): lambda and how it moves.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Damping {
    lambda: f64,
}

impl Default for Damping {
    fn default() -> Self {
        Self::new()
    }
}

impl Damping {
    /// Lambda of the first step: close to Gauss-Newton.
    pub const START: f64 = 1e-3;
    /// Factor by which lambda rises after a failed step and falls after a taken one.
    pub const FACTOR: f64 = 10.0;
    /// Lambda never falls below this.
    pub const FLOOR: f64 = 1e-12;
    /// Failed steps tried (each with a larger lambda) before an iteration is given up: a step
    /// 10^-27 the Gauss-Newton one's gradient scaling is as good as none.
    pub const MAX_RAISES: usize = 30;

    /// The schedule at its start.
    pub const fn new() -> Self {
        Self {
            lambda: Self::START,
        }
    }

    /// The current lambda.
    pub const fn lambda(&self) -> f64 {
        self.lambda
    }

    /// One iteration's step: `attempt(lambda)` solves the damped system and judges the result
    /// (`None`: singular, or not better than where it stands), with lambda raised after each
    /// failure; the first success is returned and lambda lowered, or `None` when
    /// [`Self::MAX_RAISES`] attempts all failed.
    pub fn step<T>(&mut self, mut attempt: impl FnMut(f64) -> Option<T>) -> Option<T> {
        for _ in 0..Self::MAX_RAISES {
            if let Some(taken) = attempt(self.lambda) {
                self.lambda = (self.lambda / Self::FACTOR).max(Self::FLOOR);
                return Some(taken);
            }
            self.lambda *= Self::FACTOR;
        }
        None
    }
}

/// Solves (A + lambda diag(A)) d = rhs for a symmetric positive semi-definite `normal` A of fixed
/// size, each diagonal element floored at 1e-12 in the damping; `None` when it stays singular.
pub fn damped_step<const N: usize>(
    normal: &SMatrix<f64, N, N>,
    rhs: &SVector<f64, N>,
    lambda: f64,
) -> Option<SVector<f64, N>> {
    let mut damped = *normal;
    for k in 0..N {
        damped[(k, k)] += lambda * normal[(k, k)].max(1e-12);
    }
    damped.cholesky().map(|c| c.solve(rhs))
}

/// Iterations before the minimiser stops where it is.
const MAX_ITERATIONS: usize = 100;
/// Relative fall of the cost below which the minimum is taken as found.
const COST_TOLERANCE: f64 = 1e-10;

/// Why a least-squares problem could not be solved.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum LeastSquaresError {
    /// The residuals cannot be evaluated at the starting parameters.
    #[error("the model cannot be evaluated at the starting values")]
    BadStart,
    /// Fewer residuals than parameters.
    #[error("{residuals} residuals cannot determine {parameters} parameters")]
    TooFewResiduals {
        /// Residuals.
        residuals: usize,
        /// Parameters.
        parameters: usize,
    },
    /// J^T J is singular at the minimum: some parameter is not determined by the data.
    #[error(
        "the data do not determine every parameter (J^T J is singular at the minimum): fit fewer"
    )]
    Singular {
        /// The parameters the residuals do not depend on there (may be empty when several are
        /// tied together instead).
        flat: Vec<usize>,
        /// Where the minimiser stopped.
        at: DVector<f64>,
    },
}

/// The minimum found.
#[derive(Debug, Clone, PartialEq)]
pub struct Minimum {
    /// The parameters.
    pub x: DVector<f64>,
    /// The residuals there.
    pub residuals: DVector<f64>,
    /// Their sum of squares.
    pub cost: f64,
    /// Covariance of the parameters: (J^T J)^-1 times the reduced chi-square, cost / (m - n).
    pub covariance: DMatrix<f64>,
    /// Iterations used.
    pub iterations: usize,
}

impl Minimum {
    /// Standard error of each parameter (square root of the covariance's diagonal).
    pub fn std_errors(&self) -> DVector<f64> {
        self.covariance.diagonal().map(|v| v.max(0.0).sqrt())
    }
}

/// Minimises the sum of squares of `residuals` (None: the model cannot be evaluated there, which
/// the minimiser treats as an infinite cost) from `start`; `steps[k]` is the central
/// difference's step in parameter k.
pub fn minimise(
    residuals: impl Fn(&DVector<f64>) -> Option<DVector<f64>>,
    start: DVector<f64>,
    steps: &DVector<f64>,
) -> Result<Minimum, LeastSquaresError> {
    let n = start.len();
    let mut x = start;
    let mut r = residuals(&x).ok_or(LeastSquaresError::BadStart)?;
    if r.len() < n {
        return Err(LeastSquaresError::TooFewResiduals {
            residuals: r.len(),
            parameters: n,
        });
    }
    let mut cost = r.norm_squared();
    let mut jacobian = central_differences(&residuals, &x, &r, steps);
    let mut damping = Damping::new();
    let mut iterations = 0;
    while iterations < MAX_ITERATIONS {
        iterations += 1;
        let normal = jacobian.transpose() * &jacobian;
        let gradient = jacobian.transpose() * &r;
        let taken = damping.step(|lambda| {
            let mut damped = normal.clone();
            for k in 0..n {
                damped[(k, k)] += lambda * normal[(k, k)].max(1e-12);
            }
            let step = damped.cholesky()?.solve(&(-&gradient));
            let candidate = &x + step;
            let next = residuals(&candidate)?;
            (next.norm_squared() <= cost).then_some((candidate, next))
        });
        let Some((candidate, next)) = taken else {
            break;
        };
        let next_cost = next.norm_squared();
        let change = (cost - next_cost) / cost.max(f64::MIN_POSITIVE);
        x = candidate;
        r = next;
        cost = next_cost;
        jacobian = central_differences(&residuals, &x, &r, steps);
        if change < COST_TOLERANCE {
            break;
        }
    }
    let normal = jacobian.transpose() * &jacobian;
    let flat: Vec<usize> = (0..n)
        .filter(|&k| jacobian.column(k).norm() == 0.0)
        .collect();
    let inverse = match (flat.is_empty(), normal.try_inverse()) {
        (true, Some(inverse)) => inverse,
        _ => return Err(LeastSquaresError::Singular { flat, at: x }),
    };
    let dof = (r.len() - n).max(1) as f64;
    let covariance = (&inverse + inverse.transpose()) * (0.5 * cost / dof);
    Ok(Minimum {
        x,
        residuals: r,
        cost,
        covariance,
        iterations,
    })
}

/// The Jacobian of `residuals` at `x` by central differences (one-sided where a side cannot be
/// evaluated, from `r`, the residuals at `x`).
fn central_differences(
    residuals: &impl Fn(&DVector<f64>) -> Option<DVector<f64>>,
    x: &DVector<f64>,
    r: &DVector<f64>,
    steps: &DVector<f64>,
) -> DMatrix<f64> {
    let mut jacobian = DMatrix::zeros(r.len(), x.len());
    for k in 0..x.len() {
        let h = steps[k];
        let mut plus = x.clone();
        plus[k] += h;
        let mut minus = x.clone();
        minus[k] -= h;
        let column = match (residuals(&plus), residuals(&minus)) {
            (Some(p), Some(m)) => (p - m) / (2.0 * h),
            (Some(p), None) => (p - r) / h,
            (None, Some(m)) => (r - m) / h,
            (None, None) => DVector::zeros(r.len()),
        };
        jacobian.set_column(k, &column);
    }
    jacobian
}

#[cfg(test)]
mod tests {
    use super::*;

    /// An exponential decay y = a exp(-b t) with known parameters is recovered, and the
    /// covariance's standard errors match the scatter of refits over noisy copies.
    #[test]
    fn recovers_an_exponential_decay_with_its_standard_errors() {
        let times: Vec<f64> = (0..40).map(|i| f64::from(i) * 0.1).collect();
        let truth = (2.0, 0.7);
        // Deterministic pseudo-noise of RMS ~0.01.
        let noise = |i: usize, k: usize| ((i * 7919 + k * 104_729) % 1000) as f64 / 1000.0 - 0.5;
        let mut estimates = Vec::new();
        let mut reported = 0.0;
        for k in 0..50 {
            let ys: Vec<f64> = times
                .iter()
                .enumerate()
                .map(|(i, t)| truth.0 * (-truth.1 * t).exp() + 0.035 * noise(i, k))
                .collect();
            let f = |p: &DVector<f64>| {
                Some(DVector::from_iterator(
                    times.len(),
                    times
                        .iter()
                        .zip(&ys)
                        .map(|(t, y)| p[0] * (-p[1] * t).exp() - y),
                ))
            };
            let m = minimise(
                f,
                DVector::from_vec(vec![1.0, 0.1]),
                &DVector::from_vec(vec![1e-6, 1e-6]),
            )
            .unwrap();
            assert!((m.x[0] - truth.0).abs() < 0.05, "{}", m.x);
            estimates.push(m.x[1]);
            reported += m.std_errors()[1] / 50.0;
        }
        let mean = estimates.iter().sum::<f64>() / 50.0;
        let scatter = (estimates.iter().map(|e| (e - mean).powi(2)).sum::<f64>() / 49.0).sqrt();
        assert!((mean - truth.1).abs() < 0.01, "mean {mean}");
        assert!(
            reported > 0.5 * scatter && reported < 2.0 * scatter,
            "reported {reported} vs scatter {scatter}"
        );
    }

    #[test]
    fn refuses_what_it_cannot_determine() {
        let f = |p: &DVector<f64>| Some(DVector::from_vec(vec![p[0] + p[1] - 1.0, p[0] + p[1]]));
        let err = minimise(f, DVector::zeros(2), &DVector::from_element(2, 1e-6)).unwrap_err();
        assert!(matches!(err, LeastSquaresError::Singular { flat, .. } if flat.is_empty()));
        let h = |p: &DVector<f64>| Some(DVector::from_vec(vec![p[0] - 1.0, p[0] + 1.0]));
        let err = minimise(h, DVector::zeros(2), &DVector::from_element(2, 1e-6)).unwrap_err();
        assert!(matches!(err, LeastSquaresError::Singular { flat, .. } if flat == [1]));
        let g = |_: &DVector<f64>| None;
        assert!(matches!(
            minimise(g, DVector::zeros(1), &DVector::from_element(1, 1e-6)),
            Err(LeastSquaresError::BadStart)
        ));
    }
}
