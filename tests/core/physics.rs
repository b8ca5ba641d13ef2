//! Physics core against the values docs/models.md lists and against invariants: Jacobians vs central finite
//! differences (relative 1e-6), exact event times, energy and slip at a bounce, RK4 order,
//! spin effects on a flight, determinism.

use nalgebra::{SMatrix, Vector3};
use ttball::config::Config;
use ttball::eval::sim::Rng;
use ttball::physics::{
    BallState, BounceRegime, Cursor, EventKind, FlightModel, Flow, Observer, Outcome, PARAMS,
    ParamMatrix, PhysicsParams, PredictOptions, Propagator, StateMatrix, StateRow, StateVector,
    TableBounce, TrajectoryEnd, Watch, predict, propagate::Event,
};

/// A random vector with a magnitude uniform in [lo, hi] and a uniform direction.
fn random_vector(rng: &mut Rng, lo: f64, hi: f64) -> Vector3<f64> {
    rng.unit_vector() * rng.uniform_in(lo, hi)
}

/// Central finite-difference Jacobian of `f` at `x`, with a step relative to each component.
fn finite_difference<const R: usize>(
    x: &StateVector,
    f: impl Fn(&StateVector) -> SMatrix<f64, R, 1>,
) -> SMatrix<f64, R, 9> {
    let mut jac = SMatrix::<f64, R, 9>::zeros();
    for j in 0..9 {
        let h = 1e-6 * x[j].abs().max(1.0);
        let mut plus = *x;
        let mut minus = *x;
        plus[j] += h;
        minus[j] -= h;
        jac.set_column(j, &((f(&plus) - f(&minus)) / (2.0 * h)));
    }
    jac
}

/// Largest column-wise relative error of `analytic` against `numeric`; a column's scale is its
/// own norm, floored at 1e-3 of the whole matrix so all-zero columns compare absolutely.
fn relative_error<const R: usize>(
    analytic: &SMatrix<f64, R, 9>,
    numeric: &SMatrix<f64, R, 9>,
) -> f64 {
    let floor = 1e-3 * numeric.norm().max(1e-12);
    (0..9)
        .map(|j| {
            (analytic.column(j) - numeric.column(j)).norm() / numeric.column(j).norm().max(floor)
        })
        .fold(0.0, f64::max)
}

fn state(p: [f64; 3], v: [f64; 3], w: [f64; 3]) -> BallState {
    BallState::new(p.into(), v.into(), w.into())
}

/// A config whose air exerts no force: flights are parabolas known in closed form.
fn vacuum() -> Config {
    let mut config = Config::default();
    config.aero.drag_coefficients = vec![0.0];
    config.aero.magnus_coefficients = vec![0.0];
    config
}

/// The coefficients' dependence on the Reynolds number, drag's too (a_D = 0.3 here), from below
/// Re_0 to beyond Re_max (1.5 to 45 m/s): the Jacobian matches the field; the factor f(Re)^a is
/// 1 well below Re_0, (Re / Re_0)^a well inside and (Re_max / Re_0)^a well beyond Re_max.
#[test]
fn flight_jacobian_with_the_reynolds_number_matches_finite_differences() {
    let mut config = Config::default();
    config.aero.reynolds_exponents = vec![0.3, -0.65];
    let model = FlightModel::new(&config);
    let [low, high] = [config.aero.reynolds_range[0], config.aero.reynolds_range[1]];
    let mut rng = Rng::new(13);
    let (mut checked, mut inside, mut beyond) = (0, 0, 0);
    while checked < 300 {
        let v = random_vector(&mut rng, 1.5, 45.0);
        let w = random_vector(&mut rng, 0.0, 900.0);
        let sp = model.spin_parameter(&v, &w);
        if (sp - 2.0).abs() < 1e-2 || sp < 1e-2 {
            continue;
        }
        let x = state([0.0, 0.0, 0.3], v.into(), w.into()).to_vector();
        let err = relative_error(
            &model.jacobian(&x).to_matrix(),
            &finite_difference(&x, |x| model.derivative(x)),
        );
        assert!(err < 1e-6, "relative error {err:e} at Sp = {sp}, x = {x}");
        let re = model.reynolds_number(v.norm());
        checked += 1;
        inside += usize::from(re > low && re < high);
        beyond += usize::from(re > high);
    }
    assert!(
        inside > 100 && beyond > 30,
        "{inside} inside, {beyond} beyond"
    );
    let at = |re: f64| model.reynolds_factors(re / model.reynolds_number(1.0));
    let (d, m, slope) = at(0.05 * low);
    assert!((d - 1.0).abs() < 1e-5 && (m - 1.0).abs() < 1e-5 && slope < 1e-5);
    let middle = (low * high).sqrt();
    let (d, m, slope) = at(middle);
    let ratio: f64 = middle / low;
    approx::assert_relative_eq!(d, ratio.powf(0.3), max_relative = 2e-3);
    approx::assert_relative_eq!(m, ratio.powf(-0.65), max_relative = 2e-3);
    assert!((0.9..=1.0).contains(&slope), "{slope}");
    approx::assert_relative_eq!(
        at(20.0 * high).1,
        (high / low).powf(-0.65),
        max_relative = 1e-5
    );
    // A force: C_M(Re, Sp) = P_M(Sp) f(Re)^a_M.
    let (v, w) = (
        Vector3::new(-20.0, 0.0, 0.0),
        Vector3::new(0.0, -400.0, 0.0),
    );
    let forces = model.forces(&v, &w);
    let expected = model.magnus_coefficient(forces.spin_parameter) * model.reynolds_factors(20.0).1;
    approx::assert_relative_eq!(forces.magnus_coefficient, expected, epsilon = 1e-12);
}

/// The default ball flies the levels docs/models.md ("Reynolds number") derives its defaults
/// from: the Magnus force 0.63 of the polynomial at 6 m/s (the slow real flights) and about half
/// at 9 m/s (real elite play); the drag 0.97 / 0.95 / 0.88 / 0.72 of the polynomial at 5 / 6 / 9
/// / 18 m/s, C_D 0.44 at 9 m/s and Sp 0.55 (real elite play's best constant: 0.43).
#[test]
fn the_default_ball_flies_the_documented_levels_at_every_speed() {
    let config = Config::default();
    let model = FlightModel::new(&config);
    let k_m = config.aero.magnus_scale;
    for (speed, magnus, drag) in [
        (5.0, None, 0.97),
        (6.0, Some(0.63), 0.95),
        (9.0, Some(0.52), 0.88),
        (18.0, Some(0.35), 0.72),
        (28.0, Some(0.27), 0.65),
    ] {
        let (d, m, _) = model.reynolds_factors(speed);
        assert!((d - drag).abs() < 0.006, "drag factor {d} at {speed} m/s");
        if let Some(magnus) = magnus {
            assert!(
                (k_m * m - magnus).abs() < 0.006,
                "Magnus {} at {speed} m/s",
                k_m * m
            );
        }
    }
    // A 9 m/s ball at Sp 0.55 (r w / v: 0.02 * 247.5 / 9).
    let forces = model.forces(
        &Vector3::new(-9.0, 0.0, 0.0),
        &Vector3::new(0.0, -247.5, 0.0),
    );
    approx::assert_relative_eq!(forces.spin_parameter, 0.55, epsilon = 1e-9);
    assert!(
        (forces.drag_coefficient * config.aero.drag_scale - 0.44).abs() < 0.005,
        "{forces:?}"
    );
}

#[test]
fn flight_jacobian_matches_finite_differences_including_high_spin_parameter() {
    let model = FlightModel::new(&Config::default());
    let mut rng = Rng::new(7);
    let (mut checked, mut clamped, mut high) = (0, 0, 0);
    while checked < 400 {
        let v = random_vector(&mut rng, 0.5, 15.0);
        let w = random_vector(&mut rng, 0.0, 700.0);
        let sp = model.spin_parameter(&v, &w);
        // Skip the kinks: the clamp at Sp_max and Sp = 0.
        if (sp - 2.0).abs() < 1e-2 || sp < 1e-3 {
            continue;
        }
        let x = state(random_vector(&mut rng, 0.0, 2.0).into(), v.into(), w.into()).to_vector();
        let analytic = model.jacobian(&x).to_matrix();
        let numeric = finite_difference(&x, |x| model.derivative(x));
        let err = relative_error(&analytic, &numeric);
        assert!(err < 1e-6, "relative error {err:e} at Sp = {sp}, x = {x}");
        checked += 1;
        clamped += usize::from(sp > 2.0);
        high += usize::from(sp > 1.0 && sp < 2.0);
    }
    assert!(
        clamped > 50 && high > 30,
        "coverage: {clamped} clamped, {high} with 1 < Sp < 2"
    );
}

/// With the spin known only to a variance across the flight (the filter's prediction), the
/// coefficients are evaluated at the spin parameter of sqrt(|w_perp|^2 + variance): the Jacobian
/// still matches the field, spins near zero included, and a spin of zero sees the drag of its
/// spread (more than the plain model's), while a large one barely notices it.
#[test]
fn flight_jacobian_with_a_spin_variance_matches_finite_differences() {
    let plain = FlightModel::new(&Config::default());
    let model = plain.with_spin_variance(80.0 * 80.0);
    let mut rng = Rng::new(11);
    let mut checked = 0;
    while checked < 300 {
        let v = random_vector(&mut rng, 0.5, 15.0);
        let w = random_vector(&mut rng, 0.0, if checked % 3 == 0 { 20.0 } else { 500.0 });
        let sp = model.spin_parameter(&v, &w);
        if (sp - 2.0).abs() < 1e-2 || v.cross(&w).norm() < 1e-3 {
            continue;
        }
        let x = state(random_vector(&mut rng, 0.0, 2.0).into(), v.into(), w.into()).to_vector();
        let err = relative_error(
            &model.jacobian(&x).to_matrix(),
            &finite_difference(&x, |x| model.derivative(x)),
        );
        assert!(err < 1e-6, "relative error {err:e} at Sp = {sp}, x = {x}");
        checked += 1;
    }
    let at_rest = state([0.0, 0.0, 0.3], [-5.0, 0.0, 0.0], [0.0, 0.0, 0.0]).to_vector();
    let (d_plain, d_spread) = (plain.derivative(&at_rest), model.derivative(&at_rest));
    // Moving toward -x, the drag pushes toward +x.
    assert!(
        d_spread[3] > d_plain[3],
        "more drag: {} vs {}",
        d_spread[3],
        d_plain[3]
    );
    assert_eq!(d_spread[4], 0.0, "no Magnus force without a spin");
    let fast = state([0.0, 0.0, 0.3], [-5.0, 0.0, 0.0], [0.0, 2000.0, 0.0]).to_vector();
    let relative =
        (model.derivative(&fast) - plain.derivative(&fast)).norm() / plain.derivative(&fast).norm();
    assert!(relative < 0.01, "{relative}");
}

#[test]
fn flight_jacobian_with_spin_decay_matches_finite_differences() {
    let mut config = Config::default();
    config.aero.spin_decay_rate = 0.7;
    let model = FlightModel::new(&config);
    let x = state([0.0, 0.0, 0.3], [-7.0, 0.5, 1.2], [10.0, -200.0, 40.0]).to_vector();
    let err = relative_error(
        &model.jacobian(&x).to_matrix(),
        &finite_difference(&x, |x| model.derivative(x)),
    );
    assert!(err < 1e-6, "relative error {err:e}");
    assert_eq!(model.derivative(&x)[7], 0.7 * 200.0);
}

#[test]
fn bounce_jacobian_matches_finite_differences_sliding_and_rolling() {
    let config = Config::default();
    let bounce = TableBounce::new(&config);
    let mut rng = Rng::new(11);
    let (mut sliding, mut rolling) = (0, 0);
    while sliding + rolling < 400 {
        let v = Vector3::new(
            rng.uniform_in(-9.0, 9.0),
            rng.uniform_in(-3.0, 3.0),
            rng.uniform_in(-8.0, -0.5),
        );
        let w = random_vector(&mut rng, 0.0, 500.0);
        let x = state(
            [rng.uniform_in(-1.3, 1.3), rng.uniform_in(-0.7, 0.7), 0.02],
            v.into(),
            w.into(),
        )
        .to_vector();
        let u = bounce.slip(&x);
        let alpha = config.table.friction * (1.0 + config.table.restitution) * v.z.abs() / u.norm();
        if (alpha - 0.4).abs() < 1e-3 {
            continue;
        }
        let b = bounce.apply(&x);
        let numeric = finite_difference(&x, |x| bounce.apply(x).state);
        let err = relative_error(&b.jacobian, &numeric);
        assert!(err < 1e-6, "relative error {err:e} ({:?}) at {x}", b.regime);
        match b.regime {
            BounceRegime::Sliding => sliding += 1,
            BounceRegime::Rolling => rolling += 1,
        }
    }
    assert!(
        sliding > 50 && rolling > 50,
        "coverage: {sliding} sliding, {rolling} rolling"
    );
}

#[test]
fn bounce_never_adds_energy_and_rolling_leaves_no_slip() {
    let config = Config::default();
    let bounce = TableBounce::new(&config);
    let (m, r) = (config.ball.mass, config.ball.radius);
    let mut rng = Rng::new(13);
    let mut rolled = 0;
    for _ in 0..2000 {
        let v = Vector3::new(
            rng.uniform_in(-12.0, 12.0),
            rng.uniform_in(-4.0, 4.0),
            rng.uniform_in(-9.0, -0.1),
        );
        let before = state(
            [0.0, 0.0, r],
            v.into(),
            random_vector(&mut rng, 0.0, 800.0).into(),
        );
        let b = bounce.apply(&before.to_vector());
        let after = BallState::from_vector(&b.state);
        let (e0, e1) = (before.kinetic_energy(m, r), after.kinetic_energy(m, r));
        assert!(
            e1 <= e0 * (1.0 + 1e-12),
            "energy rose from {e0} to {e1} ({:?})",
            b.regime
        );
        if b.regime == BounceRegime::Rolling {
            assert!(bounce.slip(&b.state).norm() < 1e-9 * (1.0 + v.norm()));
            rolled += 1;
        }
        // Sliding never reverses the slip: friction only brakes it.
        if b.regime == BounceRegime::Sliding {
            assert!(bounce.slip(&b.state).dot(&bounce.slip(&before.to_vector())) > 0.0);
        }
    }
    assert!(rolled > 100);
}

/// The end of a propagation and the events on the way.
type Run = (Cursor, Vec<Event>);

/// Final state of a propagation of `x` over `duration`, and the events on the way.
fn run(propagator: &Propagator, x: &StateVector, duration: f64, watch: Watch) -> Run {
    struct Keep(Vec<Event>);
    impl Observer for Keep {
        fn on_event(&mut self, event: &Event) -> ttball::physics::Flow {
            self.0.push(*event);
            ttball::physics::Flow::Continue
        }
    }
    let mut cursor = Cursor::with_jacobian(0.0, &BallState::from_vector(x));
    let mut keep = Keep(Vec::new());
    let outcome = propagator.advance(&mut cursor, duration, watch, &mut keep);
    assert_eq!(outcome, Outcome::Reached);
    (cursor, keep.0)
}

/// The state-transition matrix through flights with sliding and rolling bounces (including the
/// sensitivity of the contact time) and through a plane crossing, against finite differences of
/// the propagation itself.
#[test]
fn propagation_jacobian_matches_finite_differences_through_bounces() {
    let config = Config::default();
    let propagator = Propagator::new(&config);
    let watch = Watch {
        plane_x: Some(-1.6),
        ..Watch::FLIGHT
    };
    let shots = [
        // Flat drive over the net: slides through the bounce, crosses the hitting plane.
        state([1.3, 0.0, 0.30], [-4.5, 0.0, 1.6], [0.0, 0.0, 0.0]),
        // Backspin with sidespin: slides through two bounces.
        state([1.2, -0.2, 0.25], [-4.0, 0.3, 1.5], [0.0, 120.0, -30.0]),
        // Slow, steep ball with topspin: rolls out of two bounces.
        state([-0.2, 0.0, 0.45], [-1.0, 0.1, -1.0], [0.0, -60.0, 0.0]),
        // High spin parameter (Sp about 1.2): rolls, crosses the hitting plane.
        state([-0.1, 0.0, 0.35], [-3.0, 0.0, 1.0], [0.0, -200.0, 30.0]),
    ];
    let mut regimes = Vec::new();
    for shot in shots {
        let x0 = shot.to_vector();
        let (end, events) = run(&propagator, &x0, 0.9, watch);
        regimes.extend(events.iter().filter_map(|e| match e.kind {
            EventKind::TableBounce { regime } => Some(regime),
            _ => None,
        }));
        // One pair of perturbed runs per component serves every finite-difference Jacobian.
        let perturbed: Vec<_> = (0..9)
            .map(|j| {
                let h = 1e-6 * x0[j].abs().max(1.0);
                let (mut plus, mut minus) = (x0, x0);
                plus[j] += h;
                minus[j] -= h;
                (
                    h,
                    run(&propagator, &plus, 0.9, watch),
                    run(&propagator, &minus, 0.9, watch),
                )
            })
            .collect();
        let numeric = |value: &dyn Fn(&Run) -> StateVector| {
            StateMatrix::from_fn(|i, j| {
                let (h, plus, minus) = &perturbed[j];
                (value(plus)[i] - value(minus)[i]) / (2.0 * h)
            })
        };
        let transition = end.tangent.expect("tangent").transition();
        let err = relative_error(&transition, &numeric(&|r| r.0.state));
        assert!(err < 1e-6, "relative error {err:e} for {shot:?}");

        // Each event's time gradient and state sensitivity.
        assert!(!events.is_empty());
        for (i, event) in events.iter().enumerate() {
            let s = event.sensitivity.expect("sensitivity");
            let times = numeric(&|r| StateVector::from_element(r.1[i].t));
            let err_t = relative_error(&s.time_gradient, &times.fixed_rows::<1>(0).into_owned());
            assert!(
                err_t < 1e-6,
                "event {i} time gradient error {err_t:e} for {shot:?}"
            );
            let err_after = relative_error(&s.after, &numeric(&|r| r.1[i].after));
            assert!(
                err_after < 1e-6,
                "event {i} state error {err_after:e} for {shot:?}"
            );
        }
    }
    assert!(regimes.contains(&BounceRegime::Sliding) && regimes.contains(&BounceRegime::Rolling));
}

/// The state's sensitivity to the physical parameters (drag and Magnus scales, the table's
/// restitution and friction) through flights with sliding and rolling bounces and a plane
/// crossing, and each event's time and state sensitivity, against central finite differences of
/// propagations with perturbed parameters; the state transition is unchanged by tracking them.
#[test]
fn parameter_sensitivities_match_finite_differences_through_bounces() {
    let propagator = Propagator::new(&Config::default());
    let base = PhysicsParams {
        drag_scale: 0.9,
        magnus_scale: 0.7,
        restitution: 0.92,
        friction: 0.22,
    };
    let watch = Watch {
        plane_x: Some(-1.6),
        ..Watch::BOUNCES
    };
    let shots = [
        state([1.3, 0.0, 0.30], [-4.5, 0.0, 1.6], [0.0, 0.0, 0.0]),
        state([1.2, -0.2, 0.25], [-4.0, 0.3, 1.5], [0.0, 120.0, -30.0]),
        state([-0.2, 0.0, 0.45], [-1.0, 0.1, -1.0], [0.0, -60.0, 0.0]),
        state([1.1, 0.1, 0.3], [-7.0, -0.4, 0.8], [20.0, -250.0, 10.0]),
    ];
    let propagate = |params: &PhysicsParams, x: &StateVector, tracked: bool| {
        struct Keep(Vec<Event>);
        impl Observer for Keep {
            fn on_event(&mut self, event: &Event) -> Flow {
                self.0.push(*event);
                Flow::Continue
            }
        }
        let p = propagator.with_params(params);
        let mut cursor = if tracked {
            Cursor::tracking_params(0.0, *x)
        } else {
            Cursor::tracking(0.0, *x)
        };
        let mut keep = Keep(Vec::new());
        assert_eq!(
            p.advance(&mut cursor, 0.9, watch, &mut keep),
            Outcome::Reached
        );
        (cursor, keep.0)
    };
    let mut regimes = Vec::new();
    for shot in shots {
        let x0 = shot.to_vector();
        let (end, events) = propagate(&base, &x0, true);
        let (plain, _) = propagate(&base, &x0, false);
        assert_eq!(end.state, plain.state);
        let tangent = end.tangent.expect("tangent");
        assert_eq!(
            tangent.transition(),
            plain.tangent.expect("tangent").transition()
        );
        regimes.extend(events.iter().filter_map(|e| match e.kind {
            EventKind::TableBounce { regime } => Some(regime),
            _ => None,
        }));
        let theta = base.to_vector();
        let perturbed: Vec<_> = (0..PARAMS)
            .map(|j| {
                let h = 1e-6;
                let (mut plus, mut minus) = (theta, theta);
                plus[j] += h;
                minus[j] -= h;
                let run = |t| propagate(&PhysicsParams::from_vector(&t), &x0, false);
                (h, run(plus), run(minus))
            })
            .collect();
        let numeric = |value: &dyn Fn(&Run) -> StateVector| {
            ParamMatrix::from_fn(|i, j| {
                let (h, plus, minus) = &perturbed[j];
                (value(plus)[i] - value(minus)[i]) / (2.0 * h)
            })
        };
        let check = |analytic: &ParamMatrix, numeric: &ParamMatrix, what: &str| {
            let scale = numeric.norm().max(1e-9);
            let err = (analytic - numeric).norm() / scale;
            assert!(err < 1e-5, "{what}: relative error {err:e} for {shot:?}");
        };
        check(
            &tangent.params().expect("params"),
            &numeric(&|r| r.0.state),
            "end state",
        );
        for (i, event) in events.iter().enumerate() {
            let s = event
                .sensitivity
                .and_then(|s| s.params)
                .expect("parameter sensitivity");
            check(&s.after, &numeric(&|r| r.1[i].after), "event state");
            let times = numeric(&|r| StateVector::from_element(r.1[i].t));
            let err_t = (s.time_gradient - times.fixed_rows::<1>(0)).norm()
                / times.fixed_rows::<1>(0).norm().max(1e-9);
            assert!(
                err_t < 1e-5,
                "event {i} time gradient {err_t:e} for {shot:?}"
            );
        }
    }
    assert!(regimes.contains(&BounceRegime::Sliding) && regimes.contains(&BounceRegime::Rolling));
}

/// The covariance carried by a propagation (block-structured before any event) equals
/// transition * P * transition' computed in full, in flight and after a bounce.
#[test]
fn carried_covariance_equals_the_full_product() {
    let propagator = Propagator::new(&Config::default());
    let x0 = state([1.2, -0.2, 0.25], [-4.0, 0.3, 1.5], [0.0, 120.0, -30.0]).to_vector();
    let a = StateMatrix::from_fn(|i, j| ((9 * i + j) as f64 * 0.61).sin());
    let p = a * a.transpose() + StateMatrix::identity();
    for (duration, bounces) in [(0.05, 0), (0.5, 1)] {
        let (end, events) = run(&propagator, &x0, duration, Watch::BOUNCES);
        assert_eq!(events.len(), bounces);
        let tangent = end.tangent.expect("tangent");
        let transition = tangent.transition();
        let full = transition * p * transition.transpose();
        let carried = tangent.carry_covariance(&p);
        assert!(
            (carried - full).norm() <= 1e-12 * full.norm(),
            "after {duration} s"
        );
    }
}

#[test]
fn contact_and_plane_times_are_exact_not_rounded_to_the_step() {
    let config = vacuum();
    let g = config.gravity;
    let r = config.ball.radius;
    let propagator = Propagator::with_step(&config, 0.004);
    let start = state([0.9, 0.1, 0.5], [-2.0, 0.0, 0.0], [0.0, 0.0, 0.0]);
    let trajectory = predict(
        &propagator,
        &start,
        &PredictOptions {
            horizon: 1.5,
            sample_interval: 0.01,
            plane_x: None,
            stop_at_plane: false,
        },
    );
    let contact = trajectory.bounces().next().expect("bounce");
    let expected = (2.0 * (0.5 - r) / g).sqrt();
    assert!(
        (contact.t - expected).abs() < 1e-12,
        "contact at {} vs {expected}",
        contact.t
    );
    assert!(
        (contact.t / 0.004).fract() > 0.01,
        "the contact time is not on the step grid"
    );
    assert!((contact.before[2] - r).abs() < 1e-15);
    assert!((contact.after[5] - 0.9 * (expected * g)).abs() < 1e-9);

    // A plane crossing in free flight (x is linear in time in a vacuum).
    let high = state([-1.0, 0.0, 1.0], [-2.0, 0.0, 0.0], [0.0, 0.0, 0.0]);
    let to_plane = predict(
        &propagator,
        &high,
        &PredictOptions {
            horizon: 1.0,
            sample_interval: 0.01,
            plane_x: Some(-1.6),
            stop_at_plane: true,
        },
    );
    let crossing = to_plane.plane_crossing().expect("plane");
    assert!((crossing.t - 0.3).abs() < 1e-12, "plane at {}", crossing.t);
    assert_eq!(to_plane.end, TrajectoryEnd::Plane);
    assert_eq!(to_plane.samples.last().map(|s| s.t), Some(crossing.t));
}

#[test]
fn rk4_error_falls_sixteen_fold_when_the_step_halves() {
    let config = Config::default();
    // High above the floor, away from the table: a pure flight with drag and Magnus.
    let start = state([3.0, 0.0, 3.0], [-9.0, 1.0, 3.0], [50.0, -250.0, 30.0]).to_vector();
    let duration = 0.8;
    let end = |h: f64| {
        let propagator = Propagator::with_step(&config, h);
        let mut cursor = Cursor::new(0.0, &BallState::from_vector(&start));
        assert_eq!(
            propagator.advance(&mut cursor, duration, Watch::FLIGHT, &mut ()),
            Outcome::Reached
        );
        cursor.state
    };
    let reference = end(1e-4);
    let errors: Vec<f64> = [0.1, 0.05, 0.025]
        .iter()
        .map(|&h| (end(h) - reference).norm())
        .collect();
    for pair in errors.windows(2) {
        let ratio = pair[0] / pair[1];
        assert!(
            (13.0..19.0).contains(&ratio),
            "error ratio {ratio} ({errors:?})"
        );
    }
    // At the default step (40 ms) the integration error (2e-6 m) is far below any camera's noise.
    let at_default = (end(Config::default().prediction.step) - reference).norm();
    println!("error at the default step {at_default:e}");
    assert!(at_default < 5e-6, "error at the default step {at_default}");
}

/// A duration a rounding error over a whole number of largest steps takes that number of steps,
/// not one more (a trajectory sample at k x 10 ms lands a rounding error off the step grid).
#[test]
fn a_duration_a_rounding_error_over_whole_steps_takes_no_extra_step() {
    struct Steps(usize);
    impl Observer for Steps {
        fn on_step(&mut self, _cursor: &Cursor) -> Flow {
            self.0 += 1;
            Flow::Continue
        }
    }
    let propagator = Propagator::with_step(&Config::default(), 0.02);
    let high = state([3.0, 0.0, 3.0], [-5.0, 0.0, 1.0], [0.0, 0.0, 0.0]);
    for (duration, steps) in [
        (0.02 * (1.0 + 1e-12), 1),
        (3.0 * 0.02 * (1.0 + 1e-12), 3),
        (0.0201, 2),
    ] {
        let mut cursor = Cursor::new(0.0, &high);
        let mut counted = Steps(0);
        assert_eq!(
            propagator.advance(&mut cursor, duration, Watch::FLIGHT, &mut counted),
            Outcome::Reached
        );
        assert_eq!(counted.0, steps, "{duration}");
        assert_eq!(cursor.t, duration);
    }
}

/// The samples between RK4 steps are interpolated (a cubic Hermite of the step's ends and their
/// derivatives): at the default 40 ms step and 10 ms samples they agree with a finely integrated
/// flight to 5e-6 (m, m/s, rad/s; measured 2.5e-6, the RK4 error itself is about as large),
/// through a bounce and the plane crossing, with the same events (to 5e-7 s; 1.2e-7 measured, at
/// the floor after 0.96 s) and the same end.
#[test]
fn interpolated_samples_match_a_fine_integration_through_events() {
    let mut config = Config::default();
    config.aero = ttball::config::AeroParams::seed_2014();
    let options = PredictOptions {
        horizon: 1.5,
        sample_interval: 0.01,
        plane_x: Some(-1.6),
        stop_at_plane: false,
    };
    let shot = state([1.3, 0.1, 0.30], [-5.5, -0.4, 1.2], [40.0, -150.0, 30.0]);
    let coarse = predict(&Propagator::new(&config), &shot, &options);
    let fine = predict(&Propagator::with_step(&config, 0.000_5), &shot, &options);
    assert_eq!(config.prediction.step, 0.04);
    assert_eq!(coarse.samples.len(), fine.samples.len());
    assert_eq!(coarse.end, fine.end);
    assert_eq!(coarse.events.len(), fine.events.len());
    assert!(coarse.bounces().count() >= 1 && coarse.plane_crossing().is_some());
    for (a, b) in coarse.events.iter().zip(&fine.events) {
        assert_eq!(
            std::mem::discriminant(&a.kind),
            std::mem::discriminant(&b.kind)
        );
        assert!((a.t - b.t).abs() < 5e-7, "event at {} vs {}", a.t, b.t);
    }
    let worst = coarse
        .samples
        .iter()
        .zip(&fine.samples)
        .map(|(a, b)| {
            assert!((a.t - b.t).abs() < 5e-7, "sample at {} vs {}", a.t, b.t);
            // Position [m] and velocity [m/s] as they are; the spin (150 rad/s, decaying) per
            // rad/s of its magnitude.
            let d = a.state.to_vector() - b.state.to_vector();
            let spin = d.fixed_rows::<3>(6).norm() / b.state.spin.norm().max(1.0);
            d.fixed_rows::<6>(0).amax().max(spin)
        })
        .fold(0.0, f64::max);
    println!("largest sample difference {worst:e}");
    assert!(worst < 5e-6, "largest sample difference {worst}");
    // Interpolation, not integration, filled the samples between steps: fewer flight-field
    // evaluations than a 10 ms step would need is what it is for, and it must not be exact.
    let stepped = predict(&Propagator::with_step(&config, 0.01), &shot, &options);
    assert_ne!(coarse.samples, stepped.samples);
}

/// Same launch, three spins: topspin dips and bounces first, backspin floats and bounces last.
#[test]
fn topspin_dips_and_backspin_floats() {
    let propagator = Propagator::new(&Config::default());
    let options = PredictOptions {
        horizon: 1.0,
        sample_interval: 0.01,
        plane_x: None,
        stop_at_plane: false,
    };
    let flight = |wy: f64| {
        predict(
            &propagator,
            &state([1.3, 0.0, 0.30], [-4.5, 0.0, 1.6], [0.0, wy, 0.0]),
            &options,
        )
    };
    let (top, flat, back) = (flight(-150.0), flight(0.0), flight(150.0));
    let height_at = |t: &ttball::physics::Trajectory, k: usize| t.samples[k].state.position.z;
    assert!(height_at(&top, 15) < height_at(&flat, 15) - 0.015);
    assert!(height_at(&back, 15) > height_at(&flat, 15) + 0.015);
    let first = |t: &ttball::physics::Trajectory| *t.bounces().next().expect("bounce");
    let (bt, bf, bb) = (first(&top), first(&flat), first(&back));
    assert!(
        bt.t < bf.t && bf.t < bb.t,
        "bounce times {} {} {}",
        bt.t,
        bf.t,
        bb.t
    );
    // Moving toward -x, a later bounce lies further along -x.
    assert!(bt.before[0] > bf.before[0] && bf.before[0] > bb.before[0]);
    // The table's friction turns backspin into less backspin and speeds a topspin ball up less.
    assert!(bb.after[7] < bb.before[7]);
}

#[test]
fn net_hit_floor_and_table_edge() {
    let propagator = Propagator::new(&Config::default());
    let options = PredictOptions {
        horizon: 2.0,
        sample_interval: 0.01,
        plane_x: None,
        stop_at_plane: false,
    };
    // Low, flat ball into the net.
    let into_net = predict(
        &propagator,
        &state([1.0, 0.0, 0.10], [-6.0, 0.0, 0.0], [0.0; 3]),
        &options,
    );
    assert_eq!(into_net.end, TrajectoryEnd::Net);
    let last = into_net.events.last().expect("net event");
    assert!(matches!(last.kind, EventKind::Net { hit: true, clearance } if clearance < 0.0));
    assert!(last.before[0].abs() < 1e-15);
    // Beside the table: no bounce, then the floor.
    let beside = predict(
        &propagator,
        &state([0.5, 1.2, 0.3], [-1.0, 0.0, 0.0], [0.0; 3]),
        &options,
    );
    assert_eq!(beside.end, TrajectoryEnd::Floor);
    assert_eq!(beside.bounces().count(), 0);
    let floor = beside.events.last().expect("floor event");
    assert!((floor.before[2] - (0.02 - 0.76)).abs() < 1e-12);
    // Over the net with room to spare: a crossing with its clearance.
    let over = predict(
        &propagator,
        &state([1.0, 0.0, 0.35], [-6.0, 0.0, 0.5], [0.0; 3]),
        &options,
    );
    let crossing = over
        .events
        .iter()
        .find_map(|e| match e.kind {
            EventKind::Net { clearance, hit } => Some((clearance, hit)),
            _ => None,
        })
        .expect("net crossing");
    assert!(!crossing.1 && crossing.0 > 0.1, "{crossing:?}");
    // A table without a net (`table.net_height: 0`, as the launcher data's): the ball that hit
    // the net passes over the table's middle, its clearance its height over the table.
    let mut netless = Config::default();
    netless.table.net_height = 0.0;
    netless.validate().expect("a table without a net is valid");
    let passes = predict(
        &Propagator::new(&netless),
        &state([1.0, 0.0, 0.10], [-6.0, 0.0, 0.0], [0.0; 3]),
        &options,
    );
    assert_ne!(passes.end, TrajectoryEnd::Net);
    let crossing = passes
        .events
        .iter()
        .find_map(|e| match e.kind {
            EventKind::Net { clearance, hit } => Some((clearance, hit, e.before[2])),
            _ => None,
        })
        .expect("net-plane crossing");
    assert!(!crossing.1, "{crossing:?}");
    assert!(
        (crossing.0 - (crossing.2 - 0.02)).abs() < 1e-12,
        "{crossing:?}"
    );
}

#[test]
fn a_ball_touching_the_table_while_falling_bounces_at_once() {
    let propagator = Propagator::new(&Config::default());
    let mut cursor = Cursor::new(0.0, &state([0.5, 0.0, 0.019], [-3.0, 0.0, -2.0], [0.0; 3]));
    propagator.advance(&mut cursor, 0.01, Watch::BOUNCES, &mut ());
    assert!(cursor.state[5] > 1.0, "the ball goes up after the bounce");
}

#[test]
fn predictions_are_deterministic() {
    let propagator = Propagator::new(&Config::default());
    let options = PredictOptions {
        horizon: 1.2,
        sample_interval: 0.005,
        plane_x: Some(-1.6),
        stop_at_plane: false,
    };
    let shot = state([1.2, 0.3, 0.25], [-6.5, -0.8, 1.5], [30.0, -180.0, 60.0]);
    let a = predict(&propagator, &shot, &options);
    let b = predict(&propagator, &shot, &options);
    assert_eq!(a, b);
    assert!(a.samples.len() > 100);
}

/// A margin of a state and its gradient.
type Margin<'a> = dyn Fn(&StateVector) -> (f64, StateRow) + 'a;

/// The margins that decide a prediction's branches (a bounce's regime, where it lands, how the
/// ball passes the net) have the gradients their finite differences say, and their signs agree
/// with the branch taken.
#[test]
fn branch_margins_have_exact_gradients_and_the_branch_signs() {
    let config = Config::default();
    let propagator = Propagator::new(&config);
    let states = [
        BallState::new(
            [-0.6, 0.2, 0.02].into(),
            [-4.0, 0.5, -2.5].into(),
            [5.0, -40.0, 10.0].into(),
        ),
        BallState::new(
            [0.9, -0.5, 0.02].into(),
            [-3.0, -0.8, -1.5].into(),
            [-30.0, 60.0, 5.0].into(),
        ),
        BallState::new(
            [0.001, 0.1, 0.17].into(),
            [-5.0, 0.2, 0.4].into(),
            [0.0, 80.0, 0.0].into(),
        ),
        BallState::new(
            [0.001, 0.85, 0.05].into(),
            [-5.0, 0.2, 0.4].into(),
            [0.0, 80.0, 0.0].into(),
        ),
    ];
    let margins: [(&str, &Margin); 4] = [
        ("regime", &|x| propagator.bounce().regime_margin(x)),
        ("landing", &|x| propagator.landing_margin(x)),
        ("outline", &|x| propagator.outline_margin(x)),
        ("net", &|x| propagator.net_margin(x)),
    ];
    for state in &states {
        let x = state.to_vector();
        for (name, margin) in &margins {
            let (_, gradient) = margin(&x);
            for i in 0..9 {
                let h = 1e-6;
                let mut up = x;
                up[i] += h;
                let mut down = x;
                down[i] -= h;
                let numeric = (margin(&up).0 - margin(&down).0) / (2.0 * h);
                assert!(
                    (numeric - gradient[i]).abs() < 1e-6,
                    "{name} d/dx{i}: {numeric} vs {}",
                    gradient[i]
                );
            }
        }
        let rolling = propagator.bounce().regime_margin(&x).0 >= 0.0;
        let regime = propagator.bounce().apply(&x).regime;
        assert_eq!(rolling, regime == BounceRegime::Rolling, "{state:?}");
    }
    // The net: a hit below the top, a clear pass above it, a pass beside a post.
    let at_net = |y: f64, z: f64| {
        BallState::new(
            [0.0, y, z].into(),
            [-5.0, 0.0, 0.0].into(),
            Vector3::zeros(),
        )
        .to_vector()
    };
    assert!(propagator.net_margin(&at_net(0.0, 0.10)).0 < 0.0);
    assert!(propagator.net_margin(&at_net(0.0, 0.20)).0 > 0.0);
    assert!(propagator.net_margin(&at_net(1.0, 0.10)).0 > 0.0);
}

/// A ball that passes the table's level just outside its outline is reported as a table miss
/// when watched, and not otherwise; the flight is the same either way (to the integration error
/// of the step the event splits: 4e-9 m at the 40 ms step).
#[test]
fn a_near_miss_of_the_table_is_an_event_when_watched() {
    let propagator = Propagator::new(&Config::default());
    // Along the side line, 1 cm outside it, falling.
    let start = BallState::new(
        [-0.5, 0.7625 + 0.01 + 0.02, 0.2].into(),
        [-2.0, 0.02, 0.0].into(),
        Vector3::zeros(),
    );
    let mut events = Vec::new();
    let mut run = |table_misses: bool| {
        let mut recorder = Recorder(Vec::new());
        let mut cursor = Cursor::new(0.0, &start);
        let watch = Watch {
            table_misses,
            ..Watch::FLIGHT
        };
        propagator.advance(&mut cursor, 0.3, watch, &mut recorder);
        events.push(recorder.0);
        cursor.state
    };
    let watched = run(true);
    let unwatched = run(false);
    assert!(
        (watched - unwatched).norm() < 1e-8,
        "{}",
        (watched - unwatched).norm()
    );
    let misses: Vec<f64> = events[0]
        .iter()
        .filter_map(|e| match e.kind {
            EventKind::TableMiss { distance } => Some(distance),
            _ => None,
        })
        .collect();
    assert_eq!(misses.len(), 1, "{:?}", events[0]);
    assert!((misses[0] - 0.03).abs() < 0.01, "{misses:?}");
    assert!(
        events[1]
            .iter()
            .all(|e| !matches!(e.kind, EventKind::TableMiss { .. }))
    );
}

struct Recorder(Vec<Event>);

impl Observer for Recorder {
    fn on_event(&mut self, event: &Event) -> Flow {
        self.0.push(*event);
        Flow::Continue
    }
}
