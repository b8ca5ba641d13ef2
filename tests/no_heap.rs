//! No heap allocation per detection: the estimator's whole per-detection path (measurement,
//! prediction, update, rollback of late detections, interception with covariance) runs on
//! fixed-size matrices and buffers allocated once. Counted with a counting global allocator.
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    reason = "test code: fail loudly"
)]

use ttball::config::Config;
use ttball::eval::sim::{Cameras, Session, SimOptions, simulate};
use ttball::online::estimator::Estimator;

/// Three shots seen by both cameras.
fn session(config: &Config) -> Session {
    simulate(
        config,
        &SimOptions {
            cameras: Cameras::WideAndHighSpeed,
            shots: 3,
            seed: 4,
            ..SimOptions::default()
        },
    )
    .unwrap()
}

#[test]
fn handling_detections_allocates_nothing() {
    let config = Config::default();
    let session = session(&config);
    let mut estimator = Estimator::new(&config);
    // The first shot warms up: the first track takes its buffers.
    let first_of_second = session.stream.iter().position(|d| d.shot == 1).unwrap();
    for sim in &session.stream[..first_of_second] {
        estimator.handle(&sim.detection);
    }
    let rest = &session.stream[first_of_second..];
    let mut outputs = 0usize;
    let info = allocation_counter::measure(|| {
        for sim in rest {
            let out = estimator.handle(&sim.detection);
            outputs += usize::from(out.intercept.is_some());
        }
    });
    let counters = estimator.counters();
    assert!(rest.len() > 1000, "{} detections", rest.len());
    assert!(outputs > 1000 && counters.rollbacks > 50 && counters.tracks == 3);
    assert_eq!(info.count_total, 0, "{info:?}");
}

/// The 150 fps camera alone: every ended track's lesson is its flight smoothed, inline and on a
/// worker thread, in buffers allocated once (the detections' records go to the worker and come
/// back).
#[test]
fn smoothed_lessons_allocate_nothing() {
    use ttball::online::estimator::Waiting;
    let config = Config::default();
    let session = simulate(
        &config,
        &SimOptions {
            cameras: Cameras::WideOnly,
            shots: 5,
            seed: 4,
            ..SimOptions::default()
        },
    )
    .unwrap();
    for worker in [false, true] {
        let mut estimator = Estimator::new(&config);
        if worker {
            estimator.run_lessons_on_a_worker(Waiting::Wait).unwrap();
        }
        let first_of_second = session.stream.iter().position(|d| d.shot == 1).unwrap();
        for sim in &session.stream[..first_of_second] {
            estimator.handle(&sim.detection);
        }
        // A thread's first blocking receive on a channel allocates its waiting context, once
        // (crossbeam keeps it per thread): on a loaded machine the first wait for a lesson can
        // fall in the measured detections, so this thread blocks once before them.
        let (send, receive) = crossbeam::channel::bounded::<()>(0);
        let sender = std::thread::spawn(move || {
            std::thread::sleep(std::time::Duration::from_millis(5));
            send.send(()).unwrap();
        });
        receive.recv().unwrap();
        sender.join().unwrap();
        let rest = &session.stream[first_of_second..];
        let info = allocation_counter::measure(|| {
            for sim in rest {
                estimator.handle(&sim.detection);
            }
        });
        assert!(
            estimator.counters().smoothed_lessons >= 2,
            "worker {worker}"
        );
        assert_eq!(info.count_total, 0, "worker {worker}: {info:?}");
    }
}

/// The node's whole per-detection path, `Pipeline::on_detection`: the message converted, the
/// filter updated, the interception predicted and the `/ball/state` and `/ball/intercept`
/// messages built (their `frame_id` borrowed from a constant) allocate nothing. The
/// `/ball/trajectory` and markers, at most 50 times a second, do (their sample vectors).
#[test]
fn the_pipeline_allocates_nothing_per_detection_but_the_trajectory() {
    use ttball::ros::msgs::convert::detection_to_msg;
    use ttball::ros::pipeline::Pipeline;

    let config = Config::default();
    let session = session(&config);
    let messages: Vec<_> = session
        .stream
        .iter()
        .map(|d| (d.shot, detection_to_msg(&d.detection)))
        .collect();
    let mut pipeline = Pipeline::new(&config);
    let first_of_second = messages.iter().position(|(shot, _)| *shot == 1).unwrap();
    for (_, msg) in &messages[..first_of_second] {
        pipeline.on_detection(msg);
    }
    let (mut plain, mut trajectories, mut allocating) = (0usize, 0usize, 0usize);
    for (_, msg) in &messages[first_of_second..] {
        let mut step = None;
        let info = allocation_counter::measure(|| step = Some(pipeline.on_detection(msg)));
        let step = step.unwrap();
        if step.published.trajectory.is_some() {
            trajectories += 1;
        } else {
            assert!(step.published.state.is_some() || step.published.intercept.is_none());
            plain += 1;
            allocating += usize::from(info.count_total > 0);
        }
    }
    assert!(plain > 900 && trajectories > 20, "{plain} {trajectories}");
    assert_eq!(
        allocating, 0,
        "{allocating} of {plain} detections allocated"
    );
}
