//! Cost of the racket model a controller calls: one hit (impact with contact solve), one hit with
//! its return flight to the landing point, and one racket-command plan. `cargo bench --bench
//! stroke`.

use std::hint::black_box;

use criterion::{Criterion, criterion_group, criterion_main};
use nalgebra::{Vector2, Vector3};
use ttball::config::Config;
use ttball::online::stroke::{Aim, ReturnCondition, Stroke};
use ttball::physics::{BallState, RacketModel, RacketState};

/// The real rally ball of `ttball predict` at the default hitting plane.
fn incoming() -> BallState {
    BallState::new(
        Vector3::new(-1.6, -0.067, 0.359),
        Vector3::new(-2.58, -0.06, 0.45),
        Vector3::new(3.0, -137.0, -4.0),
    )
}

fn benches(c: &mut Criterion) {
    let config = Config::default();
    let model = RacketModel::new(&config);
    let stroke = Stroke::new(&config);
    let ball = incoming();
    let racket = RacketState {
        velocity: Vector3::new(2.7, 0.0, 0.0),
        normal: Vector3::x(),
        impact_offset: 0.0,
    };
    let mut group = c.benchmark_group("stroke");
    group.bench_function("hit", |b| b.iter(|| model.hit(black_box(&ball), &racket)));
    group.bench_function("rebound_with_return_flight", |b| {
        b.iter(|| stroke.rebound(black_box(&ball), &racket))
    });
    for (name, condition) in [
        ("plan_net_clearance", ReturnCondition::NetClearance(0.15)),
        ("plan_flight_time", ReturnCondition::FlightTime(0.5)),
    ] {
        let aim = Aim {
            target: Vector2::new(0.9, 0.3),
            condition,
            impact_offset: 0.0,
            brush_speed: 1.0,
        };
        group.bench_function(name, |b| b.iter(|| stroke.plan(black_box(&ball), &aim)));
    }
    group.finish();
}

criterion_group!(stroke, benches);
criterion_main!(stroke);
