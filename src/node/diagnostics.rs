//! The node's `/diagnostics` message (`diagnostic_msgs/DiagnosticArray`): one status named
//! `<node>: estimator` (rates, what happened to every detection by reason, queue drops and
//! processing time over the last period), and one per camera source, `<node>: source <key>`
//! ([`source_status`]: its detections, frame rate against the configured band, rejections,
//! STALE when it falls silent while the others deliver). Pure: the caller passes the clock
//! readings.

use crate::model::stats::DurationSummary;
use crate::online::estimator::{Counters, Rejection};
use crate::online::estimator::{Dropped, LearnedParams, LearnedSourceNoise};
use crate::online::learned::REYNOLDS_EXPONENT_NAMES;
use crate::physics::PhysicsParams;
use crate::ros::msgs::builtin_interfaces::Time;
use crate::ros::msgs::diagnostic_msgs::{DiagnosticArray, DiagnosticStatus, KeyValue};
use crate::ros::msgs::std_msgs::Header;

/// What happened to detections before they reached the estimator, and to the node's outputs.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct TransportCounters {
    /// Detections taken from DDS (decoded or not).
    pub received: u64,
    /// Detection samples that did not decode as `BallDetection` (dropped).
    pub undecodable: u64,
    /// Detections dropped because the queue to the estimator was full (the oldest goes).
    pub dropped_queue_full: u64,
    /// Detections lost before the node took them: gaps in their publishers' sequence numbers
    /// (not received, so not among the rejected).
    pub lost_before_node: u64,
    /// Messages that DDS refused to publish.
    pub publish_errors: u64,
    /// Service requests answered (`~/predict_trajectory`, `~/predict_rebound`, `~/plan_return`).
    pub service_requests: u64,
    /// Requests refused because the estimator had too many waiting.
    pub service_busy: u64,
}

/// Processing and queueing times of one diagnostics period.
#[derive(Debug, Clone, Default)]
pub struct Window {
    /// `Pipeline::handle_detection` time per detection, its own work [ns].
    pub processing: Vec<u64>,
    /// Time each detection waited from DDS receiving it to its processing [ns].
    pub queue_wait: Vec<u64>,
    /// `Pipeline::add_due_trajectory` time per published trajectory [ns].
    pub trajectory: Vec<u64>,
}

impl Window {
    /// An empty window with room for `capacity` detections.
    pub fn with_capacity(capacity: usize) -> Self {
        Self {
            processing: Vec::with_capacity(capacity),
            queue_wait: Vec::with_capacity(capacity),
            trajectory: Vec::with_capacity(capacity),
        }
    }

    /// Records one detection.
    pub fn record(&mut self, processing_ns: u64, queue_wait_ns: u64) {
        self.processing.push(processing_ns);
        self.queue_wait.push(queue_wait_ns);
    }

    /// Records one published trajectory.
    pub fn record_trajectory(&mut self, ns: u64) {
        self.trajectory.push(ns);
    }
}

/// Everything one diagnostics message reports.
#[derive(Debug, Clone, Copy)]
pub struct Snapshot<'a> {
    /// Fully qualified node name, e.g. `/ttball`.
    pub node: &'a str,
    /// The detections topic, for the message when nothing arrives.
    pub detections_topic: &'a str,
    /// When the snapshot was taken [ns since the epoch].
    pub stamp: i64,
    /// Length of the period the window covers [s].
    pub period: f64,
    /// The estimator's counters (whole run).
    pub counters: &'a Counters,
    /// The transport's counters (whole run).
    pub transport: &'a TransportCounters,
    /// The same transport counters at the start of the period.
    pub transport_before: &'a TransportCounters,
    /// Detections waiting in the queue now.
    pub queue_len: usize,
    /// The live track, if any.
    pub track: Option<u32>,
    /// What the estimator has learned of the physics.
    pub learned: &'a LearnedParams,
    /// What it has learned of each source's noise (reported for the sources that taught it
    /// something).
    pub learned_noise: &'a [LearnedSourceNoise],
}

/// The estimator's status and its message: a warning when detections were dropped, lost or
/// undecodable in the period (`now`: those three counts), else what it tracks.
fn status(
    s: &Snapshot<'_>,
    (dropped_now, lost_now, undecodable_now): (u64, u64, u64),
    count: usize,
    rate: f64,
) -> (u8, String) {
    if dropped_now > 0 {
        (
            DiagnosticStatus::WARN,
            format!(
                "{dropped_now} detections dropped in the last {:.1} s: the estimator falls behind (raise node.queue_capacity or lower the camera rate)",
                s.period
            ),
        )
    } else if lost_now > 0 {
        (
            DiagnosticStatus::WARN,
            format!(
                "{lost_now} detections lost before the node in the last {:.1} s (gaps in their publishers' sequence numbers): the network or DDS dropped them (check the network, raise qos.detections_depth)",
                s.period
            ),
        )
    } else if undecodable_now > 0 {
        (
            DiagnosticStatus::WARN,
            format!(
                "{undecodable_now} detections on {} did not decode as ttball_msgs/msg/BallDetection",
                s.detections_topic
            ),
        )
    } else if count == 0 {
        (
            DiagnosticStatus::OK,
            format!("waiting for detections on {}", s.detections_topic),
        )
    } else {
        (
            DiagnosticStatus::OK,
            match s.track {
                Some(track) => format!("tracking ball {track} ({rate:.0} detections/s)"),
                None => format!("no ball tracked ({rate:.0} detections/s)"),
            },
        )
    }
}

/// The learned physics and the cameras' learned noise, as key-value pairs.
fn learned_values(s: &Snapshot<'_>) -> Vec<KeyValue> {
    let mut values = Vec::new();
    let learned = s.learned.params.to_vector();
    for (i, name) in PhysicsParams::NAMES.iter().enumerate() {
        values.push(kv(&format!("learned {name}"), format!("{:.4}", learned[i])));
        values.push(kv(
            &format!("learned {name} sigma"),
            format!("{:.4}", s.learned.sigma[i]),
        ));
        values.push(kv(
            &format!("learned {name} flight-to-flight sigma"),
            format!("{:.4}", s.learned.flight_sigma[i]),
        ));
    }
    for (i, name) in REYNOLDS_EXPONENT_NAMES.iter().enumerate() {
        let l = s.learned;
        values.push(kv(
            &format!("learned Reynolds exponent {name}"),
            format!("{:.4}", l.reynolds_exponents[i]),
        ));
        values.push(kv(
            &format!("learned Reynolds exponent {name} sigma"),
            format!("{:.4}", l.reynolds_sigma[i]),
        ));
        values.push(kv(
            &format!("learned Reynolds exponent {name} determined"),
            l.reynolds_determined()[i].to_string(),
        ));
    }
    values.push(kv("learned physics: tracks", s.learned.tracks.to_string()));
    for n in s.learned_noise.iter().filter(|n| n.has_learned()) {
        let source = &n.source;
        values.push(kv(
            &format!("learned noise {source}: position sigma [mm]"),
            format!("{:.2}", n.position_sigma * 1e3),
        ));
        values.push(kv(
            &format!("learned noise {source}: stamp sigma [ms]"),
            format!("{:.2}", n.stamp_sigma * 1e3),
        ));
    }
    values
}

/// Builds the diagnostics message of one period and empties `window`.
pub fn diagnostics_msg(snapshot: &Snapshot<'_>, window: &mut Window) -> DiagnosticArray {
    let s = snapshot;
    let processing = DurationSummary::of(&mut window.processing);
    let wait = DurationSummary::of(&mut window.queue_wait);
    let trajectory = DurationSummary::of(&mut window.trajectory);
    window.processing.clear();
    window.queue_wait.clear();
    window.trajectory.clear();
    let rate = processing.count as f64 / s.period.max(1e-9);
    let dropped_now = s.transport.dropped_queue_full - s.transport_before.dropped_queue_full;
    let undecodable_now = s.transport.undecodable - s.transport_before.undecodable;
    let lost_now = s.transport.lost_before_node - s.transport_before.lost_before_node;
    let (level, message) = status(
        s,
        (dropped_now, lost_now, undecodable_now),
        processing.count,
        rate,
    );
    let c = s.counters;
    let t = s.transport;
    let us = |ns: f64| format!("{:.1}", ns * 1e-3);
    let mut values = vec![
        kv("detections per second [1/s]", format!("{rate:.1}")),
        kv("processing time mean [us]", us(processing.mean)),
        kv("processing time p99 [us]", us(processing.p99)),
        kv("processing time max [us]", us(processing.max)),
        kv("trajectories published", trajectory.count.to_string()),
        kv("trajectory time p99 [us]", us(trajectory.p99)),
        kv("queue wait p99 [us]", us(wait.p99)),
        kv("queue length", s.queue_len.to_string()),
        kv("detections received", t.received.to_string()),
        kv("fused", c.fused.to_string()),
        kv("initialising", c.initializing.to_string()),
        kv(
            "rejected",
            (c.total_rejected() + t.undecodable + t.dropped_queue_full).to_string(),
        ),
        kv("rejected: undecodable", t.undecodable.to_string()),
        kv("rejected: queue full", t.dropped_queue_full.to_string()),
        kv("lost before the node", t.lost_before_node.to_string()),
    ];
    values.extend(Rejection::ALL.iter().map(|r| {
        kv(
            &format!("rejected: {}", r.name()),
            c.rejected(*r).to_string(),
        )
    }));
    values.extend(Dropped::ALL.iter().map(|r| {
        kv(
            &format!("lessons dropped: {}", r.name()),
            c.lessons_dropped(*r).to_string(),
        )
    }));
    values.extend([
        kv("tracks", c.tracks.to_string()),
        kv(
            "live track",
            s.track
                .map_or_else(|| "none".to_owned(), |id| id.to_string()),
        ),
        kv(
            "tracks re-anchored on their own detections",
            c.reanchored.to_string(),
        ),
        kv("late detections fused by rollback", c.rollbacks.to_string()),
        kv(
            "tracks that taught their flight smoothed",
            c.smoothed_lessons.to_string(),
        ),
        kv("all-zero spins ignored", c.zero_spin_ignored.to_string()),
        kv(
            "tracks seeded by the robot's announced hits",
            c.seeded_by_hit.to_string(),
        ),
        kv(
            "announced hits that seeded no track",
            c.hits_not_seeded.to_string(),
        ),
        kv("publish errors", t.publish_errors.to_string()),
        kv("service requests", t.service_requests.to_string()),
        kv(
            "service requests refused (busy)",
            t.service_busy.to_string(),
        ),
    ]);
    values.extend(learned_values(s));
    DiagnosticArray {
        header: Header {
            stamp: Time::from_nanos(s.stamp),
            frame_id: "".into(),
        },
        status: vec![DiagnosticStatus {
            level,
            name: format!("{}: estimator", s.node.trim_start_matches('/')),
            message,
            hardware_id: s.node.to_owned(),
            values,
        }],
    }
}

/// One camera source's detections over a diagnostics period.
#[derive(Debug, Clone, Default)]
pub struct SourceWindow {
    /// Detections of the source in the period.
    pub detections: u64,
    /// Of those, rejected (by the estimator, or never reaching it).
    pub rejected: u64,
    /// Stamp differences of consecutive detections [ns] (bounded: the first ones of the period).
    intervals: Vec<i64>,
    last_stamp: Option<i64>,
}

/// Stamp intervals kept per period and source (a 900 fps camera's second).
const MAX_INTERVALS: usize = 1024;

impl SourceWindow {
    /// An empty window (room for its intervals allocated once).
    pub fn new() -> Self {
        Self {
            intervals: Vec::with_capacity(MAX_INTERVALS),
            ..Self::default()
        }
    }

    /// Records one detection of stamp `stamp` [ns].
    pub fn record(&mut self, stamp: i64, rejected: bool) {
        self.detections += 1;
        self.rejected += u64::from(rejected);
        if let Some(last) = self.last_stamp
            && self.intervals.len() < MAX_INTERVALS
        {
            self.intervals.push(stamp - last);
        }
        self.last_stamp = Some(stamp);
    }

    /// The frame rate its stamps show [Hz]: the median interval between consecutive
    /// detections, over intervals shorter than `max_interval` [s] (within a flight).
    fn frame_rate(&mut self, max_interval: f64) -> Option<f64> {
        let max = (max_interval * 1e9) as i64;
        let mut within: Vec<i64> = self
            .intervals
            .iter()
            .copied()
            .filter(|&d| d > 0 && d <= max)
            .collect();
        if within.len() < 5 {
            return None;
        }
        within.sort_unstable();
        Some(1e9 / within[within.len() / 2] as f64)
    }

    fn clear(&mut self) {
        self.detections = 0;
        self.rejected = 0;
        self.intervals.clear();
    }
}

/// A source's expectations: its configuration key, frame rate (0: none) and when silence is
/// STALE.
#[derive(Debug, Clone, Copy)]
pub struct SourceExpectation<'a> {
    /// `sources.<key>`.
    pub key: &'a str,
    /// Frames per second it should deliver while it sees the ball [Hz]; 0: no expectation
    /// (never STALE, no rate check).
    pub frame_rate: f64,
    /// Silence after which, while other sources deliver, it is STALE [s].
    pub stale_after: f64,
}

/// Most detections of a source rejected (with at least this many) is an ERROR.
const MIN_FOR_REJECTION_RULE: u64 = 20;
/// Fewest detections of the other sources in a period that make a silent source STALE: the
/// tail of another camera's burst (a few frames of the 900 fps camera, milliseconds of flight,
/// in which a 150 fps camera owes at most one frame) does not.
const MIN_OTHERS_FOR_STALE: u64 = 10;
/// The frame-rate band, as fractions of the expected rate.
const RATE_BAND: (f64, f64) = (0.8, 1.25);

/// The status of one source over a period, and empties `window`. `silent_for`: seconds since its
/// last detection (infinite if never); `others`: the other sources' detections in the period.
pub fn source_status(
    node: &str,
    expected: &SourceExpectation<'_>,
    window: &mut SourceWindow,
    silent_for: f64,
    others: u64,
) -> DiagnosticStatus {
    let key = expected.key;
    let max_interval = if expected.frame_rate > 0.0 {
        5.0 / expected.frame_rate
    } else {
        0.05
    };
    let rate = window.frame_rate(max_interval);
    let (n, rejected) = (window.detections, window.rejected);
    let (level, message) = if n == 0 {
        if expected.frame_rate > 0.0
            && silent_for > expected.stale_after
            && others >= MIN_OTHERS_FOR_STALE
        {
            let since = if silent_for.is_finite() {
                format!("for {silent_for:.1} s")
            } else {
                "since the node started".to_owned()
            };
            (
                DiagnosticStatus::STALE,
                format!(
                    "no detections {since} while the other sources delivered {others}: is the camera running and publishing? (sources.{key}.frame_rate: 0 if this setup has no such camera)"
                ),
            )
        } else {
            (DiagnosticStatus::OK, "no detections (idle)".to_owned())
        }
    } else if n >= MIN_FOR_REJECTION_RULE && 2 * rejected > n {
        (
            DiagnosticStatus::ERROR,
            format!(
                "{rejected} of its {n} detections rejected: check the camera's calibration, frame and stamps (the estimator's status says why)"
            ),
        )
    } else {
        match rate {
            Some(r)
                if expected.frame_rate > 0.0
                    && !(RATE_BAND.0 * expected.frame_rate..=RATE_BAND.1 * expected.frame_rate)
                        .contains(&r) =>
            {
                (
                    DiagnosticStatus::WARN,
                    format!(
                        "frame rate {r:.0} Hz, expected {:.0} Hz (sources.{key}.frame_rate): dropped frames or another camera mode",
                        expected.frame_rate
                    ),
                )
            }
            Some(r) => (
                DiagnosticStatus::OK,
                format!("{n} detections at {r:.0} fps"),
            ),
            None => (DiagnosticStatus::OK, format!("{n} detections")),
        }
    };
    window.clear();
    let mut values = vec![
        kv("detections", n.to_string()),
        kv("rejected", rejected.to_string()),
        kv(
            "frame rate [Hz]",
            rate.map_or_else(|| "unknown".to_owned(), |r| format!("{r:.1}")),
        ),
        kv(
            "expected frame rate [Hz]",
            format!("{:.1}", expected.frame_rate),
        ),
    ];
    if silent_for.is_finite() {
        values.push(kv(
            "seconds since its last detection",
            format!("{silent_for:.1}"),
        ));
    }
    DiagnosticStatus {
        level,
        name: format!("{}: source {key}", node.trim_start_matches('/')),
        message,
        hardware_id: key.to_owned(),
        values,
    }
}

/// What to log of the tracks' smoothings dropped since `before` (the counts by reason of
/// [`Counters::lessons_dropped`]): one warning per reason with new ones.
pub fn dropped_lessons_warnings(
    before: &[u64; Dropped::ALL.len()],
    now: &[u64; Dropped::ALL.len()],
) -> Vec<String> {
    Dropped::ALL
        .iter()
        .zip(before.iter().zip(now))
        .filter(|(_, (b, n))| n > b)
        .map(|(reason, (b, n))| {
            let why = match reason {
                Dropped::Backlog => "more tracks ended than the lessons worker could take",
                Dropped::Late => {
                    "the lessons worker fell behind the detections (give the node more CPUs: node.cpus)"
                }
                Dropped::Failed => "the smoothing failed on the lessons worker",
            };
            format!(
                "{} track lesson(s) not smoothed ({}): {why}; each track taught its filter's lesson",
                n - b,
                reason.name()
            )
        })
        .collect()
}

fn kv(key: &str, value: String) -> KeyValue {
    KeyValue {
        key: key.to_owned(),
        value,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Only reasons with new drops are warned of, each once with how many.
    #[test]
    fn dropped_lessons_are_warned_of_once() {
        assert!(dropped_lessons_warnings(&[1, 2, 3], &[1, 2, 3]).is_empty());
        let warnings = dropped_lessons_warnings(&[1, 2, 3], &[1, 2, 5]);
        assert_eq!(warnings.len(), 1);
        assert!(
            warnings[0].starts_with("2 track lesson(s) not smoothed (failed)"),
            "{warnings:?}"
        );
    }

    fn value<'a>(msg: &'a DiagnosticArray, key: &str) -> &'a str {
        let status = &msg.status[0];
        status
            .values
            .iter()
            .find(|kv| kv.key == key)
            .map(|kv| kv.value.as_str())
            .unwrap_or_else(|| panic!("no {key}"))
    }

    #[test]
    fn sources_are_ok_warn_error_or_stale_by_rule() {
        let expected = SourceExpectation {
            key: "highspeed_900fps",
            frame_rate: 900.0,
            stale_after: 3.0,
        };
        let mut w = SourceWindow::new();
        let frame = 1_000_000_000 / 900;
        for i in 0..300 {
            w.record(i * frame, i % 10 == 0);
        }
        let ok = source_status("/ttball", &expected, &mut w, 0.0, 150);
        assert_eq!(
            (ok.level, ok.hardware_id.as_str()),
            (DiagnosticStatus::OK, "highspeed_900fps")
        );
        assert_eq!(ok.name, "ttball: source highspeed_900fps");
        assert_eq!(ok.message, "300 detections at 900 fps");
        assert_eq!(w.detections, 0, "emptied");
        // Every other frame: 450 fps.
        for i in 0..300 {
            w.record(2 * i * frame, false);
        }
        let slow = source_status("/ttball", &expected, &mut w, 0.0, 150);
        assert_eq!(slow.level, DiagnosticStatus::WARN, "{}", slow.message);
        for i in 0..300 {
            w.record(i * frame, i % 3 != 0);
        }
        let bad = source_status("/ttball", &expected, &mut w, 0.0, 150);
        assert_eq!(bad.level, DiagnosticStatus::ERROR, "{}", bad.message);
        // Silent while the 150 fps camera delivers: STALE; all silent: idle.
        let stale = source_status("/ttball", &expected, &mut w, 4.2, 150);
        assert_eq!(stale.level, DiagnosticStatus::STALE);
        assert!(stale.message.contains("for 4.2 s"), "{}", stale.message);
        // Silent while another camera delivered only the tail of a burst: idle.
        let tail = source_status("/ttball", &expected, &mut w, 4.2, 6);
        assert_eq!(tail.level, DiagnosticStatus::OK, "{}", tail.message);
        let never = source_status("/ttball", &expected, &mut w, f64::INFINITY, 150);
        assert!(
            never.message.contains("since the node started"),
            "{}",
            never.message
        );
        let idle = source_status("/ttball", &expected, &mut w, 4.2, 0);
        assert_eq!(idle.level, DiagnosticStatus::OK);
        let short = source_status("/ttball", &expected, &mut w, 1.0, 150);
        assert_eq!(short.level, DiagnosticStatus::OK);
        let unexpected = SourceExpectation {
            frame_rate: 0.0,
            ..expected
        };
        let unknown = source_status("/ttball", &unexpected, &mut w, f64::INFINITY, 150);
        assert_eq!(unknown.level, DiagnosticStatus::OK);
    }

    #[test]
    fn reports_rates_times_and_every_reason() {
        let mut rejected = [0; Rejection::ALL.len()];
        rejected[0] = 3; // Rejection::ALL[0]
        let counters = Counters {
            fused: 140,
            rejected,
            ..Counters::default()
        };
        let transport = TransportCounters {
            received: 150,
            undecodable: 1,
            ..TransportCounters::default()
        };
        let mut window = Window::with_capacity(8);
        for i in 0..150 {
            window.record(10_000 + i * 100, 2_000);
        }
        window.record_trajectory(30_000);
        let msg = diagnostics_msg(
            &Snapshot {
                node: "/ttball",
                detections_topic: "/ball/detections",
                stamp: 1_500_000_000,
                period: 1.0,
                counters: &counters,
                transport: &transport,
                transport_before: &transport,
                queue_len: 0,
                track: Some(4),
                learned: &learned(),
                learned_noise: &learned_noise(),
            },
            &mut window,
        );
        assert!(
            window.processing.is_empty()
                && window.queue_wait.is_empty()
                && window.trajectory.is_empty()
        );
        let status = &msg.status[0];
        assert_eq!(status.name, "ttball: estimator");
        assert_eq!(status.level, DiagnosticStatus::OK);
        assert_eq!(status.message, "tracking ball 4 (150 detections/s)");
        assert_eq!(value(&msg, "detections per second [1/s]"), "150.0");
        assert_eq!(value(&msg, "processing time max [us]"), "24.9");
        assert_eq!(value(&msg, "trajectories published"), "1");
        assert_eq!(value(&msg, "trajectory time p99 [us]"), "30.0");
        assert_eq!(value(&msg, "rejected"), "4");
        assert_eq!(
            value(&msg, &format!("rejected: {}", Rejection::ALL[0].name())),
            "3"
        );
        for r in Rejection::ALL {
            value(&msg, &format!("rejected: {}", r.name()));
        }
        assert_eq!(msg.header.stamp, Time::from_nanos(1_500_000_000));
        assert_eq!(value(&msg, "learned magnus_scale"), "0.6000");
        assert_eq!(value(&msg, "learned friction sigma"), "0.0100");
        for (key, expected) in [
            ("a_M", "-0.8000"),
            ("a_M determined", "true"),
            ("a_D determined", "false"),
        ] {
            let key = format!("learned Reynolds exponent {key}");
            assert_eq!(value(&msg, &key), expected, "{key}");
        }
        assert_eq!(
            value(&msg, "learned noise wide_150fps: position sigma [mm]"),
            "3.10"
        );
        assert_eq!(
            value(&msg, "learned noise wide_150fps: stamp sigma [ms]"),
            "0.40"
        );
        // A source that has taught nothing yet is not reported.
        assert!(
            !status
                .values
                .iter()
                .any(|kv| kv.key.contains("highspeed_900fps")),
            "{:?}",
            status.values
        );
    }

    /// The 150 fps camera has taught its noise, the 900 fps one nothing yet.
    fn learned_noise() -> [LearnedSourceNoise; 2] {
        let source = |source: &str, position_sigma, stamp_sigma, weight| LearnedSourceNoise {
            source: source.to_owned(),
            position_sigma,
            stamp_sigma,
            estimate: crate::online::estimator::SourceNoiseEstimate {
                position_scale: 1.0,
                timing_variance: stamp_sigma * stamp_sigma,
                spin_scale: 1.0,
                weight,
                spin_weight: weight,
            },
        };
        [
            source("wide_150fps", 0.0031, 0.0004, 300.0),
            source("highspeed_900fps", 0.001, 0.0, 20.0),
        ]
    }

    fn learned() -> LearnedParams {
        LearnedParams {
            params: PhysicsParams {
                drag_scale: 1.1,
                magnus_scale: 0.6,
                restitution: 0.93,
                friction: 0.2,
            },
            sigma: [0.02, 0.05, 0.003, 0.01],
            tracks: 12,
            flight_sigma: [0.03, 0.1, 0.02, 0.0],
            reynolds_exponents: [0.0, -0.8],
            reynolds_sigma: [0.1, 0.05],
            reynolds_prior_sigma: [0.1, 0.3],
        }
    }

    /// The message of a 1 s period with no detection processed and no track.
    fn transport_only(
        node: &str,
        now: &TransportCounters,
        before: &TransportCounters,
        queue_len: usize,
    ) -> DiagnosticArray {
        diagnostics_msg(
            &Snapshot {
                node,
                detections_topic: "/ball/detections",
                stamp: 0,
                period: 1.0,
                counters: &Counters::default(),
                transport: now,
                transport_before: before,
                queue_len,
                track: None,
                learned: &learned(),
                learned_noise: &[],
            },
            &mut Window::default(),
        )
    }

    #[test]
    fn drops_in_the_period_warn() {
        let before = TransportCounters::default();
        let now = TransportCounters {
            received: 500,
            dropped_queue_full: 20,
            ..before
        };
        let msg = transport_only("/robot/ttball", &now, &before, 256);
        assert_eq!(msg.status[0].level, DiagnosticStatus::WARN);
        assert!(msg.status[0].message.starts_with("20 detections dropped"));
        assert_eq!(value(&msg, "rejected: queue full"), "20");
        assert_eq!(msg.status[0].name, "robot/ttball: estimator");
    }

    #[test]
    fn losses_before_the_node_in_the_period_warn_and_are_not_rejections() {
        let before = TransportCounters {
            received: 400,
            lost_before_node: 2,
            ..TransportCounters::default()
        };
        let now = TransportCounters {
            received: 500,
            lost_before_node: 9,
            ..before
        };
        let msg = transport_only("/ttball", &now, &before, 0);
        assert_eq!(msg.status[0].level, DiagnosticStatus::WARN);
        assert!(
            msg.status[0]
                .message
                .starts_with("7 detections lost before the node"),
            "{}",
            msg.status[0].message
        );
        assert_eq!(value(&msg, "lost before the node"), "9");
        assert_eq!(value(&msg, "rejected"), "0");
    }
}
