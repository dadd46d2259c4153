#!/usr/bin/env python3
"""Benchmark the simulation bridge: physics step, full bridge tick, lock-step ticks per second with a
trivial controller in-process and over ROS (G1 on the default ladder, 200 Hz control).

    .venv/bin/python scripts/bench_sim.py [--ticks 1000] [--ros-ticks 1000] [--no-ros]

Targets (issue 3): >= 2x real time in-process, >= 1x over ROS. The last line of the output is one
JSON object; every key carries its unit.
"""
from __future__ import annotations

import argparse
import json
import os
import pathlib
import subprocess
import sys
import tempfile
import time

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parents[1]


def stats(samples_s: list[float]) -> tuple[float, float]:
    arr = np.asarray(samples_s) * 1e3
    return float(np.median(arr)), float(np.percentile(arr, 99))


def bench_in_process(ticks: int) -> dict:
    from sim_bridge.backend import ResetRequest
    from sim_bridge.bridge import SimBridge
    from sim_bridge.params import load_bridge_params
    from sim_bridge.pybullet_backend import PyBulletBackend
    from sim_bridge.simple_control import GravityCompensatedPd

    params = load_bridge_params(execution="lockstep")
    backend = PyBulletBackend(params)
    bridge = SimBridge(backend, params)
    state = bridge.reset(ResetRequest(robot="g1", ladder="default", initial_posture="standing"))
    controller = GravityCompensatedPd(backend.robot, backend.robot.q_reference())
    for _ in range(50):  # settle
        bridge.offer_actuator_command(controller(state))
        state = bridge.step_lockstep()
    # full bridge tick (validation, actuators every physics step, sensors, diagnostics), the physics
    # steps inside it, and the whole loop with the controller
    substeps = params.physics.substeps
    tick_times, physics, loop_start = [], [], time.perf_counter()
    for _ in range(ticks):
        cmd = controller(state)
        t0 = time.perf_counter()
        bridge.offer_actuator_command(cmd)
        state = bridge.step_lockstep()
        tick_times.append(time.perf_counter() - t0)
        physics.append(backend.physics_time_s / substeps)
    loop = time.perf_counter() - loop_start
    backend.close()
    physics_p50, physics_p99 = stats(physics)
    tick_p50, tick_p99 = stats(tick_times)
    rate = ticks / loop
    return {"physics_step_ms_p50": physics_p50, "physics_step_ms_p99": physics_p99,
            "bridge_tick_ms_p50": tick_p50, "bridge_tick_ms_p99": tick_p99,
            "inprocess_ticks_per_s": rate, "inprocess_realtime_factor": rate * params.physics.control_period_s,
            "fell": bool(state.fell)}


def bench_ros(ticks: int) -> dict:
    from climb_core.ros_env import local_dds_env

    env = local_dds_env(domain_id=int(os.environ.get("BENCH_ROS_DOMAIN_ID", 60 + os.getpid() % 30)))
    with tempfile.TemporaryDirectory() as tmp:
        out = pathlib.Path(tmp) / "ros.json"
        bridge = subprocess.Popen([sys.executable, "-m", "sim_bridge.node", "--ros-args", "-p", f"max_ticks:={ticks}",
                                   "-p", "execution:=lockstep"], env=env, cwd=ROOT,
                                  stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        controller = subprocess.Popen([sys.executable, __file__, "--controller", str(out), str(ticks)], env=env,
                                      cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        try:
            controller.wait(timeout=600)
            bridge.wait(timeout=60)
        finally:
            for proc in (controller, bridge):
                if proc.poll() is None:
                    proc.kill()
                    proc.wait()
        if controller.returncode != 0 or not out.is_file():
            raise RuntimeError(f"ROS benchmark failed: {controller.stderr.read().decode()[-2000:]}")
        return json.loads(out.read_text())


def controller_main(out_path: str, ticks: int) -> int:
    """A trivial lock-step controller: answers each state with the standing PD (in joint space)."""
    from climb_core.ros_env import apply_local_dds_env

    apply_local_dds_env()
    import array

    import rclpy
    from climb_msgs.msg import JointCommand
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import JointState

    from climb_core.robot import load_robot
    from sim_bridge.simple_control import GravityCompensatedPd

    robot = load_robot("g1")
    pd = GravityCompensatedPd(robot, robot.q_reference())
    q_base = robot.q_reference()[:7]
    reliable = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
    arrivals: list[float] = []
    answer: list[float] = []
    rclpy.init()
    node = Node("bench_sim_controller")
    pub = node.create_publisher(JointCommand, "joint_command", reliable)

    def on_state(msg: JointState) -> None:
        t0 = time.perf_counter()
        arrivals.append(time.monotonic())
        q, v = np.asarray(msg.position), np.asarray(msg.velocity)
        tau = pd.gravity_torques(np.concatenate([q_base, q])) + pd.kp * (pd.q_des - q) - pd.kd * v
        cmd = JointCommand()
        cmd.header.stamp = msg.header.stamp
        cmd.names = list(msg.name)
        cmd.modes = array.array("B", [JointCommand.TORQUE] * len(msg.name))
        cmd.values = np.clip(tau, -pd.effort, pd.effort).tolist()
        pub.publish(cmd)
        answer.append(time.perf_counter() - t0)

    node.create_subscription(JointState, "joint_states", on_state, reliable)
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    deadline = time.monotonic() + 600
    try:
        while len(arrivals) < ticks + 1 and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.1)
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    if len(arrivals) < ticks + 1:
        return 1
    gaps = np.diff(arrivals)
    rate = ticks / (arrivals[-1] - arrivals[0])
    p50, p99 = stats(list(gaps))
    c50, c99 = stats(answer)
    pathlib.Path(out_path).write_text(json.dumps({
        "ros_ticks_per_s": rate, "ros_realtime_factor": rate * 0.005, "ros_tick_ms_p50": p50, "ros_tick_ms_p99": p99,
        "ros_controller_ms_p50": c50, "ros_controller_ms_p99": c99}))
    return 0


def main() -> int:
    if len(sys.argv) > 1 and sys.argv[1] == "--controller":
        return controller_main(sys.argv[2], int(sys.argv[3]))
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--ticks", type=int, default=1000, help="in-process control ticks")
    parser.add_argument("--ros-ticks", type=int, default=1000, help="ticks over ROS")
    parser.add_argument("--no-ros", action="store_true", help="skip the two-process measurement")
    args = parser.parse_args()
    result = {"robot": "g1", "ladder": "default", "control_period_s": 0.005, "physics_dt_s": 0.001,
              "cpu_count": os.cpu_count(), "load_average_1min": os.getloadavg()[0]}
    result.update(bench_in_process(args.ticks))
    print(f"physics step      p50 {result['physics_step_ms_p50']:.3f} ms  p99 {result['physics_step_ms_p99']:.3f} ms")
    print(f"bridge tick       p50 {result['bridge_tick_ms_p50']:.3f} ms  p99 {result['bridge_tick_ms_p99']:.3f} ms")
    print(f"in-process        {result['inprocess_ticks_per_s']:.0f} ticks/s = "
          f"{result['inprocess_realtime_factor']:.2f}x real time (target >= 2x)")
    if not args.no_ros:
        result.update(bench_ros(args.ros_ticks))
        print(f"over ROS          {result['ros_ticks_per_s']:.0f} ticks/s = {result['ros_realtime_factor']:.2f}x "
              f"real time (target >= 1x); tick p50 {result['ros_tick_ms_p50']:.2f} ms p99 "
              f"{result['ros_tick_ms_p99']:.2f} ms")
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
