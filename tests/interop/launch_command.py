"""Prints, as JSON, the command line launch_ros would run for launch/ttball.launch.py, without a
ROS 2 installation: `launch` and `launch_ros` are replaced by stand-ins that record the
launch description, and the command is built as launch_ros's Node action builds it
(launch_ros/actions/node.py: executable, arguments, then --ros-args with `-r __node:=`,
`-r __ns:=` (made absolute), a --params-file per parameters entry (a dict written to a temporary
file under the wildcard `/**`, values typed as YAML), and a `-r from:=to` per remapping).

    python launch_command.py launch/ttball.launch.py namespace:=robot1 detections:=/vision/ball

What this checks is the file's use of the launch API and the arguments ttball receives; that
launch_ros itself runs it could not be checked here (launch_ros is not on PyPI).
"""

import json
import os
import sys
import tempfile
import types

import yaml


class LaunchConfiguration:
    def __init__(self, name):
        self.name = name


class DeclareLaunchArgument:
    def __init__(self, name, default_value=None, description=""):
        self.name, self.default_value, self.description = name, default_value, description


class LaunchDescription:
    def __init__(self, entities):
        self.entities = entities


class Node:
    def __init__(self, **kwargs):
        self.kwargs = kwargs


def install_stand_ins():
    launch = types.ModuleType("launch")
    launch.LaunchDescription = LaunchDescription
    actions = types.ModuleType("launch.actions")
    actions.DeclareLaunchArgument = DeclareLaunchArgument
    substitutions = types.ModuleType("launch.substitutions")
    substitutions.LaunchConfiguration = LaunchConfiguration
    launch_ros = types.ModuleType("launch_ros")
    ros_actions = types.ModuleType("launch_ros.actions")
    ros_actions.Node = Node
    sys.modules.update({"launch": launch, "launch.actions": actions, "launch.substitutions": substitutions,
                        "launch_ros": launch_ros, "launch_ros.actions": ros_actions})


def main(path, overrides):
    install_stand_ins()
    scope = {"__file__": os.path.abspath(path)}
    with open(path) as f:
        exec(compile(f.read(), path, "exec"), scope)
    description = scope["generate_launch_description"]()
    values = {e.name: e.default_value for e in description.entities if isinstance(e, DeclareLaunchArgument)}
    for item in overrides:
        name, value = item.split(":=", 1)
        if name not in values:
            sys.exit(f"launch_command: no launch argument {name} (have {sorted(values)})")
        values[name] = value

    def resolve(value):
        return values[value.name] if isinstance(value, LaunchConfiguration) else value

    (node,) = [e for e in description.entities if isinstance(e, Node)]
    k = node.kwargs
    cmd = [k["executable"], *[resolve(a) for a in k.get("arguments", [])], "--ros-args"]
    if k.get("name"):
        cmd += ["-r", f"__node:={resolve(k['name'])}"]
    namespace = resolve(k.get("namespace") or "")
    if namespace:
        cmd += ["-r", f"__ns:={namespace if namespace.startswith('/') else '/' + namespace}"]
    for entry in k.get("parameters", []):
        if isinstance(entry, dict):
            params = {resolve(n): yaml.safe_load(str(resolve(v))) for n, v in entry.items()}
            with tempfile.NamedTemporaryFile("w", suffix=".yaml", delete=False) as f:
                yaml.safe_dump({"/**": {"ros__parameters": params}}, f)
            cmd += ["--params-file", f.name]
        else:
            cmd += ["--params-file", resolve(entry)]
    for source, target in k.get("remappings", []):
        cmd += ["-r", f"{resolve(source)}:={resolve(target)}"]
    print(json.dumps({"package": k["package"], "cmd": cmd}))


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2:])
