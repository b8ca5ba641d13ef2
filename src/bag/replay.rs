//! Offline replay of a ROS 2 MCAP bag through the node's own code path ([`Pipeline`]): the
//! detections of the bag, in log-time order, go through `Pipeline::handle_detection` exactly as
//! the live node's would, the trajectory due after one (`Pipeline::take_due_trajectory`) flown
//! where the output is written, and the output bag holds the input topics unchanged plus what the
//! node would have published, each with the log time of the detection that produced it. Time comes from the messages only, so two replays give
//! byte-identical files.
//!
//! When the bag carries the simulator's truth (`/ball/truth`: the true state at each detection's
//! stamp; `/ball/truth/intercept`: each shot's true crossing and bounce), the replay scores the
//! estimator with the same [`Scorer`] as `ttball evaluate`.

use std::borrow::Borrow;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use crate::bag::{
    BagContents, BagError, BagMessage, BagReader, BagWriter, ChannelInfo, Damage, channel_of,
    decode, read_bag_file,
};
use crate::config::{Config, TopicsParams};
use crate::eval::{EvalReport, Scorer};
use crate::model::detection::Detection;
use crate::model::frames::Frames;
use crate::model::stats::DurationHistogram;
use crate::offline::smooth::{SmoothedState, Smoothing, smooth};
use crate::online::estimator::{Counters, Estimate, Output, TrackStatus, Waiting};
use crate::ros::msgs::convert::{
    add_static_transforms, detection_from_msg_in, state_from_msg, state_msg,
    truth_intercept_from_msg,
};
use crate::ros::msgs::definitions;
use crate::ros::msgs::tf2_msgs::TFMessage;
use crate::ros::msgs::ttball_msgs::msg::{BallDetection, BallState, InterceptPrediction, RobotHit};
pub use crate::ros::msgs::type_names::{
    DETECTION_TYPE, INTERCEPT_TYPE, MARKERS_TYPE, ODOMETRY_TYPE, ROBOT_HIT_TYPE, STATE_TYPE,
    TF_MESSAGE_TYPE, TRAJECTORY_TYPE,
};
use crate::ros::pipeline::{DueTrajectory, Pipeline, Published};

/// The static transforms' topic (tf2), read by the node and, when a bag has it, by the replay.
pub const TF_STATIC_TOPIC: &str = "/tf_static";
/// The topic of each shot's true crossing and bounce, next to `topics.truth`.
pub fn truth_intercept_topic(truth: &str) -> String {
    format!("{truth}/intercept")
}

/// Why a replay could not run.
#[derive(Debug, thiserror::Error)]
pub enum ReplayError {
    /// Reading or writing a bag failed.
    #[error(transparent)]
    Bag(#[from] BagError),
    /// The bag has no detection topic.
    #[error(
        "{path}: no topic `{topic}` (topics in the bag: {present}); set the detection topic with -p topics.detections:=/your/topic"
    )]
    NoDetections {
        /// The input bag.
        path: PathBuf,
        /// The topic looked for.
        topic: String,
        /// The topics present.
        present: String,
    },
    /// The detection topic carries another type.
    #[error("{path}: topic `{topic}` carries `{found}`, not `{DETECTION_TYPE}`")]
    WrongType {
        /// The input bag.
        path: PathBuf,
        /// The topic.
        topic: String,
        /// Its type.
        found: String,
    },
    /// The detection topic has the detection type's name, but its schema declares other fields.
    #[error(
        "{path}: topic `{topic}` is `{DETECTION_TYPE}`, but not ttball's definition of it: its fields are `{found}`, ttball's are `{expected}`; record it with this version of ttball_msgs (msgs/msg/BallDetection.msg)"
    )]
    SchemaMismatch {
        /// The input bag.
        path: PathBuf,
        /// The topic.
        topic: String,
        /// The bag's fields, `type name; ...`.
        found: String,
        /// ttball's fields.
        expected: String,
    },
}

/// What a replay did.
#[derive(Debug, Clone, PartialEq)]
pub struct ReplaySummary {
    /// The input bag.
    pub input: PathBuf,
    /// The output bag.
    pub output: PathBuf,
    /// Messages read from the input (all topics).
    pub messages: usize,
    /// Detection messages read.
    pub detections: u64,
    /// Detection messages whose payload could not be decoded (skipped).
    pub undecodable: u64,
    /// Robot-hit messages (`topics.robot_hits`) refused: undecodable, in an unknown frame or
    /// with a face normal that is not a unit vector.
    pub robot_hits_refused: u64,
    /// What the estimator did with the decoded ones.
    pub counters: Counters,
    /// How many interceptions were predicted in full and how many moved from the last full one.
    pub intercepts: crate::online::intercept::TrackerCounts,
    /// What the estimator learned (the physics, each source's noise), as it ended.
    pub learned: crate::online::estimator::LearnedSummary,
    /// Messages written to the output bag.
    pub written: u64,
    /// Processing time per detection [ns], mean (each detection's own work: the lessons'
    /// smoothing it waited for or took over left out).
    pub processing_mean_ns: f64,
    /// 99th percentile of the processing time per detection [ns].
    pub processing_p99_ns: f64,
    /// Trajectories published (`/ball/trajectory` with its markers), each after the detection's
    /// own messages.
    pub trajectories: u64,
    /// Time to predict one and make its messages [ns], mean.
    pub trajectory_mean_ns: f64,
    /// Its 99th percentile [ns].
    pub trajectory_p99_ns: f64,
    /// Log time spanned by the detections [s].
    pub recorded_seconds: f64,
    /// Time spent processing them [s], their own work and the trajectories (the lessons'
    /// smoothing left out).
    pub processing_seconds: f64,
    /// Time the detections spent on the lessons worker's smoothing [s]: a replay keeps the live
    /// node's lessons at the same points by waiting where one is due and not yet done, after
    /// taking back and smoothing itself the jobs the worker has not started.
    pub lesson_wait_seconds: f64,
    /// Why the input was read only in part (truncated or corrupt); empty when it was whole.
    pub damage: Vec<Damage>,
    /// True when the replay was interrupted (the output holds what was done, finished).
    pub interrupted: bool,
    /// Accuracy against the bag's truth, when it has one.
    pub accuracy: Option<EvalReport>,
}

impl ReplaySummary {
    /// Recorded duration over processing time.
    pub fn real_time_factor(&self) -> f64 {
        if self.processing_seconds > 0.0 {
            self.recorded_seconds / self.processing_seconds
        } else {
            f64::INFINITY
        }
    }
}

/// The output topics of the pipeline, with their channels.
struct Outputs {
    state: u16,
    intercept: u16,
    trajectory: u16,
    markers: u16,
    /// When `topics.odometry` is set.
    odometry: Option<u16>,
}

impl Outputs {
    /// The output channels of `config`'s topics, added to `writer`.
    fn new<W: std::io::Write + std::io::Seek>(
        writer: &mut BagWriter<W>,
        config: &Config,
    ) -> Result<Self, BagError> {
        let topics = config.resolved_topics();
        Ok(Self {
            state: writer.channel(&topics.state, STATE_TYPE)?,
            intercept: writer.channel(&topics.intercept, INTERCEPT_TYPE)?,
            trajectory: writer.channel(&topics.trajectory, TRAJECTORY_TYPE)?,
            markers: writer.channel(&topics.markers, MARKERS_TYPE)?,
            odometry: match topics.odometry.as_str() {
                "" => None,
                topic => Some(writer.channel(topic, ODOMETRY_TYPE)?),
            },
        })
    }

    /// Writes what the pipeline published for one detection, at its log time `t`; returns how
    /// many messages.
    fn write<W: std::io::Write + std::io::Seek>(
        &self,
        writer: &mut BagWriter<W>,
        t: u64,
        p: &Published,
    ) -> Result<u64, BagError> {
        let mut written = 0;
        if let Some(s) = &p.state {
            writer.write(self.state, STATE_TYPE, t, s)?;
            written += 1;
        }
        if let Some(i) = &p.intercept {
            writer.write(self.intercept, INTERCEPT_TYPE, t, i)?;
            written += 1;
        }
        if let Some(tr) = &p.trajectory {
            writer.write(self.trajectory, TRAJECTORY_TYPE, t, tr)?;
            written += 1;
        }
        if let Some(mk) = &p.markers {
            writer.write(self.markers, MARKERS_TYPE, t, mk)?;
            written += 1;
        }
        if let (Some(channel), Some(o)) = (self.odometry, &p.odometry) {
            writer.write(channel, ODOMETRY_TYPE, t, o)?;
            written += 1;
        }
        Ok(written)
    }
}

/// The channels a replay of `input` with `config` writes, known before it starts: the input's
/// (when its summary names them) and ttball's outputs (e.g. to advertise them to a live view).
pub fn replay_channels(input: &Path, config: &Config) -> Result<Vec<ChannelInfo>, ReplayError> {
    let reader = BagReader::open(input)?;
    let mut channels = reader.channels().to_vec();
    channels.extend(output_channels(&config.resolved_topics()));
    Ok(channels)
}

/// The channels of ttball's outputs on `topics` (an empty topic is off).
pub fn output_channels(topics: &TopicsParams) -> impl Iterator<Item = ChannelInfo> {
    [
        (&topics.state, STATE_TYPE),
        (&topics.intercept, INTERCEPT_TYPE),
        (&topics.trajectory, TRAJECTORY_TYPE),
        (&topics.markers, MARKERS_TYPE),
        (&topics.odometry, ODOMETRY_TYPE),
    ]
    .into_iter()
    .filter(|(topic, _)| !topic.is_empty())
    .filter_map(|(topic, type_name)| ChannelInfo::ros2(topic, type_name))
}

/// What the replay's writing thread is given to write, in the output's order.
enum Writing {
    /// The input's next channel, copied to the output.
    Channel(ChannelInfo),
    /// An input message, copied unchanged (its channel is the input's index).
    Copy(BagMessage),
    /// What the pipeline published for a detection of this log time, with the trajectory due
    /// after it, predicted by the writer: off the detections' thread when it has its own.
    Published(u64, Box<Published>, Option<Box<DueTrajectory>>),
}

/// The output bag as the replay writes it: its writer, the pipeline's channels, the channels
/// copied from the input (by the input's index), how many messages it holds and the times its
/// trajectories took to predict.
struct OutputBag {
    writer: BagWriter<std::io::BufWriter<std::fs::File>>,
    outputs: Outputs,
    copied: Vec<u16>,
    written: Written,
}

/// What an output bag was given: the messages it holds and its trajectories' times [ns].
#[derive(Debug, Default)]
struct Written {
    messages: u64,
    trajectory_times: DurationHistogram,
}

impl OutputBag {
    fn write(&mut self, writing: Writing) -> Result<(), BagError> {
        match writing {
            Writing::Channel(info) => self.copied.push(self.writer.add_channel(&info)?),
            Writing::Copy(m) => {
                let channel =
                    self.copied
                        .get(m.channel)
                        .copied()
                        .ok_or_else(|| BagError::Write {
                            path: self.writer.path().to_path_buf(),
                            reason: format!("input channel {} was never added", m.channel),
                        })?;
                self.writer
                    .write_raw(channel, m.log_time, m.publish_time, &m.data)?;
                self.written.messages += 1;
            }
            Writing::Published(t, mut published, due) => {
                if let Some(due) = due {
                    let started = Instant::now();
                    due.publish_into(&mut published);
                    self.written
                        .trajectory_times
                        .record(u64::try_from(started.elapsed().as_nanos()).unwrap_or(u64::MAX));
                }
                self.written.messages += self.outputs.write(&mut self.writer, t, &published)?;
            }
        }
        Ok(())
    }

    /// Finishes the file (also after an error, which `result` holds and is given first); what
    /// it was given.
    fn finish(self, result: Result<(), BagError>) -> Result<Written, BagError> {
        let finished = self.writer.finish();
        result?;
        finished?;
        Ok(self.written)
    }
}

/// How many messages go to the writing thread at once: one hand-over, one wake-up.
const WRITING_BATCH: usize = 1024;
/// How many batches the replay's loop may run ahead of the writing thread.
const WRITING_QUEUE: usize = 4;

/// Where the replay's writes go. With more than one core to run on, to a thread of its own:
/// encoding, compressing and writing off the estimator's thread, so that the whole run takes
/// about its processing. With one, in the replay's own thread: a second thread there would
/// only take its turns in the middle of detections. Watched (the live view at recorded pace),
/// in the replay's own thread too, so that an interrupted replay stops showing at once. The
/// file is the same, byte for byte, either way: one writer writes it, in the order it is given.
enum Writes {
    /// Written at once; the first error, after which nothing more is written.
    Inline(Box<OutputBag>, Option<BagError>),
    /// Batched to the writing thread.
    Threaded {
        /// What is given but not yet sent.
        batch: Vec<Writing>,
        queue: std::sync::mpsc::SyncSender<Vec<Writing>>,
        thread: std::thread::JoinHandle<Result<Written, BagError>>,
        path: PathBuf,
    },
}

impl Writes {
    /// Starts writing `bag`: on a thread of its own when the process may run on more than one
    /// core and no one watches what is written.
    fn start(bag: OutputBag, path: &Path) -> Result<Self, BagError> {
        if bag.writer.is_observed()
            || std::thread::available_parallelism().map_or(1, |n| n.get()) < 2
        {
            return Ok(Self::Inline(Box::new(bag), None));
        }
        let (queue, given) = std::sync::mpsc::sync_channel(WRITING_QUEUE);
        let thread = std::thread::Builder::new()
            .name("replay-writer".into())
            .spawn(move || {
                let mut bag = bag;
                let written = given
                    .iter()
                    .flatten()
                    .try_for_each(|writing| bag.write(writing));
                bag.finish(written)
            })
            .map_err(|error| BagError::Io {
                path: path.to_path_buf(),
                error,
            })?;
        Ok(Self::Threaded {
            batch: Vec::with_capacity(WRITING_BATCH),
            queue,
            thread,
            path: path.to_path_buf(),
        })
    }

    /// Gives one thing to write; false once writing has failed (the error is
    /// [`Self::finish`]'s).
    fn send(&mut self, writing: Writing) -> bool {
        match self {
            Self::Inline(bag, error) => {
                if error.is_none()
                    && let Err(e) = bag.write(writing)
                {
                    *error = Some(e);
                }
                error.is_none()
            }
            Self::Threaded { batch, queue, .. } => {
                batch.push(writing);
                if batch.len() < WRITING_BATCH {
                    return true;
                }
                let full = std::mem::replace(batch, Vec::with_capacity(WRITING_BATCH));
                queue.send(full).is_ok()
            }
        }
    }

    /// Writes what is given, finishes the file and gives what it was given, or the first
    /// error.
    fn finish(self) -> Result<Written, BagError> {
        match self {
            Self::Inline(bag, error) => bag.finish(error.map_or(Ok(()), Err)),
            Self::Threaded {
                batch,
                queue,
                thread,
                path,
            } => {
                // A thread that stopped on an error gives it below.
                let _ = queue.send(batch);
                drop(queue);
                thread.join().unwrap_or_else(|_| {
                    Err(BagError::Write {
                        path,
                        reason: "the writing thread stopped unexpectedly".into(),
                    })
                })
            }
        }
    }
}

/// The true states a bag carries, by stamp (for `ttball smooth`'s errors).
struct BagTruth {
    states: BTreeMap<i64, crate::physics::BallState>,
    /// The shots' truth (their bounces).
    shots: Vec<crate::eval::ShotTruth>,
}

/// The channels of the truth topics (states on `topic`, shot events beside it) among a bag's,
/// when it has both.
fn truth_channels(channels: &[ChannelInfo], topic: &str) -> Option<(usize, usize)> {
    Some((
        channel_of(channels, topic)?,
        channel_of(channels, &truth_intercept_topic(topic))?,
    ))
}

/// Scoring against the simulator's truth as the bag tells it, in one pass: each shot's event
/// (written at its launch, before its detections) and each detection's true state (written
/// straight after the detection, at its log time). A detection's output waits for its true
/// state; one whose truth does not come before the next detection is not scored.
struct TruthScoring {
    scorer: Scorer,
    /// Each shot's index in the scorer, by its id.
    shots: BTreeMap<u32, usize>,
    /// The latest detection and the estimator's output for it, waiting for its true state.
    waiting: Option<(Detection, Output)>,
}

impl TruthScoring {
    fn new() -> Self {
        Self {
            scorer: Scorer::new(Vec::new()),
            shots: BTreeMap::new(),
            waiting: None,
        }
    }

    /// A shot's event: its true crossing and bounce.
    fn add_shot(&mut self, msg: &InterceptPrediction) {
        let (id, shot) = truth_intercept_from_msg(msg);
        let index = self.scorer.add_shot(shot);
        self.shots.insert(id, index);
    }

    /// A true state: the waiting detection's, when the stamps and a known shot agree, scored.
    fn true_state(&mut self, msg: &BallState) {
        let (stamp, id, state) = state_from_msg(msg);
        let Some(&shot) = self.shots.get(&id) else {
            return;
        };
        if let Some((d, out)) = self.waiting.take_if(|(d, _)| d.stamp == stamp) {
            let outlier = (d.position - state.position).norm() > OUTLIER_DISTANCE;
            self.scorer.score(shot, &d, &state, outlier, &out);
        }
    }
}

/// The truth among `messages` on these channels ([`truth_channels`]): the true states of its
/// shots (those with an event).
fn read_truth<M: Borrow<BagMessage>>(
    (state_channel, event_channel): (usize, usize),
    messages: impl IntoIterator<Item = M>,
) -> BagTruth {
    let mut shots = std::collections::BTreeSet::new();
    let mut shot_truths = Vec::new();
    let mut shot_states = Vec::new();
    for m in messages {
        let m = m.borrow();
        if m.channel == event_channel
            && let Ok(msg) = decode::<InterceptPrediction>(&m.data)
        {
            let (shot, truth) = truth_intercept_from_msg(&msg);
            shots.insert(shot);
            shot_truths.push(truth);
        } else if m.channel == state_channel
            && let Ok(msg) = decode::<BallState>(&m.data)
        {
            shot_states.push(state_from_msg(&msg));
        }
    }
    let states = shot_states
        .into_iter()
        .filter(|(_, shot, _)| shots.contains(shot))
        .map(|(stamp, _, state)| (stamp, state))
        .collect();
    BagTruth {
        states,
        shots: shot_truths,
    }
}

/// The channel of `topic` in a bag read from `path`, checked to carry `BallDetection`.
pub fn detection_channel(
    channels: &[ChannelInfo],
    topic: &str,
    path: &Path,
) -> Result<usize, ReplayError> {
    let Some(channel) = channel_of(channels, topic) else {
        let present: Vec<&str> = channels.iter().map(|c| c.topic.as_str()).collect();
        return Err(ReplayError::NoDetections {
            path: path.to_path_buf(),
            topic: topic.to_owned(),
            present: if present.is_empty() {
                "none".to_string()
            } else {
                present.join(", ")
            },
        });
    };
    let info = &channels[channel];
    if info.schema_name != DETECTION_TYPE {
        return Err(ReplayError::WrongType {
            path: path.to_path_buf(),
            topic: topic.to_owned(),
            found: info.schema_name.clone(),
        });
    }
    // Same name, other fields: the payloads would decode as garbage or not at all.
    if info.schema_encoding == "ros2msg" && !info.schema_data.is_empty() {
        let listed = |text: &str| {
            definitions::fields(text)
                .iter()
                .map(|(ty, name)| format!("{ty} {name}"))
                .collect::<Vec<_>>()
                .join("; ")
        };
        let found = listed(&String::from_utf8_lossy(&info.schema_data));
        let expected = listed(definitions::definition(DETECTION_TYPE).unwrap_or_default());
        if found != expected {
            return Err(ReplayError::SchemaMismatch {
                path: path.to_path_buf(),
                topic: topic.to_owned(),
                found,
                expected,
            });
        }
    }
    Ok(channel)
}

/// A detection further than this from the truth is an outlier for scoring [m].
const OUTLIER_DISTANCE: f64 = 0.03;

/// Replays `input` into `output` (see the module doc), streaming, in one pass: the input is read
/// a chunk at a time, each detection scored against its true state as it follows (a bag with
/// the simulator's truth), and nothing grows with the length of the bag but the scorer's
/// errors. `progress` is called with (bytes read, bytes) now and then; setting `cancel` stops
/// early with a properly finished output.
pub fn replay(
    input: &Path,
    output: &Path,
    config: &Config,
    progress: &mut dyn FnMut(u64, u64),
    cancel: &AtomicBool,
) -> Result<ReplaySummary, ReplayError> {
    replay_observed(input, output, config, progress, cancel, None)
}

/// [`replay`], every message written to `output` shown to `observer` too, as it is written
/// (e.g. the live view at recorded pace: `ttball replay --foxglove`).
pub fn replay_observed(
    input: &Path,
    output: &Path,
    config: &Config,
    progress: &mut dyn FnMut(u64, u64),
    cancel: &AtomicBool,
    observer: Option<crate::bag::Observer>,
) -> Result<ReplaySummary, ReplayError> {
    let mut reader = BagReader::open(input)?;
    let topic = &config.resolved_topics().detections;
    // A finished bag names its channels in its summary: the detection topic is checked before
    // anything is written. A bag without a summary (cut off) is checked as its channels appear.
    let detections_on = if !reader.has_summary() {
        None
    } else {
        Some(detection_channel(reader.channels(), topic, input)?)
    };
    let mut writer = BagWriter::create(output)?;
    if let Some(observer) = observer {
        writer.observe(observer);
    }
    let outputs = Outputs::new(&mut writer, config)?;
    let bag = OutputBag {
        writer,
        outputs,
        copied: Vec::new(),
        written: Written::default(),
    };
    let mut writing = Writes::start(bag, output)?;
    let mut pipeline = Pipeline::new(config);
    if std::thread::available_parallelism().map_or(1, |n| n.get()) >= 2 {
        // The lessons are waited for where they are due: the same output as inline. A thread
        // that cannot start leaves them inline.
        let _ = pipeline.run_lessons_on_a_worker(Waiting::Wait);
    }
    let mut session = Session {
        pipeline,
        copied: 0,
        detections_on,
        tf_static_on: None,
        robot_hits_on: None,
        robot_hits_topic: config.resolved_topics().robot_hits,
        truth_on: None,
        truth_topic: config.resolved_topics().truth,
        truth: None,
        messages: 0,
        detections: 0,
        undecodable: 0,
        robot_hits_refused: 0,
        times: DurationHistogram::new(),
        first_last: None,
    };
    let mut interrupted = false;
    let result = (|| -> Result<(), ReplayError> {
        while let Some(m) = reader.next_message() {
            if cancel.load(Ordering::Relaxed) {
                interrupted = true;
                break;
            }
            let channel = m.channel;
            if !session.on_message(&reader, &mut writing, m, topic, input)? {
                // The writing thread stopped on an error, which its end gives.
                break;
            }
            if session.detections.is_multiple_of(1024) && Some(channel) == session.detections_on {
                let (done, total) = reader.progress();
                progress(done, total);
            }
        }
        if session.detections_on.is_none() && !interrupted {
            detection_channel(reader.channels(), topic, input)?;
        }
        Ok(())
    })();
    // The output is finished whatever happened above.
    let written = writing.finish();
    result?;
    let written = written?;
    let (done, total) = reader.progress();
    progress(done, total);
    Ok(session.summary(
        input,
        output,
        reader.damage().to_vec(),
        interrupted,
        written,
    ))
}

/// One replay in progress: the node's pipeline, where the inputs are, and what is counted. Each
/// input message goes through [`Session::on_message`], in log-time order; what is written goes
/// to [`Writes`].
struct Session {
    pipeline: Pipeline,
    /// How many input channels the output copies so far (the reader's first ones).
    copied: usize,
    detections_on: Option<usize>,
    tf_static_on: Option<usize>,
    robot_hits_on: Option<usize>,
    robot_hits_topic: String,
    /// The truth's channels (states, shot events), once both are known.
    truth_on: Option<(usize, usize)>,
    truth_topic: String,
    /// The scoring against the truth, from the bag's first shot event.
    truth: Option<TruthScoring>,
    messages: usize,
    detections: u64,
    undecodable: u64,
    robot_hits_refused: u64,
    times: DurationHistogram,
    /// Log times of the first and the latest detection [ns].
    first_last: Option<(u64, u64)>,
}

impl Session {
    /// Copies one input message to the output and, as the node would, feeds it to the pipeline
    /// (a detection, a static transform or an announced robot hit), writing what it publishes
    /// after it. False when the writing thread has stopped (on an error).
    fn on_message(
        &mut self,
        reader: &BagReader,
        writing: &mut Writes,
        m: BagMessage,
        topic: &str,
        input: &Path,
    ) -> Result<bool, ReplayError> {
        self.messages += 1;
        if self.copied < reader.channels().len() {
            while self.copied < reader.channels().len() {
                let info = reader.channels()[self.copied].clone();
                if !writing.send(Writing::Channel(info)) {
                    return Ok(false);
                }
                self.copied += 1;
            }
            self.find_channels(reader, topic, input)?;
        }
        let published = self.feed(&m);
        let log_time = m.log_time;
        if !writing.send(Writing::Copy(m)) {
            return Ok(false);
        }
        Ok(match published {
            Some((published, due)) => writing.send(Writing::Published(
                log_time,
                Box::new(published),
                due.map(Box::new),
            )),
            None => true,
        })
    }

    /// Looks up the channels the replay reads among the reader's, once new ones appear (a bag
    /// without a summary names its channels as it goes; a topic's first channel is the one
    /// read): the detections (checked to be `BallDetection`), `/tf_static`, the robot's hits
    /// and the simulator's truth.
    fn find_channels(
        &mut self,
        reader: &BagReader,
        topic: &str,
        input: &Path,
    ) -> Result<(), ReplayError> {
        if self.detections_on.is_none() && reader.channel(topic).is_some() {
            self.detections_on = Some(detection_channel(reader.channels(), topic, input)?);
        }
        if self.tf_static_on.is_none() {
            self.tf_static_on = reader.channel(TF_STATIC_TOPIC);
        }
        if self.robot_hits_on.is_none() {
            self.robot_hits_on = reader
                .channel(&self.robot_hits_topic)
                .filter(|&c| reader.channels()[c].schema_name == ROBOT_HIT_TYPE);
        }
        if self.truth_on.is_none() {
            self.truth_on = truth_channels(reader.channels(), &self.truth_topic);
        }
        Ok(())
    }

    /// Feeds one input message to the pipeline; what it published, when it is a detection, and
    /// the trajectory due after it.
    fn feed(&mut self, m: &BagMessage) -> Option<(Published, Option<DueTrajectory>)> {
        // Static transforms bring detections in other frames into `table`, as in the node.
        if Some(m.channel) == self.tf_static_on {
            if let Ok(msg) = decode::<TFMessage>(&m.data) {
                self.pipeline.on_static_transforms(&msg);
            }
            return None;
        }
        // The simulator's truth, scored against as it comes.
        if let Some((states, events)) = self.truth_on
            && (m.channel == states || m.channel == events)
        {
            if m.channel == events {
                if let Ok(msg) = decode::<InterceptPrediction>(&m.data) {
                    self.truth
                        .get_or_insert_with(TruthScoring::new)
                        .add_shot(&msg);
                }
            } else if let (Some(truth), Ok(msg)) =
                (self.truth.as_mut(), decode::<BallState>(&m.data))
            {
                truth.true_state(&msg);
            }
            return None;
        }
        // The robot's announced hits seed the return's track, as in the node.
        if Some(m.channel) == self.robot_hits_on {
            let refused = match decode::<RobotHit>(&m.data) {
                Ok(msg) => self.pipeline.on_robot_hit(&msg).is_err(),
                Err(_) => true,
            };
            self.robot_hits_refused += u64::from(refused);
            return None;
        }
        if Some(m.channel) != self.detections_on {
            return None;
        }
        self.detections += 1;
        let Ok(msg) = decode::<BallDetection>(&m.data) else {
            self.undecodable += 1;
            return None;
        };
        let (started, waited) = (Instant::now(), self.pipeline.lesson_wait());
        let step = self.pipeline.handle_detection(&msg);
        // The detection's own work: what it waited for the worker's lessons is the worker's.
        let own = started
            .elapsed()
            .saturating_sub(self.pipeline.lesson_wait() - waited);
        self.times
            .record(u64::try_from(own.as_nanos()).unwrap_or(u64::MAX));
        let due = self.pipeline.take_due_trajectory();
        self.first_last = Some(
            self.first_last
                .map_or((m.log_time, m.log_time), |(a, _)| (a, m.log_time)),
        );
        if let Some(truth) = self.truth.as_mut() {
            truth.waiting = step.detection.zip(step.output);
        }
        Some((step.published, due))
    }

    /// What the replay did.
    fn summary(
        mut self,
        input: &Path,
        output: &Path,
        damage: Vec<Damage>,
        interrupted: bool,
        written: Written,
    ) -> ReplaySummary {
        let timing = self.times.summary();
        let trajectory_timing = written.trajectory_times.summary();
        // The bag has ended: the live track's lesson is learned, as when a node stops.
        self.pipeline.end_of_input();
        let counters = self.pipeline.counters();
        let estimator = self.pipeline.estimator();
        ReplaySummary {
            input: input.to_path_buf(),
            output: output.to_path_buf(),
            messages: self.messages,
            detections: self.detections,
            undecodable: self.undecodable,
            robot_hits_refused: self.robot_hits_refused,
            counters,
            intercepts: estimator.intercept_counts(),
            learned: estimator.learned_summary(),
            written: written.messages,
            processing_mean_ns: timing.mean,
            processing_p99_ns: timing.p99,
            trajectories: trajectory_timing.count as u64,
            trajectory_mean_ns: trajectory_timing.mean,
            trajectory_p99_ns: trajectory_timing.p99,
            recorded_seconds: self.first_last.map_or(0.0, |(a, b)| (b - a) as f64 * 1e-9),
            processing_seconds: (timing.total + trajectory_timing.total) * 1e-9,
            lesson_wait_seconds: estimator.lesson_wait().as_secs_f64(),
            damage,
            interrupted,
            accuracy: self.truth.map(|t| t.scorer.report(counters)),
        }
    }
}

/// The detections of a bag, decoded.
#[derive(Debug, Clone)]
pub struct BagDetections {
    /// The whole bag.
    pub contents: BagContents,
    /// The detections brought into the table frame (`frames.table_frame`, by the bag's
    /// `/tf_static` as the node would), in log-time (arrival) order.
    pub detections: Vec<Detection>,
    /// For every message of the bag, the index of its detection in `detections`.
    pub message_detection: Vec<Option<usize>>,
    /// Detection messages that could not be decoded.
    pub undecodable: u64,
    /// Detection messages in a frame not connected to the table frame.
    pub unknown_frame: u64,
}

/// Reads `path` and decodes its detections (`topics.detections`).
pub fn read_detections(path: &Path, config: &Config) -> Result<BagDetections, ReplayError> {
    let contents = read_bag_file(path)?;
    let channel = detection_channel(
        &contents.channels,
        &config.resolved_topics().detections,
        path,
    )?;
    let tf_static = contents
        .channels
        .iter()
        .position(|c| c.topic == TF_STATIC_TOPIC);
    let mut frames = Frames::new(&config.frames.table_frame);
    let mut detections = Vec::new();
    let mut message_detection = Vec::with_capacity(contents.messages.len());
    let (mut undecodable, mut unknown_frame) = (0u64, 0u64);
    for m in &contents.messages {
        let mut index = None;
        if Some(m.channel) == tf_static
            && let Ok(msg) = decode::<TFMessage>(&m.data)
        {
            add_static_transforms(&mut frames, &msg);
        }
        if m.channel == channel {
            match decode::<BallDetection>(&m.data).map(|msg| detection_from_msg_in(&msg, &frames)) {
                Err(_) => undecodable += 1,
                Ok(Err(_)) => unknown_frame += 1,
                Ok(Ok(d)) => {
                    index = Some(detections.len());
                    detections.push(d);
                }
            }
        }
        message_detection.push(index);
    }
    Ok(BagDetections {
        contents,
        detections,
        message_detection,
        undecodable,
        unknown_frame,
    })
}

/// What `ttball smooth` did with one bag.
#[derive(Debug, Clone, PartialEq)]
pub struct SmoothSummary {
    /// The input bag.
    pub input: PathBuf,
    /// The output bag.
    pub output: PathBuf,
    /// Detection messages read.
    pub detections: u64,
    /// Detection messages whose payload could not be decoded.
    pub undecodable: u64,
    /// Detection messages not in the `table` frame.
    pub unknown_frame: u64,
    /// What the smoother did (flights, failures, outliers, the estimator's counters).
    pub smoothing: Smoothing,
    /// Messages written to the output bag.
    pub written: u64,
    /// Why the input was read only in part; empty when it was whole.
    pub damage: Vec<Damage>,
    /// Errors of the smoothed states against the bag's truth, when it has one.
    pub truth_errors: Option<TruthErrors>,
}

/// Root-mean-square errors of estimates against the simulator's truth.
#[derive(Debug, Clone, Copy, PartialEq, Default, serde::Serialize)]
pub struct TruthErrors {
    /// States compared.
    pub count: usize,
    /// States within [`crate::eval::BOUNCE_WINDOW`] of a bounce, left out of the errors.
    pub at_bounce: usize,
    /// Position [m].
    pub position: f64,
    /// Velocity [m/s].
    pub velocity: f64,
    /// Spin [rad/s].
    pub spin: f64,
}

/// Smooths `input` into `output`: the input's messages unchanged plus, on `topics.smoothed`
/// (`ttball_msgs/msg/BallState`), the whole-flight fit at every detection the estimator took
/// ([`crate::offline::smooth`]), each with its detection's log time. `progress` gets (flights done,
/// flights); setting `cancel` stops fitting and writes what is done, finished.
pub fn smooth_bag(
    input: &Path,
    output: &Path,
    config: &Config,
    progress: &mut dyn FnMut(usize, usize),
    cancel: &AtomicBool,
) -> Result<SmoothSummary, ReplayError> {
    let BagDetections {
        contents,
        detections,
        message_detection,
        undecodable,
        unknown_frame,
    } = read_detections(input, config)?;
    let count = message_detection.iter().flatten().count() as u64 + undecodable + unknown_frame;
    let truth = truth_channels(&contents.channels, &config.resolved_topics().truth)
        .map(|channels| read_truth(channels, &contents.messages));
    let smoothing = smooth(config, &detections, progress, cancel);
    let mut by_detection: Vec<Option<&SmoothedState>> = vec![None; detections.len()];
    for s in &smoothing.states {
        by_detection[s.index] = Some(s);
    }

    let mut writer = BagWriter::create(output)?;
    let mut written = 0u64;
    let result = (|| -> Result<(), ReplayError> {
        let mut copied = Vec::with_capacity(contents.channels.len());
        for channel in &contents.channels {
            copied.push(writer.add_channel(channel)?);
        }
        let smoothed = writer.channel(&config.resolved_topics().smoothed, STATE_TYPE)?;
        for (m, index) in contents.messages.iter().zip(&message_detection) {
            writer.write_raw(copied[m.channel], m.log_time, m.publish_time, &m.data)?;
            written += 1;
            if let Some(s) = index.and_then(|i| by_detection[i]) {
                writer.write(
                    smoothed,
                    STATE_TYPE,
                    m.log_time,
                    &smoothed_msg(s, &config.frames.table_frame),
                )?;
                written += 1;
            }
        }
        Ok(())
    })();
    let finished = writer.finish();
    result?;
    finished?;

    let truth_errors = truth.map(|truth| {
        let mut sums = TruthErrors::default();
        for s in &smoothing.states {
            if truth.shots.iter().any(|shot| shot.at_bounce(s.stamp)) {
                sums.at_bounce += 1;
            } else if let Some(t) = truth.states.get(&s.stamp) {
                let e = &s.fitted.state;
                sums.count += 1;
                sums.position += (e.position - t.position).norm_squared();
                sums.velocity += (e.velocity - t.velocity).norm_squared();
                sums.spin += (e.spin - t.spin).norm_squared();
            }
        }
        let n = sums.count.max(1) as f64;
        TruthErrors {
            count: sums.count,
            at_bounce: sums.at_bounce,
            position: (sums.position / n).sqrt(),
            velocity: (sums.velocity / n).sqrt(),
            spin: (sums.spin / n).sqrt(),
        }
    });
    Ok(SmoothSummary {
        input: input.to_path_buf(),
        output: output.to_path_buf(),
        detections: count,
        undecodable,
        unknown_frame,
        smoothing,
        written,
        damage: contents.damage,
        truth_errors,
    })
}

/// A smoothed state as a `BallState` message: status TRACKING, `nis` the detection's squared
/// whitened residual against the smoothed state.
fn smoothed_msg(s: &SmoothedState, frame: &str) -> BallState {
    state_msg(
        &Estimate {
            stamp: s.stamp,
            track_id: s.track_id,
            status: TrackStatus::Tracking,
            state: s.fitted.state,
            covariance: s.fitted.covariance,
            bounces: s.fitted.bounces,
            nis: s.nis,
        },
        frame,
    )
}
