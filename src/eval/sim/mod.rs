//! The simulator: what a table-tennis robot's two camera systems deliver during play, with the
//! truth alongside, for evaluating the estimator (and, through the replay command, for writing
//! sample bags). A pure core: no I/O, no clock, no ROS or MCAP types; a session is a function of
//! the configuration, the options and a `u64` seed, with its own random numbers ([`Rng`], from [`crate::model::rng`]).
//!
//! - [`launch`]: real (GDM) and random launch states, and the good-shot check.
//! - [`params`]: the cameras (150 fps wide, 900 fps high-speed), shots and truth step.
//! - [`camera`]: frame clocks, noise, dropouts, outliers, latency.
//! - [`session`]: [`simulate`] a sequence of shots into a detection stream sorted by arrival.

pub mod camera;
pub mod launch;
pub mod params;
pub mod session;

pub use crate::model::rng::{Rng, SplitMix64, Stream};
pub use camera::{CameraCounts, FrameClock};
pub use launch::{
    GDM_RALLIES_CSV, GoodShot, LaunchCsvError, LaunchRecord, Rejection, ShotCheck, ShotKind,
    SpinKind, check_shot, gdm_rallies, parse_launch_csv, random_launch,
};
pub use params::{
    CameraParams, Cameras, FieldOfView, Interval, ParamError, RandomLaunchParams, ShotParams,
    SimParams, Spread,
};
pub use session::{
    Acceptance, CameraReport, DEFAULT_EPOCH, Session, ShotTruth, SimDetection, SimError,
    SimOptions, TruthEvent, simulate,
};
