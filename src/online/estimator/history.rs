//! The track's history and fusion: moving snapshots forward through the physics, fusing a
//! detection at its stamp (position, or position and spin; the bounce's hypotheses near the
//! table's edge), the newest one directly and a late one by rolling back through the history
//! and re-applying what came after it.

use super::*;

impl Estimator {
    /// Moves a snapshot forward to `stamp`, counting bounces.
    pub(super) fn advance(&self, snapshot: &mut Snapshot, stamp: i64) {
        self.advance_with(&self.propagator, snapshot, stamp, None);
    }

    pub(super) fn advance_with(
        &self,
        propagator: &Propagator,
        snapshot: &mut Snapshot,
        stamp: i64,
        sensitivity: Option<&mut NoiseSensitivity>,
    ) {
        let dt = (stamp - snapshot.stamp) as f64 * 1e-9;
        if dt > 0.0 {
            let report = snapshot.ekf.predict(
                propagator,
                &self.settings.filter,
                &self.model_noise.scales(snapshot.spin_measured),
                sensitivity,
                dt,
            );
            snapshot.bounces += report.bounces;
            snapshot.robot_half_bounces += report.robot_half_bounces;
            snapshot.bounce_jump = report.last_jump.or(snapshot.bounce_jump);
        }
        snapshot.stamp = stamp.max(snapshot.stamp);
    }

    /// Fuses a measurement into a snapshot at the detection's stamp, carrying the covariance's
    /// `sensitivity` to the noise scales along when given.
    pub(super) fn fuse(
        &mut self,
        snapshot: &mut Snapshot,
        d: &Detection,
        m: &Measurement,
        sensitivity: Option<&mut NoiseSensitivity>,
    ) -> Result<f64, Rejection> {
        let prior = *snapshot;
        // With a horizon the scales learn from the probe's predictions, not from these updates.
        let scoring = sensitivity.is_some() && self.probe.is_none();
        let noise = sensitivity.map(|sensitivity| NoiseCarry {
            sensitivity,
            scored: scoring,
        });
        let (mut result, innovation, spin_reset) =
            self.predict_and_update(&self.propagator, snapshot, d, m, noise);
        self.innovation = innovation;
        self.counters.spin_resets += u64::from(spin_reset);
        if self.near_table_edge(snapshot) || self.lands_near_table_edge(&prior, d.stamp) {
            // An edge ball: estimate and ball may land on either side of the table's edge. The
            // hypothesis that explains the detection best wins.
            for alternative in &self.edge_alternatives {
                let mut other = prior;
                let (fused, _, spin_reset) =
                    self.predict_and_update(alternative, &mut other, d, m, None);
                self.counters.spin_resets += u64::from(spin_reset);
                let Ok(fused) = fused else {
                    continue;
                };
                let better = match result {
                    Ok(current) => {
                        fused.whole_nis < current.whole_nis && other.bounces != snapshot.bounces
                    }
                    Err(_) => true,
                };
                if better {
                    *snapshot = other;
                    self.counters.edge_retries += 1;
                    result = Ok(fused);
                }
            }
        }
        match result {
            Ok(fused) => {
                snapshot.record(d.stamp, &fused);
                self.score = scoring.then_some((fused.score, prior.spin_measured));
                Ok(fused.nis)
            }
            Err(UpdateError::Gated { .. }) => Err(Rejection::Gated),
            Err(UpdateError::NotFinite) => Err(Rejection::NonFinite),
            Err(UpdateError::NotPositiveDefinite) => Err(Rejection::BadCovariance),
        }
    }

    pub(super) fn predict_and_update(
        &self,
        propagator: &Propagator,
        snapshot: &mut Snapshot,
        d: &Detection,
        m: &Measurement,
        mut noise: Option<NoiseCarry<'_>>,
    ) -> (Result<Fused, UpdateError>, Option<noise::Innovation>, bool) {
        let sensitivity = noise.as_mut().map(|carry| &mut *carry.sensitivity);
        self.advance_with(propagator, snapshot, d.stamp, sensitivity);
        let x = &snapshot.ekf.x;
        let velocity = x.fixed_rows::<3>(3).into_owned();
        let p = snapshot.ekf.state_covariance();
        let hph = p.fixed_view::<3, 3>(0, 0).into_owned();
        let (m, at_contact) = self.measurement_at(snapshot, m);
        let (y, spin) = match &m {
            Measurement::Position { z, .. } => (z - x.fixed_rows::<3>(0), None),
            Measurement::PositionSpin { z, .. } => (
                z.fixed_rows::<3>(0) - x.fixed_rows::<3>(0),
                Some((
                    z.fixed_rows::<3>(3) - x.fixed_rows::<3>(6),
                    p.fixed_view::<3, 3>(6, 6).into_owned(),
                    Matrix3::zeros(),
                )),
            ),
        };
        let innovation = (!at_contact).then_some(noise::Innovation {
            y,
            hph,
            r0: Matrix3::zeros(),
            velocity,
            spin,
        });
        let (result, spin_reset) = match &m {
            Measurement::Position { z, r, .. } => (
                snapshot.ekf.update_partially(
                    z,
                    &position_H(),
                    r,
                    self.settings.gate_position,
                    noise,
                    self.settings
                        .along_flight_gain(snapshot.bounces, self.guards_spin_along_flight()),
                ),
                false,
            ),
            Measurement::PositionSpin { z, r, .. } => {
                let fused = self.fuse_position_spin(snapshot, z, r, noise);
                snapshot.spin_measured |= fused.0.is_ok();
                fused
            }
        };
        (result, innovation, spin_reset)
    }

    /// The measurement as the estimate `snapshot` sees it: with the extra noise of a ball at the
    /// table (which teaches nothing of its camera's: the flag), and its stamp's timing noise
    /// along the estimate's velocity.
    pub(super) fn measurement_at(
        &self,
        snapshot: &Snapshot,
        m: &Measurement,
    ) -> (Measurement, bool) {
        let at_contact =
            self.settings.contact_var > 0.0 && self.at_the_table(snapshot, CONTACT_BAND);
        let m = if at_contact {
            m.with_extra_position_variance(self.settings.contact_var)
        } else {
            *m
        };
        let velocity = snapshot.ekf.x.fixed_rows::<3>(3).into_owned();
        (m.at_velocity(&velocity), at_contact)
    }

    /// True when the estimate is within `band` [m] of its contact height over the table: a few
    /// milliseconds from a bounce.
    pub(super) fn at_the_table(&self, snapshot: &Snapshot, band: f64) -> bool {
        let x = &snapshot.ekf.x;
        (x[2] - self.flight.radius()).abs() < band
            && self.propagator.distance_outside_table(x[0], x[1]) < EDGE_MARGIN
    }

    /// True when the estimate is low over the table's edge, where a bounce is a close call.
    pub(super) fn near_table_edge(&self, snapshot: &Snapshot) -> bool {
        let x = &snapshot.ekf.x;
        let outside = self.propagator.distance_outside_table(x[0], x[1]);
        x[2] < 0.1 && outside.abs() < EDGE_MARGIN
    }

    /// True when the estimate, low and falling, comes down to the table's height within
    /// [`EDGE_MARGIN`] of its edge before `stamp` (in a vacuum, to first order: where it would
    /// bounce). A ball that crosses a side edge fast is outside the margin at both ends of a
    /// step: 4.5 m/s sideways is 3 cm in one 150 fps frame interval.
    pub(super) fn lands_near_table_edge(&self, snapshot: &Snapshot, stamp: i64) -> bool {
        let x = &snapshot.ekf.x;
        let dt = (stamp - snapshot.stamp) as f64 * 1e-9;
        let height = x[2] - self.flight.radius();
        let (vz, g) = (x[5], self.flight.gravity());
        if dt <= 0.0 || x[2] >= 0.1 || height < 0.0 || vz >= 0.0 || g <= 0.0 {
            return false;
        }
        // height + vz t - g t^2 / 2 = 0, the later root.
        let t = (vz + (vz * vz + 2.0 * g * height).sqrt()) / g;
        t <= dt
            && self
                .propagator
                .distance_outside_table(x[0] + x[3] * t, x[1] + x[4] * t)
                .abs()
                < EDGE_MARGIN
    }

    /// A position + spin measurement. The position is gated on its own; when it fits but the
    /// spin does not, the filter's spin (learned from curvature, where the EKF can be
    /// overconfident at high spin parameters) is forgotten in favour of the camera's; the flag says
    /// whether it was, for the counters.
    pub(super) fn fuse_position_spin(
        &self,
        snapshot: &mut Snapshot,
        z: &SVector<f64, 6>,
        r: &Matrix6<f64>,
        mut noise: Option<NoiseCarry<'_>>,
    ) -> (Result<Fused, UpdateError>, bool) {
        let z_position = z.fixed_rows::<3>(0).into_owned();
        let r_position = r.fixed_view::<3, 3>(0, 0).into_owned();
        let gate = self.settings.gate_position;
        if let Some(nis) = snapshot.ekf.nis(&z_position, &position_H(), &r_position)
            && nis > gate
        {
            return (Err(UpdateError::Gated { nis, gate }), false);
        }
        let h = position_spin_H();
        let first = snapshot.ekf.update(
            z,
            &h,
            r,
            self.settings.gate_position_spin,
            noise.as_mut().map(NoiseCarry::reborrow),
        );
        // A fallback below fuses part of the measurement; the spin's misfit still counts
        // against this hypothesis when two are compared (an edge ball).
        let whole = |fused: Result<Fused, UpdateError>, whole_nis: f64| {
            fused.map(|f| Fused { whole_nis, ..f })
        };
        match first {
            // At the table the measured spin may be of the other side of the bounce (the
            // bounce's time is uncertain by a millisecond or two, and it changes the spin by
            // hundreds of rad/s): the position alone.
            Err(UpdateError::Gated { nis, .. })
                if self.at_the_table(snapshot, BOUNCE_SPIN_MARGIN) =>
            {
                (
                    whole(
                        snapshot
                            .ekf
                            .update(&z_position, &position_H(), &r_position, gate, noise),
                        nis,
                    ),
                    false,
                )
            }
            Err(UpdateError::Gated { nis: whole_nis, .. }) => {
                snapshot.ekf.reset_spin(
                    self.settings.spin_prior_var,
                    noise.as_mut().map(|carry| &mut *carry.sensitivity),
                );
                let refit = match snapshot.ekf.update(
                    z,
                    &h,
                    r,
                    self.settings.gate_position_spin,
                    noise.as_mut().map(NoiseCarry::reborrow),
                ) {
                    Ok(fused) => Ok(fused),
                    Err(_) => {
                        snapshot
                            .ekf
                            .update(&z_position, &position_H(), &r_position, gate, noise)
                    }
                };
                (whole(refit, whole_nis), true)
            }
            other => (other, false),
        }
    }

    pub(super) fn fuse_newest(&mut self, d: &Detection, m: Measurement) -> Result<f64, Rejection> {
        let Some(track) = &self.track else {
            return Err(Rejection::TooOld);
        };
        if track
            .history
            .back()
            .is_some_and(|e| same_frame(&e.detection, d))
        {
            return Err(Rejection::Duplicate);
        }
        let mut snapshot = track.now;
        let track_was_spin_measured = snapshot.spin_measured;
        // The sensitivity to the noise scales moves on only with a detection fused.
        let mut sensitivity = self.sensitivity.as_deref().copied();
        let mut result = self.fuse(&mut snapshot, d, &m, sensitivity.as_mut());
        if result == Err(Rejection::Gated)
            && let Some((retried, nis)) = self
                .retry_edge_bounce(d, &m)
                .or_else(|| self.retry_bounce_forgetting_spin(d, &m))
        {
            snapshot = retried;
            result = Ok(nis);
        }
        self.learn_noise(d);
        let nis = result?;
        if let (Some(kept), Some(mut moved)) = (self.sensitivity.as_deref_mut(), sensitivity) {
            if snapshot.spin_measured && !track_was_spin_measured {
                // The acceleration's scale of the phase that starts here has added nothing yet.
                let [acceleration, _, _] = &mut moved;
                *acceleration = StateMatrix::zeros();
            }
            *kept = moved;
        }
        self.learn_ahead(d, &m, &snapshot);
        self.judge_contest(d, &m);
        self.push_history(Entry {
            detection: *d,
            measurement: m,
            after: snapshot,
        });
        self.keep_for_refit(d, &m);
        self.refit_when_due();
        Ok(nis)
    }

    /// With a horizon (`ekf.model_noise_horizon`): once the newest fused detection `d` is that
    /// far past the held estimate, the estimate is predicted to it and the model noise learns
    /// from how far the prediction misses it (its position; the same score as an update's, of
    /// an innovation a horizon ahead); then the estimate just after `d` is held instead.
    fn learn_ahead(&mut self, d: &Detection, m: &Measurement, after: &Snapshot) {
        let Some(probe) = self.probe.as_deref() else {
            return;
        };
        let due = probe
            .from
            .as_ref()
            .is_none_or(|(from, _)| d.stamp - from.stamp >= self.settings.model_noise_horizon);
        let held = if due { probe.from } else { None };
        // Each fused detection fades what was learned, as without a horizon.
        self.model_noise.fade();
        if !due {
            return;
        }
        if let Some((mut ahead, mut sensitivity)) = held {
            self.advance_with(
                &self.propagator,
                &mut ahead,
                d.stamp,
                Some(&mut sensitivity),
            );
            let (z, r) = self.measurement_at(&ahead, m).0.position();
            if let Some(fused) = ahead.ekf.score(&z, &position_H(), &r, &sensitivity) {
                self.model_noise
                    .learn_ahead(&fused.score, ahead.spin_measured);
            }
        }
        let sensitivity = self.sensitivity.as_deref().copied();
        if let (Some(held), Some(sensitivity)) = (self.probe.as_deref_mut(), sensitivity) {
            held.from = Some((*after, sensitivity));
        }
    }

    /// An edge ball whose kept bounce hypothesis fails a detection: the other hypotheses are
    /// tried again from before the ball came down to the table, every detection since re-applied
    /// with the table grown and shrunk by [`EDGE_MARGIN`]. The first detection after a bounce may
    /// come too soon after it to tell landing on the table from passing beside it (0.3 ms at
    /// 900 fps), and a hypothesis chosen on it leaves the other, tried one detection later, to
    /// start from a ball already below the table's height. Taken when the newest detection fuses
    /// and the detections re-applied fit better (lower NIS of their whole measurements in sum)
    /// than they did; the history is rewritten with it. Returns the estimate at `d` and its NIS.
    fn retry_edge_bounce(&mut self, d: &Detection, m: &Measurement) -> Option<(Snapshot, f64)> {
        let track = self.track.as_ref()?;
        if !self.near_table_edge(&track.now) {
            return None;
        }
        // From the last entry before the latest bounce, or, with no bounce since the history
        // starts, before the ball came down to the table's height.
        let contact = self.flight.radius();
        let history = &track.history;
        let before = history
            .iter()
            .rev()
            .map(|e| e.after.bounces)
            .find(|&b| b < track.now.bounces)
            .unwrap_or(track.now.bounces);
        let from = history
            .iter()
            .rposition(|e| e.after.bounces == before && e.after.ekf.x[2] > contact)?;
        let again = history.len() - from - 1;
        if again == 0 || again > EDGE_RETRY_LIMIT {
            return None;
        }
        let kept: f64 = history
            .iter()
            .skip(from + 1)
            .map(|e| e.after.whole_nis)
            .sum();
        let mut best: Option<([Snapshot; EDGE_RETRY_LIMIT], Snapshot, f64, f64)> = None;
        for alternative in &self.edge_alternatives {
            let mut snapshot = history[from].after;
            let mut afters = [snapshot; EDGE_RETRY_LIMIT];
            let mut total = 0.0;
            for (slot, entry) in afters.iter_mut().zip(history.iter().skip(from + 1)) {
                total += match self.reapply(
                    alternative,
                    &mut snapshot,
                    &entry.detection,
                    &entry.measurement,
                ) {
                    Some(f) => f.whole_nis,
                    // A detection the hypothesis cannot explain counts as at the gate.
                    None => self.whole_gate(&entry.measurement),
                };
                *slot = snapshot;
            }
            let Some(fused) = self.reapply(alternative, &mut snapshot, d, m) else {
                continue;
            };
            if total < kept && best.as_ref().is_none_or(|b| total < b.3) {
                best = Some((afters, snapshot, fused.nis, total));
            }
        }
        let (afters, snapshot, nis, _) = best?;
        let track = self.track.as_mut()?;
        for (entry, after) in track.history.iter_mut().skip(from + 1).zip(afters) {
            entry.after = after;
        }
        self.counters.edge_retries += 1;
        Some((snapshot, nis))
    }

    /// A detection gated after a bounce: the bounce tried again from the last estimate before
    /// it with the spin forgotten (its covariance reset to the prior), every detection since
    /// re-applied. Before a bounce the spin is learned from the flight's curvature alone, which
    /// can misread it and grow sure of it (a spin about the flight's direction, or a fast one
    /// at a high spin parameter); the bounce then kicks the ball another way than predicted,
    /// and the detections after it, which tell the spin, are gated one by one until the track
    /// is refuted. Taken when the detection fuses and the positions since the bounce, `d`'s
    /// included, are more likely with the spin forgotten than as they were (the sum of NIS and
    /// log-determinant of each innovation's covariance: the wider covariance pays for its
    /// width) by more than [`BOUNCE_RETRY_EVIDENCE`], and the detections before `d` at least as
    /// well as they were (a detection that is not the ball, which a spin forgotten can explain
    /// too, pulls the flight away from them); the history is rewritten with it. Returns the
    /// estimate at `d` and its NIS.
    fn retry_bounce_forgetting_spin(
        &mut self,
        d: &Detection,
        m: &Measurement,
    ) -> Option<(Snapshot, f64)> {
        let track = self.track.as_ref()?;
        let bounces = track.now.bounces;
        let history = &track.history;
        let (start, from) = match history.iter().rposition(|e| e.after.bounces < bounces) {
            Some(i) => (history[i].after, i + 1),
            None if track.base.bounces < bounces => (track.base, 0),
            None => return None,
        };
        if history.len() - from > BOUNCE_RETRY_LIMIT {
            return None;
        }
        let mut forgotten = start;
        forgotten.ekf.reset_spin(self.settings.spin_prior_var, None);
        let entries = || history.iter().skip(from);
        let kept = self.hypothesis_cost(start, entries(), d, m)?;
        let retried = self.hypothesis_cost(forgotten, entries(), d, m)?;
        if !retried.fuses_d
            || retried.with_d > kept.with_d - BOUNCE_RETRY_EVIDENCE
            || retried.since > kept.since
        {
            return None;
        }
        // Taken: the estimates since the bounce redone.
        let mut track = self.track.take()?;
        let mut snapshot = forgotten;
        for entry in track.history.iter_mut().skip(from) {
            let (detection, measurement) = (entry.detection, entry.measurement);
            self.reapply(&self.propagator, &mut snapshot, &detection, &measurement);
            entry.after = snapshot;
        }
        self.track = Some(track);
        // The same pass as the one scored above: it fuses `d` again.
        let fused = self.reapply(&self.propagator, &mut snapshot, d, m)?;
        self.counters.bounce_retries += 1;
        Some((snapshot, fused.nis))
    }

    /// How unlikely the positions of `entries` and then `d` are under the hypothesis that
    /// starts at `snapshot` ([`HypothesisCost`]). None when an innovation's covariance is not
    /// positive definite.
    fn hypothesis_cost<'a>(
        &self,
        mut snapshot: Snapshot,
        entries: impl Iterator<Item = &'a Entry>,
        d: &Detection,
        m: &Measurement,
    ) -> Option<HypothesisCost> {
        let mut cost = 0.0;
        for entry in entries {
            let (nis, log_det) =
                self.position_likelihood(&mut snapshot, &entry.detection, &entry.measurement)?;
            cost += nis.min(self.settings.gate_position) + log_det;
            self.reapply(
                &self.propagator,
                &mut snapshot,
                &entry.detection,
                &entry.measurement,
            );
        }
        let (nis, log_det) = self.position_likelihood(&mut snapshot, d, m)?;
        Some(HypothesisCost {
            since: cost,
            with_d: cost + nis + log_det,
            fuses_d: self
                .reapply(&self.propagator, &mut snapshot, d, m)
                .is_some(),
        })
    }

    /// The snapshot moved to `d`'s stamp, and its position's NIS and log-determinant of the
    /// innovation's covariance there (as [`Ekf::nis_and_log_det`]).
    fn position_likelihood(
        &self,
        snapshot: &mut Snapshot,
        d: &Detection,
        m: &Measurement,
    ) -> Option<(f64, f64)> {
        self.advance(snapshot, d.stamp);
        let (z, r) = self.measurement_at(snapshot, m).0.position();
        snapshot.ekf.nis_and_log_det(&z, &position_H(), &r)
    }

    /// A detection re-applied to a hypothesis's snapshot (its table given by `propagator`): the
    /// snapshot is moved to its stamp and, where it fits, updated with it and the fused
    /// measurement returned (nothing learned of the noise, no counter moved).
    fn reapply(
        &self,
        propagator: &Propagator,
        snapshot: &mut Snapshot,
        d: &Detection,
        m: &Measurement,
    ) -> Option<Fused> {
        let fused = self
            .predict_and_update(propagator, snapshot, d, m, None)
            .0
            .ok()?;
        snapshot.record(d.stamp, &fused);
        Some(fused)
    }

    /// The gate of a measurement's every dimension: what a detection a hypothesis cannot explain
    /// counts as when hypotheses are compared.
    fn whole_gate(&self, m: &Measurement) -> f64 {
        match m {
            Measurement::Position { .. } => self.settings.gate_position,
            Measurement::PositionSpin { .. } => self.settings.gate_position_spin,
        }
    }

    /// Fuses a detection older than the newest fused one: roll back, fuse, re-apply the newer.
    pub(super) fn fuse_late(&mut self, d: &Detection, m: Measurement) -> Result<f64, Rejection> {
        let Some(track) = &self.track else {
            return Err(Rejection::TooOld);
        };
        if track.now.stamp - d.stamp > self.settings.rollback || d.stamp < track.base.stamp {
            return Err(Rejection::TooOld);
        }
        if track.history.iter().any(|e| same_frame(&e.detection, d)) {
            return Err(Rejection::Duplicate);
        }
        let index = track
            .history
            .partition_point(|e| e.detection.stamp <= d.stamp);
        let mut snapshot = match index {
            0 => track.base,
            i => track.history[i - 1].after,
        };
        let result = self.fuse(&mut snapshot, d, &m, None);
        self.learn_noise(d);
        let nis = result?;
        let late = Entry {
            detection: *d,
            measurement: m,
            after: snapshot,
        };
        let Some(mut track) = self.track.take() else {
            return Err(Rejection::TooOld);
        };
        for entry in track.history.iter_mut().skip(index) {
            // A re-applied detection that no longer passes the gate is skipped.
            let mut next = snapshot;
            if self
                .fuse(&mut next, &entry.detection, &entry.measurement, None)
                .is_ok()
            {
                snapshot = next;
            } else {
                self.advance(&mut snapshot, entry.detection.stamp);
            }
            entry.after = snapshot;
        }
        let mut index = index;
        if track.history.len() >= self.history_capacity
            && let Some(oldest) = track.history.pop_front()
        {
            track.base = oldest.after;
            index = index.saturating_sub(1);
        }
        track.history.insert(index, late);
        track.now = snapshot;
        self.track = Some(track);
        self.counters.rollbacks += 1;
        self.keep_for_refit(d, &m);
        Ok(nis)
    }

    pub(super) fn push_history(&mut self, entry: Entry) {
        let rollback = self.settings.rollback;
        let capacity = self.history_capacity;
        let Some(track) = self.track.as_mut() else {
            return;
        };
        track.now = entry.after;
        while track.history.len() >= capacity
            || track
                .history
                .front()
                .is_some_and(|e| e.detection.stamp < entry.after.stamp - rollback)
        {
            let Some(oldest) = track.history.pop_front() else {
                break;
            };
            track.base = oldest.after;
        }
        track.history.push_back(entry);
    }
}

#[cfg(test)]
mod tests {
    use super::BOUNCE_RETRY_EVIDENCE;
    use crate::model::stats::chi_square_quantile;

    /// The evidence a bounce retried needs is the likelihood-ratio test's threshold it says.
    #[test]
    fn the_bounce_retry_evidence_is_the_chi_square_quantile_of_the_spin() {
        assert!((BOUNCE_RETRY_EVIDENCE - chi_square_quantile(0.999, 3)).abs() < 0.01);
    }
}
