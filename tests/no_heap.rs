//! No heap allocation per detection: the estimator's whole per-detection path (measurement,
//! prediction, update, rollback of late detections, interception with covariance) runs on
//! fixed-size matrices and buffers allocated once. Counted with a counting global allocator.
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    reason = "test code: fail loudly"
)]

use ttball::config::Config;
use ttball::estimator::Estimator;
use ttball::sim::{Cameras, SimOptions, simulate};

#[test]
fn handling_detections_allocates_nothing() {
    let config = Config::default();
    let session = simulate(
        &config,
        &SimOptions {
            cameras: Cameras::WideAndHighSpeed,
            shots: 3,
            seed: 4,
            ..SimOptions::default()
        },
    )
    .unwrap();
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
