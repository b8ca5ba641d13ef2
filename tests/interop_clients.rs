//! Interoperability with MCAP clients ttball did not write: Python `mcap` + `mcap-ros2-support`
//! and `rosbags`, and Foxglove's own TypeScript parsers (`@mcap/core`, `@mcap/support`,
//! `@foxglove/rosmsg`, `@foxglove/rosmsg2-serialization`, `@foxglove/rosmsg-msgs-common`),
//! decode every message of a replay's output, smoothed (`ttball smooth`), to the same values
//! ttball wrote, and a bag written by `mcap-ros2-support` replays in ttball.
//!
//! Needs a Python with those packages and the npm packages of `tests/interop/foxglove/`:
//! `.ci/run` makes a virtual environment and sets `TTBALL_PYTHON` to its interpreter, and runs
//! `npm ci` there. Without them the tests say so and pass, except under CI (`CI=true`), where
//! a missing client fails them.
#![cfg(feature = "cli")]
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    reason = "test code: fail loudly"
)]

use std::path::{Path, PathBuf};
use std::process::Command;

mod common;

use common::ok as ttball;

fn dir() -> PathBuf {
    common::scratch("interop")
}

fn python() -> Option<PathBuf> {
    match std::env::var_os("TTBALL_PYTHON") {
        Some(p) => Some(PathBuf::from(p)),
        None => {
            assert!(
                std::env::var("CI").as_deref() != Ok("true"),
                "CI must set TTBALL_PYTHON (see .ci/run)"
            );
            eprintln!(
                "skipped: set TTBALL_PYTHON to a Python with mcap, mcap-ros2-support and rosbags (see .ci/run)"
            );
            None
        }
    }
}

fn script(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/interop")
        .join(name)
}

/// The npm packages' directory, when `npm ci` has filled it.
fn foxglove_parsers() -> Option<PathBuf> {
    let dir = script("foxglove");
    if dir.join("node_modules/@mcap/core").is_dir() {
        return Some(dir);
    }
    assert!(
        std::env::var("CI").as_deref() != Ok("true"),
        "CI must install Foxglove's parsers: npm ci in tests/interop/foxglove (see .ci/run)"
    );
    eprintln!("skipped: run `npm ci` in tests/interop/foxglove for Foxglove's parsers");
    None
}

/// A replay's output (all its topics, odometry included) smoothed: every message type ttball
/// writes in one bag, and its `ttball dump`.
fn every_output(d: &Path) -> (PathBuf, PathBuf) {
    let s = |p: &Path| p.to_str().unwrap().to_owned();
    let sim = d.join("sim.mcap");
    let out = d.join("out.mcap");
    ttball(&[
        "simulate",
        "--output",
        &s(&sim),
        "--shots",
        "2",
        "--seed",
        "5",
    ]);
    let replayed = d.join("replayed.mcap");
    ttball(&[
        "replay",
        &s(&sim),
        "--output",
        &s(&replayed),
        "-p",
        "topics.odometry:=ball/odometry",
    ]);
    // Smoothing the replay's output adds /ball/smoothed to everything above.
    ttball(&["smooth", &s(&replayed), "--output", &s(&out)]);
    let dump = ttball(&["dump", &s(&out)]);
    let dump_path = d.join("out.jsonl");
    std::fs::write(&dump_path, &dump).unwrap();
    (out, dump_path)
}

/// Every topic a replay writes (and the smoother's), as a client's report must list them.
const EVERY_TOPIC: [&str; 8] = [
    "/ball/detections",
    "/ball/state",
    "/ball/intercept",
    "/ball/trajectory",
    "/ball/markers",
    "/ball/odometry",
    "/ball/truth",
    "/ball/smoothed",
];

/// Runs a client's checker (`checker BAG DUMP`) on [`every_output`] in `d`: it must succeed and
/// report every topic; its report.
fn check_every_output(mut checker: Command, d: &Path) -> String {
    let (out, dump_path) = every_output(d);
    let check = checker.arg(&out).arg(&dump_path).output().unwrap();
    let report = String::from_utf8_lossy(&check.stdout).into_owned();
    assert!(
        check.status.success(),
        "{report}{}",
        String::from_utf8_lossy(&check.stderr)
    );
    for topic in EVERY_TOPIC {
        assert!(
            report.contains(&format!("{topic}: ")),
            "{topic} not checked: {report}"
        );
    }
    report
}

#[test]
fn foxglove_parsers_decode_every_message_ttball_writes_to_the_same_values() {
    let Some(parsers) = foxglove_parsers() else {
        return;
    };
    let mut node = Command::new("node");
    node.arg(parsers.join("check_bag.mjs"))
        .current_dir(&parsers);
    let report = check_every_output(node, &common::scratch("interop-foxglove"));
    assert!(report.contains("CRCs valid"), "{report}");
    // ttball's standard definitions are ROS 2 Humble's: equal to Jazzy's but for the marker
    // type Jazzy added (a constant: the wire format and type hash are the same).
    for standard in [
        "std_msgs/Header (humble)",
        "std_msgs/Header (jazzy)",
        "visualization_msgs/Marker (humble)",
        "visualization_msgs/Marker (jazzy; jazzy adds ARROW_STRIP=12)",
        "geometry_msgs/TwistWithCovariance (jazzy)",
    ] {
        assert!(
            report.contains(standard),
            "{standard} not checked: {report}"
        );
    }
}

#[test]
fn python_clients_decode_every_message_ttball_writes_to_the_same_values() {
    let Some(python) = python() else { return };
    let mut check = Command::new(&python);
    check.arg(script("check_bag.py"));
    let report = check_every_output(check, &dir());
    // The standard types, decoded by rosbags' own Humble and Jazzy definitions as well.
    for standard in [
        "visualization_msgs/msg/MarkerArray (humble)",
        "visualization_msgs/msg/MarkerArray (jazzy)",
        "nav_msgs/msg/Odometry (humble)",
        "nav_msgs/msg/Odometry (jazzy)",
    ] {
        assert!(
            report.contains(standard),
            "{standard} not checked: {report}"
        );
    }
}

#[test]
fn a_bag_written_by_mcap_ros2_support_replays_in_ttball() {
    let Some(python) = python() else { return };
    let d = dir();
    let bag = d.join("python.mcap");
    let write = Command::new(&python)
        .arg(script("write_bag.py"))
        .arg(&bag)
        .arg(Path::new(env!("CARGO_MANIFEST_DIR")).join("msgs/msg"))
        .output()
        .unwrap();
    assert!(
        write.status.success(),
        "{}",
        String::from_utf8_lossy(&write.stderr)
    );
    let out = d.join("python-out.mcap");
    let summary = ttball(&[
        "replay",
        bag.to_str().unwrap(),
        "--output",
        out.to_str().unwrap(),
    ]);
    assert!(
        summary.contains("detections read 45, fused 41, initialising 4, rejected 0, undecodable 0"),
        "{summary}"
    );
    assert!(summary.contains("tracks 1"), "{summary}");
}

/// The MCAP format's conformance corpus (`tests/data/mcap_conformance/`: every record type in
/// every layout the writers produce: statistics, summaries, chunks, indexes, repeated schemas and
/// channels, ...), each variant written from its JSON by Foxglove's own writer
/// (`write_conformance.mjs`; the corpus's own files are Git LFS objects the copy lacks):
/// ttball's reader gives each file's channels (with their schemas) and messages as the JSON
/// lists them (messages in log-time order, file order among equal times), undamaged; the
/// records ttball does not use (attachments, metadata, indexes, statistics) are read past
/// without error. The padded variants (every record that may have them carries extra trailing
/// bytes, as a newer writer's fields would be) are laid out by `@mcap/core`'s record builder,
/// which McapWriter does not expose, and read like the others: the reader skips what it does not
/// know inside a record.
#[test]
fn the_mcap_conformance_corpus_reads_as_its_json_lists() {
    use serde_json::Value;
    use std::collections::{BTreeMap, HashMap};
    let Some(parsers) = foxglove_parsers() else {
        return;
    };
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/mcap_conformance");
    let written = common::scratch("mcap-conformance");
    let generate = Command::new("node")
        .arg(parsers.join("write_conformance.mjs"))
        .arg(&root)
        .arg(&written)
        .current_dir(&parsers)
        .output()
        .unwrap();
    let log = String::from_utf8_lossy(&generate.stdout);
    assert!(
        generate.status.success() && log.contains("written 416, 208 of them padded"),
        "{log}{}",
        String::from_utf8_lossy(&generate.stderr)
    );
    let number = |v: &Value| v.as_str().unwrap().parse::<u64>().unwrap();
    let bytes = |v: &Value| -> Vec<u8> {
        v.as_array()
            .unwrap()
            .iter()
            .map(|b| u8::try_from(number(b)).unwrap())
            .collect()
    };
    let text = |v: &Value| v.as_str().unwrap().to_owned();
    let mut files = 0;
    let mut messages = 0;
    let mut dirs: Vec<PathBuf> = std::fs::read_dir(&root)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.is_dir())
        .collect();
    dirs.sort();
    for dir in dirs {
        let mut specs: Vec<PathBuf> = std::fs::read_dir(&dir)
            .unwrap()
            .map(|e| e.unwrap().path())
            .filter(|p| p.extension().is_some_and(|e| e == "json"))
            .collect();
        specs.sort();
        for spec in specs {
            let path = written.join(spec.with_extension("mcap").file_name().unwrap());
            let name = path.display().to_string();
            let listed: Value =
                serde_json::from_str(&std::fs::read_to_string(&spec).unwrap()).unwrap();
            let mut schemas: HashMap<u64, (String, String, Vec<u8>)> = HashMap::new();
            let mut channels: HashMap<u64, ttball::bag::ChannelInfo> = HashMap::new();
            let mut expected = Vec::new();
            for record in listed["records"].as_array().unwrap() {
                let fields: HashMap<&str, &Value> = record["fields"]
                    .as_array()
                    .unwrap()
                    .iter()
                    .map(|f| (f[0].as_str().unwrap(), &f[1]))
                    .collect();
                match record["type"].as_str().unwrap() {
                    "Schema" => {
                        schemas.insert(
                            number(fields["id"]),
                            (
                                text(fields["name"]),
                                text(fields["encoding"]),
                                bytes(fields["data"]),
                            ),
                        );
                    }
                    "Channel" => {
                        let (schema_name, schema_encoding, schema_data) = schemas
                            .get(&number(fields["schema_id"]))
                            .cloned()
                            .unwrap_or_default();
                        let metadata: BTreeMap<String, String> = fields["metadata"]
                            .as_object()
                            .unwrap()
                            .iter()
                            .map(|(k, v)| (k.clone(), text(v)))
                            .collect();
                        channels.insert(
                            number(fields["id"]),
                            ttball::bag::ChannelInfo {
                                topic: text(fields["topic"]),
                                schema_name,
                                schema_encoding,
                                schema_data,
                                message_encoding: text(fields["message_encoding"]),
                                metadata,
                            },
                        );
                    }
                    "Message" => expected.push((
                        channels[&number(fields["channel_id"])].clone(),
                        number(fields["log_time"]),
                        number(fields["publish_time"]),
                        bytes(fields["data"]),
                    )),
                    _ => {}
                }
            }
            expected.sort_by_key(|m| m.1);
            let bag = ttball::bag::read_bag_file(&path).unwrap_or_else(|e| panic!("{name}: {e}"));
            assert!(bag.damage.is_empty(), "{name}: {:?}", bag.damage);
            for channel in channels.values() {
                assert!(bag.channels.contains(channel), "{name}: {channel:?}");
            }
            let read: Vec<_> = bag
                .messages
                .iter()
                .map(|m| {
                    (
                        bag.channels[m.channel].clone(),
                        m.log_time,
                        m.publish_time,
                        m.data.clone(),
                    )
                })
                .collect();
            assert_eq!(read, expected, "{name}");
            files += 1;
            messages += read.len();
        }
    }
    // Every variant was written and read, with every message its JSON lists.
    assert_eq!(files, 416);
    assert!(messages > 800, "{messages}");
}

/// Whether a loopback-only network namespace can be made for a test of the node (CI must).
fn loopback_only_namespace() -> bool {
    if common::can_isolate_network() {
        return true;
    }
    assert!(
        std::env::var("CI").as_deref() != Ok("true"),
        "CI must be able to make a loopback-only network namespace"
    );
    eprintln!("skipped: `unshare -n` failed");
    false
}

/// Foxglove's own WebSocket client (`live_client.mjs`, `@foxglove/ws-protocol`) watching
/// `url` for `seconds` after the first message; its report.
fn watch_live_view(parsers: &Path, url: &str, seconds: u32, report: &Path) -> Command {
    let mut client = Command::new("node");
    client
        .arg(parsers.join("live_client.mjs"))
        .arg(url)
        .arg(seconds.to_string())
        .arg(report)
        .current_dir(parsers);
    client
}

/// The report's every channel advertised with its ros2msg schema and cdr encoding, every
/// message received on each of `topics` decoded with nothing left over.
fn assert_live_view(report: &serde_json::Value, topics: &[&str]) {
    assert_eq!(report["server"]["name"], "ttball", "{report:#}");
    assert!(
        report["problems"].as_array().unwrap().is_empty(),
        "{report:#}"
    );
    for channel in report["channels"].as_array().unwrap() {
        assert_eq!(channel["encoding"], "cdr", "{channel}");
        assert_eq!(channel["schemaEncoding"], "ros2msg", "{channel}");
    }
    for topic in topics {
        let seen = &report["topics"][topic];
        let received = seen["received"].as_u64().unwrap_or(0);
        assert!(received > 0, "nothing on {topic}: {report:#}");
        assert_eq!(seen["decoded"].as_u64(), Some(received), "{topic}");
    }
}

/// Whether two JSON values are equal, numbers within `relative` of each other (0: equal as
/// doubles, 1 == 1.0).
fn close_json(a: &serde_json::Value, b: &serde_json::Value, relative: f64) -> bool {
    use serde_json::Value;
    match (a, b) {
        (Value::Number(x), Value::Number(y)) => {
            let (x, y) = (
                x.as_f64().unwrap_or(f64::NAN),
                y.as_f64().unwrap_or(f64::NAN),
            );
            (x - y).abs() <= relative * x.abs().max(y.abs()).max(1e-300)
        }
        (Value::Array(x), Value::Array(y)) => {
            x.len() == y.len() && x.iter().zip(y).all(|(p, q)| close_json(p, q, relative))
        }
        (Value::Object(x), Value::Object(y)) => {
            x.len() == y.len()
                && x.iter()
                    .all(|(k, v)| y.get(k).is_some_and(|w| close_json(v, w, relative)))
        }
        _ => a == b,
    }
}

/// `ttball replay --foxglove` serves the bag and the outputs at recorded pace (here 8x) to
/// Foxglove's own WebSocket client: every topic advertised with its schema, every message
/// decoded, and each topic's first one equal to the message of the same topic and log time in
/// the replay's output bag.
#[test]
fn a_replay_is_watched_live_by_foxglove_s_websocket_client() {
    let Some(parsers) = foxglove_parsers() else {
        return;
    };
    let d = common::scratch("live-replay");
    let output = d.join("out.mcap");
    let bag = common::root().join("bags/sim_rally_2cams.mcap");
    // Port 0: the replay binds a free port itself and says which (a port picked here and
    // released could be taken by any other connection before the replay binds it).
    let mut replay = Command::new(env!("CARGO_BIN_EXE_ttball"))
        .args(["replay", bag.to_str().unwrap(), "--output"])
        .arg(&output)
        .args(["--foxglove", "127.0.0.1:0"])
        .args(["--rate", "8", "--foxglove-wait", "30"])
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let stderr = replay.stderr.take().unwrap();
    let (url_tx, url_rx) = std::sync::mpsc::channel();
    let reader = std::thread::spawn(move || {
        use std::io::BufRead;
        let mut text = String::new();
        for line in std::io::BufReader::new(stderr)
            .lines()
            .map_while(Result::ok)
        {
            if let Some(rest) = line.strip_prefix("Foxglove live view on ") {
                let url = rest
                    .split_whitespace()
                    .next()
                    .unwrap_or_default()
                    .to_owned();
                let _ = url_tx.send(url);
            }
            text += &line;
            text.push('\n');
        }
        text
    });
    let url = url_rx
        .recv_timeout(std::time::Duration::from_secs(60))
        .unwrap_or_default();
    let report_path = d.join("view.json");
    let client = watch_live_view(&parsers, &url, 4, &report_path)
        .output()
        .unwrap();
    let status = replay.wait().unwrap();
    let replay_stderr = reader.join().unwrap();
    assert!(
        url.starts_with("ws://127.0.0.1:") && client.status.success() && status.success(),
        "url {url:?}\nclient: {}{}\nreplay: {replay_stderr}",
        String::from_utf8_lossy(&client.stdout),
        String::from_utf8_lossy(&client.stderr),
    );
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&report_path).unwrap()).unwrap();
    let topics = [
        "/ball/detections",
        "/ball/state",
        "/ball/intercept",
        "/ball/trajectory",
        "/ball/markers",
        "/ball/truth",
    ];
    assert_live_view(&report, &topics);
    let dump = ttball(&["dump", output.to_str().unwrap()]);
    for topic in topics {
        let seen = &report["topics"][topic];
        let log_time = seen["first_log_time"].as_str().unwrap();
        let needle = format!("{{\"log_time\":{log_time},");
        let recorded = dump
            .lines()
            .filter(|l| l.starts_with(&needle) && l.contains(&format!("\"topic\":\"{topic}\"")))
            .map(|l| serde_json::from_str::<serde_json::Value>(l).unwrap())
            .any(|m| close_json(&m["message"], &seen["first"], 0.0));
        assert!(
            recorded,
            "{topic}: the first message seen live is not the bag's"
        );
    }
}

/// `ttball node --foxglove` shows the detections it takes and every output live to Foxglove's
/// own WebSocket client, beside DDS (fed by `ttball play`, in the loopback-only namespace).
#[test]
fn the_node_is_watched_live_by_foxglove_s_websocket_client() {
    let Some(parsers) = foxglove_parsers().filter(|_| loopback_only_namespace()) else {
        return;
    };
    let d = common::scratch("live-node");
    let report_path = d.join("view.json");
    let client = watch_live_view(&parsers, "ws://127.0.0.1:18765", 3, &report_path);
    let script = format!(
        r#"
export ROS_DOMAIN_ID=46 ROS_LOCALHOST_ONLY=1
cd "{dir}"
"{ttball}" node --foxglove 127.0.0.1:18765 > node.out 2> node.err &
node=$!
{client:?} > client.out 2> client.err &
client=$!
"{ttball}" play "{bag}" --rate 4 --wait 30 > play.out 2> play.err
wait $client
kill -TERM $node
wait $node
echo $? > node.rc
"#,
        dir = d.display(),
        ttball = env!("CARGO_BIN_EXE_ttball"),
        bag = common::root().join("bags/sim_rally_2cams.mcap").display(),
    );
    common::run_on_loopback_only(&script);
    let read = |name: &str| std::fs::read_to_string(d.join(name)).unwrap_or_default();
    assert_eq!(read("node.rc").trim(), "0", "node: {}", read("node.err"));
    let report: serde_json::Value = serde_json::from_str(&read("view.json")).unwrap_or_else(|e| {
        panic!(
            "{e}: client: {}{}\nnode: {}",
            read("client.out"),
            read("client.err"),
            read("node.err")
        )
    });
    assert_live_view(
        &report,
        &[
            "/ball/detections",
            "/ball/state",
            "/ball/intercept",
            "/ball/trajectory",
            "/ball/markers",
        ],
    );
}

/// The Foxglove app acts on `ttball node --foxglove` through Foxglove's own WebSocket client
/// (`act_client.mjs`, `@foxglove/ws-protocol`): it reads every parameter of the node, sets one
/// (taken, and told to the app's parameter subscribers), and is refused with ROS's ranges and
/// reasons (out of range, read-only, a wrong type: the value unchanged, the reason in a status);
/// it calls `~/predict_trajectory`, `~/predict_rebound` and `~/plan_return` with requests
/// encoded from their advertised `ros2msg` schemas, and each response equals the pipeline's
/// own answer to the same request.
#[test]
fn the_foxglove_app_sets_the_node_s_parameters_and_calls_its_services() {
    use ttball::ros::msgs::ttball_msgs::srv::{
        PlanReturnRequest, PredictReboundRequest, PredictTrajectoryRequest,
    };
    let Some(parsers) = foxglove_parsers().filter(|_| loopback_only_namespace()) else {
        return;
    };
    let d = common::scratch("live-act");
    let config = ttball::config::Config::default();
    // The node's configuration after the app's one accepted set.
    let set = ttball::config::yaml::load(None, &["intercept.plane_x:=-1.45"]).unwrap();
    let pipeline = ttball::ros::pipeline::Pipeline::new(&set);
    // A ball from the opponent's side, as a state message; the racket's hit of it at the plane.
    let mut ball = ttball::ros::msgs::ttball_msgs::msg::BallState::default();
    ball.header.stamp = ttball::ros::msgs::builtin_interfaces::Time::from_nanos(2_000_000_000);
    ball.header.frame_id = "table".into();
    (ball.position.x, ball.position.y, ball.position.z) = (1.2, 0.1, 0.25);
    (ball.velocity.x, ball.velocity.y, ball.velocity.z) = (-6.0, -0.2, 1.2);
    ball.spin.y = 80.0;
    let trajectory = PredictTrajectoryRequest {
        track_id: 0,
        initial: ball.clone(),
        horizon: 0.5,
        dt: 0.01,
    };
    let mut rebound = PredictReboundRequest::default();
    (rebound.ball_position.x, rebound.ball_position.z) = (-1.6, 0.2);
    (rebound.ball_velocity.x, rebound.ball_velocity.z) = (-5.0, -1.0);
    rebound.ball_spin.y = 50.0;
    (rebound.racket_velocity.x, rebound.racket_velocity.z) = (4.0, 1.0);
    rebound.racket_normal.x = 1.0;
    let mut plan = PlanReturnRequest {
        track_id: 0,
        ball: ball.clone(),
        ..PlanReturnRequest::default()
    };
    (plan.ball.position.x, plan.ball.position.z) = (-1.6, 0.2);
    (plan.ball.velocity.x, plan.ball.velocity.z) = (-5.0, -1.0);
    (plan.target.x, plan.target.y) = (1.0, 0.3);
    fn json<T: serde::Serialize>(value: &T) -> serde_json::Value {
        serde_json::to_value(value).unwrap()
    }
    let requests = serde_json::json!({
        "sets": [
            [{"name": "intercept.plane_x", "value": -1.45}],
            [{"name": "intercept.plane_x", "value": 5.0}],
            [{"name": "aero.magnus_scale", "value": 0.5}],
            [{"name": "tracking.timeout", "value": "soon"}],
        ],
        "calls": {
            "/ttball/predict_trajectory": json(&trajectory),
            "/ttball/predict_rebound": json(&rebound),
            "/ttball/plan_return": json(&plan),
        },
    });
    std::fs::write(d.join("requests.json"), requests.to_string()).unwrap();
    let script = format!(
        r#"
export ROS_DOMAIN_ID=47 ROS_LOCALHOST_ONLY=1
cd "{dir}"
"{ttball}" node --foxglove 127.0.0.1:18766 > node.out 2> node.err &
node=$!
cd "{parsers}"
node act_client.mjs ws://127.0.0.1:18766 "{dir}/requests.json" "{dir}/act.json" > "{dir}/client.out" 2> "{dir}/client.err"
kill -TERM $node
wait $node
echo $? > "{dir}/node.rc"
"#,
        dir = d.display(),
        parsers = parsers.display(),
        ttball = env!("CARGO_BIN_EXE_ttball"),
    );
    common::run_on_loopback_only(&script);
    let read = |name: &str| std::fs::read_to_string(d.join(name)).unwrap_or_default();
    assert_eq!(read("node.rc").trim(), "0", "node: {}", read("node.err"));
    let report: serde_json::Value = serde_json::from_str(&read("act.json")).unwrap_or_else(|e| {
        panic!(
            "{e}: client: {}\nnode: {}",
            read("client.err"),
            read("node.err")
        )
    });
    assert!(
        report["problems"].as_array().unwrap().is_empty(),
        "{report:#}"
    );
    let capabilities = report["capabilities"].to_string();
    assert!(
        capabilities.contains("parameters") && capabilities.contains("services"),
        "{capabilities}"
    );
    // Every parameter, with its value and ROS type.
    let all = report["all"].as_object().unwrap();
    for name in ttball::config::yaml::parameter_names(&config) {
        assert!(all.contains_key(&name), "{name} not offered");
    }
    assert_eq!(all["intercept.plane_x"], -1.6);
    assert_eq!(all["tracking.timeout"], config.tracking.timeout);
    // Taken; refused out of range, read-only and of the wrong type, each value unchanged.
    assert_eq!(report["sets"][0]["intercept.plane_x"], -1.45);
    assert_eq!(report["sets"][1]["intercept.plane_x"], -1.45);
    assert_eq!(
        report["sets"][2]["aero.magnus_scale"],
        config.aero.magnus_scale
    );
    assert_eq!(
        report["sets"][3]["tracking.timeout"],
        config.tracking.timeout
    );
    let statuses = report["statuses"].to_string();
    for why in ["out of range", "read-only", "expected"] {
        assert!(statuses.contains(why), "no status says {why:?}: {statuses}");
    }
    let updates = report["updates"].as_array().unwrap();
    assert!(
        updates
            .iter()
            .any(|p| p["name"] == "intercept.plane_x" && p["value"] == -1.45),
        "{updates:?}"
    );
    // Each service: advertised with its schemas, answered as the pipeline answers.
    let services = report["services"].to_string();
    for ty in ["PredictTrajectory", "PredictRebound", "PlanReturn"] {
        assert!(
            services.contains(&format!("ttball_msgs/srv/{ty}_Request")),
            "{services}"
        );
    }
    for (name, expected) in [
        (
            "/ttball/predict_trajectory",
            json(&pipeline.predict_trajectory(&trajectory)),
        ),
        (
            "/ttball/predict_rebound",
            json(&pipeline.predict_rebound(&rebound)),
        ),
        ("/ttball/plan_return", json(&pipeline.plan_return(&plan))),
    ] {
        let got = &report["calls"][name]["response"];
        assert_eq!(got["success"], true, "{name}: {:#}", report["calls"][name]);
        // The node's configuration comes through its parameters, the test's from the
        // defaults: the same values, which may round their last bit differently.
        assert!(
            close_json(got, &expected, 1e-12),
            "{name}: {got:#} against {expected:#}"
        );
    }
}

/// The shipped viewer configurations (`config/foxglove_layout.json`, `config/ttball.rviz`) show
/// what ttball publishes: every topic they name is one of the node's (by default names;
/// `/ball/odometry` once `topics.odometry` is set), every panel the layout places is
/// configured, and both are fixed on the table frame.
#[test]
fn the_viewer_configurations_name_ttball_s_topics_and_frame() {
    use serde_json::Value;
    let config = ttball::config::Config::default();
    let t = config.resolved_topics();
    let published = [
        t.state.as_str(),
        t.intercept.as_str(),
        t.trajectory.as_str(),
        t.markers.as_str(),
        t.diagnostics.as_str(),
        "/ball/odometry",
        "/rosout",
    ];
    let root = common::root();
    let layout: Value = serde_json::from_str(
        &std::fs::read_to_string(root.join("config/foxglove_layout.json")).unwrap(),
    )
    .unwrap();
    let panels = layout["configById"].as_object().unwrap();
    let mut named = Vec::new();
    for panel in panels.values() {
        for key in ["topicPath", "topicToRender"] {
            if let Some(topic) = panel[key].as_str() {
                named.push(topic.to_owned());
            }
        }
        for path in panel["paths"].as_array().into_iter().flatten() {
            let value = path["value"].as_str().unwrap();
            named.push(value.split('.').next().unwrap().to_owned());
        }
        for topic in panel["topics"]
            .as_object()
            .into_iter()
            .flatten()
            .map(|(k, _)| k)
        {
            named.push(topic.clone());
        }
    }
    assert!(named.len() > 10, "{named:?}");
    for topic in &named {
        assert!(
            published.contains(&topic.as_str()),
            "the layout names {topic}"
        );
    }
    assert_eq!(
        panels["3D!table"]["followTf"],
        config.frames.table_frame.as_str()
    );
    fn leaves(node: &Value, out: &mut Vec<String>) {
        match node {
            Value::String(id) => out.push(id.clone()),
            Value::Object(split) => {
                leaves(&split["first"], out);
                leaves(&split["second"], out);
            }
            _ => panic!("not a layout node: {node}"),
        }
    }
    let mut placed = Vec::new();
    leaves(&layout["layout"], &mut placed);
    let mut configured: Vec<String> = panels.keys().cloned().collect();
    placed.sort();
    configured.sort();
    assert_eq!(placed, configured);

    let rviz: serde_norway::Value =
        serde_norway::from_str(&std::fs::read_to_string(root.join("config/ttball.rviz")).unwrap())
            .unwrap();
    let manager = &rviz["Visualization Manager"];
    assert_eq!(
        manager["Global Options"]["Fixed Frame"].as_str(),
        Some(config.frames.table_frame.as_str())
    );
    let topics: Vec<&str> = manager["Displays"]
        .as_sequence()
        .unwrap()
        .iter()
        .filter_map(|d| d["Topic"]["Value"].as_str())
        .collect();
    assert_eq!(topics, [t.markers.as_str(), "/ball/odometry"]);
}
