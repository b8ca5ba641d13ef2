//! Table bounce: the impulse model with Coulomb friction of Nakashima, Ogawa, Kobayashi and Hayakawa
//! (ACC 2010), for a thin spherical shell (I = 2/3 m r^2), as stated in docs/models.md "Table bounce":
//!
//! ```text
//! u = (v_x - r w_y, v_y + r w_x)                slip of the contact point
//! alpha = mu (1 + e) |v_z| / |u|                 sliding throughout the impact
//! alpha = 2/5  if the value above is >= 2/5      the ball rolls out (slip becomes zero)
//! v_x' = v_x - alpha u_x   v_y' = v_y - alpha u_y   v_z' = -e v_z
//! w_x' = w_x - 3 alpha u_y / (2 r)   w_y' = w_y + 3 alpha u_x / (2 r)   w_z' = w_z
//! ```
//!
//! [`TableBounce::apply`] also returns the exact Jacobian of this map; in the sliding case alpha
//! depends on the state, which adds the terms of d(alpha u)/d(v, w).

use nalgebra::{Matrix2, SMatrix, Vector2};

use super::state::{SPIN, StateMatrix, StateRow, StateVector, VELOCITY};
use crate::config::Config;

/// Tangential impulse ratio at which the contact point stops slipping (thin shell: 2/5).
pub const ROLLING_ALPHA: f64 = 0.4;

/// How the contact point ends the impact.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum BounceRegime {
    /// Slipping throughout the impact: friction impulse mu (1 + e) m |v_z| against the slip.
    Sliding,
    /// Slip brought to zero during the impact: the ball leaves rolling.
    Rolling,
}

/// The result of one bounce.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Bounce {
    /// State just after the impact (position unchanged).
    pub state: StateVector,
    /// d(state after)/d(state before) at a fixed contact point.
    pub jacobian: StateMatrix,
    /// d(state after)/d(e_t, mu_t): the restitution's and the friction's columns.
    pub table_jacobian: SMatrix<f64, 9, 2>,
    /// Sliding or rolling.
    pub regime: BounceRegime,
}

/// The table-bounce model with its restitution, friction and the ball radius.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TableBounce {
    restitution: f64,
    friction: f64,
    radius: f64,
}

impl TableBounce {
    /// The model with the configured table restitution and friction and ball radius.
    pub fn new(config: &Config) -> Self {
        Self {
            restitution: config.table.restitution,
            friction: config.table.friction,
            radius: config.ball.radius,
        }
    }

    /// The same model with another restitution e_t and friction mu_t [-].
    pub fn with_table(&self, restitution: f64, friction: f64) -> Self {
        Self {
            restitution,
            friction,
            ..*self
        }
    }

    /// The restitution e_t and friction mu_t [-].
    pub fn table(&self) -> (f64, f64) {
        (self.restitution, self.friction)
    }

    /// Slip velocity of the contact point, (v_x - r w_y, v_y + r w_x) [m/s].
    pub fn slip(&self, x: &StateVector) -> Vector2<f64> {
        let r = self.radius;
        Vector2::new(x[VELOCITY] - r * x[SPIN + 1], x[VELOCITY + 1] + r * x[SPIN])
    }

    /// The margin that decides the regime of an impact in state `x`,
    /// mu (1 + e) |v_z| - 2/5 |u| [m/s] (rolling when >= 0, sliding below), and its gradient.
    pub fn regime_margin(&self, x: &StateVector) -> (f64, StateRow) {
        let k = self.friction * (1.0 + self.restitution);
        let vz = x[VELOCITY + 2];
        let u = self.slip(x);
        let u_norm = u.norm();
        let mut gradient = StateRow::zeros();
        gradient[VELOCITY + 2] = if vz < 0.0 { -k } else { k };
        if u_norm > 0.0 {
            let u_hat = u * (ROLLING_ALPHA / u_norm);
            gradient[VELOCITY] -= u_hat.x;
            gradient[SPIN + 1] += self.radius * u_hat.x;
            gradient[VELOCITY + 1] -= u_hat.y;
            gradient[SPIN] -= self.radius * u_hat.y;
        }
        (k * vz.abs() - ROLLING_ALPHA * u_norm, gradient)
    }

    /// The state just after an impact with the table, and its Jacobian.
    pub fn apply(&self, x: &StateVector) -> Bounce {
        self.apply_in(x, None)
    }

    /// The impact as the other regime would make it (sliding where the ball rolls out, or
    /// rolling where it slides): the other branch of the bounce map, for the spread between the
    /// two when the state is uncertain.
    pub fn apply_other_regime(&self, x: &StateVector) -> Bounce {
        let other = match self.apply(x).regime {
            BounceRegime::Sliding => BounceRegime::Rolling,
            BounceRegime::Rolling => BounceRegime::Sliding,
        };
        self.apply_in(x, Some(other))
    }

    /// The impact in the regime the state decides, or in `forced`.
    fn apply_in(&self, x: &StateVector, forced: Option<BounceRegime>) -> Bounce {
        let r = self.radius;
        let e = self.restitution;
        let u = self.slip(x);
        let u_norm = u.norm();
        let vz = x[VELOCITY + 2];
        let sliding_alpha = if u_norm > 0.0 {
            self.friction * (1.0 + e) * vz.abs() / u_norm
        } else {
            f64::INFINITY
        };

        // du/dx: u_x = v_x - r w_y, u_y = v_y + r w_x.
        let mut du_dx = SMatrix::<f64, 2, 9>::zeros();
        du_dx[(0, VELOCITY)] = 1.0;
        du_dx[(0, SPIN + 1)] = -r;
        du_dx[(1, VELOCITY + 1)] = 1.0;
        du_dx[(1, SPIN)] = r;

        // Tangential impulse per unit mass, delta = alpha u, and its Jacobian; with its
        // derivative with respect to (e, mu) (zero when the ball rolls out).
        let mut ddelta_dtable = Matrix2::zeros();
        let rolls = match forced {
            Some(regime) => regime == BounceRegime::Rolling || u_norm == 0.0,
            None => sliding_alpha >= ROLLING_ALPHA,
        };
        let (regime, delta, ddelta_dx) = if rolls {
            (
                BounceRegime::Rolling,
                u * ROLLING_ALPHA,
                du_dx * ROLLING_ALPHA,
            )
        } else {
            let k = self.friction * (1.0 + e);
            let u_hat = u / u_norm;
            let delta = u_hat * (k * vz.abs());
            let ddelta_du =
                (Matrix2::identity() - u_hat * u_hat.transpose()) * (k * vz.abs() / u_norm);
            let mut ddelta_dx = ddelta_du * du_dx;
            let dabs_vz = if vz < 0.0 { -1.0 } else { 1.0 };
            for row in 0..2 {
                ddelta_dx[(row, VELOCITY + 2)] += k * dabs_vz * u_hat[row];
                ddelta_dtable[(row, 0)] = self.friction * vz.abs() * u_hat[row];
                ddelta_dtable[(row, 1)] = (1.0 + e) * vz.abs() * u_hat[row];
            }
            (BounceRegime::Sliding, delta, ddelta_dx)
        };

        let spin_gain = 3.0 / (2.0 * r);
        let mut after = *x;
        after[VELOCITY] -= delta.x;
        after[VELOCITY + 1] -= delta.y;
        after[VELOCITY + 2] = -e * vz;
        after[SPIN] -= spin_gain * delta.y;
        after[SPIN + 1] += spin_gain * delta.x;

        let mut jacobian = StateMatrix::identity();
        jacobian[(VELOCITY + 2, VELOCITY + 2)] = -e;
        for col in 0..9 {
            jacobian[(VELOCITY, col)] -= ddelta_dx[(0, col)];
            jacobian[(VELOCITY + 1, col)] -= ddelta_dx[(1, col)];
            jacobian[(SPIN, col)] -= spin_gain * ddelta_dx[(1, col)];
            jacobian[(SPIN + 1, col)] += spin_gain * ddelta_dx[(0, col)];
        }

        let mut table_jacobian = SMatrix::<f64, 9, 2>::zeros();
        table_jacobian[(VELOCITY + 2, 0)] = -vz;
        for col in 0..2 {
            table_jacobian[(VELOCITY, col)] = -ddelta_dtable[(0, col)];
            table_jacobian[(VELOCITY + 1, col)] = -ddelta_dtable[(1, col)];
            table_jacobian[(SPIN, col)] = -spin_gain * ddelta_dtable[(1, col)];
            table_jacobian[(SPIN + 1, col)] = spin_gain * ddelta_dtable[(0, col)];
        }

        Bounce {
            state: after,
            jacobian,
            table_jacobian,
            regime,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::physics::state::BallState;
    use approx::assert_relative_eq;
    use nalgebra::Vector3;

    fn model() -> TableBounce {
        TableBounce::new(&Config::default())
    }

    fn at_contact(v: [f64; 3], w: [f64; 3]) -> StateVector {
        BallState::new(Vector3::new(0.5, 0.1, 0.02), v.into(), w.into()).to_vector()
    }

    #[test]
    fn normal_velocity_is_restituted() {
        let b = model().apply(&at_contact([0.0, 0.0, -4.0], [0.0, 0.0, 0.0]));
        assert_relative_eq!(b.state[VELOCITY + 2], 3.6, epsilon = 1e-12);
        assert_eq!(
            b.state.fixed_rows::<3>(0),
            at_contact([0.0; 3], [0.0; 3]).fixed_rows::<3>(0)
        );
    }

    /// A fast horizontal ball with little spin slides: the friction impulse is mu (1 + e) |v_z|.
    #[test]
    fn sliding_impulse_is_coulomb() {
        let x = at_contact([-6.0, 0.0, -2.0], [0.0, 0.0, 0.0]);
        let b = model().apply(&x);
        assert_eq!(b.regime, BounceRegime::Sliding);
        // mu (1 + e) |v_z| = 0.25 * 1.9 * 2 = 0.95 m/s against the slip (-x), so v_x rises.
        assert_relative_eq!(b.state[VELOCITY], -6.0 + 0.95, epsilon = 1e-12);
        // The friction at the bottom of the ball spins it up as topspin for a -x ball: w_y < 0.
        assert_relative_eq!(b.state[SPIN + 1], -1.5 / 0.02 * 0.95, epsilon = 1e-9);
    }

    #[test]
    fn rolling_bounce_leaves_zero_slip() {
        // Slow ball, steep impact: alpha would exceed 2/5.
        let x = at_contact([-1.0, 0.4, -4.0], [20.0, -10.0, 5.0]);
        let b = model().apply(&x);
        assert_eq!(b.regime, BounceRegime::Rolling);
        let slip_after = model().slip(&b.state);
        assert!(
            slip_after.norm() < 1e-12,
            "slip after rolling bounce {slip_after}"
        );
        assert_eq!(b.state[SPIN + 2], 5.0);
    }
}
