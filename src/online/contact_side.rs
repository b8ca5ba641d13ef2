//! The published covariance of a ball near a table contact: which side of the contact it is on.
//!
//! A few millimetres above the table a detection fits a ball still coming down and a ball
//! already bouncing back alike (both are where it is; their vertical velocities differ by
//! (1 + e) |v_z|). The filter follows one side, the one its prediction took, and its covariance
//! knows nothing of the other: with the 150 fps camera, one estimate in some 10,000 is taken a
//! couple of milliseconds on the wrong side of the true bounce, its vertical velocity metres per
//! second off at a standard deviation of millimetres per second (docs/accuracy.md, "The side of
//! the bounce"). What the estimate is sure of is the mixture of the two sides, and the
//! covariance it publishes says so:
//!
//! ```text
//! h = z - r,  u = |v_z|,  w = sqrt(u^2 + 2 g h)
//! tau = 2 h / (u + w)                    time to the contact (coming down) or since it (going up):
//!                                        1/2 g tau^2 + u tau = h, the flight under gravity
//! sigma_tau^2 = J P J',  J = d tau / d(z, v_z) = (1 / w, -sign(v_z) tau / w)
//! p = Phi(-tau / sigma_tau)              the chance the ball is on the other side
//! P_published = P + p D D'               D the bounce's jump in velocity and spin
//! ```
//!
//! P + p D D' is the mean square error about the followed side's mean of the two-component
//! mixture (p of it on the other side, whose mean is the followed one's plus D). D comes from
//! the bounce map at the estimate (coming down) or is the jump the filter's own last bounce
//! made (going up: the rolling bounce's map cannot be inverted). Only the published covariance
//! is widened: the filter goes on with its own (carried, the wider one lost what the detections
//! after the contact would tell; docs/accuracy.md), and the detection after the contact decides
//! which side the ball is on. A pure function: no state, no allocation.

use crate::model::stats::normal_cdf;
use crate::physics::bounce::TableBounce;
use crate::physics::state::{POSITION, StateMatrix, StateVector, VELOCITY};

/// Beyond this many standard deviations of the contact time the other side is not considered
/// (its chance under 1e-15).
const SIDE_SIGMAS: f64 = 8.0;

/// The covariance `p` of state `x`, widened by the chance that the ball is on the other side of
/// a table contact (module doc). `over_table`: whether the ball is above the table's top;
/// `jump`: the state change of the filter's last bounce (after - before), if it made one.
pub fn with_contact_side(
    bounce: &TableBounce,
    (radius, gravity): (f64, f64),
    x: &StateVector,
    p: &StateMatrix,
    over_table: bool,
    jump: Option<&StateVector>,
) -> StateMatrix {
    let (height, vz) = (x[POSITION + 2] - radius, x[VELOCITY + 2]);
    // Coming down, the other side has bounced already; going up after the filter's bounce, it
    // has not bounced yet.
    let coming_down = vz < 0.0 && over_table;
    let going_up_after_a_bounce = vz > 0.0 && jump.is_some();
    if !(coming_down || going_up_after_a_bounce) {
        return *p;
    }
    // From 1/2 g tau^2 + u tau - h = 0: d tau/dh = 1 / w, d tau/du = -tau / w (w = g tau + u).
    let speed = vz.abs();
    let w = (speed * speed + 2.0 * gravity * height.max(0.0)).sqrt();
    let tau = 2.0 * height / (speed + w);
    let (dz, dv) = (1.0 / w, -vz.signum() * tau / w);
    let (i, j) = (POSITION + 2, VELOCITY + 2);
    let variance = dz * dz * p[(i, i)] + 2.0 * dz * dv * p[(i, j)] + dv * dv * p[(j, j)];
    if variance.is_nan() || variance <= 0.0 || tau > SIDE_SIGMAS * variance.sqrt() {
        return *p;
    }
    let other = normal_cdf(-tau / variance.sqrt());
    // The bounce map only where the other side has a chance.
    let mut d = match jump {
        Some(jump) if !coming_down => -jump,
        _ => bounce.apply(x).state - x,
    };
    // Both sides are where the detection is: the jump is in velocity and spin only.
    d.fixed_rows_mut::<3>(POSITION).fill(0.0);
    p + d * d.transpose() * other
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::Config;
    use approx::assert_relative_eq;

    const G: f64 = 9.81;

    /// The time to (or since) the contact of a ball `h` above it at vertical speed `u`, from
    /// 1/2 g tau^2 + u tau = h solved the textbook way.
    fn contact_time(h: f64, u: f64) -> f64 {
        (-u + (u * u + 2.0 * G * h).sqrt()) / G
    }

    fn ball(z: f64, vz: f64) -> StateVector {
        StateVector::from_column_slice(&[0.5, 0.0, z, -3.0, 0.0, vz, 0.0, 50.0, 0.0])
    }

    fn covariance(sigma_z: f64, sigma_vz: f64) -> StateMatrix {
        let mut p = StateMatrix::identity() * 1e-6;
        p[(2, 2)] = sigma_z * sigma_z;
        p[(5, 5)] = sigma_vz * sigma_vz;
        p
    }

    /// Coming down, the other side's chance is Phi(-tau / sigma_tau) and its jump the bounce
    /// map's; far from the table, beside it, or at rest nothing changes.
    #[test]
    fn a_ball_coming_down_may_have_bounced() {
        let config = Config::default();
        let bounce = TableBounce::new(&config);
        let r = config.ball.radius;
        // 1 mm above the contact at 2 m/s: tau about 0.5 ms; sigma_z 1 mm: sigma_tau = 1 mm / w.
        let x = ball(r + 0.001, -2.0);
        let p = covariance(0.001, 1e-6);
        let widened = with_contact_side(&bounce, (r, G), &x, &p, true, None);
        let w = (4.0 + 2.0 * G * 0.001_f64).sqrt();
        let chance = normal_cdf(-contact_time(0.001, 2.0) / (0.001 / w));
        let d = bounce.apply(&x).state - x;
        assert_relative_eq!(
            widened[(5, 5)] - p[(5, 5)],
            chance * d[5] * d[5],
            max_relative = 1e-9
        );
        assert_relative_eq!(widened[(7, 5)], chance * d[7] * d[5], max_relative = 1e-9);
        // The position is where the detection is on either side.
        assert_eq!(widened.fixed_view::<3, 3>(0, 0), p.fixed_view::<3, 3>(0, 0));
        assert!(widened[(5, 5)] > 1.0, "{}", widened[(5, 5)]);
        // Far above the table (also at the top of a flight, where v_z is about 0), beside it,
        // or without a vertical velocity: unchanged.
        assert_eq!(
            with_contact_side(&bounce, (r, G), &ball(0.3, -2.0), &p, true, None),
            p
        );
        let apex = covariance(0.001, 0.05);
        assert_eq!(
            with_contact_side(&bounce, (r, G), &ball(0.3, -0.01), &apex, true, None),
            apex
        );
        assert_eq!(with_contact_side(&bounce, (r, G), &x, &p, false, None), p);
        assert_eq!(
            with_contact_side(&bounce, (r, G), &ball(r + 0.001, 0.0), &p, true, None),
            p
        );
    }

    /// Going up, the other side has not bounced: the filter's own jump, at the chance that the
    /// contact is still ahead; without a bounce of the filter's (a ball launched upwards)
    /// nothing changes.
    #[test]
    fn a_ball_going_up_may_not_have_bounced_yet() {
        let config = Config::default();
        let bounce = TableBounce::new(&config);
        let r = config.ball.radius;
        let before = ball(r, -2.0);
        let jump = bounce.apply(&before).state - before;
        // Just bounced (tau 0.2 ms at sigma_tau 0.5 ms) against long after it.
        let p = covariance(0.001, 1e-6);
        let near = with_contact_side(
            &bounce,
            (r, G),
            &ball(r + 0.0004, 1.8),
            &p,
            true,
            Some(&jump),
        );
        let far = with_contact_side(&bounce, (r, G), &ball(r + 0.05, 1.8), &p, true, Some(&jump));
        let w = (1.8f64 * 1.8 + 2.0 * G * 0.0004).sqrt();
        let chance = normal_cdf(-contact_time(0.0004, 1.8) / (0.001 / w));
        assert_relative_eq!(
            near[(5, 5)] - p[(5, 5)],
            chance * jump[5] * jump[5],
            max_relative = 1e-9
        );
        assert_eq!(far, p);
        assert_eq!(
            with_contact_side(&bounce, (r, G), &ball(r + 0.0004, 1.8), &p, true, None),
            p
        );
    }

    /// sigma_tau is the first-order spread of the contact time over (z, v_z), checked against
    /// the chance computed from the textbook solution's finite differences.
    #[test]
    fn the_contact_time_spread_is_its_gradient_through_the_covariance() {
        let config = Config::default();
        let bounce = TableBounce::new(&config);
        let r = config.ball.radius;
        let x = ball(r + 0.002, -2.5);
        let mut p = covariance(0.0015, 0.05);
        p[(2, 5)] = 0.3 * 0.0015 * 0.05;
        p[(5, 2)] = p[(2, 5)];
        let tau = |z: f64, vz: f64| contact_time(z - r, vz.abs());
        let h = 1e-7;
        let dz = (tau(x[2] + h, x[5]) - tau(x[2] - h, x[5])) / (2.0 * h);
        let dv = (tau(x[2], x[5] + h) - tau(x[2], x[5] - h)) / (2.0 * h);
        let variance = dz * dz * p[(2, 2)] + 2.0 * dz * dv * p[(2, 5)] + dv * dv * p[(5, 5)];
        let chance = normal_cdf(-tau(x[2], x[5]) / variance.sqrt());
        let d = bounce.apply(&x).state - x;
        let widened = with_contact_side(&bounce, (r, G), &x, &p, true, None);
        assert_relative_eq!(
            widened[(5, 5)] - p[(5, 5)],
            chance * d[5] * d[5],
            max_relative = 1e-6
        );
    }
}
