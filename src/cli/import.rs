//! `ttball import mpi`: real launcher flights (MPI for Intelligent Systems' CSV recordings) as a
//! bag of detections in the `table` frame, ready for `ttball replay`.

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{Context, bail};
use clap::{Args, Subcommand, ValueEnum};
use ttball::bag::record::write_detections;
use ttball::config::Config;
use ttball::eval::real::mpi::{
    LauncherFlights, RawFlight, SpinKind, flight_detections, parse_mpi_csv,
};
use ttball::eval::sim::DEFAULT_EPOCH;
use ttball::model::detection::{Source, seconds_to_ns};

use super::{ConfigArgs, write_stdout};

/// `ttball import ...`.
#[derive(Debug, Subcommand)]
pub enum ImportCommand {
    /// Recorded flights in the CSV format of the MPI for Intelligent Systems' launcher flights
    /// (trajectory,t_s,x_m,y_m,z_m), whatever the files' names.
    ///
    /// In the launcher's frame (`--frame launcher`, x along the table from the launcher's end line,
    /// z up) the transform into `table` is worked out from the flights themselves (the bounce
    /// heights give the surface, the launch positions the lateral centre, the launcher stands at
    /// the far end line): x_t = 1.37 - x, y_t = c_y - y, z_t = z - z_surface. Flights follow each
    /// other 1 s apart.
    #[command(
        visible_alias = "csv",
        after_help = "Example:\n  \
        ttball import mpi tests/data/mpi_launcher/*.csv --output bags/real_launcher.mcap"
    )]
    Mpi(MpiArgs),
}

/// Arguments of `ttball import mpi`.
#[derive(Debug, Args)]
pub struct MpiArgs {
    /// The CSV files.
    #[arg(required = true, value_name = "FILE.csv")]
    pub files: Vec<PathBuf>,

    /// The bag to write.
    #[arg(long, short, value_name = "OUT.mcap")]
    pub output: PathBuf,

    #[arg(long, value_enum, default_value = "launcher", help = FRAME_HELP)]
    pub frame: CsvFrame,

    /// The table geometry, ball and topics.
    #[command(flatten)]
    pub config: ConfigArgs,
}

/// What `--frame` says.
pub(super) const FRAME_HELP: &str = "The frame of the CSV files' coordinates: `launcher` (the \
    MPI launcher's; the transform into `table` is worked out from the flights) or `table` \
    (ttball's `table` frame; a flight moving toward +x is turned half a turn about z, so that \
    every flight comes toward the robot)";

/// The frame of recorded flights' coordinates.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum CsvFrame {
    /// The MPI launcher's.
    Launcher,
    /// ttball's `table` frame.
    Table,
}

/// The flights of CSV `files` in the MPI launcher's format, given in `frame`, in the `table`
/// frame (for `config`'s ball, table and gravity), with their noise.
pub(super) fn recorded_flights(
    files: &[PathBuf],
    frame: CsvFrame,
    config: &Config,
) -> anyhow::Result<LauncherFlights> {
    let raw = read_mpi_files(files)?;
    if raw.is_empty() {
        bail!(
            "no flights in {}",
            files
                .iter()
                .map(|f| f.display().to_string())
                .collect::<Vec<_>>()
                .join(", ")
        );
    }
    Ok(match frame {
        CsvFrame::Launcher => {
            LauncherFlights::new(raw, config.ball.radius, config.table.length, config.gravity)
                .context(
                    "cannot work out the frame transform from these flights (with flights \
                     recorded in ttball's table frame, give --frame table)",
                )?
        }
        CsvFrame::Table => LauncherFlights::in_table_frame(raw, config.gravity),
    })
}

/// The flights of CSV files in the MPI launcher's format, the spin kind of each from its name.
fn read_mpi_files(files: &[PathBuf]) -> anyhow::Result<Vec<RawFlight>> {
    let mut raw = Vec::new();
    for file in files {
        let name = file.file_name().map(|n| n.to_string_lossy());
        let kind = SpinKind::of_file_name(name.as_deref().unwrap_or_default());
        let text = std::fs::read_to_string(file)
            .with_context(|| format!("cannot read {}", file.display()))?;
        raw.extend(parse_mpi_csv(&text, kind).with_context(|| format!("{}", file.display()))?);
    }
    Ok(raw)
}

impl ImportCommand {
    /// Runs the import.
    pub fn run(self) -> anyhow::Result<ExitCode> {
        let Self::Mpi(args) = self;
        let config = args.config.load()?;
        let recorded = recorded_flights(&args.files, args.frame, &config)?;
        let mut detections = Vec::new();
        let mut epoch = DEFAULT_EPOCH;
        for flight in &recorded.flights {
            let span = flight.samples.last().map_or(0.0, |(t, _)| *t);
            detections.extend(flight_detections(flight, epoch, Source::WIDE_150FPS));
            epoch += seconds_to_ns(span + 1.0);
        }
        let written = write_detections(&detections, &config, &args.output)?;
        let frame = match &recorded.estimate {
            Some(estimate) => {
                let t = estimate.transform;
                format!(
                    "x_t = {:.4} - x, y_t = {:.4} - y, z_t = z - {:.4} m",
                    t.c_x, t.c_y, t.z_surface
                )
            }
            None => "table, as recorded".to_owned(),
        };
        write_stdout(&format!(
            "{}: {} flights, {} detections (frame: {frame})\n",
            args.output.display(),
            recorded.flights.len(),
            written,
        ))?;
        Ok(ExitCode::SUCCESS)
    }
}
