//! One simulated camera system: a frame clock with a random phase, a box-shaped view, gaussian
//! position (and spin) noise, dropped frames, outliers and a jittered latency (numbers in
//! [`CameraParams`]: 150 fps / 2 mm / 8 ms and 900 fps / 1 mm / 12 rad/s / 3 ms by default).
//!
//! Every frame inside a shot consumes the same fixed number of random draws from the camera's
//! own stream, whatever happens to it, so a session is reproducible draw for draw.

use nalgebra::Vector3;

use super::params::CameraParams;
use crate::model::detection::{Detection, Source, seconds_to_ns};
use crate::model::rng::Rng;
use crate::physics::{BallState, Cursor, Outcome, Propagator, Watch};

/// Nanoseconds per second.
pub(crate) const NS_PER_S: f64 = 1e9;

/// A camera's frame times: `origin + round(k * period)` [ns] for integer k.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FrameClock {
    /// Time of frame 0 [ns].
    pub origin: i64,
    /// Frame period [ns], not necessarily an integer.
    pub period: f64,
}

impl FrameClock {
    /// The stamp of frame `k` [ns].
    pub fn stamp(&self, k: i64) -> i64 {
        self.origin + (k as f64 * self.period).round() as i64
    }

    /// The stamps of the frames in [from, to] [ns], in order.
    pub fn frames(&self, from: i64, to: i64) -> impl Iterator<Item = i64> + '_ {
        let mut k = ((from - self.origin) as f64 / self.period).ceil() as i64 - 1;
        while self.stamp(k) < from {
            k += 1;
        }
        (k..)
            .map(move |k| self.stamp(k))
            .take_while(move |&stamp| stamp <= to)
    }
}

/// What one camera did over a session.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct CameraCounts {
    /// Frames taken while a shot was in flight with the true ball inside the view.
    pub frames_in_view: u64,
    /// Of those, frames dropped (no detection).
    pub dropped: u64,
    /// Detections cut because the reported position fell outside the view.
    pub cut: u64,
    /// Detections delivered.
    pub detections: u64,
    /// Of those, outliers.
    pub outliers: u64,
    /// Of those, detections with a spin measurement.
    pub with_spin: u64,
}

/// The random draws of one frame, taken all together so every frame consumes the same number.
struct FrameDraws {
    dropout: f64,
    outlier: f64,
    noise: Vector3<f64>,
    outlier_direction: Vector3<f64>,
    outlier_distance: f64,
    outlier_confidence: f64,
    spin: f64,
    spin_noise: Vector3<f64>,
    latency: f64,
}

impl FrameDraws {
    fn draw(rng: &mut Rng) -> Self {
        Self {
            dropout: rng.uniform(),
            outlier: rng.uniform(),
            noise: rng.normal3(),
            outlier_direction: rng.unit_vector(),
            outlier_distance: rng.uniform(),
            outlier_confidence: rng.uniform(),
            spin: rng.uniform(),
            spin_noise: rng.normal3(),
            latency: rng.normal(),
        }
    }
}

/// One detection as delivered, with what it was made from.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Measurement {
    /// Arrival time at the estimator [ns]: stamp + latency.
    pub arrival: i64,
    /// The detection.
    pub detection: Detection,
    /// True when it is an outlier.
    pub outlier: bool,
}

/// A free-running frame clock whose intervals are the period plus -1, 0 or +1 jitter, drawn
/// from its own stream; frames are asked for in increasing time, so it keeps its last frame.
#[derive(Debug, Clone)]
pub(crate) struct JitteredClock {
    /// The next frame's stamp [ns].
    next: i64,
    period: f64,
    jitter: f64,
    rng: Rng,
}

impl JitteredClock {
    /// The frames in [from, to], in order (from at or after the previous call's `to`).
    fn frames(&mut self, from: i64, to: i64) -> Vec<i64> {
        let mut frames = Vec::new();
        while self.next <= to {
            if self.next >= from {
                frames.push(self.next);
            }
            let step = (self.rng.index(3) as f64 - 1.0).mul_add(self.jitter, self.period);
            self.next += step.round() as i64;
        }
        frames
    }
}

/// A camera during a session: its parameters, clock, random stream and counts.
#[derive(Debug, Clone)]
pub(crate) struct Camera<'a> {
    pub params: &'a CameraParams,
    pub clock: FrameClock,
    /// The clock that replaces `clock` when the frame intervals are jittered.
    pub jittered: Option<JitteredClock>,
    pub rng: Rng,
    pub counts: CameraCounts,
}

impl<'a> Camera<'a> {
    /// A camera whose frame clock starts at `epoch` plus a phase uniform in one period (its
    /// intervals jittered from `jitter_rng` when the camera's are).
    pub fn new(
        params: &'a CameraParams,
        epoch: i64,
        clock_rng: &mut Rng,
        rng: Rng,
        jitter_rng: Rng,
    ) -> Self {
        let period = NS_PER_S / params.frame_rate;
        let phase = (clock_rng.uniform() * period).floor() as i64;
        Self {
            params,
            clock: FrameClock {
                origin: epoch + phase,
                period,
            },
            jittered: (params.interval_jitter > 0.0).then(|| JitteredClock {
                next: epoch + phase,
                period,
                jitter: params.interval_jitter * NS_PER_S,
                rng: jitter_rng,
            }),
            rng,
            counts: CameraCounts::default(),
        }
    }

    /// Observes a flight launched at `launch_stamp` from `launch` until `end_stamp` [ns]: every
    /// frame in that time, the true state propagated frame to frame with `propagator`. Returns
    /// (measurement, true state) pairs.
    pub fn observe(
        &mut self,
        propagator: &Propagator,
        launch_stamp: i64,
        launch: &BallState,
        end_stamp: i64,
    ) -> Vec<(Measurement, BallState)> {
        let mut out = Vec::new();
        let mut cursor = Cursor::new(0.0, launch);
        let frames: Vec<i64> = match self.jittered.as_mut() {
            Some(jittered) => jittered.frames(launch_stamp, end_stamp),
            None => self.clock.frames(launch_stamp, end_stamp).collect(),
        };
        for stamp in frames {
            let t = (stamp - launch_stamp) as f64 / NS_PER_S;
            let duration = t - cursor.t;
            let outcome = propagator.advance(&mut cursor, duration, Watch::FLIGHT, &mut ());
            if matches!(outcome, Outcome::Terminated(_)) {
                break;
            }
            let truth = cursor.ball();
            let draws = FrameDraws::draw(&mut self.rng);
            if let Some(m) = self.measure(stamp, &truth, &draws) {
                out.push((m, truth));
            }
        }
        out
    }

    /// The detection of one frame, if any.
    fn measure(
        &mut self,
        stamp: i64,
        truth: &BallState,
        draws: &FrameDraws,
    ) -> Option<Measurement> {
        let p = self.params;
        if !p.view.contains(&truth.position) {
            return None;
        }
        self.counts.frames_in_view += 1;
        if draws.dropout < p.dropout_probability {
            self.counts.dropped += 1;
            return None;
        }
        let outlier = draws.outlier < p.outlier_probability;
        let mut position = truth.position + p.position_sigma * draws.noise;
        let mut confidence = p.confidence;
        if outlier {
            let d = p.outlier_displacement;
            position +=
                (d.min + (d.max - d.min) * draws.outlier_distance) * draws.outlier_direction;
            let c = p.outlier_confidence;
            confidence = (c.min + (c.max - c.min) * draws.outlier_confidence) as f32;
        }
        if !p.view.contains(&position) {
            self.counts.cut += 1;
            return None;
        }
        // An outlier is some other blob: no spin can be read from it.
        let spin = (!outlier && draws.spin < p.spin_probability)
            .then(|| truth.spin + p.spin_sigma * draws.spin_noise);
        let latency = (p.latency_mean + p.latency_jitter * draws.latency).max(0.0);
        let arrival = stamp + seconds_to_ns(latency);
        // The tracker's clock: the exposure time rounded to its resolution.
        let stamp = if p.stamp_resolution > 0.0 {
            let resolution = seconds_to_ns(p.stamp_resolution).max(1);
            (stamp as f64 / resolution as f64).round() as i64 * resolution
        } else {
            stamp
        };
        self.counts.detections += 1;
        self.counts.outliers += u64::from(outlier);
        self.counts.with_spin += u64::from(spin.is_some());
        Some(Measurement {
            arrival,
            detection: Detection {
                stamp,
                source: self.source(),
                position,
                position_covariance: None,
                spin,
                spin_covariance: None,
                confidence,
            },
            outlier,
        })
    }

    fn source(&self) -> Source {
        self.params.source
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frame_clock_lists_every_frame_in_the_window_once() {
        let clock = FrameClock {
            origin: 1_000,
            period: NS_PER_S / 150.0,
        };
        let from = 1_000 + 20_000_000; // frame 3 exactly
        let to = from + 99_000_000; // frame 18 is at from + 100 ms
        let stamps: Vec<i64> = clock.frames(from, to).collect();
        // 150 fps over 99 ms: frames 3 to 17 (6.667 ms apart), the first at or after `from`.
        assert_eq!(stamps.len(), 15, "{stamps:?}");
        assert_eq!(stamps[0], clock.stamp(3));
        assert_eq!(stamps[0], from);
        assert!(clock.stamp(2) < from);
        assert!(
            stamps
                .windows(2)
                .all(|w| (w[1] - w[0] - 6_666_667).abs() <= 1)
        );
        assert!(stamps.iter().all(|&s| (from..=to).contains(&s)));
        assert!(clock.stamp(18) > to);
    }
}
