//! The distribution of the per-detection cost over a whole stream, as the node pays it: every
//! detection message of a simulated 150 + 900 fps session, in arrival order, through
//! `Pipeline::on_detection` (conversion, filter update with rollbacks, interception with
//! covariance, the `/ball/state` and `/ball/intercept` messages, and the `/ball/trajectory` +
//! markers at their 50 Hz). Each call is timed alone; the stream is run several times with a
//! fresh pipeline and the quantiles taken over all calls. Criterion measures one input at a
//! time; this measures the tail. `cargo bench --bench per_detection` (pin it to one core with
//! `taskset -c 1` for the figures in the README).
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    reason = "benchmark: fail loudly"
)]

use std::hint::black_box;
use std::time::Instant;

use ttball::config::Config;
use ttball::eval::sim::{Cameras, SimOptions, simulate};
use ttball::online::estimator::Estimator;
use ttball::ros::msgs::convert::detection_to_msg;
use ttball::ros::pipeline::Pipeline;

const RUNS: usize = 5;

fn quantile(sorted: &[u64], q: f64) -> f64 {
    sorted[((sorted.len() - 1) as f64 * q).round() as usize] as f64 * 1e-3
}

fn report(name: &str, mut ns: Vec<u64>) {
    if ns.is_empty() {
        return;
    }
    ns.sort_unstable();
    let mean = ns.iter().sum::<u64>() as f64 / ns.len() as f64 * 1e-3;
    println!(
        "{name:<44} {:>8} {:>7.1} {:>7.1} {:>7.1} {:>7.1} {:>7.1} {:>8.1}",
        ns.len(),
        mean,
        quantile(&ns, 0.5),
        quantile(&ns, 0.9),
        quantile(&ns, 0.99),
        quantile(&ns, 0.999),
        *ns.last().unwrap() as f64 * 1e-3,
    );
}

fn main() {
    // `cargo bench` passes `--bench`; `cargo test --benches` runs it once, quickly.
    let quick = !std::env::args().any(|a| a == "--bench");
    let config = Config::default();
    let session = simulate(
        &config,
        &SimOptions {
            cameras: Cameras::WideAndHighSpeed,
            shots: if quick { 2 } else { 40 },
            seed: 11,
            ..SimOptions::default()
        },
    )
    .expect("simulate");
    let messages: Vec<_> = session
        .stream
        .iter()
        .map(|d| detection_to_msg(&d.detection))
        .collect();
    let runs = if quick { 1 } else { RUNS };
    // The 150 fps camera alone: every track's lesson is its flight smoothed when it ends.
    let wide = simulate(
        &config,
        &SimOptions {
            cameras: Cameras::WideOnly,
            shots: if quick { 2 } else { 40 },
            seed: 11,
            ..SimOptions::default()
        },
    )
    .expect("simulate");
    let mut filter_lessons = config.clone();
    filter_lessons.adaptation.smoothed_lessons = false;
    let (mut wide_smoothed, mut wide_filter) = (vec![], vec![]);
    let (mut wide_idle, mut idle_stages) = (vec![], vec![]);

    let (mut all, mut without_trajectory, mut with_trajectory) = (vec![], vec![], vec![]);
    let (mut filter_only, mut handle) = (vec![], vec![]);
    for _ in 0..runs {
        let mut pipeline = Pipeline::new(&config);
        for msg in &messages {
            let started = Instant::now();
            let step = pipeline.on_detection(black_box(msg));
            let ns = started.elapsed().as_nanos() as u64;
            all.push(ns);
            if step.published.trajectory.is_some() {
                with_trajectory.push(ns);
            } else {
                without_trajectory.push(ns);
            }
            black_box(step);
        }
        let mut estimator = Estimator::new(&config);
        for d in &session.stream {
            let started = Instant::now();
            black_box(estimator.handle(black_box(&d.detection)));
            handle.push(started.elapsed().as_nanos() as u64);
        }
        let mut estimator = Estimator::new(&config);
        for d in &session.stream {
            let started = Instant::now();
            black_box(estimator.update(black_box(&d.detection)));
            filter_only.push(started.elapsed().as_nanos() as u64);
        }
        // As the node runs it: an ended track's lesson a stage at a time while no detection
        // waits (150 fps: 6.7 ms between frames), timed apart.
        let mut estimator = Estimator::new(&config);
        for d in &wide.stream {
            let started = Instant::now();
            black_box(estimator.handle(black_box(&d.detection)));
            wide_idle.push(started.elapsed().as_nanos() as u64);
            while estimator.has_idle_work() {
                let started = Instant::now();
                estimator.learn_in_idle_time();
                idle_stages.push(started.elapsed().as_nanos() as u64);
            }
        }
        for (config, times) in [
            (&config, &mut wide_smoothed),
            (&filter_lessons, &mut wide_filter),
        ] {
            let mut estimator = Estimator::new(config);
            for d in &wide.stream {
                let started = Instant::now();
                black_box(estimator.handle(black_box(&d.detection)));
                times.push(started.elapsed().as_nanos() as u64);
            }
        }
    }
    println!(
        "{} detections ({} shots, 150 + 900 fps) x {runs} runs; times in us",
        messages.len(),
        session.shots.len()
    );
    println!(
        "{:<44} {:>8} {:>7} {:>7} {:>7} {:>7} {:>7} {:>8}",
        "path", "calls", "mean", "p50", "p90", "p99", "p99.9", "max"
    );
    report("Pipeline::on_detection (all)", all);
    report(
        "  without a trajectory (the per-detection path)",
        without_trajectory,
    );
    report("  with the 50 Hz trajectory + markers", with_trajectory);
    report("Estimator::handle (update + interception)", handle);
    report("Estimator::update (filter, rollbacks)", filter_only);
    println!(
        "the 150 fps camera alone: {} detections ({} shots) x {runs} runs",
        wide.stream.len(),
        wide.shots.len()
    );
    report("Estimator::handle, lessons in idle time (node)", wide_idle);
    report("  a lesson's stage, in idle time", idle_stages);
    report("Estimator::handle, lessons at once (replay)", wide_smoothed);
    report(
        "  the filter's lessons (smoothed_lessons: false)",
        wide_filter,
    );
}
