//! `ttball import mpi`: real launcher flights (MPI for Intelligent Systems' CSV recordings) as a
//! bag of detections in the `table` frame, ready for `ttball replay`.

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{Context, bail};
use clap::{Args, Subcommand};
use ttball::bag::record::write_detections;
use ttball::eval::real::mpi::{
    RawFlight, SpinKind, estimate_transform, flight_detections, parse_mpi_csv,
};
use ttball::eval::sim::DEFAULT_EPOCH;
use ttball::model::detection::{Source, seconds_to_ns};

use super::{ConfigArgs, write_stdout};

/// `ttball import ...`.
#[derive(Debug, Subcommand)]
pub enum ImportCommand {
    /// Launcher flights recorded by the MPI for Intelligent Systems (CSV: trajectory,t_s,x_m,y_m,z_m).
    ///
    /// The frame transform into `table` is worked out from the flights themselves (the bounce
    /// heights give the surface, the launch positions the lateral centre, the launcher stands at
    /// the far end line): x_t = 1.37 - x, y_t = c_y - y, z_t = z - z_surface. Flights follow each other 1 s
    /// apart. Other recordings in this format and frame (x along the table from the launcher's
    /// end line, z up) import the same way, whatever their files' names.
    #[command(after_help = "Example:\n  \
        ttball import mpi tests/data/mpi_launcher/*.csv --output bags/real_launcher.mcap")]
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

    /// The table geometry, ball and topics.
    #[command(flatten)]
    pub config: ConfigArgs,
}

/// The flights of CSV files in the MPI launcher's format, the spin kind of each from its name.
pub(super) fn read_mpi_files(files: &[PathBuf]) -> anyhow::Result<Vec<RawFlight>> {
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
        let raw = read_mpi_files(&args.files)?;
        if raw.is_empty() {
            bail!("no flights in {:?}", args.files);
        }
        let estimate = estimate_transform(
            &raw,
            config.ball.radius,
            config.table.length,
            config.gravity,
        )
        .context("cannot work out the frame transform from these flights")?;
        let transform = estimate.transform;
        let mut detections = Vec::new();
        let mut epoch = DEFAULT_EPOCH;
        for flight in &raw {
            let flight = flight.to_table(&transform);
            let span = flight.samples.last().map_or(0.0, |(t, _)| *t);
            detections.extend(flight_detections(&flight, epoch, Source::WIDE_150FPS));
            epoch += seconds_to_ns(span + 1.0);
        }
        let written = write_detections(&detections, &config, &args.output)?;
        write_stdout(&format!(
            "{}: {} flights, {} detections (frame: x_t = {:.4} - x, y_t = {:.4} - y, z_t = z - {:.4} m)\n",
            args.output.display(),
            raw.len(),
            written,
            transform.c_x,
            transform.c_y,
            transform.z_surface
        ))?;
        Ok(ExitCode::SUCCESS)
    }
}
