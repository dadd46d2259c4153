#!/usr/bin/env python3
"""Benchmark the simulation bridge: physics step, full bridge tick, lock-step ticks per second with a
trivial controller in-process and over ROS (G1 standing on the default ladder scene, 200 Hz control).

    .venv/bin/python scripts/bench_sim.py [--ticks 1000] [--ros-ticks 1000] [--repeat 3] [--no-ros] [--no-pin]

Targets (issue 3): >= 2x real time in-process, >= 1x over ROS (two processes). The machine may be
shared: every measurement is repeated (``--repeat``, interleaved in-process / ROS) and the medians
over the repeats are reported, with the 1-minute load average around each run. The trivial
controller (StandingPd, ~0.1 ms per tick) is the same in both modes. Over ROS the bridge is pinned
to CPU 0 (its ``cpu_affinity`` parameter) and the controller process to CPU 1, unless --no-pin.

The last line of the output is one JSON object; every key carries its unit: physics_step_p50_ms /
_p99_ms (stepSimulation, per tick / substeps), bridge_tick_p50_ms / _p99_ms (offer the command +
step_lockstep: validation, actuators, 5 physics steps, sensors, diagnostics),
lockstep_inprocess_rtf (ticks/s x control period, controller included), lockstep_ros_rtf (bridge
node and controller in two processes), ros_tick_p50_ms / _p99_ms (period between two states at the
controller), plus the per-repeat values. CPU per tick (inprocess_cpu_per_tick_ms: the main thread;
ros_bridge_cpu_per_tick_ms: the whole node process, DDS threads included;
ros_controller_cpu_per_tick_ms) and the rate that CPU alone would allow (*_cpu_bound_rtf; the
lock-step exchange is sequential, so over ROS the two processes' CPU add up) separate the work
from waiting for a core; on a busy machine the CPU time inflates too (shared caches).
"""
from __future__ import annotations

import argparse
import json
import os
import pathlib
import statistics
import subprocess
import sys
import tempfile
import time

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parents[1]
CONTROL_PERIOD_S = 0.005  # [s] the bridge's default (config/nodes/sim_bridge.yaml)


def stats(samples_s: list[float]) -> tuple[float, float]:
    """[ms] median and 99th percentile of samples in seconds."""
    arr = np.asarray(samples_s) * 1e3
    return float(np.median(arr)), float(np.percentile(arr, 99))


class StandingPd:
    """The trivial controller: GravityCompensatedPd toward the reference posture (gravity torques
    with the feet carrying the robot, at the measured configuration). Over ROS it answers each
    joint_states at once with the latest sim/base_truth pose (one tick old: the bridge publishes
    the base truth after the joint states). ~0.1 ms per tick."""

    def __init__(self, robot):
        from sim_bridge.simple_control import GravityCompensatedPd

        self.pd = GravityCompensatedPd(robot, robot.q_reference())
        self.q_full = robot.q_reference().copy()  # [base position, quaternion xyzw, joints]

    def torques(self, q: np.ndarray, v: np.ndarray, base_pose: np.ndarray | None = None) -> np.ndarray:
        pd = self.pd
        if base_pose is not None:
            self.q_full[:7] = base_pose
        self.q_full[7:] = q
        tau = pd.gravity_torques(self.q_full) + pd.kp * (pd.q_des - q) - pd.kd * v
        return np.clip(tau, -pd.effort, pd.effort)


def bench_in_process(ticks: int) -> dict:
    from sim_bridge.backend import ResetRequest
    from sim_bridge.bridge import SimBridge
    from sim_bridge.commands import TORQUE, ActuatorCommand
    from sim_bridge.params import load_bridge_params
    from sim_bridge.pybullet_backend import PyBulletBackend

    params = load_bridge_params(execution="lockstep")
    backend = PyBulletBackend(params)
    bridge = SimBridge(backend, params)
    try:
        state = bridge.reset(ResetRequest(robot="g1", ladder="default", initial_posture="standing"))
        controller = StandingPd(backend.robot)
        modes = np.full(len(state.joint_names), TORQUE, dtype=np.uint8)

        def command(s):
            return ActuatorCommand(modes, controller.torques(s.q, s.v, s.base.q[:7]), s.stamp_ns)

        for _ in range(50):  # settle
            bridge.offer_actuator_command(command(state))
            state = bridge.step_lockstep()
        substeps = params.physics.substeps
        tick_times, physics = [], []
        loop_start, cpu_start = time.perf_counter(), time.thread_time()
        for _ in range(ticks):
            cmd = command(state)
            t0 = time.perf_counter()
            bridge.offer_actuator_command(cmd)
            state = bridge.step_lockstep()
            tick_times.append(time.perf_counter() - t0)
            physics.append(backend.physics_time_s / substeps)
        loop, cpu = time.perf_counter() - loop_start, time.thread_time() - cpu_start
        height = float(state.base.T_world_base[2, 3])
    finally:
        backend.close()
    physics_p50, physics_p99 = stats(physics)
    tick_p50, tick_p99 = stats(tick_times)
    rate = ticks / loop
    return {"physics_step_p50_ms": physics_p50, "physics_step_p99_ms": physics_p99,
            "bridge_tick_p50_ms": tick_p50, "bridge_tick_p99_ms": tick_p99,
            "lockstep_inprocess_ticks_per_s": rate,
            "lockstep_inprocess_rtf": rate * params.physics.control_period_s,
            "inprocess_cpu_per_tick_ms": cpu / ticks * 1e3,
            "lockstep_inprocess_cpu_bound_rtf": params.physics.control_period_s * ticks / cpu,
            "fell": bool(state.fell), "base_height_end_m": height}


def bench_ros(ticks: int, pin: bool = True) -> dict:
    from climb_core.ros_env import local_dds_env

    env = local_dds_env(domain_id=int(os.environ.get("BENCH_ROS_DOMAIN_ID", 60 + os.getpid() % 30)))
    with tempfile.TemporaryDirectory() as tmp:
        out = pathlib.Path(tmp) / "ros.json"
        pin = pin and len(os.sched_getaffinity(0)) >= 2
        bridge = subprocess.Popen([sys.executable, "-m", "sim_bridge.node", "--ros-args", "-p", f"max_ticks:={ticks}",
                                   "-p", "execution:=lockstep"] + (["-p", "cpu_affinity:=[0]"] if pin else []),
                                  env=env, cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        controller = subprocess.Popen([sys.executable, __file__, "--controller", str(out), str(ticks), str(bridge.pid),
                                       "1" if pin else "-1"],
                                      env=env, cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
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


def process_cpu_s(pid: int) -> float:
    """[s] user + system CPU time of a process so far (Linux /proc)."""
    fields = pathlib.Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def controller_main(out_path: str, ticks: int, bridge_pid: int, pin_cpu: int = -1) -> int:
    """The trivial lock-step controller over ROS: answers each joint_states with StandingPd
    (pinned to ``pin_cpu`` unless negative)."""
    from climb_core.ros_env import apply_local_dds_env

    apply_local_dds_env()
    import array

    import rclpy
    from climb_msgs.msg import JointCommand
    from nav_msgs.msg import Odometry
    from rclpy.node import Node
    from sensor_msgs.msg import JointState

    from climb_core.robot import load_robot
    from climb_core.ros_env import make_executor, pin_to_cpus
    from sim_bridge.node import qos

    robot = load_robot("g1")
    controller = StandingPd(robot)
    base_pose = robot.q_reference()[:7].copy()  # latest sim/base_truth pose
    arrivals: list[float] = []
    answer: list[float] = []
    heights: list[float] = []  # [m] base height seen at each state
    rclpy.init()
    node = Node("bench_sim_controller")
    pub = node.create_publisher(JointCommand, "joint_command", qos("joint_command"))
    cmd = JointCommand()  # built once: names and modes never change
    cmd.modes = array.array("B", [JointCommand.TORQUE] * len(controller.pd.q_des))

    cpu = {}  # CPU time of both processes at the first and the last state

    def on_state(msg: JointState) -> None:
        t0 = time.perf_counter()
        arrivals.append(time.monotonic())
        if len(arrivals) in (1, ticks + 1):
            cpu[len(arrivals)] = (process_cpu_s(bridge_pid), time.process_time())
        if len(cmd.names) != len(msg.name):
            cmd.names = list(msg.name)
        q = np.frombuffer(msg.position, dtype=float)
        v = np.frombuffer(msg.velocity, dtype=float)
        cmd.header.stamp = msg.header.stamp
        cmd.values = array.array("d", controller.torques(q, v, base_pose).tobytes())
        heights.append(base_pose[2])
        pub.publish(cmd)
        answer.append(time.perf_counter() - t0)

    def on_base(msg: Odometry) -> None:
        p, o = msg.pose.pose.position, msg.pose.pose.orientation
        base_pose[:] = (p.x, p.y, p.z, o.x, o.y, o.z, o.w)

    node.create_subscription(JointState, "joint_states", on_state, qos("joint_states"))
    node.create_subscription(Odometry, "sim/base_truth", on_base, qos("sim/base_truth"))
    executor = make_executor()
    executor.add_node(node)
    if pin_cpu >= 0:
        pin_to_cpus([pin_cpu])
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
    bridge_cpu = (cpu[ticks + 1][0] - cpu[1][0]) / ticks * 1e3  # [ms] per tick
    controller_cpu = (cpu[ticks + 1][1] - cpu[1][1]) / ticks * 1e3
    pathlib.Path(out_path).write_text(json.dumps({
        "ros_bridge_cpu_per_tick_ms": bridge_cpu, "ros_controller_cpu_per_tick_ms": controller_cpu,
        # the exchange is sequential (state -> command -> step): both processes' CPU per tick bound the rate
        "lockstep_ros_cpu_bound_rtf": CONTROL_PERIOD_S * 1e3 / (bridge_cpu + controller_cpu),
        "lockstep_ros_ticks_per_s": rate, "lockstep_ros_rtf": rate * CONTROL_PERIOD_S,
        "ros_tick_p50_ms": p50, "ros_tick_p99_ms": p99, "ros_controller_p50_ms": c50, "ros_controller_p99_ms": c99,
        "ros_min_base_height_m": float(min(heights))}))
    return 0


def main() -> int:
    if len(sys.argv) > 1 and sys.argv[1] == "--controller":
        return controller_main(sys.argv[2], int(sys.argv[3]), int(sys.argv[4]), int(sys.argv[5]))
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--ticks", type=int, default=1000, help="in-process control ticks per repeat")
    parser.add_argument("--ros-ticks", type=int, default=1000, help="ticks over ROS per repeat")
    parser.add_argument("--repeat", type=int, default=3, help="repeats (medians are reported)")
    parser.add_argument("--no-ros", action="store_true", help="skip the two-process measurement")
    parser.add_argument("--no-pin", action="store_true", help="over ROS, leave both processes to the scheduler")
    args = parser.parse_args()
    runs: list[dict] = []
    for k in range(max(args.repeat, 1)):
        run = {"load_average_1min_before": os.getloadavg()[0]}
        run.update(bench_in_process(args.ticks))
        if not args.no_ros:
            run.update(bench_ros(args.ros_ticks, pin=not args.no_pin))
        run["load_average_1min_after"] = os.getloadavg()[0]
        runs.append(run)
        line = (f"run {k + 1}: physics step p50 {run['physics_step_p50_ms']:.3f} ms, bridge tick p50 "
                f"{run['bridge_tick_p50_ms']:.3f} ms, in-process {run['lockstep_inprocess_rtf']:.2f}x")
        if not args.no_ros:
            line += f", over ROS {run['lockstep_ros_rtf']:.2f}x"
        print(line + f" (load {run['load_average_1min_before']:.1f} -> {run['load_average_1min_after']:.1f})",
              flush=True)
    keys = [key for key, value in runs[0].items() if isinstance(value, float)]
    result = {"robot": "g1", "ladder": "default", "control_period_s": CONTROL_PERIOD_S, "physics_dt_s": 0.001,
              "ros_pinned": not args.no_ros and not args.no_pin and len(os.sched_getaffinity(0)) >= 2,
              "cpu_count": os.cpu_count(), "repeats": len(runs), "statistic": "median over repeats",
              "fell": any(run["fell"] for run in runs)}
    result.update({key: statistics.median(run[key] for run in runs) for key in keys})
    result["per_repeat"] = {key: [round(run[key], 4) for run in runs] for key in keys}
    print(f"physics step      p50 {result['physics_step_p50_ms']:.3f} ms  p99 {result['physics_step_p99_ms']:.3f} ms")
    print(f"bridge tick       p50 {result['bridge_tick_p50_ms']:.3f} ms  p99 {result['bridge_tick_p99_ms']:.3f} ms")
    print(f"in-process        {result['lockstep_inprocess_ticks_per_s']:.0f} ticks/s = "
          f"{result['lockstep_inprocess_rtf']:.2f}x real time (target >= 2x)")
    if not args.no_ros:
        print(f"over ROS          {result['lockstep_ros_ticks_per_s']:.0f} ticks/s = {result['lockstep_ros_rtf']:.2f}x "
              f"real time (target >= 1x); tick p50 {result['ros_tick_p50_ms']:.2f} ms p99 "
              f"{result['ros_tick_p99_ms']:.2f} ms")
    cpu_line = (f"CPU per tick      in-process {result['inprocess_cpu_per_tick_ms']:.2f} ms "
                f"(bound {result['lockstep_inprocess_cpu_bound_rtf']:.2f}x)")
    if not args.no_ros:
        cpu_line += (f"; ROS bridge {result['ros_bridge_cpu_per_tick_ms']:.2f} + controller "
                     f"{result['ros_controller_cpu_per_tick_ms']:.2f} ms "
                     f"(bound {result['lockstep_ros_cpu_bound_rtf']:.2f}x)")
    print(cpu_line)
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
