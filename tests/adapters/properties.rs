//! Properties over random input: the filter's covariance stays symmetric positive definite
//! whatever the detections, decoding arbitrary bytes as a message never panics, and neither does
//! reading arbitrary bytes, or a real bag with bytes flipped, cut or inserted, as MCAP; messages
//! written in any order of log time are read in log-time order, file order among equal times.
//!
//! `PROPTEST_CASES=N cargo test --release --test adapters properties::` runs N cases of each (the longer
//! fuzzing run in the README).
#![cfg(feature = "bag")]
#![allow(clippy::unwrap_used, reason = "test code: fail loudly")]

use nalgebra::{Matrix3, Vector3};
use proptest::prelude::*;
use ttball::bag::{BagReader, decode};
use ttball::config::Config;
use ttball::eval::sim::{SimOptions, simulate};
use ttball::model::detection::Detection;
use ttball::online::estimator::Estimator;
use ttball::ros::msgs::ttball_msgs::msg::{BallDetection, BallState, PredictedTrajectory};

/// A real stream (one simulated shot, both cameras) to corrupt.
fn stream() -> &'static [Detection] {
    static STREAM: std::sync::OnceLock<Vec<Detection>> = std::sync::OnceLock::new();
    STREAM.get_or_init(|| {
        let session = simulate(
            &Config::default(),
            &SimOptions {
                shots: 1,
                seed: 21,
                ..SimOptions::default()
            },
        )
        .unwrap();
        session.stream.iter().map(|s| s.detection).collect()
    })
}

/// A small real bag (one simulated shot with its truth, as `ttball simulate` writes it).
fn small_bag() -> &'static [u8] {
    static BAG: std::sync::OnceLock<Vec<u8>> = std::sync::OnceLock::new();
    BAG.get_or_init(|| {
        let config = Config::default();
        let session = simulate(
            &config,
            &SimOptions {
                shots: 1,
                seed: 22,
                ..SimOptions::default()
            },
        )
        .unwrap();
        let path = std::path::Path::new(env!("CARGO_TARGET_TMPDIR"))
            .join(format!("props-{}.mcap", std::process::id()));
        ttball::bag::record::write_session(&session, &config, &path, true).unwrap();
        let bytes = std::fs::read(&path).unwrap();
        let _ = std::fs::remove_file(&path);
        bytes
    })
}

/// Reads every message of `bytes` as an MCAP bag; the number read.
fn read_all(bytes: Vec<u8>) -> usize {
    let Ok(mut reader) = BagReader::from_bytes(bytes, std::path::Path::new("fuzz.mcap")) else {
        return 0;
    };
    let mut n = 0;
    while reader.next_message().is_some() {
        n += 1;
    }
    let _ = reader.damage();
    n
}

/// A damage done to a bag's bytes.
#[derive(Debug, Clone)]
enum Damage {
    /// XOR a byte at a relative position with a mask.
    Flip(f64, u8),
    /// Cut the file at a relative position.
    Cut(f64),
    /// Insert bytes at a relative position.
    Insert(f64, Vec<u8>),
}

fn damage() -> impl Strategy<Value = Damage> {
    prop_oneof![
        (0.0f64..1.0, 1u8..=255).prop_map(|(at, mask)| Damage::Flip(at, mask)),
        (0.0f64..1.0).prop_map(Damage::Cut),
        (0.0f64..1.0, prop::collection::vec(any::<u8>(), 1..16))
            .prop_map(|(at, bytes)| Damage::Insert(at, bytes)),
    ]
}

/// One corruption of one detection of the stream.
#[derive(Debug, Clone)]
enum Corruption {
    /// Move it by this much [m].
    Displace([f64; 3]),
    /// Shift its stamp [ns]: out of order, duplicates, a little ahead, or far off (a glitched
    /// clock, up to a day either way).
    Restamp(i64),
    /// A measured spin [rad/s] with this covariance scale (all zero: a placeholder).
    Spin([f64; 3], f64),
    /// Its own position covariance: a random symmetric matrix (maybe not positive definite).
    Covariance([f64; 6]),
    /// A non-finite coordinate.
    NotFinite,
    /// A confidence.
    Confidence(f32),
}

fn corruption() -> impl Strategy<Value = Corruption> {
    prop_oneof![
        prop::array::uniform3(-0.5f64..0.5).prop_map(Corruption::Displace),
        (-40_000_000i64..40_000_000).prop_map(Corruption::Restamp),
        (-86_400_000_000_000i64..86_400_000_000_000).prop_map(Corruption::Restamp),
        prop::array::uniform3(-200.0f64..200.0).prop_map(Corruption::Displace),
        (prop::array::uniform3(-700.0f64..700.0), 1e-3f64..1e4)
            .prop_map(|(w, s)| Corruption::Spin(w, s)),
        Just(Corruption::Spin([0.0; 3], 1.0)),
        prop::array::uniform6(-1e-4f64..1e-4).prop_map(Corruption::Covariance),
        Just(Corruption::NotFinite),
        (-1.0f32..2.0).prop_map(Corruption::Confidence),
    ]
}

fn apply(d: &mut Detection, c: &Corruption) {
    match c {
        Corruption::Displace(v) => d.position += Vector3::from(*v),
        Corruption::Restamp(dt) => d.stamp += dt,
        Corruption::Spin(w, s) => {
            d.spin = Some(Vector3::from(*w));
            d.spin_covariance = Some(Matrix3::identity() * *s);
        }
        Corruption::Covariance(c) => {
            d.position_covariance = Some(Matrix3::new(
                c[0], c[1], c[2], c[1], c[3], c[4], c[2], c[4], c[5],
            ));
        }
        Corruption::NotFinite => d.position.y = f64::NAN,
        Corruption::Confidence(x) => d.confidence = *x,
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 64, ..ProptestConfig::default() })]

    #[test]
    fn the_covariance_stays_symmetric_positive_definite(
        corruptions in prop::collection::vec((any::<prop::sample::Index>(), corruption()), 0..60)
    ) {
        let mut detections = stream().to_vec();
        for (index, c) in &corruptions {
            let i = index.index(detections.len());
            apply(&mut detections[i], c);
        }
        let mut estimator = Estimator::new(&Config::default());
        let mut estimates = 0;
        for d in &detections {
            if let Some(e) = estimator.handle(d).estimate {
                estimates += 1;
                let p = e.covariance;
                prop_assert!(p.iter().all(|v| v.is_finite()));
                prop_assert!((p - p.transpose()).abs().max() <= 1e-9 * p.abs().max().max(1e-300));
                prop_assert!(p.cholesky().is_some(), "not positive definite: {p}");
                prop_assert!(e.state.is_finite());
            }
        }
        prop_assert!(estimates > detections.len() / 2, "{estimates} estimates");
        let c = estimator.counters();
        prop_assert_eq!(c.fused + c.initializing + c.total_rejected(), c.received);
    }

    #[test]
    fn reading_arbitrary_bytes_as_mcap_never_panics(
        bytes in prop::collection::vec(any::<u8>(), 0..2000),
        with_magic in any::<bool>(),
    ) {
        let mut input = if with_magic { b"\x89MCAP0\r\n".to_vec() } else { Vec::new() };
        input.extend_from_slice(&bytes);
        read_all(input);
    }

    #[test]
    fn reading_a_damaged_bag_never_panics(damages in prop::collection::vec(damage(), 1..8)) {
        let original = small_bag();
        let mut bytes = original.to_vec();
        for d in &damages {
            let at = |r: f64, len: usize| ((r * len as f64) as usize).min(len.saturating_sub(1));
            match d {
                Damage::Flip(r, mask) => {
                    let i = at(*r, bytes.len());
                    if let Some(b) = bytes.get_mut(i) {
                        *b ^= mask;
                    }
                }
                Damage::Cut(r) => bytes.truncate(at(*r, bytes.len())),
                Damage::Insert(r, extra) => {
                    let i = at(*r, bytes.len());
                    bytes.splice(i..i, extra.iter().copied());
                }
            }
        }
        static TOTAL: std::sync::OnceLock<usize> = std::sync::OnceLock::new();
        let total = *TOTAL.get_or_init(|| read_all(original.to_vec()));
        let read = read_all(bytes);
        // Never more than the bag holds, give or take a flipped length that splits a record.
        prop_assert!(read <= total + 8, "{read} of {total}");
    }

    #[test]
    fn messages_are_read_in_log_time_order_whatever_order_they_were_written_in(
        steps in prop::collection::vec(-3i64..6, 1..600),
    ) {
        // Log times that mostly rise (as a recorder writes them) with steps back and repeats.
        let mut t = 1_000i64;
        let written: Vec<(u64, u16)> = steps
            .iter()
            .enumerate()
            .map(|(i, step)| {
                t = (t + step).max(0);
                (t as u64, i as u16)
            })
            .collect();
        let path = std::path::Path::new(env!("CARGO_TARGET_TMPDIR"))
            .join(format!("order-{}.mcap", std::process::id()));
        let mut writer = ttball::bag::BagWriter::create(&path).unwrap();
        let channel = writer.channel("/ball/detections", "ttball_msgs/msg/BallDetection").unwrap();
        for (log_time, i) in &written {
            writer.write_raw(channel, *log_time, *log_time, &i.to_le_bytes()).unwrap();
        }
        writer.finish().unwrap();
        let mut reader = BagReader::open(&path).unwrap();
        let mut read = Vec::new();
        while let Some(m) = reader.next_message() {
            read.push((m.log_time, u16::from_le_bytes([m.data[0], m.data[1]])));
        }
        let _ = std::fs::remove_file(&path);
        let mut expected = written;
        expected.sort_by_key(|(log_time, _)| *log_time); // stable: file order among equal times
        prop_assert_eq!(read, expected);
    }

    #[test]
    fn decoding_arbitrary_bytes_never_panics(bytes in prop::collection::vec(any::<u8>(), 0..600)) {
        let _ = decode::<BallDetection>(&bytes);
        let _ = decode::<BallState>(&bytes);
        let _ = decode::<PredictedTrajectory>(&bytes);
    }
}
