//! The physical parameters that differ from ball to ball and from table to table, and that the
//! estimator learns online (docs/estimator.md): scale factors k_D and k_M on the drag
//! and Magnus forces of the flight model ([`super::aero`]), and the table's restitution e_t and
//! friction mu_t of the bounce model ([`super::bounce`]).
//!
//! The propagator carries, when asked, the sensitivity of the state to them
//! ([`super::Tangent::params`]): in flight d/dt (dx/dtheta) = A (dx/dtheta) + df/dtheta, where
//! df/dk_D and df/dk_M are the drag and Magnus accelerations at unit scale; at a bounce
//! dx+/dtheta = J (dx-/dtheta) + db/dtheta, with the bounce map's own derivative with respect to
//! e_t and mu_t; an event's time moves with them as with the state.

use nalgebra::{SMatrix, SVector};

use crate::config::Config;

/// Number of physical parameters.
pub const PARAMS: usize = 4;
/// Index of k_D, the drag scale factor.
pub const DRAG_SCALE: usize = 0;
/// Index of k_M, the Magnus scale factor.
pub const MAGNUS_SCALE: usize = 1;
/// Index of e_t, the table's normal restitution.
pub const RESTITUTION: usize = 2;
/// Index of mu_t, the table's Coulomb friction.
pub const FRICTION: usize = 3;
// The table's two parameters are adjacent (the bounce's columns are added as one block), and so
// are the flight's two.
const _: () = assert!(FRICTION == RESTITUTION + 1 && MAGNUS_SCALE == DRAG_SCALE + 1);

/// The parameters as a column vector (k_D, k_M, e_t, mu_t).
pub type ParamVector = SVector<f64, PARAMS>;
/// d(state)/d(parameters): 9 rows, one column per parameter.
pub type ParamMatrix = SMatrix<f64, 9, PARAMS>;
/// d(a scalar)/d(parameters), e.g. of an event's time [s per parameter unit].
pub type ParamRow = SMatrix<f64, 1, PARAMS>;
/// A covariance over the parameters.
pub type ParamCovariance = SMatrix<f64, PARAMS, PARAMS>;
/// Dimension of the augmented state: the ball's 9 and the parameters.
pub const AUGMENTED: usize = 9 + PARAMS;
/// A covariance over the augmented state (ball, parameters).
pub type AugmentedMatrix = SMatrix<f64, AUGMENTED, AUGMENTED>;
/// The state and the parameters together, (x, theta).
pub type AugmentedVector = SVector<f64, AUGMENTED>;

/// The covariance over (state, parameters) of a state of covariance `p` and parameters known
/// exactly.
pub fn with_known_params(p: &super::StateMatrix) -> AugmentedMatrix {
    let mut augmented = AugmentedMatrix::zeros();
    augmented.fixed_view_mut::<9, 9>(0, 0).copy_from(p);
    augmented
}

/// The adaptable physical parameters.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PhysicsParams {
    /// k_D [-]: scales the drag force of C_D(Sp) (1 = the configured polynomial).
    pub drag_scale: f64,
    /// k_M [-]: scales the Magnus force of C_M(Sp) (1 = the configured polynomial).
    pub magnus_scale: f64,
    /// e_t [-]: the table's normal coefficient of restitution.
    pub restitution: f64,
    /// mu_t [-]: the Coulomb friction between ball and table.
    pub friction: f64,
}

impl PhysicsParams {
    /// The names of the parameters as reported, in vector order.
    pub const NAMES: [&'static str; PARAMS] =
        ["drag_scale", "magnus_scale", "restitution", "friction"];

    /// The configured values (`aero.drag_scale`, `aero.magnus_scale`, `table.restitution`,
    /// `table.friction`).
    pub fn from_config(config: &Config) -> Self {
        Self {
            drag_scale: config.aero.drag_scale,
            magnus_scale: config.aero.magnus_scale,
            restitution: config.table.restitution,
            friction: config.table.friction,
        }
    }

    /// The parameters as a vector (k_D, k_M, e_t, mu_t).
    pub fn to_vector(&self) -> ParamVector {
        ParamVector::new(
            self.drag_scale,
            self.magnus_scale,
            self.restitution,
            self.friction,
        )
    }

    /// The parameters of a vector (k_D, k_M, e_t, mu_t).
    pub fn from_vector(v: &ParamVector) -> Self {
        Self {
            drag_scale: v[DRAG_SCALE],
            magnus_scale: v[MAGNUS_SCALE],
            restitution: v[RESTITUTION],
            friction: v[FRICTION],
        }
    }

    /// The configuration with these parameters in place of its own.
    pub fn apply_to(&self, config: &mut Config) {
        config.aero.drag_scale = self.drag_scale;
        config.aero.magnus_scale = self.magnus_scale;
        config.table.restitution = self.restitution;
        config.table.friction = self.friction;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn vector_and_config_round_trip() {
        let p = PhysicsParams {
            drag_scale: 1.1,
            magnus_scale: 0.6,
            restitution: 0.93,
            friction: 0.2,
        };
        assert_eq!(PhysicsParams::from_vector(&p.to_vector()), p);
        let mut config = Config::default();
        p.apply_to(&mut config);
        assert_eq!(PhysicsParams::from_config(&config), p);
        assert_eq!(p.to_vector()[RESTITUTION], 0.93);
    }
}
