//! The simulator against its specification: determinism, the arrival-ordered stream, the noise,
//! dropout, outlier and spin statistics of the two cameras, good shots, the views and the truth.
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    clippy::panic,
    reason = "tests fail loudly by design"
)]

use std::sync::OnceLock;

use nalgebra::Vector3;
use ttball::config::Config;
use ttball::eval::sim::{
    Cameras, DEFAULT_EPOCH, Session, ShotKind, SimDetection, SimError, SimOptions, simulate,
};
use ttball::model::detection::Source;
use ttball::physics::{BallState, Cursor, EventKind, PredictOptions, Propagator, Watch, predict};

const SHOTS: usize = 40;

/// One 40-shot session with both cameras, shared by the statistical tests.
fn session() -> &'static Session {
    static SESSION: OnceLock<Session> = OnceLock::new();
    SESSION.get_or_init(|| {
        simulate(
            &Config::default(),
            &SimOptions {
                shots: SHOTS,
                seed: 1,
                ..SimOptions::default()
            },
        )
        .expect("the default session simulates")
    })
}

fn of(source: Source) -> impl Iterator<Item = &'static SimDetection> {
    session()
        .stream
        .iter()
        .filter(move |d| d.detection.source == source)
}

fn mean_std(xs: &[f64]) -> (f64, f64) {
    let n = xs.len() as f64;
    let mean = xs.iter().sum::<f64>() / n;
    let var = xs.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0);
    (mean, var.sqrt())
}

fn small(shots: usize, seed: u64, cameras: Cameras) -> Session {
    simulate(
        &Config::default(),
        &SimOptions {
            shots,
            seed,
            cameras,
            ..SimOptions::default()
        },
    )
    .unwrap()
}

#[test]
fn same_seed_gives_the_same_session_and_another_seed_another() {
    let a = small(3, 7, Cameras::WideAndHighSpeed);
    let b = small(3, 7, Cameras::WideAndHighSpeed);
    let c = small(3, 8, Cameras::WideAndHighSpeed);
    assert_eq!(a, b);
    assert!(a.stream.len() > 500);
    assert_ne!(a.shots[0].launch, c.shots[0].launch);
    assert_ne!(a.shots[0].launch_stamp, c.shots[0].launch_stamp);
    assert_ne!(
        a.stream[0].detection.position,
        c.stream[0].detection.position
    );
}

#[test]
fn wide_only_is_the_wide_part_of_the_two_camera_session() {
    let both = small(3, 9, Cameras::WideAndHighSpeed);
    let wide = small(3, 9, Cameras::WideOnly);
    assert_eq!(wide.shots, both.shots);
    assert!(
        wide.stream
            .iter()
            .all(|d| d.detection.source == Source::WIDE_150FPS)
    );
    let wide_of_both: Vec<_> = both
        .stream
        .iter()
        .filter(|d| d.detection.source == Source::WIDE_150FPS)
        .copied()
        .collect();
    assert_eq!(wide.stream, wide_of_both);
    assert!(both.stream.len() > 3 * wide.stream.len());
    assert_eq!(wide.cameras.len(), 1);
    assert_eq!(both.cameras.len(), 2);
}

#[test]
fn stream_is_sorted_by_arrival_and_stamps_come_out_of_order() {
    let stream = &session().stream;
    assert!(stream.windows(2).all(|w| {
        let key = |d: &SimDetection| (d.arrival, d.detection.stamp, d.detection.source.0);
        key(&w[0]) < key(&w[1])
    }));
    let inversions: Vec<i64> = stream
        .windows(2)
        .filter(|w| w[1].detection.stamp < w[0].detection.stamp)
        .map(|w| w[0].detection.stamp - w[1].detection.stamp)
        .collect();
    // Each wide detection (8 ms) arrives after the high-speed frames (3 ms) up to ~5 ms younger.
    let wide = of(Source::WIDE_150FPS).count();
    assert!(
        inversions.len() > wide / 2,
        "{} inversions for {wide} wide detections",
        inversions.len()
    );
    assert!(inversions.iter().all(|&d| d < 15_000_000), "{inversions:?}");
    // Stamps are epoch-sized integers.
    assert!(stream.iter().all(|d| d.detection.stamp > DEFAULT_EPOCH));
}

#[test]
fn latencies_have_the_configured_mean_and_jitter() {
    for (source, mean, jitter) in [
        (Source::WIDE_150FPS, 0.008, 0.0015),
        (Source::HIGHSPEED_900FPS, 0.003, 0.0005),
    ] {
        let latencies: Vec<f64> = of(source)
            .map(|d| (d.arrival - d.detection.stamp) as f64 * 1e-9)
            .collect();
        let (m, s) = mean_std(&latencies);
        assert!(
            (m - mean).abs() < 0.05 * jitter + 1e-6,
            "{source:?} mean {m}"
        );
        assert!((s / jitter - 1.0).abs() < 0.05, "{source:?} jitter {s}");
        assert!(latencies.iter().all(|&l| l >= 0.0));
    }
}

#[test]
fn measurement_noise_matches_the_sigmas() {
    // The specified defaults: 2 mm wide, 1 mm high-speed, 12 rad/s spin.
    for (source, sigma) in [
        (Source::WIDE_150FPS, 0.002),
        (Source::HIGHSPEED_900FPS, 0.001),
    ] {
        let errors: Vec<Vector3<f64>> = of(source)
            .filter(|d| !d.outlier)
            .map(|d| d.detection.position - d.truth.position)
            .collect();
        assert!(errors.len() > 3000, "{source:?}: {}", errors.len());
        for axis in 0..3 {
            let e: Vec<f64> = errors.iter().map(|e| e[axis]).collect();
            let (m, s) = mean_std(&e);
            assert!(
                (s / sigma - 1.0).abs() < 0.05,
                "{source:?} axis {axis}: std {s}"
            );
            assert!(m.abs() < 0.1 * sigma, "{source:?} axis {axis}: mean {m}");
        }
        // No good detection is further than 6 sigma from the ball in any axis.
        assert!(errors.iter().all(|e| e.amax() < 6.0 * sigma));
    }
    let spin_errors: Vec<Vector3<f64>> = of(Source::HIGHSPEED_900FPS)
        .filter_map(|d| d.detection.spin.map(|w| w - d.truth.spin))
        .collect();
    for axis in 0..3 {
        let e: Vec<f64> = spin_errors.iter().map(|e| e[axis]).collect();
        let (m, s) = mean_std(&e);
        assert!((s / 12.0 - 1.0).abs() < 0.05, "spin axis {axis}: std {s}");
        assert!(m.abs() < 1.0, "spin axis {axis}: mean {m}");
    }
    // Covariances are left to the estimator's configuration.
    assert!(session().stream.iter().all(|d| {
        d.detection.position_covariance.is_none() && d.detection.spin_covariance.is_none()
    }));
}

#[test]
fn outliers_are_half_a_percent_displaced_5_to_30_cm_with_low_confidence() {
    let stream = &session().stream;
    let outliers: Vec<&SimDetection> = stream.iter().filter(|d| d.outlier).collect();
    let fraction = outliers.len() as f64 / stream.len() as f64;
    assert!(
        (0.0035..0.0065).contains(&fraction),
        "outlier fraction {fraction}"
    );
    for source in [Source::WIDE_150FPS, Source::HIGHSPEED_900FPS] {
        assert!(outliers.iter().any(|d| d.detection.source == source));
    }
    for d in &outliers {
        let distance = (d.detection.position - d.truth.position).norm();
        assert!((0.04..0.31).contains(&distance), "outlier at {distance} m");
        assert!((0.3..=0.6).contains(&d.detection.confidence));
        assert!(d.detection.spin.is_none());
    }
    assert!(
        stream
            .iter()
            .filter(|d| !d.outlier)
            .all(|d| d.detection.confidence == 0.9)
    );
}

#[test]
fn two_percent_of_the_frames_are_dropped() {
    let session = session();
    let (mut frames, mut dropped) = (0, 0);
    for report in &session.cameras {
        let c = report.counts;
        frames += c.frames_in_view;
        dropped += c.dropped;
        let delivered = of(report.source).count() as u64;
        assert_eq!(c.detections, delivered);
        assert_eq!(c.frames_in_view, c.dropped + c.cut + c.detections);
        assert_eq!(
            c.outliers,
            of(report.source).filter(|d| d.outlier).count() as u64
        );
    }
    let fraction = dropped as f64 / frames as f64;
    assert!((0.016..0.024).contains(&fraction), "dropout {fraction}");

    // Independently of the counters: the missing frames inside each shot's run of high-speed
    // detections (the ball stays in its view from x = 0.05 m to the end of the shot).
    let period = 1e9 / 900.0;
    let (mut spanned, mut missing) = (0.0, 0.0);
    for shot in 0..session.shots.len() {
        let mut stamps: Vec<i64> = of(Source::HIGHSPEED_900FPS)
            .filter(|d| d.shot == shot)
            .map(|d| d.detection.stamp)
            .collect();
        stamps.sort_unstable();
        for w in stamps.windows(2) {
            let frames = ((w[1] - w[0]) as f64 / period).round();
            assert!(frames >= 1.0);
            spanned += frames;
            missing += frames - 1.0;
        }
    }
    let fraction = missing / spanned;
    assert!(
        (0.016..0.025).contains(&fraction),
        "missing frames {fraction}"
    );
}

#[test]
fn the_high_speed_camera_measures_spin_on_80_percent_of_its_frames_the_wide_never() {
    let good: Vec<&SimDetection> = of(Source::HIGHSPEED_900FPS)
        .filter(|d| !d.outlier)
        .collect();
    let with_spin = good.iter().filter(|d| d.detection.spin.is_some()).count();
    let fraction = with_spin as f64 / good.len() as f64;
    assert!((0.78..0.82).contains(&fraction), "spin fraction {fraction}");
    assert!(of(Source::WIDE_150FPS).all(|d| d.detection.spin.is_none()));
}

#[test]
fn the_high_speed_camera_sees_only_the_robots_half() {
    let high_speed: Vec<&SimDetection> = of(Source::HIGHSPEED_900FPS).collect();
    assert!(
        high_speed
            .iter()
            .all(|d| d.detection.position.x <= 0.05 && d.truth.position.x <= 0.05)
    );
    // It does see up to its edge, and the wide camera sees beyond it.
    assert!(high_speed.iter().any(|d| d.truth.position.x > 0.0));
    assert!(of(Source::WIDE_150FPS).any(|d| d.truth.position.x > 1.0));
    // Frame rates: 900 fps and 150 fps over the same flights.
    let ratio = high_speed.len() as f64 / of(Source::WIDE_150FPS).count() as f64;
    assert!((2.5..5.5).contains(&ratio), "{ratio}");
}

#[test]
fn every_shot_is_a_good_shot() {
    let config = Config::default();
    let session = session();
    assert_eq!(session.shots.len(), SHOTS);
    let r = config.ball.radius;
    let plane_x = config.intercept.plane_x;
    let half_length = config.table.length / 2.0;
    let half_width = config.table.width / 2.0;
    // An independent look with the estimator's propagator at 10 ms steps (the simulator's aim
    // step; at the default 40 ms the flight is 1e-6 m off after a second, and a shot may land
    // 0.1 um inside the table's edge: shot 32 of this session does).
    let coarse = Propagator::with_step(&config, 0.01);
    let mut previous_end = DEFAULT_EPOCH;
    for (i, shot) in session.shots.iter().enumerate() {
        let gap = (shot.launch_stamp - previous_end) as f64 * 1e-9;
        assert!((0.4..=1.0).contains(&gap), "shot {i}: gap {gap}");
        previous_end = shot.end_stamp;
        assert!(shot.launch.position.x > 0.0 && shot.launch.velocity.x < 0.0);
        assert_eq!(shot.record.is_some(), shot.kind == ShotKind::Real);

        let (b, p) = (&shot.bounce, &shot.intercept);
        assert!(shot.net.before.position.z - r > config.table.net_height);
        assert!(shot.launch_stamp < shot.net.stamp && shot.net.stamp < b.stamp);
        assert!(b.stamp < p.stamp && p.stamp < shot.end_stamp);
        assert!(
            (-half_length..0.0).contains(&b.before.position.x),
            "shot {i}"
        );
        assert!(b.before.position.y.abs() <= half_width);
        assert!((b.before.position.z - r).abs() < 1e-9);
        assert!(b.before.velocity.z < 0.0 && b.after.velocity.z > 0.0);
        assert!((p.before.position.x - plane_x).abs() < 1e-9);
        assert!(p.before.velocity.x < 0.0 && p.before.position.z >= 0.0);
        let follow = shot.end_stamp - p.stamp;
        assert!((follow - 30_000_000).abs() <= 1, "{follow}");
        assert_eq!(
            b.stamp,
            shot.launch_stamp + (b.since_launch * 1e9).round() as i64
        );

        let trajectory = predict(
            &coarse,
            &shot.launch,
            &PredictOptions {
                horizon: 3.0,
                sample_interval: 0.01,
                plane_x: Some(plane_x),
                stop_at_plane: true,
            },
        );
        let kinds: Vec<EventKind> = trajectory.events.iter().map(|e| e.kind).collect();
        assert!(
            matches!(
                kinds.as_slice(),
                [
                    EventKind::Net { hit: false, .. },
                    EventKind::TableBounce { .. },
                    EventKind::Plane { .. }
                ]
            ),
            "shot {i}: {kinds:?}"
        );
        // 10 us: the estimator's 10 ms steps against the truth's 0.25 ms, over a whole flight
        // where Sp may cross the clamp at 2 (a kink that costs RK4 its order).
        let dt_bounce = trajectory.events[1].t - b.since_launch;
        assert!(dt_bounce.abs() < 1e-5, "shot {i}: {dt_bounce:e}");
        assert!((trajectory.events[2].t - p.since_launch).abs() < 1e-5);

        // No detection's truth touches the table between the bounce and the end of the shot.
        assert!(
            session
                .stream
                .iter()
                .filter(|d| d.shot == i && d.detection.stamp > b.stamp)
                .all(|d| d.truth.position.z > r || d.truth.position.x < -half_length)
        );
    }
    let accepted: u64 = session.acceptance.iter().map(|a| a.accepted).sum();
    assert_eq!(accepted, SHOTS as u64);
    assert!(session.acceptance.iter().all(|a| a.accepted <= a.drawn));
    let real = session
        .shots
        .iter()
        .filter(|s| s.kind == ShotKind::Real)
        .count();
    assert!((10..=30).contains(&real), "{real} real shots of {SHOTS}");
    for kind in [
        ShotKind::Top,
        ShotKind::Back,
        ShotKind::Side,
        ShotKind::Mixed,
    ] {
        assert!(session.shots.iter().any(|s| s.kind == kind), "{kind:?}");
    }
}

#[test]
fn truth_at_each_detection_is_the_flight_from_the_launch() {
    let config = Config::default();
    let session = session();
    // A finer propagator than the truth's: the truth is the converged flight, not a grid's.
    let fine = Propagator::with_step(&config, 0.0001);
    let close = |a: &BallState, b: &BallState, tol: f64| {
        (a.position - b.position).amax() < tol
            && (a.velocity - b.velocity).amax() < tol
            && (a.spin - b.spin).amax() < tol
    };
    let mut checked = 0;
    for d in session.stream.iter().filter(|d| d.shot < 3) {
        let shot = &session.shots[d.shot];
        let from_launch = shot.state_at(d.detection.stamp).unwrap();
        assert!(close(&from_launch, &d.truth, 1e-9), "{d:?}");
        if checked % 10 == 0 {
            let mut cursor = Cursor::new(0.0, &shot.launch);
            let t = (d.detection.stamp - shot.launch_stamp) as f64 * 1e-9;
            fine.advance(&mut cursor, t, Watch::FLIGHT, &mut ());
            assert!(close(&cursor.ball(), &d.truth, 1e-9), "{d:?}");
        }
        checked += 1;
    }
    assert!(checked > 1000);
    let shot = &session.shots[0];
    assert_eq!(shot.state_at(shot.launch_stamp), Some(shot.launch));
    assert_eq!(shot.state_at(shot.launch_stamp - 1), None);
    assert_eq!(shot.state_at(shot.end_stamp + 1), None);
    // The intercept stamp is rounded to the nanosecond: the state there is the crossing's.
    let at_plane = shot.state_at(shot.intercept.stamp).unwrap();
    assert!((at_plane.position - shot.intercept.before.position).amax() < 1e-8);
}

/// A shot from the robot's end is a drawn shot turned half around the vertical through the
/// net's centre: launched behind the robot's end toward +x, over the net, bounced on the
/// opponent's half, crossing the opponent's plane; its truth the flight of its own launch; the
/// 900 fps camera sees it from its start to the net.
#[test]
fn shots_from_the_robots_end_fly_the_turned_flight() {
    let config = Config::default();
    let mut options = SimOptions {
        shots: 12,
        seed: 3,
        ..SimOptions::default()
    };
    options.params.shots.from_robot_fraction = 0.5;
    let session = simulate(&config, &options).unwrap();
    let fine = Propagator::with_step(&config, 0.0001);
    let from_robot: Vec<usize> = (0..session.shots.len())
        .filter(|&i| session.shots[i].from_robot)
        .collect();
    assert!((3..=9).contains(&from_robot.len()), "{from_robot:?}");
    let half_length = config.table.length / 2.0;
    for (i, shot) in session.shots.iter().enumerate() {
        let sign = if shot.from_robot { -1.0 } else { 1.0 };
        assert!(sign * shot.launch.position.x > 0.0 && sign * shot.launch.velocity.x < 0.0);
        let b = &shot.bounce.before.position;
        assert!(
            (-half_length..0.0).contains(&(sign * b.x)),
            "shot {i}: {b:?}"
        );
        let p = &shot.intercept.before.position;
        assert!(
            (p.x - sign * config.intercept.plane_x).abs() < 1e-9,
            "shot {i}"
        );
        assert!(shot.net.stamp < shot.bounce.stamp && shot.bounce.stamp < shot.intercept.stamp);
        // The truth at a detection is the flight of the shot's own launch.
        let d = session
            .stream
            .iter()
            .find(|d| d.shot == i && d.detection.stamp > shot.bounce.stamp)
            .unwrap();
        let mut cursor = Cursor::new(0.0, &shot.launch);
        let t = (d.detection.stamp - shot.launch_stamp) as f64 * 1e-9;
        fine.advance(&mut cursor, t, Watch::FLIGHT, &mut ());
        assert!(
            (cursor.ball().position - d.truth.position).amax() < 1e-9,
            "shot {i}"
        );
        let fast: Vec<i64> = session
            .stream
            .iter()
            .filter(|d| d.shot == i && d.detection.source == Source::HIGHSPEED_900FPS)
            .map(|d| d.detection.stamp)
            .collect();
        assert!(!fast.is_empty());
        if shot.from_robot {
            assert!(fast.iter().all(|&t| t < shot.bounce.stamp), "shot {i}");
        } else {
            assert!(fast.iter().any(|&t| t > shot.bounce.stamp), "shot {i}");
        }
    }
    // Without shots from the robot's end, the launches are those of the default (the choice is
    // not drawn).
    options.params.shots.from_robot_fraction = 0.0;
    let incoming = simulate(&config, &options).unwrap();
    assert!(incoming.shots.iter().all(|s| !s.from_robot));
    let plain = simulate(
        &config,
        &SimOptions {
            shots: 12,
            seed: 3,
            ..SimOptions::default()
        },
    )
    .unwrap();
    assert_eq!(incoming, plain);
}

#[test]
fn bad_parameters_are_errors_not_panics() {
    let mut options = SimOptions {
        shots: 1,
        ..SimOptions::default()
    };
    options.params.wide.frame_rate = 0.0;
    let result = simulate(&Config::default(), &options);
    assert!(
        matches!(&result, Err(SimError::Params(e)) if e.name == "frame_rate"),
        "{result:?}"
    );
    let mut config = Config::default();
    config.prediction.step = -1.0;
    let result = simulate(&config, &SimOptions::default());
    assert!(matches!(result, Err(SimError::Config(_))), "{result:?}");
    // Shots that can never be good: the ball should cross the plane 5 m above the table.
    let mut options = SimOptions {
        shots: 1,
        ..SimOptions::default()
    };
    options.params.shots.min_plane_height = 5.0;
    options.params.shots.max_tries = 5;
    let result = simulate(&Config::default(), &options);
    assert!(
        matches!(result, Err(SimError::NoGoodShot { tries: 5, .. })),
        "{result:?}"
    );
}
