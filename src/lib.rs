//! ttball: a real-time table-tennis ball-state estimator for robots.
//!
//! The crate is a pure core (no I/O, no clock, no ROS or MCAP types) and thin adapters around it:
//! - [`physics`]: flight (spin-parameter aerodynamic model), table bounce, event-aware propagation.
//! - [`estimator`]: the one entry point, `Estimator::handle(detection)`: tracking, out-of-order
//!   fusion, gating, initialisation, interception after every update.
//! - [`batch`]: the batch (maximum a posteriori, robust) fit of one whole flight: the offline
//!   smoother and the base of calibration.
//! - [`calibrate`]: the aero and bounce coefficients fitted to many recorded flights at once.
//! - [`rebound_calibration`]: the racket's rubber constants fitted to recorded hits, with
//!   standard errors and k-fold cross-validation.
//! - [`least_squares`]: a small dense Levenberg-Marquardt with central-difference Jacobians.
//! - [`smooth`]: a recording cut into flights by the estimator's tracks, each fitted whole: the
//!   smoothed state at every detection.
//! - [`eval`]: accuracy of the estimator on a simulated session against its truth.
//! - [`ekf`]: the extended Kalman filter over (position, velocity, spin).
//! - [`intercept`]: the predicted crossing of the robot's hitting plane, with its covariance.
//! - [`stroke`]: the robot's hit: the ball's rebound off the racket and its return flight, and
//!   the racket command (velocity, face normal) that returns the ball to a target.
//! - [`stats`]: chi-square quantiles for gates and consistency checks.
//! - [`detection`]: one 3D ball detection, as the estimator takes it.
//! - [`config`]: every physical constant and tuning value, with defaults and range checks.
//! - [`sim`]: simulated camera detections of real and random shots, with the truth, from a seed.
//! - `pipeline` (feature `interface`): the node minus its transport, one detection message in,
//!   the messages to publish out; the ROS node and the MCAP replay both drive it.
//! - `bag` (feature `bag`): ROS 2 MCAP bags as rosbag2 and Foxglove read and write them.
//! - `record` (feature `bag`): simulated play written as a bag, with its truth.
//! - `replay` (feature `bag`): an MCAP bag through the node's code path, into an output bag.
//! - `plot` (feature `plot`): figures (SVG, PNG) of what the estimator saw on one track or time
//!   window: detections, filtered track, predictions, truth; pure rendering, no file I/O.
//! - `msgs` (feature `interface`): serde mirrors of the ROS 2 interfaces in `msgs/` (package
//!   `ttball_msgs`) for ros2-client and MCAP, in wire (field) order.
//!
//! Units are SI everywhere (m, s, kg, rad/s) in the `table` frame described in the README.

#[cfg(feature = "bag")]
pub mod bag;
pub mod batch;
pub mod calibrate;
pub mod config;
pub mod detection;
pub mod ekf;
pub mod estimator;
pub mod eval;
pub mod frames;
pub mod intercept;
pub mod least_squares;
#[cfg(feature = "live-view")]
pub mod live_view;
#[cfg(feature = "interface")]
pub mod msgs;
#[cfg(feature = "node")]
pub mod node;
pub mod physics;
#[cfg(feature = "interface")]
pub mod pipeline;
#[cfg(feature = "plot")]
pub mod plot;
pub mod real;
pub mod rebound_calibration;
#[cfg(feature = "bag")]
pub mod record;
#[cfg(feature = "bag")]
pub mod replay;
pub mod sim;
pub mod smooth;
pub mod stats;
pub mod stroke;
