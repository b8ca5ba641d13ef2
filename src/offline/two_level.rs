//! The ball's and table's parameters and the Reynolds exponents calibrated with the estimator's
//! own model of many flights (`ttball calibrate --method estimator`): the two-level model of
//! [`crate::online::estimator`] (each flight its own drag and Magnus scales and restitution
//! about the shared ones, theta_f = h(theta_g) + d, d ~ N(0, D), its scales the ball's at its
//! speeds), each flight smoothed with the filter's process noise, solved for the shared theta_g
//! at once instead of flight after flight.
//!
//! 1. The noise: one estimator runs through every flight in order, as a replay would, and what
//!    it learned of the cameras' noise and of how far the flights stray from the model is folded
//!    into the configuration ([`LearnedSummary::configuration`]); so is its theta_g, the first
//!    linearisation point.
//! 2. Each iteration: every flight alone through an estimator started at the current theta_g
//!    with the configured prior P_pr (no drift), its track ended ([`Estimator::end_of_input`]),
//!    so that its flight is smoothed (`adaptation.smoothed_lessons`). Its posterior N(theta',
//!    P') over the prior N(theta_g, P_pr) is the flight's likelihood of theta_g in information
//!    form: J = P'^-1 - P_pr^-1, b = P'^-1 theta' - P_pr^-1 theta_g (the dispersion D included,
//!    [`crate::online::estimator`]'s `Learned::absorbed`). With the configured prior N(theta_0,
//!    P_0): theta_g <- (P_0^-1 + sum J)^-1 (P_0^-1 theta_0 + sum b), a Gauss-Newton step of the
//!    joint maximum a posteriori theta_g, each flight relinearised at the new theta_g.
//! 3. Until theta_g moves by less than [`CONVERGED`] of its prior sigma (at most
//!    [`MAX_ITERATIONS`]); its covariance is (P_0^-1 + sum J)^-1. A flight's smoothed lesson
//!    is taken or not (its pass bounces when the filter's does) depending on theta_g, so the
//!    steps can cycle: a step no shorter than the last halves the steps from then on.
//!
//! Each flight starts from the flights' joint estimate with its covariance (its diagonal, no
//! wider than the configured prior), as a flight late in a session starts where the earlier
//! ones left it, so that its filter linearises near there.
//!
//! An exponent the flights do not determine stays at its prior, the other parameters
//! conditioned on it, as online. Parameters with a zero prior sigma (or not asked for) keep
//! their configured values. Unlike
//! [`super::calibrate`] (one deterministic trajectory per flight and nothing else), the flights
//! here stray from the model as the estimator allows them to: on real flights the two differ, and
//! this one gives the estimator's numbers.

use nalgebra::{Cholesky, DMatrix, DVector};

use crate::config::Config;
use crate::model::detection::Detection;
use crate::online::estimator::{
    Estimator, Learned, LearnedParams, LearnedPhysics, LearnedSummary, SHAPE, ShapeCovariance,
    ShapeVector, configured_shape, shape_prior_variances,
};
use crate::physics::params::{PARAMS, ParamVector, PhysicsParams};

/// Converged when theta_g moves by less than this fraction of each parameter's prior sigma.
pub const CONVERGED: f64 = 5e-3;
/// The smallest prior sigma a flight starts from (the flights' joint estimate can be surer).
const MIN_SIGMA: f64 = 1e-4;
/// The most iterations.
pub const MAX_ITERATIONS: usize = 30;

/// What the calibration found.
#[derive(Debug, Clone)]
pub struct TwoLevelCalibration {
    /// The configuration with the calibrated parameters (and the learned noise) in place.
    pub config: Config,
    /// The calibrated parameters with their standard errors; `tracks` counts the flights.
    pub params: LearnedParams,
    /// What the first pass, flight after flight, learned (the online estimator's numbers).
    pub online: LearnedSummary,
    /// Iterations run.
    pub iterations: usize,
    /// Whether theta_g settled within [`CONVERGED`].
    pub converged: bool,
    /// theta_g's ball and table parameters after each iteration.
    pub history: Vec<PhysicsParams>,
}

/// Why it could not calibrate.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum TwoLevelError {
    /// No flight had detections.
    #[error("no flight to calibrate from")]
    NoFlights,
    /// No parameter is adapted (every prior sigma zero, or the adaptation off).
    #[error(
        "no parameter to calibrate: every adaptation.*_sigma is zero or adaptation.enabled is false"
    )]
    NothingToFit,
    /// The information matrix was not positive definite.
    #[error("the flights' information on the parameters is singular at iteration {0}")]
    Singular(usize),
}

/// Calibrates theta_g from `flights` (each one flight's detections, in stamp order) with the
/// estimator's model, starting from `config` (see the module doc). `progress` is told each
/// iteration.
pub fn calibrate_two_level(
    config: &Config,
    flights: &[Vec<Detection>],
    progress: &mut dyn FnMut(&str),
) -> Result<TwoLevelCalibration, TwoLevelError> {
    if flights.iter().all(Vec::is_empty) {
        return Err(TwoLevelError::NoFlights);
    }
    let prior_var = shape_prior_variances(config);
    let active: Vec<usize> = (0..SHAPE).filter(|&i| prior_var[i] > 0.0).collect();
    if active.is_empty() {
        return Err(TwoLevelError::NothingToFit);
    }
    let theta_0 = configured_shape(config);

    // 1. Flight after flight, as the node would: the noise, and the first theta_g.
    let mut sequential = Estimator::new(config);
    for d in flights.iter().flatten() {
        sequential.handle(d);
    }
    sequential.end_of_input();
    let online = sequential.learned_summary();
    let mut base = online.configuration(config);
    base.adaptation.drift_per_hour = 0.0;
    let (mut theta_g, online_covariance) = sequential.learned_shape();
    let mut sigma_g = online_covariance.diagonal().map(|v| v.max(0.0).sqrt());
    progress(&format!(
        "flight after flight (the online estimator): {}",
        describe(&theta_g)
    ));

    // 2. The joint optimum.
    let n = active.len();
    let sub = |v: &ShapeVector| DVector::from_iterator(n, active.iter().map(|&i| v[i]));
    let prior_information = DMatrix::from_diagonal(&sub(&prior_var).map(|v| 1.0 / v));
    let mut joint_covariance = DMatrix::zeros(n, n);
    let mut history = Vec::new();
    let mut converged = false;
    let mut iterations = 0;
    let (mut damping, mut last_step) = (1.0, f64::INFINITY);
    while iterations < MAX_ITERATIONS && !converged {
        iterations += 1;
        // Each flight starts where the flights' joint estimate is, as a flight late in a
        // session starts where the earlier ones left it: its filter linearises near there.
        let sigma = |i: usize| {
            if prior_var[i] > 0.0 {
                sigma_g[i].clamp(MIN_SIGMA, prior_var[i].sqrt())
            } else {
                0.0
            }
        };
        let mut at = with_shape(&base, &theta_g);
        at.adaptation.sigma = (0..PARAMS).map(sigma).collect();
        at.adaptation.reynolds_sigma = (PARAMS..SHAPE).map(sigma).collect();
        let (flights_information, flights_weighted) =
            flights_information(&at, flights, &active, &theta_g, iterations)?;
        let information = &prior_information + flights_information;
        let weighted = &prior_information * sub(&theta_0) + flights_weighted;
        let Some(joint) = Cholesky::new(information) else {
            return Err(TwoLevelError::Singular(iterations));
        };
        let solved = joint.solve(&weighted);
        // The joint covariance: the next flights' prior sigmas, and the standard errors.
        joint_covariance = joint.inverse();
        for (k, &i) in active.iter().enumerate() {
            sigma_g[i] = joint_covariance[(k, k)].max(0.0).sqrt();
        }
        // The step in prior sigmas; a step that does not shrink halves the next ones (a
        // flight's smoothed lesson taken or not flips with theta_g: a two-cycle, damped).
        let step = active
            .iter()
            .enumerate()
            .map(|(k, &i)| ((solved[k] - theta_g[i]) / prior_var[i].sqrt()).abs())
            .fold(0.0, f64::max);
        if step >= last_step {
            damping *= 0.5;
        }
        last_step = step;
        for (k, &i) in active.iter().enumerate() {
            theta_g[i] += damping * (solved[k] - theta_g[i]);
        }
        converged = damping * step < CONVERGED;
        history.push(PhysicsParams::from_vector(&params_of(&theta_g)));
        progress(&format!("  iteration {iterations}: {}", describe(&theta_g)));
    }
    // As online: an exponent the flights do not determine stays at its prior.
    let mut covariance = ShapeCovariance::zeros();
    for (r, &i) in active.iter().enumerate() {
        for (c, &j) in active.iter().enumerate() {
            covariance[(i, j)] = joint_covariance[(r, c)];
        }
    }
    let learned = LearnedPhysics {
        params: Learned::prior_of(config).with_estimate(theta_g, covariance),
    };
    let params = LearnedParams {
        tracks: flights.iter().filter(|f| !f.is_empty()).count() as u64,
        flight_sigma: online.params.flight_sigma,
        ..learned.params()
    };
    params.apply_to(&mut base);
    base.adaptation.drift_per_hour = config.adaptation.drift_per_hour;
    Ok(TwoLevelCalibration {
        params,
        config: base,
        online,
        iterations,
        converged,
        history,
    })
}

/// The ball's and table's parameters of the learned ones.
fn params_of(theta: &ShapeVector) -> ParamVector {
    theta.fixed_rows::<PARAMS>(0).into_owned()
}

/// `config` with the learned parameters `theta` (the ball's and table's, the exponents).
fn with_shape(config: &Config, theta: &ShapeVector) -> Config {
    let mut c = config.clone();
    PhysicsParams::from_vector(&params_of(theta)).apply_to(&mut c);
    c.aero.reynolds_exponents = vec![theta[PARAMS], theta[PARAMS + 1]];
    c
}

/// The flights' information on theta_g in sum, each flight alone through an estimator of `at`
/// (the parameters `active`): J = P'^-1 - P_pr^-1 and b = P'^-1 theta' - P_pr^-1 theta_g.
fn flights_information(
    at: &Config,
    flights: &[Vec<Detection>],
    active: &[usize],
    theta_g: &ShapeVector,
    iteration: usize,
) -> Result<(DMatrix<f64>, DVector<f64>), TwoLevelError> {
    let n = active.len();
    let sub = |v: &ShapeVector| DVector::from_iterator(n, active.iter().map(|&i| v[i]));
    let flight_prior = sub(&shape_prior_variances(at));
    let flight_prior_information = DMatrix::from_diagonal(&flight_prior.map(|v| 1.0 / v));
    let mut information = DMatrix::zeros(n, n);
    let mut weighted = DVector::zeros(n);
    for flight in flights.iter().filter(|f| !f.is_empty()) {
        let mut estimator = Estimator::new(at);
        for d in flight {
            estimator.handle(d);
        }
        estimator.end_of_input();
        let (theta, covariance) = estimator.learned_shape();
        let covariance = DMatrix::from_fn(n, n, |r, c| covariance[(active[r], active[c])]);
        let Some(posterior) = Cholesky::new(covariance) else {
            return Err(TwoLevelError::Singular(iteration));
        };
        let posterior_information = posterior.inverse();
        information += &posterior_information - &flight_prior_information;
        weighted += &posterior_information * sub(&theta) - &flight_prior_information * sub(theta_g);
    }
    Ok((information, weighted))
}

/// The learned parameters in a line.
fn describe(theta: &ShapeVector) -> String {
    let p = PhysicsParams::from_vector(&params_of(theta));
    format!(
        "drag_scale {:.4}, magnus_scale {:.4}, restitution {:.4}, friction {:.4}, a_D {:.3}, a_M {:.3}",
        p.drag_scale,
        p.magnus_scale,
        p.restitution,
        p.friction,
        theta[PARAMS],
        theta[PARAMS + 1]
    )
}
