"""Launches the ttball node (launch_ros), e.g.

    ros2 launch ttball ttball.launch.py namespace:=robot1 params_file:=/path/to/my.yaml \
        detections:=/vision/ball service_mapping:=cyclone

Arguments (`ros2 launch ttball ttball.launch.py --show-args`):
  namespace        the node's namespace; its topics (ball/state, ...) and services follow it
  params_file      a ROS 2 parameters file (`ttball config print` writes every parameter);
                   default: the package's config/ttball.yaml, i.e. the defaults
  detections       the topic the detections arrive on (a remap of ball/detections)
  service_mapping  enhanced (rmw_fastrtps, rmw_connextdds; the default) or cyclone
                   (rmw_cyclonedds), as RMW_IMPLEMENTATION of the callers
  use_sim_time     follow /clock
  learned_file     keep what the node learns (the ball's and table's physics, the noise) in this
                   file, rewritten as it learns; give it as params_file next time to start from
                   it (empty, the default: not kept)
"""

import os

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node


def default_params_file():
    """config/ttball.yaml of the installed package, else of this source tree."""
    try:
        from ament_index_python.packages import get_package_share_directory
        return os.path.join(get_package_share_directory("ttball"), "config", "ttball.yaml")
    except Exception:  # not installed: the repository's copy
        return os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "config", "ttball.yaml")


def generate_launch_description():
    arguments = [
        DeclareLaunchArgument("namespace", default_value="", description="the node's namespace"),
        DeclareLaunchArgument("params_file", default_value=default_params_file(),
                              description="a ROS 2 parameters file"),
        DeclareLaunchArgument("detections", default_value="ball/detections",
                              description="the detections topic"),
        DeclareLaunchArgument("service_mapping", default_value="enhanced",
                              description="enhanced (rmw_fastrtps) or cyclone (rmw_cyclonedds)"),
        DeclareLaunchArgument("use_sim_time", default_value="false", description="follow /clock"),
        DeclareLaunchArgument("learned_file", default_value="",
                              description="keep what the node learns in this file (empty: not kept)"),
    ]
    node = Node(
        package="ttball",
        executable="ttball",
        name="ttball",
        namespace=LaunchConfiguration("namespace"),
        # launch_ros runs: ttball node --learned FILE --ros-args -r __node:=ttball -r __ns:=...
        # --params-file ...
        arguments=["node", "--learned", LaunchConfiguration("learned_file")],
        parameters=[
            LaunchConfiguration("params_file"),
            {
                "node.service_mapping": LaunchConfiguration("service_mapping"),
                "use_sim_time": LaunchConfiguration("use_sim_time"),
            },
        ],
        remappings=[("ball/detections", LaunchConfiguration("detections"))],
        output="screen",
    )
    return LaunchDescription(arguments + [node])
