//! What the estimator thread does with the samples it takes off the detections subscription
//! before the pipeline sees them: the bounded drop-oldest queue (`node.queue_capacity`) and the
//! count of samples lost before the node, from gaps in each publisher's sequence numbers (RTPS
//! numbers a writer's samples 1, 2, 3, ... (DDS 1.4 / RTPS 2.5 §8.3.5.4); a best-effort sample
//! lost on the network or overwritten in RustDDS's reader history before the node took it
//! leaves a gap).

use std::collections::VecDeque;
use std::time::Instant;

use crate::ros::msgs::ttball_msgs::msg::BallDetection;

/// A detection taken off DDS, with the instant DDS received it.
pub type Queued = (BallDetection, Instant);

/// The detections taken off DDS and waiting for the estimator: at most `capacity`; when full,
/// the oldest goes.
pub struct DetectionQueue {
    waiting: VecDeque<Queued>,
    capacity: usize,
}

impl DetectionQueue {
    /// An empty queue of at most `capacity` (at least 1) detections.
    pub fn new(capacity: usize) -> Self {
        Self {
            waiting: VecDeque::with_capacity(capacity.clamp(1, 4096)),
            capacity: capacity.max(1),
        }
    }

    /// Queues a detection DDS received at `received`; returns whether the oldest had to be
    /// dropped for it.
    pub fn push(&mut self, detection: BallDetection, received: Instant) -> bool {
        let full = self.waiting.len() >= self.capacity;
        if full {
            self.waiting.pop_front();
        }
        self.waiting.push_back((detection, received));
        full
    }

    /// The oldest waiting detection.
    pub fn pop(&mut self) -> Option<Queued> {
        self.waiting.pop_front()
    }

    /// Detections waiting.
    pub fn len(&self) -> usize {
        self.waiting.len()
    }

    /// Whether none is waiting.
    pub fn is_empty(&self) -> bool {
        self.waiting.is_empty()
    }
}

/// Publishers whose last sequence number is kept; a newer one replaces the one seen first (a
/// restarted camera driver is a new publisher).
const MAX_PUBLISHERS: usize = 32;

/// The last sequence number taken from each publisher.
#[derive(Debug)]
pub struct SequenceGaps<P> {
    last: Vec<(P, i64)>,
}

impl<P: PartialEq> SequenceGaps<P> {
    /// No publisher seen yet.
    pub fn new() -> Self {
        Self {
            last: Vec::with_capacity(MAX_PUBLISHERS),
        }
    }

    /// Takes the sample `sequence` of `publisher`; returns how many of the publisher's samples
    /// before it never arrived (0 for its first sample, a repeated or an older one).
    pub fn take(&mut self, publisher: P, sequence: i64) -> u64 {
        match self.last.iter_mut().find(|(p, _)| *p == publisher) {
            Some((_, last)) => {
                let missing = sequence.saturating_sub(*last).saturating_sub(1);
                *last = (*last).max(sequence);
                u64::try_from(missing).unwrap_or(0)
            }
            None => {
                if self.last.len() >= MAX_PUBLISHERS {
                    self.last.remove(0);
                }
                self.last.push((publisher, sequence));
                0
            }
        }
    }
}

impl<P: PartialEq> Default for SequenceGaps<P> {
    fn default() -> Self {
        Self::new()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn detection(sec: i32) -> BallDetection {
        let mut d = BallDetection::default();
        d.header.stamp.sec = sec;
        d
    }

    #[test]
    fn a_full_queue_drops_the_oldest() {
        let mut queue = DetectionQueue::new(4);
        let now = Instant::now();
        let dropped = (0..10)
            .filter(|&sec| queue.push(detection(sec), now))
            .count();
        assert_eq!(dropped, 6);
        assert_eq!(queue.len(), 4);
        let kept: Vec<i32> = std::iter::from_fn(|| queue.pop())
            .map(|(d, _)| d.header.stamp.sec)
            .collect();
        assert_eq!(kept, [6, 7, 8, 9], "the newest stay, in order");
        assert!(queue.is_empty());
    }

    #[test]
    fn gaps_count_the_missing_samples_of_each_publisher() {
        let mut gaps = SequenceGaps::new();
        // Publisher 'a' is first seen at 5 (samples before the match are not losses).
        assert_eq!(gaps.take('a', 5), 0);
        assert_eq!(gaps.take('a', 6), 0);
        assert_eq!(gaps.take('b', 1), 0);
        assert_eq!(gaps.take('a', 9), 2, "7 and 8 missing");
        assert_eq!(gaps.take('b', 2), 0, "publishers are counted apart");
        assert_eq!(gaps.take('a', 9), 0, "a repeat is no loss");
        assert_eq!(gaps.take('a', 8), 0, "nor is a late one");
        assert_eq!(gaps.take('a', 10), 0, "the late one did not move the last");
        assert_eq!(
            gaps.take('b', i64::MAX),
            u64::try_from(i64::MAX - 3).unwrap()
        );
    }

    #[test]
    fn publishers_are_kept_in_bounded_memory() {
        let mut gaps = SequenceGaps::new();
        for publisher in 0..10 * MAX_PUBLISHERS {
            assert_eq!(gaps.take(publisher, 1), 0);
            assert_eq!(gaps.take(publisher, 3), 1);
        }
        assert_eq!(gaps.last.len(), MAX_PUBLISHERS);
    }
}
