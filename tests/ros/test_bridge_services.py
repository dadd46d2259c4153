"""The `sim_bridge` node in real-time mode: watchdog over ROS, gripper commands and the sim/perturb
and sim/reset services (a bridge process, rclpy in this test process)."""
from __future__ import annotations

import array
import pathlib
import subprocess
import sys
import time

import pytest

pytestmark = pytest.mark.ros

ROOT = pathlib.Path(__file__).resolve().parents[2]


def test_realtime_bridge_services_watchdog_and_gripper():
    from climb_core.ros_env import apply_local_dds_env, local_dds_env

    apply_local_dds_env()
    import rclpy
    from climb_msgs.msg import GripperCommand, JointCommand
    from climb_msgs.srv import SimPerturb, SimReset
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.node import Node
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import JointState

    bridge = subprocess.Popen([sys.executable, "-m", "sim_bridge.node", "--ros-args", "-p", "execution:=realtime",
                               "-p", "max_ticks:=6000"], env=local_dds_env(), cwd=ROOT,
                              stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    rclpy.init()
    node = Node("bridge_services_test")
    reliable = QoSProfile(depth=50, reliability=ReliabilityPolicy.RELIABLE)
    diags: list = []
    states: list = []
    node.create_subscription(DiagnosticArray, "diagnostics", lambda m: diags.extend(m.status), reliable)
    node.create_subscription(JointState, "joint_states", lambda m: states.append(m), reliable)
    cmd_pub = node.create_publisher(JointCommand, "joint_command", reliable)
    grip_pub = node.create_publisher(GripperCommand, "gripper_command", reliable)
    perturb = node.create_client(SimPerturb, "sim/perturb")
    reset = node.create_client(SimReset, "sim/reset")

    def spin_until(predicate, timeout: float) -> bool:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            rclpy.spin_once(node, timeout_sec=0.05)
            if predicate():
                return True
        return False

    def call(client, request):
        future = client.call_async(request)
        assert spin_until(future.done, 30.0), "service call timed out"
        return future.result()

    def named(prefix: str) -> list:
        return [d for d in diags if d.name.startswith(prefix)]

    try:
        assert perturb.wait_for_service(timeout_sec=60.0) and reset.wait_for_service(timeout_sec=10.0)
        assert spin_until(lambda: len(states) > 20, 30.0)  # real time: states flow without any command
        # no commands at all: the watchdog damps and says so
        assert spin_until(lambda: named("sim_bridge/watchdog"), 10.0)
        assert named("sim_bridge/watchdog")[0].level == bytes([2])
        # commands resume -> reported
        names = list(states[-1].name)
        cmd = JointCommand(names=names, modes=array.array("B", [JointCommand.DAMPING] * len(names)),
                           values=array.array("d", [0.0] * len(names)))

        def resumed() -> bool:  # keep commanding at ~100 Hz until the bridge reports the resume
            cmd_pub.publish(cmd)
            return any(d.message == "commands resumed" for d in diags)

        assert spin_until(resumed, 15.0)
        # a bad command is rejected with a diagnostic naming the problem
        cmd_pub.publish(JointCommand(names=["no_such_joint"], modes=array.array("B", [0]),
                                     values=array.array("d", [1.0])))
        assert spin_until(lambda: any("unknown joint 'no_such_joint'" in d.message for d in diags), 5.0)
        # gripper: the hands are far from any rung while standing -> closes without latching
        grip_pub.publish(GripperCommand(hand="left_hand", command=GripperCommand.CLOSE))
        assert spin_until(lambda: any("close without latching" in d.message for d in named("sim_bridge/grasp")), 5.0)
        # perturbation service: a drop happens (diagnostic), a bad request is refused with the field
        ok = call(perturb, SimPerturb.Request(kind=SimPerturb.Request.DROP, mass=2.0, radius=0.08, speed=3.0,
                                              target_link="torso"))
        assert ok.success, ok.error
        assert spin_until(lambda: any("ball of 2.0 kg" in d.message for d in diags), 5.0)
        bad = call(perturb, SimPerturb.Request(kind=7))
        assert not bad.success and "perturbation.kind" in bad.error
        # reset service: new ladder (YAML name), time restarts
        before = len(states)
        result = call(reset, SimReset.Request(ladder="vertical", initial_posture="standing", seed=3))
        assert result.success, result.error
        assert spin_until(lambda: len(states) > before + 5, 10.0)
        stamps = [s.header.stamp.sec + 1e-9 * s.header.stamp.nanosec for s in states[before:]]
        assert min(stamps) < 0.1  # [s] sim time restarted at 0
        refused = call(reset, SimReset.Request(ladder="no_such_ladder"))
        assert not refused.success and "no_such_ladder" in refused.error
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
        bridge.terminate()
        try:
            bridge.communicate(timeout=20)
        except subprocess.TimeoutExpired:
            bridge.kill()
            bridge.communicate()
