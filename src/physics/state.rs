//! The ball's 9-dimensional state in the `table` frame: position [m], velocity [m/s], spin [rad/s].

use nalgebra::{SMatrix, SVector, Vector3};
use serde::{Deserialize, Serialize};

/// The state as a column vector, ordered (position, velocity, spin).
pub type StateVector = SVector<f64, 9>;
/// A 9x9 matrix over the state (state-transition matrix, covariance).
pub type StateMatrix = SMatrix<f64, 9, 9>;
/// A row vector over the state (e.g. the gradient of an event time).
pub type StateRow = SMatrix<f64, 1, 9>;

/// Index of the first position component in a [`StateVector`].
pub const POSITION: usize = 0;
/// Index of the first velocity component in a [`StateVector`].
pub const VELOCITY: usize = 3;
/// Index of the first spin component in a [`StateVector`].
pub const SPIN: usize = 6;

/// Position, velocity and spin of the ball in the `table` frame.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct BallState {
    /// Ball centre [m].
    pub position: Vector3<f64>,
    /// Velocity of the ball centre [m/s].
    pub velocity: Vector3<f64>,
    /// Angular velocity [rad/s].
    pub spin: Vector3<f64>,
}

impl BallState {
    /// A state from its three parts.
    pub fn new(position: Vector3<f64>, velocity: Vector3<f64>, spin: Vector3<f64>) -> Self {
        Self {
            position,
            velocity,
            spin,
        }
    }

    /// The state as a column vector (position, velocity, spin).
    pub fn to_vector(&self) -> StateVector {
        let mut x = StateVector::zeros();
        x.fixed_rows_mut::<3>(POSITION).copy_from(&self.position);
        x.fixed_rows_mut::<3>(VELOCITY).copy_from(&self.velocity);
        x.fixed_rows_mut::<3>(SPIN).copy_from(&self.spin);
        x
    }

    /// The state from a column vector (position, velocity, spin).
    pub fn from_vector(x: &StateVector) -> Self {
        Self {
            position: x.fixed_rows::<3>(POSITION).into_owned(),
            velocity: x.fixed_rows::<3>(VELOCITY).into_owned(),
            spin: x.fixed_rows::<3>(SPIN).into_owned(),
        }
    }

    /// True when every component is finite.
    pub fn is_finite(&self) -> bool {
        self.to_vector().iter().all(|v| v.is_finite())
    }

    /// Kinetic energy of a thin spherical shell (I = 2/3 m r^2) [J].
    pub fn kinetic_energy(&self, mass: f64, radius: f64) -> f64 {
        let inertia = 2.0 / 3.0 * mass * radius * radius;
        0.5 * mass * self.velocity.norm_squared() + 0.5 * inertia * self.spin.norm_squared()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn vector_round_trip_keeps_order() {
        let s = BallState::new(
            Vector3::new(1.0, 2.0, 3.0),
            Vector3::new(4.0, 5.0, 6.0),
            Vector3::new(7.0, 8.0, 9.0),
        );
        let x = s.to_vector();
        assert_eq!(x.as_slice(), &[1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0]);
        assert_eq!(BallState::from_vector(&x), s);
    }
}
