//! `ttball smooth` on the sample bags: one smoothed state per detection the estimator took, at
//! that detection's stamp and on its track, close to the truth; deterministic; bad usage gets
//! a clear error.
#![cfg(feature = "cli")]
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    reason = "test code: fail loudly"
)]

use crate::common;

use std::collections::BTreeMap;

use common::{ok, run, scratch};
use ttball::bag::{decode, read_bag_file};
use ttball::ros::msgs::ttball_msgs::msg::{BallDetection, BallState, InterceptPrediction};

/// (stamp in ns, track) of every message of `topic`.
fn states(path: &std::path::Path, topic: &str) -> Vec<(i64, u32, BallState)> {
    let bag = read_bag_file(path).expect("bag");
    let channel = bag.channel(topic).expect("topic");
    bag.messages
        .iter()
        .filter(|m| m.channel == channel)
        .map(|m| {
            let s: BallState = decode(&m.data).expect("state");
            let stamp =
                i64::from(s.header.stamp.sec) * 1_000_000_000 + i64::from(s.header.stamp.nanosec);
            (stamp, s.track_id, s)
        })
        .collect()
}

#[test]
fn smooths_every_fused_detection_on_its_track_deterministically() {
    let d = scratch("smooth");
    let (a, b, replayed) = (d.join("a.mcap"), d.join("b.mcap"), d.join("r.mcap"));
    let s = |p: &std::path::Path| p.to_str().unwrap().to_owned();
    let input = "bags/sim_rally_2cams.mcap";
    let summary = ok(&["smooth", input, "--output", &s(&a)]);
    ok(&["smooth", input, "--output", &s(&b)]);
    assert_eq!(std::fs::read(&a).unwrap(), std::fs::read(&b).unwrap());
    assert!(summary.contains("8 flights fitted"), "{summary}");
    assert!(summary.contains("against the bag's truth"), "{summary}");

    // The input's detections are all there, unchanged.
    let original = read_bag_file(std::path::Path::new(input)).unwrap();
    let smoothed_bag = read_bag_file(&a).unwrap();
    let topic = |bag: &ttball::bag::BagContents| {
        let c = bag.channel("/ball/detections").unwrap();
        bag.messages
            .iter()
            .filter(|m| m.channel == c)
            .map(|m| m.data.clone())
            .collect::<Vec<_>>()
    };
    assert_eq!(topic(&original), topic(&smoothed_bag));
    let detection_stamps: Vec<i64> = topic(&original)
        .iter()
        .map(|data| {
            let d: BallDetection = decode(data).unwrap();
            i64::from(d.header.stamp.sec) * 1_000_000_000 + i64::from(d.header.stamp.nanosec)
        })
        .collect();

    // One smoothed state per detection the online filter took, on the track it took it into.
    ok(&["replay", input, "--output", &s(&replayed)]);
    let online: BTreeMap<i64, u32> = states(&replayed, "/ball/state")
        .into_iter()
        .map(|(stamp, track, _)| (stamp, track))
        .collect();
    let smoothed = states(&a, "/ball/smoothed");
    let truth: BTreeMap<i64, BallState> = states(&a, "/ball/truth")
        .into_iter()
        .map(|(stamp, _, s)| (stamp, s))
        .collect();
    assert!(smoothed.len() >= detection_stamps.len() * 98 / 100);
    // Each shot's true bounce: within 2 ms of it a velocity is the one before or the one after
    // by a hair of timing, and is left out.
    let bag = read_bag_file(&a).unwrap();
    let events = bag.channel("/ball/truth/intercept").unwrap();
    let bounces: Vec<i64> = bag
        .messages
        .iter()
        .filter(|m| m.channel == events)
        .map(|m| {
            let i: InterceptPrediction = decode(&m.data).unwrap();
            i64::from(i.bounce_stamp.sec) * 1_000_000_000 + i64::from(i.bounce_stamp.nanosec)
        })
        .collect();
    let (mut velocity, mut n, mut at_bounce) = (0.0, 0, 0);
    for (stamp, track, state) in &smoothed {
        assert!(detection_stamps.contains(stamp));
        if let Some(online_track) = online.get(stamp) {
            assert_eq!(online_track, track, "at {stamp}");
        }
        if bounces.iter().any(|b| (stamp - b).abs() <= 2_000_000) {
            at_bounce += 1;
            continue;
        }
        let t = &truth[stamp];
        let dv = [
            state.velocity.x - t.velocity.x,
            state.velocity.y - t.velocity.y,
            state.velocity.z - t.velocity.z,
        ];
        velocity += dv.iter().map(|v| v * v).sum::<f64>();
        n += 1;
        // A covariance with positive variances on its diagonal.
        assert!((0..9).all(|k| state.covariance[k * 10] > 0.0));
    }
    let rms = (velocity / f64::from(n)).sqrt();
    assert!(rms < 0.005, "smoothed velocity RMS {rms} m/s");
    assert!(at_bounce < n / 50, "{at_bounce} of {n} at a bounce");
    assert!(
        summary.contains(&format!("{at_bounce} within 2 ms of a bounce left out")),
        "{summary}"
    );
}

#[test]
fn refuses_to_overwrite_its_input_and_explains_a_missing_bag() {
    let same = run(&[
        "smooth",
        "bags/sim_rally_wide.mcap",
        "--output",
        "bags/sim_rally_wide.mcap",
    ]);
    assert_eq!(same.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&same.stderr).contains("would overwrite its input"));

    let d = scratch("smooth-missing");
    let missing = run(&[
        "smooth",
        "no/such.mcap",
        "--output",
        d.join("o.mcap").to_str().unwrap(),
    ]);
    assert_eq!(missing.status.code(), Some(1));
    let err = String::from_utf8_lossy(&missing.stderr);
    assert!(err.contains("no/such.mcap"), "{err}");
}
