//! The live track refitted on a schedule of its own age (`ekf.refit_interval`): its fused
//! detections are kept with their measurements ([`TrackRefit`]; whitened at each refit, with
//! the process noise over their lag), and every interval the maximum a posteriori
//! fit of them and of the flight's parameters ([`crate::online::refit`]) replaces the mean of
//! the track's estimate and of every snapshot in its history (so that a late detection rolled
//! back into the history meets the refitted flight); the covariances stay the filter's. The
//! schedule is the track's own stamps, so a replay refits exactly where the node did.

use super::*;
use crate::online::refit::{self, AugmentedVector, Flight, Observation, Prior};
use crate::physics::state::SPIN;

/// Fewest detections a refit is made from.
const MIN_DETECTIONS: usize = 8;
/// Most Levenberg-Marquardt iterations of one refit (from the last refit's solution, two or
/// three suffice).
const MAX_ITERATIONS: usize = 6;

/// The live track's detections, kept for its refits, and the last refit's solution.
#[derive(Debug, Clone)]
pub(super) struct TrackRefit {
    /// The fused detections' times from `start` [s] and measurements, in stamp order;
    /// allocated once.
    observations: Vec<(f64, Measurement)>,
    /// Them whitened for one refit; allocated once.
    whitened: Vec<Observation>,
    /// The track they belong to (0: none).
    track: u32,
    /// The stamp of the refit's time 0: the track's first estimate [ns].
    start: i64,
    /// The track's first estimate, the first refit's starting point with the spin of the
    /// moment.
    guess: AugmentedVector,
    /// The table bounces the track had made at `start`.
    start_bounces: u32,
    /// The last refit's (x_0, theta).
    solution: Option<AugmentedVector>,
    /// The track age of the next refit [ns].
    next: i64,
    /// No more refits of this track: a detection did not fit in the buffer, or a spin was
    /// measured (the filter then linearises at a measured spin).
    done: bool,
}

impl TrackRefit {
    /// Room for `capacity` detections.
    pub(super) fn new(capacity: usize) -> Self {
        Self {
            observations: Vec::with_capacity(capacity),
            whitened: Vec::with_capacity(capacity),
            track: 0,
            start: 0,
            guess: AugmentedVector::zeros(),
            start_bounces: 0,
            solution: None,
            next: 0,
            done: false,
        }
    }
}

/// (x, theta) of a snapshot.
fn augmented(snapshot: &Snapshot) -> AugmentedVector {
    let mut y = AugmentedVector::zeros();
    y.fixed_rows_mut::<9>(0).copy_from(&snapshot.ekf.x);
    y.fixed_rows_mut::<PARAMS>(9).copy_from(&snapshot.ekf.theta);
    y
}

impl Estimator {
    /// Keeps the fused detection `d` (measured as `m`) of the live track for its refits.
    pub(super) fn keep_for_refit(&mut self, d: &Detection, m: &Measurement) {
        let interval = self.settings.refit_interval;
        let (Some(track), true) = (&self.track, interval > 0) else {
            return;
        };
        let kept = &mut self.refit;
        if kept.track != track.id {
            kept.track = track.id;
            kept.start = track.base.stamp;
            kept.guess = augmented(&track.base);
            kept.start_bounces = track.base.bounces;
            kept.solution = None;
            kept.next = interval;
            kept.done = false;
            kept.observations.clear();
        }
        if matches!(m, Measurement::PositionSpin { .. })
            || kept.observations.len() >= self.settings.refit_max
        {
            kept.done = true;
        }
        if d.stamp < kept.start || kept.done {
            return;
        }
        let t = (d.stamp - kept.start) as f64 * 1e-9;
        let at = kept.observations.partition_point(|(k, _)| *k <= t);
        kept.observations.insert(at, (t, *m));
    }

    /// Refits the live track when its age has reached the next refit's (see the module doc).
    pub(super) fn refit_when_due(&mut self) {
        let interval = self.settings.refit_interval;
        let Some(track) = &self.track else {
            return;
        };
        let kept = &mut self.refit;
        if interval <= 0 || kept.track != track.id || kept.done {
            return;
        }
        let age = track.now.stamp - kept.start;
        if age < kept.next {
            return;
        }
        while kept.next <= age {
            kept.next += interval;
        }
        if kept.observations.len() < MIN_DETECTIONS {
            return;
        }
        // The flight strays from the model by the white acceleration the filter assumes: a
        // detection tau before the newest is that much less sure of the flight now, q tau^3 / 3
        // per axis (its correlation with the others' left out).
        let density = self.settings.filter.process.acceleration_density
            * self.model_noise.scales().acceleration;
        let newest = kept.observations.last().map_or(0.0, |(t, _)| *t);
        kept.whitened.clear();
        for (index, (t, m)) in kept.observations.iter().enumerate() {
            let lag = newest - t;
            let m = m.with_extra_position_variance(density * lag * lag * lag / 3.0);
            if let Ok(o) = Observation::new(index, *t, &m) {
                kept.whitened.push(o);
            }
        }
        let start = kept.solution.unwrap_or_else(|| {
            let mut y = kept.guess;
            y.fixed_rows_mut::<3>(SPIN)
                .copy_from(&track.now.ekf.x.fixed_rows::<3>(SPIN));
            y
        });
        let (params, covariance) = track.param_prior;
        // Parameters the adaptation keeps fixed have no variance: their information is huge.
        let Some(param_information) =
            (covariance + ParamCovariance::identity() * 1e-12).try_inverse()
        else {
            return;
        };
        let prior = Prior {
            spin_sigma: self.settings.spin_prior_var.sqrt(),
            params,
            param_information,
        };
        let Some(solution) = refit::solve(
            &self.propagator,
            &kept.whitened,
            &start,
            &prior,
            MAX_ITERATIONS,
        ) else {
            return;
        };
        kept.solution = Some(solution.y);
        let (start_stamp, start_bounces) = (kept.start, kept.start_bounces);
        if let Some(track) = self.track.as_mut()
            && refitted(
                &self.propagator,
                &solution.y,
                start_stamp,
                start_bounces,
                track,
            )
        {
            self.counters.refits += 1;
        }
    }
}

/// Moves the means of the track's snapshots (its base, its history's, its estimate) from
/// `start` on to the refitted flight `y`; false, and nothing moved, when the refitted flight
/// bounces on the table at another time than the track's estimates do (a bounce the filter has
/// yet to see, or has seen that the fit puts elsewhere: the filter's bookkeeping of bounces
/// stays its own).
fn refitted(
    propagator: &Propagator,
    y: &AugmentedVector,
    start: i64,
    start_bounces: u32,
    track: &mut Track,
) -> bool {
    let theta = y.fixed_rows::<PARAMS>(9).into_owned();
    let time = |stamp: i64| (stamp - start) as f64 * 1e-9;
    // First check, then move.
    let mut flight = Flight::new(propagator, y);
    let snapshots = std::iter::once(&track.base)
        .chain(track.history.iter().map(|e| &e.after))
        .chain(std::iter::once(&track.now));
    for s in snapshots.filter(|s| s.stamp >= start) {
        let (_, bounces) = flight.at(time(s.stamp));
        if s.bounces != start_bounces + bounces {
            return false;
        }
    }
    let mut flight = Flight::new(propagator, y);
    let mut move_to = |s: &mut Snapshot| {
        if s.stamp >= start {
            let (x, _) = flight.at(time(s.stamp));
            s.ekf.x = x;
            s.ekf.theta = theta;
        }
    };
    move_to(&mut track.base);
    for entry in track.history.iter_mut() {
        move_to(&mut entry.after);
    }
    move_to(&mut track.now);
    true
}
