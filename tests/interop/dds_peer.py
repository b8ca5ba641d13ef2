"""A DDS peer for `ttball node`, written with Eclipse Cyclone DDS (Python binding), which ttball
did not write: it proves the node interoperates over DDS, and lets you try the node without ROS 2.

    pip install cyclonedds mcap
    ttball node &                                   # in one shell (same ROS_DOMAIN_ID)
    python dds_peer.py publish bags/sim_rally_2cams.mcap --out results.json
    python dds_peer.py listen --count 100           # e.g. against `ttball play BAG`
    python dds_peer.py call-predict --horizon 0.5   # needs `-p node.service_mapping:=cyclone`
    python dds_peer.py call-plan --target 0.9 0.3   # likewise
    python dds_peer.py call-rebound --racket 1.6 0 0.15 1 0 0
    python dds_peer.py params --node /ttball         # rcl_interfaces' parameter services, ~/reset
    python dds_peer.py record --clock 1000 --seconds 5   # /diagnostics while publishing /clock
    python dds_peer.py set-params --node /ttball use_sim_time:=true   # as `ros2 param set`
    python dds_peer.py discovery --distro humble     # ros_discovery_info, checked against DDS

`publish` plays a bag's detections to /ball/detections at their recorded times and records the
node's /ball/state and /ball/intercept (with latency); `listen` records detections published by
someone else; `call-predict`, `call-rebound` and `call-plan` call the node's PredictTrajectory,
PredictRebound and PlanReturn services. `python dds_peer.py COMMAND --help` has the details.

The ROS 2 messages are declared below as plain (final) Cyclone IDL structs under their ROS 2 DDS
type names, so Cyclone speaks plain CDR (encapsulation 00 01 00 00) like ROS 2 and RustDDS. DDS
topics follow ROS 2: /ball/state is `rt/ball/state`; a service /s is `rq/sRequest` and
`rr/sReply`, each payload led by rmw_cyclonedds' request header (client guid, sequence number).

Network: unless CYCLONEDDS_URI is already set, Cyclone is restricted to the loopback interface
(LOOPBACK_URI). DDS discovery multicasts, so for tests also run inside a loopback-only network
namespace:
    unshare -n bash -c 'ip link set lo up; ip link set lo multicast on;
                        ip route add 224.0.0.0/4 dev lo; ...'
The domain id is ROS_DOMAIN_ID (default 0), as in ROS 2.
"""

import argparse
import collections
import json
import math
import os
import random
import sys
import threading
import time
from dataclasses import dataclass

from cyclonedds.core import Listener, Policy, Qos
from cyclonedds.domain import DomainParticipant
from cyclonedds.idl import IdlStruct
from cyclonedds.idl import types as t
from cyclonedds.pub import DataWriter
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic
from cyclonedds.util import duration
from mcap.reader import make_reader

LOOPBACK_URI = (
    '<CycloneDDS><Domain id="any"><General><Interfaces>'
    '<NetworkInterface address="127.0.0.1" multicast="true"/>'
    "</Interfaces></General>"
    # A receive buffer as large as the machine allows: a listener descheduled under load keeps
    # the best-effort samples that arrive meanwhile instead of the socket dropping them.
    '<Internal><SocketReceiveBufferSize min="default" max="4MB"/></Internal>'
    "</Domain></CycloneDDS>"
)


# ---- ROS 2 message types (fields, types and order exactly as the .msg files) -------------------


@dataclass
class Time_(IdlStruct, typename="builtin_interfaces::msg::dds_::Time_"):
    sec: t.int32
    nanosec: t.uint32


@dataclass
class Clock_(IdlStruct, typename="rosgraph_msgs::msg::dds_::Clock_"):
    clock: Time_


@dataclass
class Header_(IdlStruct, typename="std_msgs::msg::dds_::Header_"):
    stamp: Time_
    frame_id: str


@dataclass
class Point_(IdlStruct, typename="geometry_msgs::msg::dds_::Point_"):
    x: t.float64
    y: t.float64
    z: t.float64


@dataclass
class Vector3_(IdlStruct, typename="geometry_msgs::msg::dds_::Vector3_"):
    x: t.float64
    y: t.float64
    z: t.float64


@dataclass
class BallDetection_(IdlStruct, typename="ttball_msgs::msg::dds_::BallDetection_"):
    header: Header_
    position: Point_
    position_covariance: t.array[t.float64, 9]
    has_spin: bool
    spin: Vector3_
    spin_covariance: t.array[t.float64, 9]
    source: t.uint8
    confidence: t.float32


@dataclass
class BallState_(IdlStruct, typename="ttball_msgs::msg::dds_::BallState_"):
    header: Header_
    track_id: t.uint32
    status: t.uint8
    position: Point_
    velocity: Vector3_
    spin: Vector3_
    covariance: t.array[t.float64, 81]
    bounces: t.uint32
    nis: t.float64


@dataclass
class InterceptPrediction_(IdlStruct, typename="ttball_msgs::msg::dds_::InterceptPrediction_"):
    header: Header_
    track_id: t.uint32
    valid: bool
    intercept_stamp: Time_
    position: Point_
    velocity: Vector3_
    spin: Vector3_
    covariance: t.array[t.float64, 81]
    bounce_valid: bool
    bounce_stamp: Time_
    bounce_position: Point_
    reason: t.uint8
    time_variance: t.float64


@dataclass
class PredictedTrajectory_(IdlStruct, typename="ttball_msgs::msg::dds_::PredictedTrajectory_"):
    header: Header_
    track_id: t.uint32
    stamps: t.sequence[Time_]
    positions: t.sequence[Point_]
    velocities: t.sequence[Vector3_]
    spins: t.sequence[Vector3_]


# rmw_cyclonedds ("cyclone" service mapping): the type is the ROS one, the payload is led by the
# request header {uint64 client guid; int64 sequence number}, which the server echoes in the reply.
@dataclass
class PredictTrajectory_Request_(IdlStruct, typename="ttball_msgs::srv::dds_::PredictTrajectory_Request_"):
    client_guid: t.uint64
    sequence_number: t.int64
    track_id: t.uint32
    initial: BallState_
    horizon: t.float64
    dt: t.float64


@dataclass
class PredictTrajectory_Response_(IdlStruct, typename="ttball_msgs::srv::dds_::PredictTrajectory_Response_"):
    client_guid: t.uint64
    sequence_number: t.int64
    success: bool
    message: str
    trajectory: PredictedTrajectory_


@dataclass
class PredictRebound_Request_(IdlStruct, typename="ttball_msgs::srv::dds_::PredictRebound_Request_"):
    client_guid: t.uint64
    sequence_number: t.int64
    ball_position: Point_
    ball_velocity: Vector3_
    ball_spin: Vector3_
    racket_velocity: Vector3_
    racket_normal: Vector3_
    impact_offset: t.float64


@dataclass
class PredictRebound_Response_(IdlStruct, typename="ttball_msgs::srv::dds_::PredictRebound_Response_"):
    client_guid: t.uint64
    sequence_number: t.int64
    success: bool
    message: str
    ball_velocity: Vector3_
    ball_spin: Vector3_
    rebound_power_coefficient: t.float64
    contact_time: t.float64
    mean_force: t.float64
    peak_force: t.float64
    reduced_mass: t.float64
    wrist_force: t.float64
    lands_on_table: bool
    landing_position: Point_


@dataclass
class PlanReturn_Request_(IdlStruct, typename="ttball_msgs::srv::dds_::PlanReturn_Request_"):
    client_guid: t.uint64
    sequence_number: t.int64
    track_id: t.uint32
    ball: BallState_
    target: Point_
    flight_time: t.float64
    net_clearance: t.float64
    impact_offset: t.float64
    brush_speed: t.float64


@dataclass
class PlanReturn_Response_(IdlStruct, typename="ttball_msgs::srv::dds_::PlanReturn_Response_"):
    client_guid: t.uint64
    sequence_number: t.int64
    success: bool
    message: str
    impact_stamp: Time_
    impact_position: Point_
    racket_velocity: Vector3_
    racket_normal: Vector3_
    ball_velocity: Vector3_
    ball_spin: Vector3_
    landing_position: Point_
    flight_time: t.float64
    net_clearance: t.float64
    landing_error: t.float64
    landing_covariance: t.array[t.float64, 9]
    contact_time: t.float64
    peak_force: t.float64
    wrist_force: t.float64


# ---- rcl_interfaces (parameters) and std_srvs, with rmw_cyclonedds' request header -------------


@dataclass
class ParameterValue_(IdlStruct, typename="rcl_interfaces::msg::dds_::ParameterValue_"):
    type: t.uint8
    bool_value: bool
    integer_value: t.int64
    double_value: t.float64
    string_value: str
    byte_array_value: t.sequence[t.uint8]
    bool_array_value: t.sequence[bool]
    integer_array_value: t.sequence[t.int64]
    double_array_value: t.sequence[t.float64]
    string_array_value: t.sequence[str]


@dataclass
class Parameter_(IdlStruct, typename="rcl_interfaces::msg::dds_::Parameter_"):
    name: str
    value: ParameterValue_


@dataclass
class FloatingPointRange_(IdlStruct, typename="rcl_interfaces::msg::dds_::FloatingPointRange_"):
    from_value: t.float64
    to_value: t.float64
    step: t.float64


@dataclass
class IntegerRange_(IdlStruct, typename="rcl_interfaces::msg::dds_::IntegerRange_"):
    from_value: t.int64
    to_value: t.int64
    step: t.uint64


@dataclass
class ParameterDescriptor_(IdlStruct, typename="rcl_interfaces::msg::dds_::ParameterDescriptor_"):
    name: str
    type: t.uint8
    description: str
    additional_constraints: str
    read_only: bool
    dynamic_typing: bool
    floating_point_range: t.sequence[FloatingPointRange_, 1]
    integer_range: t.sequence[IntegerRange_, 1]


@dataclass
class SetParametersResult_(IdlStruct, typename="rcl_interfaces::msg::dds_::SetParametersResult_"):
    successful: bool
    reason: str


@dataclass
class ParameterEvent_(IdlStruct, typename="rcl_interfaces::msg::dds_::ParameterEvent_"):
    stamp: Time_
    node: str
    new_parameters: t.sequence[Parameter_]
    changed_parameters: t.sequence[Parameter_]
    deleted_parameters: t.sequence[Parameter_]


@dataclass
class ListParametersResult_(IdlStruct, typename="rcl_interfaces::msg::dds_::ListParametersResult_"):
    names: t.sequence[str]
    prefixes: t.sequence[str]


@dataclass
class ListParameters_Request_(IdlStruct, typename="rcl_interfaces::srv::dds_::ListParameters_Request_"):
    client_guid: t.uint64
    sequence_number: t.int64
    prefixes: t.sequence[str]
    depth: t.uint64


@dataclass
class ListParameters_Response_(IdlStruct, typename="rcl_interfaces::srv::dds_::ListParameters_Response_"):
    client_guid: t.uint64
    sequence_number: t.int64
    result: ListParametersResult_


@dataclass
class GetParameters_Request_(IdlStruct, typename="rcl_interfaces::srv::dds_::GetParameters_Request_"):
    client_guid: t.uint64
    sequence_number: t.int64
    names: t.sequence[str]


@dataclass
class GetParameters_Response_(IdlStruct, typename="rcl_interfaces::srv::dds_::GetParameters_Response_"):
    client_guid: t.uint64
    sequence_number: t.int64
    values: t.sequence[ParameterValue_]


@dataclass
class DescribeParameters_Request_(IdlStruct, typename="rcl_interfaces::srv::dds_::DescribeParameters_Request_"):
    client_guid: t.uint64
    sequence_number: t.int64
    names: t.sequence[str]


@dataclass
class DescribeParameters_Response_(IdlStruct, typename="rcl_interfaces::srv::dds_::DescribeParameters_Response_"):
    client_guid: t.uint64
    sequence_number: t.int64
    descriptors: t.sequence[ParameterDescriptor_]


@dataclass
class SetParameters_Request_(IdlStruct, typename="rcl_interfaces::srv::dds_::SetParameters_Request_"):
    client_guid: t.uint64
    sequence_number: t.int64
    parameters: t.sequence[Parameter_]


@dataclass
class SetParameters_Response_(IdlStruct, typename="rcl_interfaces::srv::dds_::SetParameters_Response_"):
    client_guid: t.uint64
    sequence_number: t.int64
    results: t.sequence[SetParametersResult_]


@dataclass
class SetParametersAtomically_Request_(
        IdlStruct, typename="rcl_interfaces::srv::dds_::SetParametersAtomically_Request_"):
    client_guid: t.uint64
    sequence_number: t.int64
    parameters: t.sequence[Parameter_]


@dataclass
class SetParametersAtomically_Response_(
        IdlStruct, typename="rcl_interfaces::srv::dds_::SetParametersAtomically_Response_"):
    client_guid: t.uint64
    sequence_number: t.int64
    result: SetParametersResult_


@dataclass
class Trigger_Request_(IdlStruct, typename="std_srvs::srv::dds_::Trigger_Request_"):
    client_guid: t.uint64
    sequence_number: t.int64
    structure_needs_at_least_one_member: t.uint8


@dataclass
class Trigger_Response_(IdlStruct, typename="std_srvs::srv::dds_::Trigger_Response_"):
    client_guid: t.uint64
    sequence_number: t.int64
    success: bool
    message: str


# ---- diagnostic_msgs and rcl_interfaces/Log, for `record` ---------------------------------------


@dataclass
class KeyValue_(IdlStruct, typename="diagnostic_msgs::msg::dds_::KeyValue_"):
    key: str
    value: str


@dataclass
class DiagnosticStatus_(IdlStruct, typename="diagnostic_msgs::msg::dds_::DiagnosticStatus_"):
    level: t.uint8
    name: str
    message: str
    hardware_id: str
    values: t.sequence[KeyValue_]


@dataclass
class DiagnosticArray_(IdlStruct, typename="diagnostic_msgs::msg::dds_::DiagnosticArray_"):
    header: Header_
    status: t.sequence[DiagnosticStatus_]


@dataclass
class Log_(IdlStruct, typename="rcl_interfaces::msg::dds_::Log_"):
    stamp: Time_
    level: t.uint8
    name: str
    msg: str
    file: str
    function: str
    line: t.uint32


# ---- tf2_msgs, for detections in a camera frame --------------------------------------------------


@dataclass
class Quaternion_(IdlStruct, typename="geometry_msgs::msg::dds_::Quaternion_"):
    x: t.float64
    y: t.float64
    z: t.float64
    w: t.float64


@dataclass
class Transform_(IdlStruct, typename="geometry_msgs::msg::dds_::Transform_"):
    translation: Vector3_
    rotation: Quaternion_


@dataclass
class TransformStamped_(IdlStruct, typename="geometry_msgs::msg::dds_::TransformStamped_"):
    header: Header_
    child_frame_id: str
    transform: Transform_


@dataclass
class TFMessage_(IdlStruct, typename="tf2_msgs::msg::dds_::TFMessage_"):
    transforms: t.sequence[TransformStamped_]


def rotate(q, v, inverse=False):
    """The vector v rotated by the unit quaternion q = (x, y, z, w) (or by its inverse)."""
    x, y, z, w = q
    if inverse:
        x, y, z = -x, -y, -z
    # v' = v + 2 w (u x v) + 2 u x (u x v), u = (x, y, z)
    ux = (y * v[2] - z * v[1], z * v[0] - x * v[2], x * v[1] - y * v[0])
    uux = (y * ux[2] - z * ux[1], z * ux[0] - x * ux[2], x * ux[1] - y * ux[0])
    return [v[i] + 2 * w * ux[i] + 2 * uux[i] for i in range(3)]


def into_frame(detection, frame, pose):
    """The table-frame detection expressed in `frame`, whose pose in `table` is `pose`
    (x, y, z, qx, qy, qz, qw): p_frame = R^T (p_table - t), spin likewise rotated."""
    t_, q = pose[:3], pose[3:]
    n = math.sqrt(sum(c * c for c in q))
    q = [c / n for c in q]
    p = detection.position
    local = rotate(q, [p.x - t_[0], p.y - t_[1], p.z - t_[2]], inverse=True)
    w = detection.spin
    spin = rotate(q, [w.x, w.y, w.z], inverse=True)
    detection.header.frame_id = frame
    detection.position = Point_(x=local[0], y=local[1], z=local[2])
    detection.spin = Vector3_(x=spin[0], y=spin[1], z=spin[2])
    return detection


# ---- DDS plumbing ------------------------------------------------------------------------------


def participant():
    """A DomainParticipant on ROS_DOMAIN_ID, restricted to loopback unless CYCLONEDDS_URI is set
    (Cyclone reads CYCLONEDDS_URI when the first participant creates the domain)."""
    os.environ.setdefault("CYCLONEDDS_URI", LOOPBACK_URI)
    return DomainParticipant(int(os.environ.get("ROS_DOMAIN_ID", "0")))


def qos(reliable, depth, transient_local=False):
    """KeepLast(depth), Volatile (or TransientLocal), Reliable or BestEffort (as ROS 2 maps its
    QoS profiles)."""
    reliability = Policy.Reliability.Reliable(duration(seconds=1)) if reliable else Policy.Reliability.BestEffort
    durability = Policy.Durability.TransientLocal if transient_local else Policy.Durability.Volatile
    return Qos(reliability, Policy.History.KeepLast(depth), durability)


def ros_topic(prefix, name, suffix=""):
    """ROS 2 name -> DDS topic name: ("rt", "/ball/state") -> "rt/ball/state"."""
    return prefix + "/" + name.strip("/") + suffix


def warn_incompatible(kind):
    """A listener that says so when QoS prevents a match (otherwise a silent non-match)."""
    def report(entity, status):
        topic = entity.topic.name if entity is not None else "?"
        print(f"dds_peer: incompatible QoS on {kind} {topic} (policy id {status.last_policy_id})",
              file=sys.stderr)

    return Listener(on_offered_incompatible_qos=report, on_requested_incompatible_qos=report)


def writer(dp, name, data_type, reliable, depth):
    return DataWriter(dp, Topic(dp, name, data_type), qos(reliable, depth), listener=warn_incompatible("writer"))


class Recorder:
    """A DataReader whose samples are taken from Cyclone's receive thread (a listener, so none is
    lost and recv_ns is the arrival time), kept as {"stamp_ns"?, "recv_ns", "cdr"} plus the sample."""

    def __init__(self, dp, name, data_type, reliable, depth, keep=True, transient_local=False):
        self.records, self.samples, self.keep, self.count = [], [], keep, 0
        self.lock = threading.Lock()
        self.arrived = threading.Condition(self.lock)
        listener = warn_incompatible("reader")
        listener.merge(Listener(on_data_available=self._take))
        self.reader = DataReader(dp, Topic(dp, name, data_type), qos(reliable, depth, transient_local),
                                 listener=listener)

    def _take(self, reader):
        while True:
            now = time.monotonic_ns()  # before take(), which also deserialises
            samples = reader.take(N=256)
            if not samples:
                return
            with self.lock:
                for sample in samples:
                    if not sample.sample_info.valid_data:
                        continue
                    self.count += 1
                    if not self.keep:
                        continue
                    record = {"recv_ns": now, "cdr": sample.serialize().hex()}
                    if hasattr(sample, "header"):
                        record = {"stamp_ns": stamp_ns(sample.header.stamp), **record}
                    self.records.append(record)
                    self.samples.append(sample)
                self.arrived.notify_all()

    def snapshot(self):
        with self.lock:
            return list(self.records)


def stamp_ns(stamp):
    return stamp.sec * 1_000_000_000 + stamp.nanosec


def wait_until(condition, deadline):
    """Polls condition() until it holds or time.monotonic() passes deadline; returns it."""
    while not condition():
        if time.monotonic() >= deadline:
            return False
        time.sleep(0.01)
    return True


def write_json(path, value):
    if path:
        with open(path, "w") as out:
            json.dump(value, out)
            out.write("\n")


def percentile(sorted_values, p):
    """Nearest-rank percentile of a sorted list."""
    return sorted_values[max(0, math.ceil(p / 100 * len(sorted_values)) - 1)]


# ---- sub-commands ------------------------------------------------------------------------------


def read_detections(bag, topic):
    """(log_time, BallDetection_) for every message on topic, in log-time order, decoded by Cyclone."""
    with open(bag, "rb") as f:
        return [(m.log_time, BallDetection_.deserialize(m.data))
                for _, _, m in make_reader(f).iter_messages(topics=[topic], log_time_order=True)]


def latency_ms(sent, outputs):
    """recv_ns of each output (state or intercept, stamped with its detection's stamp) minus
    send_ns of the detection with that stamp (FIFO when stamps repeat)."""
    pending = collections.defaultdict(collections.deque)
    for s in sent:
        pending[s["stamp_ns"]].append(s["send_ns"])
    values = sorted((r["recv_ns"] - pending[r["stamp_ns"]].popleft()) / 1e6
                    for r in outputs if pending.get(r["stamp_ns"]))
    if not values:
        return {"p50": None, "p99": None, "max": None, "count": 0}
    return {"p50": percentile(values, 50), "p99": percentile(values, 99), "max": values[-1],
            "count": len(values)}


def cmd_publish(args):
    detections = read_detections(args.bag, args.bag_topic or args.topic)
    end = args.first + args.count if args.count else None
    detections = detections[args.first:end]
    if args.only_source is not None:
        detections = [(t_, d) for t_, d in detections if d.source == args.only_source]
    if args.frame:
        detections = [(t_, into_frame(d, args.frame, args.frame_pose)) for t_, d in detections]
    if not detections:
        sys.exit(f"dds_peer: no messages on {args.topic} in {args.bag}")
    dp = participant()
    keep = not args.count_only
    states = Recorder(dp, ros_topic("rt", args.state_topic), BallState_, True, 10000, keep)
    intercepts = Recorder(dp, ros_topic("rt", args.intercept_topic), InterceptPrediction_, True, 10000, keep)
    out = writer(dp, ros_topic("rt", args.topic), BallDetection_, False, 100)  # REP 2003 sensor data
    if args.frame:
        # table -> frame on /tf_static, transient local as tf2's static broadcaster publishes it.
        tf_qos = Qos(Policy.Reliability.Reliable(duration(seconds=1)), Policy.History.KeepLast(1),
                     Policy.Durability.TransientLocal)
        tf_writer = DataWriter(dp, Topic(dp, "rt/tf_static", TFMessage_), tf_qos)
        x, y, z, qx, qy, qz, qw = args.frame_pose
        tf_writer.write(TFMessage_(transforms=[TransformStamped_(
            header=Header_(stamp=Time_(sec=0, nanosec=0), frame_id="table"), child_frame_id=args.frame,
            transform=Transform_(translation=Vector3_(x=x, y=y, z=z),
                                 rotation=Quaternion_(x=qx, y=qy, z=qz, w=qw)))]))

    # The detections are volatile: send none before the node's reader has matched ours. Then give
    # the node's state/intercept writers up to 2 s more to match our readers (not required).
    if not wait_until(out.get_matched_subscriptions, time.monotonic() + args.wait_match):
        print(f"dds_peer: no subscriber to {args.topic} matched within {args.wait_match} s "
              f"(is `ttball node` running, on ROS_DOMAIN_ID={os.environ.get('ROS_DOMAIN_ID', '0')}?)",
              file=sys.stderr)
        return 3
    deadline = time.monotonic() + 2.0
    for rec, name in ((states, args.state_topic), (intercepts, args.intercept_topic)):
        if not wait_until(rec.reader.get_matched_publications, deadline):
            print(f"dds_peer: warning: no publisher of {name} matched yet", file=sys.stderr)
    time.sleep(0.5)

    # Each detection at its recorded offset / rate from the start, against the monotonic clock
    # (absolute targets, so sleep overshoot does not accumulate). send_ns is taken after write().
    sent, first, start = [], detections[0][0], time.monotonic_ns()
    for log_time, detection in detections:
        target = start + round((log_time - first) / args.rate)
        delay = target - time.monotonic_ns()
        if delay > 0:
            time.sleep(delay / 1e9)
        out.write(detection)
        if keep:
            sent.append({"stamp_ns": stamp_ns(detection.header.stamp), "send_ns": time.monotonic_ns()})
    time.sleep(args.linger)
    if not keep:
        result = {"sent": len(detections), "states": states.count, "intercepts": intercepts.count}
        write_json(args.out, result)
        print(f"dds_peer: sent {len(detections)} detections in {(time.monotonic_ns() - start) / 1e9:.1f} s, "
              f"received {states.count} states, {intercepts.count} intercepts", file=sys.stderr)
        return 0

    result = {"sent": sent, "states": states.snapshot(), "intercepts": intercepts.snapshot()}
    result["latency_ms"] = latency_ms(sent, result["states"])
    result["intercept_latency_ms"] = latency_ms(sent, result["intercepts"])
    write_json(args.out, result)

    def describe(lat):
        if not lat["count"]:
            return "n/a"
        return f"p50 {lat['p50']:.3f} ms, p99 {lat['p99']:.3f} ms, max {lat['max']:.3f} ms over {lat['count']}"
    print(f"dds_peer: sent {len(sent)} detections in {(sent[-1]['send_ns'] - start) / 1e9:.2f} s, received "
          f"{len(result['states'])} states, {len(result['intercepts'])} intercepts; latency to the state "
          f"{describe(result['latency_ms'])}; to the intercept {describe(result['intercept_latency_ms'])}",
          file=sys.stderr)
    return 0


@dataclass
class WrongDetection_(IdlStruct, typename="ttball_msgs::msg::dds_::BallDetection_"):
    """A detection type of the right name and other fields (another version of the .msg)."""
    label: str
    value: t.int64


@dataclass
class String_(IdlStruct, typename="std_msgs::msg::dds_::String_"):
    data: str


def cmd_publish_wrong(args):
    dp = participant()
    data_type, sample = {
        "other-fields": (WrongDetection_, lambda i: WrongDetection_(label=f"not a detection {i}", value=i)),
        "other-type": (String_, lambda i: String_(data=f"not a detection {i}")),
    }[args.kind]
    out = writer(dp, ros_topic("rt", args.topic), data_type, True, 1000)
    if not wait_until(out.get_matched_subscriptions, time.monotonic() + args.wait_match):
        print(f"dds_peer: no subscriber to {args.topic} matched a {args.kind} writer within "
              f"{args.wait_match} s", file=sys.stderr)
        write_json(args.out, {"matched": False, "sent": 0})
        return 3
    time.sleep(0.5)
    for i in range(args.count):
        out.write(sample(i))
        time.sleep(0.001)
    time.sleep(args.linger)
    write_json(args.out, {"matched": True, "sent": args.count})
    print(f"dds_peer: sent {args.count} {args.kind} samples on {args.topic}", file=sys.stderr)
    return 0


def cmd_listen(args):
    dp = participant()
    rec = Recorder(dp, ros_topic("rt", args.topic), BallDetection_, False, 10000)
    deadline = time.monotonic() + args.timeout
    with rec.arrived:
        while not (args.count and len(rec.records) >= args.count):
            left = deadline - time.monotonic()
            if left <= 0:
                break
            rec.arrived.wait(left)
    received = rec.snapshot()
    write_json(args.out, {"received": received})
    print(f"dds_peer: received {len(received)} detections on {args.topic}", file=sys.stderr)
    return 0


def call(args, request_type, reply_type, **fields):
    """Calls the service args.service once with request_type(**fields) (rmw_cyclonedds mapping)
    and returns (exit code, reply): 3 when the service did not match, 4 when no reply came."""
    dp = participant()
    service = args.service.strip("/")
    request_writer = writer(dp, ros_topic("rq", service, "Request"), request_type, True, 10)
    replies = Recorder(dp, ros_topic("rr", service, "Reply"), reply_type, True, 10)

    # Both directions must be matched before the (volatile) request is sent.
    deadline = time.monotonic() + args.timeout
    if not wait_until(lambda: request_writer.get_matched_subscriptions()
                      and replies.reader.get_matched_publications(), deadline):
        print(f"dds_peer: service {args.service} not matched within {args.timeout} s (is `ttball node` "
              "running with -p node.service_mapping:=cyclone?)", file=sys.stderr)
        return 3, None

    # Discovery is asymmetric: the node's reply writer may match our reply reader a little after
    # we see it, and a reply written before that is lost (volatile). Give it a moment, and should
    # a reply still be lost, ask again (a new sequence number; either answer will do).
    time.sleep(0.5)
    guid, attempts = random.getrandbits(64), 3
    sent = []

    def ours():
        return next((r for r in replies.samples if (r.client_guid, r.sequence_number) in sent), None)

    for seq in range(1, attempts + 1):
        sent.append((guid, seq))
        request_writer.write(request_type(client_guid=guid, sequence_number=seq, **fields))
        with replies.arrived:
            replies.arrived.wait_for(ours, args.timeout / attempts)
        if ours() is not None:
            break
        print(f"dds_peer: no reply from {args.service} to request {seq} yet", file=sys.stderr)
    reply = ours()
    if reply is None:
        print(f"dds_peer: no reply from {args.service} within {args.timeout} s", file=sys.stderr)
        return 4, None
    return 0, reply


def report(args, reply, **extra):
    """Writes the reply as JSON {success, message, cdr, **extra} and says what it was."""
    write_json(args.out, {"success": reply.success, "message": reply.message,
                          "cdr": reply.serialize().hex(), **extra})
    print(f"dds_peer: {args.service}: success={reply.success}"
          + "".join(f" {key}={value}" for key, value in extra.items())
          + (f" message={reply.message!r}" if reply.message else ""), file=sys.stderr)
    return 0


def ball_state(values):
    """A BallState_ stamped now, in the table frame, from (x, y, z, vx, vy, vz, wx, wy, wz)."""
    x, y, z, vx, vy, vz, wx, wy, wz = values
    now = time.time_ns()
    return BallState_(
        header=Header_(stamp=Time_(sec=now // 1_000_000_000, nanosec=now % 1_000_000_000), frame_id="table"),
        track_id=0, status=2, position=Point_(x=x, y=y, z=z), velocity=Vector3_(x=vx, y=vy, z=vz),
        spin=Vector3_(x=wx, y=wy, z=wz), covariance=[0.0] * 81, bounces=0, nis=0.0)


def cmd_call_predict(args):
    code, reply = call(args, PredictTrajectory_Request_, PredictTrajectory_Response_, track_id=args.track_id,
                       initial=ball_state(args.initial), horizon=args.horizon, dt=args.dt)
    return code if reply is None else report(args, reply, points=len(reply.trajectory.stamps))


def cmd_call_rebound(args):
    x, y, z, vx, vy, vz, wx, wy, wz = args.ball
    rvx, rvy, rvz, nx, ny, nz = args.racket
    code, reply = call(args, PredictRebound_Request_, PredictRebound_Response_,
                       ball_position=Point_(x=x, y=y, z=z), ball_velocity=Vector3_(x=vx, y=vy, z=vz),
                       ball_spin=Vector3_(x=wx, y=wy, z=wz), racket_velocity=Vector3_(x=rvx, y=rvy, z=rvz),
                       racket_normal=Vector3_(x=nx, y=ny, z=nz), impact_offset=args.impact_offset)
    return code if reply is None else report(args, reply, lands_on_table=reply.lands_on_table)


def cmd_call_plan(args):
    tx, ty = args.target
    code, reply = call(args, PlanReturn_Request_, PlanReturn_Response_, track_id=args.track_id,
                       ball=ball_state(args.ball), target=Point_(x=tx, y=ty, z=0.0),
                       flight_time=args.flight_time, net_clearance=args.net_clearance,
                       impact_offset=args.impact_offset, brush_speed=args.brush_speed)
    return code if reply is None else report(args, reply, landing_error=reply.landing_error)


def parameter_value(value):
    """A Python bool, int, float, str or list of floats as rcl_interfaces/ParameterValue."""
    fields = dict(type=0, bool_value=False, integer_value=0, double_value=0.0, string_value="",
                  byte_array_value=[], bool_array_value=[], integer_array_value=[], double_array_value=[],
                  string_array_value=[])
    if isinstance(value, bool):
        fields.update(type=1, bool_value=value)
    elif isinstance(value, int):
        fields.update(type=2, integer_value=value)
    elif isinstance(value, float):
        fields.update(type=3, double_value=value)
    elif isinstance(value, str):
        fields.update(type=4, string_value=value)
    elif isinstance(value, list):
        fields.update(type=8, double_array_value=[float(v) for v in value])
    return ParameterValue_(**fields)


def plain_value(value):
    """An rcl_interfaces/ParameterValue as a Python value (None when NOT_SET)."""
    return {0: None, 1: value.bool_value, 2: value.integer_value, 3: value.double_value,
            4: value.string_value, 8: list(value.double_array_value)}.get(value.type, "?")


def call_node(args, service, request_type, reply_type, **fields):
    """`call` of the service ~/service of the node args.node; returns (exit code, reply)."""
    ns = argparse.Namespace(service=f"{args.node.rstrip('/')}/{service}", timeout=args.timeout)
    return call(ns, request_type, reply_type, **fields)


def cmd_params(args):
    """Lists, gets, describes and sets the node's parameters through rcl_interfaces' services (as
    `ros2 param` does), records /parameter_events meanwhile, and calls ~/reset."""
    node = args.node.rstrip("/")
    dp = participant()
    events = Recorder(dp, "rt/parameter_events", ParameterEvent_, True, 1000)
    out = {}

    def ask(service, request_type, reply_type, **fields):
        code, reply = call_node(args, service, request_type, reply_type, **fields)
        if reply is None:
            sys.exit(code)
        return reply

    listed = ask("list_parameters", ListParameters_Request_, ListParameters_Response_, prefixes=[], depth=0)
    out["list"] = list(listed.result.names)
    names = ["intercept.plane_x", "table.restitution", "node.namespace", "use_sim_time",
             "gating.max_consecutive_rejections", "aero.drag_coefficients", "no.such_parameter"]
    got = ask("get_parameters", GetParameters_Request_, GetParameters_Response_, names=names)
    out["get"] = {n: plain_value(v) for n, v in zip(names, got.values)}
    described = ask("describe_parameters", DescribeParameters_Request_, DescribeParameters_Response_,
                    names=["table.restitution", "intercept.plane_x", "gating.probability"])
    out["describe"] = [{"name": d.name, "type": d.type, "description": d.description,
                        "constraints": d.additional_constraints, "read_only": d.read_only,
                        "range": [[r.from_value, r.to_value] for r in d.floating_point_range]}
                       for d in described.descriptors]
    sets = [("intercept.plane_x", -1.45), ("table.restitution", 0.8), ("gating.probability", 2.0),
            ("tracking.timeout", "fast")]
    result = ask("set_parameters", SetParameters_Request_, SetParameters_Response_,
                 parameters=[Parameter_(name=n, value=parameter_value(v)) for n, v in sets])
    out["set"] = [{"name": n, "successful": r.successful, "reason": r.reason}
                  for (n, _), r in zip(sets, result.results)]
    atomic = ask("set_parameters_atomically", SetParametersAtomically_Request_, SetParametersAtomically_Response_,
                 parameters=[Parameter_(name="ekf.acceleration_noise_density", value=parameter_value(0.003)),
                             Parameter_(name="tracking.coast_after", value=parameter_value(5.0))])
    out["atomic_refused"] = {"successful": atomic.result.successful, "reason": atomic.result.reason}
    atomic = ask("set_parameters_atomically", SetParametersAtomically_Request_, SetParametersAtomically_Response_,
                 parameters=[Parameter_(name="ekf.acceleration_noise_density", value=parameter_value(0.003)),
                             Parameter_(name="sources.wide_150fps.position_sigma", value=parameter_value(0.0025))])
    out["atomic"] = {"successful": atomic.result.successful, "reason": atomic.result.reason}
    got = ask("get_parameters", GetParameters_Request_, GetParameters_Response_, names=names)
    out["get_after"] = {n: plain_value(v) for n, v in zip(names, got.values)}
    reset = ask("reset", Trigger_Request_, Trigger_Response_, structure_needs_at_least_one_member=0)
    out["reset"] = {"success": reset.success, "message": reset.message}
    time.sleep(0.5)
    out["events"] = [{"node": e.node, "changed": {p.name: plain_value(p.value) for p in e.changed_parameters},
                      "new": len(e.new_parameters)} for e in events.samples]
    write_json(args.out, out)
    print(f"dds_peer: {node}: {len(out['list'])} parameters, sets {[s['successful'] for s in out['set']]}, "
          f"{len(out['events'])} parameter events", file=sys.stderr)
    return 0


def cmd_set_params(args):
    """Sets parameters of --node through rcl_interfaces/SetParameters, as `ros2 param set` does."""
    sets = []
    for assignment in args.assignments:
        name, sep, text = assignment.partition(":=")
        if not sep:
            print(f"dds_peer: {assignment!r} is not NAME:=VALUE", file=sys.stderr)
            return 2
        value = {"true": True, "false": False}.get(text.lower())
        if value is None:
            try:
                value = int(text)
            except ValueError:
                try:
                    value = float(text)
                except ValueError:
                    value = text
        sets.append((name, value))
    code, reply = call_node(args, "set_parameters", SetParameters_Request_, SetParameters_Response_,
                            parameters=[Parameter_(name=n, value=parameter_value(v)) for n, v in sets])
    if reply is None:
        return code
    out = [{"name": n, "successful": r.successful, "reason": r.reason} for (n, _), r in zip(sets, reply.results)]
    write_json(args.out, out)
    print(f"dds_peer: set {[(o['name'], o['successful']) for o in out]}", file=sys.stderr)
    return 0 if all(o["successful"] for o in out) else 5


def cmd_record(args):
    """Records /diagnostics and /rosout for --seconds; with --clock, publishes a simulated time
    on /clock meanwhile, as `ros2 bag play --clock` does."""
    dp = participant()
    diagnostics = Recorder(dp, "rt/diagnostics", DiagnosticArray_, True, 1000)
    # Transient local, as rcl offers /rosout: a node's log from before the match arrives too.
    rosout = Recorder(dp, "rt/rosout", Log_, True, 1000, transient_local=True)
    clock = writer(dp, "rt/clock", Clock_, False, 1) if args.clock is not None else None
    started = time.monotonic()
    deadline = started + args.seconds
    while time.monotonic() < deadline and not (args.until_file and os.path.exists(args.until_file)):
        if clock is not None:
            now = int((args.clock + time.monotonic() - started) * 1e9)
            clock.write(Clock_(clock=Time_(sec=now // 1_000_000_000, nanosec=now % 1_000_000_000)))
            time.sleep(0.02)
        else:
            time.sleep(0.1)
    out = {
        "diagnostics": [{"stamp_ns": stamp_ns(d.header.stamp),
                         "status": [{"level": s.level, "name": s.name, "message": s.message,
                                     "hardware_id": s.hardware_id} for s in d.status]}
                        for d in diagnostics.samples],
        "rosout": [{"level": r.level, "name": r.name, "msg": r.msg} for r in rosout.samples],
    }
    write_json(args.out, out)
    print(f"dds_peer: recorded {len(out['diagnostics'])} diagnostics, {len(out['rosout'])} log records",
          file=sys.stderr)
    return 0


def discovery_type(gid_length):
    """rmw_dds_common/msg/ParticipantEntitiesInfo with GIDs of `gid_length` bytes: 24 up to
    Humble (`char[24] data`), 16 from Iron on (`uint8[16] data`)."""

    @dataclass
    class Gid_(IdlStruct, typename="rmw_dds_common::msg::dds_::Gid_"):
        data: t.array[t.uint8, gid_length]

    @dataclass
    class NodeEntitiesInfo_(IdlStruct, typename="rmw_dds_common::msg::dds_::NodeEntitiesInfo_"):
        node_namespace: str
        node_name: str
        reader_gid_seq: t.sequence[Gid_]
        writer_gid_seq: t.sequence[Gid_]

    @dataclass
    class ParticipantEntitiesInfo_(IdlStruct, typename="rmw_dds_common::msg::dds_::ParticipantEntitiesInfo_"):
        gid: Gid_
        node_entities_info_seq: t.sequence[NodeEntitiesInfo_]

    return ParticipantEntitiesInfo_


def cmd_discovery(args):
    """Reads ros_discovery_info in --distro's layout and the DDS endpoints it names."""
    from cyclonedds.builtin import (BuiltinDataReader, BuiltinTopicDcpsPublication,
                                    BuiltinTopicDcpsSubscription)
    gid_length = 24 if args.distro == "humble" else 16
    dp = participant()
    raw = DataReader(dp, Topic(dp, "ros_discovery_info", discovery_type(gid_length)),
                     qos(True, 100, transient_local=True))
    publications = BuiltinDataReader(dp, BuiltinTopicDcpsPublication)
    subscriptions = BuiltinDataReader(dp, BuiltinTopicDcpsSubscription)
    endpoints, nodes, decoded, undecodable = {}, {}, 0, 0
    deadline = time.monotonic() + args.timeout
    while time.monotonic() < deadline:
        for reader in (publications, subscriptions):
            for e in reader.take(N=256):
                if getattr(e, "topic_name", None):
                    endpoints[e.key.bytes.hex()] = e.topic_name
        try:
            samples = raw.take(N=64)
        except Exception as error:  # a layout that is not the writer's does not deserialise
            undecodable += 1
            print(f"dds_peer: ros_discovery_info does not decode as {args.distro}'s: {error}", file=sys.stderr)
            samples = []
        for sample in samples:
            decoded += 1
            for n in sample.node_entities_info_seq:
                nodes[(n.node_namespace, n.node_name)] = {
                    "namespace": n.node_namespace, "name": n.node_name,
                    "writers": [bytes(g.data).hex() for g in n.writer_gid_seq],
                    "readers": [bytes(g.data).hex() for g in n.reader_gid_seq],
                }
        wanted = nodes.get(("/", args.node))
        if wanted and all(w[:32] in endpoints for w in wanted["writers"] + wanted["readers"]):
            break
        time.sleep(0.1)
    out = {"distro": args.distro, "gid_length": gid_length, "decoded": decoded,
           "undecodable": undecodable, "nodes": list(nodes.values()), "endpoints": endpoints}
    write_json(args.out, out)
    print(f"dds_peer: {decoded} ros_discovery_info samples decoded as {args.distro}'s, {undecodable} not; "
          f"{len(endpoints)} endpoints", file=sys.stderr)
    return 0


STATE = ("X", "Y", "Z", "VX", "VY", "VZ", "WX", "WY", "WZ")
# A ball at the robot's hitting plane after its bounce, flying toward the robot.
INCOMING = [-1.6, 0.1, 0.25, -5.0, 0.4, -1.0, 20.0, -150.0, 30.0]


def call_options(p, run):
    """The options every call-* command shares."""
    p.add_argument("--timeout", type=float, default=10.0, metavar="SECONDS",
                   help="for matching and for the reply, each (default %(default)s)")
    p.add_argument("--out", metavar="FILE.json", help="write the reply here")
    p.set_defaults(run=run)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter,
                                     epilog="Environment: ROS_DOMAIN_ID (default 0); CYCLONEDDS_URI "
                                            "(default: loopback only, see the module docstring).")
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("publish", help="play a bag's detections to the node, record its states and intercepts",
                       description="Publish every detection of BAG (BestEffort, KeepLast 100, Volatile) at its "
                                   "recorded time once a subscriber has matched, while recording the node's "
                                   "states and intercepts (Reliable, KeepLast 10000). Writes JSON {sent, states, "
                                   "intercepts, latency_ms}. Exit code 3 when no subscriber matched.")
    p.add_argument("bag", help="MCAP file with ttball_msgs/BallDetection messages (CDR)")
    p.add_argument("--topic", default="/ball/detections", help="detections topic (default %(default)s)")
    p.add_argument("--bag-topic", help="the detections' topic in the bag (default: --topic)")
    p.add_argument("--state-topic", default="/ball/state", help="default %(default)s")
    p.add_argument("--intercept-topic", default="/ball/intercept", help="default %(default)s")
    p.add_argument("--rate", type=float, default=1.0, help="playback speed factor (default %(default)s)")
    p.add_argument("--first", type=int, default=0, help="index of the first detection to send (default 0)")
    p.add_argument("--count", type=int, default=0, help="how many to send (default: all from --first)")
    p.add_argument("--frame", help="send the detections in this frame, after publishing its pose in `table` "
                                    "(--frame-pose) on /tf_static")
    p.add_argument("--frame-pose", type=float, nargs=7, metavar=("X", "Y", "Z", "QX", "QY", "QZ", "QW"),
                   default=[-3.0, 0.5, 2.5, 0.0, 0.0, 0.7071067811865476, 0.7071067811865476],
                   help="the frame's pose in `table` (default: 3 m behind, 2.5 m up, a quarter turn about z)")
    p.add_argument("--only-source", type=int, metavar="CODE",
                   help="send only the detections of this source (BallDetection.SOURCE_*: 1 the 150 fps camera)")
    p.add_argument("--count-only", action="store_true",
                   help="keep counts only, not every sample (long runs); writes {sent, states, intercepts}")
    p.add_argument("--wait-match", type=float, default=10.0, metavar="SECONDS",
                   help="how long to wait for a subscriber (default %(default)s)")
    p.add_argument("--linger", type=float, default=2.0, metavar="SECONDS",
                   help="keep recording this long after the last detection (default %(default)s)")
    p.add_argument("--out", metavar="FILE.json", help="write the results here")
    p.set_defaults(run=cmd_publish)

    p = sub.add_parser("publish-wrong", help="publish samples of a wrong type on the detections topic",
                       description="Publish --count samples on the detections topic (Reliable) that are not "
                                   "detections: 'other-fields' has the detection's DDS type name and other "
                                   "fields (the node must count them undecodable), 'other-type' another type "
                                   "name (DDS does not match it with the node). Exit code 3 when nothing matched.")
    p.add_argument("kind", choices=["other-fields", "other-type"])
    p.add_argument("--topic", default="/ball/detections", help="default %(default)s")
    p.add_argument("--count", type=int, default=100, help="default %(default)s")
    p.add_argument("--wait-match", type=float, default=10.0, metavar="SECONDS", help="default %(default)s")
    p.add_argument("--linger", type=float, default=0.5, metavar="SECONDS", help="default %(default)s")
    p.add_argument("--out", metavar="FILE.json", help="write {matched, sent} here")
    p.set_defaults(run=cmd_publish_wrong)

    p = sub.add_parser("listen", help="record detections published by someone else (e.g. `ttball play`)",
                       description="Subscribe to detections (BestEffort, KeepLast 10000) until --count arrive "
                                   "or --timeout passes. Writes JSON {received: [{stamp_ns, recv_ns, cdr}]}.")
    p.add_argument("--topic", default="/ball/detections", help="default %(default)s")
    p.add_argument("--count", type=int, default=0, help="stop after this many (default: wait for --timeout)")
    p.add_argument("--timeout", type=float, default=30.0, metavar="SECONDS", help="default %(default)s")
    p.add_argument("--out", metavar="FILE.json", help="write the results here")
    p.set_defaults(run=cmd_listen)

    p = sub.add_parser("call-predict", help="call the node's PredictTrajectory service",
                       description="Call ttball_msgs/srv/PredictTrajectory over DDS (rmw_cyclonedds mapping: "
                                   "rq/<service>Request, rr/<service>Reply, Reliable, KeepLast 10). Writes JSON "
                                   "{success, message, cdr, points}. Exit code 3 when the service did not match, "
                                   "4 when no reply came within --timeout.")
    p.add_argument("--service", default="/ttball/predict_trajectory", help="default %(default)s")
    p.add_argument("--track-id", type=int, default=0, help="track to predict from; 0 = --initial (default 0)")
    p.add_argument("--horizon", type=float, default=0.5, metavar="SECONDS", help="default %(default)s")
    p.add_argument("--dt", type=float, default=0.01, metavar="SECONDS", help="default %(default)s")
    p.add_argument("--initial", type=float, nargs=9, metavar=STATE,
                   default=[1.0178, -0.0184, 0.4448, -5.4122, -0.1333, 1.5129, 7.051, -40.643, -3.915],
                   help="initial state in the table frame [m, m/s, rad/s] (default: the rally ball of "
                        "`ttball predict`)")
    call_options(p, cmd_call_predict)

    p = sub.add_parser("call-rebound", help="call the node's PredictRebound service",
                       description="Call ttball_msgs/srv/PredictRebound over DDS (rmw_cyclonedds mapping, as "
                                   "call-predict): the ball's rebound off the racket and where it lands. Writes "
                                   "JSON {success, message, cdr, lands_on_table}; exit codes as call-predict.")
    p.add_argument("--service", default="/ttball/predict_rebound", help="default %(default)s")
    p.add_argument("--ball", type=float, nargs=9, metavar=STATE, default=INCOMING,
                   help="ball just before impact, table frame [m, m/s, rad/s] (default %(default)s)")
    p.add_argument("--racket", type=float, nargs=6, metavar=("VX", "VY", "VZ", "NX", "NY", "NZ"), required=True,
                   help="velocity of the racket's impact point [m/s] and unit normal of its face, toward the ball")
    p.add_argument("--impact-offset", type=float, default=0.0, metavar="METRES",
                   help="impact point from the racket's centre of gravity along its long axis (default 0)")
    call_options(p, cmd_call_rebound)

    p = sub.add_parser("call-plan", help="call the node's PlanReturn service",
                       description="Call ttball_msgs/srv/PlanReturn over DDS (rmw_cyclonedds mapping, as "
                                   "call-predict): the racket command that returns the ball to --target. Writes "
                                   "JSON {success, message, cdr, landing_error}; exit codes as call-predict.")
    p.add_argument("--service", default="/ttball/plan_return", help="default %(default)s")
    p.add_argument("--track-id", type=int, default=0,
                   help="plan against this track's interception; 0 = --ball (default 0)")
    p.add_argument("--ball", type=float, nargs=9, metavar=STATE, default=INCOMING,
                   help="ball just before impact, table frame [m, m/s, rad/s] (default %(default)s)")
    p.add_argument("--target", type=float, nargs=2, metavar=("X", "Y"), default=[0.9, 0.0],
                   help="landing point on the opponent's half [m] (default %(default)s)")
    p.add_argument("--flight-time", type=float, default=0.0, metavar="SECONDS",
                   help="time from impact to landing; 0 = use --net-clearance (default 0)")
    p.add_argument("--net-clearance", type=float, default=0.0, metavar="METRES",
                   help="ball bottom over the net top; 0 = the node's stroke.net_clearance (default 0)")
    p.add_argument("--impact-offset", type=float, default=0.0, metavar="METRES",
                   help="impact point from the racket's centre of gravity along its long axis (default 0)")
    p.add_argument("--brush-speed", type=float, default=0.0, metavar="M/S",
                   help="racket speed along the face, upward (> 0 topspin) (default 0)")
    call_options(p, cmd_call_plan)

    p = sub.add_parser("record", help="record /diagnostics and /rosout (optionally publishing /clock)",
                       description="Subscribe to /diagnostics and /rosout (Reliable, KeepLast 1000) for --seconds. "
                                   "Writes JSON {diagnostics: [{stamp_ns, status: [{level, name, message, "
                                   "hardware_id}]}], rosout: [{level, name, msg}]}.")
    p.add_argument("--seconds", type=float, default=10.0, help="at most (default %(default)s)")
    p.add_argument("--until-file", metavar="PATH", help="stop as soon as this file exists")
    p.add_argument("--clock", type=float, metavar="SECONDS",
                   help="meanwhile publish /clock (rosgraph_msgs/Clock, best effort) at 50 Hz, "
                        "starting at this simulated time and running at the wall clock's rate")
    p.add_argument("--out", metavar="FILE.json", help="write the records here")
    p.set_defaults(run=cmd_record)

    p = sub.add_parser("params", help="list, get, describe and set the node's parameters; call ~/reset",
                       description="Call rcl_interfaces' parameter services of --node as `ros2 param` does "
                                   "(rmw_cyclonedds mapping), set a few (some refused on purpose), call "
                                   "~/reset, and record /parameter_events meanwhile. Writes JSON {list, get, "
                                   "describe, set, atomic_refused, atomic, get_after, reset, events}.")
    p.add_argument("--node", default="/ttball", help="the node's fully qualified name (default %(default)s)")
    call_options(p, cmd_params)

    p = sub.add_parser("set-params", help="set the node's parameters, as `ros2 param set` does",
                       description="Call --node's rcl_interfaces/SetParameters (rmw_cyclonedds mapping) with "
                                   "NAME:=VALUE assignments (true/false, integers, floats, else strings). "
                                   "Writes JSON [{name, successful, reason}]; exits 5 when one was refused.")
    p.add_argument("--node", default="/ttball", help="the node's fully qualified name (default %(default)s)")
    p.add_argument("assignments", nargs="+", metavar="NAME:=VALUE")
    call_options(p, cmd_set_params)

    p = sub.add_parser("discovery", help="read ros_discovery_info as --distro lays it out",
                       description="Read rmw_dds_common/ParticipantEntitiesInfo on ros_discovery_info (reliable, "
                                   "transient local) with --distro's GID length (humble 24 bytes, jazzy 16) and "
                                   "the DDS publications and subscriptions (built-in topics), until --node's "
                                   "endpoints are all seen or --timeout. Writes JSON {distro, gid_length, decoded, "
                                   "undecodable, nodes: [{namespace, name, writers, readers}], endpoints: "
                                   "{guid: topic}}.")
    p.add_argument("--distro", choices=["humble", "jazzy"], required=True)
    p.add_argument("--node", default="ttball", help="the node's name, in namespace / (default %(default)s)")
    p.add_argument("--timeout", type=float, default=15.0, help="seconds (default %(default)s)")
    p.add_argument("--out", metavar="FILE.json", help="write the result here")
    p.set_defaults(run=cmd_discovery)

    args = parser.parse_args(argv)
    return args.run(args)


if __name__ == "__main__":
    code = main()
    # Every output is written and closed by now. Leave without the interpreter's teardown: the
    # Cyclone binding's listener threads can still be running then, and its finalisers were seen
    # to kill the process (SIGILL) after a recording with /clock written meanwhile.
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code or 0)
