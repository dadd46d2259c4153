"""The QoS of every topic of the graph, in one table (no rclpy at import; :func:`qos_for` builds
the rclpy QoSProfile).

Rules (FIELD_NOTES: a reliable publisher and a best-effort subscriber never match, silently; a
TRANSIENT_LOCAL subscriber never matches a VOLATILE publisher): every topic is RELIABLE; every
topic is VOLATILE except the latched ones (``climb/request``, ``robot_description``), which are
TRANSIENT_LOCAL with depth 1 so that a late joiner (the recorder, RViz) gets the last message.
Publishers and subscribers of one topic take the same profile from here. docs/interfaces.md and
docs/sim_bridge.md list the same table.
"""
from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class TopicQos:
    depth: int  # KEEP_LAST history depth
    reliability: str = "reliable"  # reliable | best_effort
    durability: str = "volatile"  # volatile | transient_local
    description: str = ""


_V, _L = "volatile", "transient_local"

#: topic name (relative names resolve in the node's namespace; /clock is absolute) -> QoS.
#: ``ft/<sensor>`` stands for every F/T topic; ``<stage>/status`` for every status topic.
QOS_TABLE: dict[str, TopicQos] = {
    # simulator / robot side (sim_bridge)
    "joint_states": TopicQos(10, description="actuated joints: position, velocity, effort"),
    "ft/<sensor>": TopicQos(10, description="6-axis F/T per sensor (wrists, ankles)"),
    "imu": TopicQos(10, description="root link IMU"),
    "sim/base_truth": TopicQos(10, description="simulator ground truth of the base (Odometry)"),
    "sim/contacts": TopicQos(10, description="simulator ground truth of the contacts, for the judge"),
    "/clock": TopicQos(1, description="lock-step sim time"),
    "diagnostics": TopicQos(50, description="every node's diagnostics"),
    # controller
    "joint_command": TopicQos(10, description="per-joint mode and value"),
    "gripper_command": TopicQos(10, description="open / close / position a hand"),
    "controller/state": TopicQos(10, description="FSM state every tick (the coordinator's heartbeat)"),
    # planning pipeline
    "plan/request": TopicQos(10, description="plan request JSON (coordinator -> guide_path)"),
    "guide_path": TopicQos(1, description="GuidePath"),
    "contact_plan": TopicQos(1, description="ContactPlan"),
    "whole_body_plan": TopicQos(1, description="WholeBodyPlan (controller input)"),
    "primitive_adaptation/request": TopicQos(10, description="primitive-sequence request (YAML / JSON)"),
    "<stage>/status": TopicQos(10, description="ClimbStatus of a stage (guide_path, contact_search, ...)"),
    # coordinator / visualisation
    "climb/status": TopicQos(10, description="ClimbStatus of the climb"),
    "climb/request": TopicQos(1, durability=_L, description="latched: the accepted request"),
    "climb/markers": TopicQos(1, description="MarkerArray for RViz"),
    "robot_description": TopicQos(1, durability=_L, description="latched: the robot's URDF"),
}


def lookup(topic: str) -> TopicQos:
    """The table entry of ``topic`` (KeyError naming the topic when it has none)."""
    name = topic if topic == "/clock" else topic.lstrip("/")
    if name in QOS_TABLE:
        return QOS_TABLE[name]
    if name.startswith("ft/") and name.count("/") == 1:
        return QOS_TABLE["ft/<sensor>"]
    if name.endswith("/status") and name.count("/") == 1:
        return QOS_TABLE["<stage>/status"]
    # a namespaced topic (replay under a namespace): match on its last components
    parts = name.split("/")
    for k in range(1, len(parts)):
        try:
            return lookup("/".join(parts[k:]))
        except KeyError:
            pass
    raise KeyError(f"topic {topic!r} has no QoS in msgs_py.topics.QOS_TABLE; add it there")


def qos_for(topic: str):
    """The rclpy QoSProfile of ``topic`` (KEEP_LAST history) from :data:`QOS_TABLE`."""
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

    spec = lookup(topic)
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=spec.depth,
                      reliability=ReliabilityPolicy.RELIABLE if spec.reliability == "reliable"
                      else ReliabilityPolicy.BEST_EFFORT,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL if spec.durability == "transient_local"
                      else DurabilityPolicy.VOLATILE)
