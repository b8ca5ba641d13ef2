//! The racket impact model against the numbers of its sources (Kawazoe & Suzuki;
//! Kawazoe et al. 2010; docs/models.md "Racket impact") and against its invariants, and on
//! real rebounds (tt_rackets).
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    reason = "test helpers outside #[test] functions: fail loudly"
)]

use approx::assert_relative_eq;
use nalgebra::{Vector2, Vector3};
use ttball::config::Config;
use ttball::online::stroke::{Aim, PlanError, ReturnCondition, ReturnOutcome, Stroke};
use ttball::physics::bounce::BounceRegime;
use ttball::physics::racket::{RacketModel, RacketState, rebound_power_coefficient};
use ttball::physics::state::BallState;

/// The defaults with the seeds' rubber (config/presets/rubber_sriver_seed.yaml): Kawazoe &
/// Suzuki's e_RB(V), a grip that rolls the ball out, no torsional return, known exactly.
fn seed_rubber() -> Config {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("config/presets/rubber_sriver_seed.yaml");
    ttball::config::yaml::load(Some(&path), &[] as &[String]).unwrap()
}

/// The seed's own ball (38 mm, 2.5 g) and rubber.
fn seed_config() -> Config {
    let mut config = seed_rubber();
    config.ball.mass = 0.0025;
    config.ball.radius = 0.019;
    config
}

/// The seed racket hanging free (no arm), as in the paper's figures.
fn free_racket(config: &Config) -> RacketModel {
    RacketModel::new(config).with_arm_mass(0.0)
}

/// Top point A of the seed racket: 132 mm from its centre of gravity.
const POINT_A: f64 = 0.132;

#[test]
fn reduced_mass_at_the_top_point_is_the_papers_78_1_g() {
    let model = free_racket(&seed_config());
    let mr = model.reduced_mass(POINT_A);
    assert!((mr - 0.0781).abs() < 0.0002, "M_r = {mr} kg");
    // At the centre of gravity a free racket's reduced mass is its whole mass.
    assert_relative_eq!(model.reduced_mass(0.0), 0.171, max_relative = 1e-12);
    // Holding the racket (1 kg at the grip) makes it larger everywhere on the face, much larger
    // near the face centre, 18 mm above the centre of gravity (Kawazoe & Suzuki Fig. 10 and 19); at the
    // tip the racket turns about a point near the hand, where the arm's mass adds little.
    let held = RacketModel::new(&seed_config());
    let (min, max) = held.face_offsets();
    for i in 0..=50 {
        let b = min + (max - min) * f64::from(i) / 50.0;
        assert!(held.reduced_mass(b) >= model.reduced_mass(b), "at {b}");
    }
    assert!(held.reduced_mass(0.018) > 1.5 * model.reduced_mass(0.018));
}

#[test]
fn rebound_power_coefficients_are_the_papers_at_8_16_24_30_m_s() {
    let config = seed_config();
    let model = free_racket(&config);
    let ratio = 0.0025 / 0.0781;
    for (speed, expected) in [(8.0, 0.620), (16.0, 0.524), (24.0, 0.429), (30.0, 0.358)] {
        let e = rebound_power_coefficient(model.rubber_restitution(speed), ratio);
        assert!(
            (e - expected).abs() < 0.0006,
            "e({speed}) = {e}, paper {expected}"
        );
        // The same through the whole normal impact at point A (M_r = 78.2 g).
        let impact = model.normal_impact(speed, POINT_A).expect("contact");
        assert!(
            (impact.rebound_power_coefficient - expected).abs() < 0.001,
            "e({speed}) = {}",
            impact.rebound_power_coefficient
        );
    }
}

#[test]
fn e_falls_with_impact_speed() {
    let model = free_racket(&seed_config());
    let mut last = f64::INFINITY;
    for speed in [2.0, 5.0, 10.0, 15.0, 20.0, 25.0, 30.0] {
        let e = model
            .normal_impact(speed, 0.0)
            .expect("contact")
            .rebound_power_coefficient;
        assert!(e < last, "e({speed}) = {e} does not fall");
        last = e;
    }
}

/// Kawazoe & Suzuki Fig. 13: e falls with a smaller reduced mass, steeply below about 20 g and hardly
/// above it.
#[test]
fn e_falls_with_smaller_reduced_mass_little_above_20_g() {
    let model = free_racket(&seed_config());
    for speed in [8.0, 16.0, 24.0] {
        let e_rb = model.rubber_restitution(speed);
        let e = |mr: f64| rebound_power_coefficient(e_rb, 0.0025 / mr);
        let masses = [0.002, 0.005, 0.01, 0.02, 0.05, 0.0781, 0.171, 1.0];
        for pair in masses.windows(2) {
            assert!(
                e(pair[0]) < e(pair[1]),
                "e not rising with M_r at {speed} m/s"
            );
        }
        // The knee: from 20 g down to 5 g e loses more than twice what it gains from 20 g up to
        // the seed racket's smallest reduced mass (78.1 g) ...
        let above = e(0.0781) - e(0.02);
        let below = e(0.02) - e(0.005);
        assert!(below > 2.5 * above, "{below} vs {above}");
        // ... and from there a held racket or even a rigid wall adds little (conclusion 2).
        assert!(e(1.0) - e(0.0781) < 0.06);
        assert!(e_rb - e(0.0781) < 0.06);
    }
}

/// Kawazoe & Suzuki Fig. 19: along the long axis, e peaks where the reduced mass is largest.
#[test]
fn e_peaks_where_the_reduced_mass_is_largest_along_the_long_axis() {
    for arm_mass in [0.0, 1.0] {
        let model = RacketModel::new(&seed_config()).with_arm_mass(arm_mass);
        let (min, max) = model.face_offsets();
        let offsets: Vec<f64> = (0..=200)
            .map(|i| min + (max - min) * f64::from(i) / 200.0)
            .collect();
        let argmax = |f: &dyn Fn(f64) -> f64| {
            offsets
                .iter()
                .copied()
                .max_by(|a, b| f(*a).total_cmp(&f(*b)))
                .expect("offsets")
        };
        let peak_e = argmax(&|b| {
            model
                .normal_impact(30.0, b)
                .expect("contact")
                .rebound_power_coefficient
        });
        let peak_mass = argmax(&|b| model.reduced_mass(b));
        assert_eq!(peak_e, peak_mass, "arm {arm_mass} kg");
        if arm_mass == 0.0 {
            // A free racket: at its centre of gravity.
            assert!(peak_e.abs() <= (max - min) / 200.0);
        }
    }
}

#[test]
fn contact_lasts_about_a_millisecond_at_rally_speeds_and_shortens_with_speed() {
    let model = RacketModel::new(&seed_rubber());
    let mut last = f64::INFINITY;
    for speed in [3.0, 5.0, 10.0, 15.0, 20.0, 30.0] {
        let impact = model.normal_impact(speed, 0.0).expect("contact");
        let c = impact.contact;
        assert!(
            (0.5e-3..2.0e-3).contains(&c.contact_time),
            "T_c({speed}) = {}",
            c.contact_time
        );
        assert!(c.contact_time < last);
        last = c.contact_time;
        // The impulse is the ball's momentum change (Kawazoe & Suzuki eq. 8) and F_max = pi/2 F_mean.
        let change = 0.0027 * (1.0 + impact.rebound_power_coefficient) * speed;
        assert_relative_eq!(c.impulse, change, max_relative = 1e-9);
        assert_relative_eq!(
            c.peak_force,
            std::f64::consts::FRAC_PI_2 * c.mean_force,
            max_relative = 1e-12
        );
    }
    // The default characteristic is set to 1.0 ms at 10 m/s on the held racket's centre of
    // gravity (config/ttball.yaml).
    let tc = model
        .normal_impact(10.0, 0.0)
        .expect("contact")
        .contact
        .contact_time;
    assert!((tc - 1.0e-3).abs() < 5e-6, "{tc}");
}

#[test]
fn the_transcribed_eq1_is_refused_with_a_clear_message() {
    let mut config = seed_rubber();
    let kgf = 9.80665;
    let kgf_per_mm: f64 = 9806.65;
    config.racket.restoring_force_vs_stiffness = [-0.0999, 0.1098, 0.1433, -0.066]
        .iter()
        .enumerate()
        .map(|(i, c)| c * kgf / kgf_per_mm.powi(i as i32))
        .collect();
    let stroke = Stroke::new(&config);
    let err = stroke
        .rebound(&incoming(), &racket_at_rest(Vector3::x()))
        .expect_err("no contact");
    let text = err.to_string();
    assert!(text.contains("no contact solution"), "{text}");
    assert!(
        text.contains("racket.restoring_force_vs_stiffness"),
        "{text}"
    );
}

fn incoming() -> BallState {
    BallState::new(
        Vector3::new(-1.6, 0.1, 0.25),
        Vector3::new(-5.0, 0.4, -1.0),
        Vector3::new(20.0, -150.0, 30.0),
    )
}

fn racket_at_rest(normal: Vector3<f64>) -> RacketState {
    RacketState {
        velocity: Vector3::zeros(),
        normal,
        impact_offset: 0.05,
    }
}

fn tilted_stroke() -> RacketState {
    RacketState {
        velocity: Vector3::new(4.0, -0.5, 2.5),
        normal: Vector3::new(0.9, -0.1, 0.4).normalize(),
        impact_offset: 0.03,
    }
}

/// Normal momentum of ball and racket (reduced mass at the impact point) is conserved; the
/// tangential impulse is bounded by mu times the normal one; total energy does not grow.
#[test]
fn normal_momentum_is_conserved_and_energy_does_not_grow() {
    let config = seed_rubber();
    let model = RacketModel::new(&config);
    let m = config.ball.mass;
    for racket in [racket_at_rest(Vector3::x()), tilted_stroke()] {
        let ball = incoming();
        let hit = model.hit(&ball, &racket).expect("hit");
        let n = racket.normal;
        let mr = hit.normal.reduced_mass;
        let before = m * ball.velocity.dot(&n) + mr * racket.velocity.dot(&n);
        let after = m * hit.ball.velocity.dot(&n) + mr * hit.racket_velocity.dot(&n);
        assert_relative_eq!(before, after, max_relative = 1e-12);
        // Energy in the racket's frame before the impact.
        let energy = |b: &BallState, racket_velocity: Vector3<f64>| {
            let rel = BallState::new(b.position, b.velocity - racket.velocity, b.spin);
            rel.kinetic_energy(m, config.ball.radius)
                + 0.5 * mr * (racket_velocity - racket.velocity).norm_squared()
        };
        let e0 = energy(&ball, racket.velocity);
        let e1 = energy(&hit.ball, hit.racket_velocity);
        assert!(e1 < e0, "energy grew: {e0} -> {e1}");
        let normal_change = (hit.ball.velocity - ball.velocity).dot(&n);
        let tangential = (hit.ball.velocity - ball.velocity) - n * normal_change;
        assert!(tangential.norm() <= config.racket.rubber_friction * normal_change + 1e-12);
    }
}

/// With e_RB = 1, no friction and a rigid holder, the impact is perfectly elastic.
#[test]
fn an_elastic_frictionless_hit_keeps_the_energy() {
    let mut config = seed_rubber();
    config.racket.rubber_restitution = vec![1.0];
    config.racket.rubber_friction = 0.0;
    let model = RacketModel::new(&config);
    let m = config.ball.mass;
    let ball = incoming();
    let racket = tilted_stroke();
    let hit = model.hit(&ball, &racket).expect("hit");
    let mr = hit.normal.reduced_mass;
    let energy = |v: Vector3<f64>, vr: Vector3<f64>| {
        0.5 * m * v.norm_squared() + 0.5 * mr * vr.dot(&racket.normal).powi(2)
    };
    assert_relative_eq!(
        energy(ball.velocity, racket.velocity),
        energy(hit.ball.velocity, hit.racket_velocity),
        max_relative = 1e-12
    );
    assert_eq!(hit.ball.spin, ball.spin);
}

/// A racket at rest, face along +x: Kawazoe & Suzuki eq. (12) for the normal velocity, and a rolling
/// impact leaves no slip at the contact point.
#[test]
fn a_racket_at_rest_rebounds_as_eq12_and_rolling_leaves_no_slip() {
    let config = seed_rubber();
    let model = RacketModel::new(&config);
    let ball = BallState::new(
        Vector3::new(-1.6, 0.0, 0.2),
        Vector3::new(-8.0, 0.0, 0.0),
        Vector3::new(0.0, 0.0, 0.0),
    );
    let hit = model
        .hit(&ball, &racket_at_rest(Vector3::x()))
        .expect("hit");
    let (m, mr) = (config.ball.mass, hit.normal.reduced_mass);
    let e_rb = model.rubber_restitution(8.0);
    assert_relative_eq!(
        hit.ball.velocity.x,
        8.0 * (e_rb * mr - m) / (m + mr),
        max_relative = 1e-12
    );
    // A spinning ball grips the rubber and leaves rolling: contact-point velocity zero.
    let spinning = BallState::new(ball.position, ball.velocity, Vector3::new(0.0, -60.0, 40.0));
    let hit = model
        .hit(&spinning, &racket_at_rest(Vector3::x()))
        .expect("hit");
    assert_eq!(hit.regime, BounceRegime::Rolling);
    let n = Vector3::x();
    let v = hit.ball.velocity;
    let slip = v - n * v.dot(&n) - config.ball.radius * hit.ball.spin.cross(&n);
    assert!(slip.norm() < 1e-12, "slip {slip}");
}

/// Kawazoe et al. 2010: the grip force of eq. (14) and the grip's shock acceleration of eq. (42) are the
/// same physics: M_H A = |chi| F. A free racket loads nothing.
#[test]
fn wrist_force_and_grip_acceleration_agree() {
    let config = seed_rubber();
    for arm in [0.3, 1.0, 5.0] {
        let model = RacketModel::new(&config).with_arm_mass(arm);
        for offset in [-0.04, 0.0, 0.05, 0.1, 0.13] {
            let load = model.wrist_load(offset, 100.0);
            assert_relative_eq!(
                arm * load.peak_acceleration,
                load.peak_force,
                max_relative = 1e-9
            );
        }
    }
    let free = RacketModel::new(&config)
        .with_arm_mass(0.0)
        .wrist_load(0.1, 100.0);
    assert_eq!(free.peak_force, 0.0);
}

/// The plate's vibration (Kawazoe & Suzuki eq. 14-20): the energy left in the modes lowers the
/// restitution as eq. (19) says, and a mode far above 1 / T_c takes almost nothing.
#[test]
fn vibration_loss_follows_eq19() {
    let mut config = seed_rubber();
    let plain = RacketModel::new(&config)
        .normal_impact(20.0, 0.1)
        .expect("contact");
    assert_eq!(plain.vibration_energy, 0.0);
    config.racket.vibration_mode_frequencies = vec![400.0, 900.0];
    config.racket.vibration_mode_masses = vec![0.08, 0.05];
    let with_modes = RacketModel::new(&config)
        .normal_impact(20.0, 0.1)
        .expect("contact");
    let (m, mr, v) = (config.ball.mass, with_modes.reduced_mass, 20.0);
    let loss = 2.0 * with_modes.vibration_energy * (m + mr) / (m * mr * v * v);
    assert!(loss > 0.0);
    assert_relative_eq!(
        with_modes.restitution.powi(2),
        with_modes.rubber_restitution.powi(2) - loss,
        max_relative = 1e-12
    );
    assert!(with_modes.rebound_power_coefficient < plain.rebound_power_coefficient);
    config.racket.vibration_mode_frequencies = vec![50_000.0];
    config.racket.vibration_mode_masses = vec![0.05];
    let stiff = RacketModel::new(&config)
        .normal_impact(20.0, 0.1)
        .expect("contact");
    assert!(plain.rebound_power_coefficient - stiff.rebound_power_coefficient < 1e-4);
}

#[test]
fn bad_racket_states_are_refused_with_reasons() {
    let model = RacketModel::new(&seed_rubber());
    let ball = incoming();
    let cases = [
        (racket_at_rest(Vector3::new(2.0, 0.0, 0.0)), "unit vector"),
        (racket_at_rest(-Vector3::x()), "does not approach"),
        (
            RacketState {
                impact_offset: 0.3,
                ..racket_at_rest(Vector3::x())
            },
            "off the face",
        ),
        (
            RacketState {
                velocity: Vector3::new(f64::NAN, 0.0, 0.0),
                ..racket_at_rest(Vector3::x())
            },
            "non-finite",
        ),
    ];
    for (racket, words) in cases {
        let text = model.hit(&ball, &racket).expect_err(words).to_string();
        assert!(text.contains(words), "{text}");
    }
}

fn aim(target: (f64, f64), condition: ReturnCondition) -> Aim {
    Aim {
        target: Vector2::new(target.0, target.1),
        condition,
        impact_offset: 0.0,
        brush_speed: 0.0,
    }
}

/// The planner's command, fed to the forward model, lands within 1 mm of the target.
#[test]
fn the_planned_command_lands_on_the_target() {
    let stroke = Stroke::new(&seed_rubber());
    let balls = [
        incoming(),
        BallState::new(
            Vector3::new(-1.6, -0.3, 0.15),
            Vector3::new(-7.0, 0.8, 0.5),
            Vector3::new(0.0, 200.0, 0.0),
        ),
    ];
    let aims = [
        aim((0.9, 0.3), ReturnCondition::NetClearance(0.15)),
        aim((1.2, -0.5), ReturnCondition::NetClearance(0.3)),
        aim((0.6, 0.0), ReturnCondition::FlightTime(0.6)),
        Aim {
            brush_speed: 2.0,
            impact_offset: 0.06,
            ..aim((1.0, 0.5), ReturnCondition::NetClearance(0.1))
        },
    ];
    for ball in &balls {
        for a in &aims {
            let plan = stroke
                .plan(ball, a)
                .unwrap_or_else(|e| panic!("{a:?}: {e}"));
            // The command through the public forward model, as a controller would check it.
            let rebound = stroke.rebound(ball, &plan.racket).expect("rebound");
            assert_eq!(rebound.flight.outcome, ReturnOutcome::Lands, "{a:?}");
            let (t, landing) = rebound.flight.landing.expect("landing");
            let miss = (landing.position.xy() - a.target).norm();
            assert!(miss < 1e-3, "{a:?}: missed by {miss} m");
            match a.condition {
                ReturnCondition::NetClearance(c) => {
                    let (_, clearance) = rebound.flight.net.expect("net crossing");
                    assert!((clearance - c).abs() < 1e-3, "clearance {clearance}");
                }
                ReturnCondition::FlightTime(f) => assert!((t - f).abs() < 1e-3, "time {t}"),
            }
            assert!(plan.racket.velocity.norm() <= 8.0);
        }
    }
}

#[test]
fn unreachable_targets_are_reported() {
    let mut config = seed_rubber();
    config.stroke.max_racket_speed = 2.0;
    let stroke = Stroke::new(&config);
    let err = stroke
        .plan(
            &incoming(),
            &aim((1.2, 0.0), ReturnCondition::FlightTime(0.25)),
        )
        .expect_err("too fast");
    assert!(matches!(err, PlanError::TooFast { .. }), "{err}");
    assert!(err.to_string().contains("stroke.max_racket_speed"));
    let off = stroke
        .plan(
            &incoming(),
            &aim((-0.5, 0.0), ReturnCondition::NetClearance(0.1)),
        )
        .expect_err("own half");
    assert!(off.to_string().contains("opponent's half"), "{off}");
}

mod properties {
    use super::*;
    use proptest::prelude::*;
    use ttball::physics::racket::ImpactError;

    fn racket_state() -> impl Strategy<Value = RacketState> {
        (
            prop::array::uniform3(-3.0f64..8.0),
            (-0.8f64..0.8, -0.6f64..0.6),
            -0.04f64..0.13,
        )
            .prop_map(|(v, (yaw, pitch), offset)| RacketState {
                velocity: v.into(),
                normal: Vector3::new(
                    pitch.cos() * yaw.cos(),
                    pitch.cos() * yaw.sin(),
                    pitch.sin(),
                ),
                impact_offset: offset,
            })
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(2000))]

        /// Any hit of any incoming ball: finite, normal momentum conserved, energy not created,
        /// friction within mu, the contact point's slip reduced but never reversed, about a
        /// millisecond of contact at rally speeds; a ball that does not approach the face is refused.
        #[test]
        fn every_hit_obeys_the_impact_laws(
            v in (-15.0f64..-0.5, -3.0f64..3.0, -4.0f64..4.0),
            w in prop::array::uniform3(-700.0f64..700.0),
            racket in racket_state(),
        ) {
            let config = seed_rubber();
            let model = RacketModel::new(&config);
            let ball = BallState::new(Vector3::new(-1.6, 0.0, 0.3), Vector3::new(v.0, v.1, v.2), w.into());
            let n = racket.normal;
            let relative = ball.velocity - racket.velocity;
            match model.hit(&ball, &racket) {
                Err(ImpactError::NotApproaching { .. }) => prop_assert!(relative.dot(&n) >= 0.0),
                Err(e) => prop_assert!(false, "{e}"),
                Ok(hit) => {
                    prop_assert!(hit.ball.is_finite());
                    let (m, mr) = (config.ball.mass, hit.normal.reduced_mass);
                    let p0 = m * ball.velocity.dot(&n) + mr * racket.velocity.dot(&n);
                    let p1 = m * hit.ball.velocity.dot(&n) + mr * hit.racket_velocity.dot(&n);
                    prop_assert!((p0 - p1).abs() <= 1e-12 * p0.abs().max(1e-3));
                    let r = config.ball.radius;
                    let energy = |b: &BallState, vr: Vector3<f64>| {
                        BallState::new(b.position, b.velocity - racket.velocity, b.spin)
                            .kinetic_energy(m, r)
                            + 0.5 * mr * (vr - racket.velocity).norm_squared()
                    };
                    prop_assert!(energy(&hit.ball, hit.racket_velocity) <= energy(&ball, racket.velocity) * (1.0 + 1e-12));
                    let change = hit.ball.velocity - ball.velocity;
                    let normal_change = change.dot(&n);
                    prop_assert!(normal_change > 0.0);
                    prop_assert!((change - n * normal_change).norm() <= config.racket.rubber_friction * normal_change * (1.0 + 1e-9));
                    let slip = |v: Vector3<f64>, w: Vector3<f64>| {
                        let rel = v - racket.velocity;
                        rel - n * rel.dot(&n) - r * w.cross(&n)
                    };
                    let before = slip(ball.velocity, ball.spin);
                    let after = slip(hit.ball.velocity, hit.ball.spin);
                    prop_assert!(after.norm() <= before.norm() * (1.0 + 1e-9) + 1e-12);
                    prop_assert!(after.dot(&before) >= -1e-9);
                    // Hertz: T_c grows as V^-1/5 at gentle touches; about a millisecond above 1 m/s.
                    let tc = hit.normal.contact.contact_time;
                    prop_assert!(tc > 0.4e-3, "T_c {tc}");
                    if hit.normal.impact_speed >= 1.0 {
                        prop_assert!(tc < 1.6e-3, "T_c {tc}");
                    }
                }
            }
        }
    }

    /// Random incoming balls and reachable targets: every plan found lands within 1 mm, and
    /// nearly all are found.
    #[test]
    fn random_plans_land_on_their_targets() {
        let stroke = Stroke::new(&seed_rubber());
        let mut state = 0x2545_f491_4f6c_dd1du64;
        let mut uniform = |lo: f64, hi: f64| {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            lo + (hi - lo) * (state >> 11) as f64 / (1u64 << 53) as f64
        };
        let (mut found, total) = (0, 60);
        for _ in 0..total {
            let ball = BallState::new(
                Vector3::new(-1.6, uniform(-0.5, 0.5), uniform(0.1, 0.5)),
                Vector3::new(uniform(-8.0, -2.0), uniform(-1.0, 1.0), uniform(-1.5, 1.5)),
                Vector3::new(
                    uniform(-50.0, 50.0),
                    uniform(-300.0, 300.0),
                    uniform(-80.0, 80.0),
                ),
            );
            let condition = if uniform(0.0, 1.0) < 0.5 {
                ReturnCondition::NetClearance(uniform(0.05, 0.4))
            } else {
                ReturnCondition::FlightTime(uniform(0.4, 0.9))
            };
            let a = Aim {
                target: Vector2::new(uniform(0.3, 1.2), uniform(-0.6, 0.6)),
                condition,
                impact_offset: uniform(-0.04, 0.12),
                brush_speed: uniform(-1.0, 3.0),
            };
            match stroke.plan(&ball, &a) {
                Ok(plan) => {
                    found += 1;
                    let rebound = stroke.rebound(&ball, &plan.racket).expect("rebound");
                    let (_, landing) = rebound.flight.landing.expect("lands");
                    let miss = (landing.position.xy() - a.target).norm();
                    assert!(miss < 1e-3, "{a:?}: {miss}");
                    assert_eq!(rebound.flight.outcome, ReturnOutcome::Lands);
                }
                Err(e) => eprintln!("{a:?}: {e}"),
            }
        }
        assert!(
            found * 10 >= total * 9,
            "only {found} of {total} plans found"
        );
    }
}

/// The landing covariance of a planned return, to first order, matches a Monte Carlo over the
/// ball state's uncertainty at impact (2000 samples; standard deviations within 10 %).
#[test]
fn landing_covariance_matches_monte_carlo() {
    use ttball::physics::state::StateMatrix;
    let stroke = Stroke::new(&seed_rubber());
    let ball = incoming();
    let plan = stroke
        .plan(&ball, &aim((0.9, 0.2), ReturnCondition::NetClearance(0.2)))
        .expect("plan");
    let sigmas = [0.002, 0.002, 0.002, 0.05, 0.05, 0.05, 20.0, 20.0, 20.0];
    let covariance = StateMatrix::from_diagonal(&sigmas.map(|s| s * s).into());
    let linear = stroke
        .landing_covariance(&ball, &covariance, &plan.racket)
        .expect("covariance");
    let mut gaussian = gaussians(0x9e37_79b9_7f4a_7c15);
    let mut samples = Vec::new();
    while samples.len() < 2000 {
        let mut x = ball.to_vector();
        for (k, s) in sigmas.iter().enumerate() {
            x[k] += s * gaussian();
        }
        let rebound = stroke
            .rebound(&BallState::from_vector(&x), &plan.racket)
            .expect("rebound");
        if let Some((t, landing)) = rebound.flight.landing {
            samples.push([landing.position.x, landing.position.y, t]);
        }
    }
    assert_spread_matches(&samples, &linear);
}

/// Standard normal numbers from `seed` (xorshift64 and Box-Muller): deterministic.
fn gaussians(seed: u64) -> impl FnMut() -> f64 {
    let mut state = seed;
    move || {
        let mut uniform = || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            ((state >> 11) as f64 + 0.5) / (1u64 << 53) as f64
        };
        let (u1, u2) = (uniform(), uniform());
        (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
    }
}

/// The landings' sampled standard deviations (x, y, flight time) are the first-order
/// covariance's within 10 %.
fn assert_spread_matches(samples: &[[f64; 3]], linear: &nalgebra::Matrix3<f64>) {
    for k in 0..3 {
        let mean = samples.iter().map(|s| s[k]).sum::<f64>() / samples.len() as f64;
        let var =
            samples.iter().map(|s| (s[k] - mean).powi(2)).sum::<f64>() / (samples.len() - 1) as f64;
        let (sampled, predicted) = (var.sqrt(), linear[(k, k)].sqrt());
        eprintln!("landing component {k}: Monte Carlo sigma {sampled:.5}, linear {predicted:.5}");
        assert!(
            (sampled / predicted - 1.0).abs() < 0.1,
            "component {k}: Monte Carlo {sampled}, linear {predicted}"
        );
    }
}

/// With a calibrated rubber (the inverted offensive preset: its constants' covariance and the
/// scatter of single hits about the model), the landing covariance of a planned return includes
/// both, even for a ball known exactly, and matches a Monte Carlo over them (2000 samples of the
/// rubber's constants from their covariance and of the outgoing velocity and spin's scatter;
/// standard deviations within 10 %). The scatter of single hits dominates: 0.23 m/s and
/// 14 rad/s per component move the landing by 18 cm (x) and 10 cm (y) on this drive, the
/// constants' uncertainty by 4 mm. The scatter includes the recording's measurement noise, so
/// this is an upper bound.
#[test]
fn landing_covariance_includes_the_calibrated_rubbers_uncertainty() {
    use nalgebra::{DMatrix, DVector};
    use ttball::physics::state::StateMatrix;
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("config/presets/rubber_inverted_offensive.yaml");
    let config = ttball::config::yaml::load(Some(&path), &[] as &[String]).unwrap();
    let r = &config.racket;
    assert!(!r.rubber_covariance.is_empty() && r.rebound_scatter[0] > 0.0);
    let stroke = Stroke::new(&config);
    let ball = incoming();
    let plan = stroke
        .plan(&ball, &aim((0.9, 0.2), ReturnCondition::NetClearance(0.2)))
        .expect("plan");
    let linear = stroke
        .landing_covariance(&ball, &StateMatrix::zeros(), &plan.racket)
        .expect("covariance");
    // The constants alone, for scale.
    let mut exact_scatter = config.clone();
    exact_scatter.racket.rebound_scatter = vec![0.0, 0.0];
    let constants_only = Stroke::new(&exact_scatter)
        .landing_covariance(&ball, &StateMatrix::zeros(), &plan.racket)
        .expect("covariance");
    eprintln!(
        "landing sigma x, y [mm]: constants {:.1} {:.1}, all {:.1} {:.1}",
        constants_only[(0, 0)].sqrt() * 1e3,
        constants_only[(1, 1)].sqrt() * 1e3,
        linear[(0, 0)].sqrt() * 1e3,
        linear[(1, 1)].sqrt() * 1e3
    );
    assert!(constants_only[(0, 0)] > 0.0 && linear[(0, 0)] > 4.0 * constants_only[(0, 0)]);

    let theta = stroke.racket().rubber_parameters();
    let n = theta.len();
    let root = DMatrix::from_row_slice(n, n, &r.rubber_covariance)
        .cholesky()
        .expect("a positive definite covariance")
        .l();
    let mut gaussian = gaussians(0x2545_f491_4f6c_dd1d);
    let (sv, sw) = (r.rebound_scatter[0], r.rebound_scatter[1]);
    let mut samples = Vec::new();
    while samples.len() < 2000 {
        let z = DVector::from_fn(n, |_, _| gaussian());
        let sampled = DVector::from_vec(theta.clone()) + &root * z;
        let mut c = exact_scatter.clone();
        c.racket.rubber_restitution = sampled.as_slice()[..n - 3].to_vec();
        c.racket.rubber_friction = sampled[n - 3];
        c.racket.rubber_tangential_restitution = sampled[n - 2];
        c.racket.rubber_torsional_restitution = sampled[n - 1];
        let model = RacketModel::new(&c);
        let mut after = model.hit(&ball, &plan.racket).expect("hit").ball;
        after.velocity += Vector3::new(gaussian(), gaussian(), gaussian()) * sv;
        after.spin += Vector3::new(gaussian(), gaussian(), gaussian()) * sw;
        if let Some((t, landing)) = stroke.return_flight(&after).landing {
            samples.push([landing.position.x, landing.position.y, t]);
        }
    }
    assert_spread_matches(&samples, &linear);
}

/// The rubber's tangential restitution e_t (Garwin 1969, Cross 2002): where the rubber grips
/// the ball, the contact point leaves with -e_t times its incoming slip (0 rolls, as the seed's
/// model); the angular momentum about the contact point is conserved whatever e_t (the contact
/// force acts there); and the friction cap still holds a ball that slides.
#[test]
fn tangential_restitution_reverses_the_contact_point_where_the_rubber_grips() {
    let n = Vector3::x();
    let ball = BallState::new(
        Vector3::new(-1.6, 0.0, 0.2),
        Vector3::new(-8.0, 0.0, 1.5),
        Vector3::new(0.0, -60.0, 40.0),
    );
    let contact_slip =
        |b: &BallState, r: f64| b.velocity - n * b.velocity.dot(&n) - r * b.spin.cross(&n);
    for e_t in [0.0, 0.3, 0.7, -0.5] {
        let mut config = seed_rubber();
        config.racket.rubber_tangential_restitution = e_t;
        let r = config.ball.radius;
        let model = RacketModel::new(&config);
        let hit = model.hit(&ball, &racket_at_rest(n)).expect("hit");
        assert_eq!(hit.regime, BounceRegime::Rolling, "e_t {e_t}");
        let (before, after) = (contact_slip(&ball, r), contact_slip(&hit.ball, r));
        assert!(
            (after + e_t * before).norm() < 1e-12 * before.norm().max(1.0),
            "e_t {e_t}: slip {before} -> {after}"
        );
        // Angular momentum about the contact point (-r n from the centre), per unit mass: a
        // thin shell's spin term is 2/3 r^2 w.
        let about_contact =
            |b: &BallState| (-r * n).cross(&(-b.velocity)) + 2.0 / 3.0 * r * r * b.spin;
        let (l0, l1) = (about_contact(&ball), about_contact(&hit.ball));
        let tangential = |l: Vector3<f64>| l - n * l.dot(&n);
        assert!(
            (tangential(l1) - tangential(l0)).norm() < 1e-12,
            "e_t {e_t}: {l0} -> {l1}"
        );
    }
    // Little friction: the ball slides, the cap is the Coulomb impulse whatever e_t.
    let mut config = seed_rubber();
    config.racket.rubber_friction = 0.01;
    config.racket.rubber_tangential_restitution = 0.7;
    let sliding = RacketModel::new(&config)
        .hit(&ball, &racket_at_rest(n))
        .expect("hit");
    config.racket.rubber_tangential_restitution = 0.0;
    let seed = RacketModel::new(&config)
        .hit(&ball, &racket_at_rest(n))
        .expect("hit");
    assert_eq!(sliding.regime, BounceRegime::Sliding);
    assert_eq!(sliding.ball, seed.ball);
}

/// One recorded rebound of `tests/data/tt_rackets/` (racket frame, z the face normal): ball
/// velocity and spin before and after.
struct RealRebound {
    v_in: Vector3<f64>,
    w_in: Vector3<f64>,
    v_out: Vector3<f64>,
    w_out: Vector3<f64>,
}

/// The recorded rebounds on one racket (`racket_NN.csv`).
fn real_rebounds(racket: &str) -> Vec<RealRebound> {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data/tt_rackets/test")
        .join(format!("racket_{racket}.csv"));
    let text = std::fs::read_to_string(&path).unwrap();
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().unwrap().trim().split(',').collect();
    let column = |name: &str| header.iter().position(|h| *h == name).unwrap();
    let v3 = |row: &[f64], prefix: &str| {
        Vector3::new(
            row[column(&format!("{prefix}_x"))],
            row[column(&format!("{prefix}_y"))],
            row[column(&format!("{prefix}_z"))],
        )
    };
    lines
        .filter(|l| !l.trim().is_empty())
        .map(|l| {
            let row: Vec<f64> = l
                .trim()
                .split(',')
                .map(|x| x.parse().unwrap_or(0.0))
                .collect();
            RealRebound {
                v_in: v3(&row, "v_in"),
                w_in: v3(&row, "spin_before"),
                v_out: v3(&row, "v_out"),
                w_out: v3(&row, "spin_after"),
            }
        })
        .collect()
}

/// RMS errors [m/s, rad/s] of the model's outgoing velocity and spin over recorded rebounds on
/// a racket at rest.
fn rebound_rms(model: &RacketModel, rebounds: &[RealRebound]) -> (f64, f64) {
    let (mut v2, mut w2) = (0.0, 0.0);
    for r in rebounds {
        let ball = BallState::new(Vector3::zeros(), r.v_in, r.w_in);
        let hit = model
            .hit(&ball, &racket_at_rest(Vector3::z()))
            .expect("a recorded hit");
        v2 += (hit.ball.velocity - r.v_out).norm_squared();
        w2 += (hit.ball.spin - r.w_out).norm_squared();
    }
    let n = rebounds.len() as f64;
    ((v2 / n).sqrt(), (w2 / n).sqrt())
}

/// On the real rebounds of five inverted rubbers (tt_rackets), a tangential restitution of 0.7
/// (their median contact-point reversal) returns the spin they return: the outgoing spin's RMS
/// error falls to well under half the rolling model's on every racket, and the velocity's does
/// not grow; on the long pips (which slide) it does not help. Not a calibration: the first
/// step of issue 26, whose targets need the normal restitution fitted too.
#[test]
fn tangential_restitution_returns_the_spin_real_inverted_rubbers_return() {
    let rolling = seed_rubber();
    let mut elastic = seed_rubber();
    elastic.racket.rubber_tangential_restitution = 0.7;
    let (rolling, elastic) = (RacketModel::new(&rolling), RacketModel::new(&elastic));
    for racket in ["01", "02", "03", "04", "09", "05"] {
        let rebounds = real_rebounds(racket);
        assert!(rebounds.len() > 150, "racket {racket}");
        let (v0, w0) = rebound_rms(&rolling, &rebounds);
        let (v1, w1) = rebound_rms(&elastic, &rebounds);
        eprintln!(
            "racket {racket}: rolling {v0:.2} m/s, {w0:.0} rad/s; e_t 0.7 {v1:.2} m/s, {w1:.0} rad/s"
        );
        if racket == "05" {
            assert!(w1 >= w0, "long pips: {w0} -> {w1}");
        } else {
            assert!(w1 < 0.5 * w0, "racket {racket}: spin RMS {w0} -> {w1}");
            assert!(v1 <= v0, "racket {racket}: velocity RMS {v0} -> {v1}");
        }
    }
}

/// Seconds since the return's first detection, and the (landing [m], velocity [m/s]) errors of
/// the estimate after that detection, None before the return has a track.
type ReturnError = (f64, Option<(f64, f64)>);

/// A simulated return: the estimator's configuration (the inverted offensive preset), the
/// robot's hit as announced, the 150 fps camera's detections of the incoming ball up to the hit
/// and of the return after it (with the return's true state), and where the return lands.
struct ReturnScenario {
    config: Config,
    hit: ttball::online::estimator::RobotHit,
    incoming: Vec<ttball::model::detection::Detection>,
    back: Vec<(ttball::model::detection::Detection, BallState)>,
    landing: Vector3<f64>,
}

/// The ball flies to the robot, the robot hits it with the planned stroke of a rubber slightly
/// livelier than the configured preset (and a hit's own scatter), and the return flies to the
/// opponent's half.
fn return_scenario(seed: u64) -> ReturnScenario {
    use ttball::model::detection::{Detection, Source};
    use ttball::online::estimator::{Estimator, RobotHit};
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("config/presets/rubber_inverted_offensive.yaml");
    let config = ttball::config::yaml::load(Some(&path), &[] as &[String]).unwrap();
    let mut truth_config = config.clone();
    truth_config.racket.rubber_restitution[0] += 0.02;
    truth_config.racket.rubber_tangential_restitution += 0.03;
    let truth = Estimator::new(&seed_rubber());
    let mut gaussian = gaussians(seed);
    // The incoming ball just after its bounce on the robot's half, to the hitting plane.
    let start = BallState::new(
        Vector3::new(-0.7, 0.05 + 0.1 * gaussian(), 0.03),
        Vector3::new(-5.5 + 0.3 * gaussian(), 0.2 * gaussian(), 1.8),
        Vector3::new(0.0, -80.0 + 20.0 * gaussian(), 10.0 * gaussian()),
    );
    let incoming = truth.predict_flight(&start, 1e-4, 0.5);
    let at_plane = incoming
        .samples
        .iter()
        .find(|s| s.state.position.x < -1.45)
        .unwrap();
    let hit_stamp = (at_plane.t * 1e9).round() as i64;
    let stroke = Stroke::new(&config);
    let plan = stroke
        .plan(
            &at_plane.state,
            &aim((0.9, 0.2), ReturnCondition::NetClearance(0.2)),
        )
        .unwrap();
    let mut after = RacketModel::new(&truth_config)
        .hit(&at_plane.state, &plan.racket)
        .unwrap()
        .ball;
    after.velocity += Vector3::new(gaussian(), gaussian(), gaussian()) * 0.1;
    after.spin += Vector3::new(gaussian(), gaussian(), gaussian()) * 8.0;
    let back = truth.predict_flight(&after, 1e-4, 1.0);
    let landing = back.bounces().next().unwrap().before;
    let frame = 1e9 / 150.0;
    let detect = |stamp: i64, position: Vector3<f64>| Detection {
        stamp,
        source: Source::WIDE_150FPS,
        position,
        position_covariance: None,
        spin: None,
        spin_covariance: None,
        confidence: 1.0,
    };
    let mut k = 0;
    let mut scenario = ReturnScenario {
        config,
        hit: RobotHit {
            stamp: hit_stamp,
            racket: plan.racket,
        },
        incoming: Vec::new(),
        back: Vec::new(),
        landing: Vector3::new(landing[0], landing[1], landing[2]),
    };
    loop {
        let stamp = (f64::from(k) * frame).round() as i64;
        k += 1;
        if stamp > hit_stamp {
            break;
        }
        let s = incoming.samples
            [((stamp as f64 * 1e-5).round() as usize).min(incoming.samples.len() - 1)];
        let noise = Vector3::new(gaussian(), gaussian(), gaussian()) * 0.002;
        scenario
            .incoming
            .push(detect(stamp, s.state.position + noise));
    }
    loop {
        let stamp = (f64::from(k) * frame).round() as i64;
        k += 1;
        let index = ((stamp - hit_stamp) as f64 * 1e-5).round() as usize;
        let Some(s) = back.samples.get(index) else {
            break;
        };
        if s.state.position.z < 0.03 || s.state.position.x > landing[0] {
            break;
        }
        let noise = Vector3::new(gaussian(), gaussian(), gaussian()) * 0.002;
        scenario
            .back
            .push((detect(stamp, s.state.position + noise), s.state));
    }
    scenario
}

/// The estimator on a simulated return ([`return_scenario`]), the hit announced or not. Returns,
/// per detection of the return flight, (seconds since the first one, landing error [m], velocity
/// error [m/s]) of the estimate after it, or None before a track of the return exists; and the
/// estimator's counters.
fn simulated_return(
    announce: bool,
    seed: u64,
) -> (Vec<ReturnError>, ttball::online::estimator::Counters) {
    use ttball::online::estimator::Estimator;
    let scenario = return_scenario(seed);
    let mut estimator = Estimator::new(&scenario.config);
    if announce {
        estimator.expect_hit(scenario.hit);
    }
    let mut incoming_track = None;
    for d in &scenario.incoming {
        estimator.handle(d);
        incoming_track = estimator.estimate().map(|e| e.track_id);
    }
    let landing = scenario.landing;
    let first = scenario.back.first().map_or(0, |(d, _)| d.stamp);
    let mut out = Vec::new();
    for (d, truth) in &scenario.back {
        estimator.handle(d);
        let since = (d.stamp - first) as f64 * 1e-9;
        let error = estimator
            .estimate()
            .filter(|e| Some(e.track_id) != incoming_track && e.stamp == d.stamp)
            .and_then(|e| {
                let predicted = estimator.predict_flight(&e.state, 0.01, 1.0);
                let bounce = predicted.bounces().next()?.before;
                Some((
                    ((bounce[0] - landing[0]).powi(2) + (bounce[1] - landing[1]).powi(2)).sqrt(),
                    (e.state.velocity - truth.velocity).norm(),
                ))
            });
        out.push((since, error));
    }
    (out, estimator.counters())
}

/// The same through a bag and the node's code path (`ttball replay`): the robot's hit recorded
/// on `topics.robot_hits` as a `ttball_msgs/RobotHit` seeds the return's track at its first
/// detection; a hit whose face normal is not a unit vector is refused and counted.
#[test]
fn a_recorded_robot_hit_seeds_the_return_in_the_replay() {
    use ttball::bag::BagWriter;
    use ttball::bag::replay::{DETECTION_TYPE, ROBOT_HIT_TYPE};
    use ttball::ros::msgs::convert::detection_to_msg;
    use ttball::ros::msgs::geometry_msgs::Vector3 as RosVector3;
    use ttball::ros::msgs::ttball_msgs::msg::RobotHit as RobotHitMsg;
    let scenario = return_scenario(0x9e37_79b9);
    let dir = std::path::Path::new(env!("CARGO_TARGET_TMPDIR"))
        .join(format!("robot-hit-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let (input, output) = (dir.join("in.mcap"), dir.join("out.mcap"));
    let topics = scenario.config.resolved_topics();
    let ros = |v: &Vector3<f64>| RosVector3 {
        x: v.x,
        y: v.y,
        z: v.z,
    };
    let hit_msg = |normal: Vector3<f64>| RobotHitMsg {
        header: ttball::ros::msgs::std_msgs::Header {
            stamp: ttball::ros::msgs::builtin_interfaces::Time::from_nanos(scenario.hit.stamp),
            frame_id: "table".into(),
        },
        racket_velocity: ros(&scenario.hit.racket.velocity),
        racket_normal: ros(&normal),
        impact_offset: scenario.hit.racket.impact_offset,
    };
    let mut w = BagWriter::create(&input).unwrap();
    let detections = w.channel(&topics.detections, DETECTION_TYPE).unwrap();
    let hits = w.channel(&topics.robot_hits, ROBOT_HIT_TYPE).unwrap();
    let log = |stamp: i64| u64::try_from(stamp + 1_000_000_000).unwrap();
    // A bad announcement first (refused), then the plan's, a frame before the hit.
    w.write(
        hits,
        ROBOT_HIT_TYPE,
        log(0),
        &hit_msg(scenario.hit.racket.normal * 2.0),
    )
    .unwrap();
    let write_detection = |w: &mut BagWriter<_>, d: &ttball::model::detection::Detection| {
        w.write(
            detections,
            DETECTION_TYPE,
            log(d.stamp),
            &detection_to_msg(d),
        )
        .unwrap();
    };
    for d in &scenario.incoming {
        write_detection(&mut w, d);
    }
    w.write(
        hits,
        ROBOT_HIT_TYPE,
        log(scenario.hit.stamp),
        &hit_msg(scenario.hit.racket.normal),
    )
    .unwrap();
    for (d, _) in &scenario.back {
        write_detection(&mut w, d);
    }
    w.finish().unwrap();
    let cancel = std::sync::atomic::AtomicBool::new(false);
    let summary =
        ttball::bag::replay::replay(&input, &output, &scenario.config, &mut |_, _| {}, &cancel)
            .unwrap();
    assert_eq!(summary.robot_hits_refused, 1);
    assert_eq!(summary.counters.seeded_by_hit, 1);
    assert_eq!(summary.counters.hits_not_seeded, 0);
    assert_eq!(summary.counters.tracks, 2, "{:?}", summary.counters);
    std::fs::remove_dir_all(&dir).unwrap();
}

/// The return's track after an announced robot hit ([`Estimator::expect_hit`]) starts at its
/// first detection, from the predicted rebound with the preset rubber's uncertainty, and has
/// converged 20 ms later (three 150 fps frames): over 20 simulated returns (a truth rubber 0.02
/// livelier and 0.03 more elastic than the preset, 0.1 m/s and 8 rad/s per component of scatter
/// per hit), the velocity error is at most 0.16 m/s (median 0.10; asserted 0.25 and 0.15) and
/// the landing on the opponent's half is predicted to a median 59 mm (51 mm at 50 ms, 45 mm at
/// 100 ms). Unannounced, the initialiser needs five detections (27 ms) and predicts the landing
/// to 222 mm at 50 ms and 153 mm at 100 ms. The numbers are printed.
#[test]
fn the_return_after_an_announced_hit_is_tracked_from_its_first_detection() {
    let at = |errors: &[ReturnError], t: f64| {
        errors
            .iter()
            .find(|(since, _)| *since >= t - 1e-4)
            .and_then(|(_, e)| *e)
    };
    let median = |v: &mut Vec<f64>| {
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    let mut table = Vec::new();
    for announce in [true, false] {
        let mut first_estimate = Vec::new();
        let (mut landing, mut velocity) = (vec![Vec::new(); 4], vec![Vec::new(); 4]);
        for seed in 0..20u64 {
            let (errors, counters) = simulated_return(announce, 0x9e37_79b9 + seed);
            assert_eq!(counters.seeded_by_hit, u64::from(announce), "seed {seed}");
            let first = errors.iter().position(|(_, e)| e.is_some()).unwrap();
            first_estimate.push(errors[first].0);
            for (k, t) in [0.0, 0.02, 0.05, 0.1].into_iter().enumerate() {
                if let Some((l, v)) = at(&errors, t) {
                    landing[k].push(l);
                    velocity[k].push(v);
                }
            }
        }
        let row: Vec<String> = (0..4)
            .map(|k| {
                if landing[k].is_empty() {
                    "-".to_owned()
                } else {
                    let worst = velocity[k].iter().copied().fold(0.0, f64::max);
                    format!(
                        "{:.0} mm, {:.2} m/s (max {:.2})",
                        median(&mut landing[k]) * 1e3,
                        median(&mut velocity[k]),
                        worst
                    )
                }
            })
            .collect();
        eprintln!(
            "announced {announce}: first estimate after {:.0} ms; median landing error, velocity error at 0 / 20 / 50 / 100 ms: {}",
            median(&mut first_estimate) * 1e3,
            row.join(" | ")
        );
        table.push((first_estimate, landing, velocity));
    }
    let (first, landing, velocity) = &table[0];
    assert!(first.iter().all(|t| *t == 0.0), "{first:?}");
    assert!(velocity[1].iter().all(|v| *v <= 0.25), "{:?}", velocity[1]);
    assert!(
        velocity[1][velocity[1].len() / 2] <= 0.15,
        "{:?}",
        velocity[1]
    );
    let unannounced = &table[1];
    assert!(
        unannounced.0.iter().all(|t| *t > 0.02),
        "{:?}",
        unannounced.0
    );
    // At 50 ms the announced track predicts the landing better than the unannounced one.
    assert!(landing[2][landing[2].len() / 2] < unannounced.1[2][unannounced.1[2].len() / 2]);
}

/// A stray detection just after the announced hit does not cost the seed: the predicted rebound
/// waits for the detection it explains (within `tracking.timeout` of the impact); an announced
/// hit whose return never shows is counted as having seeded nothing.
#[test]
fn an_announced_hit_waits_past_a_stray_detection_and_times_out_without_a_return() {
    use ttball::online::estimator::Estimator;
    let scenario = return_scenario(0x9e37_79b9 + 3);
    let run = |stray: bool, back: bool| {
        let mut estimator = Estimator::new(&scenario.config);
        estimator.expect_hit(scenario.hit);
        for d in &scenario.incoming {
            estimator.handle(d);
        }
        if stray {
            let mut d = scenario.back[0].0;
            d.stamp = scenario.hit.stamp + 1_000_000;
            d.position = Vector3::new(0.5, -0.6, 0.9);
            estimator.handle(&d);
        }
        let returns: &[_] = if back { &scenario.back } else { &[] };
        for (d, _) in returns {
            estimator.handle(d);
        }
        // Detections of the next ball, long after the hit (two: a lone jump in time is held
        // until the next confirms it).
        for (k, d) in scenario.incoming[..2].iter().enumerate() {
            let mut late = *d;
            late.stamp = scenario.hit.stamp + 2_000_000_000 + k as i64 * 6_666_667;
            estimator.handle(&late);
        }
        estimator.counters()
    };
    let counters = run(true, true);
    assert_eq!((counters.seeded_by_hit, counters.hits_not_seeded), (1, 0));
    let counters = run(false, false);
    assert_eq!((counters.seeded_by_hit, counters.hits_not_seeded), (0, 1));
}
