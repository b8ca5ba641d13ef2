//! Tests of the offline layer and of the real data: the batch fit, smoothing, the flight and
//! rubber calibrations, and the estimator on the real launcher flights.

#[cfg(feature = "cli")]
#[path = "../common/mod.rs"]
mod common;

mod batch;
mod calibrate;
mod real_flights;
mod rubber_calibration;
mod smooth;
