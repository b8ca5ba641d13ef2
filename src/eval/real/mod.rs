//! Real ball flights: the MPI launcher trajectories in ttball's `table` frame, their measurement
//! noise, and how well the estimator predicts them.
//!
//! - [`mpi`]: parsing the CSV files of the MPI launcher data set and the rigid transform from
//!   the launcher's frame into the `table` frame, worked out from the data (see its module doc
//!   for the reasoning); real flights as [`Detection`](crate::model::detection::Detection)s.
//! - The short ballistic fits they use (the measured bounce, smoothed positions) are general
//!   tools and live in [`crate::offline::ballistic`].
//! - [`noise`]: the position noise of recorded flights, per axis, from the residuals of a local
//!   polynomial fit.
//! - [`accuracy`]: each flight through [`Estimator::handle`](crate::online::estimator::Estimator::handle),
//!   and the predicted crossing of a plane after the bounce at fixed leads against the measured
//!   crossing, per spin kind and overall.
//!
//! Everything here is core: no I/O (the caller reads the files and passes their text), no clock.
//!
//! The data: "mn5008" launcher trajectories recorded by the Intelligent Soft Robots group (MPI
//! for Intelligent Systems), repository `intelligent-soft-robots/ball_prediction`, files
//! `data/mn5008_{backspin,no_spin,topspin}.hdf5`, converted to CSV without changing any value.
//! BSD 3-Clause License, Copyright (c) 2023, Intelligent Soft Robots; the licence's full text
//! (`LICENSE` next to the CSV files) goes with every copy of the data. The repository holds a
//! copy (`tests/data/mpi_launcher/`, with the licence), which the tests and
//! `bags/real_launcher.mcap` are made from.

pub mod accuracy;
pub mod mpi;
pub mod noise;

pub use accuracy::{
    FlightResult, GroupSummary, LeadOutcome, LeadSummary, MeasuredCrossing, Plane, RealEvalOptions,
    RealReport, Unscored, drag_only, evaluate_flights, measured_crossing, topspin,
};
pub use mpi::{
    Flight, FrameTransform, LauncherFlights, MpiError, RawFlight, SpinKind, TransformEstimate,
    estimate_transform, flight_detections, parse_mpi_csv,
};
pub use noise::{AxisNoise, NoiseEstimate, estimate_noise};
