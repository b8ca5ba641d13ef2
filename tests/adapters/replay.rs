//! Replay of MCAP bags through the node's code path: determinism, what the output holds, and
//! bad input (wrong type, missing topic, truncated file, non-finite values, foreign frames,
//! interruption), each with a clear outcome and a properly finished output.
#![cfg(feature = "bag")]
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    reason = "test code: fail loudly"
)]

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};

use ttball::bag::record::write_session;
use ttball::bag::replay::{DETECTION_TYPE, ReplayError, STATE_TYPE, replay};
use ttball::bag::{BagWriter, ChunkDamage, Damage, decode, read_bag_file};
use ttball::config::Config;
use ttball::eval::sim::{Cameras, SimOptions, simulate};
use ttball::online::estimator::Rejection;
use ttball::ros::msgs::convert::detection_to_msg;
use ttball::ros::msgs::ttball_msgs::msg::{BallDetection, BallState, InterceptPrediction};

pub(crate) fn dir(name: &str) -> PathBuf {
    let d = Path::new(env!("CARGO_TARGET_TMPDIR"))
        .join(format!("replay-{}-{name}", std::process::id()));
    std::fs::create_dir_all(&d).unwrap();
    d
}

fn simulated_bag(path: &Path, shots: usize) -> ttball::eval::sim::Session {
    let config = Config::default();
    let session = simulate(
        &config,
        &SimOptions {
            cameras: Cameras::WideAndHighSpeed,
            shots,
            seed: 11,
            ..SimOptions::default()
        },
    )
    .unwrap();
    write_session(&session, &config, path, true).unwrap();
    session
}

pub(crate) fn run(
    input: &Path,
    output: &Path,
) -> Result<ttball::bag::replay::ReplaySummary, ReplayError> {
    replay(
        input,
        output,
        &Config::default(),
        &mut |_, _| {},
        &AtomicBool::new(false),
    )
}

#[test]
fn replays_are_byte_identical_and_hold_every_output_topic() {
    let d = dir("determinism");
    let input = d.join("sim.mcap");
    let session = simulated_bag(&input, 3);
    let (a, b) = (d.join("a.mcap"), d.join("b.mcap"));
    let summary = run(&input, &a).unwrap();
    run(&input, &b).unwrap();
    assert_eq!(std::fs::read(&a).unwrap(), std::fs::read(&b).unwrap());

    assert_eq!(summary.detections, session.stream.len() as u64);
    let c = summary.counters;
    assert_eq!(
        c.fused + c.initializing + c.total_rejected(),
        summary.detections
    );
    assert_eq!(c.tracks, 3);
    let accuracy = summary.accuracy.expect("the simulated bag carries truth");
    // Scored in the one pass: every detection against the true state that follows it.
    assert_eq!(accuracy.shots, 3);
    assert_eq!(accuracy.detections, session.stream.len());
    assert!(
        accuracy.leads[2].position_error.rms < 0.005,
        "{:?}",
        accuracy.leads[2]
    );

    let out = read_bag_file(&a).unwrap();
    assert!(out.damage.is_empty());
    let count = |topic: &str| {
        let ch = out.channel(topic).unwrap_or_else(|| panic!("no {topic}"));
        out.messages.iter().filter(|m| m.channel == ch).count()
    };
    assert_eq!(count("/ball/detections"), session.stream.len());
    assert_eq!(count("/ball/truth"), session.stream.len());
    let states = count("/ball/state");
    assert!(states > session.stream.len() - 20, "{states} states");
    assert_eq!(
        count("/ball/intercept"),
        states - 3 * 2,
        "no intercept while initialising"
    );
    let trajectories = count("/ball/trajectory");
    assert!(
        trajectories > 20 && trajectories < states / 5,
        "{trajectories}"
    );
    assert_eq!(count("/ball/markers"), trajectories);
    let state_channel = out.channel("/ball/state").unwrap();
    assert_eq!(out.channels[state_channel].schema_name, STATE_TYPE);
    // Output messages carry the log time of the detection that produced them.
    let detection_times: std::collections::BTreeSet<u64> = out
        .messages
        .iter()
        .filter(|m| m.channel == out.channel("/ball/detections").unwrap())
        .map(|m| m.log_time)
        .collect();
    for m in out.messages.iter().filter(|m| m.channel == state_channel) {
        assert!(detection_times.contains(&m.log_time));
        let state: BallState = decode(&m.data).unwrap();
        assert_eq!(state.header.frame_id, "table");
    }
    let intercept_channel = out.channel("/ball/intercept").unwrap();
    let valid = out
        .messages
        .iter()
        .filter(|m| m.channel == intercept_channel)
        .filter(|m| decode::<InterceptPrediction>(&m.data).unwrap().valid)
        .count();
    assert!(valid > states / 2);
}

fn write_detections(path: &Path, topic_type: &str, detections: &[BallDetection]) {
    let mut w = BagWriter::create(path).unwrap();
    let ch = w.channel("/ball/detections", topic_type).unwrap();
    for (i, d) in detections.iter().enumerate() {
        w.write(ch, topic_type, 1_000_000_000 + i as u64 * 1_000_000, d)
            .unwrap();
    }
    w.finish().unwrap();
}

#[test]
fn a_detection_topic_of_another_type_is_an_error_naming_it() {
    let d = dir("wrong-type");
    let input = d.join("in.mcap");
    let mut w = BagWriter::create(&input).unwrap();
    let ch = w.channel("/ball/detections", STATE_TYPE).unwrap();
    w.write(ch, STATE_TYPE, 1, &BallState::default()).unwrap();
    w.finish().unwrap();
    let err = run(&input, &d.join("out.mcap")).unwrap_err();
    let text = err.to_string();
    assert!(matches!(err, ReplayError::WrongType { .. }), "{text}");
    assert!(
        text.contains("/ball/detections") && text.contains(STATE_TYPE),
        "{text}"
    );
}

#[test]
fn a_bag_without_the_detection_topic_lists_what_it_has() {
    let d = dir("no-topic");
    let input = d.join("in.mcap");
    let mut w = BagWriter::create(&input).unwrap();
    let ch = w.channel("/camera/ball", DETECTION_TYPE).unwrap();
    w.write(ch, DETECTION_TYPE, 1, &BallDetection::default())
        .unwrap();
    w.finish().unwrap();
    let text = run(&input, &d.join("out.mcap")).unwrap_err().to_string();
    assert!(
        text.contains("no topic `/ball/detections`") && text.contains("/camera/ball"),
        "{text}"
    );
    assert!(
        text.contains("topics.detections"),
        "says what to do: {text}"
    );
}

#[test]
fn a_truncated_bag_is_replayed_as_far_as_it_goes_and_the_output_is_finished() {
    let d = dir("truncated");
    let input = d.join("sim.mcap");
    simulated_bag(&input, 2);
    let bytes = std::fs::read(&input).unwrap();
    let cut = d.join("cut.mcap");
    std::fs::write(&cut, &bytes[..bytes.len() * 6 / 10]).unwrap();
    let output = d.join("out.mcap");
    let summary = run(&cut, &output).unwrap();
    assert!(
        matches!(
            summary.damage.as_slice(),
            [.., Damage::Stopped { .. } | Damage::CutChunk { .. }]
        ),
        "{:?}",
        summary.damage
    );
    assert!(
        summary.detections > 100,
        "{} detections read",
        summary.detections
    );
    let out = read_bag_file(&output).unwrap();
    assert!(out.damage.is_empty(), "the output is a finished file");
    assert!(out.channel("/ball/state").is_some());
    // Not MCAP at all: a clear error naming the file.
    let junk = d.join("junk.mcap");
    std::fs::write(&junk, b"this is not a bag").unwrap();
    let text = run(&junk, &d.join("junk-out.mcap"))
        .unwrap_err()
        .to_string();
    assert!(
        text.contains("junk.mcap") && text.contains("not an MCAP file"),
        "{text}"
    );
    let missing = run(&d.join("missing.mcap"), &d.join("x.mcap"))
        .unwrap_err()
        .to_string();
    assert!(missing.contains("missing.mcap"), "{missing}");
}

/// An empty file, and a finished bag with nothing in it: clear errors naming the file.
#[test]
fn an_empty_bag_is_a_clear_error() {
    let d = dir("empty");
    let empty = d.join("empty.mcap");
    std::fs::write(&empty, b"").unwrap();
    let text = run(&empty, &d.join("out.mcap")).unwrap_err().to_string();
    assert!(
        text.contains("empty.mcap") && text.contains("empty (0 bytes)"),
        "{text}"
    );
    let nothing = d.join("nothing.mcap");
    BagWriter::create(&nothing).unwrap().finish().unwrap();
    let text = run(&nothing, &d.join("out.mcap")).unwrap_err().to_string();
    assert!(
        text.contains("nothing.mcap") && text.contains("topics in the bag: none"),
        "{text}"
    );
    assert!(
        !d.join("out.mcap").exists(),
        "nothing is written for a refused bag"
    );
}

/// Bytes overwritten in the middle of a bag: the chunk they hit fails its CRC and is skipped
/// (said in the summary), every other chunk is replayed, no garbage is decoded, and the output
/// is finished.
#[test]
fn a_corrupted_chunk_is_skipped_and_the_rest_replayed() {
    let d = dir("corrupt-chunk");
    let input = d.join("sim.mcap");
    let session = simulated_bag(&input, 6);
    let mut bytes = std::fs::read(&input).unwrap();
    let middle = bytes.len() / 2;
    for b in &mut bytes[middle..middle + 64] {
        *b ^= 0x5a;
    }
    let corrupt = d.join("corrupt.mcap");
    std::fs::write(&corrupt, &bytes).unwrap();
    let output = d.join("out.mcap");
    let summary = run(&corrupt, &output).unwrap();
    assert!(
        // Caught by the chunk's CRC, or before it by the decompressor, as the bytes fall.
        summary.damage.iter().any(|d| matches!(
            d,
            Damage::ChunkSkipped {
                why: ChunkDamage::CrcMismatch | ChunkDamage::Decompression { .. },
                ..
            }
        )),
        "{:?}",
        summary.damage
    );
    let total = session.stream.len() as u64;
    assert!(
        summary.detections > total / 3 && summary.detections < total,
        "{} of {total} detections read",
        summary.detections
    );
    assert_eq!(summary.undecodable, 0);
    let c = summary.counters;
    assert_eq!(c.fused + c.initializing + c.total_rejected(), c.received);
    let out = read_bag_file(&output).unwrap();
    assert!(out.damage.is_empty(), "the output is a finished file");
}

/// A detection topic with the right type name but other fields: refused, naming the file, the
/// topic and the fields, before anything is written.
#[test]
fn a_detection_schema_with_other_fields_is_an_error_naming_them() {
    let d = dir("schema-mismatch");
    let input = d.join("in.mcap");
    let mut w = BagWriter::create(&input).unwrap();
    let ch = w
        .add_channel(&ttball::bag::ChannelInfo {
            topic: "/ball/detections".into(),
            schema_name: DETECTION_TYPE.into(),
            schema_encoding: "ros2msg".into(),
            schema_data: b"std_msgs/Header header\nfloat32 x\nfloat32 y\n".to_vec(),
            message_encoding: "cdr".into(),
            metadata: Default::default(),
        })
        .unwrap();
    w.write_raw(ch, 1, 1, &[0, 1, 0, 0, 0, 0, 0, 0]).unwrap();
    w.finish().unwrap();
    let output = d.join("out.mcap");
    let err = run(&input, &output).unwrap_err();
    let text = err.to_string();
    assert!(matches!(err, ReplayError::SchemaMismatch { .. }), "{text}");
    assert!(
        text.contains("in.mcap") && text.contains("/ball/detections") && text.contains("float32 x"),
        "{text}"
    );
    assert!(!output.exists());
    // A bag recorded with ttball's own definition (comments and all) passes the check.
    let ok = d.join("ok.mcap");
    let mut w = BagWriter::create(&ok).unwrap();
    let ch = w.channel("/ball/detections", DETECTION_TYPE).unwrap();
    w.write(ch, DETECTION_TYPE, 1, &BallDetection::default())
        .unwrap();
    w.finish().unwrap();
    assert!(run(&ok, &d.join("ok-out.mcap")).is_ok());
}

#[test]
fn bad_detections_are_counted_by_reason() {
    let d = dir("bad-detections");
    let session = simulate(
        &Config::default(),
        &SimOptions {
            shots: 1,
            seed: 3,
            ..SimOptions::default()
        },
    )
    .unwrap();
    let mut msgs: Vec<BallDetection> = session
        .stream
        .iter()
        .map(|s| detection_to_msg(&s.detection))
        .collect();
    msgs[50].position.x = f64::NAN;
    msgs[60].header.frame_id = "camera_left".into();
    msgs[70].confidence = 2.0;
    let input = d.join("in.mcap");
    write_detections(&input, DETECTION_TYPE, &msgs);
    let summary = run(&input, &d.join("out.mcap")).unwrap();
    let c = summary.counters;
    assert_eq!(c.rejected(Rejection::NonFinite), 1);
    assert_eq!(c.rejected(Rejection::UnknownFrame), 1);
    assert_eq!(c.rejected(Rejection::BadConfidence), 1);
    assert_eq!(c.received, msgs.len() as u64);
    assert_eq!(c.fused + c.initializing + c.total_rejected(), c.received);
}

#[test]
fn an_interrupted_replay_finishes_its_output() {
    let d = dir("interrupted");
    let input = d.join("sim.mcap");
    simulated_bag(&input, 3);
    let output = d.join("out.mcap");
    let cancel = AtomicBool::new(false);
    let summary = replay(
        &input,
        &output,
        &Config::default(),
        &mut |done, _| {
            if done >= 1024 {
                cancel.store(true, Ordering::Relaxed);
            }
        },
        &cancel,
    )
    .unwrap();
    assert!(summary.interrupted);
    assert!(summary.detections >= 1024 && summary.detections < 1200);
    let out = read_bag_file(&output).unwrap();
    assert!(out.damage.is_empty());
}

#[test]
fn a_rosbag2_directory_is_read_as_one_bag() {
    let d = dir("rosbag2");
    let bag_dir = d.join("rally");
    std::fs::create_dir_all(&bag_dir).unwrap();
    std::fs::write(
        bag_dir.join("metadata.yaml"),
        "rosbag2_bagfile_information: {}\n",
    )
    .unwrap();
    let session = simulated_bag(&bag_dir.join("rally_0.mcap"), 1);
    let summary = run(&bag_dir, &d.join("out.mcap")).unwrap();
    assert_eq!(summary.detections, session.stream.len() as u64);
    assert_eq!(summary.counters.tracks, 1);
}

/// The bags of `tests/data/rosbag2_bags/`, written by rosbag2 itself.
fn rosbag2_bag(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data/rosbag2_bags")
        .join(name)
}

/// Every bag rosbag2 wrote, in MCAP and in sqlite3 storage (one file, five splits with
/// metadata.yaml, three without, service events; sqlite3 schemas from before Humble to Jazzy's) is
/// read whole and undamaged, each topic with as many messages as its metadata.yaml counts
/// (`multiple_files` has none: 3177, as Python's `mcap` reads it), in log-time order; and the
/// replay refuses each (no detection topic) naming the topics it has.
#[test]
fn bags_written_by_rosbag2_are_read_whole_and_in_order() {
    for (name, total) in [
        ("talker", 20),
        ("wbag", 6074),
        ("multiple_files", 3177),
        ("cdr_test", 7),
        ("bag_with_topics_and_service_events", 10),
        ("sqlite3/talker", 20),
        ("sqlite3/wbag", 6074),
        ("sqlite3/cdr_test", 7),
        ("sqlite3/bag_with_topics_and_service_events", 10),
    ] {
        let path = rosbag2_bag(name);
        let bag = read_bag_file(&path).unwrap();
        assert!(bag.damage.is_empty(), "{name}: {:?}", bag.damage);
        assert_eq!(bag.messages.len(), total, "{name}");
        assert!(bag.messages.is_sorted_by_key(|m| m.log_time), "{name}");
        if let Ok(text) = std::fs::read_to_string(path.join("metadata.yaml")) {
            let metadata: serde_norway::Value = serde_norway::from_str(&text).unwrap();
            let info = &metadata["rosbag2_bagfile_information"];
            assert_eq!(info["message_count"].as_u64(), Some(total as u64), "{name}");
            for topic in info["topics_with_message_count"].as_sequence().unwrap() {
                let topic_name = topic["topic_metadata"]["name"].as_str().unwrap();
                let counted = bag.channel(topic_name).map_or(0, |c| {
                    bag.messages.iter().filter(|m| m.channel == c).count()
                });
                assert_eq!(
                    Some(counted as u64),
                    topic["message_count"].as_u64(),
                    "{name} {topic_name}"
                );
            }
        }
        let output = dir("rosbag2-refused").join(format!("{}.mcap", name.replace('/', "_")));
        let refused = run(&path, &output).unwrap_err().to_string();
        assert!(
            refused.contains("no topic `/ball/detections` (topics in the bag: ")
                && refused.contains("-p topics.detections:="),
            "{refused}"
        );
    }
}

/// Splits are read in their recording order: metadata.yaml's `relative_file_paths` when it has
/// them, else by split number (`x_2` before `x_10`, which name order would swap: with more
/// messages in the late splits than the reorder window holds, the stream would come out of
/// order). A listed file that is missing, or compressed per file, is a clear error.
#[test]
fn split_bags_are_read_in_recording_order() {
    let d = dir("splits").join("many");
    std::fs::create_dir_all(&d).unwrap();
    let per_file = 2500u64;
    for split in 0..12u64 {
        let mut w = BagWriter::create(&d.join(format!("many_{split}.mcap"))).unwrap();
        let ch = w.channel("/ball/detections", DETECTION_TYPE).unwrap();
        for i in 0..per_file {
            let t = 1_000 + split * per_file + i;
            w.write(ch, DETECTION_TYPE, t, &BallDetection::default())
                .unwrap();
        }
        w.finish().unwrap();
    }
    let names = |files: Vec<PathBuf>| -> Vec<String> {
        files
            .iter()
            .map(|f| f.file_name().unwrap().to_string_lossy().into_owned())
            .collect()
    };
    let order = names(ttball::bag::rosbag2_files(&d).unwrap());
    assert_eq!(order[..3], ["many_0.mcap", "many_1.mcap", "many_2.mcap"]);
    assert_eq!(order[11], "many_11.mcap");
    let mut reader = ttball::bag::BagReader::open(&d).unwrap();
    let mut times = Vec::new();
    while let Some(m) = reader.next_message() {
        times.push(m.log_time);
    }
    assert_eq!(times.len() as u64, 12 * per_file);
    assert!(times.is_sorted(), "split order broken");

    // metadata.yaml's order rules, and what it lists must be there.
    std::fs::write(
        d.join("metadata.yaml"),
        "rosbag2_bagfile_information:\n  relative_file_paths:\n  - many_1.mcap\n  - many_0.mcap\n",
    )
    .unwrap();
    assert_eq!(
        names(ttball::bag::rosbag2_files(&d).unwrap()),
        ["many_1.mcap", "many_0.mcap"]
    );
    for (listed, says) in [
        ("many_12.mcap", "lists `many_12.mcap`, which is missing"),
        ("many_0.mcap.zstd", "`ros2 bag decompress` it first"),
    ] {
        std::fs::write(
            d.join("metadata.yaml"),
            format!("rosbag2_bagfile_information:\n  relative_file_paths:\n  - {listed}\n"),
        )
        .unwrap();
        let error = ttball::bag::rosbag2_files(&d).unwrap_err().to_string();
        assert!(error.contains(says), "{error}");
    }
}

/// Every channel ttball writes carries the QoS its publisher offers as rosbag2 records it, so
/// that `ros2 bag play` republishes detections best effort and the outputs reliable.
#[test]
fn written_channels_carry_their_offered_qos() {
    let d = dir("qos");
    let input = d.join("in.mcap");
    simulated_bag(&input, 1);
    let output = d.join("out.mcap");
    run(&input, &output).unwrap();
    let bag = read_bag_file(&output).unwrap();
    for channel in &bag.channels {
        let profiles: serde_norway::Value =
            serde_norway::from_str(&channel.metadata["offered_qos_profiles"]).unwrap();
        let profile = &profiles[0];
        let (reliability, durability) = if channel.topic == "/ball/detections" {
            (2, 2)
        } else {
            (1, 2)
        };
        assert_eq!(
            (
                profile["reliability"].as_u64(),
                profile["durability"].as_u64()
            ),
            (Some(reliability), Some(durability)),
            "{}",
            channel.topic
        );
        assert_eq!(profile["liveliness"].as_u64(), Some(1));
    }
}
