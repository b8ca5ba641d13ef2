//! Calibration from recorded flights (Isomura et al. 2014 eq. 4-9; docs/models.md "Identification from recorded
//! flights"): the coefficients of C_D(Sp) and C_M(Sp), the table's restitution and friction and,
//! optionally, the air density that best explain many flights together, each flight's state at
//! its first detection (position, velocity, spin) a nuisance parameter (eq. 9). Measured spins
//! (the 900 fps camera) enter as observations of that state, which is eq. (8).
//!
//! The cost is the batch fit's ([`crate::offline::batch`]) summed over the flights: whitened residuals of
//! every detection under Huber's loss, a weak prior on each flight's spin
//! ([`CALIBRATION_SPIN_PRIOR`], which only bounds the spin along the velocity that no flight
//! shows), minimised by Levenberg-Marquardt over (theta, x_1 .. x_n). The Jacobian of a
//! detection with respect to its flight's state is the state-transition matrix; with respect to
//! theta it is a central difference through the whole flight. The normal equations have an arrow
//! shape and are solved by the Schur complement on theta (each flight's 9 x 9 block eliminated),
//! so the work grows linearly with the flights. Standard errors are the square roots of the
//! diagonal of the inverse reduced normal matrix times the reduced chi-square.
//!
//! The polynomial orders are fixed by the user or chosen by Akaike's criterion,
//! `AIC = N ln(sigma_e) + 2k` (N detections, sigma_e the root of the robust cost per measured
//! dimension, k aero coefficients): C_D's order with C_M at the configured one, then C_M's with
//! that C_D, each started from the configured orders' solution. Air density and the aero
//! coefficients scale the same forces, so they are not fitted together.

use nalgebra::{DMatrix, DVector, SMatrix, SVector};
use thiserror::Error;

use crate::config::Config;
use crate::model::detection::Detection;
use crate::model::least_squares::Damping;
use crate::model::stats::ErrorStats;
use crate::offline::batch::{
    Linearised, Observations, Residual, fit_from_guess, residuals, spin_prior_cost,
};
use crate::physics::FlightModel;
use crate::physics::aero::Polynomial;
use crate::physics::propagate::{Cursor, Propagator, Watch};
use crate::physics::state::{BallState, StateMatrix, StateVector};

/// Standard deviation of the prior on each flight's spin during calibration [rad/s]: weak
/// enough not to pull real spins (up to about 600 rad/s) toward zero, strong enough to bound the
/// spin along the velocity, which neither the flight nor (mostly) the bounce shows.
pub const CALIBRATION_SPIN_PRIOR: f64 = 1000.0;
/// Flights with fewer usable detections are left out.
pub const MIN_FLIGHT_DETECTIONS: usize = 10;
/// Highest polynomial order of C_D tried or accepted.
pub const MAX_DRAG_ORDER: usize = 3;
/// Highest polynomial order of C_M tried or accepted.
pub const MAX_MAGNUS_ORDER: usize = 4;
/// Most parameters fitted at once (besides the flights' states).
const MAX_PARAMETERS: usize = MAX_DRAG_ORDER + MAX_MAGNUS_ORDER + 2 + 2;
// The scales (2) replace the coefficients, so they fit in the same room.
/// Largest number of Levenberg-Marquardt iterations of one fit.
const MAX_ITERATIONS: usize = 100;
/// Relative cost change at which a fit has converged.
const COST_TOLERANCE: f64 = 1e-8;
/// A fit of the order search, scored.
struct Candidate {
    trial: OrderTrial,
    solution: Solution,
    flights: Vec<Flight>,
}

impl Candidate {
    /// Scores a fit at `orders` by AIC = N ln(sigma_e) + 2k, sigma_e the root of the robust
    /// cost per measured dimension.
    fn new(orders: (usize, usize), solution: Solution, flights: Vec<Flight>) -> Self {
        let cost = &solution.cost;
        let sigma_e = (cost.cost / cost.dims.max(1) as f64).sqrt();
        let k = (orders.0 + 1 + orders.1 + 1) as f64;
        Self {
            trial: OrderTrial {
                drag_order: orders.0,
                magnus_order: orders.1,
                aic: cost.positions as f64 * sigma_e.ln() + 2.0 * k,
                sigma_e,
                position_rms: cost.position_rms(),
            },
            solution,
            flights,
        }
    }

    fn orders(&self) -> (usize, usize) {
        (self.trial.drag_order, self.trial.magnus_order)
    }
}

/// Table frictions the fit is restarted from (see [`calibrate`]).
const FRICTION_STARTS: [f64; 5] = [0.1, 0.2, 0.3, 0.4, 0.6];
/// The default polynomials are refitted at another order over Sp in [0, this].
const REFIT_SPIN_PARAMETER: f64 = 1.5;

/// One fitted constant of the configuration.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub enum Parameter {
    /// Coefficient of Sp^k of C_D.
    Drag(usize),
    /// Coefficient of Sp^k of C_M.
    Magnus(usize),
    /// The scale factor k_D on the drag of the configured C_D(Sp).
    DragScale,
    /// The scale factor k_M on the Magnus force of the configured C_M(Sp).
    MagnusScale,
    /// Table restitution e_t.
    Restitution,
    /// Table friction mu_t.
    Friction,
    /// Air density [kg/m^3].
    AirDensity,
    /// The exponent a_D of the Reynolds number's factor on C_D.
    DragReynolds,
    /// The exponent a_M of the Reynolds number's factor on C_M.
    MagnusReynolds,
    /// The spin's decay rate in flight lambda [1/s].
    SpinDecay,
}

impl Parameter {
    /// The configuration key (with the index of a coefficient).
    pub fn name(&self) -> String {
        match self {
            Self::Drag(k) => format!("aero.drag_coefficients[{k}]"),
            Self::Magnus(k) => format!("aero.magnus_coefficients[{k}]"),
            Self::DragScale => "aero.drag_scale".to_owned(),
            Self::MagnusScale => "aero.magnus_scale".to_owned(),
            Self::Restitution => "table.restitution".to_owned(),
            Self::Friction => "table.friction".to_owned(),
            Self::AirDensity => "air.density".to_owned(),
            Self::DragReynolds => "aero.reynolds_exponents[0]".to_owned(),
            Self::MagnusReynolds => "aero.reynolds_exponents[1]".to_owned(),
            Self::SpinDecay => "aero.spin_decay_rate".to_owned(),
        }
    }

    /// Its value in `config` (0 for a coefficient beyond the polynomial's length).
    pub fn value(&self, config: &Config) -> f64 {
        let element = |list: &[f64], k: usize| list.get(k).copied().unwrap_or(0.0);
        let aero = &config.aero;
        match self {
            Self::Drag(k) => element(&aero.drag_coefficients, *k),
            Self::Magnus(k) => element(&aero.magnus_coefficients, *k),
            Self::DragScale => aero.drag_scale,
            Self::MagnusScale => aero.magnus_scale,
            Self::Restitution => config.table.restitution,
            Self::Friction => config.table.friction,
            Self::AirDensity => config.air.density,
            Self::DragReynolds => element(&aero.reynolds_exponents, 0),
            Self::MagnusReynolds => element(&aero.reynolds_exponents, 1),
            Self::SpinDecay => aero.spin_decay_rate,
        }
    }

    fn set(&self, config: &mut Config, value: f64) {
        let coefficient = |list: &mut Vec<f64>, k: usize| {
            if list.len() <= k {
                list.resize(k + 1, 0.0);
            }
            list[k] = value;
        };
        match self {
            Self::Drag(k) => coefficient(&mut config.aero.drag_coefficients, *k),
            Self::Magnus(k) => coefficient(&mut config.aero.magnus_coefficients, *k),
            Self::DragScale => config.aero.drag_scale = value,
            Self::MagnusScale => config.aero.magnus_scale = value,
            Self::Restitution => config.table.restitution = value,
            Self::Friction => config.table.friction = value,
            Self::AirDensity => config.air.density = value,
            Self::DragReynolds => coefficient(&mut config.aero.reynolds_exponents, 0),
            Self::MagnusReynolds => coefficient(&mut config.aero.reynolds_exponents, 1),
            Self::SpinDecay => config.aero.spin_decay_rate = value,
        }
    }

    /// The central-difference step at `value`.
    fn step(&self, value: f64) -> f64 {
        1e-5 * value.abs().max(0.1)
    }

    /// True when `value` is at the edge of the values the physics is defined at: a fit that
    /// ends there was stopped by the bound, not determined by the data.
    pub fn at_bound(&self, value: f64) -> bool {
        let h = 10.0 * self.step(value);
        !self.admits(value + h) || !self.admits(value - h)
    }

    /// True when the physics is defined at `value`.
    fn admits(&self, value: f64) -> bool {
        value.is_finite()
            && match self {
                Self::Drag(_) | Self::Magnus(_) => true,
                Self::DragScale | Self::MagnusScale => value > 0.0 && value <= 5.0,
                Self::Restitution => value > 0.0 && value < 1.0,
                Self::Friction => (0.0..2.0).contains(&value),
                Self::AirDensity => value > 0.0,
                Self::DragReynolds | Self::MagnusReynolds => (-3.0..=3.0).contains(&value),
                Self::SpinDecay => (0.0..=20.0).contains(&value),
            }
    }
}

/// What to fit.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Options {
    /// The C_D and C_M coefficients.
    pub aero: bool,
    /// The scale factors k_D and k_M on the configured C_D(Sp) and C_M(Sp): the parameters the
    /// estimator learns online (not with `aero`).
    pub scales: bool,
    /// Table restitution and friction.
    pub bounce: bool,
    /// Air density (not with `aero`).
    pub density: bool,
    /// The exponents of the Reynolds number's factors on C_D and C_M.
    pub reynolds: bool,
    /// The spin's decay rate in flight.
    pub decay: bool,
    /// Order of C_D; `None` chooses it by AIC.
    pub drag_order: Option<usize>,
    /// Order of C_M; `None` chooses it by AIC.
    pub magnus_order: Option<usize>,
}

/// Where a flight came from: its recording and the estimator's track.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub struct FlightLabel {
    /// Index of the recording (bag) among those given.
    pub recording: usize,
    /// The estimator's track id in it.
    pub track_id: u32,
}

/// The detections of one flight.
#[derive(Debug, Clone, PartialEq)]
pub struct FlightInput {
    /// Where it came from.
    pub label: FlightLabel,
    /// Its detections (any order).
    pub detections: Vec<Detection>,
}

/// A fitted parameter.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct FittedParameter {
    /// Which.
    pub parameter: Parameter,
    /// Its configuration key.
    pub name: String,
    /// The fitted value.
    pub value: f64,
    /// The value of the configuration calibration started from.
    pub initial: f64,
    /// Its standard error.
    pub std_error: f64,
}

/// How well one flight is explained, before and after calibration.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct FlightResidual {
    /// The flight.
    pub label: FlightLabel,
    /// Usable detections.
    pub detections: usize,
    /// Of them measuring spin.
    pub measured_spins: usize,
    /// RMS position residual per axis with the starting configuration [m].
    pub position_rms_before: f64,
    /// The same with the calibrated one [m].
    pub position_rms: f64,
    /// Detections beyond the Huber threshold after calibration.
    pub outliers: usize,
}

/// One fit of the order search.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct OrderTrial {
    /// Order of C_D.
    pub drag_order: usize,
    /// Order of C_M.
    pub magnus_order: usize,
    /// Akaike's criterion, N ln(sigma_e) + 2k.
    pub aic: f64,
    /// sigma_e: the root of the robust cost per measured dimension [-] (the seed's RMS position
    /// error, whitened, when every detection has the same noise and none is an outlier).
    pub sigma_e: f64,
    /// The RMS position residual per axis [m].
    pub position_rms: f64,
}

/// A flight left out, and why.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct SkippedFlight {
    /// The flight.
    pub label: FlightLabel,
    /// Why.
    pub reason: String,
}

/// The result of a calibration.
#[derive(Debug, Clone, PartialEq)]
pub struct Calibration {
    /// The starting configuration with the fitted values.
    pub config: Config,
    /// The fitted values with their standard errors.
    pub parameters: Vec<FittedParameter>,
    /// Their covariance (the order of `parameters`).
    pub covariance: DMatrix<f64>,
    /// The orders of C_D and C_M (those of the configuration when aero is not fitted).
    pub orders: (usize, usize),
    /// The fits of the order search (empty when the orders were given).
    pub order_trials: Vec<OrderTrial>,
    /// Every flight fitted.
    pub flights: Vec<FlightResidual>,
    /// Flights left out.
    pub skipped: Vec<SkippedFlight>,
    /// RMS position residual per axis over all flights, starting configuration [m].
    pub position_rms_before: f64,
    /// The same, calibrated [m].
    pub position_rms: f64,
    /// Reduced chi-square of the calibrated fit (about 1 when the noise model is right).
    pub reduced_chi_square: f64,
    /// 5th, 50th and 95th percentiles of the spin parameter Sp over the fitted detections: the
    /// range where the fitted C_D(Sp) and C_M(Sp) are supported by data.
    pub spin_parameter: [f64; 3],
    /// Levenberg-Marquardt iterations over all fits.
    pub iterations: usize,
}

/// Why a calibration cannot be made.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum CalibrationError {
    /// Nothing selected.
    #[error("nothing to fit: choose aero or scales, bounce and/or density")]
    NothingToFit,
    /// Density and aero (or the scales) together.
    #[error(
        "air density and the aero coefficients scale the same forces (rho C_D, rho C_M) and cannot be fitted together; fit aero or scales (they absorb the density) or density alone"
    )]
    DensityWithAero,
    /// The scales and the coefficients together.
    #[error(
        "the scale factors and the polynomial coefficients move the same forces and cannot be fitted together; fit aero (the curves) or scales (the curves kept, scaled)"
    )]
    ScalesWithAero,
    /// An order beyond the supported ones.
    #[error("polynomial order {order} of {which} is above the highest supported, {max}")]
    OrderTooHigh {
        /// "C_D" or "C_M".
        which: &'static str,
        /// Asked for.
        order: usize,
        /// Highest.
        max: usize,
    },
    /// Too few usable flights.
    #[error(
        "calibration needs at least {needed} flights with {MIN_FLIGHT_DETECTIONS} or more usable detections, found {found}"
    )]
    TooFewFlights {
        /// Needed.
        needed: usize,
        /// Found.
        found: usize,
    },
    /// The data do not determine the parameters.
    #[error(
        "the flights do not determine the parameters (singular normal equations); fit fewer (e.g. lower orders) or add flights with other speeds and spins"
    )]
    Singular,
}

/// One flight being calibrated.
#[derive(Clone)]
struct Flight {
    label: FlightLabel,
    observations: Observations,
    state: StateVector,
}

/// A flight's share of the normal equations: its own block, its coupling to theta and theta's.
struct Blocks {
    v: StateMatrix,
    g: StateVector,
    w: SMatrix<f64, MAX_PARAMETERS, 9>,
    u: SMatrix<f64, MAX_PARAMETERS, MAX_PARAMETERS>,
    gt: SVector<f64, MAX_PARAMETERS>,
}

/// The cost of one flight (or of several, summed) and its residuals' sums.
#[derive(Debug, Clone, Copy, Default)]
struct FlightCost {
    cost: f64,
    squares: f64,
    dims: usize,
    miss_squares: f64,
    positions: usize,
    outliers: usize,
}

impl FlightCost {
    /// The RMS position residual per axis [m].
    fn position_rms(&self) -> f64 {
        (self.miss_squares / (3.0 * self.positions.max(1) as f64)).sqrt()
    }
}

impl std::iter::Sum for FlightCost {
    fn sum<I: Iterator<Item = Self>>(costs: I) -> Self {
        costs.fold(Self::default(), |a, c| Self {
            cost: a.cost + c.cost,
            squares: a.squares + c.squares,
            dims: a.dims + c.dims,
            miss_squares: a.miss_squares + c.miss_squares,
            positions: a.positions + c.positions,
            outliers: a.outliers + c.outliers,
        })
    }
}

/// The parameters being fitted and the configuration around them.
struct Model<'a> {
    base: &'a Config,
    parameters: Vec<Parameter>,
    /// Huber's loss (else least squares).
    robust: bool,
}

impl Model<'_> {
    /// The base configuration with `theta`; a fitted polynomial has exactly the fitted
    /// coefficients (none of the base's higher ones; [`parameters`] fits orders 0 to n).
    fn config(&self, theta: &[f64]) -> Config {
        let mut c = self.base.clone();
        let count = |of: fn(&Parameter) -> bool| self.parameters.iter().filter(|p| of(p)).count();
        let drag = count(|p| matches!(p, Parameter::Drag(_)));
        let magnus = count(|p| matches!(p, Parameter::Magnus(_)));
        if drag > 0 {
            c.aero.drag_coefficients.resize(drag, 0.0);
        }
        if magnus > 0 {
            c.aero.magnus_coefficients.resize(magnus, 0.0);
        }
        for (p, v) in self.parameters.iter().zip(theta) {
            p.set(&mut c, *v);
        }
        c
    }

    fn admits(&self, theta: &[f64]) -> bool {
        self.parameters.iter().zip(theta).all(|(p, v)| p.admits(*v))
    }
}

/// Calibrates `options`' parameters of `config` from `flights`; `progress` gets a line now and
/// then.
pub fn calibrate(
    config: &Config,
    flights: &[FlightInput],
    options: &Options,
    progress: &mut dyn FnMut(&str),
) -> Result<Calibration, CalibrationError> {
    let configured = check_options(config, options)?;
    let propagator = Propagator::new(config);
    let (prepared, skipped) = prepare_flights(config, &propagator, flights, progress)?;
    let before: Vec<FlightCost> = prepared
        .iter()
        .map(|f| flight_cost(&propagator, f, &f.state, true))
        .collect();

    // First at the configured orders (or the given ones), with the friction restarts: the
    // flights' states and the bounce constants are then in the right basin for every other
    // order tried, each started from these polynomials refitted to it.
    let first_orders = (
        options.drag_order.unwrap_or(configured.0),
        options.magnus_order.unwrap_or(configured.1),
    );
    if options.aero {
        progress(&format!(
            "C_D order {}, C_M order {}",
            first_orders.0, first_orders.1
        ));
    }
    let (solution, prepared) =
        fit_at_orders(config, config, options, first_orders, prepared, progress)?;
    let first = Candidate::new(first_orders, solution, prepared);
    let (chosen, order_trials, iterations) =
        if options.aero && (options.drag_order.is_none() || options.magnus_order.is_none()) {
            choose_orders(config, options, first, progress)?
        } else {
            let iterations = first.solution.iterations;
            (first, Vec::new(), iterations)
        };
    Ok(report(
        config,
        options,
        chosen,
        &before,
        skipped,
        order_trials,
        iterations,
    ))
}

/// The options' consistency, and the polynomial orders `config` has (capped at the largest
/// calibrated).
fn check_options(config: &Config, options: &Options) -> Result<(usize, usize), CalibrationError> {
    if !(options.aero
        || options.scales
        || options.bounce
        || options.density
        || options.reynolds
        || options.decay)
    {
        return Err(CalibrationError::NothingToFit);
    }
    if (options.aero || options.scales) && options.density {
        return Err(CalibrationError::DensityWithAero);
    }
    if options.aero && options.scales {
        return Err(CalibrationError::ScalesWithAero);
    }
    for (which, order, max) in [
        ("C_D", options.drag_order, MAX_DRAG_ORDER),
        ("C_M", options.magnus_order, MAX_MAGNUS_ORDER),
    ] {
        if let Some(order) = order.filter(|o| *o > max) {
            return Err(CalibrationError::OrderTooHigh { which, order, max });
        }
    }
    Ok((
        config
            .aero
            .drag_coefficients
            .len()
            .saturating_sub(1)
            .min(MAX_DRAG_ORDER),
        config
            .aero
            .magnus_coefficients
            .len()
            .saturating_sub(1)
            .min(MAX_MAGNUS_ORDER),
    ))
}

/// Each flight fitted alone with the starting physics: the nuisance states' first values. A
/// flight too short or whose fit fails is skipped with its reason; at least two must remain.
fn prepare_flights(
    config: &Config,
    propagator: &Propagator,
    flights: &[FlightInput],
    progress: &mut dyn FnMut(&str),
) -> Result<(Vec<Flight>, Vec<SkippedFlight>), CalibrationError> {
    let mut prepared = Vec::new();
    let mut skipped = Vec::new();
    progress(&format!(
        "fitting each of the {} flights alone",
        flights.len()
    ));
    for input in flights {
        let observations = Observations::new(config, &input.detections);
        if observations.list.len() < MIN_FLIGHT_DETECTIONS {
            skipped.push(SkippedFlight {
                label: input.label,
                reason: format!(
                    "{} usable detections, fewer than the {MIN_FLIGHT_DETECTIONS} calibration needs",
                    observations.list.len()
                ),
            });
            continue;
        }
        let fit = fit_from_guess(
            propagator,
            &observations,
            &input.detections,
            config.gravity,
            CALIBRATION_SPIN_PRIOR,
        );
        match fit {
            Ok(fit) => prepared.push(Flight {
                label: input.label,
                observations,
                state: fit.start.to_vector(),
            }),
            Err(e) => skipped.push(SkippedFlight {
                label: input.label,
                reason: e.to_string(),
            }),
        }
    }
    let needed = 2;
    if prepared.len() < needed {
        return Err(CalibrationError::TooFewFlights {
            needed,
            found: prepared.len(),
        });
    }
    Ok((prepared, skipped))
}

/// The polynomial orders by Akaike's criterion, from the fit at the first orders: C_D's order
/// with C_M's fixed, then C_M's with the best C_D (an order the options fix is not searched).
/// Returns the chosen fit, every order tried, and the iterations of all of them.
fn choose_orders(
    config: &Config,
    options: &Options,
    first: Candidate,
    progress: &mut dyn FnMut(&str),
) -> Result<(Candidate, Vec<OrderTrial>, usize), CalibrationError> {
    let first_orders = first.orders();
    let mut iterations = first.solution.iterations;
    let start = Model {
        base: config,
        parameters: parameters(options, first_orders),
        robust: true,
    }
    .config(&first.solution.theta);
    let mut candidates = vec![first];
    let mut try_orders = |orders: (usize, usize),
                          candidates: &mut Vec<Candidate>,
                          progress: &mut dyn FnMut(&str)|
     -> Result<(), CalibrationError> {
        if candidates.iter().any(|c| c.orders() == orders) {
            return Ok(());
        }
        progress(&format!("C_D order {}, C_M order {}", orders.0, orders.1));
        let flights = candidates[0].flights.clone();
        match fit_at_orders(config, &start, options, orders, flights, progress) {
            Ok((solution, flights)) => {
                iterations += solution.iterations;
                candidates.push(Candidate::new(orders, solution, flights));
                Ok(())
            }
            // Orders the data cannot determine are not candidates.
            Err(CalibrationError::Singular) => {
                progress("  the flights do not determine these orders; skipped");
                Ok(())
            }
            Err(e) => Err(e),
        }
    };
    let best = |candidates: &[Candidate]| {
        candidates
            .iter()
            .enumerate()
            .min_by(|a, b| a.1.trial.aic.total_cmp(&b.1.trial.aic))
            .map_or(0, |(i, _)| i)
    };
    if options.drag_order.is_none() {
        for d in 0..=MAX_DRAG_ORDER {
            try_orders((d, first_orders.1), &mut candidates, progress)?;
        }
    }
    let drag = candidates[best(&candidates)].trial.drag_order;
    if options.magnus_order.is_none() {
        for m in 0..=MAX_MAGNUS_ORDER {
            try_orders((drag, m), &mut candidates, progress)?;
        }
    }
    let order_trials = candidates.iter().map(|c| c.trial).collect();
    let chosen = candidates.swap_remove(best(&candidates));
    Ok((chosen, order_trials, iterations))
}

/// The calibration as reported: the fitted configuration, each constant with its standard
/// error, each flight's residuals before and after, and the spin parameters the flights span.
fn report(
    config: &Config,
    options: &Options,
    chosen: Candidate,
    before: &[FlightCost],
    skipped: Vec<SkippedFlight>,
    order_trials: Vec<OrderTrial>,
    iterations: usize,
) -> Calibration {
    let orders = chosen.orders();
    let (solution, prepared) = (chosen.solution, chosen.flights);
    let model = Model {
        base: config,
        parameters: parameters(options, orders),
        robust: true,
    };
    let fitted = model.config(&solution.theta);
    let fitted_propagator = Propagator::new(&fitted);
    let scale = solution.reduced_chi_square;
    let parameters_out = model
        .parameters
        .iter()
        .enumerate()
        .map(|(i, p)| FittedParameter {
            parameter: *p,
            name: p.name(),
            value: solution.theta[i],
            initial: p.value(config),
            std_error: (solution.covariance[(i, i)] * scale).max(0.0).sqrt(),
        })
        .collect();
    let mut flights_out = Vec::with_capacity(prepared.len());
    let mut spin_parameters = Vec::new();
    let model_flight = FlightModel::new(&fitted);
    for (f, b) in prepared.iter().zip(before) {
        let after = flight_cost(&fitted_propagator, f, &f.state, true);
        flights_out.push(FlightResidual {
            label: f.label,
            detections: f.observations.list.len(),
            measured_spins: f.observations.list.iter().filter(|o| o.dims == 6).count(),
            position_rms_before: b.position_rms(),
            position_rms: after.position_rms(),
            outliers: after.outliers,
        });
        let mut cursor = Cursor::new(0.0, &BallState::from_vector(&f.state));
        for o in &f.observations.list {
            let duration = o.t - cursor.t;
            fitted_propagator.advance(&mut cursor, duration, Watch::BOUNCES, &mut ());
            let ball = cursor.ball();
            spin_parameters.push(model_flight.spin_parameter(&ball.velocity, &ball.spin));
        }
    }
    spin_parameters.sort_by(f64::total_cmp);
    let quantile = |q: f64| {
        spin_parameters
            .get(((spin_parameters.len().saturating_sub(1)) as f64 * q).round() as usize)
            .copied()
            .unwrap_or(0.0)
    };
    Calibration {
        config: fitted,
        parameters: parameters_out,
        covariance: solution.covariance * scale,
        orders,
        order_trials,
        flights: flights_out,
        skipped,
        position_rms_before: before.iter().copied().sum::<FlightCost>().position_rms(),
        position_rms: solution.cost.position_rms(),
        reduced_chi_square: scale,
        spin_parameter: [quantile(0.05), quantile(0.5), quantile(0.95)],
        iterations,
    }
}

/// The fit at fixed polynomial orders: least squares from the `start` configuration's constants
/// (its polynomials refitted to `orders`; a robust loss from a poor start lets a flight give up
/// on its detections), then Huber's loss from there, then restarts over the friction (the cost
/// is only piecewise smooth in it: each bounce slides or rolls out, and a rolling bounce does
/// not depend on it), keeping the best. Returns the solution and the flights at it.
fn fit_at_orders(
    base: &Config,
    start: &Config,
    options: &Options,
    orders: (usize, usize),
    mut flights: Vec<Flight>,
    progress: &mut dyn FnMut(&str),
) -> Result<(Solution, Vec<Flight>), CalibrationError> {
    let mut model = Model {
        base,
        parameters: parameters(options, orders),
        robust: false,
    };
    let theta = start_values(start, &model.parameters, orders);
    let least_squares = solve(&model, theta, &mut flights, progress)?;
    model.robust = true;
    let mut solution = solve(&model, least_squares.theta.clone(), &mut flights, progress)?;
    let mut iterations = least_squares.iterations + solution.iterations;
    if let Some(index) = model
        .parameters
        .iter()
        .position(|p| *p == Parameter::Friction)
    {
        for mu in FRICTION_STARTS {
            progress(&format!("  restarting from friction {mu}"));
            let mut theta = solution.theta.clone();
            theta[index] = mu;
            let mut trial_flights = flights.clone();
            let trial = match solve(&model, theta, &mut trial_flights, progress) {
                Ok(trial) => trial,
                // A start where every bounce rolls out leaves the friction undetermined there:
                // that restart tells nothing, the solution stands.
                Err(CalibrationError::Singular) => {
                    progress("  the flights do not determine the friction from there; skipped");
                    continue;
                }
                Err(e) => return Err(e),
            };
            iterations += trial.iterations;
            if trial.cost.cost < solution.cost.cost {
                solution = trial;
                flights = trial_flights;
            }
        }
    }
    solution.iterations = iterations;
    Ok((solution, flights))
}

/// The parameters `options` fit at polynomial orders `orders`.
fn parameters(options: &Options, orders: (usize, usize)) -> Vec<Parameter> {
    let mut out = Vec::new();
    if options.aero {
        out.extend((0..=orders.0).map(Parameter::Drag));
        out.extend((0..=orders.1).map(Parameter::Magnus));
    }
    if options.scales {
        out.extend([Parameter::DragScale, Parameter::MagnusScale]);
    }
    if options.bounce {
        out.extend([Parameter::Restitution, Parameter::Friction]);
    }
    if options.density {
        out.push(Parameter::AirDensity);
    }
    if options.reynolds {
        out.extend([Parameter::DragReynolds, Parameter::MagnusReynolds]);
    }
    if options.decay {
        out.push(Parameter::SpinDecay);
    }
    out
}

/// Starting values: the configuration's, with each polynomial refitted by least squares over
/// Sp in [0, 1.5] when its order differs from the configured one.
fn start_values(config: &Config, parameters: &[Parameter], orders: (usize, usize)) -> Vec<f64> {
    let drag = refit(&config.aero.drag_coefficients, orders.0);
    let magnus = refit(&config.aero.magnus_coefficients, orders.1);
    parameters
        .iter()
        .map(|p| match p {
            Parameter::Drag(k) => drag.get(*k).copied().unwrap_or(0.0),
            Parameter::Magnus(k) => magnus.get(*k).copied().unwrap_or(0.0),
            other => other.value(config),
        })
        .collect()
}

/// The least-squares polynomial of `order` closest to `coefficients` over Sp in [0, 1.5].
fn refit(coefficients: &[f64], order: usize) -> Vec<f64> {
    if coefficients.len() == order + 1 {
        return coefficients.to_vec();
    }
    let samples = 31;
    let polynomial = Polynomial::new(coefficients);
    let sp = |i: usize| REFIT_SPIN_PARAMETER * i as f64 / (samples - 1) as f64;
    let a = DMatrix::from_fn(samples, order + 1, |i, k| sp(i).powi(k as i32));
    let b = DVector::from_fn(samples, |i, _| polynomial.value(sp(i)));
    let normal = a.transpose() * &a;
    match normal.cholesky() {
        Some(c) => c.solve(&(a.transpose() * b)).iter().copied().collect(),
        None => {
            let mut out = coefficients.to_vec();
            out.resize(order + 1, 0.0);
            out
        }
    }
}

/// The cost of one flight at its state `x` with `propagator`'s physics.
fn flight_cost(
    propagator: &Propagator,
    flight: &Flight,
    x: &StateVector,
    robust: bool,
) -> FlightCost {
    let mut scratch = Vec::with_capacity(flight.observations.list.len());
    residuals(
        propagator,
        &flight.observations.list,
        x,
        false,
        &mut scratch,
    );
    let mut out = FlightCost::default();
    for (o, r) in flight.observations.list.iter().zip(&scratch) {
        let length = r.value.norm();
        let (weight, cost) = o.loss(length, robust);
        out.cost += cost;
        out.squares += weight * length * length;
        out.dims += o.dims;
        out.miss_squares += r.miss.norm_squared();
        out.positions += 1;
        if weight < 1.0 {
            out.outliers += 1;
        }
    }
    out.cost += spin_prior_cost(x, CALIBRATION_SPIN_PRIOR);
    out
}

/// One flight's blocks at `x`: the nominal residuals with the transition matrix, theta's
/// columns by central differences (`perturbed`: the propagators at theta +- each step, `steps`
/// their sizes).
fn flight_blocks(
    nominal: &Propagator,
    perturbed: &[(Propagator, Propagator)],
    steps: &[f64],
    flight: &Flight,
    x: &StateVector,
    robust: bool,
) -> Blocks {
    let list = &flight.observations.list;
    let mut base: Vec<Residual> = Vec::with_capacity(list.len());
    residuals(nominal, list, x, true, &mut base);
    // Columns of -d r / d theta, per observation.
    let mut columns = vec![SMatrix::<f64, 6, MAX_PARAMETERS>::zeros(); list.len()];
    let (mut plus, mut minus) = (Vec::new(), Vec::new());
    for (j, ((p, m), h)) in perturbed.iter().zip(steps).enumerate() {
        residuals(p, list, x, false, &mut plus);
        residuals(m, list, x, false, &mut minus);
        for (column, (a, b)) in columns.iter_mut().zip(plus.iter().zip(&minus)) {
            column.set_column(j, &((b.value - a.value) / (2.0 * h)));
        }
    }
    // The flight's own block is the batch fit's normal equations.
    let own = Linearised::new(list, &base, robust, CALIBRATION_SPIN_PRIOR, x);
    let mut out = Blocks {
        v: own.normal,
        g: own.gradient,
        w: SMatrix::zeros(),
        u: SMatrix::zeros(),
        gt: SVector::zeros(),
    };
    for ((o, r), jt) in list.iter().zip(&base).zip(&columns) {
        let (weight, _) = o.loss(r.value.norm(), robust);
        out.w += jt.transpose() * r.jacobian * weight;
        out.u += jt.transpose() * jt * weight;
        out.gt += jt.transpose() * r.value * weight;
    }
    out
}

/// `f` over `items` on every core, in order.
fn parallel_map<T: Sync, R: Send>(items: &[T], f: impl Fn(&T) -> R + Sync) -> Vec<R> {
    let workers = std::thread::available_parallelism()
        .map_or(1, |n| n.get())
        .min(items.len())
        .max(1);
    let chunk = items.len().div_ceil(workers).max(1);
    std::thread::scope(|scope| {
        let handles: Vec<_> = items
            .chunks(chunk)
            .map(|part| scope.spawn(|| part.iter().map(&f).collect::<Vec<R>>()))
            .collect();
        handles
            .into_iter()
            .flat_map(|h| h.join().unwrap_or_else(|e| std::panic::resume_unwind(e)))
            .collect()
    })
}

/// A solved calibration at fixed orders.
struct Solution {
    theta: Vec<f64>,
    covariance: DMatrix<f64>,
    cost: FlightCost,
    reduced_chi_square: f64,
    iterations: usize,
}

/// Total cost of all flights at theta and their states.
fn total_cost(
    model: &Model,
    theta: &[f64],
    states: &[StateVector],
    flights: &[Flight],
) -> FlightCost {
    let propagator = Propagator::new(&model.config(theta));
    let indices: Vec<usize> = (0..flights.len()).collect();
    parallel_map(&indices, |&i| {
        flight_cost(&propagator, &flights[i], &states[i], model.robust)
    })
    .into_iter()
    .sum()
}

/// Levenberg-Marquardt over theta and the flights' states, the states eliminated by the Schur
/// complement; `flights`' states are updated in place.
fn solve(
    model: &Model,
    mut theta: Vec<f64>,
    flights: &mut [Flight],
    progress: &mut dyn FnMut(&str),
) -> Result<Solution, CalibrationError> {
    let p = model.parameters.len();
    let mut damping = Damping::new();
    let mut iterations = 0;
    let mut states: Vec<StateVector> = flights.iter().map(|f| f.state).collect();
    let mut current = total_cost(model, &theta, &states, flights);
    let mut reduced_normal = DMatrix::<f64>::zeros(p, p);
    for iteration in 1..=MAX_ITERATIONS {
        iterations = iteration;
        let normal = NormalEquations::at(model, &theta, flights, &states);
        reduced_normal = normal.reduced();
        let taken = damping.step(|lambda| {
            let (candidate, candidate_states) =
                normal.damped_step(model, &theta, &states, lambda)?;
            let next = total_cost(model, &candidate, &candidate_states, flights);
            (next.cost.is_finite() && next.cost <= current.cost).then_some((
                candidate,
                candidate_states,
                next,
            ))
        });
        let Some((candidate, candidate_states, next)) = taken else {
            break;
        };
        let change = (current.cost - next.cost) / current.cost.max(f64::MIN_POSITIVE);
        theta = candidate;
        states = candidate_states;
        current = next;
        progress(&format!(
            "  iteration {iteration}: cost {:.1}, RMS position residual {:.2} mm",
            current.cost,
            current.position_rms() * 1e3
        ));
        if change < COST_TOLERANCE {
            break;
        }
    }
    for (f, x) in flights.iter_mut().zip(&states) {
        f.state = *x;
    }
    // A parameter the flights say nothing of (the friction when every bounce rolls out) leaves
    // the normal matrix singular: a ridge a billionth of its scale lets the others' covariance
    // stand and gives that one a standard error that says so.
    let ridge = 1e-9 * reduced_normal.diagonal().amax().max(f64::MIN_POSITIVE);
    let covariance = reduced_normal
        .clone()
        .cholesky()
        .or_else(|| (reduced_normal + DMatrix::identity(p, p) * ridge).cholesky())
        .map(|c| c.inverse())
        .ok_or(CalibrationError::Singular)?;
    let dof = current.dims as f64 - p as f64 - 9.0 * flights.len() as f64;
    Ok(Solution {
        theta,
        covariance,
        cost: current,
        reduced_chi_square: current.squares / dof.max(1.0),
        iterations,
    })
}

/// The Gauss-Newton normal equations of all flights at (theta, states), in their arrow shape:
/// theta's block `u` and right-hand side `gt`, and each flight's blocks (its own 9 x 9 `v`, its
/// coupling `w` to theta, its right-hand side `g`).
struct NormalEquations {
    blocks: Vec<Blocks>,
    u: DMatrix<f64>,
    gt: DVector<f64>,
}

impl NormalEquations {
    /// Linearises every flight at `theta` and its state: Jacobians from the transition matrix
    /// for the states and central differences through the flights for the constants.
    fn at(model: &Model, theta: &[f64], flights: &[Flight], states: &[StateVector]) -> Self {
        let p = model.parameters.len();
        let nominal = Propagator::new(&model.config(theta));
        let steps: Vec<f64> = model
            .parameters
            .iter()
            .zip(theta)
            .map(|(q, v)| q.step(*v))
            .collect();
        let perturbed: Vec<(Propagator, Propagator)> = (0..p)
            .map(|j| {
                let mut plus = theta.to_vec();
                plus[j] += steps[j];
                let mut minus = theta.to_vec();
                minus[j] -= steps[j];
                (
                    Propagator::new(&model.config(&plus)),
                    Propagator::new(&model.config(&minus)),
                )
            })
            .collect();
        let indices: Vec<usize> = (0..flights.len()).collect();
        let blocks = parallel_map(&indices, |&i| {
            flight_blocks(
                &nominal,
                &perturbed,
                &steps,
                &flights[i],
                &states[i],
                model.robust,
            )
        });
        let mut u = DMatrix::<f64>::zeros(p, p);
        let mut gt = DVector::<f64>::zeros(p);
        for b in &blocks {
            u += b.u.view((0, 0), (p, p));
            gt += b.gt.rows(0, p);
        }
        Self { blocks, u, gt }
    }

    /// The undamped reduced matrix (the states eliminated), for the covariance at the end.
    fn reduced(&self) -> DMatrix<f64> {
        let p = self.u.nrows();
        let mut reduced = self.u.clone();
        for b in &self.blocks {
            if let Some(vi) = b.v.try_inverse() {
                let w = b.w.view((0, 0), (p, 9));
                reduced -= w * vi * w.transpose();
            }
        }
        reduced
    }

    /// The step damped by `lambda` (Marquardt's scaling on theta's and every state's block):
    /// theta from the reduced system, then each flight's state back-substituted; `None` when a
    /// block is singular or theta leaves the model's domain.
    fn damped_step(
        &self,
        model: &Model,
        theta: &[f64],
        states: &[StateVector],
        lambda: f64,
    ) -> Option<(Vec<f64>, Vec<StateVector>)> {
        let p = self.u.nrows();
        let mut s = self.u.clone();
        for k in 0..p {
            s[(k, k)] += lambda * self.u[(k, k)].max(1e-12);
        }
        let mut rhs = self.gt.clone();
        let mut damped_inverses = Vec::with_capacity(self.blocks.len());
        for b in &self.blocks {
            let mut v = b.v;
            for k in 0..9 {
                v[(k, k)] += lambda * b.v[(k, k)].max(1e-12);
            }
            let vi = v.try_inverse()?;
            let w = b.w.view((0, 0), (p, 9));
            s -= w * vi * w.transpose();
            rhs -= w * (vi * b.g);
            damped_inverses.push(vi);
        }
        let step = s.cholesky()?.solve(&rhs);
        let candidate: Vec<f64> = theta.iter().zip(step.iter()).map(|(a, d)| a + d).collect();
        if !model.admits(&candidate) {
            return None;
        }
        let candidate_states = self
            .blocks
            .iter()
            .zip(&damped_inverses)
            .zip(states)
            .map(|((b, vi), x)| {
                let w = b.w.view((0, 0), (p, 9));
                x + vi * (b.g - w.transpose() * &step)
            })
            .collect();
        Some((candidate, candidate_states))
    }
}

/// How well `config` forecasts a flight: its state fitted to the detections of the first
/// `fraction` of its duration, the RMS distance [m] between the positions predicted from there
/// and the later detections. `None` when either part has too few detections or the fit fails.
pub fn forecast_error(config: &Config, detections: &[Detection], fraction: f64) -> Option<f64> {
    let first = detections.iter().map(|d| d.stamp).min()?;
    let last = detections.iter().map(|d| d.stamp).max()?;
    let cut = first + ((last - first) as f64 * fraction) as i64;
    let (early, late): (Vec<Detection>, Vec<Detection>) =
        detections.iter().partition(|d| d.stamp <= cut);
    if early.len() < MIN_FLIGHT_DETECTIONS || late.is_empty() {
        return None;
    }
    let propagator = Propagator::new(config);
    let observations = Observations::new(config, &early);
    let fit = fit_from_guess(
        &propagator,
        &observations,
        &early,
        config.gravity,
        CALIBRATION_SPIN_PRIOR,
    )
    .ok()?;
    let stamps: Vec<i64> = late.iter().map(|d| d.stamp).collect();
    let states = fit.states_at(&propagator, &stamps);
    let (mut sum, mut n) = (0.0, 0usize);
    for (d, s) in late.iter().zip(states) {
        if let Some(s) = s
            && d.position.iter().all(|v| v.is_finite())
        {
            sum += (s.state.position - d.position).norm_squared();
            n += 1;
        }
    }
    (n > 0).then(|| (sum / n as f64).sqrt())
}

/// Forecast errors on flights left out of a calibration, with the starting and the calibrated
/// configuration ([`forecast_error`]).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct Holdout {
    /// Fraction of each flight's duration fitted before forecasting the rest.
    pub fraction: f64,
    /// Flights forecast with both configurations.
    pub flights: usize,
    /// RMS forecast errors with the starting configuration [m].
    pub before: ErrorStats,
    /// The same with the calibrated configuration [m].
    pub after: ErrorStats,
}

/// [`forecast_error`] of every flight with `start` and with `calibrated`.
pub fn holdout(
    start: &Config,
    calibrated: &Config,
    flights: &[FlightInput],
    fraction: f64,
) -> Holdout {
    let (mut before, mut after) = (Vec::new(), Vec::new());
    for f in flights {
        if let (Some(b), Some(a)) = (
            forecast_error(start, &f.detections, fraction),
            forecast_error(calibrated, &f.detections, fraction),
        ) {
            before.push(b);
            after.push(a);
        }
    }
    Holdout {
        fraction,
        flights: before.len(),
        before: ErrorStats::of(&before),
        after: ErrorStats::of(&after),
    }
}

/// Standard deviation of a fitted polynomial's value at `x` [-], from the calibration's
/// covariance over its coefficients (`drag`: C_D, else C_M); 0 when it was not fitted.
pub fn polynomial_sigma(calibration: &Calibration, drag: bool, x: f64) -> f64 {
    let basis: Vec<(usize, f64)> = calibration
        .parameters
        .iter()
        .enumerate()
        .filter_map(|(i, p)| match (p.parameter, drag) {
            (Parameter::Drag(k), true) | (Parameter::Magnus(k), false) => {
                Some((i, x.powi(k as i32)))
            }
            _ => None,
        })
        .collect();
    let mut variance = 0.0;
    for &(i, a) in &basis {
        for &(j, b) in &basis {
            variance += a * b * calibration.covariance[(i, j)];
        }
    }
    variance.max(0.0).sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn refitting_a_polynomial_at_its_own_order_keeps_it_and_at_another_stays_close() {
        let c = Config {
            aero: crate::config::AeroParams::seed_2014(),
            ..Config::default()
        };
        assert_eq!(
            refit(&c.aero.drag_coefficients, 2),
            c.aero.drag_coefficients
        );
        let cubic = refit(&c.aero.magnus_coefficients, 3);
        assert_eq!(cubic.len(), 4);
        for sp in [0.0, 0.3, 0.8, 1.4] {
            let error = Polynomial::new(&cubic).value(sp)
                - Polynomial::new(&c.aero.magnus_coefficients).value(sp);
            assert!(error.abs() < 0.02, "at {sp}: {error}");
        }
    }

    #[test]
    fn parameters_round_trip_through_the_configuration() {
        let mut c = Config::default();
        for (p, v) in [
            (Parameter::Drag(3), 0.05),
            (Parameter::Magnus(1), -1.8),
            (Parameter::Restitution, 0.87),
            (Parameter::Friction, 0.32),
            (Parameter::AirDensity, 1.15),
        ] {
            p.set(&mut c, v);
            assert_eq!(p.value(&c), v, "{}", p.name());
        }
        assert_eq!(c.aero.drag_coefficients.len(), 4);
        assert!(!Parameter::Restitution.admits(1.0));
        assert!(!Parameter::Friction.admits(-0.1));
    }

    #[test]
    fn refuses_what_cannot_be_fitted() {
        let c = Config::default();
        let none = calibrate(&c, &[], &Options::default(), &mut |_| {});
        assert_eq!(none, Err(CalibrationError::NothingToFit));
        let both = Options {
            aero: true,
            density: true,
            ..Options::default()
        };
        assert_eq!(
            calibrate(&c, &[], &both, &mut |_| {}),
            Err(CalibrationError::DensityWithAero)
        );
        let high = Options {
            aero: true,
            drag_order: Some(7),
            ..Options::default()
        };
        assert!(matches!(
            calibrate(&c, &[], &high, &mut |_| {}),
            Err(CalibrationError::OrderTooHigh { .. })
        ));
        let bounce = Options {
            bounce: true,
            ..Options::default()
        };
        assert_eq!(
            calibrate(&c, &[], &bounce, &mut |_| {}),
            Err(CalibrationError::TooFewFlights {
                needed: 2,
                found: 0
            })
        );
    }
}
