"""The bridge's ROS interface as data (no rclpy here): names, types and the one QoS of each topic.

A reliable publisher matches both reliable and best-effort subscribers; a best-effort publisher
never matches a reliable subscriber, so every topic the bridge publishes is RELIABLE, and the
subscriptions are RELIABLE too (a controller must publish commands RELIABLE). Durability is
VOLATILE everywhere. The QoS comes from the graph's one table, msgs_py.topics (the node builds
its QoSProfiles with msgs_py.topics.qos_for; a test checks this table agrees);
docs/sim_bridge.md has the same table.
"""
from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class TopicSpec:
    name: str  # relative names resolve in the node's namespace; /clock is absolute
    type: str  # package/msg/Type
    direction: str  # pub | sub
    reliability: str  # reliable | best_effort
    depth: int  # KEEP_LAST history depth
    description: str


FT_PREFIX = "ft/"

TOPICS: dict[str, TopicSpec] = {spec.name: spec for spec in (
    TopicSpec("joint_states", "sensor_msgs/msg/JointState", "pub", "reliable", 10,
              "actuated joints (robot model order): position [rad], velocity [rad/s], effort = applied torque [N m]"),
    TopicSpec("ft/<sensor>", "geometry_msgs/msg/WrenchStamped", "pub", "reliable", 10,
              "6-axis F/T in the sensor link frame (frame_id), distal side on proximal side [N, N m]"),
    TopicSpec("imu", "sensor_msgs/msg/Imu", "pub", "reliable", 10,
              "root link frame: orientation, angular velocity [rad/s], specific force [m/s^2]"),
    TopicSpec("sim/base_truth", "nav_msgs/msg/Odometry", "pub", "reliable", 10,
              "root link pose in world; twist in the root link frame (= Pinocchio free-flyer v)"),
    TopicSpec("/clock", "rosgraph_msgs/msg/Clock", "pub", "reliable", 1,
              "lock-step only: sim time, published right before the state stamped with it"),
    TopicSpec("sim/contacts", "climb_msgs/msg/SimContacts", "pub", "reliable", 10,
              "sim only (the judge): per limb normal / tangential force [N], surface, rung, grasped; fell"),
    TopicSpec("diagnostics", "diagnostic_msgs/msg/DiagnosticArray", "pub", "reliable", 50,
              "over-current trips, watchdog, controller lost, rejected commands, falls, grasps, step time"),
    TopicSpec("joint_command", "climb_msgs/msg/JointCommand", "sub", "reliable", 10,
              "per-joint mode and value; lock-step: header.stamp = the state stamp it answers"),
    TopicSpec("gripper_command", "climb_msgs/msg/GripperCommand", "sub", "reliable", 10,
              "open / close / position a hand; takes effect at header.stamp (0 = next tick)"),
)}

SERVICES = {
    "sim/reset": ("climb_msgs/srv/SimReset", "robot, ladder (name or YAML text), initial posture or q, seed"),
    "sim/perturb": ("climb_msgs/srv/SimPerturb", "drop a ball, offset a rung, shift the rails at at_time"),
}
