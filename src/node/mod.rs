//! The live ROS 2 node (`ttball node`), on ros2-client (pure-Rust ROS 2 on RustDDS): detections
//! in from `topics.detections`, [`Pipeline::handle_detection`] then
//! [`Pipeline::add_due_trajectory`] (the code path `ttball replay` runs), state, intercept,
//! trajectory, markers and diagnostics out, and three services, private to the node:
//! - `~/predict_trajectory` (`ttball_msgs/srv/PredictTrajectory`): the flight of the live track
//!   or of a given state ([`Pipeline::predict_trajectory`]);
//! - `~/predict_rebound` (`ttball_msgs/srv/PredictRebound`): the ball's rebound off the racket
//!   for a given stroke and its return flight ([`Pipeline::predict_rebound`]);
//! - `~/plan_return` (`ttball_msgs/srv/PlanReturn`): the racket command that returns the live
//!   track's ball (at its predicted interception) or a given ball to a target
//!   ([`Pipeline::plan_return`]).
//!
//! Threads: the one estimator thread takes detections off the subscription itself (RustDDS's
//! reader wakes it), runs the pipeline and publishes the outputs and the diagnostics. Before each
//! detection it takes everything DDS holds into its queue (`node.queue_capacity`; when full the
//! oldest is dropped and counted), so a burst is shed oldest first, as it would be by a queue
//! between two threads, without a hand-over on the way of every detection. The DDS thread takes
//! service requests, of every service, off DDS and hands them to the estimator thread through a
//! small channel (so that they see the live track); their replies come back to it, and it sends
//! them. A third thread spins ros2-client's node (graph discovery, `ros_discovery_info`).
//! [`NodeHandle::stop`] stops the DDS thread first; the estimator then takes what DDS holds,
//! processes and publishes what was queued, and ends; then DDS shuts down.

#[cfg(all(feature = "humble", feature = "jazzy"))]
compile_error!(
    "the features `humble` and `jazzy` exclude each other (jazzy is a default feature): build \
     Humble's node with `--no-default-features --features cli,humble`"
);
#[cfg(not(any(feature = "humble", feature = "jazzy")))]
compile_error!("the node speaks one ROS 2 distribution: enable the feature `jazzy` or `humble`");

/// The ROS 2 distribution this build speaks (the feature `jazzy` or `humble`): its
/// `ros_discovery_info` layout (GIDs of 16 bytes from Iron on, 24 before).
pub const ROS_DISTRIBUTION: &str = if cfg!(feature = "humble") {
    "humble"
} else {
    "jazzy"
};

mod affinity;
mod dds;
mod diagnostics;
mod foxglove;
mod intake;
mod keeper;
pub mod parameters;
mod play;
pub mod rosout;
mod services;

use std::pin::Pin;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::task::{Context, Poll, Wake, Waker};
use std::thread::JoinHandle;
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use crossbeam::channel::{self, Receiver, Select, Sender, TrySendError};
use futures::channel::{mpsc, oneshot};
use futures::{FutureExt, Stream, StreamExt};
use ros2_client::{Gid, MessageInfo, Node, Publisher, ReadResult, RmwRequestId, Subscription};
use serde::Serialize;
use tracing::{debug, info, warn};

pub use dds::domain_id;
use diagnostics::dropped_lessons_warnings;
pub use diagnostics::{
    Snapshot, SourceExpectation, SourceWindow, TransportCounters, Window, diagnostics_msg,
    source_status,
};
pub use play::{Latency, LatencyReport, PlayOptions, PlaySummary, play};

use crate::bag::ChannelInfo;
use crate::bag::live_view::LiveView;
use crate::bag::mcap_time;
use crate::bag::replay::{
    DETECTION_TYPE, INTERCEPT_TYPE, MARKERS_TYPE, ROBOT_HIT_TYPE, STATE_TYPE, TRAJECTORY_TYPE,
};
use crate::bag::replay::{ODOMETRY_TYPE, TF_MESSAGE_TYPE, TF_STATIC_TOPIC, output_channels};
use crate::config::{Config, SourceIndex};
use crate::model::detection::Source;
use crate::model::stats::{DurationHistogram, DurationSummary};
use crate::online::estimator::{Counters, Dropped, LearnedSummary, Verdict, Waiting};
use crate::ros::msgs::diagnostic_msgs::DiagnosticArray;
use crate::ros::msgs::geometry_msgs::{Quaternion, Transform, TransformStamped, Vector3};
use crate::ros::msgs::nav_msgs::Odometry;
use crate::ros::msgs::rosgraph_msgs::Clock;
use crate::ros::msgs::std_msgs::Header;
use crate::ros::msgs::tf2_msgs::TFMessage;
use crate::ros::msgs::ttball_msgs::msg::{
    BallDetection, BallState, InterceptPrediction, PredictedTrajectory, RobotHit,
};
pub use crate::ros::msgs::type_names::{
    CLOCK_TYPE, DIAGNOSTICS_TYPE, PLAN_RETURN_TYPE, PREDICT_REBOUND_TYPE, PREDICT_TRAJECTORY_TYPE,
};
use crate::ros::msgs::visualization_msgs::MarkerArray;
use crate::ros::pipeline::{Pipeline, Published};
use intake::{DetectionQueue, Queued, SequenceGaps};
use parameters::Parameters;
use ros2_client::parameters::raw::ParameterEvent;
use services::{Effect, Reply, Servers, Service};

impl ros2_client::Message for BallDetection {}
impl ros2_client::Message for Clock {}
impl ros2_client::Message for TFMessage {}
impl ros2_client::Message for RobotHit {}

/// Base name of the trajectory service, private to the node (`~/predict_trajectory`).
pub const PREDICT_TRAJECTORY_SERVICE: &str = "predict_trajectory";
/// Base name of the rebound service, private to the node (`~/predict_rebound`).
pub const PREDICT_REBOUND_SERVICE: &str = "predict_rebound";
/// Base name of the racket command service, private to the node (`~/plan_return`).
pub const PLAN_RETURN_SERVICE: &str = "plan_return";

/// The simulated time's topic, followed with `use_sim_time`.
pub const CLOCK_TOPIC: &str = "/clock";

/// Service requests that may wait for the estimator thread; more are refused as busy.
const REQUEST_QUEUE: usize = 16;

/// Why the node could not start or run.
#[derive(Debug, thiserror::Error)]
pub enum NodeError {
    /// `ROS_DOMAIN_ID` is not a domain id.
    #[error(
        "ROS_DOMAIN_ID={0:?} is not a DDS domain id: set it to a whole number from 0 to 232, or unset it for domain 0"
    )]
    DomainId(String),
    /// A node, topic or service name is malformed.
    #[error("invalid ROS 2 name {0}")]
    Name(String),
    /// DDS refused to create something (participant, topic, reader, writer).
    #[error("DDS: {0}")]
    Dds(String),
    /// The node's threads cannot run on the CPUs `node.cpus` names.
    #[error("{0}")]
    Cpus(String),
    /// A thread of the node could not start or ended abnormally.
    #[error("node thread: {0}")]
    Thread(String),
    /// Reading the bag to play failed.
    #[error(transparent)]
    Replay(#[from] crate::bag::replay::ReplayError),
    /// The Foxglove live view could not start.
    #[error(transparent)]
    LiveView(#[from] crate::bag::live_view::LiveViewError),
}

/// Where the node runs: DDS domain and interfaces. [`Placement::from_env`] reads them as ROS 2
/// does.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Placement {
    /// DDS domain (`ROS_DOMAIN_ID`).
    pub domain: u16,
    /// Addresses of the interfaces DDS may use; `None` = all.
    pub interfaces: Option<Vec<std::net::IpAddr>>,
    /// Where to serve the Foxglove live view as well (`--foxglove HOST:PORT`); `None`: nowhere.
    pub live_view: Option<String>,
    /// Where to keep what the estimator learns (`--learned FILE`), rewritten as it learns and
    /// when the node stops; `None`: nowhere.
    pub learned_file: Option<std::path::PathBuf>,
    /// What that file is written against: the node's configuration without the learned files
    /// among its layers (`config::yaml::without_learned_files`), so that what an earlier run
    /// learned and this one did not move stays in it; `None`: the node's configuration.
    pub learned_base: Option<Config>,
    /// Publish the node's log records on `/rosout` (`--disable-rosout-logs`: false).
    pub rosout: bool,
}

impl Placement {
    /// The domain from `ROS_DOMAIN_ID` and the interfaces from the configuration and
    /// `ROS_LOCALHOST_ONLY` / `ROS_AUTOMATIC_DISCOVERY_RANGE`.
    pub fn from_env(config: &Config) -> Result<Self, NodeError> {
        let var = |name: &str| std::env::var(name).ok();
        Ok(Self {
            domain: dds::domain_id(var("ROS_DOMAIN_ID").as_deref())?,
            interfaces: dds::interfaces(
                &config.node,
                var("ROS_LOCALHOST_ONLY").as_deref(),
                var("ROS_AUTOMATIC_DISCOVERY_RANGE").as_deref(),
            ),
            live_view: None,
            learned_file: None,
            learned_base: None,
            rosout: true,
        })
    }

    /// The interfaces in words, for logs.
    pub fn describe_interfaces(&self) -> String {
        match &self.interfaces {
            None => "all interfaces".to_owned(),
            Some(list) => list
                .iter()
                .map(ToString::to_string)
                .collect::<Vec<_>>()
                .join(", "),
        }
    }
}

/// What the node did, returned when it stops.
#[derive(Debug, Clone, PartialEq)]
pub struct NodeSummary {
    /// The estimator's counters.
    pub counters: Counters,
    /// What happened before the estimator and to the outputs.
    pub transport: TransportCounters,
    /// Processing time per detection over the whole run: mean [ns].
    pub processing_mean_ns: f64,
    /// Longest processing time of one detection [ns].
    pub processing_max_ns: f64,
    /// Time in the node per detection [ns]: from RustDDS receiving the sample (its reception
    /// timestamp) to the estimator thread having published its state and intercept (waking the
    /// estimator + queue wait + processing + publishing); over the whole run, in constant memory.
    pub in_node: DurationSummary,
    /// How long the node ran [s].
    pub seconds: f64,
    /// What the estimator had learned when the node stopped.
    pub learned: NodeLearned,
}

/// What a node's estimator had learned when it stopped, and the configuration it ran with then
/// (its parameters as last set).
#[derive(Debug, Clone, PartialEq)]
pub struct NodeLearned {
    /// The configuration the estimator ran with at the end.
    pub config: Config,
    /// What it learned.
    pub learned: LearnedSummary,
}

/// A running node. Dropping it without [`NodeHandle::stop`] leaves its threads running until
/// the process ends.
pub struct NodeHandle {
    stop: Option<oneshot::Sender<()>>,
    dds: Option<JoinHandle<Result<NodeSummary, NodeError>>>,
    ended: Receiver<()>,
    name: String,
}

impl NodeHandle {
    /// The node's fully qualified name, e.g. `/ttball`.
    pub fn name(&self) -> &str {
        &self.name
    }

    /// Fires (disconnects) when the node stops on its own, e.g. after a fatal DDS error; for
    /// `crossbeam::select!` beside a signal channel.
    pub fn ended(&self) -> &Receiver<()> {
        &self.ended
    }

    /// Stops the node cleanly: no more detections are taken, those queued are processed and
    /// published, then DDS is shut down.
    pub fn stop(mut self) -> Result<NodeSummary, NodeError> {
        if let Some(stop) = self.stop.take() {
            let _ = stop.send(());
        }
        match self.dds.take().map(JoinHandle::join) {
            Some(Ok(result)) => result,
            Some(Err(_)) => Err(NodeError::Thread("the DDS thread panicked".to_owned())),
            None => Err(NodeError::Thread("the node was already stopped".to_owned())),
        }
    }
}

/// Counters shared by the DDS and estimator threads.
#[derive(Debug, Default)]
struct Shared {
    received: AtomicU64,
    undecodable: AtomicU64,
    dropped_queue_full: AtomicU64,
    lost_before_node: AtomicU64,
    publish_errors: AtomicU64,
    service_requests: AtomicU64,
    service_busy: AtomicU64,
}

impl Shared {
    fn snapshot(&self) -> TransportCounters {
        let get = |c: &AtomicU64| c.load(Ordering::Relaxed);
        TransportCounters {
            received: get(&self.received),
            undecodable: get(&self.undecodable),
            dropped_queue_full: get(&self.dropped_queue_full),
            lost_before_node: get(&self.lost_before_node),
            publish_errors: get(&self.publish_errors),
            service_requests: get(&self.service_requests),
            service_busy: get(&self.service_busy),
        }
    }

    fn add(counter: &AtomicU64) -> u64 {
        counter.fetch_add(1, Ordering::Relaxed) + 1
    }
}

/// A service request in the queue to the estimator thread, and its reply on the way back.
type PendingRequest = (RmwRequestId, services::Request);
type PendingReply = (RmwRequestId, Reply);

/// The node's publishers.
struct Outputs {
    state: Publisher<BallState>,
    intercept: Publisher<InterceptPrediction>,
    trajectory: Publisher<PredictedTrajectory>,
    markers: Publisher<MarkerArray>,
    diagnostics: Publisher<DiagnosticArray>,
    parameter_events: Publisher<ParameterEvent>,
    /// When `topics.odometry` is set.
    odometry: Option<Publisher<Odometry>>,
}

/// Starts the node with a validated configuration: creates the participant, the node, its
/// subscription, publishers and services, then starts its threads, on the CPUs `node.cpus`
/// names (all of them, RustDDS's included) or wherever the OS puts them.
pub fn start(config: &Config, placement: &Placement) -> Result<NodeHandle, NodeError> {
    let cpus = config
        .node
        .cpu_list()
        .map_err(|reason| NodeError::Cpus(format!("node.cpus {:?}: {reason}", config.node.cpus)))?;
    affinity::start_on(&cpus, || start_here(config, placement))
}

/// The node's publishers of its outputs (`topics.*`, reliable at `qos.outputs_depth`) and of
/// `/parameter_events`.
fn create_outputs(
    node: &mut Node,
    context: &ros2_client::Context,
    config: &Config,
) -> Result<Outputs, NodeError> {
    let topics = &config.resolved_topics();
    let output_qos = dds::reliable(config.qos.outputs_depth);
    let parameter_events = node
        .create_publisher(&context.get_parameter_events_topic(), None)
        .map_err(dds::error)?;
    Ok(Outputs {
        odometry: match topics.odometry.as_str() {
            "" => None,
            topic => Some(publisher(node, topic, ODOMETRY_TYPE, &output_qos)?),
        },
        parameter_events,
        state: publisher(node, &topics.state, STATE_TYPE, &output_qos)?,
        intercept: publisher(node, &topics.intercept, INTERCEPT_TYPE, &output_qos)?,
        trajectory: publisher(node, &topics.trajectory, TRAJECTORY_TYPE, &output_qos)?,
        markers: publisher(node, &topics.markers, MARKERS_TYPE, &output_qos)?,
        diagnostics: publisher(node, &topics.diagnostics, DIAGNOSTICS_TYPE, &output_qos)?,
    })
}

/// The node's other inputs: `/tf_static` (its topic, to publish the table's pose on too) and
/// the robot's announced hits.
fn create_transform_and_hit_inputs(
    node: &mut Node,
    config: &Config,
) -> Result<
    (
        ros2_client::dds::rustdds::Topic,
        Subscription<TFMessage>,
        Subscription<RobotHit>,
    ),
    NodeError,
> {
    let tf_topic = node
        .create_topic(
            &dds::name(TF_STATIC_TOPIC)?,
            dds::message_type(TF_MESSAGE_TYPE),
            &dds::tf_static(),
        )
        .map_err(dds::error)?;
    let tf_static = node
        .create_subscription(&tf_topic, None)
        .map_err(dds::error)?;
    let robot_hits_topic = node
        .create_topic(
            &dds::name(&config.resolved_topics().robot_hits)?,
            dds::message_type(ROBOT_HIT_TYPE),
            &dds::reliable(10),
        )
        .map_err(dds::error)?;
    let robot_hits = node
        .create_subscription(&robot_hits_topic, None)
        .map_err(dds::error)?;
    Ok((tf_topic, tf_static, robot_hits))
}

/// The table's pose published on `/tf_static`, when the configuration places the table in a
/// parent frame; the publisher is kept for the node's life (the topic is transient local).
fn publish_table_pose(
    node: &mut Node,
    tf_topic: &ros2_client::dds::rustdds::Topic,
    table_pose: Option<&TFMessage>,
) -> Result<Option<Publisher<TFMessage>>, NodeError> {
    let Some(msg) = table_pose else {
        return Ok(None);
    };
    let publisher: Publisher<TFMessage> =
        node.create_publisher(tf_topic, None).map_err(dds::error)?;
    if publisher.publish(msg.clone()).is_err() {
        warn!("the table's pose could not be published on {TF_STATIC_TOPIC}");
    }
    Ok(Some(publisher))
}

/// The node's pipeline: its lessons on a worker the detections never wait for, the table's
/// pose taken when the node publishes one.
fn node_pipeline(config: &Config, table_pose: Option<&TFMessage>) -> Pipeline {
    let mut pipeline = Pipeline::new(config);
    if let Err(e) = pipeline.run_lessons_on_a_worker(Waiting::Never) {
        warn!("no thread for the tracks' lessons ({e}): they run between detections");
    }
    if let Some(msg) = table_pose {
        pipeline.on_static_transforms(msg);
    }
    pipeline
}

/// A running Foxglove live view and the topics it shows.
type RunningLiveView = (LiveView, crate::config::TopicsParams);

/// The Foxglove live view, when asked for, and the receiver of its app's requests (one that
/// never delivers without a live view).
fn start_live_view(
    placement: &Placement,
    topics: &crate::config::TopicsParams,
    fq_name: &str,
) -> Result<(Option<RunningLiveView>, Receiver<foxglove::AppRequest>), NodeError> {
    let Some(address) = &placement.live_view else {
        return Ok((None, channel::never()));
    };
    let (app_tx, app_rx) = channel::bounded::<foxglove::AppRequest>(REQUEST_QUEUE);
    let channels: Vec<_> = ChannelInfo::ros2(&topics.detections, DETECTION_TYPE)
        .into_iter()
        .chain(output_channels(topics))
        .collect();
    let view = LiveView::start_with(
        address,
        &channels,
        Some(foxglove::interaction(&app_tx, fq_name)),
    )?;
    info!(
        "Foxglove live view on ws://{}:{} (in Foxglove: Open connection)",
        address.rsplit_once(':').map_or("", |(host, _)| host),
        view.port()
    );
    Ok((Some((view, topics.clone())), app_rx))
}

/// The keeper of the learned file, when asked for.
fn start_keeper(
    placement: &Placement,
    config: &Config,
    fq_name: &str,
) -> Result<Option<keeper::LearnedKeeper>, NodeError> {
    let Some(path) = &placement.learned_file else {
        return Ok(None);
    };
    keeper::LearnedKeeper::start(
        path.clone(),
        placement
            .learned_base
            .clone()
            .unwrap_or_else(|| config.clone()),
        fq_name.to_owned(),
    )
    .map(Some)
    .map_err(|e| NodeError::Thread(e.to_string()))
}

/// Logs where the node runs and what it reads and writes.
fn log_start(config: &Config, placement: &Placement, fq_name: &str) {
    let topics = config.resolved_topics();
    let service_names = Service::ALL
        .iter()
        .map(|s| format!("{fq_name}/{}", s.name()))
        .collect::<Vec<_>>()
        .join(", ");
    info!(
        "node {fq_name} on DDS domain {} (ROS 2 {ROS_DISTRIBUTION}), {}{}: detections from {} (best effort, depth {}), outputs on {}, {}, {}, {}, {} (reliable, depth {}), services {service_names} ({:?} mapping){}",
        placement.domain,
        placement.describe_interfaces(),
        if config.node.cpus.is_empty() {
            String::new()
        } else {
            format!(", threads on CPUs {}", config.node.cpus)
        },
        topics.detections,
        config.qos.detections_depth,
        topics.state,
        topics.intercept,
        topics.trajectory,
        topics.markers,
        topics.diagnostics,
        config.qos.outputs_depth,
        config.node.service_mapping,
        if config.use_sim_time {
            format!("; node time from {CLOCK_TOPIC} (use_sim_time)")
        } else {
            String::new()
        },
    );
}

fn start_here(config: &Config, placement: &Placement) -> Result<NodeHandle, NodeError> {
    let context = dds::context(placement.domain, placement.interfaces.as_deref())?;
    let node_name = dds::node_name(config)?;
    let mut node = dds::node(&context, node_name.clone(), false)?;
    let fq_name = node_name.fully_qualified_name();

    let topics = &config.resolved_topics();
    let detections_topic = dds::detections_topic(&mut node, config)?;
    let subscription: Subscription<BallDetection> = node
        .create_subscription(&detections_topic, None)
        .map_err(dds::error)?;
    let outputs = create_outputs(&mut node, &context, config)?;
    // The DDS thread makes the /clock reader when `use_sim_time` is first set on the running
    // node (it holds the node), and hands it to the estimator thread.
    let (clock_wanted_tx, clock_wanted_rx) = mpsc::unbounded::<()>();
    let (clock_made_tx, clock_made_rx) = channel::bounded::<Subscription<Clock>>(1);
    let clock = NodeClock::start(&mut node, config, clock_wanted_tx, clock_made_rx)?;
    let (tf_topic, tf_static, robot_hits) = create_transform_and_hit_inputs(&mut node, config)?;
    let table_pose = table_transform(config, wall_clock_ns());
    let tf_publisher = publish_table_pose(&mut node, &tf_topic, table_pose.as_ref())?;
    let servers = Servers::new(&mut node, &node_name, config.node.service_mapping)?;
    if placement.rosout {
        rosout::install(
            node.create_publisher(&context.get_rosout_topic(), Some(dds::rosout()))
                .map_err(dds::error)?,
            &fq_name,
        );
    }
    let spinner = dds::spawn_spinner(&mut node)?;

    let shared = Arc::new(Shared::default());
    let capacity = usize::try_from(config.node.queue_capacity).unwrap_or(usize::MAX);
    let (request_tx, request_rx) = channel::bounded::<PendingRequest>(REQUEST_QUEUE);
    let (reply_tx, reply_rx) = mpsc::unbounded::<PendingReply>();
    let (stop_tx, stop_rx) = oneshot::channel::<()>();
    let (ended_tx, ended_rx) = channel::bounded::<()>(0);

    let parameters = Parameters::new(config);
    let pipeline = node_pipeline(config, table_pose.as_ref());
    let (live_view, app_rx) = start_live_view(placement, topics, &fq_name)?;
    let keeper = start_keeper(placement, config, &fq_name)?;
    let estimator = EstimatorThread {
        keeper,
        live_view,
        pipeline,
        tf_static,
        robot_hits,
        _tf_publisher: tf_publisher,
        clock,
        outputs,
        shared: Arc::clone(&shared),
        node_name: fq_name.clone(),
        detections_topic: topics.detections.clone(),
        period: Duration::from_secs_f64(config.node.diagnostics_period),
        capacity,
        parameters,
        sources: config
            .sources
            .all()
            .iter()
            .map(|_| (SourceWindow::new(), None))
            .collect(),
        source_index: config.sources.index(),
        started: Instant::now(),
        lessons_dropped: [0; Dropped::ALL.len()],
    };
    let estimator = std::thread::Builder::new()
        .name("ttball-estimator".to_owned())
        .spawn(move || estimator.run(subscription, (&request_rx, &app_rx), &reply_tx))
        .map_err(|e| NodeError::Thread(e.to_string()))?;

    log_start(config, placement, &fq_name);

    let dds = std::thread::Builder::new()
        .name("ttball-dds".to_owned())
        .spawn(move || {
            let started = Instant::now();
            let clock = ClockMaker {
                wanted: clock_wanted_rx,
                made: clock_made_tx,
            };
            dds_loop(
                &servers,
                &request_tx,
                reply_rx,
                stop_rx,
                &shared,
                (&mut node, clock),
            );
            // The estimator takes this as its stop: it processes what DDS holds and ends.
            drop(request_tx);
            let estimator = estimator
                .join()
                .map_err(|_| NodeError::Thread("the estimator thread panicked".to_owned()))?;
            // Readers and writers go before their node (the estimator's went with it), the node
            // before its participant.
            rosout::uninstall();
            drop(servers);
            spinner.stop_with(node);
            drop(context);
            drop(ended_tx);
            Ok(NodeSummary {
                counters: estimator.counters,
                transport: shared.snapshot(),
                processing_mean_ns: estimator.processing_mean_ns,
                processing_max_ns: estimator.processing_max_ns,
                in_node: estimator.in_node,
                seconds: started.elapsed().as_secs_f64(),
                learned: estimator.learned,
            })
        })
        .map_err(|e| NodeError::Thread(e.to_string()))?;

    Ok(NodeHandle {
        stop: Some(stop_tx),
        dds: Some(dds),
        ended: ended_rx,
        name: fq_name,
    })
}

/// The node's reader of `/clock` (`use_sim_time`). Made only when needed: ros2-client's spinner
/// keeps a /clock topic of its own under another type name (builtin_interfaces' Time, which no
/// ROS 2 clock publisher matches), and RustDDS logs an error when one participant has a topic
/// under two types.
fn clock_subscription(node: &mut Node) -> Result<Subscription<Clock>, NodeError> {
    let topic = node
        .create_topic(
            &dds::name(CLOCK_TOPIC)?,
            dds::message_type(CLOCK_TYPE),
            &dds::clock(),
        )
        .map_err(dds::error)?;
    node.create_subscription(&topic, None).map_err(dds::error)
}

/// The DDS thread's side of a `/clock` reader made on request (see [`NodeClock`]).
struct ClockMaker {
    wanted: mpsc::UnboundedReceiver<()>,
    made: Sender<Subscription<Clock>>,
}

fn publisher<M: Serialize>(
    node: &mut Node,
    topic: &str,
    ros_type: &str,
    qos: &ros2_client::QosProfile,
) -> Result<Publisher<M>, NodeError> {
    let topic = node
        .create_topic(&dds::name(topic)?, dds::message_type(ros_type), qos)
        .map_err(dds::error)?;
    node.create_publisher(&topic, None).map_err(dds::error)
}

/// Wakes the estimator thread when RustDDS's reader has a new sample: the waker of the
/// subscription's stream rings a crossbeam channel the thread selects on beside its others.
struct Doorbell(Sender<()>);

impl Wake for Doorbell {
    fn wake(self: Arc<Self>) {
        self.wake_by_ref();
    }

    fn wake_by_ref(self: &Arc<Self>) {
        // Full means already rung: one ring wakes the thread for everything that came.
        let _ = self.0.try_send(());
    }
}

/// Takes service requests off DDS and sends the replies until `stop` fires; makes the
/// `/clock` reader when the estimator thread asks for it.
fn dds_loop(
    servers: &Servers,
    requests: &Sender<PendingRequest>,
    mut replies: mpsc::UnboundedReceiver<PendingReply>,
    stop: oneshot::Receiver<()>,
    shared: &Shared,
    (node, mut clock): (&mut Node, ClockMaker),
) {
    futures::executor::block_on(async {
        let incoming = servers.requests();
        futures::pin_mut!(incoming);
        let mut stop = stop.fuse();
        loop {
            futures::select! {
                () = clock.wanted.select_next_some() => match clock_subscription(node) {
                    Ok(subscription) => {
                        let _ = clock.made.try_send(subscription);
                    }
                    Err(e) => warn!("cannot read {CLOCK_TOPIC} for use_sim_time: {e}"),
                },
                request = incoming.select_next_some() => match request {
                    Ok((id, request)) => {
                        if let Err(TrySendError::Full((id, request))) = requests.try_send((id, request)) {
                            Shared::add(&shared.service_busy);
                            send_reply(servers, id, busy_reply(request.service()), shared);
                        }
                    }
                    Err((service, e)) => warn!("a {} request did not decode: {e}", service.name()),
                },
                reply = replies.select_next_some() => {
                    let (id, reply) = reply;
                    Shared::add(&shared.service_requests);
                    send_reply(servers, id, reply, shared);
                }
                _ = stop => break,
            }
        }
    });
}

fn send_reply(servers: &Servers, id: RmwRequestId, reply: Reply, shared: &Shared) {
    let service = reply.service();
    if let Err(e) = servers.send(id, reply) {
        Shared::add(&shared.publish_errors);
        warn!("cannot send a {} reply: {e}", service.name());
    }
}

/// The refusal of a request when [`REQUEST_QUEUE`] requests already wait for the estimator.
fn busy_reply(service: Service) -> Reply {
    Reply::refusal(service, busy_message())
}

/// Why a request is refused when [`REQUEST_QUEUE`] requests already wait for the estimator.
fn busy_message() -> String {
    format!("busy: {REQUEST_QUEUE} requests are waiting; try again")
}

/// What the estimator thread owns.
struct EstimatorThread {
    pipeline: Pipeline,
    outputs: Outputs,
    shared: Arc<Shared>,
    node_name: String,
    detections_topic: String,
    period: Duration,
    capacity: usize,
    /// The node's parameters (the configuration the pipeline runs with).
    parameters: Parameters,
    clock: NodeClock,
    /// Each source's detections over the diagnostics period, in the order of
    /// [`crate::config::SourcesParams::all`], and when it last delivered one.
    sources: Vec<(SourceWindow, Option<Instant>)>,
    /// Each detection's source's place in `sources` (the ids are read-only parameters).
    source_index: SourceIndex,
    started: Instant,
    /// `/tf_static`, taken between detections.
    tf_static: Subscription<TFMessage>,
    /// The robot's announced hits (`topics.robot_hits`), taken between detections.
    robot_hits: Subscription<RobotHit>,
    /// The writer of the table's pose (kept: the transform is transient local).
    _tf_publisher: Option<Publisher<TFMessage>>,
    /// The Foxglove live view, and the topics it shows the detections and outputs on.
    live_view: Option<RunningLiveView>,
    /// The keeper of what the estimator learned in a file (`--learned`).
    keeper: Option<keeper::LearnedKeeper>,
    /// The tracks' smoothings dropped by the last diagnostics, by reason: new ones are logged.
    lessons_dropped: [u64; Dropped::ALL.len()],
}

/// The table's pose in `frames.table_parent` as a `/tf_static` message, if one is configured.
fn table_transform(config: &Config, stamp: i64) -> Option<TFMessage> {
    let parent = config.frames.table_parent.trim_start_matches('/');
    let &[x, y, z, qx, qy, qz, qw] = config.frames.table_pose.as_slice() else {
        return None;
    };
    (!parent.is_empty()).then(|| TFMessage {
        transforms: vec![TransformStamped {
            header: Header {
                stamp: crate::ros::msgs::builtin_interfaces::Time::from_nanos(stamp),
                frame_id: parent.to_owned().into(),
            },
            child_frame_id: config.frames.table_frame.clone(),
            transform: Transform {
                translation: Vector3 { x, y, z },
                rotation: Quaternion {
                    x: qx,
                    y: qy,
                    z: qz,
                    w: qw,
                },
            },
        }],
    })
}

/// The node's clock: the system clock, or with `use_sim_time` the latest `/clock` (0 until the
/// first, as in rclcpp). `use_sim_time` may be set on the running node, as rclcpp's may: the
/// first time, the DDS thread (which holds the node) is asked for the `/clock` reader.
struct NodeClock {
    /// `use_sim_time` as it stands.
    simulated: bool,
    /// The reader has been asked for (or made at the start).
    asked: bool,
    subscription: Option<Subscription<Clock>>,
    latest: Option<i64>,
    wanted: mpsc::UnboundedSender<()>,
    made: Receiver<Subscription<Clock>>,
}

impl NodeClock {
    /// The node's clock: `/clock` with `use_sim_time` (its reader made now), else the system's;
    /// a reader asked for later is `wanted` from the DDS thread and comes back on `made`.
    fn start(
        node: &mut Node,
        config: &Config,
        wanted: mpsc::UnboundedSender<()>,
        made: Receiver<Subscription<Clock>>,
    ) -> Result<Self, NodeError> {
        let subscription = if config.use_sim_time {
            Some(clock_subscription(node)?)
        } else {
            None
        };
        Ok(Self {
            simulated: config.use_sim_time,
            asked: subscription.is_some(),
            subscription,
            latest: None,
            wanted,
            made,
        })
    }

    /// Now [ns since the epoch].
    fn now_ns(&mut self) -> i64 {
        if !self.simulated {
            return wall_clock_ns();
        }
        if self.subscription.is_none() {
            self.subscription = self.made.try_recv().ok();
        }
        if let Some(subscription) = &self.subscription {
            while let Ok(Some((clock, _))) = subscription.take() {
                self.latest = Some(clock.clock.to_nanos());
            }
        }
        self.latest.unwrap_or(0)
    }

    /// Follows `use_sim_time` set on the running node.
    fn set_simulated(&mut self, simulated: bool) {
        if simulated != self.simulated {
            info!(
                "node time from {}",
                if simulated {
                    "/clock (use_sim_time)"
                } else {
                    "the system clock"
                }
            );
        }
        self.simulated = simulated;
        if simulated && !self.asked {
            self.asked = self.wanted.unbounded_send(()).is_ok();
        }
    }
}

/// What the estimator thread did.
struct EstimatorResult {
    counters: Counters,
    processing_mean_ns: f64,
    processing_max_ns: f64,
    in_node: DurationSummary,
    learned: NodeLearned,
}

/// Processing and in-node times of the detections, over a diagnostics period and the run.
struct Timings {
    window: Window,
    total_ns: f64,
    max_ns: u64,
    count: u64,
    in_node: DurationHistogram,
}

impl EstimatorThread {
    fn run(
        mut self,
        subscription: Subscription<BallDetection>,
        (requests, app_requests): (&Receiver<PendingRequest>, &Receiver<foxglove::AppRequest>),
        replies: &mpsc::UnboundedSender<PendingReply>,
    ) -> EstimatorResult {
        let (bell, rung) = channel::bounded::<()>(1);
        let waker = Waker::from(Arc::new(Doorbell(bell)));
        let mut context = Context::from_waker(&waker);
        let detections = subscription.async_stream();
        futures::pin_mut!(detections);
        let mut queue = DetectionQueue::new(self.capacity);
        let mut gaps = SequenceGaps::new();
        let mut timings = Timings {
            window: Window::with_capacity(self.capacity.clamp(1024, 4096)),
            total_ns: 0.0,
            max_ns: 0,
            count: 0,
            in_node: DurationHistogram::new(),
        };
        let now = self.now();
        let declared = self.parameters.declared_event(now, &self.node_name);
        self.publish_parameter_event(declared);
        let ticker = channel::tick(self.period);
        let mut period_start = Instant::now();
        let mut transport_before = self.shared.snapshot();

        let mut wake_on = Select::new();
        let on_bell = wake_on.recv(&rung);
        let on_request = wake_on.recv(requests);
        let on_app_request = wake_on.recv(app_requests);
        wake_on.recv(&ticker);
        loop {
            self.take_static_transforms();
            self.take_robot_hits();
            self.take_from_dds(detections.as_mut(), &mut context, &mut queue, &mut gaps);
            if let Some(queued) = queue.pop() {
                self.process(queued, &mut timings);
            }
            // Requests and diagnostics between detections; the thread waits only when no
            // detection is queued (the doorbell rings for the next).
            let operation = if queue.is_empty() {
                wake_on.select()
            } else {
                match wake_on.try_select() {
                    Ok(operation) => operation,
                    Err(_) => continue,
                }
            };
            match operation.index() {
                i if i == on_bell => {
                    let _ = operation.recv(&rung);
                }
                i if i == on_request => match operation.recv(requests) {
                    Ok(pending) => self.answer(pending, replies),
                    // The DDS thread stopped: the node stops.
                    Err(_) => break,
                },
                i if i == on_app_request => {
                    if let Ok(request) = operation.recv(app_requests) {
                        self.answer_app(request);
                    }
                }
                _ => {
                    let _ = operation.recv(&ticker);
                    let now = Instant::now();
                    let transport = self.shared.snapshot();
                    self.publish_diagnostics(
                        &mut timings.window,
                        now - period_start,
                        &transport,
                        &transport_before,
                        queue.len(),
                    );
                    period_start = now;
                    transport_before = transport;
                    if let Some(keeper) = &mut self.keeper {
                        keeper.offer(
                            self.parameters.config(),
                            self.pipeline.estimator().learned_summary(),
                        );
                    }
                }
            }
        }
        // What DDS holds when the node stops is processed and published too.
        self.take_from_dds(detections.as_mut(), &mut context, &mut queue, &mut gaps);
        while let Some(queued) = queue.pop() {
            self.process(queued, &mut timings);
        }
        let transport = self.shared.snapshot();
        self.publish_diagnostics(
            &mut timings.window,
            period_start.elapsed(),
            &transport,
            &transport_before,
            0,
        );
        self.finish(&timings)
    }

    /// Answers one service request, publishing the parameter event of an accepted change.
    fn answer(
        &mut self,
        (id, request): PendingRequest,
        replies: &mpsc::UnboundedSender<PendingReply>,
    ) {
        let (reply, effect) = request.answer(&mut self.pipeline, &mut self.parameters);
        let (success, message) = reply.outcome();
        debug!("{}: success {success} {message}", request.service().name());
        let _ = replies.unbounded_send((id, reply));
        self.apply(effect);
    }

    /// Answers one request of the live view's app; a refused parameter shows in the app.
    fn answer_app(&mut self, request: foxglove::AppRequest) {
        let answered = foxglove::answer(request, &mut self.pipeline, &mut self.parameters);
        if !answered.refused.is_empty() {
            let why = format!("parameters refused: {}", answered.refused.join("; "));
            warn!("{why}");
            if let Some((view, _)) = &self.live_view {
                view.publish_status(::foxglove::websocket::Status::warning(why));
            }
        }
        self.apply(answered.effect);
    }

    /// Takes an accepted change of parameters: the clock's source, `/parameter_events`, and the
    /// live view's parameter subscribers.
    fn apply(&mut self, effect: Effect) {
        let Effect::Changed(change) = effect else {
            return;
        };
        let names: Vec<&str> = change.changed.iter().map(|p| p.name.as_str()).collect();
        info!("parameters set: {}", names.join(", "));
        self.clock
            .set_simulated(self.parameters.config().use_sim_time);
        if let Some((view, _)) = &self.live_view {
            view.publish_parameters(
                change
                    .changed
                    .iter()
                    .map(|p| foxglove::to_app(&p.name, &p.value))
                    .collect(),
            );
        }
        let now = self.now();
        let event = parameters::change_event(&change, now, &self.node_name);
        self.publish_parameter_event(event);
    }

    /// The stream has ended: the live track's lesson and every lesson waiting are learned, the
    /// learned file written, and what the thread did summed up.
    fn finish(mut self, timings: &Timings) -> EstimatorResult {
        self.pipeline.end_of_input();
        let learned = NodeLearned {
            config: self.parameters.config().clone(),
            learned: self.pipeline.estimator().learned_summary(),
        };
        if let Some(keeper) = self.keeper.take() {
            keeper.finish(&learned.config, learned.learned.clone());
        }
        EstimatorResult {
            learned,
            counters: self.pipeline.counters(),
            processing_mean_ns: if timings.count > 0 {
                timings.total_ns / timings.count as f64
            } else {
                0.0
            },
            processing_max_ns: timings.max_ns as f64,
            in_node: timings.in_node.summary(),
        }
    }

    /// Takes every sample the subscription holds into the queue, counting what was dropped
    /// and lost on the way; when none is left, the stream leaves the doorbell with RustDDS's
    /// reader.
    fn take_from_dds<S>(
        &self,
        mut detections: Pin<&mut S>,
        context: &mut Context<'_>,
        queue: &mut DetectionQueue,
        gaps: &mut SequenceGaps<Gid>,
    ) where
        S: Stream<Item = ReadResult<(BallDetection, MessageInfo)>>,
    {
        let shared = &*self.shared;
        while let Poll::Ready(Some(sample)) = detections.as_mut().poll_next(context) {
            let taken = Instant::now();
            Shared::add(&shared.received);
            match sample {
                Ok((detection, info)) => {
                    let lost = gaps.take(info.publisher_gid(), info.sequence_number());
                    if lost > 0 {
                        let before = shared.lost_before_node.fetch_add(lost, Ordering::Relaxed);
                        if before == 0 || (before + lost) / 1000 > before / 1000 {
                            warn!(
                                "{} detections lost before the node so far (gaps in their publishers' sequence numbers): the network or DDS dropped them",
                                before + lost
                            );
                        }
                    }
                    let received = taken.checked_sub(age(&info)).unwrap_or(taken);
                    if queue.push(detection, received) {
                        let dropped = Shared::add(&shared.dropped_queue_full);
                        if dropped == 1 || dropped.is_multiple_of(1000) {
                            warn!(
                                "the estimator falls behind: {dropped} detections dropped so far (queue full)"
                            );
                        }
                    }
                }
                Err(e) => {
                    let n = Shared::add(&shared.undecodable);
                    if n == 1 || n.is_multiple_of(1000) {
                        warn!(
                            "{n} detection samples did not decode as BallDetection so far: {e:?}"
                        );
                    }
                }
            }
        }
    }

    /// Takes the robot's announced hits: each seeds the return's track at its first detection.
    fn take_robot_hits(&mut self) {
        while let Ok(Some((msg, _))) = self.robot_hits.take() {
            if let Err(e) = self.pipeline.on_robot_hit(&msg) {
                warn!("{ROBOT_HIT_TYPE}: {e} (ignored)");
            }
        }
    }

    /// Takes the static transforms `/tf_static` brought (rarely: when a broadcaster starts).
    fn take_static_transforms(&mut self) {
        while let Ok(Some((msg, _))) = self.tf_static.take() {
            let refused = self.pipeline.on_static_transforms(&msg);
            for e in refused {
                warn!("{TF_STATIC_TOPIC}: {e} (ignored)");
            }
            let names: Vec<String> = msg
                .transforms
                .iter()
                .map(|t| format!("{} -> {}", t.header.frame_id, t.child_frame_id))
                .collect();
            debug!("{TF_STATIC_TOPIC}: {}", names.join(", "));
        }
    }

    /// Runs the pipeline on one detection and publishes what it gives: the detection's own
    /// messages first, then the trajectory when one is due.
    fn process(&mut self, (detection, taken_at): Queued, timings: &mut Timings) {
        let started = Instant::now();
        let step = self.pipeline.handle_detection(&detection);
        let ns = nanos(started.elapsed());
        let fused = matches!(
            step.verdict,
            Ok(Verdict::Fused { .. } | Verdict::Initializing | Verdict::Held)
        );
        let (window, last) = &mut self.sources[self.source_index.of(Source(detection.source))];
        window.record(detection.header.stamp.to_nanos(), !fused);
        *last = Some(started);
        timings
            .window
            .record(ns, nanos(started.duration_since(taken_at)));
        timings.total_ns += ns as f64;
        timings.max_ns = timings.max_ns.max(ns);
        timings.count += 1;
        if let Some((view, topics)) = &mut self.live_view {
            let now = mcap_time(self.clock.now_ns());
            view.log_message(&topics.detections, DETECTION_TYPE, now, &detection);
        }
        self.log_to_live_view(&step.published);
        self.publish(step.published);
        timings.in_node.record(nanos(taken_at.elapsed()));
        let mut trajectory = Published::default();
        let started = Instant::now();
        if self.pipeline.add_due_trajectory(&mut trajectory) {
            timings.window.record_trajectory(nanos(started.elapsed()));
            self.log_to_live_view(&trajectory);
            self.publish(trajectory);
        }
    }

    /// Logs what is about to be published to the live view, when there is one.
    fn log_to_live_view(&mut self, p: &Published) {
        let Some((view, topics)) = &mut self.live_view else {
            return;
        };
        let now = mcap_time(self.clock.now_ns());
        view.log_optional(&topics.state, STATE_TYPE, now, p.state.as_ref());
        view.log_optional(&topics.intercept, INTERCEPT_TYPE, now, p.intercept.as_ref());
        view.log_optional(
            &topics.trajectory,
            TRAJECTORY_TYPE,
            now,
            p.trajectory.as_ref(),
        );
        view.log_optional(&topics.markers, MARKERS_TYPE, now, p.markers.as_ref());
        view.log_optional(&topics.odometry, ODOMETRY_TYPE, now, p.odometry.as_ref());
    }

    fn publish(&self, published: Published) {
        let o = &self.outputs;
        // The interception first: it is what a controller waits for (each publication wakes
        // RustDDS's sending thread, which may run before the next one is serialised).
        let results = [
            published.intercept.map(|m| o.intercept.publish(m).is_ok()),
            published.state.map(|m| o.state.publish(m).is_ok()),
            published
                .trajectory
                .map(|m| o.trajectory.publish(m).is_ok()),
            published.markers.map(|m| o.markers.publish(m).is_ok()),
            published
                .odometry
                .zip(o.odometry.as_ref())
                .map(|(m, p)| p.publish(m).is_ok()),
        ];
        for ok in results.into_iter().flatten() {
            if !ok {
                let n = Shared::add(&self.shared.publish_errors);
                if n == 1 || n.is_multiple_of(1000) {
                    warn!("{n} messages could not be published so far");
                }
            }
        }
    }

    /// The node's time, as a ROS 2 time.
    fn now(&mut self) -> ros2_client::builtin_interfaces::Time {
        ros2_client::builtin_interfaces::Time::from_nanos(self.clock.now_ns())
    }

    fn publish_parameter_event(&self, event: ParameterEvent) {
        if self.outputs.parameter_events.publish(event).is_err() {
            Shared::add(&self.shared.publish_errors);
        }
    }

    fn publish_diagnostics(
        &mut self,
        window: &mut Window,
        period: Duration,
        transport: &TransportCounters,
        transport_before: &TransportCounters,
        queue_len: usize,
    ) {
        let stamp = self.now().to_nanos();
        let counters = self.pipeline.counters();
        for warning in dropped_lessons_warnings(&self.lessons_dropped, &counters.lessons_dropped) {
            warn!("{warning}");
        }
        self.lessons_dropped = counters.lessons_dropped;
        let estimator = self.pipeline.estimator();
        let learned = estimator.learned_params();
        let learned_noise = estimator.learned_noise();
        let msg = diagnostics_msg(
            &Snapshot {
                node: &self.node_name,
                detections_topic: &self.detections_topic,
                stamp,
                period: period.as_secs_f64(),
                counters: &counters,
                transport,
                transport_before,
                queue_len,
                track: estimator.estimate().map(|e| e.track_id),
                learned: &learned,
                learned_noise: &learned_noise,
            },
            window,
        );
        let mut msg = msg;
        let now = Instant::now();
        let counts: Vec<u64> = self.sources.iter().map(|(w, _)| w.detections).collect();
        let total: u64 = counts.iter().sum();
        let config = self.parameters.config();
        let params = config.sources.all();
        for (i, ((window, last), (name, source))) in self.sources.iter_mut().zip(params).enumerate()
        {
            let expected = SourceExpectation {
                key: name,
                frame_rate: source.frame_rate,
                stale_after: config.node.source_stale_after,
            };
            // Never seen: silent since the node started.
            let silent_for = last.map_or_else(
                || {
                    let up = now.duration_since(self.started).as_secs_f64();
                    if up > expected.stale_after {
                        f64::INFINITY
                    } else {
                        up
                    }
                },
                |t| now.duration_since(t).as_secs_f64(),
            );
            // The unknown source is reported only once it has delivered.
            if i == 0 && last.is_none() {
                continue;
            }
            msg.status.push(source_status(
                &self.node_name,
                &expected,
                window,
                silent_for,
                total - counts[i],
            ));
        }
        if self.outputs.diagnostics.publish(msg).is_err() {
            Shared::add(&self.shared.publish_errors);
        }
    }
}

/// How long ago RustDDS received a sample (its reception timestamp, on the system clock); zero
/// when unknown or implausible (a clock step), so that the node's times are never made up.
fn age(info: &MessageInfo) -> Duration {
    info.received_timestamp()
        .map(|received| wall_clock_ns().saturating_sub(received.to_nanos()))
        .and_then(|ns| u64::try_from(ns).ok())
        .filter(|&ns| ns < MAX_PLAUSIBLE_AGE_NS)
        .map_or(Duration::ZERO, Duration::from_nanos)
}

/// A reception timestamp older than this is taken for a clock step [ns].
const MAX_PLAUSIBLE_AGE_NS: u64 = 1_000_000_000;

fn nanos(d: Duration) -> u64 {
    u64::try_from(d.as_nanos()).unwrap_or(u64::MAX)
}

/// Now, as ROS time [ns since the epoch].
fn wall_clock_ns() -> i64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0, |d| i64::try_from(d.as_nanos()).unwrap_or(i64::MAX))
}
