//! `ttball play`: publishes a bag's detections on DDS at their recorded pace, like
//! `ros2 bag play`, so that a robot stack (or `ttball node`) can be tested against recorded
//! rallies without ROS 2 installed. Same QoS, names and types as the node's subscription.

use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use ros2_client::{NodeName, Publisher};
use tracing::{info, warn};

use super::{NodeError, Placement, dds};
use crate::bag::{decode, read_bag_file};
use crate::config::Config;
use crate::msgs::builtin_interfaces::Time;
use crate::msgs::ttball_msgs::msg::BallDetection;
use crate::replay::detection_channel;

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
    dds::spawn_spinner(&mut node)?;

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
    // Let the last samples leave before the participant goes.
    std::thread::sleep(Duration::from_millis(100));
    summary.seconds = started.elapsed().as_secs_f64();
    Ok(summary)
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
