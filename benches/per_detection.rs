//! The per-detection cost as the node pays it: every detection message of a stream, in arrival
//! order, through `Pipeline::on_detection` (conversion, the filter's update with rollbacks, the
//! interception with covariance, the `/ball/state` and `/ball/intercept` messages, and the
//! `/ball/trajectory` + markers at their 50 Hz), the tracks' lessons on a worker thread that
//! the detections never wait for, as in the node.
//!
//! Two streams: the real launcher flights (`bags/real_launcher.mcap`, 40 flights at about
//! 180 Hz, positions only) and a simulated session of both cameras (150 + 900 fps, seed 11).
//! Criterion times each whole stream (its mean per detection is the time over the count);
//! each call is then timed alone over [`RUNS`] runs for the tail: mean, p50, p90, p99, p99.9
//! and max. `cargo bench --bench per_detection` (pin it to one core, `taskset -c 1`, for the
//! detection path alone; the worker then shares that core).
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    reason = "benchmark: fail loudly"
)]

use std::hint::black_box;
use std::path::Path;
use std::time::{Duration, Instant};

use criterion::{Criterion, criterion_group, criterion_main};
use ttball::bag::replay::read_detections;
use ttball::config::Config;
use ttball::eval::sim::{Cameras, SimOptions, simulate};
use ttball::model::detection::Detection;
use ttball::online::estimator::{Estimator, Waiting};
use ttball::ros::msgs::convert::detection_to_msg;
use ttball::ros::msgs::ttball_msgs::msg::BallDetection;
use ttball::ros::pipeline::Pipeline;

/// Runs of each stream timed call by call.
const RUNS: usize = 5;

fn quantile(sorted: &[u64], q: f64) -> f64 {
    sorted[((sorted.len() - 1) as f64 * q).round() as usize] as f64 * 1e-3
}

/// One line of the table: the calls' count, mean and quantiles [us].
fn report(name: &str, mut ns: Vec<u64>) {
    ns.sort_unstable();
    let mean = ns.iter().sum::<u64>() as f64 / ns.len().max(1) as f64 * 1e-3;
    println!(
        "{name:<32} {:>8} {:>7.1} {:>7.1} {:>7.1} {:>7.1} {:>7.1} {:>8.1}",
        ns.len(),
        mean,
        quantile(&ns, 0.5),
        quantile(&ns, 0.9),
        quantile(&ns, 0.99),
        quantile(&ns, 0.999),
        ns.last().copied().unwrap_or(0) as f64 * 1e-3,
    );
}

/// A pipeline as the node starts it.
fn node_pipeline(config: &Config) -> Pipeline {
    let mut pipeline = Pipeline::new(config);
    pipeline
        .run_lessons_on_a_worker(Waiting::Never)
        .expect("the lessons' thread starts");
    pipeline
}

/// A stream: its name, its messages and the detections in them.
type Stream = (&'static str, Vec<BallDetection>, Vec<Detection>);

/// The streams: the real launcher flights, and a simulated session of both cameras.
fn streams(config: &Config) -> Vec<Stream> {
    let bag = Path::new(env!("CARGO_MANIFEST_DIR")).join("bags/real_launcher.mcap");
    let real = read_detections(&bag, config).expect("the shipped bag reads");
    let session = simulate(
        config,
        &SimOptions {
            cameras: Cameras::WideAndHighSpeed,
            shots: 20,
            seed: 11,
            ..SimOptions::default()
        },
    )
    .expect("simulate");
    vec![
        (
            "real_launcher",
            real.detections.iter().map(detection_to_msg).collect(),
            real.detections.clone(),
        ),
        (
            "simulated_2cams",
            session
                .stream
                .iter()
                .map(|d| detection_to_msg(&d.detection))
                .collect(),
            session.stream.iter().map(|d| d.detection).collect(),
        ),
    ]
}

fn benches(c: &mut Criterion) {
    let config = Config::default();
    let streams = streams(&config);
    let mut group = c.benchmark_group("per_detection");
    group.sample_size(10);
    for (name, messages, _) in &streams {
        group.bench_function(*name, |b| {
            b.iter_custom(|iterations| {
                let mut total = Duration::ZERO;
                for _ in 0..iterations {
                    let mut pipeline = node_pipeline(&config);
                    let started = Instant::now();
                    for msg in messages {
                        black_box(pipeline.on_detection(black_box(msg)));
                    }
                    total += started.elapsed() / messages.len() as u32;
                }
                total
            })
        });
    }
    group.finish();

    println!("each call timed alone, {RUNS} runs; times in us");
    println!(
        "{:<32} {:>8} {:>7} {:>7} {:>7} {:>7} {:>7} {:>8}",
        "stream", "calls", "mean", "p50", "p90", "p99", "p99.9", "max"
    );
    for (name, messages, detections) in &streams {
        let (mut node, mut handle, mut update) = (vec![], vec![], vec![]);
        for _ in 0..RUNS {
            let mut pipeline = node_pipeline(&config);
            for msg in messages {
                let started = Instant::now();
                black_box(pipeline.on_detection(black_box(msg)));
                node.push(started.elapsed().as_nanos() as u64);
            }
            // The parts: the estimator alone (filter and interception), the filter alone.
            for (times, whole) in [(&mut handle, true), (&mut update, false)] {
                let mut estimator = Estimator::new(&config);
                estimator
                    .run_lessons_on_a_worker(Waiting::Never)
                    .expect("the lessons' thread starts");
                for d in detections {
                    let started = Instant::now();
                    if whole {
                        black_box(estimator.handle(black_box(d)));
                    } else {
                        black_box(estimator.update(black_box(d)));
                    }
                    times.push(started.elapsed().as_nanos() as u64);
                }
            }
        }
        report(name, node);
        report("  Estimator::handle", handle);
        report("  Estimator::update (the filter)", update);
    }
}

criterion_group!(per_detection, benches);
criterion_main!(per_detection);
