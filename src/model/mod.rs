//! The bottom layer: the vocabulary every other layer speaks, with no physics and no
//! configuration.
//!
//! - [`detection`]: one 3D ball detection as the core takes it, its camera source, and the
//!   nanosecond time unit of every boundary.
//! - [`frames`]: static rigid transforms between frames (tf2's convention) and detections
//!   brought into the `table` frame.
//! - [`stats`]: chi-square quantiles for gates and consistency checks, duration summaries, and the
//!   RMS/median/p95 summary of errors.
//! - [`least_squares`]: Levenberg-Marquardt, one damping schedule for every fit, and a dense
//!   minimiser with central-difference Jacobians.
//! - [`rng`]: platform-stable random numbers (xoshiro256**) for the simulator and the tests.

pub mod detection;
pub mod frames;
pub mod least_squares;
pub mod rng;
pub mod stats;
