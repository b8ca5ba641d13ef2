//! Starting tracks: the detections waiting to initialise one and their fit, a track from the
//! predicted rebound of an announced robot hit, and the continuation of a refuted track on its
//! own detections (the same id).

use super::*;

impl Estimator {
    /// A new track starts: nothing of it depends on the noise scales yet, and no prediction
    /// of the last track is held to learn the model noise from or to score a refit's contest.
    fn forget_the_last_tracks_predictions(&mut self) {
        if let Some(d) = self.sensitivity.as_deref_mut() {
            *d = [StateMatrix::zeros(); NOISE_SCALES];
        }
        if let Some(probe) = self.probe.as_deref_mut() {
            probe.from = None;
        }
        self.contest.held = None;
    }

    pub(super) fn insert_pending(&mut self, d: &Detection) {
        if self.pending.len() >= self.settings.pending_limit() {
            self.pending.remove(0);
        }
        let index = self.pending.partition_point(|p| p.stamp <= d.stamp);
        self.pending.insert(index, *d);
        // Keep only the detections within the initialisation span of the newest.
        let newest = self.pending.last().map_or(d.stamp, |p| p.stamp);
        let span = self.settings.init_span;
        self.pending.retain(|p| newest - p.stamp <= span);
    }

    pub(super) fn initialise(&mut self, d: &Detection) -> Verdict {
        if self
            .pending
            .iter()
            .any(|p| p.stamp == d.stamp && p.source == d.source)
        {
            return Verdict::Rejected(Rejection::Duplicate);
        }
        self.insert_pending(d);
        if self.pending.len() >= self.settings.init_count && !self.try_start_track() {
            // Inconsistent: drop the worst-fitting detection and wait for more.
            if let Some(fit) = self.fit_pending() {
                self.pending.remove(fit.worst);
                self.counters.rejected[Rejection::InitOutlier.index()] += 1;
                self.counters.initializing = self.counters.initializing.saturating_sub(1);
            }
        }
        Verdict::Initializing
    }

    pub(super) fn fit_pending(&self) -> Option<init::InitialFit> {
        // A rough speed from the first and last pending detections, for the timing noise.
        let (first, last) = (self.pending.first()?, self.pending.last()?);
        if first.stamp == last.stamp {
            return None;
        }
        let span = (last.stamp - first.stamp) as f64 * 1e-9;
        let speed_sq = if span > 0.0 {
            ((last.position - first.position) / span).norm_squared()
        } else {
            0.0
        };
        let weights = |d: &Detection| {
            let m = self.measurement(d).ok()?;
            Some(match m {
                Measurement::Position { r, timing, .. } => init::Weights {
                    position_var: r.diagonal().add_scalar(timing * speed_sq),
                    spin: None,
                },
                Measurement::PositionSpin { z, r, timing } => init::Weights {
                    position_var: r
                        .fixed_view::<3, 3>(0, 0)
                        .diagonal()
                        .add_scalar(timing * speed_sq),
                    spin: Some((
                        z.fixed_rows::<3>(3).into_owned(),
                        r.fixed_view::<3, 3>(3, 3).diagonal(),
                    )),
                },
            })
        };
        let theta = self.learned.global().0;
        let (k_d, k_m) = (
            theta[crate::physics::params::DRAG_SCALE],
            theta[crate::physics::params::MAGNUS_SCALE],
        );
        init::fit(
            &self.pending,
            &weights,
            &self.flight.with_scales(k_d, k_m),
            self.settings.gravity,
            &self.settings,
        )
    }

    /// Starts a track from the pending detections when they fit one ballistic flight.
    pub(super) fn try_start_track(&mut self) -> bool {
        // The ended track's lesson is learned before a track takes its prior.
        self.settle_lesson();
        let Some(fit) = self.fit_pending() else {
            return false;
        };
        let gate = chi_square_quantile(self.settings.gate_probability, fit.dof.max(1));
        let speed = fit.x.fixed_rows::<3>(3).norm();
        if fit.chi_square > gate || speed > 40.0 {
            return false;
        }
        let param_prior = self.learned.track_prior(fit.stamp);
        let (theta, p_theta) = param_prior;
        let mut snapshot = Snapshot {
            ekf: Ekf::new(fit.x, fit.P, theta, p_theta),
            stamp: fit.stamp,
            bounces: 0,
            robot_half_bounces: u32::from(already_bounced(&fit.x)),
            last_fused: fit.stamp,
            nis: 0.0,
            whole_nis: 0.0,
            bounce_jump: None,
            spin_measured: fit.spin_measured,
        };
        let first_seen = self.pending.first().map_or(fit.stamp, |d| d.stamp);
        let continued = self
            .continuation
            .take()
            .and_then(|c| self.continues(&c, &fit.x, fit.stamp, first_seen));
        let id = match continued {
            Some((id, before)) => {
                // The same ball: its id, and the bounces it has made.
                snapshot.bounces = before.bounces;
                snapshot.robot_half_bounces =
                    snapshot.robot_half_bounces.max(before.robot_half_bounces);
                self.counters.reanchored += 1;
                id
            }
            None => {
                let id = self.next_track_id;
                self.next_track_id = self.next_track_id.wrapping_add(1).max(1);
                self.counters.tracks += 1;
                id
            }
        };
        self.forget_the_last_tracks_predictions();
        let history = std::mem::take(&mut self.spare_history);
        self.track = Some(Track {
            id,
            now: snapshot,
            base: snapshot,
            history,
            consecutive_rejections: 0,
            param_prior,
            started: fit.stamp,
        });
        self.pending.clear();
        true
    }

    /// Starts the return's track at `d`, a detection after the announced `hit`, from the
    /// predicted rebound of the live track's ball (predicted at the first detection after the
    /// impact, then kept); None (nothing changed but the kept rebound) when there was no live
    /// track before the impact, the hit is impossible or `d` is gated against the rebound.
    pub(super) fn start_from_hit(
        &mut self,
        hit: &RobotHit,
        d: &Detection,
        m: Measurement,
    ) -> Option<Verdict> {
        let kept = self.expected_hit.and_then(|(_, seed)| seed);
        let seed = match kept {
            Some(seed) => seed,
            None => {
                let seed = self.rebound_seed(hit)?;
                self.expected_hit = Some((*hit, Some(seed)));
                seed
            }
        };
        self.settle_lesson();
        let param_prior = self.learned.track_prior(hit.stamp);
        let mut snapshot = seed;
        let nis = self.fuse(&mut snapshot, d, &m, None).ok()?;
        self.learn_noise(d);
        self.end_track();
        let id = self.next_track_id;
        self.next_track_id = self.next_track_id.wrapping_add(1).max(1);
        self.counters.tracks += 1;
        self.counters.seeded_by_hit += 1;
        self.forget_the_last_tracks_predictions();
        let mut history = std::mem::take(&mut self.spare_history);
        history.push_back(Entry {
            detection: *d,
            measurement: m,
            after: snapshot,
        });
        self.track = Some(Track {
            id,
            now: snapshot,
            base: seed,
            history,
            consecutive_rejections: 0,
            param_prior,
            started: d.stamp,
        });
        self.rejected_run.clear();
        Some(Verdict::Fused { nis })
    }

    /// The predicted rebound of the live track's ball at the announced `hit`, with its
    /// covariance; None when there is no live track before the impact or the hit is impossible.
    pub(super) fn rebound_seed(&self, hit: &RobotHit) -> Option<Snapshot> {
        let track = self.track.as_ref()?;
        if track.now.stamp > hit.stamp {
            return None;
        }
        let mut incoming = track.now;
        self.advance(&mut incoming, hit.stamp);
        let ball = BallState::from_vector(&incoming.ekf.x);
        let after = self.racket.hit(&ball, &hit.racket).ok()?.ball;
        let covariance =
            self.racket
                .rebound_covariance(&ball, &incoming.ekf.state_covariance(), &hit.racket)?;
        let (theta, p_theta) = self.learned.track_prior(hit.stamp);
        Some(Snapshot {
            ekf: Ekf::new(after.to_vector(), covariance, theta, p_theta),
            stamp: hit.stamp,
            bounces: 0,
            robot_half_bounces: 0,
            last_fused: hit.stamp,
            nis: 0.0,
            whole_nis: 0.0,
            bounce_jump: None,
            spin_measured: false,
        })
    }

    /// Whether a track starting at `stamp` in state `x`, fitted to detections from
    /// `first_seen` on, is the ball of the refuted track `c`: seen again within
    /// [`tracking.timeout`] of its last fused detection, within [`REANCHOR_DISTANCE`] of where
    /// its estimate had flown to, and moving the same way along the table (a racket hit turns
    /// the ball around). Then its id and the estimate it had flown to.
    pub(super) fn continues(
        &self,
        c: &Continuation,
        x: &crate::physics::StateVector,
        stamp: i64,
        first_seen: i64,
    ) -> Option<(u32, Snapshot)> {
        if first_seen - c.last.last_fused > self.settings.timeout || stamp < c.last.stamp {
            return None;
        }
        let mut flown = c.last;
        self.advance(&mut flown, stamp);
        let apart = (flown.ekf.x.fixed_rows::<3>(0) - x.fixed_rows::<3>(0)).norm();
        (apart <= REANCHOR_DISTANCE && flown.ekf.x[3] * x[3] > 0.0).then_some((c.id, flown))
    }
}
