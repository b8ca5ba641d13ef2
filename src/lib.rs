//! ttball: a real-time table-tennis ball-state estimator for robots.
//!
//! The crate is a pure core (no I/O, no clock, no ROS or MCAP types) and thin adapters around it:
//! - [`physics`]: flight (spin-parameter aerodynamic model), table bounce, event-aware propagation.
//! - [`detection`]: one 3D ball detection, as the estimator takes it.
//! - [`config`]: every physical constant and tuning value, with defaults and range checks.
//! - [`sim`]: simulated camera detections of real and random shots, with the truth, from a seed.
//! - `msgs` (feature `interface`): serde mirrors of the ROS 2 interfaces in `msgs/` (package
//!   `ttball_msgs`) for ros2-client and MCAP, in wire (field) order.
//!
//! Units are SI everywhere (m, s, kg, rad/s) in the `table` frame described in the README.

pub mod config;
pub mod detection;
#[cfg(feature = "interface")]
pub mod msgs;
pub mod physics;
pub mod sim;
