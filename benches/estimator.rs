//! Cost of the per-detection path: one EKF update, the estimator's update of a detection in order
//! and of a late one (rollback), one interception prediction with covariance at several horizons,
//! and the whole `Estimator::handle` (update + interception), on states and detections from a
//! simulated 150 + 900 fps session; the batch fit of a flight so far, and a shot with its track
//! refitted (`ekf.refit_interval`) and without. `cargo bench --bench estimator`; the distribution over a whole
//! stream is `cargo bench --bench per_detection`.

use std::hint::black_box;

use criterion::{BatchSize, Criterion, criterion_group, criterion_main};
use nalgebra::{Matrix3, Matrix6, SVector};
use ttball::config::Config;
use ttball::eval::sim::{Cameras, SimOptions, simulate};
use ttball::offline::batch::fit_flight;
use ttball::online::ekf::{BounceNoise, Ekf, position_H, position_spin_H};
use ttball::online::estimator::Estimator;
use ttball::online::intercept::{InterceptQuery, predict_intercept};
use ttball::physics::{BallState, Propagator, StateMatrix};

fn incoming() -> BallState {
    BallState::new(
        [1.3, 0.0, 0.30].into(),
        [-6.5, 0.1, 1.4].into(),
        [10.0, -150.0, 20.0].into(),
    )
}

fn benches(c: &mut Criterion) {
    let config = Config::default();
    let propagator = Propagator::new(&config);
    let x = incoming().to_vector();
    let p = StateMatrix::identity() * 1e-4;

    let mut group = c.benchmark_group("ekf_update");
    // With the physical parameters uncertain, as the estimator's filter has them.
    let ekf = Ekf::new(
        x,
        p,
        propagator.params().to_vector(),
        ttball::physics::ParamCovariance::from_diagonal_element(1e-3),
    );
    let z3 = x.fixed_rows::<3>(0).into_owned();
    let r3 = Matrix3::identity() * 4e-6;
    group.bench_function("position", |b| {
        b.iter_batched(
            || ekf,
            |e| e.update(black_box(&z3), &position_H(), &r3, 100.0),
            BatchSize::SmallInput,
        )
    });
    let mut z6 = SVector::<f64, 6>::zeros();
    z6.fixed_rows_mut::<3>(0).copy_from(&z3);
    z6.fixed_rows_mut::<3>(3).copy_from(&x.fixed_rows::<3>(6));
    let r6 = Matrix6::identity() * 4e-6;
    group.bench_function("position_spin", |b| {
        b.iter_batched(
            || ekf,
            |e| e.update(black_box(&z6), &position_spin_H(), &r6, 100.0),
            BatchSize::SmallInput,
        )
    });
    group.finish();

    // The trajectory the node publishes: the default horizon at the default spacing, through the
    // bounce, the plane and on to the floor.
    let options = ttball::physics::PredictOptions {
        horizon: config.prediction.horizon,
        sample_interval: config.prediction.trajectory_dt,
        plane_x: Some(config.intercept.plane_x),
        stop_at_plane: false,
    };
    c.bench_function("predicted_trajectory", |b| {
        b.iter(|| ttball::physics::predict(&propagator, black_box(&incoming()), &options))
    });

    let mut group = c.benchmark_group("intercept_with_covariance");
    for horizon in [0.1, 0.3, 0.6] {
        // Start the ball `horizon` seconds before it reaches the hitting plane.
        let query = InterceptQuery {
            plane_x: config.intercept.plane_x,
            horizon: 1.5,
            bounced_on_robot_half: false,
            bounce_noise: BounceNoise::from_config(&config),
        };
        let full = predict_intercept(&propagator, &x, &p, &query);
        let to_plane = full.crossing.map(|c| c.time).unwrap_or(0.6);
        let mut cursor = ttball::physics::Cursor::new(0.0, &incoming());
        propagator.advance(
            &mut cursor,
            (to_plane - horizon).max(0.0),
            ttball::physics::Watch::FLIGHT,
            &mut (),
        );
        let start = cursor.state;
        group.bench_function(format!("{:.0}ms", horizon * 1e3), |b| {
            b.iter(|| predict_intercept(&propagator, black_box(&start), &p, &query))
        });
    }
    group.finish();

    // The whole per-detection path on a real stream, in steady tracking on the robot's half.
    let session = simulate(
        &config,
        &SimOptions {
            cameras: Cameras::WideAndHighSpeed,
            shots: 2,
            seed: 5,
            ..SimOptions::default()
        },
    )
    .ok();
    if let Some(session) = session {
        let mut estimator = Estimator::new(&config);
        let shot = &session.shots[0];
        let midway = session
            .stream
            .iter()
            .position(|d| d.detection.stamp > shot.bounce.stamp - 100_000_000)
            .unwrap_or(0);
        for d in &session.stream[..midway] {
            estimator.handle(&d.detection);
        }
        // The batch fit of the flight so far (what an online refit would solve): the shot's
        // detections up to 100 ms before its bounce, and up to 50 ms after it, from the true
        // state at the first one (its seven spin starts included).
        let mut group = c.benchmark_group("batch_fit");
        group.sample_size(20);
        for (name, until) in [
            ("before_bounce", shot.bounce.stamp - 100_000_000),
            ("through_bounce", shot.bounce.stamp + 50_000_000),
        ] {
            let flight: Vec<_> = session
                .stream
                .iter()
                .filter(|d| d.shot == 0 && !d.outlier && d.detection.stamp <= until)
                .collect();
            let Some(first) = flight.iter().min_by_key(|d| d.detection.stamp) else {
                continue;
            };
            let initial = first.truth;
            let detections: Vec<_> = flight.iter().map(|d| d.detection).collect();
            if let Ok(fit) = fit_flight(&config, &detections, &initial) {
                println!(
                    "batch_fit/{name}: {} detections, {} Levenberg-Marquardt iterations",
                    fit.used, fit.iterations
                );
            }
            group.bench_function(name, |b| {
                b.iter(|| fit_flight(&config, black_box(&detections), &initial))
            });
        }
        group.finish();

        // A track's lesson (its flight smoothed, off the detection path): one shot seen by the
        // 150 fps camera alone, its track ended, its lesson run inline.
        let wide = simulate(
            &config,
            &SimOptions {
                cameras: Cameras::WideOnly,
                shots: 1,
                seed: 5,
                ..SimOptions::default()
            },
        );
        if let Ok(wide) = wide {
            let mut fed = Estimator::new(&config);
            for d in &wide.stream {
                fed.handle(&d.detection);
            }
            let mut counted = fed.clone();
            counted.end_of_input();
            println!(
                "track_lesson: {} detections, {} smoothed",
                wide.stream.len(),
                counted.counters().smoothed_lessons
            );
            let mut group = c.benchmark_group("track_lesson");
            group.sample_size(20);
            group.bench_function("smoothed", |b| {
                b.iter_batched(
                    || fed.clone(),
                    |mut e| e.end_of_input(),
                    BatchSize::SmallInput,
                )
            });
            group.finish();
        }

        let next = session.stream[midway..]
            .iter()
            .find(|d| d.detection.spin.is_some())
            .map(|d| d.detection);
        if let Some(detection) = next {
            c.bench_function("handle_detection", |b| {
                b.iter_batched(
                    || estimator.clone(),
                    |mut e| e.handle(black_box(&detection)),
                    BatchSize::SmallInput,
                )
            });
        }

        // The filter alone (no interception), for a detection in order and for one that arrives
        // late: a 150 fps detection behind the 900 fps ones already fused (a rollback re-applies
        // them). Both at the first late arrival of the second half of the shot.
        let late = session
            .stream
            .iter()
            .enumerate()
            .skip(midway)
            .find(|(i, d)| {
                session.stream[..*i]
                    .iter()
                    .rev()
                    .take(20)
                    .filter(|e| e.detection.stamp > d.detection.stamp)
                    .count()
                    >= 3
            });
        if let Some((index, late)) = late {
            let mut before = Estimator::new(&config);
            for d in &session.stream[..index] {
                before.handle(&d.detection);
            }
            let newer = session.stream[..index]
                .iter()
                .filter(|e| e.detection.stamp > late.detection.stamp)
                .count();
            let in_order = session.stream[index..]
                .iter()
                .find(|d| d.detection.stamp > session.stream[index - 1].detection.stamp)
                .map(|d| d.detection);
            let mut group = c.benchmark_group("estimator_update");
            if let Some(d) = in_order {
                group.bench_function("in_order", |b| {
                    b.iter_batched(
                        || before.clone(),
                        |mut e| e.update(black_box(&d)),
                        BatchSize::SmallInput,
                    )
                });
            }
            group.bench_function(format!("late_rollback_{newer}_newer"), |b| {
                b.iter_batched(
                    || before.clone(),
                    |mut e| e.update(black_box(&late.detection)),
                    BatchSize::SmallInput,
                )
            });
            group.finish();
        }
    }
}

criterion_group!(estimator, benches);
criterion_main!(estimator);
