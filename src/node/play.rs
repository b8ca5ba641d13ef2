//! `ttball play`: publishes a bag's detections on DDS at their recorded pace, like
//! `ros2 bag play`, so that a robot stack (or `ttball node`) can be tested against recorded
//! rallies without ROS 2 installed. Same QoS, names and types as the node's subscription.
//!
//! With [`PlayOptions::measure_latency`] it also subscribes to the node's `/ball/state` and
//! `/ball/intercept` and reports the end-to-end latency of a live node: for each output, the time
//! from publishing the detection with its stamp to receiving it (one process, one monotonic
//! clock; through both DDS stacks and the network).

use std::collections::HashMap;
use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use futures::channel::oneshot;
use futures::{FutureExt, StreamExt};
use ros2_client::{NodeName, Publisher, Subscription};
use tracing::{info, warn};

use super::{NodeError, Placement, dds};
use crate::bag::{decode, read_bag_file};
use crate::config::Config;
use crate::msgs::builtin_interfaces::Time;
use crate::msgs::ttball_msgs::msg::{BallDetection, BallState, InterceptPrediction};
use crate::replay::{INTERCEPT_TYPE, STATE_TYPE, detection_channel};

/// How to play.
#[derive(Debug, Clone, PartialEq)]
pub struct PlayOptions {
    /// Speed factor: 2 plays twice as fast as recorded.
    pub rate: f64,
    /// Play again and again until cancelled; each pass's stamps are shifted by the passes
    /// before, so time keeps going forward for the estimator.
    pub repeat: bool,
    /// Wait this long for a subscriber before the first detection (best-effort samples sent
    /// before discovery are lost); zero starts at once.
    pub wait_for_subscriber: Duration,
    /// Subscribe to the node's state and intercept topics and measure the latency of each
    /// output (see the module doc).
    pub measure_latency: bool,
}

/// The latency of one output topic: publishing a detection -> receiving the output with its
/// stamp (the first one received per stamp).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Latency {
    /// Outputs received that matched a published detection.
    pub received: u64,
    /// Median [s].
    pub p50: f64,
    /// 99th percentile [s].
    pub p99: f64,
    /// Largest [s].
    pub max: f64,
}

impl Latency {
    /// The latencies of the first receipt of each stamp in `received` (stamp [ns], time) of a
    /// detection published at the time `sent` gives for its stamp.
    fn of(sent: &HashMap<i64, Instant>, received: &[(i64, Instant)]) -> Self {
        let mut seen = std::collections::HashSet::new();
        let mut seconds: Vec<f64> = received
            .iter()
            .filter(|(stamp, _)| seen.insert(*stamp))
            .filter_map(|(stamp, at)| Some(at.saturating_duration_since(*sent.get(stamp)?)))
            .map(|d| d.as_secs_f64())
            .collect();
        seconds.sort_by(f64::total_cmp);
        let quantile = |q: f64| {
            let last = seconds.len().saturating_sub(1);
            seconds
                .get((last as f64 * q).round() as usize)
                .copied()
                .unwrap_or(0.0)
        };
        Self {
            received: seconds.len() as u64,
            p50: quantile(0.5),
            p99: quantile(0.99),
            max: seconds.last().copied().unwrap_or(0.0),
        }
    }
}

/// The end-to-end latency of a live node's outputs.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct LatencyReport {
    /// `topics.state`.
    pub state: Latency,
    /// `topics.intercept`.
    pub intercept: Latency,
}

/// What a play did.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct PlaySummary {
    /// Detections published.
    pub published: u64,
    /// Detection messages of the bag that did not decode (skipped).
    pub undecodable: u64,
    /// Detections DDS refused to publish.
    pub errors: u64,
    /// Passes over the bag begun.
    pub passes: u64,
    /// Subscribers matched when playing started.
    pub subscribers: usize,
    /// Wall time spent [s].
    pub seconds: f64,
    /// The node's latency, when measured.
    pub latency: Option<LatencyReport>,
}

/// Gap between two passes of a repeated play, in both wall and stamp time [ns].
const PASS_GAP_NS: i64 = 500_000_000;

/// Plays the detections of `bag` (see the module doc). `progress` gets (published in this pass,
/// detections per pass); `cancel` stops at the next detection.
pub fn play(
    bag: &Path,
    config: &Config,
    placement: &Placement,
    options: &PlayOptions,
    cancel: &AtomicBool,
    progress: &mut dyn FnMut(u64, u64),
) -> Result<PlaySummary, NodeError> {
    let contents = read_bag_file(bag).map_err(crate::replay::ReplayError::from)?;
    let channel = detection_channel(&contents.channels, &config.topics.detections, bag)?;
    let mut undecodable = 0u64;
    let detections: Vec<(u64, BallDetection)> = contents
        .messages
        .iter()
        .filter(|m| m.channel == channel)
        .filter_map(|m| match decode::<BallDetection>(&m.data) {
            Ok(msg) => Some((m.log_time, msg)),
            Err(_) => {
                undecodable += 1;
                None
            }
        })
        .collect();
    let (Some((first, _)), Some((last, _))) = (detections.first(), detections.last()) else {
        return Ok(PlaySummary {
            undecodable,
            ..PlaySummary::default()
        });
    };
    let span = i64::try_from(last - first).unwrap_or(i64::MAX);

    let context = dds::context(placement.domain, placement.interfaces.as_deref())?;
    let name = NodeName::new("/", "ttball_play").map_err(|e| NodeError::Name(e.to_string()))?;
    let mut node = dds::node(&context, name, false)?;
    let topic = dds::detections_topic(&mut node, config)?;
    let publisher: Publisher<BallDetection> =
        node.create_publisher(&topic, None).map_err(dds::error)?;
    let listener = if options.measure_latency {
        Some(Listener::start(&mut node, config)?)
    } else {
        None
    };
    let spinner = dds::spawn_spinner(&mut node)?;

    let started = Instant::now();
    let deadline = started + options.wait_for_subscriber;
    while node.subscription_count(&config.topics.detections) == 0
        && Instant::now() < deadline
        && !cancel.load(Ordering::Relaxed)
    {
        std::thread::sleep(Duration::from_millis(20));
    }
    let subscribers = node.subscription_count(&config.topics.detections);
    if subscribers == 0 && !options.wait_for_subscriber.is_zero() {
        warn!(
            "no subscriber of {} after {:.1} s; playing anyway",
            config.topics.detections,
            options.wait_for_subscriber.as_secs_f64()
        );
    } else {
        info!(
            "{subscribers} subscriber(s) of {}",
            config.topics.detections
        );
    }

    let mut summary = PlaySummary {
        undecodable,
        subscribers,
        ..PlaySummary::default()
    };
    let total = detections.len() as u64;
    let rate = options.rate;
    // When each stamp was published [ns -> time], for the latency.
    let mut sent = HashMap::with_capacity(if listener.is_some() {
        detections.len()
    } else {
        0
    });
    'passes: loop {
        let pass_start = Instant::now();
        let shift = i64::try_from(summary.passes)
            .unwrap_or(i64::MAX)
            .saturating_mul(span.saturating_add(PASS_GAP_NS));
        summary.passes += 1;
        for (i, (log_time, msg)) in detections.iter().enumerate() {
            let offset = Duration::from_secs_f64((log_time - first) as f64 * 1e-9 / rate);
            if !sleep_until(pass_start + offset, cancel) {
                break 'passes;
            }
            let mut msg = msg.clone();
            if shift != 0 {
                msg.header.stamp = Time::from_nanos(msg.header.stamp.to_nanos() + shift);
            }
            if listener.is_some() {
                sent.insert(msg.header.stamp.to_nanos(), Instant::now());
            }
            match publisher.publish(msg) {
                Ok(()) => summary.published += 1,
                Err(_) => summary.errors += 1,
            }
            if i % 256 == 0 {
                progress(i as u64, total);
            }
        }
        progress(total, total);
        if !options.repeat
            || !sleep_until(
                Instant::now() + Duration::from_secs_f64(PASS_GAP_NS as f64 * 1e-9 / rate),
                cancel,
            )
        {
            break;
        }
    }
    // Let the last samples leave (and their outputs come back) before the participant goes.
    std::thread::sleep(Duration::from_millis(if listener.is_some() {
        500
    } else {
        100
    }));
    if let Some(listener) = listener {
        let (states, intercepts) = listener.finish()?;
        summary.latency = Some(LatencyReport {
            state: Latency::of(&sent, &states),
            intercept: Latency::of(&sent, &intercepts),
        });
    }
    summary.seconds = started.elapsed().as_secs_f64();
    // Readers and writers go before their node, the node (and its spinner) before the
    // participant.
    drop(publisher);
    drop(topic);
    spinner.stop_with(node);
    drop(context);
    Ok(summary)
}

/// Stamps [ns] of received outputs and when they arrived.
type Arrivals = Vec<(i64, Instant)>;

/// A thread taking the node's state and intercept samples off DDS, noting when each arrived.
struct Listener {
    stop: oneshot::Sender<()>,
    thread: std::thread::JoinHandle<(Arrivals, Arrivals)>,
}

impl Listener {
    fn start(node: &mut ros2_client::Node, config: &Config) -> Result<Self, NodeError> {
        let qos = dds::reliable(config.qos.outputs_depth);
        let subscribe = |topic: &str, ros_type: &str| {
            node.create_topic(&dds::name(topic)?, dds::message_type(ros_type), &qos)
                .map_err(dds::error)
        };
        let state_topic = subscribe(&config.topics.state, STATE_TYPE)?;
        let intercept_topic = subscribe(&config.topics.intercept, INTERCEPT_TYPE)?;
        let states: Subscription<BallState> = node
            .create_subscription(&state_topic, None)
            .map_err(dds::error)?;
        let intercepts: Subscription<InterceptPrediction> = node
            .create_subscription(&intercept_topic, None)
            .map_err(dds::error)?;
        let (stop, stopped) = oneshot::channel::<()>();
        let thread = std::thread::Builder::new()
            .name("ttball-play-listener".to_owned())
            .spawn(move || {
                let (mut state_arrivals, mut intercept_arrivals) = (Vec::new(), Vec::new());
                futures::executor::block_on(async {
                    let state_stream = states.async_stream();
                    let intercept_stream = intercepts.async_stream();
                    futures::pin_mut!(state_stream, intercept_stream);
                    let mut stopped = stopped.fuse();
                    loop {
                        futures::select! {
                            sample = state_stream.select_next_some() => if let Ok((m, _)) = sample {
                                state_arrivals.push((m.header.stamp.to_nanos(), Instant::now()));
                            },
                            sample = intercept_stream.select_next_some() => if let Ok((m, _)) = sample {
                                intercept_arrivals.push((m.header.stamp.to_nanos(), Instant::now()));
                            },
                            _ = stopped => break,
                        }
                    }
                });
                (state_arrivals, intercept_arrivals)
            })
            .map_err(|e| NodeError::Thread(e.to_string()))?;
        Ok(Self { stop, thread })
    }

    fn finish(self) -> Result<(Arrivals, Arrivals), NodeError> {
        let _ = self.stop.send(());
        self.thread
            .join()
            .map_err(|_| NodeError::Thread("the latency listener panicked".to_owned()))
    }
}

/// Sleeps until `when` in short steps; false when cancelled.
fn sleep_until(when: Instant, cancel: &AtomicBool) -> bool {
    loop {
        if cancel.load(Ordering::Relaxed) {
            return false;
        }
        let now = Instant::now();
        if now >= when {
            return true;
        }
        std::thread::sleep((when - now).min(Duration::from_millis(50)));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn latency_matches_stamps_and_counts_the_first_receipt_only() {
        let t0 = Instant::now();
        let at = |us: u64| t0 + Duration::from_micros(us);
        let published: HashMap<i64, Instant> =
            (0..100).map(|i| (i * 1000, at(i as u64 * 1000))).collect();
        // Stamp i arrives i + 1 us... 100 us after it was published; stamp 7 twice (the second
        // receipt is not counted); a stamp never published is ignored.
        let mut received: Vec<(i64, Instant)> = (0..100)
            .map(|i| (i * 1000, at(i as u64 * 1000 + i as u64 + 1)))
            .collect();
        received.push((7000, at(900_000)));
        received.push((123, at(5)));
        let l = Latency::of(&published, &received);
        assert_eq!(l.received, 100);
        assert!((l.p50 - 51e-6).abs() < 1e-9, "{}", l.p50);
        assert!((l.p99 - 99e-6).abs() < 1e-9, "{}", l.p99);
        assert!((l.max - 100e-6).abs() < 1e-9, "{}", l.max);
        assert_eq!(Latency::of(&published, &[]), Latency::default());
    }
}
