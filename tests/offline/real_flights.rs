//! The estimator on real flights: the MPI launcher trajectories (`tests/data/mpi_launcher`,
//! BSD 3-Clause License, Copyright (c) 2023, Intelligent Soft Robots; the licence text is next to
//! the files; a copy of the workplace's shared data, in the repository), moved into the `table`
//! frame, and predicted.
//!
//! `cargo test --release --test
//! real_flights -- --nocapture` prints the transform's evidence, the noise and the accuracy
//! tables of the full model and of a drag-only model without spin.
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    reason = "test code: fail loudly"
)]

#[cfg(feature = "cli")]
use crate::common;

use std::path::PathBuf;
use std::sync::OnceLock;

use ttball::config::Config;
use ttball::eval::real::{
    LauncherFlights, LeadOutcome, Plane, RealEvalOptions, RealReport, SpinKind, drag_only,
    evaluate_flights, parse_mpi_csv,
};
use ttball::offline::ballistic::detect_bounce;

fn data_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/data/mpi_launcher")
}

fn data() -> Option<&'static LauncherFlights> {
    static DATA: OnceLock<Option<LauncherFlights>> = OnceLock::new();
    let data = DATA.get_or_init(|| {
        let dir = data_dir();
        let mut raw = Vec::new();
        for kind in SpinKind::ALL {
            let path = dir.join(kind.file_name().unwrap());
            let text = std::fs::read_to_string(&path).expect("the flights are in the repository");
            raw.extend(parse_mpi_csv(&text, kind).unwrap());
        }
        let config = Config::default();
        Some(
            LauncherFlights::new(raw, config.ball.radius, config.table.length, config.gravity)
                .unwrap(),
        )
    });
    data.as_ref()
}

/// The configuration for these flights: the full model with the measured noise.
fn real_config(data: &LauncherFlights) -> Config {
    let mut config = Config::default();
    config.sources.wide_150fps.position_sigma = data.position_sigma();
    config.validate().unwrap();
    config
}

#[test]
fn the_files_hold_forty_flights_of_three_kinds() {
    let Some(data) = data() else { return };
    let count = |k| data.raw.iter().filter(|f| f.spin_kind == k).count();
    assert_eq!(
        [
            count(SpinKind::Backspin),
            count(SpinKind::NoSpin),
            count(SpinKind::Topspin)
        ],
        [15, 10, 15]
    );
    let samples: usize = data.raw.iter().map(|f| f.samples.len()).sum();
    assert_eq!(samples, 4477);
}

#[test]
fn the_transform_puts_every_bounce_on_the_robots_half_at_one_radius() {
    let Some(data) = data() else { return };
    let e = data.estimate.as_ref().unwrap();
    let t = e.transform;
    println!(
        "transform: x_t = {:.3} - x, y_t = {:.4} - y, z_t = z - {:.4} [m]",
        t.c_x, t.c_y, t.z_surface
    );
    println!(
        "  {} of {} flights show a bounce; contact heights {:.4}..{:.4} m, robust sigma {:.2} mm",
        e.flights_with_bounce.0,
        e.flights_with_bounce.1,
        e.contact_heights.first().unwrap(),
        e.contact_heights.last().unwrap(),
        e.contact_height_sigma * 1e3
    );
    println!(
        "  bounces at x = {:.3}..{:.3} m: c_x admissible in ({:.3}, {:.3}); launch y {:.4}..{:.4} \
         m; {} flights start within one frame of x = 0; x spans {:.3}..{:.3} m",
        e.bounce_x.0,
        e.bounce_x.1,
        e.c_x_admissible.0,
        e.c_x_admissible.1,
        e.launch_y.0,
        e.launch_y.1,
        e.starts_at_zero,
        e.x_extent.0,
        e.x_extent.1
    );
    // The documented values (module doc of ttball::eval::real::mpi).
    assert!((t.z_surface - 0.7396).abs() < 0.0005, "{t:?}");
    assert!((t.c_y - 0.005).abs() < 0.001, "{t:?}");
    assert_eq!(t.c_x, 1.37);
    assert!(e.c_x_admissible.0 < t.c_x && t.c_x < e.c_x_admissible.1);
    assert_eq!(e.flights_with_bounce, (30, 40));

    let config = Config::default();
    let r = config.ball.radius;
    let mut bounce_heights = Vec::new();
    for flight in &data.flights {
        let first = flight.samples.first().unwrap().1;
        let last = flight.samples.last().unwrap().1;
        // Launched over the far end line, toward the robot, over the net.
        assert!(first.x > 1.0 && first.x <= 1.37 + 1e-9, "{first:?}");
        assert!(last.x < first.x - 2.0, "{last:?}");
        assert!(first.z > 0.25 && first.z < 0.45, "{first:?}");
        let Some(b) = detect_bounce(&flight.samples, config.gravity) else {
            continue;
        };
        let p = b.position;
        assert!(p.x > -1.37 && p.x < -0.5, "bounce at {p:?}");
        assert!(p.y.abs() < 0.1, "bounce at {p:?}");
        assert!((p.z - r).abs() < 0.01, "bounce at {p:?}");
        assert!(
            b.velocity_before.x < 0.0 && b.velocity_before.z < -2.0,
            "{b:?}"
        );
        bounce_heights.push(p.z);
        // Over the net at x_t = 0 with room to spare.
        let net = flight
            .samples
            .windows(2)
            .find(|w| w[0].1.x >= 0.0 && w[1].1.x < 0.0)
            .unwrap();
        assert!(net[0].1.z > config.table.net_height + 0.15, "{net:?}");
    }
    bounce_heights.sort_by(f64::total_cmp);
    let median = bounce_heights[bounce_heights.len() / 2];
    assert!((median - r).abs() < 0.001, "median contact height {median}");
}

#[test]
fn the_noise_is_about_a_millimetre_and_largest_along_the_flight() {
    let Some(data) = data() else { return };
    let n = &data.noise;
    println!("position noise (local quadratic fit, 7 samples; mm):");
    println!(
        "| component | residuals | RMS | robust sigma | inlier RMS | outliers > 5 sigma | max |"
    );
    println!("|---|---|---|---|---|---|---|");
    let rows = [
        ("x_t", n.axes[0]),
        ("y_t", n.axes[1]),
        ("z_t", n.axes[2]),
        ("along the flight", n.along),
        ("across the flight", n.across),
    ];
    for (name, a) in rows {
        println!(
            "| {name} | {} | {:.2} | {:.2} | {:.2} | {} ({:.2} %) | {:.1} |",
            a.count,
            a.rms * 1e3,
            a.robust_sigma * 1e3,
            a.inlier_rms * 1e3,
            a.outliers,
            100.0 * a.outliers as f64 / a.count.max(1) as f64,
            a.max * 1e3
        );
    }
    println!(
        "isotropic sigma (mean inlier variance) {:.2} mm; largest axis {:.2} mm: recommended \
         position_sigma = {:.4} m",
        n.isotropic_sigma() * 1e3,
        n.recommended_sigma() * 1e3,
        data.position_sigma()
    );
    for a in n.axes {
        assert!(a.count > 3000, "{a:?}");
        assert!(a.robust_sigma > 0.0002 && a.robust_sigma < 0.003, "{a:?}");
        assert!((a.outliers as f64) < 0.02 * a.count as f64, "{a:?}");
    }
    // Timing noise acts along the flight: the noise there is larger than across it.
    assert!(n.along.robust_sigma > 1.5 * n.across.robust_sigma, "{n:?}");
}

/// The full model and the drag-only model on every real flight, the setup printed.
fn full_and_drag(data: &LauncherFlights, options: &RealEvalOptions) -> (RealReport, RealReport) {
    let config = real_config(data);
    let full = evaluate_flights(&config, &data.flights, options);
    let drag = evaluate_flights(&drag_only(&config), &data.flights, options);
    println!(
        "position_sigma {:.4} m; plane {}",
        config.sources.wide_150fps.position_sigma,
        options.plane.describe()
    );
    (full, drag)
}

fn print_report(title: &str, report: &RealReport) {
    println!("\n{title}\n");
    println!("{}", report.to_markdown());
}

fn print_flights(report: &RealReport) {
    for f in &report.flights {
        let leads: Vec<String> = f
            .leads
            .iter()
            .map(|l| match l {
                LeadOutcome::Predicted {
                    y_error,
                    z_error,
                    time_error,
                    ..
                } => format!(
                    "dy {:+5.1} dz {:+5.1} mm dt {:+5.1} ms",
                    y_error * 1e3,
                    z_error * 1e3,
                    time_error * 1e3
                ),
                LeadOutcome::NoTrack => "no track".to_owned(),
                LeadOutcome::Invalid(why) => why.describe().to_owned(),
            })
            .collect();
        let spin = f
            .lead_states
            .last()
            .copied()
            .flatten()
            .map_or("-".to_owned(), |s| {
                format!("({:+.0}, {:+.0}, {:+.0})", s.spin.x, s.spin.y, s.spin.z)
            });
        match &f.crossing {
            Ok(c) => println!(
                "  {:8} {:2}: plane x {:+.3}, bounce ({:+.3}, {:+.3}) v ({:+.2}, {:+.2}) -> \
                 ({:+.2}, {:+.2}) m/s | {} | spin at the last lead {} rad/s; gated {}",
                f.spin_kind.name(),
                f.id,
                c.position.x,
                c.bounce.position.x,
                c.bounce.position.y,
                c.bounce.velocity_before.x,
                c.bounce.velocity_before.z,
                c.bounce.velocity_after.x,
                c.bounce.velocity_after.z,
                leads.join(" | "),
                spin,
                f.counters
                    .rejected(ttball::online::estimator::Rejection::Gated)
            ),
            Err(why) => println!(
                "  {:8} {:2}: not scored: {}",
                f.spin_kind.name(),
                f.id,
                why.describe()
            ),
        }
    }
}

#[test]
fn the_estimator_predicts_real_flights_through_their_bounce() {
    let Some(data) = data() else { return };
    let (full, drag) = full_and_drag(data, &RealEvalOptions::default());
    print_report("full model (drag + Magnus, spin learned online):", &full);
    print_flights(&full);
    print_report("drag only, no spin:", &drag);
    print_flights(&drag);

    let all = full.overall().unwrap();
    assert_eq!(all.scored, 24, "{all:?}");
    let scored = SpinKind::ALL.map(|k| full.group(k).unwrap().scored);
    assert_eq!(scored, [5, 10, 9]);
    let [lead200, lead100] = [&all.leads[0], &all.leads[1]];
    // One track per flight, all 40 of them.
    assert!(full.flights.iter().all(|f| f.counters.tracks == 1));
    // No detection gated within 50 ms after the bounce, in every flight that shows its bounce.
    let bounced = full.flights.iter().filter(|f| f.before_bounce.is_some());
    let gated: Vec<(u32, usize)> = bounced
        .filter(|f| f.gated_after_bounce > 0)
        .map(|f| (f.id, f.gated_after_bounce))
        .collect();
    println!("flights with detections gated within 50 ms after the bounce (id, count): {gated:?}");
    // The issue asks for none in 99 % of flights (all 40 here). The frames within a ball
    // diameter of a contact get its extra noise (`ekf.contact_position_sigma`; without it 4
    // flights; within half a diameter 1, backspin 14, whose first frame after a 16 ms gap, 3.6
    // cm above the contact height, sits 6 mm off: docs/real_flights.md).
    assert!(gated.is_empty(), "{gated:?}");
    // The table's friction is learned from these bounces, though most of them may have rolled
    // out or slid (each teaches in proportion to the probability that it slid).
    let learned = full.learned.expect("learned physics");
    let [_, _, _, friction_sigma] = learned.sigma;
    assert!(
        friction_sigma < 0.02 && (0.2..0.35).contains(&learned.params.friction),
        "{learned:?}"
    );
    // The targets: at most 15 mm RMS at 200 ms lead, 10 mm at 100 ms.
    assert!(lead200.position_error.rms <= 0.015, "{lead200:?}");
    assert!(lead100.position_error.rms <= 0.010, "{lead100:?}");
    // The predicted covariance is about honest on the crossing at 100 ms (NEES per dimension
    // about 1), cautious 200 ms ahead, where the bounce is still to come.
    assert!(lead200.crossing_nees < 0.8, "{lead200:?}");
    assert!(lead100.crossing_nees < 1.3, "{lead100:?}");
    // Within a racket's sweet spot at 100 ms, for every kind.
    assert!(lead100.valid_fraction >= 0.9, "{lead100:?}");
    assert!(lead100.time_error.rms < 0.005, "{lead100:?}");
    for kind in SpinKind::ALL {
        let l = &full.group(kind).unwrap().leads[1];
        assert!(l.valid_fraction >= 0.9, "{kind:?}: {l:?}");
        assert!(l.position_error.rms < 0.03, "{kind:?}: {l:?}");
    }
    // 200 ms ahead the spin matters: the full model predicts where drag alone cannot.
    let drag_all = drag.overall().unwrap();
    assert!(lead200.valid_fraction >= 0.9, "{lead200:?}");
    assert!(lead200.valid_fraction >= drag_all.leads[0].valid_fraction);
    assert!(lead200.position_error.rms < drag_all.leads[0].position_error.rms);
    // Topspin: the full model finds the bounce that drag alone misses by centimetres.
    let top = &full.group(SpinKind::Topspin).unwrap().leads[1];
    let top_drag = &drag.group(SpinKind::Topspin).unwrap().leads[1];
    assert!(top.bounce_position_error.rms < 0.015, "{top:?}");
    assert!(top.bounce_position_error.rms < 0.5 * top_drag.bounce_position_error.rms);
}

/// The 40 mm ball's aero coefficients (the defaults) against the seed's (the preset
/// `config/presets/seed_2014.yaml`) on the real flights: better at both leads.
#[test]
fn the_real_balls_coefficients_beat_the_seeds_on_real_flights() {
    let Some(data) = data() else { return };
    let options = RealEvalOptions::default();
    let config = real_config(data);
    let seed = ttball::config::yaml::load(
        Some(&PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("config/presets/seed_2014.yaml")),
        &[format!(
            "sources.wide_150fps.position_sigma:={}",
            config.sources.wide_150fps.position_sigma
        )],
    )
    .unwrap();
    assert_eq!(seed.aero, ttball::config::AeroParams::seed_2014());
    let ours = evaluate_flights(&config, &data.flights, &options);
    let theirs = evaluate_flights(&seed, &data.flights, &options);
    print_report("the 40 mm ball's coefficients (defaults):", &ours);
    print_report(
        "the seed's polynomials (config/presets/seed_2014.yaml):",
        &theirs,
    );
    let (a, b) = (ours.overall().unwrap(), theirs.overall().unwrap());
    for (l, m) in a.leads.iter().zip(&b.leads) {
        assert!(
            l.position_error.rms < m.position_error.rms,
            "{:.3} s: {l:?} vs {m:?}",
            l.lead
        );
    }
}

/// The kind of spin just before the bounce (or at the end of a recording that ends before it),
/// from the flight's curvature alone: backspin below zero and topspin above it on all 30
/// flights with spin, and the 10 no-spin flights between the two, well apart from both.
#[test]
fn the_kind_of_spin_before_the_bounce() {
    let Some(data) = data() else { return };
    let report = evaluate_flights(
        &real_config(data),
        &data.flights,
        &RealEvalOptions::default(),
    );
    let spins = |kind: SpinKind| -> Vec<f64> {
        report
            .flights
            .iter()
            .filter(|f| f.spin_kind == kind)
            .map(|f| {
                f.topspin_before_bounce()
                    .expect("an estimate before the bounce")
            })
            .collect()
    };
    let (back, none, top) = (
        spins(SpinKind::Backspin),
        spins(SpinKind::NoSpin),
        spins(SpinKind::Topspin),
    );
    let range = |v: &[f64]| {
        (
            v.iter().copied().fold(f64::INFINITY, f64::min),
            v.iter().copied().fold(f64::NEG_INFINITY, f64::max),
        )
    };
    let (b, n, t) = (range(&back), range(&none), range(&top));
    println!(
        "topspin component before the bounce [rad/s]: backspin {:.1} to {:.1}, no spin {:.1} to \
         {:.1}, topspin {:.1} to {:.1}",
        b.0, b.1, n.0, n.1, t.0, t.1
    );
    assert_eq!((back.len(), none.len(), top.len()), (15, 10, 15));
    assert!(
        b.1 < 0.0,
        "every backspin flight reads as backspin: {back:?}"
    );
    assert!(t.0 > 0.0, "every topspin flight reads as topspin: {top:?}");
    // The no-spin flights between the two, apart from either by more than 50 rad/s: the three
    // kinds are told apart by a boundary anywhere in those gaps. (By its sign the launcher's
    // "no spin" reads as mild topspin, 27-42 rad/s: docs/real_flights.md.)
    assert!(
        b.1 + 50.0 < n.0 && n.1 + 50.0 < t.0,
        "no spin between, well apart: {none:?}"
    );
}

/// The spin across the velocity just before the bounce, the filter's against the batch fit of
/// the same detections flying the same physics (the track's own then): the two agree within a
/// factor 1.2 in magnitude on all but at most two of the 40 flights, with a median ratio within
/// 10 % of one. Without a measured spin, the fit over the whole flight so far is the best the
/// detections allow.
#[test]
fn the_filter_s_spin_before_the_bounce_is_the_batch_fit_s() {
    let Some(data) = data() else { return };
    let report = evaluate_flights(
        &real_config(data),
        &data.flights,
        &RealEvalOptions::default(),
    );
    let mut ratios: Vec<f64> = report
        .flights
        .iter()
        .filter_map(|f| f.spin_across_before_bounce())
        .map(|(filter, batch)| filter.norm() / batch.norm())
        .collect();
    println!("|filter| / |batch| of the spin across v before the bounce: {ratios:.2?}");
    assert_eq!(ratios.len(), 40);
    let within = ratios
        .iter()
        .filter(|r| (1.0 / 1.2..=1.2).contains(*r))
        .count();
    assert!(within >= 38, "{ratios:?}");
    ratios.sort_by(f64::total_cmp);
    let median = (ratios[19] + ratios[20]) / 2.0;
    assert!((0.9..=1.1).contains(&median), "{median}");
}

#[test]
fn a_fixed_hitting_plane_near_the_robots_end_line() {
    let Some(data) = data() else { return };
    let options = RealEvalOptions {
        plane: Plane::Fixed(-1.2),
        ..RealEvalOptions::default()
    };
    let (full, drag) = full_and_drag(data, &options);
    print_report("full model:", &full);
    print_flights(&full);
    print_report("drag only, no spin:", &drag);
    let all = full.overall().unwrap();
    assert!(all.scored >= 20, "{all:?}");
    assert!(all.leads[0].valid_fraction >= 0.8, "{all:?}");
}

/// `ttball evaluate --real` runs the same evaluation from the CSV files and prints the table,
/// the tracks, the gated detections after the bounce and the spin by kind; a file that is not
/// in the format is refused with the header it expects.
#[test]
#[cfg(feature = "cli")]
fn the_command_line_evaluates_the_real_flights() {
    let files: Vec<String> = SpinKind::ALL
        .iter()
        .map(|k| format!("tests/data/mpi_launcher/{}", k.file_name().unwrap()))
        .collect();
    let json_path = common::scratch("real_flights_cli").join("real.json");
    let json_arg = json_path.to_string_lossy().into_owned();
    let mut args = vec!["evaluate", "--json", &json_arg, "--real"];
    args.extend(files.iter().map(String::as_str));
    let out = common::ok(&args);
    let data = data().unwrap();
    let report = evaluate_flights(
        &real_config(data),
        &data.flights,
        &RealEvalOptions::default(),
    );
    assert!(
        out.contains(&report.to_markdown()),
        "the table of the evaluation:\n{out}"
    );
    assert!(out.contains("tracks 40 (re-anchored 0)"), "{out}");
    assert!(out.contains("position_sigma 0.0019 m (measured)"), "{out}");
    for kind in SpinKind::ALL {
        assert!(out.contains(&format!("  {:<9} ", kind.name())), "{out}");
    }
    // The JSON: every flight's outcome at each lead, whose errors make the table's RMS, and
    // the summaries as the table has them.
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json_path).unwrap()).unwrap();
    let flights = json["flights"].as_array().unwrap();
    assert_eq!(flights.len(), data.flights.len());
    let all = report.overall().unwrap();
    for (i, lead) in all.leads.iter().enumerate() {
        let errors: Vec<f64> = flights
            .iter()
            .filter_map(|f| f["leads"].as_array()?.get(i))
            .filter(|l| l["outcome"] == "predicted")
            .map(|l| l["position_error"].as_f64().unwrap())
            .collect();
        assert_eq!(errors.len(), lead.valid);
        let rms = (errors.iter().map(|e| e * e).sum::<f64>() / errors.len() as f64).sqrt();
        approx::assert_relative_eq!(rms, lead.position_error.rms, max_relative = 1e-9);
        // Each crossing comes with its predicted spread: millimetres in y and z and in time.
        for l in flights
            .iter()
            .filter_map(|f| f["leads"].as_array()?.get(i))
            .filter(|l| l["outcome"] == "predicted")
        {
            let sigma = |key: &str| l[key].as_f64().unwrap();
            assert!(
                (5e-4..0.05).contains(&sigma("y_sigma"))
                    && (5e-4..0.05).contains(&sigma("z_sigma"))
                    && (0.0..0.05).contains(&sigma("time_sigma")),
                "{l}"
            );
        }
        let group = json["groups"].as_array().unwrap().last().unwrap();
        assert_eq!(group["spin_kind"], "all");
        let summary = &group["leads"][i];
        approx::assert_relative_eq!(
            summary["position_error"]["rms"].as_f64().unwrap(),
            lead.position_error.rms
        );
    }
    let unscored = flights.iter().filter(|f| f["scored"] == false).count();
    assert_eq!(unscored, data.flights.len() - all.scored);
    assert!(
        flights
            .iter()
            .filter(|f| f["scored"] == false)
            .all(|f| f["not_scored_because"].is_string()),
        "{flights:?}"
    );
    assert!(json["learned"]["params"]["magnus_scale"]["value"].is_f64());
    let bad = common::run(&["evaluate", "--real", "Cargo.toml"]);
    assert_eq!(bad.status.code(), Some(1));
    let stderr = String::from_utf8_lossy(&bad.stderr);
    assert!(
        stderr.contains("Cargo.toml") && stderr.contains("expected the header"),
        "{stderr}"
    );
}

/// Flights recorded in the `table` frame (`--frame table`) are evaluated and imported as they are,
/// a flight moving toward +x turned to come toward the robot: the launcher flights written in the
/// table frame, every other one turned around, give the launcher frame's numbers.
#[test]
#[cfg(feature = "cli")]
fn flights_recorded_in_the_table_frame_are_taken_as_they_are() {
    let data = data().unwrap();
    let mut csv = String::from("trajectory,t_s,x_m,y_m,z_m\n");
    for (i, flight) in data.flights.iter().enumerate() {
        let turn = if i % 2 == 1 { -1.0 } else { 1.0 };
        for (t, p) in &flight.samples {
            csv.push_str(&format!("{i},{t},{},{},{}\n", turn * p.x, turn * p.y, p.z));
        }
    }
    let dir = common::scratch("real_flights_table_frame");
    let file = dir.join("recorded_in_table.csv");
    std::fs::write(&file, csv).unwrap();
    let file = file.to_string_lossy().into_owned();
    let launcher_files: Vec<String> = SpinKind::ALL
        .iter()
        .map(|k| format!("tests/data/mpi_launcher/{}", k.file_name().unwrap()))
        .collect();
    let mut args = vec!["evaluate", "--real"];
    args.extend(launcher_files.iter().map(String::as_str));
    let launcher = common::ok(&args);
    let table = common::ok(&["evaluate", "--real", &file, "--frame", "table"]);
    let all_rows = |out: &str| -> Vec<String> {
        out.lines()
            .filter(|l| l.starts_with("| all (40)"))
            .map(str::to_owned)
            .collect()
    };
    assert_eq!(all_rows(&launcher).len(), 2, "{launcher}");
    assert_eq!(all_rows(&launcher), all_rows(&table), "{table}");
    // Forty spins in one group are summarised, not listed.
    assert!(
        table.contains("not stated filter median ") && table.contains("(40 flights)"),
        "{table}"
    );
    // Read in the launcher's frame, half of them fly away from the robot.
    let misread = common::ok(&["evaluate", "--real", &file]);
    assert_ne!(all_rows(&launcher), all_rows(&misread), "{misread}");
    let bag = dir.join("table.mcap").to_string_lossy().into_owned();
    let imported = common::ok(&["import", "csv", &file, "--frame", "table", "-o", &bag]);
    assert!(
        imported.contains("40 flights") && imported.contains("frame: table, as recorded"),
        "{imported}"
    );
    let replayed = common::ok(&[
        "replay",
        &bag,
        "-o",
        &dir.join("out.mcap").to_string_lossy(),
    ]);
    assert!(replayed.contains("tracks 40"), "{replayed}");
}

/// Flights in a file whose name states no spin are evaluated and imported like the launcher's,
/// grouped as "not stated": the same flights give the same numbers under any name.
#[test]
#[cfg(feature = "cli")]
fn flights_under_any_file_name_are_evaluated_as_spin_not_stated() {
    let dir = common::scratch("real_flights_any_name");
    let renamed = dir.join("lab_session_3.csv");
    std::fs::copy(data_dir().join("mn5008_topspin.csv"), &renamed).unwrap();
    let renamed = renamed.to_string_lossy().into_owned();
    let named = common::ok(&[
        "evaluate",
        "--real",
        "tests/data/mpi_launcher/mn5008_topspin.csv",
    ]);
    let unnamed = common::ok(&["evaluate", "--real", &renamed]);
    let rows = |out: &str, group: &str| -> Vec<String> {
        out.lines()
            .filter(|l| l.starts_with(&format!("| {group} (15)")))
            .map(|l| l.replacen(group, "", 1))
            .collect()
    };
    assert_eq!(rows(&named, "topspin").len(), 2, "{named}");
    assert_eq!(
        rows(&named, "topspin"),
        rows(&unnamed, "not stated"),
        "{unnamed}"
    );
    assert!(unnamed.contains("  not stated filter "), "{unnamed}");
    assert!(!unnamed.contains("backspin"), "{unnamed}");
    let bag = dir.join("lab.mcap").to_string_lossy().into_owned();
    let imported = common::ok(&["import", "mpi", &renamed, "--output", &bag]);
    assert!(imported.contains("15 flights"), "{imported}");
}

/// The spin's decay in flight (`aero.spin_decay_rate`, 1 /s) pays on these flights: against
/// constant spin the crossing 100 ms ahead is at least 10 % closer (7.8 -> 6.4 mm RMS), and
/// 200 ms ahead about as close, within 2 % (7.8 -> 7.7 mm; docs/models.md, "Spin decay").
#[test]
fn the_spins_decay_pays_on_real_flights() {
    let Some(data) = data() else { return };
    let options = RealEvalOptions::default();
    let config = real_config(data);
    assert!(config.aero.spin_decay_rate > 0.0);
    let mut constant = config.clone();
    constant.aero.spin_decay_rate = 0.0;
    let decaying = evaluate_flights(&config, &data.flights, &options);
    let constant = evaluate_flights(&constant, &data.flights, &options);
    let (a, b) = (decaying.overall().unwrap(), constant.overall().unwrap());
    for (l, m) in a.leads.iter().zip(&b.leads) {
        let (with, without) = (l.position_error.rms, m.position_error.rms);
        println!(
            "{:.1} s: {with:.4} m with the decay, {without:.4} m without",
            l.lead
        );
        if l.lead < 0.15 {
            assert!(with < 0.9 * without, "{:.3} s: {l:?} vs {m:?}", l.lead);
        } else {
            assert!(with <= 1.02 * without, "{:.3} s: {l:?} vs {m:?}", l.lead);
        }
    }
}
