"""Decode every message of a ttball bag with MCAP clients ttball did not write, and compare
every field with what ttball says it wrote.

Usage: check_bag.py BAG.mcap DUMP.jsonl

DUMP.jsonl is `ttball dump BAG.mcap` (one JSON object per message, in log-time order). Each
message is decoded twice, independently: by `mcap` + `mcap-ros2-support` (which parse the
ros2msg schema embedded in the bag) and by `rosbags` (its own CDR deserialiser, with the types
registered from the same schema text). Messages of ROS 2's standard types are decoded a third
and fourth time with rosbags' own typestores of ROS 2 Humble and Jazzy, independently of the
schemas the bag embeds. Every field must equal ttball's value: integers and strings exactly,
float64 exactly, float32 after rounding both sides to float32. Every channel must carry the
`offered_qos_profiles` rosbag2 records (best effort for the detections, reliable otherwise).
Exit code 0 when everything matches, 1 otherwise (with the first differences printed).
"""

import dataclasses
import json
import re
import struct
import sys

from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
import yaml
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

# rosbags' own definitions of the ROS 2 distributions ttball targets.
DISTRIBUTIONS = {"humble": get_typestore(Stores.ROS2_HUMBLE), "jazzy": get_typestore(Stores.ROS2_JAZZY)}


def plain(value):
    """A decoded message (either library) as plain dicts, lists and numbers."""
    if hasattr(value, "tolist"):  # numpy arrays (rosbags)
        return value.tolist()
    if isinstance(value, (bytes, bytearray)):
        return list(value)
    if isinstance(value, (list, tuple)):
        return [plain(v) for v in value]
    if dataclasses.is_dataclass(value):  # rosbags
        names = [f.name for f in dataclasses.fields(value)]
    else:  # mcap-ros2-support
        names = getattr(value, "__slots__", None)
    if names:  # constants (UPPER_CASE) and dunders are not fields
        return {k: plain(getattr(value, k)) for k in names if not k.startswith("__") and not k.isupper()}
    return value


def f32(x):
    return struct.unpack("<f", struct.pack("<f", x))[0]


def compare(ours, theirs, path, problems):
    if isinstance(ours, dict):
        if not isinstance(theirs, dict) or set(ours) != set(theirs):
            problems.append(f"{path}: fields {sorted(ours)} vs {sorted(theirs) if isinstance(theirs, dict) else theirs!r}")
            return
        for key in ours:
            compare(ours[key], theirs[key], f"{path}.{key}", problems)
    elif isinstance(ours, list):
        if not isinstance(theirs, list) or len(ours) != len(theirs):
            problems.append(f"{path}: {len(ours)} elements vs {theirs!r:.80}")
            return
        for i, (a, b) in enumerate(zip(ours, theirs)):
            compare(a, b, f"{path}[{i}]", problems)
    elif isinstance(ours, float) or isinstance(theirs, float):
        if not (float(ours) == float(theirs) or f32(float(ours)) == f32(float(theirs))):
            problems.append(f"{path}: {ours!r} vs {theirs!r}")
    elif ours != theirs:
        problems.append(f"{path}: {ours!r} vs {theirs!r}")


def rosbags_typestore(schemas):
    """A typestore with every type of the bag's ros2msg schemas."""
    store = get_typestore(Stores.EMPTY)
    types = {}
    for name, text in schemas.items():
        sections = re.split(r"\n=+\nMSG: ", "\n" + text.strip("\n"))
        types.update(get_types_from_msg(sections[0], name))
        for section in sections[1:]:
            dep, _, body = section.partition("\n")
            pkg, _, ty = dep.strip().partition("/")
            types.update(get_types_from_msg(body, f"{pkg}/msg/{ty}"))
    store.register(types)
    return store


def main():
    bag, dump = sys.argv[1], sys.argv[2]
    with open(dump) as f:
        expected = [json.loads(line) for line in f if line.strip()]
    decoded = []
    schemas = {}
    problems = []
    with open(bag, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for channel in reader.get_summary().channels.values():
            profiles = yaml.safe_load(channel.metadata.get("offered_qos_profiles", "null"))
            reliability = 2 if channel.topic.endswith("/detections") else 1
            if not (isinstance(profiles, list) and profiles and profiles[0].get("reliability") == reliability):
                problems.append(f"{channel.topic}: offered_qos_profiles {profiles!r}, expected reliability {reliability}")
        for schema, channel, message, ros_msg in reader.iter_decoded_messages(log_time_order=True):
            schemas[schema.name] = schema.data.decode()
            decoded.append((channel.topic, schema.name, message, ros_msg))
    store = rosbags_typestore(schemas)
    known = {e["type"] for e in expected}
    decoded = [d for d in decoded if d[1] in known]
    standard = {}
    if len(decoded) != len(expected):
        problems.append(f"{len(decoded)} messages decoded, ttball wrote {len(expected)}")
    counts = {}
    for (topic, type_name, message, ros_msg), ours in zip(decoded, expected):
        counts[topic] = counts.get(topic, 0) + 1
        if (topic, type_name, message.log_time) != (ours["topic"], ours["type"], ours["log_time"]):
            problems.append(f"order: {topic} {message.log_time} vs {ours['topic']} {ours['log_time']}")
            break
        compare(ours["message"], plain(ros_msg), f"{topic}@{message.log_time} (mcap-ros2)", problems)
        other = store.deserialize_cdr(message.data, type_name)
        compare(ours["message"], plain(other), f"{topic}@{message.log_time} (rosbags)", problems)
        for distribution, typestore in DISTRIBUTIONS.items():
            if type_name in typestore.fielddefs:
                theirs = typestore.deserialize_cdr(message.data, type_name)
                compare(ours["message"], plain(theirs), f"{topic}@{message.log_time} (rosbags {distribution})", problems)
                standard[(type_name, distribution)] = standard.get((type_name, distribution), 0) + 1
        if len(problems) > 20:
            break
    for p in problems[:20]:
        print("MISMATCH", p)
    print("checked", ", ".join(f"{t}: {n}" for t, n in sorted(counts.items())))
    print("standard types", ", ".join(f"{t} ({d}): {n}" for (t, d), n in sorted(standard.items())))
    sys.exit(1 if problems else 0)


if __name__ == "__main__":
    main()
