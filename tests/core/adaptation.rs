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
/// table's own, carried in the filter; its scatter) keeps the detections after it inside the
/// gate. Without it they are gated.
#[test]
fn the_bounce_carries_its_uncertainty() {
    let config = Config::default();
    let mut certain = config.clone();
    certain.ekf.bounce_impulse_sigma = 0.0;
    certain.ekf.bounce_restitution_sigma = 0.0;
    certain.ekf.contact_position_sigma = 0.0;
    certain.adaptation.sigma[2] = 0.0;
    certain.adaptation.sigma[3] = 0.0;
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
/// more than twice as far off (RMS, at both leads).
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
        for lead in &without.settled {
            assert!(lead.rms_ratio > 2.0, "{name}: {lead:?}");
        }
    }
}

/// A position-only tracker on play whose Magnus force is 40 % below the model's (`a-lab`):
/// each track's flight smoothed when it ends (the filter run again over the track linearised
/// along the flight its detections smooth to) teaches a Magnus scale within 10 % of the truth
/// and within 2.5 of the standard errors it reports (about 7 % after 60 flights), every track
/// but a few its flight smoothed. (What the filter's own estimate would teach instead, low:
/// `online::estimator`'s unit tests.)
#[test]
fn a_smoothed_flight_teaches_the_magnus_scale() {
    let r = report(&Config::default(), "a-lab", 60);
    let error = r.learned.params.magnus_scale - r.truth.magnus_scale;
    let relative = error / r.truth.magnus_scale;
    let sigma = r.learned.sigma[1];
    eprintln!(
        "a-lab's Magnus scale: {:+.1} % ({:.1} standard errors)",
        relative * 100.0,
        error / sigma
    );
    assert!(relative.abs() < 0.10, "{relative}");
    assert!(error.abs() < 2.5 * sigma, "{error} against {sigma}");
    assert!(r.report.counters.smoothed_lessons >= 50);
    assert_eq!(r.single_track_fraction(), 1.0);
}

/// Elite play (3-28 m/s) whose Magnus force falls with speed faster than configured (a_M -1.0
/// against -0.65), seen by the 150 + 900 fps cameras: the flights at their different speeds
/// determine the exponent, and the estimator learns it within 5 % and the Magnus scale at Re_0
/// within 5 %, and keeps one track per flight. With the exponent held at its configured value
/// the 100 ms interception is further from the true physics'.
#[test]
fn elite_flights_teach_the_magnus_forces_reynolds_exponent() {
    let steeper = ttball::eval::sets::STEEPER_ELITE;
    let config = Config::default();
    let r = run_set(&config, &steeper, 80, 3).unwrap();
    let learned = &r.learned;
    eprintln!(
        "learned {:?}, exponents {:?} +- {:?}; settled {:?}",
        learned.params, learned.reynolds_exponents, learned.reynolds_sigma, r.settled
    );
    assert!(learned.reynolds_determined()[1], "{learned:?}");
    let a_m = learned.reynolds_exponents[1];
    assert!((a_m / -1.0 - 1.0).abs() < 0.05, "a_M {a_m}");
    let k_m = learned.params.magnus_scale / r.truth.magnus_scale - 1.0;
    assert!(k_m.abs() < 0.05, "k_M {k_m}");
    assert_eq!(r.single_track_fraction(), 1.0);
    let mut held = config.clone();
    held.adaptation.reynolds_sigma = vec![0.0, 0.0];
    let without = run_set(&held, &steeper, 80, 3).unwrap();
    eprintln!("held: {:?}", without.settled);
    assert!(without.settled[1].median_ratio > r.settled[1].median_ratio);
}
