//! The rubber calibrated from recorded hits (`ttball calibrate --rebound`, issue 26) on the real
//! rebounds of tt_rackets (Gossard 2026; MIT; tests/data/tt_rackets): held-out errors per racket
//! and per rubber class, the shipped presets reproduced, the long pips' spin, a known rubber
//! recovered from synthetic hits, and the CSV format's errors.
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    reason = "test helpers outside #[test] functions: fail loudly"
)]

use std::path::{Path, PathBuf};
use std::process::Command;

use nalgebra::Vector3;
use ttball::config::Config;
use ttball::offline::rebound_calibration::{
    HitSet, HitsError, RubberCalibration, RubberCalibrationError, RubberOptions, calibrate_rubber,
};
use ttball::physics::racket::{RacketModel, RacketState};
use ttball::physics::state::BallState;

fn racket_file(racket: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data/tt_rackets/test")
        .join(format!("racket_{racket}.csv"))
}

fn hits(rackets: &[&str]) -> HitSet {
    let mut set = HitSet::default();
    for r in rackets {
        let text = std::fs::read_to_string(racket_file(r)).unwrap();
        set.add_csv(r, &text).unwrap();
    }
    assert!(set.rejected.is_empty(), "{:?}", set.rejected);
    set
}

/// The seeds' rubber (config/presets/rubber_sriver_seed.yaml), where every shipped rubber's
/// calibration starts.
fn seed_rubber() -> Config {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("config/presets/rubber_sriver_seed.yaml");
    ttball::config::yaml::load(Some(&path), &[] as &[String]).unwrap()
}

fn calibrated(rackets: &[&str]) -> RubberCalibration {
    calibrate_rubber(&seed_rubber(), &hits(rackets), &RubberOptions::default()).unwrap()
}

/// Held-out (velocity RMS, spin RMS) of `racket` in a cross-validated calibration.
fn held_out(c: &RubberCalibration, racket: &str) -> (f64, f64) {
    let cv = c.cross_validation.as_ref().unwrap();
    let e = cv.groups.iter().find(|g| g.group == racket).unwrap();
    (e.calibrated.velocity_rms, e.calibrated.spin_rms)
}

const INVERTED: [&str; 5] = ["01", "02", "03", "04", "09"];
/// The rubber classes of the shipped presets and their rackets.
const CLASSES: [(&str, &[&str]); 3] = [
    ("inverted_offensive", &["01", "03", "09"]),
    ("inverted_allround", &["02", "04"]),
    ("long_pips", &["05"]),
];

/// Calibrated on each inverted rubber alone, the model predicts the held-out hits (5 folds) to
/// 0.26-0.32 m/s velocity RMS (target 0.35) and 16-26 rad/s spin RMS (target 25: racket 09
/// misses it by 0.5 rad/s; its spin about the x axis, which no model term moves, carries a
/// measured offset of about -8 rad/s); the seed's rubber is at 1.4-1.6 m/s and 112-118 rad/s.
/// Over all five rackets' held-out hits: 0.29 m/s and 22 rad/s.
#[test]
fn calibrated_inverted_rubbers_predict_held_out_hits() {
    let (mut v2, mut w2, mut n) = (0.0, 0.0, 0.0);
    for racket in INVERTED {
        let c = calibrated(&[racket]);
        let (v, w) = held_out(&c, racket);
        let start = &c.cross_validation.as_ref().unwrap().overall.start;
        println!(
            "racket {racket}: velocity {:.3} -> {v:.3} m/s, spin {:.1} -> {w:.1} rad/s",
            start.velocity_rms, start.spin_rms
        );
        assert!(v <= 0.35, "racket {racket}: velocity {v}");
        assert!(
            w <= if racket == "09" { 26.0 } else { 25.0 },
            "racket {racket}: spin {w}"
        );
        assert!(start.velocity_rms > 1.4 && start.spin_rms > 110.0);
        let hits = c.predictions.len() as f64;
        v2 += v * v * hits;
        w2 += w * w * hits;
        n += hits;
    }
    let (v, w) = ((v2 / n).sqrt(), (w2 / n).sqrt());
    println!("all inverted: {v:.3} m/s, {w:.1} rad/s");
    assert!(v <= 0.30 && w <= 23.0, "{v} {w}");
}

/// The default rubber (one calibration on all five inverted rubbers) predicts each inverted
/// rubber's held-out hits (5 folds) to at most 0.40 m/s velocity and 30 rad/s spin RMS
/// (measured: 0.26-0.40 m/s, 16-26 rad/s); the seeds' SRIVER is at 1.4-1.6 m/s, 112-118 rad/s.
#[test]
fn the_default_rubber_predicts_every_inverted_rubber() {
    let pooled = calibrated(&INVERTED);
    for racket in INVERTED {
        let (v, w) = held_out(&pooled, racket);
        println!("default on {racket}: velocity {v:.3} m/s, spin {w:.1} rad/s");
        assert!(
            v <= 0.40 && w <= 30.0,
            "racket {racket}: {v} m/s, {w} rad/s"
        );
    }
    let fit = &pooled.fit;
    let all = fit.iter().find(|g| g.group == "all").unwrap();
    assert!(all.start.velocity_rms > 1.4 && all.start.spin_rms > 110.0);
}

/// One preset per rubber class, fitted to all its rackets, predicts each racket's held-out hits
/// within 1.3x of that racket's own calibration (measured: at most 1.17x, on racket 03's
/// velocity, 0.377 m/s against 0.322: over the 0.35 target by 8 %).
#[test]
fn a_preset_per_rubber_class_is_within_1_3x_of_per_racket_calibration() {
    for (class, rackets) in CLASSES {
        let pooled = calibrated(rackets);
        for racket in rackets {
            let own = held_out(&calibrated(&[racket]), racket);
            let shared = held_out(&pooled, racket);
            let ratio = (shared.0 / own.0, shared.1 / own.1);
            println!(
                "{class} on {racket}: velocity x{:.2}, spin x{:.2}",
                ratio.0, ratio.1
            );
            assert!(
                ratio.0 <= 1.3 && ratio.1 <= 1.3,
                "{class} on {racket}: {ratio:?}"
            );
        }
    }
}

/// The shipped presets are what the calibration gives on their rackets' hits.
#[test]
fn the_rubber_presets_are_what_calibration_gives() {
    for (class, rackets) in CLASSES {
        let path = Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("config/presets")
            .join(format!("rubber_{class}.yaml"));
        let preset = ttball::config::yaml::load(Some(&path), &[] as &[String]).unwrap();
        assert_same_rubber(class, &preset, rackets);
    }
    // The default rubber is the calibration on all five inverted rubbers.
    assert_same_rubber("default", &Config::default(), &INVERTED);
    // The seeds' rubber stays a named preset, known exactly.
    let seed = seed_rubber().racket;
    assert_eq!(seed.rubber_restitution, vec![0.77, -0.0123]);
    assert_eq!(
        (
            seed.rubber_friction,
            seed.rubber_tangential_restitution,
            seed.rubber_torsional_restitution
        ),
        (1.0, 0.0, 1.0)
    );
    assert!(seed.rubber_covariance.is_empty());
    assert_eq!(seed.rebound_scatter, vec![0.0, 0.0]);
}

/// `shipped`'s rubber is what the calibration from the seeds' rubber gives on `rackets`' hits,
/// its covariance and scatter included.
fn assert_same_rubber(class: &str, shipped: &Config, rackets: &[&str]) {
    let fitted = calibrate_rubber(
        &seed_rubber(),
        &hits(rackets),
        &RubberOptions {
            folds: 0,
            ..RubberOptions::default()
        },
    )
    .unwrap();
    let (p, f) = (&shipped.racket, &fitted.config.racket);
    let close = |a: f64, b: f64| (a - b).abs() < 2e-6;
    assert_eq!(p.rubber_restitution.len(), f.rubber_restitution.len());
    for (a, b) in p.rubber_restitution.iter().zip(&f.rubber_restitution) {
        assert!(close(*a, *b), "{class}: restitution {a} vs {b}");
    }
    assert!(close(p.rubber_friction, f.rubber_friction), "{class}");
    assert!(
        close(
            p.rubber_tangential_restitution,
            f.rubber_tangential_restitution
        ),
        "{class}"
    );
    assert!(
        close(
            p.rubber_torsional_restitution,
            f.rubber_torsional_restitution
        ),
        "{class}"
    );
    // Written to 7 significant digits (covariance) and 6 decimals (scatter).
    assert_eq!(
        p.rubber_covariance.len(),
        f.rubber_covariance.len(),
        "{class}"
    );
    for (a, b) in p.rubber_covariance.iter().zip(&f.rubber_covariance) {
        assert!(
            (a - b).abs() <= 1e-6 * b.abs() + 1e-15,
            "{class}: covariance {a} vs {b}"
        );
    }
    for (a, b) in p.rebound_scatter.iter().zip(&f.rebound_scatter) {
        assert!(close(*a, *b), "{class}: scatter {a} vs {b}");
    }
}

/// Long pips keep the incoming spin's sense where inverted rubbers return their own: with the
/// long-pips preset the outgoing spin about the face's y axis has the measured sign on 97 % of
/// the hits spinning faster than 50 rad/s (the inverted preset: 65 %), and keeps a median 0.49 of
/// the incoming spin where the rubber keeps 0.54.
#[test]
fn long_pips_keep_the_spin_as_measured() {
    let set = hits(&["05"]);
    let load = |class: &str| {
        let path = Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("config/presets")
            .join(format!("rubber_{class}.yaml"));
        RacketModel::new(&ttball::config::yaml::load(Some(&path), &[] as &[String]).unwrap())
    };
    let score = |model: &RacketModel| {
        let (mut agree, mut n) = (0, 0);
        let (mut predicted, mut measured) = (Vec::new(), Vec::new());
        for h in set.hits.iter().filter(|h| h.before.spin.y.abs() > 50.0) {
            let out = model.rebound(&h.before, &h.racket).unwrap();
            n += 1;
            if out.spin.y.signum() == h.spin_after.y.signum() {
                agree += 1;
            }
            predicted.push(out.spin.y / h.before.spin.y);
            measured.push(h.spin_after.y / h.before.spin.y);
        }
        let median = |v: &mut Vec<f64>| {
            v.sort_by(f64::total_cmp);
            v[v.len() / 2]
        };
        (
            f64::from(agree) / f64::from(n),
            median(&mut predicted),
            median(&mut measured),
        )
    };
    let (agree, predicted, measured) = score(&load("long_pips"));
    println!("long pips: sign {agree:.2}, ratio {predicted:.2} vs {measured:.2}");
    assert!(agree > 0.95, "{agree}");
    assert!(
        (predicted - measured).abs() < 0.1,
        "{predicted} vs {measured}"
    );
    let (agree, predicted, _) = score(&load("inverted_offensive"));
    println!("inverted preset on long pips: sign {agree:.2}, ratio {predicted:.2}");
    assert!(agree < 0.7 && predicted < 0.2);
}

/// Hits simulated by the model with a known rubber and noise are calibrated back to it within
/// three standard errors, and the standard errors are those of the noise (the fit's scatter
/// estimate is the noise put in).
#[test]
fn a_known_rubber_is_recovered_from_simulated_hits() {
    let mut truth = Config::default();
    truth.racket.rubber_restitution = vec![0.88, -0.018];
    truth.racket.rubber_friction = 0.55;
    truth.racket.rubber_tangential_restitution = 0.6;
    truth.racket.rubber_torsional_restitution = -0.2;
    let model = RacketModel::new(&truth);
    // Deterministic pseudo-random numbers in [-1, 1].
    let mut seed = 12345u64;
    let mut next = move || {
        seed = seed
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        ((seed >> 11) as f64 / (1u64 << 53) as f64) * 2.0 - 1.0
    };
    let mut csv = String::from(
        "v_in_x,v_in_y,v_in_z,spin_before_x,spin_before_y,spin_before_z,v_out_x,v_out_y,v_out_z,spin_after_x,spin_after_y,spin_after_z\n",
    );
    let racket = RacketState {
        velocity: Vector3::zeros(),
        normal: Vector3::z(),
        impact_offset: 0.0,
    };
    for _ in 0..400 {
        let v = Vector3::new(2.0 + 2.5 * next(), 1.0 * next(), -7.0 + 3.5 * next());
        let w = Vector3::new(30.0 * next(), 500.0 * next(), 60.0 * next());
        let out = model
            .rebound(&BallState::new(Vector3::zeros(), v, w), &racket)
            .unwrap();
        // Noise: about 0.1 m/s and 8 rad/s RMS per component (uniform, sqrt(3) sigma wide).
        let vo = out.velocity + Vector3::new(next(), next(), next()) * 0.17;
        let wo = out.spin + Vector3::new(next(), next(), next()) * 14.0;
        csv += &format!(
            "{},{},{},{},{},{},{},{},{},{},{},{}\n",
            v.x, v.y, v.z, w.x, w.y, w.z, vo.x, vo.y, vo.z, wo.x, wo.y, wo.z
        );
    }
    let mut set = HitSet::default();
    assert_eq!(set.add_csv("simulated", &csv).unwrap(), 400);
    assert_eq!(set.measured_velocity_axes(), [true, true, true]);
    let c = calibrate_rubber(
        &Config::default(),
        &set,
        &RubberOptions {
            folds: 0,
            ..RubberOptions::default()
        },
    )
    .unwrap();
    let expected = [0.88, -0.018, 0.55, 0.6, -0.2];
    for (p, t) in c.parameters.iter().zip(expected) {
        let sigma = p.std_error.unwrap();
        println!("{} = {:.4} +- {:.4} (truth {t})", p.name, p.value, sigma);
        assert!(
            (p.value - t).abs() < 3.0 * sigma,
            "{}: {} vs {t}",
            p.name,
            p.value
        );
        assert!(sigma < 0.1 * t.abs().max(0.2), "{}: sigma {sigma}", p.name);
    }
    assert!(
        (c.noise.0 - 0.098).abs() < 0.015,
        "velocity noise {}",
        c.noise.0
    );
    assert!((c.noise.1 - 8.1).abs() < 1.0, "spin noise {}", c.noise.1);
}

/// The CSV format: missing columns and partial racket vectors refuse the file with the column's
/// name; bad lines are left out one by one with their line and reason; a hit the starting model
/// cannot predict (the ball leaving the face) is refused with what to check; a set where every
/// hit grips reports the friction as not determined instead of failing.
#[test]
fn bad_hit_files_say_what_is_wrong() {
    let mut set = HitSet::default();
    let err = set.add_csv("a.csv", "v_in_x,v_in_y\n1,2\n").unwrap_err();
    assert!(matches!(&err, HitsError::MissingColumn { column, .. } if column == "v_in_z"));
    assert!(err.to_string().contains("tt_rackets"), "{err}");
    let header = "v_in_x,v_in_y,v_in_z,spin_before_x,spin_before_y,spin_before_z,v_out_x,v_out_y,v_out_z,spin_after_x,spin_after_y,spin_after_z";
    let err = set
        .add_csv("b.csv", &format!("{header},racket_normal_x\n"))
        .unwrap_err();
    assert!(matches!(err, HitsError::PartialVector { .. }), "{err}");
    assert!(matches!(
        set.add_csv("c.csv", ""),
        Err(HitsError::Empty { .. })
    ));
    let text = format!(
        "{header}\n1,0,-5,0,100,0,1,0,4,0,50,0\n1,0,-5,0,abc,0,1,0,4,0,50,0\n1,0,-5\n\n1,0,-5,0,NaN,0,1,0,4,0,50,0\n"
    );
    let mut set = HitSet::default();
    assert_eq!(set.add_csv("d.csv", &text).unwrap(), 1);
    let lines: Vec<usize> = set.rejected.iter().map(|r| r.line).collect();
    assert_eq!(lines, [3, 4, 6]);
    assert!(
        set.rejected[0].reason.contains("spin_before_y"),
        "{:?}",
        set.rejected
    );
    assert!(
        set.rejected[1].reason.contains("3 fields"),
        "{:?}",
        set.rejected
    );

    let mut leaving = HitSet::default();
    leaving
        .add_csv("e.csv", &format!("{header}\n1,0,5,0,0,0,1,0,4,0,0,0\n1,0,-5,0,0,0,1,0,4,0,0,0\n1,0,-6,0,0,0,1,0,4,0,0,0\n1,0,-7,0,0,0,1,0,5,0,0,0\n1,0,-8,0,0,0,1,0,5,0,0,0\n1,0,-9,0,0,0,1,0,6,0,0,0\n"))
        .unwrap();
    let err =
        calibrate_rubber(&Config::default(), &leaving, &RubberOptions::default()).unwrap_err();
    assert!(
        matches!(err, RubberCalibrationError::Unpredictable { index: 0, .. }),
        "{err}"
    );
    assert!(
        err.to_string().contains("normal pointing toward the ball"),
        "{err}"
    );
}

/// `ttball calibrate --rebound` writes a snippet that loads as a configuration and predicts like
/// the library's calibration, a chart, and a report with the held-out errors.
#[test]
fn the_command_line_calibrates_a_rubber() {
    let dir = std::env::temp_dir().join(format!("ttball-rubber-cli-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let snippet = dir.join("rubber.yaml");
    let chart = dir.join("rubber.svg");
    let out = Command::new(env!("CARGO_BIN_EXE_ttball"))
        .args(["calibrate", "--rebound"])
        .arg(racket_file("02"))
        .arg("-o")
        .arg(&snippet)
        .arg("--plot")
        .arg(&chart)
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(stdout.contains("held out"), "{stdout}");
    assert!(
        stdout.contains("racket.rubber_torsional_restitution"),
        "{stdout}"
    );
    let loaded = ttball::config::yaml::load(Some(&snippet), &[] as &[String]).unwrap();
    let library = calibrated(&["02"]);
    assert!(
        (loaded.racket.rubber_tangential_restitution
            - library.config.racket.rubber_tangential_restitution)
            .abs()
            < 1e-6
    );
    let svg = std::fs::read_to_string(&chart).unwrap();
    assert!(svg.contains("<svg") && svg.contains("predicted vs measured"));

    // Aero groups and bags do not mix with --rebound.
    let out = Command::new(env!("CARGO_BIN_EXE_ttball"))
        .args(["calibrate", "--fit", "aero", "--rebound"])
        .arg(racket_file("02"))
        .arg("-o")
        .arg(&snippet)
        .output()
        .unwrap();
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("only the rubber-* groups"));
    let out = Command::new(env!("CARGO_BIN_EXE_ttball"))
        .args([
            "calibrate",
            "--fit",
            "rubber-friction",
            "bags/real_launcher.mcap",
            "-o",
        ])
        .arg(&snippet)
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .unwrap();
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("--rebound HITS.csv"));
    std::fs::remove_dir_all(&dir).unwrap();
}
