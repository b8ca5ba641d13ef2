//! The command-line interface: the [`Command`] enum, one file per subcommand, and the arguments
//! shared between commands ([`ConfigArgs`]). Commands are thin adapters around the library.

pub mod calibrate;
pub mod config_cmd;
pub mod dump;
pub mod evaluate;
pub mod import;
pub mod node;
pub mod play;
pub mod plot;
pub mod predict;
pub mod racket;
pub mod replay;
pub mod report;
pub mod simulate;
pub mod smooth;

use std::io::{IsTerminal, Write};
use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

use anyhow::Context;
use clap::{Args, Parser, Subcommand};
use indicatif::{ProgressBar, ProgressStyle};
use ttball::config::Config;
use ttball::config::yaml::{self, Layer, LoadError};

/// Exit code of a command whose configuration is invalid (and of `config check` on a bad file).
pub const EXIT_BAD_CONFIG: u8 = 2;
/// Exit code of any other failure.
pub const EXIT_FAILURE: u8 = 1;

/// `ttball`: the command line.
#[derive(Debug, Parser)]
#[command(
    name = "ttball",
    version,
    about = "ttball: a real-time table-tennis ball-state estimator for robots.\n\
             Estimates position, velocity and spin from camera detections; predicts bounces and hits.",
    after_help = "Every command that reads the configuration takes `--config FILE` (a ROS 2 \
                  parameters file, see config/ttball.yaml) and `-p NAME:=VALUE` overrides.\n\
                  Exit codes: 0 success, 1 failure, 2 invalid configuration or usage.\n\n\
                  Run `ttball <COMMAND> --help` for a command's options and examples."
)]
pub struct Cli {
    /// What to do.
    #[command(subcommand)]
    pub command: Command,
}

/// The subcommands; each lives in its own file and is run by [`Command::run`].
#[derive(Debug, Subcommand)]
pub enum Command {
    /// Print the effective configuration, or check a configuration file.
    #[command(subcommand)]
    Config(config_cmd::ConfigCommand),

    /// Predict the flight of one ball state: bounces, net, floor and the hitting plane.
    ///
    /// Without arguments it predicts a real rally ball (see --position). The table lists every
    /// event with the state just after it; --csv writes the sampled trajectory.
    #[command(after_help = "Examples:\n  \
        ttball predict                                       # a real rally ball, default config\n  \
        ttball predict --velocity -7,0,1.2 --spin 0,-150,0   # a topspin drive\n  \
        ttball predict -p table.restitution:=0.93 --csv flight.csv")]
    Predict(predict::PredictArgs),

    /// Measure the estimator's accuracy on simulated play with truth.
    ///
    /// Simulates shots (real rally balls and random spins) seen by the 150 fps camera alone and
    /// by both cameras, runs every detection through the estimator in arrival order (exactly as
    /// the node would), and prints velocity, spin and interception errors, valid fractions and
    /// NEES. The estimator's camera noise is set to the simulated cameras'.
    #[command(after_help = "Examples:\n  \
        ttball evaluate                              # 200 shots, both camera setups\n  \
        ttball evaluate --shots 50 --cameras wide+highspeed --json report.json\n  \
        ttball evaluate -p ekf.acceleration_noise_density:=0.01")]
    Evaluate(evaluate::EvaluateArgs),

    /// Replay ROS 2 MCAP bags through the node's code path and write what it would publish.
    ///
    /// Reads `ttball_msgs/msg/BallDetection` from `topics.detections` in log-time order and runs
    /// each through exactly the estimator the live node runs. The output bag holds the input
    /// topics unchanged plus /ball/state, /ball/intercept, /ball/trajectory and /ball/markers
    /// (open it in Foxglove). Deterministic: two replays give byte-identical files. A bag with
    /// the simulator's truth also gets the accuracy table.
    #[command(after_help = "Examples:\n  \
        ttball replay bags/sim_rally_2cams.mcap --output out.mcap\n  \
        ttball replay bags/*.mcap --output-dir out/ --report out/report.json\n  \
        ttball replay my_rally.mcap -o out.mcap -p topics.detections:=/vision/ball -p intercept.plane_x:=-1.45\n  \
        ttball replay bags/real_launcher.mcap --learned learned.yaml   # then: ttball node --config learned.yaml")]
    Replay(replay::ReplayArgs),

    /// Calibrate the aero and bounce coefficients from recorded flights, or the racket's rubber
    /// from recorded hits.
    ///
    /// Cuts the bags' detections into flights with the estimator's tracks and fits, over all
    /// flights together, the C_D(Sp) and C_M(Sp) polynomial coefficients (orders chosen by AIC
    /// unless given), the table's restitution and friction, or the air density, with every
    /// flight's state (position, velocity, spin) as a nuisance parameter; measured spins are
    /// used where the bags have them. With --method estimator, fits the scales and the table
    /// with the estimator's own model instead (each flight smoothed with the noise it learns,
    /// its own parameters about the shared ones): the numbers the node learns online, and the
    /// noise with them. With --rebound HITS.csv, fits the rubber's restitution
    /// polynomial, friction, tangential and torsional restitution to the measured outgoing
    /// velocity and spin of recorded hits, k-fold cross-validated. Writes a configuration
    /// snippet (pass it to --config) with standard errors, and optionally a chart and JSON.
    #[command(after_help = "Examples:\n  \
        ttball calibrate my_rallies/*.mcap --output calibrated.yaml --plot calibration.png\n  \
        ttball calibrate bags/real_launcher.mcap -o launcher.yaml --holdout\n  \
        ttball calibrate rally.mcap -o table.yaml --fit bounce\n  \
        ttball calibrate bags/real_launcher.mcap -o ball.yaml --method estimator\n  \
        ttball calibrate rally.mcap -o aero.yaml --fit aero --drag-order 2 --magnus-order 4\n  \
        ttball calibrate --rebound tests/data/tt_rackets/test/racket_01.csv -o rubber.yaml --plot rubber.svg\n\n\
        Progress goes to stderr: every iteration on a terminal or with TTBALL_VERBOSE=1, the\n\
        stages otherwise.")]
    Calibrate(calibrate::CalibrateArgs),

    /// Smooth a bag: fit every flight as a whole and write the state at each detection.
    ///
    /// Cuts the detections into flights with the estimator's own tracks, fits each flight's
    /// state (position, velocity, spin) to all its detections through its bounces (robust
    /// maximum likelihood with the physics core) and writes the fitted state and covariance at
    /// every detection on topics.smoothed (/ball/smoothed, ttball_msgs/msg/BallState) beside the
    /// input's messages. Seeing the whole flight, it is far more accurate than the online
    /// filter: use it as reference for tuning, or to label recorded rallies.
    #[command(after_help = "Examples:\n  \
        ttball smooth bags/sim_rally_2cams.mcap --output smoothed.mcap\n  \
        ttball smooth rally.mcap -o smoothed.mcap --config calibrated.yaml\n  \
        ttball dump smoothed.mcap --topic /ball/smoothed | head")]
    Smooth(smooth::SmoothArgs),

    /// Print every message of a bag as JSON lines (topic, log time, decoded message).
    #[command(after_help = "Examples:\n  \
        ttball dump out.mcap --topic /ball/intercept | head\n  \
        ttball dump bags/sim_rally_2cams.mcap > messages.jsonl")]
    Dump(dump::DumpArgs),

    /// Draw what the estimator saw in a bag (SVG or PNG): views, predictions, speed and spin.
    #[command(after_help = "Examples:\n  \
        ttball plot out.mcap --list\n  \
        ttball plot out.mcap --output track.png             # the longest track\n  \
        ttball plot out.mcap --output t3.svg --track 3\n  \
        ttball plot out.mcap --output w.png --window 1.0,2.5")]
    Plot(plot::PlotArgs),

    /// Predict what a racket hit does: rebound, spin, contact time and forces, wrist load, landing.
    ///
    /// The racket impact model (Kawazoe & Suzuki; Kawazoe et al. 2010): reduced mass of the racket
    /// and arm at the impact point, velocity-dependent restitution, contact time and force from
    /// the ball-rubber restoring characteristic, spin from the rubber's friction, the force on
    /// the grip; then the return flight to its first bounce. The default ball is a real rally
    /// ball at the hitting plane; the default stroke a drive with a slightly closed face. --chart draws e along the
    /// racket and against impact speed.
    #[command(after_help = "Examples:\n  \
        ttball rebound                                                   # a drive on a real ball\n  \
        ttball rebound --racket-velocity 3,0,3 --normal 0.9,0,0.45 --offset 0.06\n  \
        ttball rebound --json -p arm.equivalent_mass:=0          # a free racket\n  \
        ttball rebound --chart racket_e.svg")]
    Rebound(racket::ReboundArgs),

    /// Plan the racket command that returns the ball to a target on the opponent's half.
    ///
    /// Solves for the racket velocity (along the face normal, plus an optional brush along the
    /// face) and the face normal so that the ball, through the full rebound and flight models,
    /// lands on --target with the given net clearance or flight time. Reports the target as
    /// unreachable when the racket would exceed stroke.max_racket_speed.
    #[command(after_help = "Examples:\n  \
        ttball aim --target 0.9,0.3                          # default clearance (stroke.net_clearance)\n  \
        ttball aim --target 1.1,-0.5 --net-clearance 0.3 --brush 2\n  \
        ttball aim --target 0.6,0 --flight-time 0.5 --json\n  \
        ttball aim --sigma 0.002,0.05,20       # and the landing's uncertainty")]
    Aim(racket::AimArgs),

    /// Import recorded ball flights from other formats as a bag of detections.
    #[command(subcommand)]
    Import(import::ImportCommand),

    /// Run the live ROS 2 node: detections in, state, intercept, trajectory, markers out.
    ///
    /// A ROS 2 node (ros2-client on RustDDS; no ROS 2 installation needed) on the domain from
    /// ROS_DOMAIN_ID. Subscribes topics.detections (ttball_msgs/msg/BallDetection, best effort)
    /// and topics.robot_hits (ttball_msgs/msg/RobotHit: the robot's own hits, announced);
    /// publishes /ball/state, /ball/intercept, /ball/trajectory, /ball/markers and /diagnostics
    /// (reliable) and serves ~/predict_trajectory, ~/predict_rebound and ~/plan_return. Every
    /// detection runs through exactly the code `ttball replay` runs. Stops cleanly on Ctrl-C or SIGTERM and prints what it did.
    /// Logs go to stderr; set their level with RUST_LOG (e.g. RUST_LOG=debug).
    #[command(after_help = "Examples:\n  \
        ttball node\n  \
        ttball node --config my.yaml -p intercept.plane_x:=-1.45\n  \
        ttball node --config learned.yaml --learned learned.yaml   # start from the last run's lesson, keep this one's\n  \
        ttball node --ros-args -r __ns:=/robot1 -r /ball/detections:=/vision/ball -p node.localhost_only:=true\n  \
        ROS_DOMAIN_ID=7 ttball node -p node.service_mapping:=cyclone   # beside rmw_cyclonedds\n\n\
        Try it without ROS 2: `ttball play bags/sim_rally_2cams.mcap` in another terminal.\n\
        DDS discovers peers by multicast on every interface: ROS_LOCALHOST_ONLY=1 (or\n\
        -p node.localhost_only:=true) keeps it on this machine.")]
    Node(node::NodeArgs),

    /// Publish a bag's detections on DDS at their recorded pace (like `ros2 bag play`).
    ///
    /// Publishes the ttball_msgs/msg/BallDetection messages of topics.detections with the
    /// node's QoS (best effort), on the domain from ROS_DOMAIN_ID, waiting first for a
    /// subscriber (--wait). With --loop, each pass's stamps continue where the last ended.
    #[command(after_help = "Examples:\n  \
        ttball play bags/sim_rally_2cams.mcap\n  \
        ttball play bags/real_launcher.mcap --rate 0.5 --loop")]
    Play(play::PlayArgs),

    /// Write a bag of simulated play (detections of both cameras, with truth).
    #[command(after_help = "Examples:\n  \
        ttball simulate --output rally.mcap --shots 20 --seed 7\n  \
        ttball simulate --output wide.mcap --cameras wide\n  \
        ttball simulate --output hour.mcap --shots 3200 --no-truth   # an hour, detections only")]
    Simulate(simulate::SimulateArgs),
}

impl Command {
    /// Runs the command; `Ok` carries the exit code of a command that ran to its end.
    pub fn run(self) -> anyhow::Result<ExitCode> {
        match self {
            Self::Config(command) => command.run(),
            Self::Predict(args) => args.run(),
            Self::Evaluate(args) => args.run(),
            Self::Replay(args) => args.run(),
            Self::Simulate(args) => args.run(),
            Self::Smooth(args) => args.run(),
            Self::Calibrate(args) => args.run(),
            Self::Dump(args) => args.run(),
            Self::Import(command) => command.run(),
            Self::Plot(args) => args.run(),
            Self::Node(args) => args.run(),
            Self::Play(args) => args.run(),
            Self::Rebound(args) => args.run(),
            Self::Aim(args) => args.run(),
        }
    }
}

/// The configuration arguments, flattened into every command that reads the configuration.
#[derive(Debug, Clone, Default, Args)]
pub struct ConfigArgs {
    /// ROS 2 parameters file with the configuration (`ttball: ros__parameters: ...`); it may set
    /// any subset of the parameters, the others keep their defaults (config/ttball.yaml).
    /// Repeatable, like ROS 2's --params-file: each file overrides the ones before it (e.g. your
    /// robot's file, then a preset from config/presets/).
    #[arg(long, value_name = "FILE")]
    pub config: Vec<PathBuf>,

    /// Parameter overrides.
    #[command(flatten)]
    pub overrides: Overrides,
}

impl ConfigArgs {
    /// The loaded and validated configuration: defaults, then `--config`, then each `-p`.
    pub fn load(&self) -> Result<Config, LoadError> {
        yaml::load_layers(&self.layers(), None)
    }

    /// The files, then the overrides, as configuration layers in the order they apply.
    pub fn layers(&self) -> Vec<Layer> {
        self.config
            .iter()
            .cloned()
            .map(Layer::File)
            .chain(self.overrides.params.iter().cloned().map(Layer::Param))
            .collect()
    }
}

/// `-p NAME:=VALUE` overrides, ROS style.
#[derive(Debug, Clone, Default, Args)]
pub struct Overrides {
    /// Set one parameter, ROS style, after the file: a dotted name, `:=`, and a YAML value
    /// (`-p intercept.plane_x:=-1.45`, `-p topics.state:=/robot/ball_state`,
    /// `-p aero.drag_coefficients:=[0.37, 0.36, -0.07]`). Repeatable; the last one of a name wins.
    #[arg(short = 'p', long = "param", value_name = "NAME:=VALUE")]
    pub params: Vec<String>,
}

/// A command line that cannot be run as given (exit code [`EXIT_BAD_CONFIG`]).
#[derive(Debug, thiserror::Error)]
#[error("{0}")]
pub struct BadUsage(pub String);

/// The configuration of `layers` without the learned files among them
/// ([`yaml::without_learned_files`]), for the node `node_fqn`: what a run's learned file is
/// written against. None where there is no learned file among them (the configuration of every
/// layer is the own one), or where the rest alone does not load (said on stderr: the file then
/// holds only what this run moved).
pub fn own_configuration(layers: &[Layer], node_fqn: Option<&str>) -> Option<Config> {
    let own = yaml::without_learned_files(layers);
    if own.len() == layers.len() {
        return None;
    }
    yaml::load_layers(&own, node_fqn)
        .inspect_err(|e| {
            eprintln!(
                "warning: the configuration without its learned files does not load ({e}); \
                 the learned file holds only what this run moved"
            );
        })
        .ok()
}

/// A `--learned FILE` whose directory does not exist is refused before any work (a node would
/// otherwise run, and a replay finish, with nowhere to keep what was learned).
pub fn check_learned_file(path: &std::path::Path) -> Result<(), BadUsage> {
    let directory = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => std::path::Path::new("."),
    };
    if directory.is_dir() {
        Ok(())
    } else {
        Err(BadUsage(format!(
            "--learned {}: the directory {} does not exist; create it, or give a file in an \
             existing one",
            path.display(),
            directory.display()
        )))
    }
}

/// The exit code for a failed command: [`EXIT_BAD_CONFIG`] when the configuration could not be
/// loaded or the command line is unusable, [`EXIT_FAILURE`] otherwise.
pub fn exit_code_for(err: &anyhow::Error) -> ExitCode {
    let bad_config = err.chain().any(|cause| {
        cause.downcast_ref::<BadUsage>().is_some()
            || cause
                .downcast_ref::<LoadError>()
                .is_some_and(|e| !matches!(e, LoadError::Internal { .. }))
    });
    ExitCode::from(if bad_config {
        EXIT_BAD_CONFIG
    } else {
        EXIT_FAILURE
    })
}

/// Sends logs (ttball's, ros2-client's and RustDDS's) to stderr (unless `console` is false:
/// ROS 2's `--disable-stdout-logs`), filtered by `RUST_LOG`, else by `level` (ROS 2's
/// `--log-level`) or `info`, with the DDS libraries at `error` (their warnings are about datagram
/// sizes and ROS_DISTRO; `RUST_LOG=rustdds=warn` shows them); ttball's records that pass the
/// filter go to `/rosout` too while a node runs.
pub fn init_logging(level: Option<&str>, console: bool) {
    use tracing_subscriber::EnvFilter;
    use tracing_subscriber::layer::SubscriberExt;
    use tracing_subscriber::util::SubscriberInitExt;
    let filter = EnvFilter::try_from_default_env().unwrap_or_else(|_| {
        let level = level.unwrap_or("info");
        EnvFilter::new(format!("{level},rustdds=error,ros2_client=error"))
    });
    let _ = tracing_subscriber::registry()
        .with(filter)
        .with(console.then(|| {
            tracing_subscriber::fmt::layer()
                .with_writer(std::io::stderr)
                .with_ansi(std::io::IsTerminal::is_terminal(&std::io::stderr()))
        }))
        .with(RosoutLayer)
        .try_init();
}

/// Hands ttball's events at or above the logger's level to `/rosout` while a node runs
/// (`ttball::node::rosout`), as rcl does.
struct RosoutLayer;

impl<S: tracing::Subscriber> tracing_subscriber::Layer<S> for RosoutLayer {
    fn on_event(&self, event: &tracing::Event<'_>, _: tracing_subscriber::layer::Context<'_, S>) {
        let meta = event.metadata();
        let level = match *meta.level() {
            tracing::Level::ERROR => ttball::node::rosout::ERROR,
            tracing::Level::WARN => ttball::node::rosout::WARN,
            tracing::Level::INFO => ttball::node::rosout::INFO,
            tracing::Level::DEBUG | tracing::Level::TRACE => ttball::node::rosout::DEBUG,
        };
        if !meta.target().starts_with("ttball") {
            return;
        }
        struct Message(String);
        impl tracing::field::Visit for Message {
            fn record_debug(&mut self, field: &tracing::field::Field, value: &dyn std::fmt::Debug) {
                if field.name() == "message" {
                    self.0 = format!("{value:?}");
                }
            }
        }
        let mut message = Message(String::new());
        event.record(&mut message);
        ttball::node::rosout::forward(
            level,
            &message.0,
            meta.file().unwrap_or_default(),
            meta.module_path().unwrap_or_default(),
            meta.line().unwrap_or_default(),
        );
    }
}

/// A flag that Ctrl-C (SIGINT) and SIGTERM set, for commands that stop cleanly, and whether
/// the handler could be installed (only one per process: tests that run several commands in
/// one process get a flag that never sets).
pub fn cancel_on_interrupt() -> (Arc<AtomicBool>, Result<(), ctrlc::Error>) {
    let cancel = Arc::new(AtomicBool::new(false));
    let flag = Arc::clone(&cancel);
    let installed = ctrlc::set_handler(move || flag.store(true, Ordering::Relaxed));
    (cancel, installed)
}

/// A progress bar on standard error with `message` and the indicatif `template` when standard
/// error is a terminal; a hidden one otherwise.
pub fn progress_bar(message: String, template: &str) -> ProgressBar {
    if !std::io::stderr().is_terminal() {
        return ProgressBar::hidden();
    }
    let bar = ProgressBar::new(0);
    bar.set_style(ProgressStyle::with_template(template).map_or_else(
        |_| ProgressStyle::default_bar(),
        |s| s.progress_chars("=> "),
    ));
    bar.set_message(message);
    bar
}

/// Writes `text` to standard output; a closed pipe (`ttball ... | head`) is not an error.
pub fn write_stdout(text: &str) -> anyhow::Result<()> {
    let mut out = std::io::stdout().lock();
    match out.write_all(text.as_bytes()).and_then(|()| out.flush()) {
        Err(e) if e.kind() == std::io::ErrorKind::BrokenPipe => Ok(()),
        other => other.context("cannot write to standard output"),
    }
}

/// Writes `bytes` to the file at `path` (created or replaced); the error names the file.
pub fn write_file(path: &std::path::Path, bytes: impl AsRef<[u8]>) -> anyhow::Result<()> {
    std::fs::write(path, bytes).with_context(|| format!("cannot write {}", path.display()))
}

/// Writes `value` to the file at `path` as indented JSON ending in a newline.
pub fn write_json(path: &std::path::Path, value: &impl serde::Serialize) -> anyhow::Result<()> {
    write_file(path, serde_json::to_string_pretty(value)? + "\n")
}
