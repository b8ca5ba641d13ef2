//! One 3D ball detection as the core sees it: the adapters turn `ttball_msgs/msg/BallDetection`
//! into this (stamp in integer nanoseconds, covariances as matrices, "all zero" as `None`).

use nalgebra::{Matrix3, Vector3};

/// A duration or offset in seconds as integer nanoseconds (rounded), the time unit at every
/// boundary of ttball.
pub fn seconds_to_ns(seconds: f64) -> i64 {
    (seconds * 1e9).round() as i64
}

/// The camera system that made a detection: `BallDetection.source`, a `SOURCE_*` code or the
/// id of a camera configured under `sources.*` (`sources.<name>.id`). The estimator takes each
/// source's noise from the source configured with its id, and `sources.unknown`'s for an id no
/// source has.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct Source(pub u8);

impl Source {
    /// `SOURCE_UNKNOWN`: not stated.
    pub const UNKNOWN: Self = Self(0);
    /// `SOURCE_WIDE_150FPS`: the 150 fps camera system that sees the whole table (position only).
    pub const WIDE_150FPS: Self = Self(1);
    /// `SOURCE_HIGHSPEED_900FPS`: the 900 fps camera system that sees the robot's half
    /// (position, and spin on most frames).
    pub const HIGHSPEED_900FPS: Self = Self(2);
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
