//! Jumps in the stamps: a detection whose stamp is more than `tracking.timeout` from the ones
//! the estimator runs on is held until the next detection says whether it was a glitch or a new
//! timeline (a new ball after a pause, a camera whose clock restarted).

use super::*;

impl Estimator {
    /// True while a detection whose stamp jumped is held (see [`Self::update`]).
    pub fn holds_a_jump(&self) -> bool {
        self.held.is_some()
    }

    /// Re-counts a held detection (counted as initialising when it was held) with its verdict.
    pub(super) fn recount_held(&mut self, verdict: Verdict) {
        if !matches!(verdict, Verdict::Initializing | Verdict::Held) {
            self.counters.initializing = self.counters.initializing.saturating_sub(1);
            self.count(verdict);
        }
    }

    /// The stamp the current detections run on: the track's last fused one, else the newest
    /// detection initialising one.
    pub(super) fn current_stamp(&self) -> Option<i64> {
        match &self.track {
            Some(track) => Some(track.now.last_fused),
            None => self.pending.last().map(|p| p.stamp),
        }
    }

    /// Holds, confirms or dismisses a jump in the stamps (see [`Self::update`]).
    pub(super) fn screen_jump(&mut self, d: &Detection, m: Measurement) -> Verdict {
        let Some(current) = self.current_stamp() else {
            return self.process(d, m);
        };
        let timeout = self.settings.timeout;
        let offset = d.stamp - current;
        // Either way: a camera whose clock restarted sends stamps from long ago, for good.
        let jump = offset.abs() > timeout;
        if !jump {
            if d.stamp > current && self.held.take().is_some() {
                self.recount_held(Verdict::Rejected(Rejection::StampJump));
            }
            return self.process(d, m);
        }
        match self.held.take() {
            Some((first, first_m))
                if (d.stamp - first.stamp).abs() <= timeout && !same_frame(&first, d) =>
            {
                // Confirmed: a new timeline starts with both detections.
                self.end_track();
                let first_verdict = self.process(&first, first_m);
                self.recount_held(first_verdict);
                self.process(d, m)
            }
            superseded => {
                if superseded.is_some() {
                    self.recount_held(Verdict::Rejected(Rejection::StampJump));
                }
                self.held = Some((*d, m));
                Verdict::Held
            }
        }
    }
}
