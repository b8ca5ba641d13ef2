//! One 3D ball detection as the core sees it: the adapters turn `ttball_msgs/msg/BallDetection`
//! into this (stamp in integer nanoseconds, covariances as matrices, "all zero" as `None`).

use nalgebra::{Matrix3, Vector3};

/// A duration or offset in seconds as integer nanoseconds (rounded), the time unit at every
/// boundary of ttball.
pub fn seconds_to_ns(seconds: f64) -> i64 {
    (seconds * 1e9).round() as i64
}

/// The camera system that made a detection.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Source {
    /// Not stated: the estimator uses `sources.unknown`.
    Unknown,
    /// The 150 fps camera system that sees the whole table (position only).
    Wide150Fps,
    /// The 900 fps camera system that sees the robot's half (position, and spin on most frames).
    HighSpeed900Fps,
}

impl Source {
    /// The `SOURCE_*` code of `BallDetection.msg`.
    pub fn code(self) -> u8 {
        match self {
            Self::Unknown => 0,
            Self::Wide150Fps => 1,
            Self::HighSpeed900Fps => 2,
        }
    }

    /// Its place in per-source arrays ordered by code (unknown, 150 fps, 900 fps): its code.
    pub fn index(self) -> usize {
        usize::from(self.code())
    }

    /// The source of a `SOURCE_*` code; unknown codes map to [`Source::Unknown`].
    pub fn from_code(code: u8) -> Self {
        match code {
            1 => Self::Wide150Fps,
            2 => Self::HighSpeed900Fps,
            _ => Self::Unknown,
        }
    }
}

/// One detection of the ball centre in the `table` frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Detection {
    /// Exposure time [ns] on the clock of the detections.
    pub stamp: i64,
    /// The camera system.
    pub source: Source,
    /// Ball centre [m].
    pub position: Vector3<f64>,
    /// Position covariance [m^2]; `None` uses the configured noise of the source.
    pub position_covariance: Option<Matrix3<f64>>,
    /// Measured angular velocity [rad/s], when the camera measured it.
    pub spin: Option<Vector3<f64>>,
    /// Spin covariance [(rad/s)^2]; `None` uses the configured noise of the source.
    pub spin_covariance: Option<Matrix3<f64>>,
    /// Detector score in [0, 1].
    pub confidence: f32,
}
