//! Track initialisation from the first few detections: a weighted least-squares fit of position
//! and velocity at the newest stamp, per axis, with the acceleration known up to the spin (pass 1:
//! gravity; pass 2: gravity + drag at the fitted velocity, with the measured spin's Magnus force
//! when there is one). The spin starts at zero with a large, configured variance unless measured,
//! so the filter learns it from the curvature of the flight.
//!
//! The fit's covariance is inflated for the acceleration it cannot know, the Magnus force of an
//! unknown spin, a_u = k_M C_M(0) sigma_w |v|: fitting a line to the parabola a_u tau^2 / 2 over a
//! window of length T biases the velocity by about a_u T / 2 and the position by a_u T^2 / 12.

use nalgebra::{Matrix2, Vector2, Vector3};

use crate::model::detection::Detection;
use crate::physics::{FlightModel, StateMatrix, StateVector};

/// A fitted initial estimate.
#[derive(Debug, Clone, Copy, PartialEq)]
#[expect(non_snake_case, reason = "matrix notation")]
pub(crate) struct InitialFit {
    /// The state at `stamp`.
    pub x: StateVector,
    /// Its covariance.
    pub P: StateMatrix,
    /// The newest stamp of the fitted detections [ns].
    pub stamp: i64,
    /// Sum of squared normalised residuals.
    pub chi_square: f64,
    /// Degrees of freedom of `chi_square` (3 n - 6).
    pub dof: u32,
    /// Index of the detection with the largest normalised residual.
    pub worst: usize,
    /// Whether the spin was measured (on every axis) rather than left to the filter to learn.
    pub spin_measured: bool,
}

/// Measurement variances of one detection, as the filter would use them.
pub(crate) struct Weights {
    pub position_var: Vector3<f64>,
    pub spin: Option<(Vector3<f64>, Vector3<f64>)>,
}

/// Fits position and velocity at the newest stamp of `detections` (sorted by stamp, at least 2,
/// spanning a non-zero time).
pub(crate) fn fit(
    detections: &[Detection],
    weights: &dyn Fn(&Detection) -> Option<Weights>,
    flight: &FlightModel,
    gravity: f64,
    spin_prior_var: f64,
) -> Option<InitialFit> {
    let newest = detections.last()?;
    let stamp = newest.stamp;
    let tau = |d: &Detection| (d.stamp - stamp) as f64 * 1e-9;

    // Measured spin, if any: variance-weighted mean.
    let mut spin_sum = Vector3::zeros();
    let mut spin_weight = Vector3::zeros();
    for d in detections {
        if let Some(Weights {
            spin: Some((w, var)),
            ..
        }) = weights(d)
        {
            let inv = var.map(|v| 1.0 / v);
            spin_sum += w.component_mul(&inv);
            spin_weight += inv;
        }
    }
    let spin_measured = spin_weight.iter().all(|&w| w > 0.0);
    let spin = if spin_measured {
        spin_sum.component_div(&spin_weight)
    } else {
        Vector3::zeros()
    };

    let mut acceleration = Vector3::new(0.0, 0.0, -gravity);
    let mut solution = None;
    for _pass in 0..2 {
        let mut p = Vector3::zeros();
        let mut v = Vector3::zeros();
        let mut cov = [Matrix2::zeros(); 3];
        for axis in 0..3 {
            let mut normal = Matrix2::zeros();
            let mut rhs = Vector2::zeros();
            for d in detections {
                let w = 1.0 / weights(d)?.position_var[axis];
                let t = tau(d);
                let a = Vector2::new(1.0, t);
                let z = d.position[axis] - 0.5 * acceleration[axis] * t * t;
                normal += a * a.transpose() * w;
                rhs += a * (w * z);
            }
            let inverse = normal.try_inverse()?;
            let pv = inverse * rhs;
            p[axis] = pv[0];
            v[axis] = pv[1];
            cov[axis] = inverse;
        }
        let forces = flight.forces(&v, &spin);
        acceleration = Vector3::new(0.0, 0.0, -gravity) + forces.drag + forces.magnus;
        solution = Some((p, v, cov));
    }
    let (p, v, cov) = solution?;

    let mut chi_square = 0.0;
    let mut worst = (0, -1.0);
    for (i, d) in detections.iter().enumerate() {
        let t = tau(d);
        let predicted = p + v * t + acceleration * (0.5 * t * t);
        let var = weights(d)?.position_var;
        let r2 = (d.position - predicted)
            .component_div(&var.map(f64::sqrt))
            .norm_squared();
        chi_square += r2;
        if r2 > worst.1 {
            worst = (i, r2);
        }
    }

    let span = (stamp - detections[0].stamp) as f64 * 1e-9;
    let unknown_accel = if spin_measured {
        0.0
    } else {
        flight.magnus_factor()
            * flight.scales().1
            * flight.magnus_coefficient(0.0)
            * spin_prior_var.sqrt()
            * v.norm()
    };
    let mut x = StateVector::zeros();
    let mut big_p = StateMatrix::zeros();
    for axis in 0..3 {
        x[axis] = p[axis];
        x[axis + 3] = v[axis];
        x[axis + 6] = spin[axis];
        big_p[(axis, axis)] = cov[axis][(0, 0)] + (unknown_accel * span * span / 12.0).powi(2);
        big_p[(axis, axis + 3)] = cov[axis][(0, 1)];
        big_p[(axis + 3, axis)] = cov[axis][(1, 0)];
        big_p[(axis + 3, axis + 3)] = cov[axis][(1, 1)] + (unknown_accel * span / 2.0).powi(2);
        big_p[(axis + 6, axis + 6)] = if spin_measured {
            1.0 / spin_weight[axis]
        } else {
            spin_prior_var
        };
    }
    let n = u32::try_from(detections.len()).unwrap_or(u32::MAX);
    Some(InitialFit {
        x,
        P: big_p,
        stamp,
        chi_square,
        dof: (3 * n).saturating_sub(6),
        worst: worst.0,
        spin_measured,
    })
}
