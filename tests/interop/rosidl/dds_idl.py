"""Write the DDS IDL of ttball's ROS 2 interfaces for fastddsgen with ROS 2's own interface tools.

rosidl_adapter (`rosidl translate`) turns every interface of msgs/ into ROS IDL, and the standard
ones that those and the Fast DDS peer use (standard/: builtin_interfaces, std_msgs,
geometry_msgs, rcl_interfaces, std_srvs, field for field as ROS 2 defines them); rosidl_parser
parses each, and each structure is written as ROS 2 maps it onto DDS (as
rosidl_generator_dds_idl does): `pkg/msg/Type` as `pkg::msg::dds_::Type_`, a service's halves as
`pkg::srv::dds_::Service_Request_` and `..._Response_`. An interface rosidl refuses fails the
run with rosidl's own message.

Needs Debian's python3-rosidl, rosidl-tools, python3-catkin-pkg and python3-empy (run it with the
system's /usr/bin/python3, which has them).

With `--json FILE`, also writes each ttball_msgs structure as rosidl read it (its fields and
constants in .msg notation), for the contract test of the Rust types
(tests/adapters/msgs_contract.rs, `TTBALL_ROSIDL_JSON`).

With `--distro NAME` (jazzy or humble), also `rmw_dds_common`'s discovery types in that
distribution's layout (distro/NAME/: 16-byte GIDs from Iron on, 24 up to Humble), for the peer's
reading of `ros_discovery_info`.

Usage: dds_idl.py MSGS_DIR WORK_DIR [--json FILE] [--distro NAME] > ttball.idl
"""

import json
import pathlib
import subprocess
import sys

from rosidl_parser.definition import (
    Array,
    BasicType,
    BoundedSequence,
    BoundedString,
    IdlLocator,
    Message,
    NamespacedType,
    Service,
    UnboundedSequence,
    UnboundedString,
)
from rosidl_parser.parser import parse_idl_file

HERE = pathlib.Path(__file__).resolve().parent

# ROS IDL's basic types as DDS IDL writes them (fastddsgen's names).
BASIC = {
    "boolean": "boolean",
    "octet": "octet",
    "char": "char",
    "float": "float",
    "double": "double",
    "int8": "char",
    "uint8": "octet",
    "int16": "short",
    "uint16": "unsigned short",
    "int32": "long",
    "uint32": "unsigned long",
    "int64": "long long",
    "uint64": "unsigned long long",
}


def packages(msgs, distro):
    """(package name, its directory) of ttball_msgs, of each standard package, and of the
    distribution's own ones."""
    yield "ttball_msgs", msgs
    folders = [HERE / "standard"] + ([HERE / "distro" / distro] if distro else [])
    for folder in folders:
        for path in sorted(p for p in folder.iterdir() if p.is_dir()):
            yield path.name, path


def parsed(name, directory, work):
    """(structure, constants) of one package's interfaces, translated to ROS IDL and parsed by
    rosidl."""
    files = sorted(
        path.relative_to(directory).as_posix()
        for kind, suffix in (("msg", "*.msg"), ("srv", "*.srv"))
        for path in (directory / kind).glob(suffix)
    )
    # rosidl's own command (its progress to stderr, stdout is the IDL written here).
    subprocess.run(
        ["rosidl", "translate", "--to", "idl", "-o", str(work / name), name,
         *(f"{directory}:{f}" for f in files)],
        stdout=sys.stderr,
        check=True,
    )
    for relative in files:
        idl = pathlib.Path(relative).with_suffix(".idl")
        content = parse_idl_file(IdlLocator(work / name, idl)).content
        for message in content.get_elements_of_type(Message):
            yield message.structure, message.constants
        for service in content.get_elements_of_type(Service):
            for half in (service.request_message, service.response_message):
                yield half.structure, half.constants


# ROS IDL's basic types in .msg notation (the inverse of rosidl_adapter's mapping).
MSG_BASIC = {
    "boolean": "bool",
    "octet": "byte",
    "float": "float32",
    "double": "float64",
}


def msg_type(t):
    """A ROS IDL type in .msg notation: `float64[9]`, `string<=8`, `geometry_msgs/Point[]`."""
    if isinstance(t, Array):
        return f"{msg_type(t.value_type)}[{t.size}]"
    if isinstance(t, UnboundedSequence):
        return f"{msg_type(t.value_type)}[]"
    if isinstance(t, BoundedSequence):
        return f"{msg_type(t.value_type)}[<={t.maximum_size}]"
    if isinstance(t, BasicType):
        return MSG_BASIC.get(t.typename, t.typename)
    if isinstance(t, UnboundedString):
        return "string"
    if isinstance(t, BoundedString):
        return f"string<={t.maximum_size}"
    if isinstance(t, NamespacedType):
        return f"{t.namespaces[0]}/{t.name}"
    raise SystemExit(f"dds_idl.py: no .msg notation for {t!r}")


def description(structure, constants):
    """A structure's fields and constants as rosidl read them, in .msg notation."""
    return {
        "fields": [f"{msg_type(m.type)} {m.name}" for m in structure.members],
        "constants": [f"{msg_type(c.type)} {c.name}={c.value}" for c in constants],
    }


def dds_name(namespaced):
    """`pkg::msg::dds_::Type_` of a ROS type `pkg/msg/Type`."""
    return "::".join([*namespaced.namespaces, "dds_", namespaced.name + "_"])


def dds_type(t):
    """The DDS IDL type of a (non-array) ROS IDL type."""
    if isinstance(t, BasicType):
        return BASIC[t.typename]
    if isinstance(t, UnboundedString):
        return "string"
    if isinstance(t, BoundedString):
        return f"string<{t.maximum_size}>"
    if isinstance(t, NamespacedType):
        return dds_name(t)
    if isinstance(t, UnboundedSequence):
        return f"sequence<{dds_type(t.value_type)}>"
    if isinstance(t, BoundedSequence):
        return f"sequence<{dds_type(t.value_type)}, {t.maximum_size}>"
    raise SystemExit(f"dds_idl.py: no DDS mapping for {t!r}")


def member(m):
    """One member's declaration."""
    if isinstance(m.type, Array):
        return f"{dds_type(m.type.value_type)} {m.name}[{m.type.size}];"
    return f"{dds_type(m.type)} {m.name};"


def used_types(structure):
    """The namespaced types a structure's members name."""
    for m in structure.members:
        t = m.type
        while hasattr(t, "value_type"):
            t = t.value_type
        if isinstance(t, NamespacedType):
            yield tuple(t.namespaced_name())


def main():
    args = sys.argv[1:]

    def option(name):
        if name not in args:
            return None
        i = args.index(name)
        value = args[i + 1]
        del args[i : i + 2]
        return value

    json_file = option("--json")
    json_file = json_file and pathlib.Path(json_file)
    distro = option("--distro")
    msgs, work = pathlib.Path(args[0]).resolve(), pathlib.Path(args[1]).resolve()
    structures, described = {}, {}
    for name, directory in packages(msgs, distro):
        for structure, constants in parsed(name, directory, work):
            structures[tuple(structure.namespaced_type.namespaced_name())] = structure
            if name == "ttball_msgs":
                # A service's halves as ROS names their types: PlanReturn_Request.
                key = f"{name}/{structure.namespaced_type.name}"
                described[key] = description(structure, constants)
    if json_file:
        json_file.write_text(json.dumps(described, indent=1, sort_keys=True) + "\n")
    out = [f"// Generated by tests/interop/rosidl/dds_idl.py from {msgs} with rosidl; do not edit.\n"]
    written = set()

    def write(key):
        # Each type after the types it names: IDL declares before use.
        if key in written:
            return
        written.add(key)
        structure = structures[key]
        for used in used_types(structure):
            write(used)
        *namespaces, _ = key
        body = "".join(f"        {member(m)}\n" for m in structure.members)
        opening = " ".join(f"module {n} {{" for n in [*namespaces, "dds_"])
        closing = " ".join("};" for _ in [*namespaces, "dds_"])
        name = structure.namespaced_type.name
        out.append(f"{opening}\n    struct {name}_ {{\n{body}    }};\n{closing}\n")

    for key in structures:
        write(key)
    sys.stdout.write("".join(out))
    ours = sum(1 for key in structures if key[0] == "ttball_msgs")
    print(f"rosidl parsed {ours} structures of {msgs} and {len(structures) - ours} standard ones",
          file=sys.stderr)


if __name__ == "__main__":
    main()
