//! `ttball rebound` and `ttball aim`: the racket impact model from the command line. `rebound`
//! predicts what a given stroke does to a given ball; `aim` finds the stroke that returns the
//! ball to a target. Both run the same core as the node's `~/predict_rebound` and
//! `~/plan_return` ([`ttball::online::stroke::Stroke`]).

use std::fmt::Write as _;
use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::Context;
use clap::Args;
use nalgebra::{Vector2, Vector3};
use ttball::config::Config;
use ttball::online::stroke::{Aim, Plan, Rebound, ReturnCondition, Stroke};
use ttball::physics::{BallState, BounceRegime, RacketState, StateMatrix, StateVector};

use super::predict::{parse_numbers, parse_vector};
use super::{BadUsage, ConfigArgs, write_stdout};

/// The ball just before impact. The default is the real rally ball of `ttball predict` (Google
/// DeepMind's rallies.json record 13233, CC-BY 4.0) where it crosses the default hitting plane.
#[derive(Debug, Args)]
pub struct BallArgs {
    /// Ball centre at impact [m], table frame (x toward the opponent, y left, z up).
    #[arg(long, value_name = "X,Y,Z", value_parser = parse_vector, allow_hyphen_values = true,
          default_value = "-1.6,-0.067,0.359")]
    pub position: Vector3<f64>,

    /// Ball velocity just before impact [m/s]; an incoming ball moves toward -x.
    #[arg(long, value_name = "VX,VY,VZ", value_parser = parse_vector, allow_hyphen_values = true,
          default_value = "-2.58,-0.06,0.45")]
    pub velocity: Vector3<f64>,

    /// Ball angular velocity just before impact [rad/s]; topspin on an incoming ball is -y.
    #[arg(long, value_name = "WX,WY,WZ", value_parser = parse_vector, allow_hyphen_values = true,
          default_value = "3,-137,-4")]
    pub spin: Vector3<f64>,
}

impl BallArgs {
    fn state(&self) -> BallState {
        BallState::new(self.position, self.velocity, self.spin)
    }
}

/// What `rebound` and `aim` share: the ball, the impact point, the output form, the
/// configuration.
#[derive(Debug, Args)]
pub struct StrokeArgs {
    /// The ball.
    #[command(flatten)]
    pub ball: BallArgs,

    /// Impact point from the racket's centre of gravity along its long axis, toward the tip [m].
    #[arg(
        long,
        value_name = "METRES",
        default_value_t = 0.0,
        allow_hyphen_values = true
    )]
    pub offset: f64,

    /// Print the result as JSON instead of text.
    #[arg(long)]
    pub json: bool,

    /// The configuration (ball, racket, arm, table, prediction, `stroke.*` limits).
    #[command(flatten)]
    pub config: ConfigArgs,
}

/// Arguments of `ttball rebound`.
#[derive(Debug, Args)]
pub struct ReboundArgs {
    /// Velocity of the racket's impact point at impact [m/s].
    #[arg(long, value_name = "VX,VY,VZ", value_parser = parse_vector, allow_hyphen_values = true,
          default_value = "2.7,0,0")]
    pub racket_velocity: Vector3<f64>,

    /// Normal of the hitting face, pointing toward the ball (normalised here); the default
    /// closes the face by 6 degrees.
    #[arg(long, value_name = "NX,NY,NZ", value_parser = parse_vector, allow_hyphen_values = true,
          default_value = "1,0,-0.1")]
    pub normal: Vector3<f64>,

    /// Also draw the racket's rebound power coefficient along its long axis and against impact
    /// speed (like Kawazoe & Suzuki's Fig. 19 and 20) to this SVG or PNG file.
    #[arg(long, value_name = "FILE")]
    pub chart: Option<PathBuf>,

    /// Ball, impact point, output, configuration.
    #[command(flatten)]
    pub common: StrokeArgs,
}

/// Arguments of `ttball aim`.
#[derive(Debug, Args)]
pub struct AimArgs {
    /// Where the ball centre should land on the opponent's half, X,Y [m] (x > 0).
    #[arg(long, value_name = "X,Y", value_parser = parse_target, allow_hyphen_values = true,
          default_value = "0.9,0.3")]
    pub target: Vector2<f64>,

    /// Height of the ball's bottom over the net top at the net [m]; default
    /// `stroke.net_clearance`.
    #[arg(long, value_name = "METRES", conflicts_with = "flight_time")]
    pub net_clearance: Option<f64>,

    /// Time from impact to landing [s], instead of a net clearance.
    #[arg(long, value_name = "SECONDS")]
    pub flight_time: Option<f64>,

    /// Racket speed along the face, upward in its plane [m/s]: > 0 brushes topspin, < 0 backspin.
    #[arg(
        long,
        value_name = "M/S",
        default_value_t = 0.0,
        allow_hyphen_values = true
    )]
    pub brush: f64,

    /// Uncertainty of the ball at impact, per-axis standard deviations of its position [m],
    /// velocity [m/s] and spin [rad/s] (e.g. the interception's): also prints the landing's
    /// uncertainty, carried through the hit and the flight (with the rubber's own, when the
    /// configuration has racket.rubber_covariance or racket.rebound_scatter, as the calibrated
    /// presets do; then it is printed even without --sigma).
    #[arg(long, value_name = "P,V,W", value_parser = parse_vector)]
    pub sigma: Option<Vector3<f64>>,

    /// Ball, impact point, output, configuration.
    #[command(flatten)]
    pub common: StrokeArgs,
}

/// Parses `X,Y` into a target of two finite numbers.
fn parse_target(text: &str) -> Result<Vector2<f64>, String> {
    parse_numbers::<2>(text, "two", "0.9,0.3").map(Vector2::from)
}

impl ReboundArgs {
    /// Predicts the rebound and prints it.
    pub fn run(self) -> anyhow::Result<ExitCode> {
        let config = self.common.config.load()?;
        let length = self.normal.norm();
        if length <= 1e-9 {
            return Err(BadUsage("--normal must not be the zero vector".into()).into());
        }
        let racket = RacketState {
            velocity: self.racket_velocity,
            normal: self.normal / length,
            impact_offset: self.common.offset,
        };
        let stroke = Stroke::new(&config);
        let ball = self.common.ball.state();
        let rebound = stroke
            .rebound(&ball, &racket)
            .map_err(|e| BadUsage(format!("cannot predict this hit: {e}")))?;
        if self.common.json {
            let value = serde_json::json!({
                "racket": racket_json(&racket),
                "rebound": rebound_json(&rebound),
            });
            write_stdout(&format!("{}\n", serde_json::to_string_pretty(&value)?))?;
        } else {
            let mut out = String::new();
            let _ = writeln!(
                out,
                "Racket impact (Kawazoe & Suzuki; docs/models.md \"Racket impact\")"
            );
            describe_rebound(&mut out, &config, &ball, &racket, &rebound);
            write_stdout(&out)?;
        }
        if let Some(path) = &self.chart {
            write_chart(&config, path)?;
        }
        Ok(ExitCode::SUCCESS)
    }
}

impl AimArgs {
    /// Plans the racket command and prints it.
    pub fn run(self) -> anyhow::Result<ExitCode> {
        let config = self.common.config.load()?;
        let stroke = Stroke::new(&config);
        let condition = stroke.condition(self.flight_time, self.net_clearance);
        let aim = Aim {
            target: self.target,
            condition,
            impact_offset: self.common.offset,
            brush_speed: self.brush,
        };
        let ball = self.common.ball.state();
        let plan = stroke
            .plan(&ball, &aim)
            .map_err(|e| BadUsage(e.to_string()))?;
        let landing_covariance = (self.sigma.is_some() || stroke.racket().is_uncertain())
            .then(|| {
                let sigma = self.sigma.unwrap_or_default();
                let variances = StateVector::from_fn(|k, _| sigma[k / 3].powi(2));
                stroke.landing_covariance(
                    &ball,
                    &StateMatrix::from_diagonal(&variances),
                    &plan.racket,
                )
            })
            .flatten();
        if self.common.json {
            let value = serde_json::json!({
                "racket": racket_json(&plan.racket),
                "racket_speed": plan.racket.velocity.norm(),
                "landing_error": plan.landing_error,
                "iterations": plan.iterations,
                "landing_covariance": landing_covariance.map(|c| c.transpose().as_slice().to_vec()),
                "rebound": rebound_json(&plan.rebound),
            });
            write_stdout(&format!("{}\n", serde_json::to_string_pretty(&value)?))?;
        } else {
            let mut out = String::new();
            let _ = writeln!(
                out,
                "Racket command for a landing at ({:.3}, {:.3}) m, {} ({} iterations)",
                aim.target.x,
                aim.target.y,
                match condition {
                    ReturnCondition::NetClearance(c) => format!("{:.3} m over the net", c),
                    ReturnCondition::FlightTime(t) => format!("{t:.3} s of flight"),
                },
                plan.iterations
            );
            describe_plan(&mut out, &plan);
            if let Some(c) = landing_covariance {
                let _ = writeln!(
                    out,
                    "  landing uncertainty     sigma x {:.3} m, y {:.3} m, flight time {:.1} ms",
                    c[(0, 0)].sqrt(),
                    c[(1, 1)].sqrt(),
                    c[(2, 2)].sqrt() * 1e3
                );
            }
            describe_rebound(&mut out, &config, &ball, &plan.racket, &plan.rebound);
            write_stdout(&out)?;
        }
        Ok(ExitCode::SUCCESS)
    }
}

fn vector(v: &Vector3<f64>, precision: usize) -> String {
    format!("({:.p$}, {:.p$}, {:.p$})", v.x, v.y, v.z, p = precision)
}

fn describe_plan(out: &mut String, plan: &Plan) {
    let n = plan.racket.normal;
    let _ = writeln!(
        out,
        "  racket velocity         {} m/s, |V| = {:.3} m/s\n  \
         face normal             {} (tilted {:.1} deg up, {:.1} deg left)\n  \
         landing error           {:.2e} m",
        vector(&plan.racket.velocity, 3),
        plan.racket.velocity.norm(),
        vector(&n, 4),
        n.z.asin().to_degrees(),
        n.y.atan2(n.x).to_degrees(),
        plan.landing_error
    );
}

fn describe_rebound(
    out: &mut String,
    config: &Config,
    ball: &BallState,
    racket: &RacketState,
    rebound: &Rebound,
) {
    let hit = &rebound.hit;
    let normal = &hit.normal;
    let contact = &normal.contact;
    let _ = writeln!(
        out,
        "  impact offset           {:+.3} m from the centre of gravity ({:.0} mm from the grip end)\n  \
         impact speed (normal)   {:.3} m/s\n  \
         reduced mass M_r        {:.1} g (racket {:.0} g, arm {:.2} kg at {:.0} mm)\n  \
         rubber restitution      {:.3} (e_RB at this speed)\n  \
         rebound power coeff. e  {:.3}\n  \
         contact time            {:.3} ms\n  \
         contact force           mean {:.1} N, peak {:.1} N\n  \
         deformation             {:.2} mm at the mean force (ball and rubber)\n  \
         tangential              {} (rubber friction {:.3})\n  \
         wrist / grip load       peak {:.1} N (chi = {:+.3}), shock {:.0} m/s^2",
        racket.impact_offset,
        (config.racket.center_of_gravity_from_grip_end + racket.impact_offset) * 1e3,
        normal.impact_speed,
        normal.reduced_mass * 1e3,
        config.racket.mass * 1e3,
        config.arm.equivalent_mass,
        config.arm.grip_from_grip_end * 1e3,
        normal.rubber_restitution,
        normal.rebound_power_coefficient,
        contact.contact_time * 1e3,
        contact.mean_force,
        contact.peak_force,
        contact.deformation_at_mean_force * 1e3,
        match hit.regime {
            BounceRegime::Rolling if config.racket.rubber_tangential_restitution == 0.0 => {
                "the ball leaves rolling on the rubber".to_owned()
            }
            BounceRegime::Rolling => format!(
                "the rubber grips: the contact point's slip leaves reversed, {:.2} of itself",
                config.racket.rubber_tangential_restitution
            ),
            BounceRegime::Sliding => "the ball slides on the rubber throughout".to_owned(),
        },
        config.racket.rubber_friction,
        hit.wrist.peak_force,
        hit.wrist.transmission,
        hit.wrist.peak_acceleration,
    );
    let _ = writeln!(
        out,
        "  ball before             v {} m/s, w {} rad/s\n  \
         ball after              v {} m/s (|v| {:.2}), w {} rad/s\n  \
         racket after            {} m/s",
        vector(&ball.velocity, 2),
        vector(&ball.spin, 0),
        vector(&hit.ball.velocity, 2),
        hit.ball.velocity.norm(),
        vector(&hit.ball.spin, 0),
        vector(&hit.racket_velocity, 3),
    );
    let flight = &rebound.flight;
    let net = flight.net.map_or_else(
        || "does not reach the net".to_owned(),
        |(t, c)| format!("crosses the net after {t:.3} s, {c:.3} m over it"),
    );
    let landing = flight.landing.map_or_else(String::new, |(t, s)| {
        format!(
            ", at ({:.3}, {:.3}) m after {t:.3} s",
            s.position.x, s.position.y
        )
    });
    let _ = writeln!(
        out,
        "Return: the ball {}; it {}{landing}.",
        net,
        flight.outcome.describe()
    );
}

fn racket_json(racket: &RacketState) -> serde_json::Value {
    serde_json::json!({
        "velocity": racket.velocity.as_slice(),
        "normal": racket.normal.as_slice(),
        "impact_offset": racket.impact_offset,
    })
}

fn rebound_json(rebound: &Rebound) -> serde_json::Value {
    let hit = &rebound.hit;
    let n = &hit.normal;
    let c = &n.contact;
    let flight = &rebound.flight;
    serde_json::json!({
        "ball_velocity": hit.ball.velocity.as_slice(),
        "ball_spin": hit.ball.spin.as_slice(),
        "racket_velocity_after": hit.racket_velocity.as_slice(),
        "impact_speed": n.impact_speed,
        "reduced_mass": n.reduced_mass,
        "rubber_restitution": n.rubber_restitution,
        "restitution": n.restitution,
        "rebound_power_coefficient": n.rebound_power_coefficient,
        "vibration_energy": n.vibration_energy,
        "contact_time": c.contact_time,
        "stiffness": c.stiffness,
        "mean_force": c.mean_force,
        "peak_force": c.peak_force,
        "impulse": c.impulse,
        "deformation_at_mean_force": c.deformation_at_mean_force,
        "deformation_at_peak_force": c.deformation_at_peak_force,
        "regime": format!("{:?}", hit.regime),
        "wrist_transmission": hit.wrist.transmission,
        "wrist_force": hit.wrist.peak_force,
        "grip_acceleration": hit.wrist.peak_acceleration,
        "outcome": flight.outcome.describe(),
        "lands_on_table": flight.outcome == ttball::online::stroke::ReturnOutcome::Lands,
        "landing": flight.landing.map(|(t, s)| serde_json::json!({
            "time": t,
            "position": s.position.as_slice(),
            "velocity": s.velocity.as_slice(),
        })),
        "net": flight.net.map(|(t, c)| serde_json::json!({ "time": t, "clearance": c })),
    })
}

fn write_chart(config: &Config, path: &std::path::Path) -> anyhow::Result<()> {
    let model = ttball::physics::RacketModel::new(config);
    let options = ttball::plot::ChartOptions::default();
    let bytes = match path.extension().and_then(|e| e.to_str()) {
        Some("svg") => {
            ttball::plot::render_rebound_chart_svg(&model, config, &options)?.into_bytes()
        }
        Some("png") => ttball::plot::render_rebound_chart_png(&model, config, &options)?,
        _ => {
            return Err(BadUsage(format!(
                "--chart {}: give a file name ending in .svg or .png",
                path.display()
            ))
            .into());
        }
    };
    std::fs::write(path, bytes)
        .with_context(|| format!("cannot write the chart to {}", path.display()))?;
    write_stdout(&format!("chart written to {}\n", path.display()))
}
