//! The whole replay as a user waits for it: `ttball::bag::replay::replay` of the shipped
//! `bags/sim_rally_2cams.mcap` (9.1 s of 150 + 900 fps play with the simulator's truth, 3,121
//! detections) into a file: reading, decoding, the node's pipeline, scoring against the truth,
//! encoding, compressing and writing. With more than one core the output is written on a thread
//! of its own; pinned to one (`taskset -c 1 cargo bench --bench replay`) in the replay's thread.
//! The real-time factor is 9.1 s over the time quoted. The per-detection cost alone is
//! `cargo bench --bench per_detection`.
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    reason = "benchmark: fail loudly"
)]

use std::path::Path;
use std::sync::atomic::AtomicBool;

use criterion::{Criterion, criterion_group, criterion_main};
use ttball::bag::replay::replay;
use ttball::config::Config;

fn benches(c: &mut Criterion) {
    let config = Config::default();
    let input = Path::new(env!("CARGO_MANIFEST_DIR")).join("bags/sim_rally_2cams.mcap");
    let output = Path::new(env!("CARGO_TARGET_TMPDIR")).join("bench-replay.mcap");
    let cancel = AtomicBool::new(false);
    let mut group = c.benchmark_group("replay_whole");
    group.sample_size(20);
    group.bench_function("sim_rally_2cams", |b| {
        b.iter(|| {
            let summary = replay(&input, &output, &config, &mut |_, _| {}, &cancel)
                .expect("the shipped bag replays");
            assert_eq!(summary.detections, 3121);
        })
    });
    group.finish();
}

criterion_group!(replay_benches, benches);
criterion_main!(replay_benches);
