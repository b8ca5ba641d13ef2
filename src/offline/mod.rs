//! The offline layer: whole recordings fitted at once, on top of the online layer's models, each
//! by Levenberg-Marquardt ([`crate::model::least_squares`]).
//!
//! - [`ballistic`]: short ballistic fits of recorded positions: the measured bounce and smoothed
//!   positions.
//! - [`batch`]: the batch (maximum a posteriori, robust) fit of one whole flight.
//! - [`smooth`]: a recording cut into flights by the estimator's tracks, each fitted whole: the
//!   smoothed state at every detection.
//! - [`calibrate`]: the aero and bounce coefficients fitted to many recorded flights at once.
//! - [`rebound_calibration`]: the racket's rubber constants fitted to recorded hits, with
//!   standard errors and k-fold cross-validation.

pub mod ballistic;
pub mod batch;
pub mod calibrate;
pub mod rebound_calibration;
pub mod smooth;
