//! rosbag2's sqlite3 storage (`.db3`): ttball's detections written in rosbag2's own schema
//! (Humble's and Jazzy's, `rosbag2_storage_default_plugins/src/.../sqlite_storage.cpp`) replay to
//! the same output as the same detections in MCAP; a damaged, cut or locked database is a
//! clear error or gives what it holds, never a panic. rosbag2's own `.db3` bags are read in
//! `replay::bags_written_by_rosbag2_are_read_whole_and_in_order`.
#![cfg(feature = "bag")]
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    reason = "test code: fail loudly"
)]

use std::path::{Path, PathBuf};

use rusqlite::Connection;
use ttball::bag::{BagContents, read_bag_file};

use crate::replay::{dir, run};

/// The schemas rosbag2 has written: Humble's (version 3: QoS profiles, the distribution) and
/// Jazzy's (version 4: each type's definition and hash too).
#[derive(Clone, Copy)]
enum Schema {
    Humble,
    Jazzy,
}

/// Writes `bag`'s messages as a rosbag2 sqlite3 bag in `dir`: `splits` files of consecutive
/// messages and a `metadata.yaml` listing them, as `ros2 bag record -s sqlite3` does.
fn write_db3(bag: &BagContents, dir: &Path, schema: Schema, splits: usize) {
    let per_file = bag.messages.len().div_ceil(splits);
    let mut names = Vec::new();
    for (split, messages) in bag.messages.chunks(per_file).enumerate() {
        let name = format!("bag_{split}.db3");
        let db = Connection::open(dir.join(&name)).unwrap();
        let hash = match schema {
            Schema::Humble => "",
            Schema::Jazzy => ",type_description_hash TEXT NOT NULL",
        };
        db.execute_batch(&format!(
            "CREATE TABLE schema(schema_version INTEGER PRIMARY KEY,ros_distro TEXT NOT NULL);
             CREATE TABLE metadata(id INTEGER PRIMARY KEY,metadata_version INTEGER NOT NULL,metadata TEXT NOT NULL);
             CREATE TABLE topics(id INTEGER PRIMARY KEY,name TEXT NOT NULL,type TEXT NOT NULL,serialization_format TEXT NOT NULL,offered_qos_profiles TEXT NOT NULL{hash});
             CREATE TABLE messages(id INTEGER PRIMARY KEY,topic_id INTEGER NOT NULL,timestamp INTEGER NOT NULL, data BLOB NOT NULL);
             CREATE INDEX timestamp_idx ON messages (timestamp ASC);"
        ))
        .unwrap();
        match schema {
            Schema::Humble => {
                db.execute("INSERT INTO schema VALUES (3, 'humble')", ())
                    .unwrap();
            }
            Schema::Jazzy => {
                db.execute_batch(
                    "INSERT INTO schema VALUES (4, 'jazzy');
                     CREATE TABLE message_definitions(id INTEGER PRIMARY KEY,topic_type TEXT NOT NULL,encoding TEXT NOT NULL,encoded_message_definition TEXT NOT NULL,type_description_hash TEXT NOT NULL);",
                )
                .unwrap();
            }
        }
        for (id, channel) in bag.channels.iter().enumerate() {
            let qos = channel
                .metadata
                .get("offered_qos_profiles")
                .cloned()
                .unwrap_or_default();
            match schema {
                Schema::Humble => db.execute(
                    "INSERT INTO topics VALUES (?1, ?2, ?3, ?4, ?5)",
                    (
                        id as i64 + 1,
                        &channel.topic,
                        &channel.schema_name,
                        "cdr",
                        qos,
                    ),
                ),
                Schema::Jazzy => {
                    db.execute(
                        "INSERT INTO message_definitions VALUES (?1, ?2, ?3, ?4, '')",
                        (
                            id as i64 + 1,
                            &channel.schema_name,
                            &channel.schema_encoding,
                            String::from_utf8(channel.schema_data.clone()).unwrap(),
                        ),
                    )
                    .unwrap();
                    db.execute(
                        "INSERT INTO topics VALUES (?1, ?2, ?3, ?4, ?5, '')",
                        (
                            id as i64 + 1,
                            &channel.topic,
                            &channel.schema_name,
                            "cdr",
                            qos,
                        ),
                    )
                }
            }
            .unwrap();
        }
        db.execute_batch("BEGIN").unwrap();
        for m in messages {
            db.execute(
                "INSERT INTO messages (topic_id, timestamp, data) VALUES (?1, ?2, ?3)",
                (m.channel as i64 + 1, m.log_time as i64, &m.data),
            )
            .unwrap();
        }
        db.execute_batch("COMMIT").unwrap();
        names.push(name);
    }
    let listed: Vec<String> = names.iter().map(|n| format!("    - {n}\n")).collect();
    std::fs::write(
        dir.join("metadata.yaml"),
        format!(
            "rosbag2_bagfile_information:\n  version: 5\n  storage_identifier: sqlite3\n  \
             relative_file_paths:\n{}  message_count: {}\n",
            listed.concat(),
            bag.messages.len()
        ),
    )
    .unwrap();
}

/// The shipped 150 fps bag (3,642 detections with their truth), as rosbag2 would record it.
fn shipped() -> (PathBuf, BagContents) {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("bags/sim_rally_wide.mcap");
    let bag = read_bag_file(&path).unwrap();
    (path, bag)
}

/// Each output topic's messages (log time, payload) of a replay's output.
fn outputs(path: &Path) -> Vec<(String, u64, Vec<u8>)> {
    let bag = read_bag_file(path).unwrap();
    assert!(bag.damage.is_empty(), "{:?}", bag.damage);
    bag.messages
        .iter()
        .map(|m| {
            (
                bag.channels[m.channel].topic.clone(),
                m.log_time,
                m.data.clone(),
            )
        })
        .filter(|(topic, _, _)| topic.starts_with("/ball/"))
        .collect()
}

/// The same detections replay to the same estimates, interceptions, trajectories and markers
/// from a `.db3` bag as from MCAP: in Jazzy's schema in one file, and in Humble's split in three.
#[test]
fn a_db3_bag_of_detections_replays_as_its_mcap_twin() {
    let (mcap, bag) = shipped();
    let d = dir("twin");
    let reference = run(&mcap, &d.join("from_mcap.mcap")).unwrap();
    let expected = outputs(&d.join("from_mcap.mcap"));
    assert!(expected.len() > 3 * reference.detections as usize);
    for (name, schema, splits) in [("jazzy", Schema::Jazzy, 1), ("humble", Schema::Humble, 3)] {
        let bag_dir = d.join(name);
        std::fs::create_dir_all(&bag_dir).unwrap();
        write_db3(&bag, &bag_dir, schema, splits);
        let output = d.join(format!("from_{name}.mcap"));
        let summary = run(&bag_dir, &output).unwrap();
        assert!(summary.damage.is_empty(), "{name}: {:?}", summary.damage);
        assert_eq!(summary.detections, reference.detections, "{name}");
        assert_eq!(summary.counters, reference.counters, "{name}");
        assert_eq!(summary.learned, reference.learned, "{name}");
        let got = outputs(&output);
        let first_difference = got.iter().zip(&expected).position(|(a, b)| a != b);
        assert!(
            got.len() == expected.len() && first_difference.is_none(),
            "{name}: {} messages against {}, first difference at {first_difference:?}: {:?}",
            got.len(),
            expected.len(),
            first_difference.map(|i| (&got[i].0, got[i].1, &expected[i].0, expected[i].1))
        );
        // The input's channels are copied with a schema Foxglove can decode.
        let copied = read_bag_file(&output).unwrap();
        let detections = copied.channel("/ball/detections").unwrap();
        assert_eq!(
            copied.channels[detections].schema_name,
            "ttball_msgs/msg/BallDetection"
        );
        assert!(!copied.channels[detections].schema_data.is_empty());
    }
}

/// A cut `.db3` file gives the messages before the cut (or, when the cut took its tables, a
/// clear error); one whose pages are overwritten is damaged, said so; a file with the SQLite
/// header and nothing of a bag after it is refused as not one. None panics, and every output
/// that is written is whole.
#[test]
fn a_damaged_db3_gives_what_it_holds_or_says_what_is_wrong() {
    let (_, bag) = shipped();
    let d = dir("damaged");
    write_db3(&bag, &d, Schema::Jazzy, 1);
    let whole = std::fs::read(d.join("bag_0.db3")).unwrap();
    let total = bag
        .messages
        .iter()
        .filter(|m| bag.channels[m.channel].topic == "/ball/detections")
        .count() as u64;

    // Cut in half.
    let cut = d.join("cut.db3");
    std::fs::write(&cut, &whole[..whole.len() / 2]).unwrap();
    match run(&cut, &d.join("cut_out.mcap")) {
        Ok(summary) => {
            assert!(summary.detections < total, "{}", summary.detections);
            let said = ttball::bag::damage_text(&summary.damage).unwrap_or_default();
            assert!(
                said.contains("damaged") || said.contains("disk I/O"),
                "{said}"
            );
            assert!(
                read_bag_file(&d.join("cut_out.mcap"))
                    .unwrap()
                    .damage
                    .is_empty()
            );
        }
        Err(e) => {
            let said = e.to_string();
            assert!(
                said.contains("cut.db3") && said.contains("damaged"),
                "{said}"
            );
        }
    }

    // Pages overwritten past the schema.
    let mut scrambled = whole.clone();
    let from = whole.len() / 3;
    for (i, b) in scrambled[from..].iter_mut().enumerate() {
        *b = (i * 7 + 13) as u8;
    }
    let scrambled_path = d.join("scrambled.db3");
    std::fs::write(&scrambled_path, &scrambled).unwrap();
    let said = match run(&scrambled_path, &d.join("scrambled_out.mcap")) {
        Ok(summary) => {
            assert!(summary.detections < total);
            ttball::bag::damage_text(&summary.damage).unwrap_or_default()
        }
        Err(e) => e.to_string(),
    };
    assert!(said.contains("damaged"), "{said}");

    // The header alone.
    let header_only = d.join("header.db3");
    let mut bytes = b"SQLite format 3\0".to_vec();
    bytes.resize(4096, 0xAB);
    std::fs::write(&header_only, &bytes).unwrap();
    let said = run(&header_only, &d.join("header_out.mcap"))
        .unwrap_err()
        .to_string();
    assert!(
        said.contains("header.db3")
            && (said.contains("not an SQLite database") || said.contains("damaged")),
        "{said}"
    );
}

/// A database another process holds locked (a recording still running) is waited for, then
/// refused with what to do; an SQLite database without rosbag2's tables is not a bag.
#[test]
fn a_locked_or_foreign_database_is_refused_with_what_to_do() {
    let (_, bag) = shipped();
    let d = dir("locked");
    write_db3(&bag, &d, Schema::Humble, 1);
    let path = d.join("bag_0.db3");
    let writer = Connection::open(&path).unwrap();
    writer.execute_batch("BEGIN EXCLUSIVE").unwrap();
    let said = run(&path, &d.join("out.mcap")).unwrap_err().to_string();
    assert!(
        said.contains("locked by another process") && said.contains("ros2 bag record"),
        "{said}"
    );
    writer.execute_batch("COMMIT").unwrap();
    assert!(run(&path, &d.join("out.mcap")).is_ok());

    let foreign = d.join("foreign.db3");
    Connection::open(&foreign)
        .unwrap()
        .execute_batch("CREATE TABLE things(id INTEGER PRIMARY KEY)")
        .unwrap();
    let said = run(&foreign, &d.join("foreign_out.mcap"))
        .unwrap_err()
        .to_string();
    assert!(said.contains("without rosbag2's tables"), "{said}");
}
