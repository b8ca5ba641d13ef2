//! What the estimator learns across tracks (docs/estimator.md, "The adaptation"): the ball's and
//! table's parameters in a two-level model and each camera's noise ([`super::camera_noise`]).
//!
//! A flight's parameters scatter about the global ones, theta_f = theta_g + d, d ~ N(0, D). A
//! track's lesson, posterior N(theta_t, P_t) over prior N(theta_g, P_pr), is a likelihood of
//! theta_f with information J = P_t^-1 - P_pr^-1 and weighted mean b = P_t^-1 theta_t -
//! P_pr^-1 theta_g; of theta_g, (I + J D)^-1 J and (I + J D)^-1 b. The Reynolds exponents
//! (a_D, a_M) enter through k_f = k_g exp((a_g - a_flown) L) ([`Learned::flight_params`]),
//! linearised [`LINEARISATIONS`] times (Gauss-Newton); an exponent the flights have not
//! determined stays at its prior ([`Learned::settled`]).

use nalgebra::{SMatrix, SVector, SymmetricEigen};

use super::camera_noise::NoiseLearner;
use super::lessons::Lessons;
use super::smoother::{Flown, Lesson, LessonJob};
use crate::config::{AdaptationParams, Config};
use crate::online::ekf::ParamCovariance;
use crate::online::learned::exponent_determined;
use crate::physics::params::{DRAG_SCALE, MAGNUS_SCALE};
use crate::physics::{FlightModel, PARAMS, ParamVector, PhysicsParams};

/// The parameters learned across tracks: the ball's and table's ([`PARAMS`], each flight's
/// filter learns them too) and the Reynolds exponents (a_D, a_M), which the flights' scales at
/// their different speeds teach.
pub(crate) const SHAPE: usize = PARAMS + 2;
/// Index of a_D, then a_M, in the learned parameters.
const DRAG_EXPONENT: usize = PARAMS;
const MAGNUS_EXPONENT: usize = PARAMS + 1;
pub(crate) type ShapeVector = SVector<f64, SHAPE>;
pub(crate) type ShapeCovariance = SMatrix<f64, SHAPE, SHAPE>;
/// d(a flight's parameters)/d(the learned ones).
type FlightMap = SMatrix<f64, PARAMS, SHAPE>;
/// Linearisations of a track's update: the first at theta_g, each next at the last's result.
const LINEARISATIONS: usize = 3;

/// What the estimator knows of the physical parameters between tracks.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Learned {
    /// theta_g.
    theta: ShapeVector,
    /// P_g.
    covariance: ShapeCovariance,
    /// When they were last learned [ns]; `None` before any track.
    stamp: Option<i64>,
    /// Tracks that contributed.
    tracks: u64,
    /// The prior.
    prior: ShapeVector,
    /// The prior variances (zero: not adapted).
    prior_var: ShapeVector,
    /// The random walk's density [unit^2/s].
    drift_density: ShapeVector,
    /// D, the flight-to-flight dispersion (diagonal).
    dispersion: ParamVector,
}

impl Learned {
    /// Nothing learned yet: the configured `prior` (the ball's and table's parameters, then the
    /// Reynolds exponents) with its variances.
    fn new(
        prior: ShapeVector,
        prior_var: ShapeVector,
        drift_density: ShapeVector,
        dispersion: ParamVector,
    ) -> Self {
        Self {
            theta: prior,
            covariance: ShapeCovariance::from_diagonal(&prior_var),
            stamp: None,
            tracks: 0,
            prior,
            prior_var,
            drift_density: drift_density.zip_map(&prior_var, |d, v| if v > 0.0 { d } else { 0.0 }),
            dispersion: ParamVector::from_fn(|i, _| {
                if prior_var[i] > 0.0 {
                    dispersion[i]
                } else {
                    0.0
                }
            }),
        }
    }

    /// Nothing learned yet, as `config`'s adaptation starts (without its drift).
    pub(crate) fn prior_of(config: &Config) -> Self {
        Self::new(
            configured_shape(config),
            shape_prior_variances(config),
            ShapeVector::zeros(),
            ParamVector::zeros(),
        )
    }

    /// The same prior with theta_g and P_g given (a joint estimate over many flights).
    pub(crate) fn with_estimate(self, theta: ShapeVector, covariance: ShapeCovariance) -> Self {
        Self {
            theta,
            covariance,
            ..self
        }
    }

    /// theta_g and P_g as learned (an undetermined exponent as well, [`Self::settled`] not
    /// applied).
    pub(crate) fn estimate(&self) -> (ShapeVector, ShapeCovariance) {
        (self.theta, self.covariance)
    }

    /// D, the flight-to-flight dispersion (variances).
    pub(crate) fn dispersion(&self) -> ParamVector {
        self.dispersion
    }

    /// theta_g and P_g of the ball's and table's parameters, as the tracks use them
    /// ([`Self::settled`]).
    pub(crate) fn global(&self) -> (ParamVector, ParamCovariance) {
        let (theta, covariance) = self.settled(&self.covariance);
        (
            theta.fixed_rows::<PARAMS>(0).into_owned(),
            covariance.fixed_view::<PARAMS, PARAMS>(0, 0).into_owned(),
        )
    }

    /// The Reynolds exponents (a_D, a_M) the tracks fly with ([`Self::settled`]).
    pub(crate) fn exponents(&self) -> [f64; 2] {
        let theta = self.settled(&self.covariance).0;
        [theta[DRAG_EXPONENT], theta[MAGNUS_EXPONENT]]
    }

    /// Whether the flights have determined the exponent at `index` ([`exponent_determined`]).
    fn determined(&self, index: usize) -> bool {
        exponent_determined(
            self.covariance[(index, index)].max(0.0).sqrt(),
            self.prior_var[index].max(0.0).sqrt(),
        )
    }

    /// theta_g with `covariance` (P_g, or P_g drifted) as the tracks use them: each adapted
    /// exponent the flights have not determined set to its prior a_0 and the rest conditioned
    /// on it, theta + P_.a (a_0 - a) / P_aa and P - P_.a P_a. / P_aa.
    fn settled(&self, covariance: &ShapeCovariance) -> (ShapeVector, ShapeCovariance) {
        let (mut theta, mut covariance) = (self.theta, *covariance);
        for i in [DRAG_EXPONENT, MAGNUS_EXPONENT] {
            let variance = covariance[(i, i)];
            if self.prior_var[i] <= 0.0 || self.determined(i) || variance <= 0.0 {
                continue;
            }
            let gain = covariance.column(i) / variance;
            theta += gain * (self.prior[i] - theta[i]);
            theta[i] = self.prior[i];
            covariance -= gain * covariance.row(i);
        }
        (theta, covariance)
    }

    /// The exponents' standard deviations now and before any track.
    pub(crate) fn exponent_sigmas(&self) -> ([f64; 2], [f64; 2]) {
        let sigma = |v: f64| v.max(0.0).sqrt();
        let at = [DRAG_EXPONENT, MAGNUS_EXPONENT];
        (
            at.map(|i| sigma(self.covariance[(i, i)])),
            at.map(|i| sigma(self.prior_var[i])),
        )
    }

    /// Tracks that contributed.
    pub(crate) fn tracks(&self) -> u64 {
        self.tracks
    }

    /// P_g at `stamp`: grown by the drift since it was learned, at most back to the prior.
    fn drifted(&self, stamp: i64) -> ShapeCovariance {
        let mut covariance = self.covariance;
        let Some(then) = self.stamp else {
            return covariance;
        };
        let dt = ((stamp - then) as f64 * 1e-9).max(0.0);
        for i in (0..SHAPE).filter(|&i| self.prior_var[i] > 0.0) {
            let grown = covariance[(i, i)] + self.drift_density[i] * dt;
            let prior = self.prior_var[i];
            if grown > prior && covariance[(i, i)] > 0.0 {
                // Back to the prior's variance, the correlations kept.
                let factor = (prior / covariance[(i, i)]).sqrt();
                for j in 0..SHAPE {
                    covariance[(i, j)] *= factor;
                    covariance[(j, i)] *= factor;
                }
            } else {
                covariance[(i, i)] = grown;
            }
        }
        covariance
    }

    /// The prior of a track starting at `stamp`: theta_g, P_g (drifted) + D, as the tracks use
    /// them ([`Self::settled`]).
    pub(crate) fn track_prior(&self, stamp: i64) -> (ParamVector, ParamCovariance) {
        let (theta, drifted) = self.settled(&self.drifted(stamp));
        (
            theta.fixed_rows::<PARAMS>(0).into_owned(),
            drifted.fixed_view::<PARAMS, PARAMS>(0, 0).into_owned()
                + ParamCovariance::from_diagonal(&self.dispersion),
        )
    }

    /// theta_g and P_g updated with what a track `lesson` learned (see the module doc). Its
    /// prior is compared at the end, grown by the drift the track's filter added on the way:
    /// what the track learned is the difference.
    pub(crate) fn absorbed(&self, lesson: &Lesson) -> Self {
        let elapsed = ((lesson.ended - lesson.started) as f64 * 1e-9).max(0.0);
        let drift = self.drift_density.fixed_rows::<PARAMS>(0) * elapsed;
        let prior = (
            lesson.prior.0,
            lesson.prior.1 + ParamCovariance::from_diagonal(&drift),
        );
        let (mut theta, mut covariance) = self
            .fuse(&prior, &lesson.posterior, &lesson.flown, lesson.ended)
            .unwrap_or_else(|| self.replaced_by(&lesson.posterior));
        for i in (0..SHAPE).filter(|&i| self.prior_var[i] <= 0.0) {
            theta[i] = self.theta[i];
            for j in 0..SHAPE {
                covariance[(i, j)] = 0.0;
                covariance[(j, i)] = 0.0;
            }
        }
        Self {
            theta,
            covariance: (covariance + covariance.transpose()) * 0.5,
            stamp: Some(lesson.ended),
            tracks: self.tracks + 1,
            ..*self
        }
    }

    /// The track's posterior in place of the ball's and table's parameters, the exponents kept
    /// (when the equations fail on a singular matrix).
    fn replaced_by(
        &self,
        (theta, covariance): &(ParamVector, ParamCovariance),
    ) -> (ShapeVector, ShapeCovariance) {
        let mut replaced = (self.theta, self.covariance);
        replaced.0.fixed_rows_mut::<PARAMS>(0).copy_from(theta);
        replaced.1.fixed_view_mut::<PARAMS, SHAPE>(0, 0).fill(0.0);
        replaced.1.fixed_view_mut::<SHAPE, PARAMS>(0, 0).fill(0.0);
        replaced
            .1
            .fixed_view_mut::<PARAMS, PARAMS>(0, 0)
            .copy_from(covariance);
        replaced
    }

    /// A flight's parameters as a function of the learned ones, linearised at `at`: the
    /// flight that flew with exponents a_f at speeds of mean ln f(Re) = L has the scales
    /// k_f = k_g exp((a_g - a_f) L); its table is the table's. The value at `at` and the
    /// derivative (zero for an exponent that is not adapted).
    fn flight_params(&self, at: &ShapeVector, flown: &Flown) -> (ParamVector, FlightMap) {
        let mut value = at.fixed_rows::<PARAMS>(0).into_owned();
        let mut map = FlightMap::identity();
        for ((scale, exponent), a_f) in
            [(DRAG_SCALE, DRAG_EXPONENT), (MAGNUS_SCALE, MAGNUS_EXPONENT)]
                .into_iter()
                .zip(flown.exponents)
        {
            let factor = ((at[exponent] - a_f) * flown.log_f).exp();
            value[scale] = at[scale] * factor;
            map[(scale, scale)] = factor;
            if self.prior_var[exponent] > 0.0 {
                map[(scale, exponent)] = value[scale] * flown.log_f;
            }
        }
        (value, map)
    }

    /// The two-level update in information form, the track's parameters linearised in the
    /// learned ones ([`Self::flight_params`]) at the updated estimate (iterated from theta_g,
    /// Gauss-Newton: scales and exponents trade along a curve, and tangents taken at points
    /// apart on it would cross, a determination the flights never gave); `None` when a matrix
    /// is singular.
    fn fuse(
        &self,
        (theta_prior, p_prior): &(ParamVector, ParamCovariance),
        (theta_track, p_track): &(ParamVector, ParamCovariance),
        flown: &Flown,
        stamp: i64,
    ) -> Option<(ShapeVector, ShapeCovariance)> {
        // The parameters not adapted stand in as unit variances that learn nothing.
        let active = |i: usize| self.prior_var[i] > 0.0;
        let fill = |i: usize, j: usize, value: f64| {
            if active(i) && active(j) {
                value
            } else if i == j {
                1.0
            } else {
                0.0
            }
        };
        let drifted = self.drifted(stamp);
        let p_global = ShapeCovariance::from_fn(|i, j| fill(i, j, drifted[(i, j)]));
        let fill_flight =
            |m: &ParamCovariance| ParamCovariance::from_fn(|i, j| fill(i, j, m[(i, j)]));
        let info_prior = fill_flight(p_prior).try_inverse()?;
        let info_track = fill_flight(p_track).try_inverse()?;
        let info_global = p_global.try_inverse()?;
        // J, made positive semidefinite (the drift inside a track can leave it slightly
        // negative where the track learned nothing).
        let j = positive_part(&(info_track - info_prior));
        let b = info_track * theta_track - info_prior * theta_prior;
        let d = ParamCovariance::from_diagonal(&self.dispersion);
        let shrink = (ParamCovariance::identity() + j * d).try_inverse()?;
        let j_flight = shrink * j;
        let j_flight = (j_flight + j_flight.transpose()) * 0.5;
        let mut updated = (self.theta, p_global);
        for _ in 0..LINEARISATIONS {
            let (value, map) = self.flight_params(&updated.0, flown);
            let offset = value - map * updated.0;
            let information = info_global + map.transpose() * j_flight * map;
            let covariance = information.try_inverse()?;
            let theta = covariance
                * (info_global * self.theta + map.transpose() * (shrink * (b - j * offset)));
            updated = (theta, covariance);
        }
        updated
            .0
            .iter()
            .chain(updated.1.iter())
            .all(|v| v.is_finite())
            .then_some(updated)
    }
}

/// The positive part of a symmetric matrix (its negative eigenvalues set to zero).
fn positive_part(m: &ParamCovariance) -> ParamCovariance {
    let eigen = SymmetricEigen::new((m + m.transpose()) * 0.5);
    let clipped = eigen.eigenvalues.map(|v| v.max(0.0));
    eigen.eigenvectors * ParamCovariance::from_diagonal(&clipped) * eigen.eigenvectors.transpose()
}

/// The prior variances of the learned physical parameters (`adaptation.*_sigma` squared; zero,
/// not adapted, without the adaptation).
fn param_prior_variances(config: &Config) -> ParamVector {
    let adaptation = &config.adaptation;
    let sigmas = ParamVector::from_fn(|i, _| AdaptationParams::of(&adaptation.sigma, i))
        * if adaptation.enabled { 1.0 } else { 0.0 };
    sigmas.component_mul(&sigmas)
}

/// The configured learned parameters: the ball's and table's, then the Reynolds exponents.
pub(crate) fn configured_shape(config: &Config) -> ShapeVector {
    shape_vector(
        &PhysicsParams::from_config(config).to_vector(),
        FlightModel::new(config).reynolds_exponents(),
    )
}

/// The learned parameters of the ball's and table's `params` and the Reynolds `exponents`.
fn shape_vector(params: &ParamVector, [a_d, a_m]: [f64; 2]) -> ShapeVector {
    let mut v = ShapeVector::zeros();
    v.fixed_rows_mut::<PARAMS>(0).copy_from(params);
    v[DRAG_EXPONENT] = a_d;
    v[MAGNUS_EXPONENT] = a_m;
    v
}

/// The prior variances of the learned parameters: [`param_prior_variances`], then the
/// Reynolds exponents' (`adaptation.reynolds_sigma` squared).
pub(crate) fn shape_prior_variances(config: &Config) -> ShapeVector {
    let on = if config.adaptation.enabled { 1.0 } else { 0.0 };
    let variance = |k| (AdaptationParams::of(&config.adaptation.reynolds_sigma, k) * on).powi(2);
    shape_vector(&param_prior_variances(config), [variance(0), variance(1)])
}

/// The random walk's density of each parameter [unit^2/s]: its prior variance drifting over
/// `adaptation.drift_per_hour` of it an hour.
pub(crate) fn drift_density(config: &Config) -> ParamVector {
    shape_drift_density(config)
        .fixed_rows::<PARAMS>(0)
        .into_owned()
}

fn shape_drift_density(config: &Config) -> ShapeVector {
    let drift = config.adaptation.drift_per_hour;
    shape_prior_variances(config) * (drift * drift / 3600.0)
}

/// What the estimator learns across tracks (see the module doc): the physical parameters, each
/// camera's noise, and the lessons of the ended tracks on their way in.
#[derive(Debug, Clone)]
pub(crate) struct Adaptation {
    /// The ball's and table's parameters.
    pub(crate) physics: Learned,
    /// Each camera's noise.
    pub(crate) cameras: NoiseLearner,
    /// The ended tracks' lessons on their way in.
    pub(crate) lessons: Lessons,
}

impl Adaptation {
    /// Nothing learned yet: the configured values.
    pub(crate) fn new(config: &Config) -> Self {
        let flight = &config.adaptation.flight_sigma;
        let dispersion = ParamVector::from_fn(|i, _| AdaptationParams::of(flight, i));
        Self {
            physics: Learned::new(
                configured_shape(config),
                shape_prior_variances(config),
                shape_drift_density(config),
                dispersion.component_mul(&dispersion),
            ),
            cameras: NoiseLearner::new(config),
            lessons: Lessons::new(),
        }
    }

    /// The physics with the lessons still waiting learned as far as they are known
    /// ([`Lessons::waiting`]): what a learned file holds between two lessons' due points.
    pub(crate) fn physics_with_waiting_lessons(&self) -> Learned {
        self.lessons
            .waiting()
            .fold(self.physics, |learned, l| learned.absorbed(&l))
    }

    /// A track's lesson learned now.
    fn absorb(&mut self, lesson: &Lesson) {
        self.physics = self.physics.absorbed(lesson);
    }

    /// A track has ended, at the detection stamped `now`: its flight to smooth, off the
    /// detection path ([`super::lessons`]), or the filter's lesson to learn now.
    pub(crate) fn track_ended(&mut self, ended: Result<LessonJob, Lesson>, now: i64) {
        let now_lesson = match ended {
            Ok(job) => self.lessons.queue(job, now),
            Err(lesson) => Some(lesson),
        };
        if let Some(lesson) = now_lesson {
            self.absorb(&lesson);
        }
    }

    /// Learns the lessons due before a detection stamped `stamp`.
    pub(crate) fn learn_due(&mut self, stamp: i64) {
        while let Some(lesson) = self.lessons.next_due(stamp, false) {
            self.absorb(&lesson);
        }
    }

    /// Learns every lesson still waiting (the input's end).
    pub(crate) fn settle(&mut self) {
        while let Some(lesson) = self.lessons.next_due(i64::MAX, true) {
            self.absorb(&lesson);
        }
    }

    /// Forgets what was learned and the lessons waiting, as a new adaptation of `config` would
    /// start, keeping the lessons' counts and their worker.
    pub(crate) fn reset(&mut self, config: &Config) {
        let mut lessons = std::mem::replace(&mut self.lessons, Lessons::new());
        lessons.forget();
        *self = Self::new(config);
        self.lessons = lessons;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn learned(dispersion: f64) -> Learned {
        Learned::new(
            ShapeVector::from_row_slice(&[1.0, 1.0, 0.9, 0.25, 0.0, -0.65]),
            ShapeVector::from_row_slice(&[0.01, 0.04, 0.0, 0.01, 0.0, 0.0]),
            ShapeVector::zeros(),
            ParamVector::new(dispersion, dispersion, 0.0, 0.0),
        )
    }

    /// The lesson of a track that started from `prior` and ended at `posterior`, between
    /// `started` and `ended`, flown with the learned exponents at speeds of ln f(Re) = 0.
    fn lesson(
        prior: (ParamVector, ParamCovariance),
        posterior: (ParamVector, ParamCovariance),
        started: i64,
        ended: i64,
    ) -> Lesson {
        Lesson {
            prior,
            posterior,
            started,
            ended,
            smoothed: false,
            flown: Flown {
                exponents: [0.0, -0.65],
                log_f: 0.0,
            },
        }
    }

    /// Without dispersion the global estimate becomes the track's posterior; the parameter that
    /// is not adapted stays as configured with zero variance.
    #[test]
    fn without_dispersion_the_track_posterior_is_taken() {
        let l = learned(0.0);
        let prior = l.track_prior(0);
        assert_eq!(
            prior.1,
            ParamCovariance::from_diagonal(&l.prior_var.fixed_rows::<PARAMS>(0))
        );
        let mut p_track = prior.1 * 0.25;
        p_track[(0, 1)] = 0.0005;
        p_track[(1, 0)] = 0.0005;
        let posterior = (ParamVector::new(1.1, 0.7, 0.9, 0.3), p_track);
        let next = l.absorbed(&lesson(prior, posterior, 0, 1_000_000_000));
        let (theta, covariance) = next.global();
        assert!((theta - posterior.0).norm() < 1e-9, "{theta}");
        assert!((covariance - posterior.1).norm() < 1e-9);
        assert_eq!(next.theta[2], 0.9);
        assert_eq!(next.covariance[(2, 2)], 0.0);
        assert_eq!(next.tracks(), 1);
    }

    /// With a dispersion, one track moves the global estimate only part of the way, by the
    /// scalar two-level formula: gain P_g / (P_g + D + R), R the track's own measurement noise.
    #[test]
    fn with_dispersion_a_track_moves_the_global_estimate_part_of_the_way() {
        let l = learned(0.02);
        let prior = l.track_prior(0);
        // The track measured k_M = 0.6 with variance R = 0.01 (scalar Kalman update of its prior).
        let (p_pr, r) = (prior.1[(1, 1)], 0.01);
        let gain_track = p_pr / (p_pr + r);
        let mut posterior = prior;
        posterior.0[1] = 1.0 + gain_track * (0.6 - 1.0);
        posterior.1[(1, 1)] = (1.0 - gain_track) * p_pr;
        let next = l.absorbed(&lesson(prior, posterior, 0, 0));
        let (p_g, d) = (0.04, 0.02);
        let gain = p_g / (p_g + d + r);
        assert!((next.theta[1] - (1.0 + gain * (0.6 - 1.0))).abs() < 1e-9);
        assert!((next.covariance[(1, 1)] - (1.0 - gain) * p_g).abs() < 1e-9);
        // The other parameters learned nothing and stay.
        assert!((next.theta[0] - 1.0).abs() < 1e-12);
        assert!((next.covariance[(0, 0)] - 0.01).abs() < 1e-12);
    }

    /// A track that learned nothing (its filter only added the drift on the way) leaves the
    /// global estimate where it was, however long it ran.
    #[test]
    fn a_track_that_learned_nothing_moves_nothing() {
        let mut l = learned(0.01);
        l.drift_density = ShapeVector::from_row_slice(&[1e-6, 1e-6, 0.0, 1e-6, 0.0, 0.0]);
        let prior = l.track_prior(0);
        let seconds = 2.0;
        let posterior = (
            prior.0,
            prior.1
                + ParamCovariance::from_diagonal(
                    &(l.drift_density.fixed_rows::<PARAMS>(0) * seconds),
                ),
        );
        let next = l.absorbed(&lesson(prior, posterior, 0, 2_000_000_000));
        assert!(
            (next.theta - l.theta).norm() < 1e-12,
            "{}",
            next.theta - l.theta
        );
    }

    /// What a track flown with `l`'s exponents at speeds of ln f(Re) = `log_f` learns of a ball
    /// of Magnus scale 0.6 and exponent -1.0: k_f = 0.6 exp((-1.0 - a_flown) log_f), measured
    /// to a variance of 1e-4.
    fn track_of_a_ball(l: &Learned, log_f: f64, ended: i64) -> Lesson {
        let (k_true, a_true) = (0.6, -1.0);
        let flown = l.exponents();
        let measured = k_true * ((a_true - flown[1]) * log_f).exp();
        let prior = l.track_prior(ended);
        let p = prior.1;
        let innovation_var = p[(1, 1)] + 1e-4;
        let gain = p.column(1) / innovation_var;
        let posterior = (
            prior.0 + gain * (measured - prior.0[1]),
            p - gain * p.row(1),
        );
        Lesson {
            flown: Flown {
                exponents: flown,
                log_f,
            },
            ..lesson(prior, posterior, ended, ended)
        }
    }

    /// An adaptation that learns the Magnus exponent a_M (prior -0.65 +- 0.3) and not a_D.
    fn learning_the_magnus_exponent() -> Learned {
        Learned::new(
            ShapeVector::from_row_slice(&[1.0, 0.7, 0.9, 0.25, 0.0, -0.65]),
            ShapeVector::from_row_slice(&[0.01, 0.16, 0.0, 0.01, 0.0, 0.09]),
            ShapeVector::zeros(),
            ParamVector::new(0.0, 0.0001, 0.0, 0.0),
        )
    }

    /// Flights at 5 m/s (ln f = 0) and at 15 m/s (ln f = 1) teach one model: the Magnus scale
    /// at Re_0 and the exponent, each within 2 % of the ball's.
    #[test]
    fn slow_and_fast_flights_teach_the_magnus_exponent() {
        let mut l = learning_the_magnus_exponent();
        for track in 0..40 {
            let log_f = if track % 2 == 0 { 0.0 } else { 1.0 };
            l = l.absorbed(&track_of_a_ball(&l, log_f, track * 1_000_000_000));
        }
        let (theta, _) = l.global();
        assert!((theta[1] - 0.6).abs() < 0.012, "{theta}");
        assert!((l.exponents()[1] + 1.0).abs() < 0.02, "{:?}", l.exponents());
        let (sigma, prior) = l.exponent_sigmas();
        assert!(sigma[1] < 0.2 * prior[1], "{sigma:?}");
        // a_D, not adapted, stays as configured.
        assert_eq!((l.exponents()[0], sigma[0]), (0.0, 0.0));
    }

    /// Flights all below Re_0 (ln f = 0) say nothing of the exponent: it stays at its prior,
    /// with its prior's sigma, and the scale learns alone.
    #[test]
    fn slow_flights_alone_leave_the_exponent_at_its_prior() {
        let mut l = learning_the_magnus_exponent();
        for track in 0..20 {
            l = l.absorbed(&track_of_a_ball(&l, 0.0, track * 1_000_000_000));
        }
        assert!((l.global().0[1] - 0.6).abs() < 0.01);
        assert!(
            (l.exponents()[1] + 0.65).abs() < 1e-12,
            "{:?}",
            l.exponents()
        );
        let (sigma, prior) = l.exponent_sigmas();
        assert!((sigma[1] - prior[1]).abs() < 1e-9, "{sigma:?}");
    }

    /// Flights of one speed above Re_0 (ln f = 0.3) determine the Magnus force at that speed,
    /// not the exponent: its sigma stays near its prior's (the update's linearisations do not
    /// cross), it stays at its prior where used, and the scale conditioned on it reproduces the
    /// flights' force.
    #[test]
    fn flights_of_one_speed_leave_the_exponent_at_its_prior_and_keep_their_force() {
        let mut l = learning_the_magnus_exponent();
        for track in 0..20 {
            l = l.absorbed(&track_of_a_ball(&l, 0.3, track * 1_000_000_000));
        }
        let (sigma, prior) = l.exponent_sigmas();
        assert!(sigma[1] > 0.95 * prior[1], "{sigma:?}");
        assert!((l.exponents()[1] + 0.65).abs() < 1e-12);
        let at_their_speed = 0.6 * ((-1.0f64 + 0.65) * 0.3).exp();
        let (theta, covariance) = l.global();
        assert!((theta[1] - at_their_speed).abs() < 0.005, "{theta}");
        assert!(covariance[(1, 1)] < l.covariance[(1, 1)]);
    }

    #[test]
    fn the_drift_grows_the_variance_up_to_the_prior() {
        let mut l = learned(0.0);
        l.drift_density = ShapeVector::from_row_slice(&[1e-6, 1e-6, 1e-6, 1e-6, 0.0, 0.0]);
        l.covariance = ShapeCovariance::from_diagonal(&ShapeVector::from_row_slice(&[
            0.001, 0.001, 0.0, 0.001, 0.0, 0.0,
        ]));
        l.stamp = Some(0);
        let an_hour = 3_600_000_000_000;
        let grown = l.drifted(an_hour);
        assert!((grown[(0, 0)] - (0.001 + 0.0036)).abs() < 1e-12);
        assert_eq!(grown[(2, 2)], 0.0);
        let much_later = l.drifted(100 * an_hour);
        assert!((much_later[(1, 1)] - 0.04).abs() < 1e-12);
        assert!((much_later[(0, 0)] - 0.01).abs() < 1e-12);
    }
}
