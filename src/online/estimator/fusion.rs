//! How one detection moves an estimate (docs/estimator.md, "The filter"): the estimate flown to
//! the detection's stamp ([`Ekf::predict`]), the measurement as the estimate sees it (the
//! table contact's extra noise within [`CONTACT_BAND`], the stamp's timing noise R + tau v v'),
//! the partial update of the spin along the flight ([`SPIN_ALONG_FLIGHT_GAIN`]) and a measured
//! spin that contradicts the filter's. Shared by the tracker and the smoother, so that a
//! track's lesson flies the filter's model.

use nalgebra::{Matrix3, Matrix6, SVector, Vector3};

use crate::config::Config;
use crate::model::stats::chi_square_quantile;
use crate::online::ekf::{
    BounceNoise, Ekf, FilterNoise, ProcessNoise, UpdateError, position_H, position_spin_H,
};
use crate::online::measurement::Measurement;
use crate::physics::{ParamVector, Propagator, StateVector};

/// How close to its contact height [m] a ball is in contact with the table in the camera's
/// eyes: its detections there get the extra noise `ekf.contact_position_sigma` (one ball
/// diameter: the ball's image meets its reflection and shadow on the surface).
pub const CONTACT_BAND: f64 = 0.04;

/// How close to its contact height [m] a ball is "at the table": a spin measured there that
/// contradicts the estimate's may be of the other side of the bounce and is not used (1.5 cm is
/// 5 ms of a ball falling at 3 m/s).
const BOUNCE_SPIN_MARGIN: f64 = 0.015;

/// How far from the table's edge [m] an estimate's bounce is a close call: the tracker tries
/// the table grown and shrunk by as much.
pub(super) const EDGE_MARGIN: f64 = 0.02;

/// The share of a position's gain the filter applies to the spin along the flight before the
/// track's first bounce (the partial update, Brink 2017). On the real launcher flights the whole
/// gain (1) predicts the crossing 100 ms ahead worse (docs/estimator.md, "What each part is kept
/// for").
pub const SPIN_ALONG_FLIGHT_GAIN: f64 = 0.7;

/// kappa: the filter's prediction evaluates C_D and C_M at the spin parameter of
/// sqrt(|w_perp|^2 + kappa^2 tr P_w_perp), the spin's magnitude across the flight widened by
/// kappa times its spread, instead of its estimate's. A spin learned from curvature starts at
/// zero, the smallest magnitude a spin can have; the forces of the spins it may be are those of
/// a larger one. On the real launcher flights kappa = 0 predicts the crossing worse at 200 and
/// at 100 ms lead (docs/estimator.md, "What each part is kept for").
pub const SPIN_PARAMETER_SPREAD: f64 = 0.5;

/// The estimate at one time, with what the track knows at that time.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Snapshot {
    pub(crate) ekf: Ekf,
    pub(crate) stamp: i64,
    pub(crate) bounces: u32,
    pub(crate) robot_half_bounces: u32,
    pub(crate) last_fused: i64,
    /// The NIS of the last fused update.
    pub(crate) nis: f64,
    /// That detection's whole measurement's NIS ([`Fused::whole_nis`]).
    pub(crate) whole_nis: f64,
    /// The state change of the last bounce the filter flew the estimate through.
    pub(crate) bounce_jump: Option<StateVector>,
    /// Whether the track's spin has been measured (a spin camera's detection fused, or fitted
    /// at the start).
    pub(crate) spin_measured: bool,
}

impl Snapshot {
    /// A track's first estimate, at `stamp`.
    pub(crate) fn starting(ekf: Ekf, stamp: i64, spin_measured: bool) -> Self {
        Self {
            ekf,
            stamp,
            bounces: 0,
            robot_half_bounces: 0,
            last_fused: stamp,
            nis: 0.0,
            whole_nis: 0.0,
            bounce_jump: None,
            spin_measured,
        }
    }

    /// The ball's speed [m/s].
    pub(crate) fn speed(&self) -> f64 {
        self.ekf.x.fixed_rows::<3>(3).norm()
    }

    /// Records the detection at `stamp` just fused into it.
    pub(crate) fn record(&mut self, stamp: i64, fused: &Fused) {
        self.last_fused = stamp;
        self.nis = fused.nis;
        self.whole_nis = fused.whole_nis;
    }
}

/// A fused measurement.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Fused {
    /// y' S^-1 y of what was fused.
    pub(crate) nis: f64,
    /// The NIS of the whole measurement against the prediction, even where only part of it was
    /// fused (a spin that did not fit): what tells two hypotheses of one detection apart,
    /// compared over the same dimensions.
    pub(crate) whole_nis: f64,
}

/// The prior innovation of one position (and spin) measurement: what the camera-noise learner
/// learns from ([`super::camera_noise`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Innovation {
    /// z - H x^- of the position [m].
    pub(crate) y: Vector3<f64>,
    /// H P^- H' of the position [m^2].
    pub(crate) hph: Matrix3<f64>,
    /// The predicted velocity [m/s].
    pub(crate) velocity: Vector3<f64>,
    /// The spin's innovation and H P^- H', when measured.
    pub(crate) spin: Option<(Vector3<f64>, Matrix3<f64>)>,
}

/// What fusing one detection into a snapshot did.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Outcome {
    /// The update, or why there was none.
    pub(crate) fused: Result<Fused, UpdateError>,
    /// The prior innovation, unless the ball was at the table (whose detections teach nothing
    /// of their camera's noise).
    pub(crate) innovation: Option<Innovation>,
    /// Whether a measured spin replaced the filter's.
    pub(crate) spin_reset: bool,
}

/// The filter's model of a flight and of its detections (see the module doc).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Fusion {
    /// The physics at the configured parameters (the filter flies its own).
    pub(crate) propagator: Propagator,
    /// What the prediction adds to the physics.
    pub(crate) noise: FilterNoise,
    /// The extra position variance of a detection of a ball at the table [m^2].
    contact_var: f64,
    /// The share of a position's gain on the spin along the flight before the first bounce.
    spin_along_flight_gain: f64,
    /// The spin's prior variance [(rad/s)^2], to which a contradicted spin is reset.
    pub(crate) spin_prior_var: f64,
    /// The gates of a position and of a position + spin.
    pub(crate) gate_position: f64,
    pub(crate) gate_position_spin: f64,
}

impl Fusion {
    /// The model of `config`, the parameters' random walk of density `param_density`.
    pub(crate) fn new(config: &Config, param_density: ParamVector) -> Self {
        let p = config.gating.probability;
        let ekf = &config.ekf;
        Self {
            propagator: Propagator::new(config),
            noise: FilterNoise {
                process: ProcessNoise {
                    acceleration_density: ekf.acceleration_noise_density,
                    spin_density: ekf.spin_noise_density,
                    param_density,
                },
                bounce: BounceNoise::from_config(config),
                spin_spread: SPIN_PARAMETER_SPREAD,
            },
            contact_var: ekf.contact_position_sigma * ekf.contact_position_sigma,
            spin_along_flight_gain: SPIN_ALONG_FLIGHT_GAIN,
            spin_prior_var: ekf.spin_prior_sigma * ekf.spin_prior_sigma,
            gate_position: chi_square_quantile(p, 3),
            gate_position_spin: chi_square_quantile(p, 6),
        }
    }

    /// The share of a position's gain on the spin along the flight after `bounces` bounces.
    pub(crate) fn along_flight_gain(&self, bounces: u32) -> f64 {
        if bounces == 0 {
            self.spin_along_flight_gain
        } else {
            1.0
        }
    }

    /// Moves a snapshot forward to `stamp` through `propagator`'s table, counting bounces.
    pub(crate) fn advance_on(&self, propagator: &Propagator, snapshot: &mut Snapshot, stamp: i64) {
        let dt = (stamp - snapshot.stamp) as f64 * 1e-9;
        if dt > 0.0 {
            let prediction = snapshot.ekf.predict(propagator, &self.noise, dt);
            let report = prediction.report;
            snapshot.ekf = prediction.ekf;
            snapshot.bounces += report.bounces;
            snapshot.robot_half_bounces += report.robot_half_bounces;
            snapshot.bounce_jump = report.last_jump.or(snapshot.bounce_jump);
        }
        snapshot.stamp = stamp.max(snapshot.stamp);
    }

    /// Moves a snapshot forward to `stamp`, counting bounces.
    pub(crate) fn advance(&self, snapshot: &mut Snapshot, stamp: i64) {
        self.advance_on(&self.propagator, snapshot, stamp);
    }

    /// The measurement as the estimate `snapshot` sees it: with the extra noise of a ball at the
    /// table (the flag says so), and its stamp's timing noise along the estimate's velocity.
    pub(crate) fn measurement_at(
        &self,
        snapshot: &Snapshot,
        m: &Measurement,
    ) -> (Measurement, bool) {
        let at_contact = self.contact_var > 0.0 && self.at_the_table(snapshot, CONTACT_BAND);
        let m = if at_contact {
            m.with_extra_position_variance(self.contact_var)
        } else {
            *m
        };
        let velocity = snapshot.ekf.x.fixed_rows::<3>(3).into_owned();
        (m.at_velocity(&velocity), at_contact)
    }

    /// True when the estimate is within `band` [m] of its contact height over the table: a few
    /// milliseconds from a bounce.
    pub(crate) fn at_the_table(&self, snapshot: &Snapshot, band: f64) -> bool {
        let x = &snapshot.ekf.x;
        (x[2] - self.propagator.flight().radius()).abs() < band
            && self.propagator.distance_outside_table(x[0], x[1]) < EDGE_MARGIN
    }

    /// Moves `snapshot` to `stamp` (through `propagator`'s table) and fuses the measurement `m`
    /// taken there.
    pub(crate) fn fuse(
        &self,
        propagator: &Propagator,
        snapshot: &mut Snapshot,
        stamp: i64,
        m: &Measurement,
    ) -> Outcome {
        self.advance_on(propagator, snapshot, stamp);
        let x = &snapshot.ekf.x;
        let p = snapshot.ekf.state_covariance();
        let (m, at_contact) = self.measurement_at(snapshot, m);
        let innovation = (!at_contact).then(|| Innovation {
            y: m.position().0 - x.fixed_rows::<3>(0),
            hph: p.fixed_view::<3, 3>(0, 0).into_owned(),
            velocity: x.fixed_rows::<3>(3).into_owned(),
            spin: match &m {
                Measurement::Position { .. } => None,
                Measurement::PositionSpin { z, .. } => Some((
                    z.fixed_rows::<3>(3) - x.fixed_rows::<3>(6),
                    p.fixed_view::<3, 3>(6, 6).into_owned(),
                )),
            },
        });
        let (fused, spin_reset) = match &m {
            Measurement::Position { z, r, .. } => {
                let gain = self.along_flight_gain(snapshot.bounces);
                let update = snapshot
                    .ekf
                    .update_partially(z, &position_H(), r, self.gate_position, gain)
                    .map(|u| (u.ekf, u.nis));
                (self.take(snapshot, update, None), false)
            }
            Measurement::PositionSpin { z, r, .. } => {
                let (fused, reset) = self.fuse_position_spin(snapshot, z, r);
                snapshot.spin_measured |= fused.is_ok();
                (fused, reset)
            }
        };
        if let Ok(fused) = &fused {
            snapshot.record(stamp, fused);
        }
        Outcome {
            fused,
            innovation,
            spin_reset,
        }
    }

    /// Puts an update's estimate into `snapshot`; its whole measurement's NIS is `whole_nis`
    /// when only part of it was fused.
    fn take(
        &self,
        snapshot: &mut Snapshot,
        update: Result<(Ekf, f64), UpdateError>,
        whole_nis: Option<f64>,
    ) -> Result<Fused, UpdateError> {
        let (ekf, nis) = update?;
        snapshot.ekf = ekf;
        Ok(Fused {
            nis,
            whole_nis: whole_nis.unwrap_or(nis),
        })
    }

    /// A position + spin measurement (see the module doc); the flag says whether the filter's
    /// spin was forgotten for the camera's.
    fn fuse_position_spin(
        &self,
        snapshot: &mut Snapshot,
        z: &SVector<f64, 6>,
        r: &Matrix6<f64>,
    ) -> (Result<Fused, UpdateError>, bool) {
        let z_position = z.fixed_rows::<3>(0).into_owned();
        let r_position = r.fixed_view::<3, 3>(0, 0).into_owned();
        let gate = self.gate_position;
        let position_alone = |ekf: &Ekf| {
            ekf.update(&z_position, &position_H(), &r_position, gate)
                .map(|u| (u.ekf, u.nis))
        };
        if let Some(nis) = snapshot.ekf.nis(&z_position, &position_H(), &r_position)
            && nis > gate
        {
            return (Err(UpdateError::Gated { nis, gate }), false);
        }
        let h = position_spin_H();
        let first = snapshot.ekf.update(z, &h, r, self.gate_position_spin);
        match first {
            // At the table the measured spin may be of the other side of the bounce (the
            // bounce's time is uncertain by a millisecond or two, and it changes the spin by
            // hundreds of rad/s): the position alone.
            Err(UpdateError::Gated { nis, .. })
                if self.at_the_table(snapshot, BOUNCE_SPIN_MARGIN) =>
            {
                let update = position_alone(&snapshot.ekf);
                (self.take(snapshot, update, Some(nis)), false)
            }
            Err(UpdateError::Gated { nis, .. }) => {
                let forgotten = snapshot.ekf.with_spin_forgotten(self.spin_prior_var);
                let update = forgotten
                    .update(z, &h, r, self.gate_position_spin)
                    .map(|u| (u.ekf, u.nis))
                    .or_else(|_| position_alone(&forgotten));
                (self.take(snapshot, update, Some(nis)), true)
            }
            other => {
                let update = other.map(|u| (u.ekf, u.nis));
                (self.take(snapshot, update, None), false)
            }
        }
    }
}
