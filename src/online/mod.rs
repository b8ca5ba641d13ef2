//! The online layer: everything the node runs per detection, and nothing else.
//!
//! - [`estimator`]: the one entry point, `Estimator::handle(detection)`: tracking, out-of-order
//!   fusion, gating, initialisation, the learned physics and noise, interception after every
//!   update.
//! - [`ekf`]: the extended Kalman filter over (position, velocity, spin) and the physical
//!   parameters it adapts.
//! - [`bounce_spread`]: a table bounce's outcome spread over the state's uncertainty beyond
//!   its linearisation (the unscented transform), for the filter and the interception.
//! - [`contact_side`]: the published covariance near a table contact, widened by the chance that
//!   the ball is on the other side of it.
//! - `initial_fit`: a track's first state, fitted to its first detections.
//! - [`measurement`]: a detection as a measurement with its noise, shared by the filter and the
//!   batch fit.
//! - [`learned`]: what an estimator learned, in words and as a configuration file to start the
//!   next one from.
//! - [`intercept`]: the predicted crossing of the robot's hitting plane, with its covariance.
//! - [`stroke`]: the robot's hit: the ball's rebound off the racket and its return flight, and
//!   the racket command (velocity, face normal) that returns the ball to a target.

pub mod bounce_spread;
pub mod contact_side;
pub mod ekf;
pub mod estimator;
pub(crate) mod initial_fit;
pub mod intercept;
pub mod learned;
pub mod measurement;
pub mod stroke;
