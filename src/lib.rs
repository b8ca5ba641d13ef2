//! ttball: a real-time table-tennis ball-state estimator for robots.
//!
//! # Layers
//!
//! The crate is a pure core (no I/O, no clock, no ROS or MCAP types) and thin adapters around
//! it, in folders that are layers, listed here from the bottom up. A layer uses only itself and the
//! layers listed before it, never one listed after it (`tests/core/layers.rs` checks every `crate::`
//! path of every source file against this list):
//!
//! 1. [`model`]: detections, time, frames, statistics, random numbers, Levenberg-Marquardt: the
//!    shared vocabulary and tools.
//! 2. [`config`]: every physical constant and tuning value, with defaults and range checks.
//! 3. [`physics`]: flight (spin-parameter aerodynamic model), table bounce, racket impact,
//!    event-aware propagation with the state-transition matrix.
//! 4. [`online`]: what the node runs per detection: the estimator (`Estimator::handle`, the one
//!    entry point), the EKF, the interception, the robot's stroke.
//! 5. [`offline`]: whole recordings fitted at once: batch fit, smoothing, calibration of the
//!    flight and of the rubber.
//! 6. [`eval`]: the simulator with its truth, the real data sets, and the scoring of the
//!    estimator against both.
//! 7. `plot` (feature `plot`): figures (SVG, PNG) of what the estimator saw; pure rendering.
//! 8. `ros` (feature `interface`): the ROS 2 interface types, their conversions, every type
//!    name, and the pipeline: the node minus its transport, one message in, the messages to
//!    publish out.
//! 9. `bag` (feature `bag`): ROS 2 MCAP bags (read, write), the replay through the pipeline,
//!    simulated play recorded as a bag, the Foxglove live view.
//! 10. `node` (feature `node`): the live ROS 2 node on ros2-client, and `ttball play`.
//!
//! The command-line tool (`src/cli`, in the binary) sits on top of them all.
//!
//! Units are SI everywhere (m, s, kg, rad/s) in the `table` frame (docs/models.md, "Frames, units and time"). The
//! models and their sources are in `docs/models.md`.

pub mod model;

pub mod config;

pub mod physics;

pub mod online;

pub mod offline;

pub mod eval;

#[cfg(feature = "plot")]
pub mod plot;

#[cfg(feature = "interface")]
pub mod ros;

#[cfg(feature = "bag")]
pub mod bag;

#[cfg(feature = "node")]
pub mod node;
