//! `ttball play`: publishes a bag's detections on DDS at their recorded pace, like
//! `ros2 bag play`, so that a robot stack (or `ttball node`) can be tested against recorded
//! rallies without ROS 2 installed. Same QoS, names and types as the node's subscription.
//!
//! With [`PlayOptions::measure_latency`] it also subscribes to the node's `/ball/state` and
//! `/ball/intercept` and reports the end-to-end latency of a live node: for each output, the time
//! from publishing the detection with its stamp to receiving it (one process, one monotonic
//! clock; through both DDS stacks and the network), in bounded memory: a publication waits 5 s
//! for its outputs, and the latencies go into fixed histograms, so `--loop --latency` can run
//! for hours.

use std::collections::HashMap;
use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use crossbeam::channel::{self, Receiver, Sender};
use futures::channel::oneshot;
use futures::{FutureExt, StreamExt};
use ros2_client::{NodeName, Publisher, Subscription};
use tracing::{info, warn};

use super::{NodeError, Placement, dds};
use crate::bag::replay::{INTERCEPT_TYPE, STATE_TYPE, detection_channel};
use crate::bag::{decode, read_bag_file};
use crate::config::Config;
use crate::model::stats::DurationHistogram;
use crate::ros::msgs::builtin_interfaces::Time;
use crate::ros::msgs::ttball_msgs::msg::{BallDetection, BallState, InterceptPrediction};

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
    fn of(histogram: &DurationHistogram) -> Self {
        let summary = histogram.summary();
        Self {
            received: summary.count as u64,
            p50: summary.p50 * 1e-9,
            p99: summary.p99 * 1e-9,
            max: summary.max * 1e-9,
        }
    }
}

/// The node's outputs whose latency is measured.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Output {
    State = 0,
    Intercept = 1,
}

/// How long a publication waits for its outputs; later ones are not counted. Bounds the memory
/// of a measurement that runs for hours (`--loop --latency`).
const LATENCY_WINDOW: Duration = Duration::from_secs(5);

/// Matches the outputs received to the detections published, by stamp, in bounded memory: the
/// publications of the last [`LATENCY_WINDOW`] and one histogram per output.
struct LatencyMeter {
    /// Publication time of each recent stamp [ns], and whether each output has been received.
    pending: HashMap<i64, (Instant, [bool; 2])>,
    histograms: [DurationHistogram; 2],
    oldest_kept: Instant,
}

impl LatencyMeter {
    fn new() -> Self {
        Self {
            pending: HashMap::new(),
            histograms: [DurationHistogram::new(), DurationHistogram::new()],
            oldest_kept: Instant::now(),
        }
    }

    fn published(&mut self, stamp: i64, at: Instant) {
        self.pending.insert(stamp, (at, [false; 2]));
        // Forget what is older than the window, at most once per second of publications.
        if at.saturating_duration_since(self.oldest_kept) > LATENCY_WINDOW + Duration::from_secs(1)
        {
            let cutoff = at.checked_sub(LATENCY_WINDOW).unwrap_or(at);
            self.pending.retain(|_, (sent, _)| *sent >= cutoff);
            self.oldest_kept = cutoff;
        }
    }

    /// Counts the first receipt of each published stamp per output; others are ignored.
    fn received(&mut self, output: Output, stamp: i64, at: Instant) {
        let Some((sent, done)) = self.pending.get_mut(&stamp) else {
            return;
        };
        let index = output as usize;
        if !done[index] {
            done[index] = true;
            self.histograms[index].record(super::nanos(at.saturating_duration_since(*sent)));
        }
    }

    /// Counts the arrivals waiting in `arrivals`.
    fn take(&mut self, arrivals: &Receiver<(Output, i64, Instant)>) {
        for (output, stamp, at) in arrivals.try_iter() {
            self.received(output, stamp, at);
        }
    }

    fn report(&self) -> LatencyReport {
        LatencyReport {
            state: Latency::of(&self.histograms[Output::State as usize]),
            intercept: Latency::of(&self.histograms[Output::Intercept as usize]),
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

/// The detection messages of `bag` with their log times, and how many did not decode.
fn detections_of(
    bag: &Path,
    config: &Config,
) -> Result<(Vec<(u64, BallDetection)>, u64), NodeError> {
    let contents = read_bag_file(bag).map_err(crate::bag::replay::ReplayError::from)?;
    let channel = detection_channel(
        &contents.channels,
        &config.resolved_topics().detections,
        bag,
    )?;
    let mut undecodable = 0u64;
    let detections = contents
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
    Ok((detections, undecodable))
}

/// Waits up to `options.wait_for_subscriber` for a subscriber of the detections and says how
/// many there are.
fn wait_for_subscribers(
    node: &ros2_client::Node,
    config: &Config,
    options: &PlayOptions,
    cancel: &AtomicBool,
) -> usize {
    let topic = config.resolved_topics().detections;
    let deadline = Instant::now() + options.wait_for_subscriber;
    while node.subscription_count(&topic) == 0
        && Instant::now() < deadline
        && !cancel.load(Ordering::Relaxed)
    {
        std::thread::sleep(Duration::from_millis(20));
    }
    let subscribers = node.subscription_count(&topic);
    if subscribers == 0 && !options.wait_for_subscriber.is_zero() {
        warn!(
            "no subscriber of {topic} after {:.1} s; playing anyway",
            options.wait_for_subscriber.as_secs_f64()
        );
    } else {
        info!("{subscribers} subscriber(s) of {topic}");
    }
    subscribers
}

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
    let (detections, undecodable) = detections_of(bag, config)?;
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
    let mut listener = if options.measure_latency {
        Some(Listener::start(&mut node, config)?)
    } else {
        None
    };
    let spinner = dds::spawn_spinner(&mut node)?;

    let started = Instant::now();
    let subscribers = wait_for_subscribers(&node, config, options, cancel);

    let mut summary = PlaySummary {
        undecodable,
        subscribers,
        ..PlaySummary::default()
    };
    let total = detections.len() as u64;
    let rate = options.rate;
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
            if let Some(listener) = listener.as_mut() {
                listener
                    .meter
                    .published(msg.header.stamp.to_nanos(), Instant::now());
            }
            match publisher.publish(msg) {
                Ok(()) => summary.published += 1,
                Err(_) => summary.errors += 1,
            }
            if let Some(listener) = listener.as_mut() {
                listener.take_arrivals();
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
        summary.latency = Some(listener.finish()?);
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

/// A thread taking the node's state and intercept samples off DDS and handing over their stamps
/// [ns] and when they arrived, and the meter that matches them to the publications.
struct Listener {
    stop: oneshot::Sender<()>,
    thread: std::thread::JoinHandle<()>,
    arrivals: Receiver<(Output, i64, Instant)>,
    meter: LatencyMeter,
}

impl Listener {
    fn start(node: &mut ros2_client::Node, config: &Config) -> Result<Self, NodeError> {
        let qos = dds::reliable(config.qos.outputs_depth);
        let subscribe = |topic: &str, ros_type: &str| {
            node.create_topic(&dds::name(topic)?, dds::message_type(ros_type), &qos)
                .map_err(dds::error)
        };
        let state_topic = subscribe(&config.resolved_topics().state, STATE_TYPE)?;
        let intercept_topic = subscribe(&config.resolved_topics().intercept, INTERCEPT_TYPE)?;
        let states: Subscription<BallState> = node
            .create_subscription(&state_topic, None)
            .map_err(dds::error)?;
        let intercepts: Subscription<InterceptPrediction> = node
            .create_subscription(&intercept_topic, None)
            .map_err(dds::error)?;
        let (stop, stopped) = oneshot::channel::<()>();
        let (tx, arrivals) = channel::unbounded();
        let thread = std::thread::Builder::new()
            .name("ttball-play-listener".to_owned())
            .spawn(move || listen(&states, &intercepts, stopped, &tx))
            .map_err(|e| NodeError::Thread(e.to_string()))?;
        Ok(Self {
            stop,
            thread,
            arrivals,
            meter: LatencyMeter::new(),
        })
    }

    /// Counts the arrivals so far.
    fn take_arrivals(&mut self) {
        self.meter.take(&self.arrivals);
    }

    /// Stops the thread, counts the last arrivals and reports.
    fn finish(self) -> Result<LatencyReport, NodeError> {
        let Self {
            stop,
            thread,
            arrivals,
            mut meter,
        } = self;
        let _ = stop.send(());
        thread
            .join()
            .map_err(|_| NodeError::Thread("the latency listener panicked".to_owned()))?;
        meter.take(&arrivals);
        Ok(meter.report())
    }
}

fn listen(
    states: &Subscription<BallState>,
    intercepts: &Subscription<InterceptPrediction>,
    stopped: oneshot::Receiver<()>,
    arrivals: &Sender<(Output, i64, Instant)>,
) {
    futures::executor::block_on(async {
        let state_stream = states.async_stream();
        let intercept_stream = intercepts.async_stream();
        futures::pin_mut!(state_stream, intercept_stream);
        let mut stopped = stopped.fuse();
        loop {
            let (output, stamp) = futures::select! {
                sample = state_stream.select_next_some() => match sample {
                    Ok((m, _)) => (Output::State, m.header.stamp.to_nanos()),
                    Err(_) => continue,
                },
                sample = intercept_stream.select_next_some() => match sample {
                    Ok((m, _)) => (Output::Intercept, m.header.stamp.to_nanos()),
                    Err(_) => continue,
                },
                _ = stopped => break,
            };
            let _ = arrivals.send((output, stamp, Instant::now()));
        }
    });
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
        let mut meter = LatencyMeter::new();
        for i in 0..100 {
            meter.published(i * 1000, at(i as u64 * 1000));
        }
        // Stamp i's state arrives i + 1 us after it was published; stamp 7's twice (the second
        // receipt is not counted); a stamp never published is ignored; one intercept.
        for i in 0..100 {
            meter.received(Output::State, i * 1000, at(i as u64 * 1000 + i as u64 + 1));
        }
        meter.received(Output::State, 7000, at(900_000));
        meter.received(Output::State, 123, at(5));
        meter.received(Output::Intercept, 7000, at(7_250));
        let report = meter.report();
        let l = report.state;
        assert_eq!(l.received, 100);
        // HDR histogram quantiles: within 0.1 % of the sample's (at the rank or its neighbour).
        assert!(
            (50e-6 * 0.999..=51e-6 * 1.001).contains(&l.p50),
            "{}",
            l.p50
        );
        assert!(
            (99e-6 * 0.999..=100e-6 * 1.001).contains(&l.p99),
            "{}",
            l.p99
        );
        assert!((l.max - 100e-6).abs() < 1e-12, "{}", l.max);
        assert_eq!(report.intercept.received, 1);
        assert!((report.intercept.max - 250e-6).abs() < 1e-12);
        assert_eq!(LatencyMeter::new().report(), LatencyReport::default());
    }

    #[test]
    fn the_latency_meter_keeps_only_the_recent_publications() {
        let t0 = Instant::now();
        let mut meter = LatencyMeter::new();
        // An hour at 1000 publications per second.
        for i in 0..3_600_000u64 {
            meter.published(i as i64, t0 + Duration::from_millis(i));
        }
        assert!(
            meter.pending.len() <= 7_000,
            "{} publications kept",
            meter.pending.len()
        );
        // An output of a publication forgotten long ago is not counted; a recent one is.
        let now = t0 + Duration::from_millis(3_600_000);
        meter.received(Output::State, 10, now);
        meter.received(Output::State, 3_599_999, now);
        assert_eq!(meter.report().state.received, 1);
    }
}
