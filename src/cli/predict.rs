//! `ttball predict`: the predicted flight of one ball state (bounces, net, floor, the hitting
//! plane), printed as a table of events and optionally written as CSV samples.

use std::fmt::Write as _;
use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::Context;
use clap::Args;
use nalgebra::Vector3;
use ttball::physics::{
    BallState, EventKind, PredictOptions, Propagator, Trajectory, TrajectoryEnd, predict,
};

use super::{ConfigArgs, write_stdout};

/// Arguments of `ttball predict`.
///
/// The default state is a real one: record 13233 of Google DeepMind's "Competitive Robot Table
/// Tennis: Initial Ball States" (rallies.json, CC-BY 4.0), a typical rally ball just after the
/// opponent's hit (5.6 m/s, 41 rad/s of topspin), turned into the `table` frame.
#[derive(Debug, Args)]
pub struct PredictArgs {
    /// Ball centre at t = 0 [m], table frame: x toward the opponent, y left, z up from the surface.
    #[arg(long, value_name = "X,Y,Z", value_parser = parse_vector, allow_hyphen_values = true,
          default_value = "1.0178,-0.0184,0.4448")]
    pub position: Vector3<f64>,

    /// Velocity at t = 0 [m/s]; incoming balls move toward -x.
    #[arg(long, value_name = "VX,VY,VZ", value_parser = parse_vector, allow_hyphen_values = true,
          default_value = "-5.4122,-0.1333,1.5129")]
    pub velocity: Vector3<f64>,

    /// Angular velocity at t = 0 [rad/s]; topspin on an incoming ball is -y.
    #[arg(long, value_name = "WX,WY,WZ", value_parser = parse_vector, allow_hyphen_values = true,
          default_value = "7.051,-40.643,-3.915")]
    pub spin: Vector3<f64>,

    /// How far ahead to predict [s]; default `prediction.horizon`.
    #[arg(long, value_name = "SECONDS")]
    pub horizon: Option<f64>,

    /// Spacing of the CSV samples [s]; default `prediction.trajectory_dt`.
    #[arg(long, value_name = "SECONDS")]
    pub dt: Option<f64>,

    /// Write the samples (t, position, velocity, spin) to this CSV file.
    #[arg(long, value_name = "FILE")]
    pub csv: Option<PathBuf>,

    /// The configuration (physics, `intercept.plane_x`, prediction step and horizon).
    #[command(flatten)]
    pub config: ConfigArgs,
}

/// Parses `X,Y,Z` into a vector of three finite numbers.
pub(crate) fn parse_vector(text: &str) -> Result<Vector3<f64>, String> {
    parse_numbers::<3>(text, "three", "1.0,-0.2,0.3").map(Vector3::from)
}

/// Parses `N` comma-separated finite numbers (`count` says N in words, `example` shows them).
pub(crate) fn parse_numbers<const N: usize>(
    text: &str,
    count: &str,
    example: &str,
) -> Result<[f64; N], String> {
    let parts: Vec<&str> = text.split(',').map(str::trim).collect();
    if parts.len() != N {
        return Err(format!(
            "expected {count} comma-separated numbers like {example}, got `{text}`"
        ));
    }
    let mut out = [0.0; N];
    for (slot, part) in out.iter_mut().zip(parts) {
        let value: f64 = part
            .parse()
            .map_err(|_| format!("`{part}` is not a number (in `{text}`)"))?;
        if !value.is_finite() {
            return Err(format!("`{part}` is not finite (in `{text}`)"));
        }
        *slot = value;
    }
    Ok(out)
}

impl PredictArgs {
    /// Runs the prediction and prints it.
    pub fn run(self) -> anyhow::Result<ExitCode> {
        let config = self.config.load()?;
        let horizon = self.horizon.unwrap_or(config.prediction.horizon);
        let dt = self.dt.unwrap_or(config.prediction.trajectory_dt);
        anyhow::ensure!(
            horizon.is_finite() && horizon > 0.0 && horizon <= 10.0,
            "--horizon must be in (0, 10] s, got {horizon}"
        );
        anyhow::ensure!(
            dt.is_finite() && dt > 0.0 && dt <= horizon,
            "--dt must be in (0, horizon] s, got {dt}"
        );
        let start = BallState::new(self.position, self.velocity, self.spin);
        let propagator = Propagator::new(&config);
        let options = PredictOptions {
            horizon,
            sample_interval: dt,
            plane_x: Some(config.intercept.plane_x),
            stop_at_plane: false,
        };
        let trajectory = predict(&propagator, &start, &options);
        write_stdout(&report(&propagator, &start, &options, &trajectory))?;
        if let Some(path) = &self.csv {
            std::fs::write(path, csv(&trajectory))
                .with_context(|| format!("cannot write the samples to {}", path.display()))?;
            write_stdout(&format!(
                "{} samples written to {}\n",
                trajectory.samples.len(),
                path.display()
            ))?;
        }
        Ok(ExitCode::SUCCESS)
    }
}

fn state_columns(out: &mut String, s: &BallState) {
    let (p, v, w) = (s.position, s.velocity, s.spin);
    let _ = write!(
        out,
        "{:7.3} {:7.3} {:7.3}  {:6.2} {:6.2} {:6.2}  {:6.0} {:6.0} {:6.0}",
        p.x, p.y, p.z, v.x, v.y, v.z, w.x, w.y, w.z
    );
}

/// The human-readable summary: the start, every event, and how the prediction ended.
fn report(
    propagator: &Propagator,
    start: &BallState,
    options: &PredictOptions,
    trajectory: &Trajectory,
) -> String {
    let flight = propagator.flight();
    let forces = flight.forces(&start.velocity, &start.spin);
    let mut out = format!(
        "Predicted flight over {:.3} s (RK4 step {:.1} ms, events root-found inside the step)\n\
         start: |v| = {:.2} m/s, |w| = {:.0} rad/s, Re = {:.2e}, Sp = {:.3}, \
         C_D = {:.3} (x k_D {:.2}), C_M = {:.3} (x k_M {:.2})\n\n",
        options.horizon,
        propagator.max_step() * 1e3,
        start.velocity.norm(),
        start.spin.norm(),
        forces.reynolds_number,
        forces.spin_parameter,
        forces.drag_coefficient,
        flight.scales().0,
        forces.magnus_coefficient,
        flight.scales().1,
    );
    out.push_str(
        "   t [s]  event                                   x [m]   y [m]   z [m]  vx     vy     vz [m/s]   wx     wy     wz [rad/s]\n",
    );
    let _ = write!(out, "{:8.4}  {:<38}", 0.0, "start");
    state_columns(&mut out, start);
    out.push('\n');
    for event in &trajectory.events {
        let label = match event.kind {
            EventKind::TableBounce { regime } => {
                let half = if event.before[0] < 0.0 {
                    "robot's"
                } else {
                    "opponent's"
                };
                format!("bounce on the {half} half ({regime:?})").to_lowercase()
            }
            EventKind::Net {
                clearance,
                hit: true,
            } => {
                format!("net hit ({:.0} mm below the top)", -clearance * 1e3)
            }
            EventKind::Net {
                clearance,
                hit: false,
            } => {
                format!("net crossed ({:.0} mm clearance)", clearance * 1e3)
            }
            EventKind::Floor => "floor".to_string(),
            EventKind::TableMiss { distance } => {
                format!("table missed ({:.0} mm outside)", distance * 1e3)
            }
            EventKind::Plane { x } => format!("hitting plane x = {x:.3} m"),
        };
        let _ = write!(out, "{:8.4}  {:<38}", event.t, label);
        state_columns(&mut out, &BallState::from_vector(&event.after));
        out.push('\n');
    }
    let end = match trajectory.end {
        TrajectoryEnd::Horizon => "the horizon",
        TrajectoryEnd::Plane => "the hitting plane",
        TrajectoryEnd::Net => "the net",
        TrajectoryEnd::Floor => "the floor",
    };
    let _ = writeln!(out, "\nThe prediction ends at {end}.");
    out
}

/// The samples as CSV with a header line.
fn csv(trajectory: &Trajectory) -> String {
    let mut out = String::from("t_s,x_m,y_m,z_m,vx_mps,vy_mps,vz_mps,wx_radps,wy_radps,wz_radps\n");
    for sample in &trajectory.samples {
        let s = sample.state.to_vector();
        let _ = write!(out, "{:.6}", sample.t);
        for value in s.iter() {
            let _ = write!(out, ",{value:.6}");
        }
        out.push('\n');
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn vectors_parse_with_signs_and_spaces() {
        assert_eq!(
            parse_vector("-1.5, 0,2e-1"),
            Ok(Vector3::new(-1.5, 0.0, 0.2))
        );
        assert!(parse_vector("1,2").is_err());
        assert!(parse_vector("1,2,x").is_err());
        assert!(parse_vector("1,2,NaN").is_err());
    }
}
