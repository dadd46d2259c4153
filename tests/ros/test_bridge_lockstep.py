"""Two processes in lock-step: the `sim_bridge` node and a tiny controller, 1000 ticks.

The controller (this file run as a script) answers every joint_states message with a joint
command stamped like it (gravity-compensated PD toward the standing posture, plus a swinging arm),
checks that its sim-time clock (use_sim_time, fed by the bridge's /clock) equals the state stamp
when the state arrives, and saves what it saw. Two runs with the same seed (and sensor noise on)
must see bit-identical joint states.
"""
from __future__ import annotations

import array
import pathlib
import subprocess
import sys
import time

import numpy as np
import pytest

pytestmark = pytest.mark.ros

ROOT = pathlib.Path(__file__).resolve().parents[2]
TICKS = 1000
PERIOD_NS = 5_000_000


def bridge_cmd(seed: int) -> list[str]:
    return [sys.executable, "-m", "sim_bridge.node", "--ros-args",
            "--params-file", str(ROOT / "config" / "nodes" / "sim_bridge.yaml"),
            "-p", f"max_ticks:={TICKS}", "-p", f"seed:={seed}", "-p", "execution:=lockstep",
            "-p", "sensors.joint_position_noise_std:=0.0002", "-p", "sensors.ft_force_noise_std:=0.5"]


def run_pair(tmp_path: pathlib.Path, seed: int, tag: str) -> dict:
    from climb_core.ros_env import local_dds_env

    env = local_dds_env()
    out = tmp_path / f"controller_{tag}.npz"
    bridge = subprocess.Popen(bridge_cmd(seed), env=env, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    controller = subprocess.Popen([sys.executable, __file__, str(out), str(TICKS)], env=env, cwd=ROOT,
                                  stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    try:
        c_out, _ = controller.communicate(timeout=120)
        b_out, _ = bridge.communicate(timeout=30)  # max_ticks: it stops by itself
    finally:
        for proc in (controller, bridge):
            if proc.poll() is None:
                proc.kill()
                proc.wait()
    assert controller.returncode == 0, c_out.decode()[-3000:]
    assert bridge.returncode == 0, b_out.decode()[-3000:]
    return dict(np.load(out))


def test_two_processes_in_lockstep_are_exact_and_deterministic(tmp_path):
    first = run_pair(tmp_path, seed=7, tag="a")
    stamps = first["stamps"]
    assert len(stamps) == TICKS + 1  # states at t = 0 .. 1000 ticks, none missed, none repeated
    assert np.array_equal(stamps, np.arange(TICKS + 1, dtype=np.int64) * PERIOD_NS)
    assert np.array_equal(first["clock_at_state"], stamps)  # /clock = t when the state stamped t arrives
    assert first["commands_sent"] == TICKS + 1
    assert not first["lost"], "the bridge reported the controller as lost"
    assert first["rejected"] == 0
    q = first["q"]
    assert np.ptp(q[:, first["swing_joint"]]) > 0.2  # [rad] the arm really moved
    assert first["min_base_height"] > 0.6  # [m] the robot stayed up
    second = run_pair(tmp_path, seed=7, tag="b")
    assert np.array_equal(second["stamps"], stamps)
    assert np.array_equal(second["q"], q)  # bit-identical, sensor noise included
    assert np.array_equal(second["v"], first["v"])


# ------------------------------------------------------------------------------------------------
# the controller process


def controller_main(out_path: str, ticks: int) -> int:
    from climb_core.ros_env import apply_local_dds_env

    apply_local_dds_env()
    import rclpy
    from climb_msgs.msg import JointCommand
    from diagnostic_msgs.msg import DiagnosticArray
    from nav_msgs.msg import Odometry
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from rclpy.parameter import Parameter
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import JointState

    from climb_core.robot import load_robot
    from sim_bridge.simple_control import GravityCompensatedPd

    robot = load_robot("g1")
    pd = GravityCompensatedPd(robot, robot.q_reference())
    swing = robot.joint_names.index("left_shoulder_pitch_joint")
    reliable = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
    rec: dict[str, list] = {"stamps": [], "clock": [], "q": [], "v": [], "z": []}
    flags = {"lost": False, "rejected": 0, "sent": 0}
    base = {"q": None}
    last = {"cmd": None}

    rclpy.init()
    node = Node("lockstep_test_controller", parameter_overrides=[Parameter("use_sim_time", value=True)])
    pub = node.create_publisher(JointCommand, "joint_command", reliable)

    def on_truth(msg: Odometry) -> None:
        p, o = msg.pose.pose.position, msg.pose.pose.orientation
        t = msg.twist.twist
        base["q"] = np.array([p.x, p.y, p.z, o.x, o.y, o.z, o.w])
        base["v"] = np.array([t.linear.x, t.linear.y, t.linear.z, t.angular.x, t.angular.y, t.angular.z])

    def on_state(msg: JointState) -> None:
        stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        if rec["stamps"] and stamp == rec["stamps"][-1]:  # a state published again (lockstep.resend_s)
            pub.publish(last["cmd"])  # while the bridge awaits the first command: the same answer
            return
        rec["stamps"].append(stamp)
        rec["clock"].append(node.get_clock().now().nanoseconds)
        q = np.array(msg.position)
        v = np.array(msg.velocity)
        rec["q"].append(q)
        rec["v"].append(v)
        q_base = base["q"] if base["q"] is not None else robot.q_reference()[:7]
        rec["z"].append(q_base[2])
        # a state-only controller (the base truth of the same tick may arrive after the joints)
        q_full = np.concatenate([robot.q_reference()[:7], q])
        tau = pd.gravity_torques(q_full) + pd.kp * (pd.q_des - q) - pd.kd * v
        tau[swing] += pd.kp[swing] * 0.4 * np.sin(2.0 * np.pi * stamp * 1e-9)  # [rad] swing the left arm
        tau = np.clip(tau, -pd.effort, pd.effort)
        cmd = JointCommand()
        cmd.header.stamp = msg.header.stamp
        cmd.names = list(msg.name)
        cmd.modes = array.array("B", [JointCommand.TORQUE] * len(msg.name))
        cmd.values = tau.tolist()
        pub.publish(cmd)
        last["cmd"] = cmd
        flags["sent"] += 1

    def on_diag(msg: DiagnosticArray) -> None:
        for status in msg.status:
            if status.name == "sim_bridge/controller" and "lost" in status.message:
                flags["lost"] = True
            if status.name == "sim_bridge/command":
                flags["rejected"] += 1
                print("command diagnostic:", status.message, flush=True)

    node.create_subscription(JointState, "joint_states", on_state, reliable)
    node.create_subscription(Odometry, "sim/base_truth", on_truth, reliable)
    node.create_subscription(DiagnosticArray, "diagnostics", on_diag, reliable)
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    deadline = time.monotonic() + 100.0
    try:
        while len(rec["stamps"]) < ticks + 1 and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.1)
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    np.savez(out_path, stamps=np.array(rec["stamps"], dtype=np.int64), clock_at_state=np.array(rec["clock"], dtype=np.int64),
             q=np.array(rec["q"]), v=np.array(rec["v"]), commands_sent=flags["sent"], lost=flags["lost"],
             rejected=flags["rejected"], swing_joint=swing, min_base_height=float(np.min(rec["z"])))
    return 0 if len(rec["stamps"]) == ticks + 1 else 1


if __name__ == "__main__":
    sys.exit(controller_main(sys.argv[1], int(sys.argv[2])))
