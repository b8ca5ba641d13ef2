//! The extended Kalman filter over the 9-state (position, velocity, spin) in the `table` frame.
//!
//! - Prediction: the physics core's propagation (spin-parameter aero model, table bounce inside
//!   the step, with its Jacobian and contact-time sensitivity) gives x and F; P = F P F' + Q.
//! - Process noise Q: continuous white acceleration of density q_a [m^2/s^3] on the velocity and
//!   a spin random walk of density q_w [(rad/s)^2/s], discretised over dt:
//!   Q_pp = q_a dt^3/3, Q_pv = q_a dt^2/2, Q_vv = q_a dt, Q_ww = q_w dt (each times I_3).
//! - Update: S = H P H' + R factored by Cholesky (a typed error when S is not positive definite),
//!   NIS = y' S^-1 y, the gain from the factor, and the Joseph form
//!   P = (I - K H) P (I - K H)' + K R K' (multiplied out), symmetrised. Fixed-size matrices: no
//!   heap allocation.

use nalgebra::{SMatrix, SVector};

use crate::physics::{
    Cursor, Event, EventKind, Flow, Observer, Propagator, StateMatrix, StateVector, Watch,
};

/// Why an update was not applied.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum UpdateError {
    /// The innovation covariance S is not positive definite.
    #[error("the innovation covariance is not positive definite")]
    NotPositiveDefinite,
    /// The measurement lies outside the Mahalanobis gate.
    #[error("normalised innovation squared {nis} beyond the gate {gate}")]
    Gated {
        /// Normalised innovation squared of the rejected measurement.
        nis: f64,
        /// The gate it exceeded.
        gate: f64,
    },
    /// The measurement or its covariance is not finite.
    #[error("the measurement is not finite")]
    NotFinite,
}

/// The process-noise densities.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ProcessNoise {
    /// White-acceleration density q_a [m^2/s^3].
    pub acceleration_density: f64,
    /// Spin random-walk density q_w [(rad/s)^2/s].
    pub spin_density: f64,
}

impl ProcessNoise {
    /// Q over a step of `dt` seconds (see the module doc).
    #[expect(non_snake_case, reason = "matrix notation")]
    pub fn discretise(&self, dt: f64) -> StateMatrix {
        let dt = dt.abs();
        let qa = self.acceleration_density;
        let mut Q = StateMatrix::zeros();
        for i in 0..3 {
            Q[(i, i)] = qa * dt * dt * dt / 3.0;
            Q[(i, i + 3)] = qa * dt * dt / 2.0;
            Q[(i + 3, i)] = qa * dt * dt / 2.0;
            Q[(i + 3, i + 3)] = qa * dt;
            Q[(i + 6, i + 6)] = self.spin_density * dt;
        }
        Q
    }
}

/// What a prediction went through.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct PredictReport {
    /// Table bounces during the step.
    pub bounces: u32,
    /// Table bounces during the step on the robot's half (x < 0).
    pub robot_half_bounces: u32,
}

impl Observer for PredictReport {
    fn on_event(&mut self, event: &Event) -> Flow {
        if matches!(event.kind, EventKind::TableBounce { .. }) {
            self.bounces += 1;
            if event.before[0] < 0.0 {
                self.robot_half_bounces += 1;
            }
        }
        Flow::Continue
    }
}

/// The filter's estimate: state and covariance.
#[derive(Debug, Clone, Copy, PartialEq)]
#[expect(non_snake_case, reason = "matrix notation")]
pub struct Ekf {
    /// State (position [m], velocity [m/s], spin [rad/s]).
    pub x: StateVector,
    /// Covariance of the state.
    pub P: StateMatrix,
}

impl Ekf {
    /// A filter at a given estimate.
    #[expect(non_snake_case, reason = "matrix notation")]
    pub fn new(x: StateVector, P: StateMatrix) -> Self {
        Self { x, P }
    }

    /// Propagates the estimate by `dt` seconds (dt >= 0) through flight and bounces.
    pub fn predict(
        &mut self,
        propagator: &Propagator,
        noise: &ProcessNoise,
        dt: f64,
    ) -> PredictReport {
        let mut report = PredictReport::default();
        if dt <= 0.0 {
            return report;
        }
        let mut cursor = Cursor::tracking(0.0, self.x);
        propagator.advance(&mut cursor, dt, Watch::BOUNCES, &mut report);
        // F P F' with F the transition of the step (the filter always tracks it).
        let carried = cursor
            .tangent
            .as_ref()
            .map_or(self.P, |t| t.carry_covariance(&self.P));
        self.x = cursor.state;
        self.P = symmetrise(&(carried + noise.discretise(dt)));
        report
    }

    /// Fuses a measurement z = H x + noise(R) when its NIS is within `gate`; returns the NIS.
    #[expect(non_snake_case, reason = "matrix notation")]
    pub fn update<const M: usize>(
        &mut self,
        z: &SVector<f64, M>,
        H: &SMatrix<f64, M, 9>,
        R: &SMatrix<f64, M, M>,
        gate: f64,
    ) -> Result<f64, UpdateError> {
        if !z.iter().chain(R.iter()).all(|v| v.is_finite()) {
            return Err(UpdateError::NotFinite);
        }
        let y = z - H * self.x;
        let PHt = self.P * H.transpose();
        let S = H * PHt + R;
        let chol = symmetrise_small(&S)
            .cholesky()
            .ok_or(UpdateError::NotPositiveDefinite)?;
        let nis = y.dot(&chol.solve(&y));
        if !nis.is_finite() {
            return Err(UpdateError::NotPositiveDefinite);
        }
        if nis > gate {
            return Err(UpdateError::Gated { nis, gate });
        }
        // K = P H' S^-1 = (S^-1 H P)'.
        let K = chol.solve(&PHt.transpose()).transpose();
        self.x += K * y;
        // The Joseph form (I - K H) P (I - K H)' + K R K', multiplied out with S = H P H' + R:
        // P - K (P H')' - (P H') K' + K S K'. Equal to it for any gain, so a rounding error in K
        // still changes P to second order only; a third of the arithmetic of the 9x9 products.
        let K_PHt = K * PHt.transpose();
        self.P = symmetrise(&(self.P - K_PHt - K_PHt.transpose() + K * S * K.transpose()));
        Ok(nis)
    }

    /// Forgets what the filter learned about the spin: its covariance goes back to `variance`
    /// [(rad/s)^2] per axis, uncorrelated with the rest (the estimate itself is kept).
    pub fn reset_spin(&mut self, variance: f64) {
        for i in 6..9 {
            for j in 0..9 {
                self.P[(i, j)] = 0.0;
                self.P[(j, i)] = 0.0;
            }
            self.P[(i, i)] = variance;
        }
    }

    /// The normalised innovation squared of a measurement, without fusing it.
    #[expect(non_snake_case, reason = "matrix notation")]
    pub fn nis<const M: usize>(
        &self,
        z: &SVector<f64, M>,
        H: &SMatrix<f64, M, 9>,
        R: &SMatrix<f64, M, M>,
    ) -> Option<f64> {
        let y = z - H * self.x;
        let S = H * self.P * H.transpose() + R;
        let chol = symmetrise_small(&S).cholesky()?;
        Some(y.dot(&chol.solve(&y)))
    }
}

/// (A + A') / 2.
pub fn symmetrise(a: &StateMatrix) -> StateMatrix {
    (a + a.transpose()) * 0.5
}

fn symmetrise_small<const M: usize>(a: &SMatrix<f64, M, M>) -> SMatrix<f64, M, M> {
    (a + a.transpose()) * 0.5
}

/// H of a position measurement: [I 0 0].
#[expect(non_snake_case, reason = "matrix notation")]
pub fn position_H() -> SMatrix<f64, 3, 9> {
    SMatrix::<f64, 3, 9>::from_fn(|i, j| if i == j { 1.0 } else { 0.0 })
}

/// H of a position + spin measurement: [[I 0 0], [0 0 I]].
#[expect(non_snake_case, reason = "matrix notation")]
pub fn position_spin_H() -> SMatrix<f64, 6, 9> {
    SMatrix::<f64, 6, 9>::from_fn(|i, j| {
        if (i < 3 && j == i) || (i >= 3 && j == i + 3) {
            1.0
        } else {
            0.0
        }
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::Config;
    use nalgebra::{Matrix3, Vector3};

    #[test]
    fn process_noise_matches_the_white_acceleration_model() {
        let q = ProcessNoise {
            acceleration_density: 2.0,
            spin_density: 5.0,
        }
        .discretise(0.1);
        assert!((q[(0, 0)] - 2.0 * 1e-3 / 3.0).abs() < 1e-15);
        assert!((q[(0, 3)] - 2.0 * 1e-2 / 2.0).abs() < 1e-15);
        assert!((q[(3, 3)] - 0.2).abs() < 1e-15);
        assert!((q[(6, 6)] - 0.5).abs() < 1e-15);
        assert_eq!(q, q.transpose());
        assert!(q.cholesky().is_some(), "Q is positive definite");
    }

    /// A linear-Gaussian sanity check: one position update of a prior with P = I and R = I moves
    /// the estimate halfway and halves the variance.
    #[test]
    #[expect(non_snake_case, reason = "matrix notation")]
    fn update_halves_variance_for_equal_prior_and_noise() {
        let mut ekf = Ekf::new(StateVector::zeros(), StateMatrix::identity());
        let z = Vector3::new(1.0, -2.0, 0.5);
        let R = Matrix3::identity();
        let nis = ekf.update(&z, &position_H(), &R, 100.0).expect("fused");
        assert!((nis - z.norm_squared() / 2.0).abs() < 1e-12);
        assert!((ekf.x[0] - 0.5).abs() < 1e-12 && (ekf.x[1] + 1.0).abs() < 1e-12);
        assert!((ekf.P[(0, 0)] - 0.5).abs() < 1e-12);
        assert_eq!(ekf.P[(3, 3)], 1.0);
        let far = Vector3::new(50.0, 0.0, 0.0);
        assert!(matches!(
            ekf.update(&far, &position_H(), &R, 10.0),
            Err(UpdateError::Gated { .. })
        ));
    }

    /// The multiplied-out covariance update equals the Joseph form written as products, for a
    /// correlated prior and a position + spin measurement.
    #[test]
    #[expect(non_snake_case, reason = "matrix notation")]
    fn update_covariance_is_the_joseph_form() {
        let A = StateMatrix::from_fn(|i, j| ((i * 7 + j * 3) % 5) as f64 * 0.1 - 0.2);
        let P = A * A.transpose() + StateMatrix::identity() * 0.5;
        let x = StateVector::from_fn(|i, _| i as f64 * 0.3);
        let H = position_spin_H();
        let R = SMatrix::<f64, 6, 6>::from_diagonal_element(0.2);
        let z = H * x + SVector::<f64, 6>::from_fn(|i, _| 0.1 * i as f64 - 0.2);
        let mut ekf = Ekf::new(x, P);
        ekf.update(&z, &H, &R, 1e6).expect("fused");
        let S = H * P * H.transpose() + R;
        let K = P * H.transpose() * S.try_inverse().expect("S invertible");
        let I_KH = StateMatrix::identity() - K * H;
        let joseph = I_KH * P * I_KH.transpose() + K * R * K.transpose();
        assert!(
            (ekf.P - joseph).amax() < 1e-13 * P.amax(),
            "{}",
            (ekf.P - joseph).amax()
        );
        assert!((ekf.x - (x + K * (z - H * x))).amax() < 1e-13);
        assert_eq!(ekf.P, ekf.P.transpose());
    }

    #[test]
    fn predict_counts_bounces_and_grows_uncertainty() {
        let config = Config::default();
        let propagator = Propagator::new(&config);
        let x = crate::physics::BallState::new(
            Vector3::new(-0.5, 0.0, 0.05),
            Vector3::new(-4.0, 0.0, -1.0),
            Vector3::zeros(),
        )
        .to_vector();
        let mut ekf = Ekf::new(x, StateMatrix::identity() * 1e-6);
        let noise = ProcessNoise {
            acceleration_density: 1.0,
            spin_density: 1.0,
        };
        let report = ekf.predict(&propagator, &noise, 0.05);
        assert_eq!(report.bounces, 1);
        assert_eq!(report.robot_half_bounces, 1);
        assert!(ekf.x[5] > 0.0);
        assert!(ekf.P[(3, 3)] > 1e-6);
        assert_eq!(ekf.P, ekf.P.transpose());
    }
}
