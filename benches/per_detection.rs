//! The per-detection cost as the node pays it, and the whole replay as a user waits for it, on
//! the shipped bags: the real launcher flights (`bags/real_launcher.mcap`, 40 flights at about
//! 180 Hz, positions only) and the simulated play of both cameras and of the 150 fps camera
//! alone.
//!
//! Per detection: every detection message, in arrival order, through `Pipeline::on_detection`
//! (conversion, the filter's update with rollbacks, the interception with covariance, the
//! `/ball/state` and `/ball/intercept` messages, and the `/ball/trajectory` + markers at their
//! 50 Hz), the tracks' lessons on a worker thread that the detections never wait for, as in the
//! node. Criterion times each whole stream (its time over its count is the mean per
//! detection, trajectories included); then, over [`RUNS`] runs, each detection's own work
//! (`Pipeline::handle_detection`, what the node publishes before anything else) and each
//! trajectory after it (`Pipeline::add_due_trajectory`) are timed alone for the tail. The whole
//! replay (`ttball::bag::replay::replay`: reading, decoding, the pipeline, encoding,
//! compressing, writing a new file) is timed [`RUNS`] times, its median quoted as a multiple of
//! real time.
//!
//! `cargo bench --bench per_detection` prints README.md's performance table last.
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    reason = "benchmark: fail loudly"
)]

use std::hint::black_box;
use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicBool;
use std::time::{Duration, Instant};

use criterion::{Criterion, criterion_group, criterion_main};
use ttball::bag::replay::{read_detections, replay};
use ttball::config::Config;
use ttball::online::estimator::Waiting;
use ttball::ros::msgs::convert::detection_to_msg;
use ttball::ros::msgs::ttball_msgs::msg::BallDetection;
use ttball::ros::pipeline::Pipeline;

/// Runs of each stream timed call by call, and of each whole replay.
const RUNS: usize = 5;

/// The shipped bags, with what README.md calls them.
const BAGS: [(&str, &str); 3] = [
    ("real_launcher", "real launcher flights, 180 Hz"),
    ("sim_rally_2cams", "simulated play, 150 + 900 fps"),
    ("sim_rally_wide", "simulated play, 150 fps alone"),
];

fn bag(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join(format!("bags/{name}.mcap"))
}

/// A pipeline as the node starts it.
fn node_pipeline(config: &Config) -> Pipeline {
    let mut pipeline = Pipeline::new(config);
    pipeline
        .run_lessons_on_a_worker(Waiting::Never)
        .expect("the lessons' thread starts");
    pipeline
}

/// The detection messages of a shipped bag.
fn messages(config: &Config, name: &str) -> Vec<BallDetection> {
    let read = read_detections(&bag(name), config).expect("the shipped bag reads");
    read.detections.iter().map(detection_to_msg).collect()
}

fn quantile(sorted: &[u64], q: f64) -> f64 {
    if sorted.is_empty() {
        return 0.0;
    }
    sorted[((sorted.len() - 1) as f64 * q).round() as usize] as f64 * 1e-3
}

fn benches(c: &mut Criterion) {
    let config = Config::default();
    let streams: Vec<_> = BAGS
        .iter()
        .map(|(name, what)| (*name, *what, messages(&config, name)))
        .collect();
    let mut group = c.benchmark_group("per_detection");
    group.sample_size(10);
    for (name, _, messages) in &streams {
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

    let machine = std::thread::available_parallelism().map_or(1, |n| n.get());
    println!(
        "\n| bag ({machine} cores) | per detection, its own work: mean / p50 / p99 / p99.9 / max \
         [us] | then each trajectory: mean / p99 [us] | whole replay [x real time] |\n\
         |---|---|---|---|"
    );
    let cancel = AtomicBool::new(false);
    let output = Path::new(env!("CARGO_TARGET_TMPDIR")).join("bench-per-detection.mcap");
    for (name, what, messages) in &streams {
        let (mut times, mut trajectories) = (Vec::with_capacity(RUNS * messages.len()), Vec::new());
        for _ in 0..RUNS {
            let mut pipeline = node_pipeline(&config);
            for msg in messages {
                let started = Instant::now();
                let mut step = black_box(pipeline.handle_detection(black_box(msg)));
                times.push(started.elapsed().as_nanos() as u64);
                let started = Instant::now();
                if black_box(pipeline.add_due_trajectory(&mut step.published)) {
                    trajectories.push(started.elapsed().as_nanos() as u64);
                }
            }
        }
        times.sort_unstable();
        trajectories.sort_unstable();
        let mean = |t: &[u64]| t.iter().sum::<u64>() as f64 / t.len().max(1) as f64 * 1e-3;
        let mut factors: Vec<f64> = (0..RUNS)
            .map(|_| {
                // Into a new file, as a first replay writes: the replay's own time, not the
                // kernel's freeing an earlier output (about 3 ms for the launcher's 12 MB here).
                let _ = std::fs::remove_file(&output);
                let started = Instant::now();
                let summary = replay(&bag(name), &output, &config, &mut |_, _| {}, &cancel)
                    .expect("the shipped bag replays");
                summary.recorded_seconds / started.elapsed().as_secs_f64()
            })
            .collect();
        factors.sort_by(f64::total_cmp);
        println!(
            "| {what} (`bags/{name}.mcap`) | {:.1} / {:.1} / {:.1} / {:.1} / {:.1} | {:.1} / {:.1} \
             | {:.0} |",
            mean(&times),
            quantile(&times, 0.5),
            quantile(&times, 0.99),
            quantile(&times, 0.999),
            times.last().copied().unwrap_or(0) as f64 * 1e-3,
            mean(&trajectories),
            quantile(&trajectories, 0.99),
            factors[RUNS / 2]
        );
    }
}

criterion_group!(per_detection, benches);
criterion_main!(per_detection);
