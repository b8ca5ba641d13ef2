//! The offline layer: whole recordings fitted at once, on top of the online layer's models, each
//! by Levenberg-Marquardt ([`crate::model::least_squares`]).
//!
//! - [`ballistic`]: short ballistic fits of recorded positions: the measured bounce and smoothed
//!   positions.
//! - [`batch`]: the batch (maximum a posteriori, robust) fit of one whole flight.
//! - [`smooth`]: a recording cut into flights by the estimator's tracks, each fitted whole: the
//!   smoothed state at every detection.
//! - [`calibrate`]: the aero and bounce coefficients fitted to many recorded flights at once.
//! - [`two_level`]: the ball's and table's parameters calibrated with the estimator's own model
//!   of many flights (each flight smoothed, its own parameters about the shared ones).
//! - [`rebound_calibration`]: the racket's rubber constants fitted to recorded hits, with
//!   standard errors and k-fold cross-validation.

pub mod ballistic;
pub mod batch;
pub mod calibrate;
pub mod rebound_calibration;
pub mod smooth;
pub mod two_level;
