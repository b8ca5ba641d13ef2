//! What the estimator learns across tracks: the physical parameters of this ball and table
//! (a two-level model) and each camera's noise ([`super::camera_noise`]).
//!
//! Each flight has its own parameters theta_f (its ball, its spin axis, the part of the table it
//! hits), scattered about the global ones theta_g of this ball and table: theta_f = theta_g + d,
//! d ~ N(0, D), D the configured flight-to-flight dispersion (`adaptation.flight_sigma`).
//! theta_g follows a slow random walk (`adaptation.drift_per_hour`), its variance capped at the
//! prior's.
//!
//! - A track starts its filter at theta_g with covariance P_g (drifted) + D: the filter learns
//!   its own flight's parameters, beside its state.
//! - When it ends, what it learned (its lesson: its flight smoothed, [`super::smoother`], or the
//!   filter's own estimate) updates theta_g. Its posterior N(theta_t, P_t) over its prior
//!   N(theta_g, P_pr) is the likelihood of theta_f with information J = P_t^-1 - P_pr^-1 and
//!   information-weighted mean b = P_t^-1 theta_t - P_pr^-1 theta_g; as a likelihood of theta_g
//!   (theta_f = theta_g + d) its information is J_g = (I + J D)^-1 J and its weighted mean
//!   (I + J D)^-1 b. So P_g'^-1 = P_g^-1 + J_g and theta_g' = P_g' (P_g^-1 theta_g +
//!   (I + J D)^-1 b). With D = 0 this is the track's posterior itself.
//!
//! Parameters with a zero prior sigma are not adapted: they keep their configured value and a
//! zero variance throughout.

use nalgebra::SymmetricEigen;

use super::camera_noise::NoiseLearner;
use super::lessons::Lessons;
use super::smoother::{Lesson, LessonJob};
use crate::config::{AdaptationParams, Config};
use crate::online::ekf::ParamCovariance;
use crate::physics::{PARAMS, ParamVector, PhysicsParams};

/// What the estimator knows of the physical parameters between tracks.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Learned {
    /// theta_g.
    theta: ParamVector,
    /// P_g.
    covariance: ParamCovariance,
    /// When they were last learned [ns]; `None` before any track.
    stamp: Option<i64>,
    /// Tracks that contributed.
    tracks: u64,
    /// The prior variances (zero: not adapted).
    prior_var: ParamVector,
    /// The random walk's density [unit^2/s].
    drift_density: ParamVector,
    /// D, the flight-to-flight dispersion (diagonal).
    dispersion: ParamVector,
}

impl Learned {
    /// Nothing learned yet: the configured `prior` with its variances.
    pub(crate) fn new(
        prior: ParamVector,
        prior_var: ParamVector,
        drift_density: ParamVector,
        dispersion: ParamVector,
    ) -> Self {
        let active = |v: &ParamVector| {
            ParamVector::from_fn(|i, _| if prior_var[i] > 0.0 { v[i] } else { 0.0 })
        };
        Self {
            theta: prior,
            covariance: ParamCovariance::from_diagonal(&prior_var),
            stamp: None,
            tracks: 0,
            prior_var,
            drift_density: active(&drift_density),
            dispersion: active(&dispersion),
        }
    }

    /// D, the flight-to-flight dispersion (variances).
    pub(crate) fn dispersion(&self) -> ParamVector {
        self.dispersion
    }

    /// theta_g and P_g.
    pub(crate) fn global(&self) -> (ParamVector, ParamCovariance) {
        (self.theta, self.covariance)
    }

    /// Tracks that contributed.
    pub(crate) fn tracks(&self) -> u64 {
        self.tracks
    }

    /// P_g at `stamp`: grown by the drift since it was learned, at most back to the prior.
    fn drifted(&self, stamp: i64) -> ParamCovariance {
        let mut covariance = self.covariance;
        let Some(then) = self.stamp else {
            return covariance;
        };
        let dt = ((stamp - then) as f64 * 1e-9).max(0.0);
        for i in (0..PARAMS).filter(|&i| self.prior_var[i] > 0.0) {
            let grown = covariance[(i, i)] + self.drift_density[i] * dt;
            let prior = self.prior_var[i];
            if grown > prior && covariance[(i, i)] > 0.0 {
                // Back to the prior's variance, the correlations kept.
                let factor = (prior / covariance[(i, i)]).sqrt();
                for j in 0..PARAMS {
                    covariance[(i, j)] *= factor;
                    covariance[(j, i)] *= factor;
                }
            } else {
                covariance[(i, i)] = grown;
            }
        }
        covariance
    }

    /// The prior of a track starting at `stamp`: theta_g, P_g (drifted) + D.
    pub(crate) fn track_prior(&self, stamp: i64) -> (ParamVector, ParamCovariance) {
        (
            self.theta,
            self.drifted(stamp) + ParamCovariance::from_diagonal(&self.dispersion),
        )
    }

    /// theta_g and P_g updated with what a track that started from `prior` (its
    /// [`Self::track_prior`]) at `started` and ended at `posterior` at `stamp` learned (see the
    /// module doc). The prior is compared at the end, grown by the drift the track's filter
    /// added on the way: what the track learned is the difference.
    pub(crate) fn absorbed(
        &self,
        prior: &(ParamVector, ParamCovariance),
        posterior: &(ParamVector, ParamCovariance),
        started: i64,
        stamp: i64,
    ) -> Self {
        let elapsed = ((stamp - started) as f64 * 1e-9).max(0.0);
        let prior = (
            prior.0,
            prior.1 + ParamCovariance::from_diagonal(&(self.drift_density * elapsed)),
        );
        // The equations failed (a singular matrix): the track's posterior.
        let updated = self.fuse(&prior, posterior, stamp).unwrap_or(*posterior);
        let active = |i: usize| self.prior_var[i] > 0.0;
        let mut theta = updated.0;
        let mut covariance = updated.1;
        for i in 0..PARAMS {
            if !active(i) {
                theta[i] = self.theta[i];
                for j in 0..PARAMS {
                    covariance[(i, j)] = 0.0;
                    covariance[(j, i)] = 0.0;
                }
            }
        }
        Self {
            theta,
            covariance: (covariance + covariance.transpose()) * 0.5,
            stamp: Some(stamp),
            tracks: self.tracks + 1,
            ..*self
        }
    }

    /// The two-level update in information form; `None` when a matrix is singular.
    fn fuse(
        &self,
        (theta_prior, p_prior): &(ParamVector, ParamCovariance),
        (theta_track, p_track): &(ParamVector, ParamCovariance),
        stamp: i64,
    ) -> Option<(ParamVector, ParamCovariance)> {
        // The parameters not adapted stand in as unit variances that learn nothing.
        let active = |i: usize| self.prior_var[i] > 0.0;
        let fill = |m: &ParamCovariance| {
            ParamCovariance::from_fn(|i, j| {
                if active(i) && active(j) {
                    m[(i, j)]
                } else if i == j {
                    1.0
                } else {
                    0.0
                }
            })
        };
        let p_global = fill(&self.drifted(stamp));
        let info_prior = fill(p_prior).try_inverse()?;
        let info_track = fill(p_track).try_inverse()?;
        let info_global = p_global.try_inverse()?;
        // J, made positive semidefinite (the drift inside a track can leave it slightly
        // negative where the track learned nothing).
        let j = positive_part(&(info_track - info_prior));
        let b = info_track * theta_track - info_prior * theta_prior;
        let d = ParamCovariance::from_diagonal(&self.dispersion);
        let shrink = (ParamCovariance::identity() + j * d).try_inverse()?;
        let j_global = shrink * j;
        let covariance = (info_global + (j_global + j_global.transpose()) * 0.5).try_inverse()?;
        let theta = covariance * (info_global * self.theta + shrink * b);
        theta
            .iter()
            .chain(covariance.iter())
            .all(|v| v.is_finite())
            .then_some((theta, covariance))
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
pub(crate) fn param_prior_variances(config: &Config) -> ParamVector {
    let adaptation = &config.adaptation;
    let sigmas = ParamVector::from_fn(|i, _| AdaptationParams::of(&adaptation.sigma, i))
        * if adaptation.enabled { 1.0 } else { 0.0 };
    sigmas.component_mul(&sigmas)
}

/// The random walk's density of each parameter [unit^2/s]: its prior variance drifting over
/// `adaptation.drift_per_hour` of it an hour.
pub(crate) fn drift_density(config: &Config) -> ParamVector {
    let drift = config.adaptation.drift_per_hour;
    param_prior_variances(config) * (drift * drift / 3600.0)
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
                PhysicsParams::from_config(config).to_vector(),
                param_prior_variances(config),
                drift_density(config),
                dispersion.component_mul(&dispersion),
            ),
            cameras: NoiseLearner::new(config),
            lessons: Lessons::new(),
        }
    }

    /// The physics with the lessons still waiting learned as far as they are known
    /// ([`Lessons::waiting`]): what a learned file holds between two lessons' due points.
    pub(crate) fn physics_with_waiting_lessons(&self) -> Learned {
        self.lessons.waiting().fold(self.physics, |learned, l| {
            learned.absorbed(&l.prior, &l.posterior, l.started, l.ended)
        })
    }

    /// A track's lesson learned now.
    fn absorb(&mut self, lesson: &Lesson) {
        self.physics = self.physics.absorbed(
            &lesson.prior,
            &lesson.posterior,
            lesson.started,
            lesson.ended,
        );
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
            ParamVector::new(1.0, 1.0, 0.9, 0.25),
            ParamVector::new(0.01, 0.04, 0.0, 0.01),
            ParamVector::zeros(),
            ParamVector::new(dispersion, dispersion, 0.0, 0.0),
        )
    }

    /// Without dispersion the global estimate becomes the track's posterior; the parameter that
    /// is not adapted stays as configured with zero variance.
    #[test]
    fn without_dispersion_the_track_posterior_is_taken() {
        let l = learned(0.0);
        let prior = l.track_prior(0);
        assert_eq!(prior.1, ParamCovariance::from_diagonal(&l.prior_var));
        let mut p_track = prior.1 * 0.25;
        p_track[(0, 1)] = 0.0005;
        p_track[(1, 0)] = 0.0005;
        let posterior = (ParamVector::new(1.1, 0.7, 0.9, 0.3), p_track);
        let next = l.absorbed(&prior, &posterior, 0, 1_000_000_000);
        assert!((next.theta - posterior.0).norm() < 1e-9, "{}", next.theta);
        assert!((next.covariance - posterior.1).norm() < 1e-9);
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
        let next = l.absorbed(&prior, &posterior, 0, 0);
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
        l.drift_density = ParamVector::new(1e-6, 1e-6, 0.0, 1e-6);
        let prior = l.track_prior(0);
        let seconds = 2.0;
        let posterior = (
            prior.0,
            prior.1 + ParamCovariance::from_diagonal(&(l.drift_density * seconds)),
        );
        let next = l.absorbed(&prior, &posterior, 0, 2_000_000_000);
        assert!(
            (next.theta - l.theta).norm() < 1e-12,
            "{}",
            next.theta - l.theta
        );
    }

    #[test]
    fn the_drift_grows_the_variance_up_to_the_prior() {
        let mut l = learned(0.0);
        l.drift_density = ParamVector::new(1e-6, 1e-6, 1e-6, 1e-6);
        l.covariance = ParamCovariance::from_diagonal(&ParamVector::new(0.001, 0.001, 0.0, 0.001));
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
