//! The estimator on simulated play against truth: the targets for the 150 + 900 fps
//! setup on a small session (the README's table uses more shots: `ttball evaluate`).
#![allow(clippy::unwrap_used, reason = "test code: fail loudly")]

use ttball::config::Config;
use ttball::eval::sim::{Cameras, SimOptions, simulate};
use ttball::eval::{EvalReport, evaluate};

fn run(cameras: Cameras, shots: usize, seed: u64) -> EvalReport {
    let mut config = Config::default();
    let options = SimOptions {
        cameras,
        shots,
        seed,
        ..SimOptions::default()
    };
    options.params.configure_estimator(&mut config);
    let session = simulate(&config, &options).unwrap();
    evaluate(&config, &session)
}

#[test]
fn both_cameras_meet_the_targets() {
    let r = run(Cameras::WideAndHighSpeed, 24, 7);
    let [lead300, lead200, lead100] = [&r.leads[0], &r.leads[1], &r.leads[2]];
    assert!(lead100.position_error.rms < 0.003, "{lead100:?}");
    assert!(lead200.position_error.median < 0.003, "{lead200:?}");
    assert!(lead300.position_error.median < 0.040, "{lead300:?}");
    assert!(lead200.valid_fraction >= 0.95, "{lead200:?}");
    assert!(
        r.velocity_error_high_speed.rms < 0.05,
        "{:?}",
        r.velocity_error_high_speed
    );
    assert!(
        r.spin_error_high_speed.rms < 15.0,
        "{:?}",
        r.spin_error_high_speed
    );
    assert!(
        (0.5..2.0).contains(&r.state_nees),
        "state NEES {}",
        r.state_nees
    );
    let c = r.counters;
    assert_eq!(c.fused + c.initializing + c.total_rejected(), c.received);
    assert_eq!(c.tracks, 24);
}

#[test]
fn the_wide_camera_alone_still_predicts_the_interception() {
    let r = run(Cameras::WideOnly, 24, 8);
    let lead100 = &r.leads[2];
    assert!(lead100.valid_fraction >= 0.9, "{lead100:?}");
    assert!(lead100.position_error.median < 0.01, "{lead100:?}");
    assert_eq!(r.spin_error_high_speed.count, 0);
}
