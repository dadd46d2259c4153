"""`ros2 launch climb_coordinator climb.launch.py [layout:=processes|composed]`: the climb graph.

The node list, parameter files and parameters come from config/graph.yaml (the same list
scripts/climb.py starts: climb_coordinator.graph.launch_entries). The project root is found by
climb_core.ros_env.project_root() (set CLIMB_ROOT on an install whose packages are not in the
source tree). Then call the `climb` action or service of climb_coordinator.
"""
from launch import LaunchDescription
from launch_ros.actions import Node

from climb_coordinator.graph import launch_entries


def generate_launch_description(layout: str = "processes"):
    nodes = []
    for e in launch_entries(layout):
        extra = {"prefix": f"nice -n {e['nice']}"} if e["nice"] else {}
        nodes.append(Node(package=e["package"], executable=e["executable"], name=e["name"], output="screen",
                          parameters=list(e["params_files"]) + ([e["params"]] if e["params"] else []), **extra))
    return LaunchDescription(nodes)
