//! ttball: a real-time table-tennis ball-state estimator for robots.
//!
//! The crate is a pure core (no I/O, no clock, no ROS or MCAP types) and thin adapters around it:
//! - [`physics`]: flight (spin-parameter aerodynamic model), table bounce, event-aware propagation.
//! - [`estimator`]: the one entry point, `Estimator::handle(detection)`: tracking, out-of-order
//!   fusion, gating, initialisation, interception after every update.
//! - [`eval`]: accuracy of the estimator on a simulated session against its truth.
//! - [`ekf`]: the extended Kalman filter over (position, velocity, spin).
//! - [`intercept`]: the predicted crossing of the robot's hitting plane, with its covariance.
//! - [`stats`]: chi-square quantiles for gates and consistency checks.
//! - [`detection`]: one 3D ball detection, as the estimator takes it.
//! - [`config`]: every physical constant and tuning value, with defaults and range checks.
//! - [`sim`]: simulated camera detections of real and random shots, with the truth, from a seed.
//! - `msgs` (feature `interface`): serde mirrors of the ROS 2 interfaces in `msgs/` (package
//!   `ttball_msgs`) for ros2-client and MCAP, in wire (field) order.
//!
//! Units are SI everywhere (m, s, kg, rad/s) in the `table` frame described in the README.

pub mod config;
pub mod detection;
pub mod ekf;
pub mod estimator;
pub mod eval;
pub mod intercept;
#[cfg(feature = "interface")]
pub mod msgs;
pub mod physics;
pub mod real;
pub mod sim;
pub mod stats;
