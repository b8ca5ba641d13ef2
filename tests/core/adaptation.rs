//! The estimator on physics, noise and timing that differ from its configuration (issue "Real
//! flights"): the harder simulated sets of `ttball evaluate --sets` (`ttball::eval::sets`),
//! and what the bounce's uncertainty and the online adaptation each buy. Every test here also
//! runs the estimator without the mechanism it proves, and fails if that does as well.
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    reason = "test code: fail loudly"
)]

use ttball::config::Config;
use ttball::eval::sets::{SetReport, TrialSet, run_set, standard_sets};

fn set(name: &str) -> TrialSet {
    standard_sets()
        .into_iter()
        .find(|s| s.name == name)
        .unwrap()
}

fn report(config: &Config, name: &str, shots: usize) -> SetReport {
    let r = run_set(config, &set(name), shots, 3).unwrap();
    eprintln!(
        "{name}: one track {:.1} %, no gate after the bounce {:.1} %, settled 200 / 100 ms ratios {:.2} {:.2} / {:.2} {:.2}, learned {:?} (truth {:?})",
        r.single_track_fraction() * 100.0,
        r.clean_bounce_fraction() * 100.0,
        r.settled[0].median_ratio,
        r.settled[0].rms_ratio,
        r.settled[1].median_ratio,
        r.settled[1].rms_ratio,
        r.learned.params,
        r.truth
    );
    r
}

#[test]
fn every_set_keeps_one_track_per_flight_through_its_bounce() {
    let config = Config::default();
    for s in standard_sets() {
        let r = report(&config, s.name, 60);
        assert!(r.single_track_fraction() >= 0.98, "{}", s.name);
        assert!(r.clean_bounce_fraction() >= 0.95, "{}", s.name);
    }
}

/// The first flights onto a table the configuration has wrong (e_t 0.85 and mu_t 0.15, or 0.95
/// and 0.35, against 0.90 and 0.25), before anything is learned: the bounce's uncertainty (the
/// table's own, carried in the filter; its scatter; its outcome over the spin's uncertainty)
/// keeps the detections after it inside the gate. Without it they are gated.
#[test]
fn the_bounce_carries_its_uncertainty() {
    let config = Config::default();
    let mut certain = config.clone();
    certain.ekf.bounce_impulse_sigma = 0.0;
    certain.ekf.bounce_restitution_sigma = 0.0;
    certain.ekf.bounce_unscented = false;
    certain.ekf.contact_position_sigma = 0.0;
    certain.adaptation.restitution_sigma = 0.0;
    certain.adaptation.friction_sigma = 0.0;
    for name in ["a-2cams", "b-2cams"] {
        let honest = run_set(&config, &set(name), 20, 1).unwrap();
        let overconfident = run_set(&certain, &set(name), 20, 1).unwrap();
        eprintln!(
            "{name}: no gate after the bounce {:.0} % with its uncertainty, {:.0} % without",
            honest.clean_bounce_fraction() * 100.0,
            overconfident.clean_bounce_fraction() * 100.0
        );
        assert!(honest.clean_bounce_fraction() >= 0.95, "{name}");
        assert!(overconfident.clean_bounce_fraction() < 0.9, "{name}");
        assert_eq!(honest.single_track_fraction(), 1.0, "{name}");
    }
}

/// Play flown with physics the configuration has wrong: after 10 flights the interception is
/// as good as the same filter's given the true physics (within 1.3x, median and RMS, at 200
/// and 100 ms lead), and the learned drag scale, restitution and friction are within 5 % of
/// the truth (the Magnus scale within 8 %: learned from the spin the 900 fps camera measures
/// on the robot's half, biased a few percent low). Without the adaptation the interception is
/// more than twice as far off.
#[test]
fn the_adaptation_learns_what_the_configuration_has_wrong() {
    let config = Config::default();
    let mut fixed = config.clone();
    fixed.adaptation.enabled = false;
    for name in ["a-2cams", "b-2cams"] {
        let r = report(&config, name, 60);
        for l in &r.settled {
            assert!(l.median_ratio <= 1.3 && l.rms_ratio <= 1.3, "{name}: {l:?}");
        }
        let [k_d, k_m, e, mu] = r.learned_errors();
        assert!(
            k_d.abs() < 0.05 && e.abs() < 0.05 && mu.abs() < 0.05,
            "{name}"
        );
        assert!(k_m.abs() < 0.08, "{name}: {k_m}");
        let without = report(&fixed, name, 60);
        let lead100 = &without.settled[1];
        assert!(lead100.median_ratio > 2.0, "{name}: {lead100:?}");
    }
}

/// Play that follows the model exactly (no process noise, no bounce scatter, the same ball and
/// table every flight) seen by both cameras, with the model's noise and the flight-to-flight
/// dispersion learned (`ekf.learn_model_noise` and `adaptation.learn_dispersion`, both on by
/// default): the estimator learns that the flights stray from the model far less than
/// configured and that its flights do not scatter (down to the dispersion's floor, a third of
/// the configured sigma), and predicts the crossing better for it; with either left out it does
/// worse.
#[test]
fn the_model_noise_and_the_dispersion_are_learned() {
    use ttball::eval::evaluate_learning;
    use ttball::eval::sim::{Cameras, SimOptions, simulate};
    let options = SimOptions {
        cameras: Cameras::WideAndHighSpeed,
        shots: 120,
        seed: 5,
        ..SimOptions::default()
    };
    let mut fixed = Config::default();
    options.params.configure_estimator(&mut fixed);
    fixed.ekf.learn_model_noise = false;
    fixed.adaptation.learn_dispersion = false;
    let session = simulate(&fixed, &options).unwrap();
    let mut learning = fixed.clone();
    learning.ekf.learn_model_noise = true;
    learning.adaptation.learn_dispersion = true;
    let mut noise_only = learning.clone();
    noise_only.adaptation.learn_dispersion = false;
    let (with, learned) = evaluate_learning(&learning, &session);
    let (without, unlearned) = evaluate_learning(&fixed, &session);
    let (noise_alone, _) = evaluate_learning(&noise_only, &session);
    let scales = learned.model_noise.scales;
    eprintln!(
        "learned {scales:?}, flight sigmas {:?}; 300/200/100 ms median {:?} mm (fixed {:?}, noise alone {:?})",
        learned.params.flight_sigma,
        with.leads
            .iter()
            .map(|l| l.position_error.median * 1e3)
            .collect::<Vec<_>>(),
        without
            .leads
            .iter()
            .map(|l| l.position_error.median * 1e3)
            .collect::<Vec<_>>(),
        noise_alone
            .leads
            .iter()
            .map(|l| l.position_error.median * 1e3)
            .collect::<Vec<_>>(),
    );
    assert!(
        scales.acceleration < 0.3 && scales.bounce < 0.5,
        "{scales:?}"
    );
    // Once the spin camera measures the spin the model misses next to nothing here: that
    // phase's acceleration scale falls to the floor (0.0001x; 0.052x with the information kept
    // as gathered rather than re-evaluated at each new scale).
    assert!(
        learned.model_noise.spin_measured_acceleration < 0.001,
        "{:?}",
        learned.model_noise
    );
    assert_eq!(
        unlearned.model_noise.scales,
        ttball::online::ekf::NoiseScales::default()
    );
    let configured = [
        fixed.adaptation.drag_scale_flight_sigma,
        fixed.adaptation.magnus_scale_flight_sigma,
        fixed.adaptation.restitution_flight_sigma,
    ];
    for (i, c) in configured.iter().enumerate() {
        assert!(
            learned.params.flight_sigma[i] < 0.5 * c,
            "{i}: {:?}",
            learned.params.flight_sigma
        );
        assert_eq!(unlearned.params.flight_sigma[i], *c);
    }
    for lead in 1..3 {
        let (a, b, c) = (
            with.leads[lead].position_error.median,
            without.leads[lead].position_error.median,
            noise_alone.leads[lead].position_error.median,
        );
        assert!(a < 0.9 * b && a < c, "lead {lead}: {a} vs {b}, {c}");
    }
}

/// A position-only tracker on play whose Magnus force is 40 % below the model's (`a-lab`): the
/// filter, linearising the product k_M C_M(Sp) |w| at its estimate, learns the Magnus scale
/// low when its own estimates teach (`adaptation.smoothed_lessons: false`); each track's flight
/// smoothed when it ends (the default: the filter run again over the track linearised along the
/// flight its detections smooth to) teaches a scale near the truth, as do the track's refits
/// (`ekf.refit_interval`, applied always). Each on its own: the lessons without refits, the
/// refits without the lessons.
#[test]
fn a_smoothed_flight_teaches_the_magnus_scale_a_position_only_filter_leans_low_on() {
    let mut smoothed = Config::default();
    assert!(smoothed.adaptation.smoothed_lessons);
    smoothed.ekf.refit_interval = 0.0;
    let mut filter = smoothed.clone();
    filter.adaptation.smoothed_lessons = false;
    // The refits at their default interval (0.1 s), applied always. At 0.05 s with the third
    // iteration (2026-12-04) this seed learns -14.8 % (seeds 1, 2 and 4 within 1.2 %; +3.1 %
    // with two iterations): one undamped Gauss-Newton step too many on some flight of this
    // misspecified set, which neither the contest nor the smoothed lessons (the default) let
    // through (+4.0 % with both at 0.05; docs/estimator.md, "The track refitted").
    let mut refitted = filter.clone();
    refitted.ekf.refit_interval = Config::default().ekf.refit_interval;
    refitted.ekf.refit_when_better = false;
    let relative = |r: &SetReport| r.learned.params.magnus_scale / r.truth.magnus_scale - 1.0;
    let alone = report(&filter, "a-lab", 60);
    let with_lessons = report(&smoothed, "a-lab", 60);
    let with_refits = report(&refitted, "a-lab", 60);
    eprintln!(
        "a-lab's Magnus scale: {:+.1} % taught by the filter, {:+.1} % by the smoothed flights, {:+.1} % refitted",
        relative(&alone) * 100.0,
        relative(&with_lessons) * 100.0,
        relative(&with_refits) * 100.0
    );
    assert!(relative(&with_lessons).abs() < 0.05);
    assert!(relative(&with_refits).abs() < 0.05);
    // The filter -6.9 %, the lessons +3.9 %, the refits +2.6 % (since the learned model noise
    // falls to its floor here, 2026-12-04: the flights' misses are the Magnus scale's alone).
    assert!(relative(&alone).abs() > 1.5 * relative(&with_lessons).abs());
    assert!(relative(&alone).abs() > 2.0 * relative(&with_refits).abs());
    assert!(with_lessons.report.counters.smoothed_lessons >= 50);
    assert_eq!(alone.report.counters.smoothed_lessons, 0);
    assert_eq!(with_lessons.single_track_fraction(), 1.0);
    assert_eq!(with_refits.single_track_fraction(), 1.0);
}
