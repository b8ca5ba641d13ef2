//! A table bounce's outcome spread over the uncertainty of the state and of the table's
//! parameters beyond its linearisation: the bounce map on sigma points of (v, w, e_t, mu_t)
//! (the unscented transform, Julier & Uhlmann 1997, kappa = 1), its covariance less the
//! linearised J C J' (and the mean's offset from the linearised outcome), the positive part.
//! A bounce slides or rolls out depending on a spin still poorly known, and its outcome moves
//! with the spin along directions the linearisation at the estimate does not see: a slow ball
//! whose fast spin the flight's curvature misread is kicked elsewhere than predicted, and
//! without this spread the detections after its bounce are gated one after another. Used by
//! the filter's prediction ([`crate::online::ekf`]) and for a bounce ahead of the interception
//! ([`crate::online::intercept`]).

use nalgebra::{SMatrix, SVector};

use crate::physics::params::{AUGMENTED, AugmentedMatrix, RESTITUTION};
use crate::physics::{EventSensitivity, PARAMS, Propagator, StateMatrix, StateVector};

/// Dimensions of the bounce's unscented transform: velocity, spin, e_t and mu_t before it.
pub const BOUNCE_SIGMA_DIMENSIONS: usize = 8;

/// The covariance of what a bounce's outcome depends on, (v, w, e_t, mu_t): state indices 3..9
/// and the table's two parameters.
pub(crate) type BounceInputs = SMatrix<f64, BOUNCE_SIGMA_DIMENSIONS, BOUNCE_SIGMA_DIMENSIONS>;

/// The index in (state, parameters) of each of (v, w, e_t, mu_t).
fn bounce_input_index(k: usize) -> usize {
    if k < 6 {
        3 + k
    } else {
        9 + RESTITUTION + (k - 6)
    }
}

/// The bounce's inputs' covariance at an event, from the covariance `start` of the
/// propagation's start and the event's sensitivities: the rows of [[T, S], [0, I]] P [.]' that
/// it needs (a quarter of the arithmetic of [`covariance_at_event`]).
pub(crate) fn bounce_inputs_at_event(
    s: &EventSensitivity,
    start: &AugmentedMatrix,
) -> BounceInputs {
    let mut a = SMatrix::<f64, BOUNCE_SIGMA_DIMENSIONS, AUGMENTED>::zeros();
    for k in 0..BOUNCE_SIGMA_DIMENSIONS {
        let i = bounce_input_index(k);
        if i < 9 {
            a.fixed_view_mut::<1, 9>(k, 0).copy_from(&s.before.row(i));
            if let Some(p) = &s.params {
                a.fixed_view_mut::<1, PARAMS>(k, 9)
                    .copy_from(&p.before.row(i));
            }
        } else {
            a[(k, i)] = 1.0;
        }
    }
    let a_start = a * start;
    a_start * a.transpose()
}

/// How much the bounce's outcome really spreads beyond its linearisation: the covariance
/// of (v, w) after the bounce over sigma points of (v, w, e_t, mu_t) before it (the
/// unscented transform, [`BOUNCE_SIGMA_DIMENSIONS`] dimensions, kappa = 1; `c` their
/// covariance), less the linearised J C J', its positive part. Both regimes, and the spin's
/// uncertainty along the directions the linearisation misses, are in it.
pub(crate) fn bounce_spread(
    propagator: &Propagator,
    before: &StateVector,
    after: &StateVector,
    c: &BounceInputs,
) -> StateMatrix {
    const N: usize = BOUNCE_SIGMA_DIMENSIONS;
    let c = *c;
    let jitter = SMatrix::<f64, N, N>::identity() * (1e-12 * c.diagonal().amax() + 1e-18);
    let Some(chol) = (c + jitter).cholesky() else {
        return StateMatrix::zeros();
    };
    let kappa = 1.0;
    let spread = (N as f64 + kappa).sqrt();
    let (w0, wi) = (kappa / (N as f64 + kappa), 0.5 / (N as f64 + kappa));
    let l = chol.l();
    let bounce = propagator.bounce();
    let (e, mu) = bounce.table();
    let outcome = |offset: &SVector<f64, N>| -> SVector<f64, 6> {
        let mut x = *before;
        for k in 0..6 {
            x[3 + k] += offset[k];
        }
        let table = bounce.with_table((e + offset[6]).clamp(0.05, 1.0), (mu + offset[7]).max(0.0));
        table.apply(&x).state.fixed_rows::<6>(3).into_owned()
    };
    let mut outcomes = [SVector::<f64, 6>::zeros(); 2 * N + 1];
    outcomes[0] = outcome(&SVector::zeros());
    for k in 0..N {
        let column = l.column(k) * spread;
        outcomes[1 + k] = outcome(&column.into_owned());
        outcomes[1 + N + k] = outcome(&(-column).into_owned());
    }
    let mean = outcomes[0] * w0 + outcomes[1..].iter().sum::<SVector<f64, 6>>() * wi;
    let mut spread_cov = SMatrix::<f64, 6, 6>::zeros();
    for (k, y) in outcomes.iter().enumerate() {
        let d = y - mean;
        spread_cov += d * d.transpose() * if k == 0 { w0 } else { wi };
    }
    // The linearised covariance of the same outcome: G C G' with G = d(v', w')/d(v, w, e,
    // mu) at the mean.
    let b = bounce.apply(before);
    let mut gm = SMatrix::<f64, 6, N>::zeros();
    gm.fixed_view_mut::<6, 6>(0, 0)
        .copy_from(&b.jacobian.fixed_view::<6, 6>(3, 3));
    gm.fixed_view_mut::<6, 2>(0, 6)
        .copy_from(&b.table_jacobian.fixed_view::<6, 2>(3, 0));
    let linear = gm * c * gm.transpose();
    // The mean's own offset from the linearised outcome counts too.
    let offset = mean - after.fixed_rows::<6>(3);
    let excess = spread_cov - linear + offset * offset.transpose();
    let eigen = nalgebra::SymmetricEigen::new((excess + excess.transpose()) * 0.5);
    let positive = eigen.eigenvectors
        * SMatrix::<f64, 6, 6>::from_diagonal(&eigen.eigenvalues.map(|v| v.max(0.0)))
        * eigen.eigenvectors.transpose();
    let mut q = StateMatrix::zeros();
    q.fixed_view_mut::<6, 6>(3, 3).copy_from(&positive);
    q
}
