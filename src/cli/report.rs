//! The accuracy table of the estimator against a truth, as `ttball evaluate` and
//! `ttball replay` (on a bag with truth) print it.

use std::fmt::Write as _;

use ttball::eval::EvalReport;
use ttball::model::stats::ErrorStats;

fn stats_mm(s: &ErrorStats) -> String {
    format!(
        "{:6.1} {:6.1} {:6.1}",
        s.rms * 1e3,
        s.median * 1e3,
        s.p95 * 1e3
    )
}

fn stats(s: &ErrorStats) -> String {
    format!("{:6.2} {:6.2} {:6.2}", s.rms, s.median, s.p95)
}

/// The accuracy table: velocity, spin, NEES and interception errors at each lead.
pub fn accuracy_table(r: &EvalReport) -> String {
    let mut out = String::new();
    out.push_str("                                         RMS median    p95\n");
    let mut rows = vec![
        ("velocity after 100 ms [m/s]", &r.velocity_error),
        ("spin after 100 ms [rad/s]", &r.spin_error),
        ("  perpendicular to v [rad/s]", &r.spin_error_perpendicular),
        ("  along v [rad/s]", &r.spin_error_parallel),
    ];
    if r.spin_error_high_speed.count > 0 {
        rows.push((
            "velocity where 900 fps sees it [m/s]",
            &r.velocity_error_high_speed,
        ));
        rows.push((
            "spin where 900 fps sees it [rad/s]",
            &r.spin_error_high_speed,
        ));
    }
    for (label, values) in rows {
        let _ = writeln!(out, "{label:<38}{}", stats(values));
    }
    let _ = writeln!(
        out,
        "state NEES per dimension              {:6.2}   (position {:.2}, velocity {:.2}, spin {:.2})",
        r.state_nees, r.block_nees[0], r.block_nees[1], r.block_nees[2]
    );
    let _ = writeln!(
        out,
        "velocity within 2 ms of the bounce    {}   ({} estimates, left out above)",
        stats(&r.velocity_error_at_bounce),
        r.velocity_error_at_bounce.count
    );
    let _ = writeln!(
        out,
        "  before / after the bounce             {:6.2} / {:.2}",
        r.bounce_nees[0], r.bounce_nees[1]
    );
    out.push_str("interception     valid   position [mm] RMS/median/p95   time [ms] RMS/median/p95   NEES/dim\n");
    for lead in &r.leads {
        let _ = writeln!(
            out,
            "  {:3.0} ms lead   {:5.1} %  {}      {}        {:5.2}",
            lead.lead * 1e3,
            lead.valid_fraction * 100.0,
            stats_mm(&lead.position_error),
            stats_mm(&lead.time_error),
            lead.position_nees
        );
    }
    out
}
