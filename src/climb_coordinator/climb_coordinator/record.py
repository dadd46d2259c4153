"""What a climb leaves behind: sampled log arrays (plots, checks) and a rosbag2 (MCAP) of the
run's topics at a decimated rate: joint_states, ft/<sensor>, sim/base_truth, joint_command,
controller/state (the topics the ROS nodes publish, same message types)."""
from __future__ import annotations

import pathlib
from dataclasses import dataclass, field

import numpy as np

from climb_core.contact import LIMBS

from .judge import limb_loads

BAG_TOPICS = ("joint_states", "sim/base_truth", "joint_command", "controller/state")


@dataclass
class ClimbLog:
    """Samples at the log rate (every array has one row per sample) plus every tick's timing."""

    joint_names: tuple[str, ...] = ()
    effort_limits: np.ndarray = field(default_factory=lambda: np.zeros(0))  # [N m]
    times: list[float] = field(default_factory=list)  # [s] sim time
    com: list[np.ndarray] = field(default_factory=list)  # [m] CoM in world (controller's model)
    base: list[np.ndarray] = field(default_factory=list)  # [m] base position in world (sim truth)
    tau: list[np.ndarray] = field(default_factory=list)  # [N m] torque behind the command
    fsm: list[str] = field(default_factory=list)
    transition: list[int] = field(default_factory=list)
    # limb -> per sample: (normal force [N], tangential force [N], surface) or None (no contact)
    loads: dict[str, list] = field(default_factory=lambda: {limb: [] for limb in LIMBS})
    tick_ms: list[float] = field(default_factory=list)  # [ms] every tick
    qp_ms: list[float] = field(default_factory=list)  # [ms] every tick
    max_current_ratio: list[float] = field(default_factory=list)  # [-] every tick (compliance)

    def arrays(self) -> dict[str, np.ndarray]:
        return {"times": np.asarray(self.times), "com": np.asarray(self.com), "base": np.asarray(self.base),
                "tau": np.asarray(self.tau), "tick_ms": np.asarray(self.tick_ms)}


class BagWriter:
    """rosbag2 writer of one climb (messages built with the ROS message classes, serialized by
    msgs_py.bag without rclpy.init)."""

    def __init__(self, path: str | pathlib.Path, joint_names: tuple[str, ...], ft_frames: dict[str, str],
                 root_link: str):
        from geometry_msgs.msg import WrenchStamped
        from nav_msgs.msg import Odometry
        from sensor_msgs.msg import JointState

        from msgs_py.bag import BagRecorder

        self.path = pathlib.Path(path)
        self.recorder = BagRecorder(self.path, close_on_signals=False)
        self.joint_names = list(joint_names)
        self._JointState, self._WrenchStamped, self._Odometry = JointState, WrenchStamped, Odometry
        self.ft_frames = dict(ft_frames)
        self.root_link = root_link
        self.count = 0
        self.plans_taken = 0  # plans handed to the controller (controller/state's plans_taken)

    def write(self, sim_state, output) -> None:
        from climb_msgs.msg import ControllerState

        from msgs_py.commands import joint_command_to_msg
        from msgs_py.geometry import pose_to_msg
        from msgs_py.stamps import make_header

        stamp_ns = int(sim_state.stamp_ns)
        t = stamp_ns * 1e-9
        rec = self.recorder
        js = self._JointState()
        js.header = make_header(t)
        js.name = list(sim_state.joint_names)
        js.position = sim_state.q.tolist()
        js.velocity = sim_state.v.tolist()
        js.effort = sim_state.tau.tolist()
        rec.write("joint_states", js, stamp_ns)
        for sensor, wrench in sim_state.ft.items():
            msg = self._WrenchStamped()
            msg.header = make_header(t, self.ft_frames.get(sensor, sensor))
            f, m = wrench.force, wrench.torque
            msg.wrench.force.x, msg.wrench.force.y, msg.wrench.force.z = (float(x) for x in f)
            msg.wrench.torque.x, msg.wrench.torque.y, msg.wrench.torque.z = (float(x) for x in m)
            rec.write(f"ft/{sensor}", msg, stamp_ns)
        odom = self._Odometry()
        odom.header = make_header(t, "world")
        odom.child_frame_id = self.root_link
        odom.pose.pose = pose_to_msg(sim_state.base.T_world_base)
        v_local = sim_state.base.v[:6]  # twist in the root link frame (Pinocchio free-flyer layout)
        tw = odom.twist.twist
        tw.linear.x, tw.linear.y, tw.linear.z = (float(x) for x in v_local[:3])
        tw.angular.x, tw.angular.y, tw.angular.z = (float(x) for x in v_local[3:6])
        rec.write("sim/base_truth", odom, stamp_ns)
        rec.write("joint_command", joint_command_to_msg(names=tuple(output.joint_names), modes=output.mode,
                                                        values=np.asarray(output.values, float),
                                                        stamp=output.stamp_ns * 1e-9), stamp_ns)
        s = output.status
        cs = ControllerState(fsm_state=s.fsm_state, mode=s.mode, transition_index=int(s.transition_index),
                             active_contacts=list(s.active_contacts), task_names=list(s.task_names),
                             task_errors=[float(e) for e in s.task_errors], qp_status=int(s.qp_status),
                             qp_solve_time_ms=float(s.qp_solve_time_ms), tick_time_ms=float(s.tick_time_ms),
                             qp_failures=int(s.qp_failures), plans_taken=int(self.plans_taken))
        cs.header = make_header(t)
        rec.write("controller/state", cs, stamp_ns)
        self.count += 1

    def close(self) -> None:
        self.recorder.close()


def sample(log: ClimbLog, backend, sim_state, output, controller) -> None:
    """One log sample (sim truth + controller quantities)."""
    log.times.append(float(sim_state.time))
    log.com.append(np.array(controller.wb.data.com[0]))
    log.base.append(np.array(sim_state.base.T_world_base[:3, 3]))
    log.tau.append(np.array(output.tau, float))
    log.fsm.append(output.status.fsm_state)
    log.transition.append(int(output.status.transition_index))
    loads = limb_loads(backend)
    for limb in LIMBS:
        load = loads.get(limb)
        log.loads[limb].append(None if load is None else (load.normal_force, load.tangential_force, load.surface))
