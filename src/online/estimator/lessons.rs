//! The lessons of ended tracks on their way into the adaptation, off the detection path
//! (docs/estimator.md, "The lessons"). A track's flight is smoothed ([`super::smoother`]) inline
//! or on a worker thread fed over crossbeam channels ([`Lessons::spawn_worker`]), and its lesson
//! enters before the first detection stamped [`LESSON_DELAY`] after the one that ended the
//! track, so what is learned, and when, depends on the data alone. At most [`MAX_PENDING`] wait;
//! what is dropped is counted by reason ([`Dropped`]). A caller that waits for a lesson due
//! (a replay) first takes back the jobs the worker has not started and smooths them itself: the
//! same lessons, without waiting for the worker to be scheduled. The detections' buffers travel
//! with the jobs and come back with the lessons.

use std::collections::VecDeque;
use std::panic::{AssertUnwindSafe, catch_unwind};
use std::time::{Duration, Instant};

use crossbeam::channel::{Receiver, Sender, TryRecvError, bounded};

use super::smoother::{Lesson, LessonJob, Smoother, TrackRecord};

/// How long after the detection that ended a track its lesson enters the adaptation [ns]: a
/// second of play, several hundred times what a smoothing takes, so that a live node's worker is
/// done long before and a replay hundreds of times faster than real time rarely waits for it.
pub const LESSON_DELAY: i64 = 1_000_000_000;

/// The most lessons waiting at a time.
pub const MAX_PENDING: usize = 4;

/// Why a track's smoothed lesson was dropped (the track teaches its filter's lesson instead).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Dropped {
    /// [`MAX_PENDING`] lessons were already waiting (a burst of short tracks).
    Backlog,
    /// The worker had not finished it when it was due, and the caller does not wait (the node).
    Late,
    /// The smoothing failed on the worker (it panicked), or the worker was gone.
    Failed,
}

impl Dropped {
    /// Every reason, in the order of [`LessonCounts::dropped`].
    pub const ALL: [Self; 3] = [Self::Backlog, Self::Late, Self::Failed];

    /// A short snake_case name for summaries and diagnostics.
    pub fn name(self) -> &'static str {
        match self {
            Self::Backlog => "backlog",
            Self::Late => "late",
            Self::Failed => "failed",
        }
    }

    /// Its place in [`Self::ALL`] (the declaration's order).
    pub(crate) fn index(self) -> usize {
        self as usize
    }
}

/// What became of the ended tracks' lessons.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct LessonCounts {
    /// Tracks whose lesson was their flight smoothed.
    pub smoothed: u64,
    /// Lessons dropped, by reason in the order of [`Dropped::ALL`].
    pub dropped: [u64; Dropped::ALL.len()],
}

impl LessonCounts {
    /// Lessons dropped for one reason.
    pub fn dropped(&self, reason: Dropped) -> u64 {
        self.dropped[reason.index()]
    }
}

/// Whether the caller waits for a lesson the worker has not finished when it is due.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Waiting {
    /// Wait (a replay: the same lessons, at the same points, with one core or more).
    Wait,
    /// Never wait on a detection: drop the lesson and count it (the live node).
    Never,
}

/// What the worker returns for a job: its number, the lesson (`None`: the smoothing failed) and
/// the job's detections' buffer.
type Done = (u64, Option<Lesson>, TrackRecord);

/// The worker thread's ends of its channels.
#[derive(Debug)]
struct Worker {
    jobs: Sender<(u64, LessonJob)>,
    done: Receiver<Done>,
    waiting: Waiting,
    /// The jobs' other end, for a caller that waits ([`Waiting::Wait`]): the jobs the worker has
    /// not started, taken back when due.
    unstarted: Option<Receiver<(u64, LessonJob)>>,
}

impl Worker {
    /// A worker's channels for a caller `waiting` or not: the caller's ends, then the thread's
    /// (its jobs' inbox and its lessons' outbox).
    fn channels(waiting: Waiting) -> (Self, Receiver<(u64, LessonJob)>, Sender<Done>) {
        let (jobs, inbox) = bounded::<(u64, LessonJob)>(MAX_PENDING);
        let (outbox, done) = bounded::<Done>(MAX_PENDING);
        let unstarted = (waiting == Waiting::Wait).then(|| inbox.clone());
        let worker = Self {
            jobs,
            done,
            waiting,
            unstarted,
        };
        (worker, inbox, outbox)
    }
}

/// A lesson waiting to enter the adaptation.
#[derive(Debug, Clone)]
struct Pending {
    /// Its number.
    id: u64,
    /// The first stamp it enters before [ns].
    due: i64,
    /// The job, until the worker took it (inline, it stays here until due).
    job: Option<LessonJob>,
    /// What the worker returned for it (`None` inside: the smoothing failed).
    done: Option<Option<Lesson>>,
    /// The filter's lesson of the same track.
    filter: Lesson,
}

/// The lessons of ended tracks (see the module doc).
#[derive(Debug)]
pub(crate) struct Lessons {
    pending: VecDeque<Pending>,
    next_id: u64,
    worker: Option<Worker>,
    /// The buffers inline smoothing works in.
    smoother: Smoother,
    /// Detections' buffers back from lessons, for the next tracks.
    spare: Vec<TrackRecord>,
    counts: LessonCounts,
    /// How long callers have spent on the worker's lessons ([`Waiting::Wait`]).
    waited: Duration,
}

impl Clone for Lessons {
    /// The same lessons waiting, run inline: a lesson the worker has taken and not yet returned
    /// is not in the clone (it is counted as failed there when due), so a clone of lessons run
    /// inline (an estimator's default) is exact.
    fn clone(&self) -> Self {
        Self {
            pending: self.pending.clone(),
            next_id: self.next_id,
            worker: None,
            smoother: Smoother::new(),
            spare: Vec::with_capacity(MAX_PENDING + 1),
            counts: self.counts,
            waited: Duration::ZERO,
        }
    }
}

impl Lessons {
    /// No lesson waiting; lessons run inline.
    pub(crate) fn new() -> Self {
        Self {
            pending: VecDeque::with_capacity(MAX_PENDING),
            next_id: 0,
            worker: None,
            smoother: Smoother::new(),
            spare: Self::first_records(),
            counts: LessonCounts::default(),
            waited: Duration::ZERO,
        }
    }

    /// A live track's record and one waiting, with room for as many as may wait: no
    /// allocation per track in steady play.
    fn first_records() -> Vec<TrackRecord> {
        let mut records = Vec::with_capacity(MAX_PENDING + 1);
        records.extend([TrackRecord::with_room(), TrackRecord::with_room()]);
        records
    }

    /// What became of the lessons so far.
    pub(crate) fn counts(&self) -> LessonCounts {
        self.counts
    }

    /// Runs the smoothing on a thread of its own from now on, the caller `waiting` for a lesson
    /// due and not done or not. The thread ends when these lessons are dropped.
    pub(crate) fn spawn_worker(&mut self, waiting: Waiting) -> std::io::Result<()> {
        let (worker, inbox, outbox) = Worker::channels(waiting);
        std::thread::Builder::new()
            .name("ttball-lessons".into())
            .spawn(move || work(&inbox, &outbox))?;
        // crossbeam keeps a context per thread, allocated at the thread's first wait on a
        // channel: taken here (nothing is sent yet), not when a detection first waits.
        let _ = worker
            .done
            .recv_timeout(std::time::Duration::from_millis(1));
        self.worker = Some(worker);
        Ok(())
    }

    /// A record for a track's detections: one back from an earlier lesson, else a new one.
    pub(crate) fn buffer(&mut self) -> TrackRecord {
        self.spare.pop().unwrap_or_else(TrackRecord::with_room)
    }

    /// Takes a record back for the next tracks (one never allocated is let go).
    pub(crate) fn recycle(&mut self, mut buffer: TrackRecord) {
        buffer.clear();
        if buffer.observations.capacity() > 0 && self.spare.len() <= MAX_PENDING {
            self.spare.push(buffer);
        }
    }

    /// Queues an ended track's job, due [`LESSON_DELAY`] after `now` (the stamp of the
    /// detection that ended it); returns the lesson to learn now in its stead when it cannot
    /// wait (the backlog full: the filter's own).
    pub(crate) fn queue(&mut self, job: LessonJob, now: i64) -> Option<Lesson> {
        self.collect();
        if self.pending.len() >= MAX_PENDING {
            return Some(self.drop_job(job));
        }
        let id = self.next_id;
        self.next_id += 1;
        let filter = job.filter;
        let job = match &self.worker {
            None => Some(job),
            Some(worker) => match worker.jobs.try_send((id, job)) {
                Ok(()) => None,
                // The worker is still busy with lessons already dropped as late: this one is
                // dropped too rather than run on a caller that never waits.
                Err(e) if worker.waiting == Waiting::Never => {
                    return Some(self.drop_job(e.into_inner().1));
                }
                Err(e) => Some(e.into_inner().1),
            },
        };
        self.pending.push_back(Pending {
            id,
            due: now.saturating_add(LESSON_DELAY),
            job,
            done: None,
            filter,
        });
        None
    }

    /// The lessons waiting, each as the filter's lesson of its track: a smoothed flight enters
    /// only when due, so that what is published depends on the data alone, never on when the
    /// worker finished.
    pub(crate) fn waiting(&self) -> impl Iterator<Item = Lesson> + '_ {
        self.pending.iter().map(|p| p.filter)
    }

    /// A job that cannot wait, counted: its track teaches the filter's lesson.
    fn drop_job(&mut self, job: LessonJob) -> Lesson {
        self.counts.dropped[Dropped::Backlog.index()] += 1;
        let lesson = job.filter;
        self.recycle(job.record);
        lesson
    }

    /// The next lesson due before `stamp` (every waiting one with `all`: the input's end),
    /// if any.
    pub(crate) fn next_due(&mut self, stamp: i64, all: bool) -> Option<Lesson> {
        if !all && stamp < self.pending.front()?.due {
            return None;
        }
        self.collect();
        let mut pending = self.pending.pop_front()?;
        if let Some(job) = pending.job.take() {
            let lesson = self.smoother.lesson(&job);
            self.recycle(job.record);
            return Some(self.count(lesson));
        }
        let waits = all
            || self
                .worker
                .as_ref()
                .is_some_and(|w| w.waiting == Waiting::Wait);
        if pending.done.is_none() && waits {
            pending.done = self
                .smooth_unstarted(pending.id)
                .or_else(|| self.wait_for(pending.id));
        }
        // A smoothing dropped leaves its track the filter's lesson.
        let dropped = match pending.done {
            Some(Some(lesson)) => return Some(self.count(lesson)),
            Some(None) => Dropped::Failed,
            None if waits || self.worker.is_none() => Dropped::Failed,
            None => Dropped::Late,
        };
        self.counts.dropped[dropped.index()] += 1;
        Some(pending.filter)
    }

    /// Takes what the worker has returned into the lessons waiting for it (a lesson no longer
    /// waited for gives its buffer back); a worker that is gone is forgotten.
    fn collect(&mut self) {
        while let Some(worker) = &self.worker {
            match worker.done.try_recv() {
                Ok(done) => self.file(done),
                Err(TryRecvError::Empty) => return,
                Err(TryRecvError::Disconnected) => self.worker = None,
            }
        }
    }

    /// Takes back the jobs the worker has not started, oldest first, and smooths them here,
    /// until job `id` (due now) or a later one: the lessons the worker would have returned,
    /// without waiting for it to be scheduled. The lesson of `id` if it was among them (else the
    /// worker is on it).
    fn smooth_unstarted(&mut self, id: u64) -> Option<Option<Lesson>> {
        let started = Instant::now();
        let mut found = None;
        while let Some((taken, job)) = self
            .worker
            .as_ref()
            .and_then(|w| w.unstarted.as_ref()?.try_recv().ok())
        {
            let lesson = smoothed(&mut self.smoother, &job);
            if taken == id {
                self.recycle(job.record);
                found = Some(lesson);
                break;
            }
            self.file((taken, lesson, job.record));
            if taken > id {
                break;
            }
        }
        self.waited += started.elapsed();
        found
    }

    /// Waits for the worker's lesson of job `id` (the ones before it filed as they come);
    /// `None` when the worker is gone.
    fn wait_for(&mut self, id: u64) -> Option<Option<Lesson>> {
        let started = Instant::now();
        let lesson = loop {
            let Some(Ok(done)) = self.worker.as_ref().map(|w| w.done.recv()) else {
                self.worker = None;
                break None;
            };
            if done.0 == id {
                self.recycle(done.2);
                break Some(done.1);
            }
            self.file(done);
        };
        self.waited += started.elapsed();
        lesson
    }

    /// How long callers have spent on the worker's lessons in all, waiting for them or smoothing
    /// the ones it had not started: time on the detection path that is the worker's, not the
    /// detection's (a replay's, [`Waiting::Wait`]).
    pub(crate) fn waited(&self) -> Duration {
        self.waited
    }

    /// Files one returned lesson with the lesson waiting for it.
    fn file(&mut self, (id, lesson, buffer): Done) {
        self.recycle(buffer);
        if let Some(p) = self.pending.iter_mut().find(|p| p.id == id) {
            p.done = Some(lesson);
        }
    }

    fn count(&mut self, lesson: Lesson) -> Lesson {
        self.counts.smoothed += u64::from(lesson.smoothed);
        lesson
    }

    /// Forgets every waiting lesson (a reset).
    pub(crate) fn forget(&mut self) {
        while let Some(pending) = self.pending.pop_front() {
            if let Some(job) = pending.job {
                self.recycle(job.record);
            }
        }
    }
}

/// A job's lesson as the worker makes it: `None` when the smoothing panicked (caught; the
/// smoother's buffers start afresh).
fn smoothed(smoother: &mut Smoother, job: &LessonJob) -> Option<Lesson> {
    let lesson = catch_unwind(AssertUnwindSafe(|| smoother.lesson(job))).ok();
    if lesson.is_none() {
        *smoother = Smoother::new();
    }
    lesson
}

/// The worker thread: each job's lesson, in order, a panicking smoothing reported as failed,
/// until the jobs' channel closes or no one takes the lessons any more.
fn work(inbox: &Receiver<(u64, LessonJob)>, outbox: &Sender<Done>) {
    let mut smoother = Smoother::new();
    for (id, job) in inbox {
        let lesson = smoothed(&mut smoother, &job);
        if outbox.send((id, lesson, job.record)).is_err() {
            return;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::Config;
    use crate::online::ekf::Ekf;
    use crate::online::estimator::fusion::{Fusion, Snapshot};
    use crate::online::estimator::smoother::Flown;
    use crate::physics::{ParamCovariance, ParamVector, StateMatrix, StateVector};

    /// A job whose filter's lesson is told by its posterior's drag scale `tag`, of a track
    /// with too few detections to be smoothed (its lesson is the filter's).
    fn job(tag: f64) -> LessonJob {
        let config = Config::default();
        let prior = (ParamVector::repeat(1.0), ParamCovariance::identity() * 0.01);
        let mut posterior = prior;
        posterior.0[0] = tag;
        LessonJob {
            fusion: Fusion::new(&config, ParamVector::zeros()),
            base: Snapshot::starting(
                Ekf::new(
                    StateVector::zeros(),
                    StateMatrix::identity(),
                    prior.0,
                    prior.1,
                ),
                0,
                false,
            ),
            record: TrackRecord::with_room(),
            filter: Lesson {
                prior,
                posterior,
                started: 0,
                ended: 0,
                smoothed: false,
                flown: Flown::default(),
            },
        }
    }

    /// Gives `lessons` a worker that takes jobs and returns nothing until told: its channels,
    /// no thread (the test is the worker: it takes jobs from the inbox, answers on the outbox).
    fn hand_worked(
        lessons: &mut Lessons,
        waiting: Waiting,
    ) -> (Receiver<(u64, LessonJob)>, Sender<Done>) {
        let (worker, inbox, outbox) = Worker::channels(waiting);
        lessons.worker = Some(worker);
        (inbox, outbox)
    }

    /// A lesson enters at the first stamp [`LESSON_DELAY`] after the detection that ended its
    /// track, not one nanosecond before, in the order the tracks ended.
    #[test]
    fn a_lesson_is_due_a_fixed_time_after_its_track_ended() {
        let mut lessons = Lessons::new();
        assert_eq!(lessons.queue(job(0.9), 1_000), None);
        assert_eq!(lessons.queue(job(0.8), 2_000), None);
        assert_eq!(lessons.next_due(1_000 + LESSON_DELAY - 1, false), None);
        let first = lessons.next_due(1_000 + LESSON_DELAY, false).expect("due");
        assert_eq!(first.posterior.0[0], 0.9);
        assert_eq!(lessons.next_due(1_000 + LESSON_DELAY, false), None);
        let second = lessons.next_due(i64::MIN, true).expect("the input's end");
        assert_eq!(second.posterior.0[0], 0.8);
        assert_eq!(lessons.counts(), LessonCounts::default());
    }

    /// One lesson more than [`MAX_PENDING`] is dropped and counted; its track teaches the
    /// filter's lesson at once.
    #[test]
    fn a_full_backlog_drops_the_lesson_and_counts_it() {
        let mut lessons = Lessons::new();
        for k in 0..MAX_PENDING {
            assert_eq!(lessons.queue(job(0.5 + k as f64 * 0.1), 0), None);
        }
        let now = lessons.queue(job(0.4), 0).expect("the filter's lesson");
        assert_eq!(now.posterior.0[0], 0.4);
        assert_eq!(lessons.counts().dropped(Dropped::Backlog), 1);
        assert_eq!(lessons.waiting().count(), MAX_PENDING);
    }

    /// A worker that has not finished a lesson when it is due: a caller that never waits drops
    /// the smoothing (counted late), learns the filter's lesson and does not block; the lesson
    /// the worker returns later is thrown away, its record kept. A worker that is gone fails its
    /// lessons, counted, each track teaching its filter's lesson.
    #[test]
    fn a_lesson_not_done_in_time_is_dropped_for_a_caller_that_never_waits() {
        let mut lessons = Lessons::new();
        let (inbox, outbox) = hand_worked(&mut lessons, Waiting::Never);
        assert_eq!(lessons.queue(job(0.9), 0), None);
        let late = lessons
            .next_due(LESSON_DELAY, false)
            .expect("the filter's lesson");
        assert_eq!((late.posterior.0[0], late.smoothed), (0.9, false));
        assert_eq!(lessons.counts().dropped(Dropped::Late), 1);
        // The worker finishes it afterwards: filed nowhere, its record back.
        let (id, taken) = inbox.try_recv().expect("the job was sent");
        let spare = lessons.spare.len();
        outbox
            .send((id, Some(taken.filter), taken.record))
            .expect("sent");
        assert_eq!(lessons.queue(job(0.8), LESSON_DELAY), None);
        assert_eq!(lessons.spare.len(), spare + 1);
        // The worker gone: the lesson waiting fails.
        drop((inbox, outbox));
        let failed = lessons
            .next_due(2 * LESSON_DELAY, false)
            .expect("the filter's lesson");
        assert_eq!(failed.posterior.0[0], 0.8);
        assert_eq!(lessons.next_due(i64::MAX, true), None);
        assert_eq!(lessons.counts().dropped(Dropped::Failed), 1);
        assert!(lessons.worker.is_none());
    }

    /// Until it is due, a lesson waiting counts as its filter's lesson whether or not the worker
    /// has returned the smoothed one: what is published before then cannot depend on the
    /// worker's speed.
    #[test]
    fn a_lesson_the_worker_returned_early_is_not_seen_before_it_is_due() {
        let mut lessons = Lessons::new();
        let (inbox, outbox) = hand_worked(&mut lessons, Waiting::Wait);
        assert_eq!(lessons.queue(job(0.9), 0), None);
        let before: Vec<f64> = lessons.waiting().map(|l| l.posterior.0[0]).collect();
        let (id, taken) = inbox.try_recv().expect("the job was sent");
        let mut smoothed = taken.filter;
        smoothed.posterior.0[0] = 0.7;
        outbox
            .send((id, Some(smoothed), taken.record))
            .expect("sent");
        lessons.collect();
        let after: Vec<f64> = lessons.waiting().map(|l| l.posterior.0[0]).collect();
        assert_eq!((before, after), (vec![0.9], vec![0.9]));
        let due = lessons.next_due(LESSON_DELAY, false).expect("due");
        assert_eq!(due.posterior.0[0], 0.7);
    }

    /// A caller that waits takes back, when a lesson is due, the jobs the worker has not
    /// started and smooths them itself: the lessons inline smoothing learns, at the same points,
    /// none dropped. The due job the worker is on is waited for, a later one taken back on the
    /// way filed until it is due.
    #[test]
    fn a_waiting_caller_smooths_the_jobs_the_worker_has_not_started() {
        let mut inline = Lessons::new();
        let mut idle = Lessons::new();
        let (inbox, outbox) = hand_worked(&mut idle, Waiting::Wait);
        for lessons in [&mut inline, &mut idle] {
            for (k, tag) in [0.7, 0.6, 0.5].into_iter().enumerate() {
                assert_eq!(lessons.queue(job(tag), k as i64), None);
            }
        }
        // The worker is on the first job and answers once the caller has taken the second.
        let (id, first) = inbox.try_recv().expect("the first job");
        let (watched, answers) = (inbox.clone(), outbox.clone());
        let worker = std::thread::spawn(move || {
            while watched.len() > 1 {
                std::thread::yield_now();
            }
            answers
                .send((id, Some(first.filter), first.record))
                .expect("sent");
        });
        for due in 0..3 {
            let a = inline.next_due(due + LESSON_DELAY, false);
            let b = idle.next_due(due + LESSON_DELAY, false);
            assert!(a.is_some(), "{due}");
            assert_eq!(a, b, "{due}");
        }
        worker.join().expect("the worker's stand-in");
        assert!(inbox.is_empty());
        drop(outbox);
        assert_eq!(idle.counts(), inline.counts());
        assert!(idle.waited() > Duration::ZERO);
    }
}
