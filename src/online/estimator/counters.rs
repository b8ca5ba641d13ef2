//! What the estimator did with each detection, and the counts of it by outcome and by reason.

use crate::online::measurement::Unusable;

/// Why a detection was not fused.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Rejection {
    /// A position, spin or covariance value is NaN or infinite.
    NonFinite,
    /// The confidence is outside [0, 1].
    BadConfidence,
    /// The confidence is below `ekf.min_confidence`.
    LowConfidence,
    /// A given covariance is not symmetric positive definite.
    BadCovariance,
    /// Older than the rollback window behind the newest fused detection, or before the track.
    TooOld,
    /// Same stamp and source as a detection already fused.
    Duplicate,
    /// Outside the Mahalanobis gate of the track.
    Gated,
    /// Dropped while initialising: it did not fit a ballistic flight with the others.
    InitOutlier,
    /// Rejected by an adapter before the filter: its `frame_id` is not `table`.
    UnknownFrame,
    /// More than `tracking.timeout` away from the stamps of the current track (or of the
    /// detections initialising one), and the next detection did not confirm the jump: a clock
    /// glitch. A jump the next detection confirms (a new ball after a pause, a restarted camera's
    /// clock) starts a new track with both.
    StampJump,
    /// The position is more than [`MAX_RANGE`] from the table's centre: not a ball in play.
    OutOfRange,
}

impl Rejection {
    /// Every reason, in the order of [`Counters::rejected`].
    pub const ALL: [Self; 11] = [
        Self::NonFinite,
        Self::BadConfidence,
        Self::LowConfidence,
        Self::BadCovariance,
        Self::TooOld,
        Self::Duplicate,
        Self::Gated,
        Self::InitOutlier,
        Self::UnknownFrame,
        Self::StampJump,
        Self::OutOfRange,
    ];

    /// A short snake_case name for summaries and diagnostics.
    pub fn name(self) -> &'static str {
        match self {
            Self::NonFinite => "non_finite",
            Self::BadConfidence => "bad_confidence",
            Self::LowConfidence => "low_confidence",
            Self::BadCovariance => "bad_covariance",
            Self::TooOld => "too_old",
            Self::Duplicate => "duplicate",
            Self::Gated => "gated",
            Self::InitOutlier => "init_outlier",
            Self::UnknownFrame => "unknown_frame",
            Self::StampJump => "stamp_jump",
            Self::OutOfRange => "out_of_range",
        }
    }

    /// Its place in [`Self::ALL`] (the declaration's order).
    pub(crate) fn index(self) -> usize {
        self as usize
    }
}

/// What happened to the detections so far.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Counters {
    /// Detections handled.
    pub received: u64,
    /// Detections fused into a track (including those fused late through a rollback).
    pub fused: u64,
    /// Detections used to initialise a track (or still waiting in the initialiser).
    pub initializing: u64,
    /// Rejected detections by reason, in the order of [`Rejection::ALL`].
    pub rejected: [u64; Rejection::ALL.len()],
    /// Tracks started.
    pub tracks: u64,
    /// Tracks refuted by their detections (a run of gated ones) and re-anchored on them: the
    /// same ball, the same id, not counted in `tracks`.
    pub reanchored: u64,
    /// Late detections fused by rolling back.
    pub rollbacks: u64,
    /// Tracks whose lesson of the physics was their flight smoothed.
    pub smoothed_lessons: u64,
    /// Tracks' smoothings dropped (each track taught its filter's lesson), by reason in the
    /// order of [`Dropped::ALL`](super::Dropped::ALL): too many waiting, late for a caller that
    /// never waits, failed on the worker.
    pub lessons_dropped: [u64; super::Dropped::ALL.len()],
    /// Spin measurements that disagreed with the filter's spin and replaced it.
    pub spin_resets: u64,
    /// Detections near the table's edge that the other bounce hypothesis explained better.
    pub edge_retries: u64,
    /// Detections that claimed a spin of exactly zero (a detector's placeholder, not a
    /// measurement): their spin was ignored, the detection judged as a position alone.
    pub zero_spin_ignored: u64,
    /// Tracks started at their first detection from the predicted rebound of an announced
    /// robot hit ([`Estimator::expect_hit`](super::Estimator::expect_hit)).
    pub seeded_by_hit: u64,
    /// Announced robot hits that seeded no track: no live track to hit, the track already
    /// past the hit, the hit impossible, or the first detection after it far from the rebound.
    pub hits_not_seeded: u64,
}

impl Counters {
    /// Rejected detections of one reason.
    pub fn rejected(&self, reason: Rejection) -> u64 {
        self.rejected[reason.index()]
    }

    /// Lessons dropped for one reason.
    pub fn lessons_dropped(&self, reason: super::Dropped) -> u64 {
        self.lessons_dropped[reason.index()]
    }

    /// All rejected detections.
    pub fn total_rejected(&self) -> u64 {
        self.rejected.iter().sum()
    }
    /// "reason count" for every reason with rejected detections, in the order of
    /// [`Rejection::ALL`].
    pub fn rejections(&self) -> Vec<String> {
        Rejection::ALL
            .iter()
            .filter(|r| self.rejected(**r) > 0)
            .map(|r| format!("{} {}", r.name(), self.rejected(*r)))
            .collect()
    }
}

impl From<Unusable> for Rejection {
    fn from(why: Unusable) -> Self {
        match why {
            Unusable::NonFinite => Self::NonFinite,
            Unusable::OutOfRange => Self::OutOfRange,
            Unusable::BadConfidence => Self::BadConfidence,
            Unusable::LowConfidence => Self::LowConfidence,
            Unusable::BadCovariance => Self::BadCovariance,
        }
    }
}

#[cfg(test)]
#[test]
fn every_reason_counts_in_its_own_place() {
    assert!(
        Rejection::ALL
            .iter()
            .enumerate()
            .all(|(i, r)| r.index() == i)
    );
    assert!(
        super::Dropped::ALL
            .iter()
            .enumerate()
            .all(|(i, r)| r.index() == i)
    );
}

/// What the estimator did with one detection.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Verdict {
    /// Fused into the track; the normalised innovation squared of the update.
    Fused {
        /// NIS of the update.
        nis: f64,
    },
    /// Taken by the initialiser of a new track.
    Initializing,
    /// Its stamp jumped beyond `tracking.timeout`: held until the next detection confirms the
    /// jump or shows a glitch (see [`Estimator::update`](super::Estimator::update)); counted as
    /// initialising meanwhile.
    Held,
    /// Not fused.
    Rejected(Rejection),
}
