#![allow(clippy::unwrap_used, clippy::expect_used, reason = "scratch")]
use ttball::config::Config;
use ttball::detection::{Source, seconds_to_ns};
use ttball::estimator::{Estimator, Rejection, Verdict};
use ttball::real::{LauncherFlights, SpinKind, detect_bounce, flight_detections, parse_mpi_csv};
#[test]
fn dbg() {
    let dir = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/data/mpi_launcher");
    let mut raw = Vec::new();
    for kind in SpinKind::ALL {
        raw.extend(
            parse_mpi_csv(
                &std::fs::read_to_string(dir.join(kind.file_name())).unwrap(),
                kind,
            )
            .unwrap(),
        );
    }
    let c = Config::default();
    let l = LauncherFlights::new(raw, c.ball.radius, c.table.length, c.gravity).unwrap();
    let mut config = Config::default();
    for kv in std::env::var("P")
        .unwrap_or_default()
        .split(',')
        .filter(|s| !s.is_empty())
    {
        let (k, v) = kv.split_once('=').unwrap();
        match k {
            "lmn" => config.ekf.learn_model_noise = v == "1",
            "ld" => config.adaptation.learn_dispersion = v == "1",
            _ => panic!(),
        }
    }
    let mut e = Estimator::new(&config);
    let mut epoch = 1_700_000_000_000_000_000i64;
    for f in &l.flights {
        let bounce = detect_bounce(&f.samples, c.gravity).map(|b| epoch + seconds_to_ns(b.time));
        let before = e.counters().reanchored;
        let mut gated = vec![];
        for d in flight_detections(f, epoch, Source::Wide150Fps) {
            let out = e.handle(&d);
            if std::env::var("SHOW").ok().as_deref()
                == Some(&format!("{} {}", f.spin_kind.name(), f.id))
            {
                if let (Some(b), Some(est)) = (bounce, out.estimate) {
                    let t = (d.stamp - b) as f64 * 1e-6;
                    if t.abs() < 40.0 {
                        let cv = est.covariance;
                        println!(
                            "  t {t:+6.1} {:?} z {:.1} v ({:+.2} {:+.2} {:+.2}) sv ({:.3} {:.3} {:.3}) w ({:+.0} {:+.0} {:+.0}) sw ({:.0} {:.0} {:.0}) resid {:?}",
                            out.verdict,
                            est.state.position.z * 1e3,
                            est.state.velocity.x,
                            est.state.velocity.y,
                            est.state.velocity.z,
                            cv[(3, 3)].sqrt(),
                            cv[(4, 4)].sqrt(),
                            cv[(5, 5)].sqrt(),
                            est.state.spin.x,
                            est.state.spin.y,
                            est.state.spin.z,
                            cv[(6, 6)].sqrt(),
                            cv[(7, 7)].sqrt(),
                            cv[(8, 8)].sqrt(),
                            ((d.position - est.state.position) * 1e3)
                                .map(|v| (v * 10.0).round() / 10.0)
                                .as_slice()
                        );
                    }
                }
            }
            if out.verdict == Verdict::Rejected(Rejection::Gated) {
                gated.push(bounce.map(|b| (d.stamp - b) as f64 * 1e-6));
            }
        }
        if e.counters().reanchored > before {
            println!(
                "{} {}: reanchored; gated at (ms from bounce) {:?}; model {:?}",
                f.spin_kind.name(),
                f.id,
                gated,
                e.learned_model_noise().scales
            );
        }
        epoch += seconds_to_ns(f.samples.last().unwrap().0 + 1.0);
    }
}
