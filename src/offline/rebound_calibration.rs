//! The rubber calibrated from recorded hits: the racket model's rubber constants (the restitution
//! polynomial e_RB(V), Coulomb friction mu, tangential restitution e_t, torsional restitution e_z;
//! [`crate::physics::racket`], docs/racket.md) that best predict the measured
//! outgoing velocity and spin of many hits, with standard errors and k-fold cross-validation.
//!
//! The cost is the sum of squares of the hits' residuals, velocity in m/s over sigma_v and spin
//! in rad/s over sigma_w, each component measured. The two noise levels are not known in advance:
//! they are re-estimated from the residuals of the previous fit until they settle (feasible
//! generalised least squares), so each kind weighs by its own scatter. Minimised by
//! Levenberg-Marquardt ([`crate::model::least_squares`]) with central-difference Jacobians; standard
//! errors from (J^T J)^-1 times the reduced chi-square. Cross-validation fits k times on all hits
//! but every k-th and scores the model on the ones left out (hit i is in fold i mod k).
//!
//! Recorded hits come as CSV ([`HitSet::add_csv`]): the columns of the tt_rackets data (Gossard
//! 2026: `v_in_*`, `spin_before_*`, `v_out_*`, `spin_after_*`, in the racket's frame with the
//! racket at rest and its normal +z), and optionally the racket's state for a robot's own hits
//! (`racket_velocity_*`, `racket_normal_*`, `impact_offset`). A velocity axis that is 0 before and
//! after in every hit is taken as not measured (tt_rackets' planar data) and left out of the
//! cost and the errors.

use std::collections::BTreeMap;

use nalgebra::{DVector, Vector3};
use serde::Serialize;
use thiserror::Error;

use crate::config::Config;
use crate::model::least_squares::{LeastSquaresError, Minimum, minimise};
use crate::physics::racket::{RacketModel, RacketState};
use crate::physics::state::BallState;

/// Highest order of the fitted restitution polynomial.
pub const MAX_RESTITUTION_ORDER: usize = 3;
/// Passes of noise re-estimation before the fit is taken as settled.
const NOISE_PASSES: usize = 4;
/// Relative change of both noise levels below which they have settled.
const NOISE_TOLERANCE: f64 = 0.01;

/// One recorded hit: the ball just before and just after, and the racket at the impact.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RecordedHit {
    /// The ball just before the impact (its position is not used).
    pub before: BallState,
    /// The racket at the impact.
    pub racket: RacketState,
    /// Measured velocity just after [m/s].
    pub velocity_after: Vector3<f64>,
    /// Measured spin just after [rad/s].
    pub spin_after: Vector3<f64>,
    /// Index of the group (input file) it came from in [`HitSet::groups`].
    pub group: usize,
}

/// Why a file of hits cannot be used at all.
#[derive(Debug, Clone, PartialEq, Eq, Error)]
pub enum HitsError {
    /// The file is empty.
    #[error("{group}: the file is empty; it needs a header line and one line per hit")]
    Empty {
        /// The file.
        group: String,
    },
    /// A column the format requires is missing.
    #[error(
        "{group}: no column {column}: a hit needs v_in_x,v_in_y,v_in_z, spin_before_x..z, v_out_x..z and spin_after_x..z (the tt_rackets columns; docs/racket.md, \"The hits file\")"
    )]
    MissingColumn {
        /// The file.
        group: String,
        /// The column.
        column: String,
    },
    /// A racket column set is given in part.
    #[error("{group}: {given} is given without {missing}: give all three components or none")]
    PartialVector {
        /// The file.
        group: String,
        /// A column present.
        given: String,
        /// A column missing.
        missing: String,
    },
}

/// A line that was not taken, and why.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct RejectedLine {
    /// The file.
    pub group: String,
    /// Line number (1 = the header).
    pub line: usize,
    /// Why.
    pub reason: String,
}

/// Recorded hits from one or more files.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct HitSet {
    /// The hits.
    pub hits: Vec<RecordedHit>,
    /// The name of each group (file).
    pub groups: Vec<String>,
    /// Lines not taken.
    pub rejected: Vec<RejectedLine>,
}

/// The racket of a hit recorded without its state: at rest, normal +z, hit at its centre of
/// gravity (tt_rackets).
const RACKET_AT_REST: RacketState = RacketState {
    velocity: Vector3::new(0.0, 0.0, 0.0),
    normal: Vector3::new(0.0, 0.0, 1.0),
    impact_offset: 0.0,
};

impl HitSet {
    /// Adds the hits of the CSV text `text` under the group name `group`; lines that are not
    /// hits are kept in [`Self::rejected`] with the reason.
    pub fn add_csv(&mut self, group: &str, text: &str) -> Result<usize, HitsError> {
        let mut lines = text.lines().enumerate();
        let Some((_, header)) = lines.next() else {
            return Err(HitsError::Empty {
                group: group.to_owned(),
            });
        };
        let columns: Vec<&str> = header.trim().split(',').map(str::trim).collect();
        let find = |name: &str| columns.iter().position(|c| *c == name);
        let required = |prefix: &str| -> Result<[usize; 3], HitsError> {
            let mut out = [0; 3];
            for (k, axis) in ["x", "y", "z"].iter().enumerate() {
                let column = format!("{prefix}_{axis}");
                out[k] = find(&column).ok_or_else(|| HitsError::MissingColumn {
                    group: group.to_owned(),
                    column,
                })?;
            }
            Ok(out)
        };
        let optional = |prefix: &str| -> Result<Option<[usize; 3]>, HitsError> {
            let found: Vec<Option<usize>> = ["x", "y", "z"]
                .iter()
                .map(|a| find(&format!("{prefix}_{a}")))
                .collect();
            match (
                found.iter().position(Option::is_some),
                found.iter().position(Option::is_none),
            ) {
                (None, _) => Ok(None),
                (Some(_), None) => Ok(Some([0, 1, 2].map(|k| found[k].unwrap_or(0)))),
                (Some(g), Some(m)) => Err(HitsError::PartialVector {
                    group: group.to_owned(),
                    given: format!("{prefix}_{}", ["x", "y", "z"][g]),
                    missing: format!("{prefix}_{}", ["x", "y", "z"][m]),
                }),
            }
        };
        let v_in = required("v_in")?;
        let w_in = required("spin_before")?;
        let v_out = required("v_out")?;
        let w_out = required("spin_after")?;
        let racket_velocity = optional("racket_velocity")?;
        let racket_normal = optional("racket_normal")?;
        let offset = find("impact_offset");
        let index = self.groups.len();
        self.groups.push(group.to_owned());
        let mut taken = 0;
        for (number, line) in lines {
            let line_number = number + 1;
            if line.trim().is_empty() {
                continue;
            }
            let fields: Vec<&str> = line.trim().split(',').map(str::trim).collect();
            let reject = |reason: String| RejectedLine {
                group: group.to_owned(),
                line: line_number,
                reason,
            };
            if fields.len() != columns.len() {
                self.rejected.push(reject(format!(
                    "{} fields where the header has {}",
                    fields.len(),
                    columns.len()
                )));
                continue;
            }
            let number_at = |i: usize| -> Result<f64, String> {
                fields[i]
                    .parse::<f64>()
                    .ok()
                    .filter(|v| v.is_finite())
                    .ok_or_else(|| {
                        format!("{} is not a finite number: {:?}", columns[i], fields[i])
                    })
            };
            let vector = |c: [usize; 3]| -> Result<Vector3<f64>, String> {
                Ok(Vector3::new(
                    number_at(c[0])?,
                    number_at(c[1])?,
                    number_at(c[2])?,
                ))
            };
            let parsed = (|| -> Result<RecordedHit, String> {
                let racket = RacketState {
                    velocity: racket_velocity
                        .map(vector)
                        .transpose()?
                        .unwrap_or(RACKET_AT_REST.velocity),
                    normal: racket_normal
                        .map(vector)
                        .transpose()?
                        .unwrap_or(RACKET_AT_REST.normal),
                    impact_offset: offset.map(number_at).transpose()?.unwrap_or(0.0),
                };
                Ok(RecordedHit {
                    before: BallState::new(Vector3::zeros(), vector(v_in)?, vector(w_in)?),
                    racket,
                    velocity_after: vector(v_out)?,
                    spin_after: vector(w_out)?,
                    group: index,
                })
            })();
            match parsed {
                Ok(hit) => {
                    self.hits.push(hit);
                    taken += 1;
                }
                Err(reason) => self.rejected.push(reject(reason)),
            }
        }
        Ok(taken)
    }

    /// Which velocity axes are measured: all but those 0 before and after in every hit.
    pub fn measured_velocity_axes(&self) -> [bool; 3] {
        [0, 1, 2].map(|k| {
            self.hits
                .iter()
                .any(|h| h.before.velocity[k] != 0.0 || h.velocity_after[k] != 0.0)
        })
    }

    /// The hits whose index `keep` accepts.
    fn subset(&self, keep: impl Fn(usize) -> bool) -> Vec<RecordedHit> {
        self.hits
            .iter()
            .enumerate()
            .filter(|(i, _)| keep(*i))
            .map(|(_, h)| *h)
            .collect()
    }
}

/// A rubber constant the calibration can fit.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub enum RubberParameter {
    /// Coefficient k of the restitution polynomial e_RB(V) (`racket.rubber_restitution[k]`).
    Restitution(usize),
    /// Coulomb friction mu (`racket.rubber_friction`).
    Friction,
    /// Tangential restitution e_t (`racket.rubber_tangential_restitution`).
    TangentialRestitution,
    /// Torsional restitution e_z (`racket.rubber_torsional_restitution`).
    TorsionalRestitution,
}

impl RubberParameter {
    /// The configuration parameter's name.
    pub fn name(self) -> String {
        match self {
            Self::Restitution(k) => format!("racket.rubber_restitution[{k}]"),
            Self::Friction => "racket.rubber_friction".into(),
            Self::TangentialRestitution => "racket.rubber_tangential_restitution".into(),
            Self::TorsionalRestitution => "racket.rubber_torsional_restitution".into(),
        }
    }

    /// Its value in `config`.
    fn get(self, config: &Config) -> f64 {
        let r = &config.racket;
        match self {
            Self::Restitution(k) => r.rubber_restitution.get(k).copied().unwrap_or(0.0),
            Self::Friction => r.rubber_friction,
            Self::TangentialRestitution => r.rubber_tangential_restitution,
            Self::TorsionalRestitution => r.rubber_torsional_restitution,
        }
    }

    /// Sets it in `config`.
    fn set(self, config: &mut Config, value: f64) {
        let r = &mut config.racket;
        match self {
            Self::Restitution(k) => {
                if r.rubber_restitution.len() <= k {
                    r.rubber_restitution.resize(k + 1, 0.0);
                }
                r.rubber_restitution[k] = value;
            }
            Self::Friction => r.rubber_friction = value,
            Self::TangentialRestitution => r.rubber_tangential_restitution = value,
            Self::TorsionalRestitution => r.rubber_torsional_restitution = value,
        }
    }

    /// Central-difference step.
    fn step(self) -> f64 {
        match self {
            Self::Restitution(k) => 1e-5 / 10f64.powi(k as i32),
            _ => 1e-5,
        }
    }
}

/// What to fit.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RubberOptions {
    /// Order of the fitted restitution polynomial (0-3); None: restitution not fitted.
    pub restitution_order: Option<usize>,
    /// Fit the Coulomb friction.
    pub friction: bool,
    /// Fit the tangential restitution.
    pub tangential: bool,
    /// Fit the torsional restitution.
    pub torsional: bool,
    /// Folds of the cross-validation (0: none; else at least 2).
    pub folds: usize,
}

impl Default for RubberOptions {
    fn default() -> Self {
        Self {
            restitution_order: Some(1),
            friction: true,
            tangential: true,
            torsional: true,
            folds: 5,
        }
    }
}

impl RubberOptions {
    /// The parameters fitted, in order.
    pub fn parameters(&self) -> Vec<RubberParameter> {
        let mut out: Vec<RubberParameter> = self
            .restitution_order
            .map(|order| (0..=order).map(RubberParameter::Restitution).collect())
            .unwrap_or_default();
        if self.friction {
            out.push(RubberParameter::Friction);
        }
        if self.tangential {
            out.push(RubberParameter::TangentialRestitution);
        }
        if self.torsional {
            out.push(RubberParameter::TorsionalRestitution);
        }
        out
    }
}

/// Why the rubber cannot be calibrated.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum RubberCalibrationError {
    /// Nothing to fit.
    #[error("no rubber parameter is selected to fit")]
    NothingToFit,
    /// Restitution order out of range.
    #[error("restitution order {0} is not supported: give 0 to {MAX_RESTITUTION_ORDER}")]
    Order(usize),
    /// Folds out of range.
    #[error("{folds} folds for {hits} hits: give 0 (no cross-validation) or 2 to {hits}")]
    Folds {
        /// Asked for.
        folds: usize,
        /// Hits.
        hits: usize,
    },
    /// The starting configuration cannot predict some hit.
    #[error(
        "the starting configuration cannot predict hit {index} ({group}): {reason}; is the racket normal pointing toward the ball?"
    )]
    Unpredictable {
        /// Index of the hit.
        index: usize,
        /// Its group.
        group: String,
        /// The model's reason.
        reason: String,
    },
    /// No parameter changes the predictions at the minimum.
    #[error(
        "these hits determine none of the parameters to fit ({names}): no hit's prediction depends on them"
    )]
    Undetermined {
        /// The parameters' names.
        names: String,
    },
    /// The minimiser failed.
    #[error("{0}")]
    Fit(LeastSquaresError),
    /// The calibrated values are outside the configuration's ranges.
    #[error("the fitted values are not a valid configuration: {0}")]
    Invalid(String),
}

/// RMS errors of predicted outgoing velocity and spin over some hits.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize)]
pub struct ReboundErrors {
    /// Hits scored.
    pub hits: usize,
    /// RMS of the outgoing velocity's error vector (measured axes) [m/s].
    pub velocity_rms: f64,
    /// RMS of the outgoing spin's error vector [rad/s].
    pub spin_rms: f64,
}

/// Squared errors summed, to be turned into RMS.
#[derive(Debug, Clone, Copy, Default)]
struct ErrorSums {
    hits: usize,
    velocity: f64,
    spin: f64,
}

impl ErrorSums {
    fn add(&mut self, velocity: f64, spin: f64) {
        self.hits += 1;
        self.velocity += velocity;
        self.spin += spin;
    }

    fn rms(self) -> ReboundErrors {
        let n = self.hits.max(1) as f64;
        ReboundErrors {
            hits: self.hits,
            velocity_rms: (self.velocity / n).sqrt(),
            spin_rms: (self.spin / n).sqrt(),
        }
    }
}

/// Errors of a model over a group of hits.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct GroupErrors {
    /// The group.
    pub group: String,
    /// With the starting configuration.
    pub start: ReboundErrors,
    /// With the calibrated one (held out, in [`CrossValidation`]).
    pub calibrated: ReboundErrors,
}

/// A fitted parameter.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct FittedRubberParameter {
    /// Which.
    pub parameter: RubberParameter,
    /// Its configuration name.
    pub name: String,
    /// Fitted value.
    pub value: f64,
    /// Standard error; None when no hit's prediction depends on it at the minimum (the friction
    /// when every hit grips: it is then only known to exceed what the grip needs).
    pub std_error: Option<f64>,
    /// Starting value.
    pub initial: f64,
    /// Smallest and largest value over the cross-validation's folds.
    pub fold_range: Option<(f64, f64)>,
}

/// The held-out errors of k-fold cross-validation.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct CrossValidation {
    /// Folds.
    pub folds: usize,
    /// Over all hits.
    pub overall: GroupErrors,
    /// Per group.
    pub groups: Vec<GroupErrors>,
}

/// One hit as measured and as predicted, for the chart.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HitPrediction {
    /// Its group.
    pub group: usize,
    /// Measured outgoing velocity and spin.
    pub measured: (Vector3<f64>, Vector3<f64>),
    /// Predicted by the starting configuration.
    pub start: (Vector3<f64>, Vector3<f64>),
    /// Predicted by the calibrated one (held out when cross-validated).
    pub calibrated: (Vector3<f64>, Vector3<f64>),
}

/// The calibrated rubber.
#[derive(Debug, Clone, PartialEq)]
pub struct RubberCalibration {
    /// The starting configuration with the fitted values.
    pub config: Config,
    /// The fitted parameters.
    pub parameters: Vec<FittedRubberParameter>,
    /// The parameters the covariance is of (the fitted ones the hits determine).
    pub covariance_parameters: Vec<RubberParameter>,
    /// Their covariance.
    pub covariance: nalgebra::DMatrix<f64>,
    /// Residual noise per measured component: velocity [m/s], spin [rad/s].
    pub noise: (f64, f64),
    /// Velocity axes measured.
    pub measured_axes: [bool; 3],
    /// In-sample errors: overall and per group.
    pub fit: Vec<GroupErrors>,
    /// Held-out errors.
    pub cross_validation: Option<CrossValidation>,
    /// Every hit measured and predicted (held out when cross-validated).
    pub predictions: Vec<HitPrediction>,
    /// Levenberg-Marquardt iterations, all passes.
    pub iterations: usize,
}

/// A model and the hits it is scored on.
#[derive(Clone)]
struct Problem<'a> {
    /// The configuration, with the parameters not fitted (or found undetermined) at their values.
    start: Config,
    /// The parameters fitted.
    parameters: Vec<RubberParameter>,
    hits: &'a [RecordedHit],
    axes: [bool; 3],
}

/// A fit's result.
struct Fit {
    /// The configuration at the minimum.
    config: Config,
    /// The parameters fitted (without those found undetermined).
    parameters: Vec<RubberParameter>,
    /// The minimum over them.
    minimum: Minimum,
    /// Residual noise per component: velocity, spin.
    noise: (f64, f64),
    iterations: usize,
}

impl Problem<'_> {
    fn config(&self, x: &DVector<f64>) -> Config {
        let mut config = self.start.clone();
        for (p, v) in self.parameters.iter().zip(x.iter()) {
            p.set(&mut config, *v);
        }
        config
    }

    /// Whitened residuals at `x` (None where the model cannot predict a hit or leaves its
    /// valid ranges).
    fn residuals(&self, x: &DVector<f64>, noise: (f64, f64)) -> Option<DVector<f64>> {
        let config = self.config(x);
        let r = &config.racket;
        if !(0.0..=5.0).contains(&r.rubber_friction)
            || !(-1.0..=1.0).contains(&r.rubber_tangential_restitution)
            || !(-1.0..=1.0).contains(&r.rubber_torsional_restitution)
        {
            return None;
        }
        let model = RacketModel::new(&config);
        let per_hit = self.axes.iter().filter(|a| **a).count() + 3;
        let mut out = DVector::zeros(self.hits.len() * per_hit);
        let mut i = 0;
        for hit in self.hits {
            let (v, w) = predict(&model, hit).ok()?;
            for k in (0..3).filter(|k| self.axes[*k]) {
                out[i] = (v[k] - hit.velocity_after[k]) / noise.0;
                i += 1;
            }
            for k in 0..3 {
                out[i] = (w[k] - hit.spin_after[k]) / noise.1;
                i += 1;
            }
        }
        Some(out)
    }

    /// The fit, its noise levels re-estimated until they settle; a parameter no prediction
    /// depends on at the minimum (the friction when every hit grips) is held there and the rest
    /// refitted.
    fn fit(mut self) -> Result<Fit, RubberCalibrationError> {
        let mut x = DVector::from_iterator(
            self.parameters.len(),
            self.parameters.iter().map(|p| self.start_value(*p)),
        );
        let mut undetermined = Vec::new();
        let mut noise = (0.1, 10.0);
        let mut iterations = 0;
        let mut pass = 0;
        loop {
            if self.parameters.is_empty() {
                return Err(RubberCalibrationError::Undetermined {
                    names: names(&undetermined),
                });
            }
            let steps = DVector::from_iterator(
                self.parameters.len(),
                self.parameters.iter().map(|p| p.step()),
            );
            let minimum = match minimise(|x| self.residuals(x, noise), x.clone(), &steps) {
                Ok(minimum) => minimum,
                Err(LeastSquaresError::Singular { flat, at }) if !flat.is_empty() => {
                    let mut kept = Vec::new();
                    let mut values = Vec::new();
                    for (k, p) in self.parameters.iter().enumerate() {
                        if flat.contains(&k) {
                            p.set(&mut self.start, at[k]);
                            undetermined.push(*p);
                        } else {
                            kept.push(*p);
                            values.push(at[k]);
                        }
                    }
                    self.parameters = kept;
                    x = DVector::from_vec(values);
                    continue;
                }
                Err(e) => return Err(RubberCalibrationError::Fit(e)),
            };
            pass += 1;
            iterations += minimum.iterations;
            x = minimum.x.clone();
            let config = self.config(&x);
            let sums = self.errors(&RacketModel::new(&config), self.hits.iter());
            let v_dims = (self.axes.iter().filter(|a| **a).count() * sums.hits).max(1) as f64;
            let w_dims = (3 * sums.hits).max(1) as f64;
            let next = (
                (sums.velocity / v_dims).sqrt().max(1e-6),
                (sums.spin / w_dims).sqrt().max(1e-6),
            );
            let settled = ((next.0 - noise.0) / noise.0).abs() < NOISE_TOLERANCE
                && ((next.1 - noise.1) / noise.1).abs() < NOISE_TOLERANCE;
            noise = next;
            if settled || pass > NOISE_PASSES {
                return Ok(Fit {
                    config,
                    parameters: self.parameters,
                    minimum,
                    noise,
                    iterations,
                });
            }
        }
    }

    /// Where the fit of `parameter` starts. Friction and tangential restitution start from the
    /// hits themselves: the median ratio of tangential to normal velocity change (with the
    /// configured friction every hit may grip, where friction has no gradient to follow) and
    /// the median reversal of the contact point's slip.
    fn start_value(&self, parameter: RubberParameter) -> f64 {
        let mut ratios = Vec::new();
        let mut reversals = Vec::new();
        for hit in self.hits {
            let n = hit.racket.normal;
            let change = hit.velocity_after - hit.before.velocity;
            let normal = change.dot(&n);
            let tangential = (change - n * normal).norm();
            if normal > 0.0 {
                ratios.push(tangential / normal);
            }
            let slip = |v: &Vector3<f64>, w: &Vector3<f64>| {
                let relative = v - hit.racket.velocity;
                relative - n * relative.dot(&n) - BALL_RADIUS_FOR_START * w.cross(&n)
            };
            let before = slip(&hit.before.velocity, &hit.before.spin);
            let after = slip(&hit.velocity_after, &hit.spin_after);
            if before.norm_squared() > 1e-6 {
                reversals.push((-after.dot(&before) / before.norm_squared()).clamp(-0.9, 0.9));
            }
        }
        match parameter {
            RubberParameter::Friction => {
                median(&mut ratios).map_or(parameter.get(&self.start), |m| m.clamp(0.05, 4.0))
            }
            RubberParameter::TangentialRestitution => {
                median(&mut reversals).unwrap_or(parameter.get(&self.start))
            }
            _ => parameter.get(&self.start),
        }
    }

    /// Squared errors of `model` over `hits`.
    fn errors<'h>(
        &self,
        model: &RacketModel,
        hits: impl Iterator<Item = &'h RecordedHit>,
    ) -> ErrorSums {
        let mut sums = ErrorSums::default();
        for hit in hits {
            if let Ok((v, w)) = predict(model, hit) {
                let (dv, dw) = self.squared_errors(hit, &v, &w);
                sums.add(dv, dw);
            }
        }
        sums
    }

    fn squared_errors(&self, hit: &RecordedHit, v: &Vector3<f64>, w: &Vector3<f64>) -> (f64, f64) {
        let dv: f64 = (0..3)
            .filter(|k| self.axes[*k])
            .map(|k| (v[k] - hit.velocity_after[k]).powi(2))
            .sum();
        (dv, (w - hit.spin_after).norm_squared())
    }
}

/// The parameters' names, comma separated.
fn names(parameters: &[RubberParameter]) -> String {
    parameters
        .iter()
        .map(|p| p.name())
        .collect::<Vec<_>>()
        .join(", ")
}

/// The ball's radius the starting values assume [m] (a 40 mm ball; only the start depends on it).
const BALL_RADIUS_FOR_START: f64 = 0.02;

/// The median of `values` (reordered), None when empty.
fn median(values: &mut [f64]) -> Option<f64> {
    values.sort_by(f64::total_cmp);
    values.get(values.len() / 2).copied()
}

/// The outgoing velocity and spin `model` predicts for `hit`.
fn predict(
    model: &RacketModel,
    hit: &RecordedHit,
) -> Result<(Vector3<f64>, Vector3<f64>), crate::physics::racket::ImpactError> {
    let after = model.rebound(&hit.before, &hit.racket)?;
    Ok((after.velocity, after.spin))
}

/// Fits the rubber constants `options` selects to `set`, from `start`.
pub fn calibrate_rubber(
    start: &Config,
    set: &HitSet,
    options: &RubberOptions,
) -> Result<RubberCalibration, RubberCalibrationError> {
    let parameters = check_inputs(start, set, options)?;
    let n = set.hits.len();
    let start_model = RacketModel::new(start);
    let axes = set.measured_velocity_axes();
    let problem = Problem {
        start: start.clone(),
        parameters: parameters.clone(),
        hits: &set.hits,
        axes,
    };
    let mut fit = problem.clone().fit()?;
    fit.config.racket.rubber_covariance = full_covariance(&fit);
    fit.config.racket.rebound_scatter = vec![fit.noise.0, fit.noise.1];
    fit.config
        .validate()
        .map_err(|e| RubberCalibrationError::Invalid(e.to_string()))?;
    let fitted_model = RacketModel::new(&fit.config);
    let mut iterations = fit.iterations;

    let folds = held_out_fits(&problem, set, options.folds)?;
    iterations += folds.iterations;
    let (held_out, fold_values) = (folds.predictions, folds.values);

    let mut predictions = Vec::with_capacity(n);
    let groups = set.groups.len();
    let (mut start_sums, mut fit_sums, mut cv_sums) = (
        vec![ErrorSums::default(); groups + 1],
        vec![ErrorSums::default(); groups + 1],
        vec![ErrorSums::default(); groups + 1],
    );
    for (i, hit) in set.hits.iter().enumerate() {
        let (Ok(s), Ok(f)) = (predict(&start_model, hit), predict(&fitted_model, hit)) else {
            continue;
        };
        let g = hit.group;
        for (sums, (v, w)) in [(&mut start_sums, s), (&mut fit_sums, f)] {
            let (dv, dw) = problem.squared_errors(hit, &v, &w);
            sums[g].add(dv, dw);
            sums[groups].add(dv, dw);
        }
        let shown = match held_out[i] {
            Some((v, w)) => {
                let (dv, dw) = problem.squared_errors(hit, &v, &w);
                cv_sums[g].add(dv, dw);
                cv_sums[groups].add(dv, dw);
                (v, w)
            }
            None => f,
        };
        predictions.push(HitPrediction {
            group: g,
            measured: (hit.velocity_after, hit.spin_after),
            start: s,
            calibrated: shown,
        });
    }
    let name = |g: usize| set.groups.get(g).cloned().unwrap_or_else(|| "all".into());
    let table = |calibrated: &[ErrorSums]| -> Vec<GroupErrors> {
        (0..=groups)
            .map(|g| GroupErrors {
                group: name(g),
                start: start_sums[g].rms(),
                calibrated: calibrated[g].rms(),
            })
            .collect()
    };
    let cross_validation = (options.folds >= 2).then(|| {
        let mut rows = table(&cv_sums);
        let overall = rows.pop().unwrap_or(GroupErrors {
            group: "all".into(),
            start: ReboundErrors::default(),
            calibrated: ReboundErrors::default(),
        });
        CrossValidation {
            folds: options.folds,
            overall,
            groups: rows,
        }
    });
    let std_errors = fit.minimum.std_errors();
    let fitted = parameters
        .iter()
        .enumerate()
        .map(|(k, p)| FittedRubberParameter {
            parameter: *p,
            name: p.name(),
            value: p.get(&fit.config),
            std_error: fit
                .parameters
                .iter()
                .position(|q| q == p)
                .map(|j| std_errors[j]),
            initial: p.get(start),
            fold_range: fold_values[k].iter().fold(None, |range, v| {
                Some(range.map_or((*v, *v), |(lo, hi): (f64, f64)| (lo.min(*v), hi.max(*v))))
            }),
        })
        .collect();
    Ok(RubberCalibration {
        config: fit.config,
        parameters: fitted,
        covariance_parameters: fit.parameters,
        covariance: fit.minimum.covariance,
        noise: fit.noise,
        measured_axes: axes,
        fit: table(&fit_sums),
        cross_validation,
        predictions,
        iterations,
    })
}

/// Checks `options` against `set` and that the starting model predicts every hit;
/// returns the parameters to fit.
fn check_inputs(
    start: &Config,
    set: &HitSet,
    options: &RubberOptions,
) -> Result<Vec<RubberParameter>, RubberCalibrationError> {
    if let Some(order) = options.restitution_order
        && order > MAX_RESTITUTION_ORDER
    {
        return Err(RubberCalibrationError::Order(order));
    }
    let parameters = options.parameters();
    if parameters.is_empty() {
        return Err(RubberCalibrationError::NothingToFit);
    }
    let n = set.hits.len();
    if options.folds == 1 || options.folds > n {
        return Err(RubberCalibrationError::Folds {
            folds: options.folds,
            hits: n,
        });
    }
    let start_model = RacketModel::new(start);
    for (index, hit) in set.hits.iter().enumerate() {
        if let Err(e) = predict(&start_model, hit) {
            return Err(RubberCalibrationError::Unpredictable {
                index,
                group: set.groups.get(hit.group).cloned().unwrap_or_default(),
                reason: e.to_string(),
            });
        }
    }
    Ok(parameters)
}

/// The k-fold cross-validation's fits: each hit predicted by the fit to the other folds.
struct HeldOut {
    /// Per hit, the prediction of the fit that did not see it.
    predictions: Vec<Option<(Vector3<f64>, Vector3<f64>)>>,
    /// Per fitted parameter, its value in each fold's fit.
    values: Vec<Vec<f64>>,
    /// The folds' solver iterations together.
    iterations: usize,
}

/// Fits `problem` once per fold with that fold's hits left out (none when `folds` is 0).
fn held_out_fits(
    problem: &Problem<'_>,
    set: &HitSet,
    folds: usize,
) -> Result<HeldOut, RubberCalibrationError> {
    let parameters = &problem.parameters;
    let n = set.hits.len();
    let mut held_out: Vec<Option<(Vector3<f64>, Vector3<f64>)>> = vec![None; n];
    let mut fold_values: Vec<Vec<f64>> = vec![Vec::new(); parameters.len()];
    let mut held_iterations = 0;
    for fold in 0..folds {
        let training = set.subset(|i| i % folds != fold);
        let fold_fit = Problem {
            hits: &training,
            ..problem.clone()
        }
        .fit()?;
        held_iterations += fold_fit.iterations;
        for (k, p) in parameters.iter().enumerate() {
            fold_values[k].push(p.get(&fold_fit.config));
        }
        let model = RacketModel::new(&fold_fit.config);
        for (i, hit) in set
            .hits
            .iter()
            .enumerate()
            .filter(|(i, _)| i % folds == fold)
        {
            held_out[i] = predict(&model, hit).ok();
        }
    }
    Ok(HeldOut {
        predictions: held_out,
        values: fold_values,
        iterations: held_iterations,
    })
}

/// The fit's covariance spread over all the rubber's constants in the order of
/// `racket.rubber_covariance` (0 for those not fitted or not determined).
fn full_covariance(fit: &Fit) -> Vec<f64> {
    let n = fit.config.racket.rubber_restitution.len();
    let size = n + 3;
    let index = |p: &RubberParameter| match p {
        RubberParameter::Restitution(k) => *k,
        RubberParameter::Friction => n,
        RubberParameter::TangentialRestitution => n + 1,
        RubberParameter::TorsionalRestitution => n + 2,
    };
    let mut out = vec![0.0; size * size];
    for (a, pa) in fit.parameters.iter().enumerate() {
        for (b, pb) in fit.parameters.iter().enumerate() {
            out[index(pa) * size + index(pb)] = fit.minimum.covariance[(a, b)];
        }
    }
    out
}

/// Counts of rejected lines by reason (the reason's text before its first ':').
pub fn rejected_by_reason(set: &HitSet) -> BTreeMap<String, usize> {
    let mut out = BTreeMap::new();
    for r in &set.rejected {
        let kind = r.reason.split(':').next().unwrap_or(&r.reason).to_owned();
        *out.entry(kind).or_insert(0) += 1;
    }
    out
}
