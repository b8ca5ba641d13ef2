//! The measurement model: a detection is a measurement of the ball centre's position, and of its spin when the camera measured one
//! (z = H x with H selecting position, or position and spin, from the state), with the detection's
//! own covariance or else its source's configured noise. Shared by the filter
//! ([`crate::online::estimator`]) and the batch fit ([`crate::offline::batch`]); the filter also
//! scales the noise by what it learned of each source.

use nalgebra::{Matrix3, Matrix6, SVector, Vector3};

use crate::config::{Config, SourceIndex, SourceParams};
use crate::model::detection::{Detection, Source};

/// Farthest a detection may be from the table's centre [m] (the table is 2.74 m long; a ball in
/// play stays within a few metres of it).
pub const MAX_RANGE: f64 = 10.0;

/// Why a detection cannot be a measurement (the estimator counts each as its
/// [`Rejection`](crate::online::estimator::Rejection) of the same name).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Unusable {
    /// A position, spin or covariance value is NaN or infinite.
    NonFinite,
    /// The position is more than [`MAX_RANGE`] from the table's centre.
    OutOfRange,
    /// The confidence is outside [0, 1].
    BadConfidence,
    /// The confidence is below `ekf.min_confidence`.
    LowConfidence,
    /// A covariance is not symmetric positive definite.
    BadCovariance,
}

/// Measurement noise of one source, as variances.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct SourceNoise {
    /// The source's name (its key under `sources`).
    pub(crate) name: String,
    /// Position variance [m^2].
    pub(crate) position_var: f64,
    /// Spin variance [(rad/s)^2], when the source measures spin.
    pub(crate) spin_var: Option<f64>,
}

impl SourceNoise {
    fn new(name: &str, p: &SourceParams) -> Self {
        Self {
            name: name.to_owned(),
            position_var: p.position_sigma * p.position_sigma,
            spin_var: (p.spin_sigma > 0.0).then_some(p.spin_sigma * p.spin_sigma),
        }
    }
}

/// How detections become measurements: each source's configured noise, and the confidence below
/// which a detection is not used.
#[derive(Debug, Clone, PartialEq)]
pub struct MeasurementModel {
    sources: Vec<SourceNoise>,
    source_index: SourceIndex,
    min_confidence: f64,
}

impl MeasurementModel {
    /// The model of `config`'s sources and `ekf.min_confidence`.
    pub fn new(config: &Config) -> Self {
        Self {
            sources: config
                .sources
                .all()
                .into_iter()
                .map(|(name, p)| SourceNoise::new(name, p))
                .collect(),
            source_index: config.sources.index(),
            min_confidence: config.ekf.min_confidence,
        }
    }

    /// Where a detection's source sits among the configured sources.
    pub fn source_index(&self, source: Source) -> usize {
        self.source_index.of(source)
    }

    /// Each configured source's noise, in the order of
    /// [`SourcesParams::all`](crate::config::SourcesParams::all).
    pub(crate) fn sources(&self) -> &[SourceNoise] {
        &self.sources
    }

    fn source(&self, source: Source) -> &SourceNoise {
        &self.sources[self.source_index.of(source)]
    }

    /// A detection as a measurement with its noise (its own covariance, else its source's), or why
    /// it is rejected.
    pub fn measure(&self, d: &Detection) -> Result<Measurement, Unusable> {
        let finite = d.position.iter().all(|v| v.is_finite())
            && d.spin.is_none_or(|w| w.iter().all(|v| v.is_finite()))
            && d.position_covariance
                .is_none_or(|c| c.iter().all(|v| v.is_finite()))
            && d.spin_covariance
                .is_none_or(|c| c.iter().all(|v| v.is_finite()));
        if !finite {
            return Err(Unusable::NonFinite);
        }
        if d.position.norm() > MAX_RANGE {
            return Err(Unusable::OutOfRange);
        }
        let confidence = f64::from(d.confidence);
        if !(0.0..=1.0).contains(&confidence) {
            return Err(Unusable::BadConfidence);
        }
        if confidence < self.min_confidence {
            return Err(Unusable::LowConfidence);
        }
        let noise = self.source(d.source);
        let r_position = match d.position_covariance {
            Some(c) if !is_spd(&c) => return Err(Unusable::BadCovariance),
            Some(c) => c,
            None => Matrix3::identity() * noise.position_var,
        };
        let spin = d.spin.filter(|_| !claims_placeholder_spin(d));
        let r_spin = match (spin, d.spin_covariance, noise.spin_var) {
            (None, _, _) => None,
            (Some(_), Some(c), _) if !is_spd(&c) => return Err(Unusable::BadCovariance),
            (Some(_), Some(c), _) => Some(c),
            (Some(_), None, Some(var)) => Some(Matrix3::identity() * var),
            // A source that does not measure spin: its spin values are ignored.
            (Some(_), None, None) => None,
        };
        Ok(match (spin, r_spin) {
            (Some(w), Some(rs)) => {
                let mut z = SVector::<f64, 6>::zeros();
                z.fixed_rows_mut::<3>(0).copy_from(&d.position);
                z.fixed_rows_mut::<3>(3).copy_from(&w);
                let mut r = Matrix6::zeros();
                r.fixed_view_mut::<3, 3>(0, 0).copy_from(&r_position);
                r.fixed_view_mut::<3, 3>(3, 3).copy_from(&rs);
                Measurement::PositionSpin { z, r, timing: 0.0 }
            }
            _ => Measurement::Position {
                z: d.position,
                r: r_position,
                timing: 0.0,
            },
        })
    }
}

/// A measurement ready for the filter.
#[derive(Debug, Clone, Copy, PartialEq)]
#[expect(
    clippy::large_enum_variant,
    reason = "kept inline: no heap allocation per detection"
)]
pub enum Measurement {
    /// A position of covariance r; its stamp's timing variance [s^2] moves it along the flight.
    Position {
        /// The ball centre [m].
        z: Vector3<f64>,
        /// Its covariance [m^2].
        r: Matrix3<f64>,
        /// The stamp's timing variance [s^2] (0 until the source's is learned).
        timing: f64,
    },
    /// A position and a spin.
    PositionSpin {
        /// The ball centre [m] and the spin [rad/s].
        z: SVector<f64, 6>,
        /// Their covariance (block diagonal).
        r: Matrix6<f64>,
        /// The stamp's timing variance [s^2].
        timing: f64,
    },
}

impl Measurement {
    /// The measurement with `variance` [m^2] added to its position's, on every axis.
    pub(crate) fn with_extra_position_variance(mut self, variance: f64) -> Self {
        match &mut self {
            Self::Position { r, .. } => *r += Matrix3::identity() * variance,
            Self::PositionSpin { r, .. } => {
                let mut position = r.fixed_view_mut::<3, 3>(0, 0);
                position += Matrix3::identity() * variance;
            }
        }
        self
    }

    /// Its position and the position's covariance.
    pub(crate) fn position(&self) -> (Vector3<f64>, Matrix3<f64>) {
        match self {
            Self::Position { z, r, .. } => (*z, *r),
            Self::PositionSpin { z, r, .. } => (
                z.fixed_rows::<3>(0).into_owned(),
                r.fixed_view::<3, 3>(0, 0).into_owned(),
            ),
        }
    }

    /// The measurement at a predicted velocity `v` [m/s]: the timing noise added to the
    /// position covariance along it (timing v v').
    pub(crate) fn at_velocity(mut self, v: &Vector3<f64>) -> Self {
        match &mut self {
            Self::Position { r, timing, .. } if *timing > 0.0 => *r += v * v.transpose() * *timing,
            Self::PositionSpin { r, timing, .. } if *timing > 0.0 => {
                let mut position = r.fixed_view_mut::<3, 3>(0, 0);
                position += v * v.transpose() * *timing;
            }
            _ => {}
        }
        self
    }
}

/// A detection whose spin is exactly zero: a detector's placeholder, not a measurement.
pub(crate) fn claims_placeholder_spin(d: &Detection) -> bool {
    d.spin.is_some_and(|w| w == Vector3::zeros())
}

fn is_spd(m: &Matrix3<f64>) -> bool {
    (m - m.transpose()).abs().max() <= 1e-9 * m.abs().max().max(f64::MIN_POSITIVE)
        && m.cholesky().is_some()
}
