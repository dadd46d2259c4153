"""The `controller` executable: a thin lifecycle node around controller_node.controller.Controller.

Lifecycle: ``on_configure`` reads the parameters (config/nodes/controller.yaml layout), builds the
robot, the environment and the controller, creates the publishers and subscriptions;
``on_activate`` starts commanding (the controller's contact set is reset from the
``initial_stance`` fixture on the first complete state); ``on_deactivate`` stops commanding;
``on_cleanup`` / ``on_shutdown`` destroy everything. With ``autostart`` (default) the node
configures and activates itself.

Execution (parameter ``execution``):

- ``lockstep``: callback-driven. The bridge publishes joint_states, ft/<sensor>, imu and
  sim/base_truth stamped t, then waits for a joint_command stamped t; the node computes as soon as
  joint_states, sim/base_truth and every F/T of stamp t are in, and publishes the command at once.
- ``realtime``: a wall-clock timer at the control period computes on the newest complete state
  (skipped when it is older than ``state_timeout_s``).

Publishes joint_command (TORQUE or PWM per joint), gripper_command, controller/state and
diagnostics (tick time, QP time, state->command latency inside the node, failures, FSM state).
Every topic is RELIABLE / VOLATILE, as the bridge's.
"""
from __future__ import annotations

import array
import gc
import os
import sys
import time
from collections import deque

import numpy as np
import rclpy
from builtin_interfaces.msg import Time
from climb_msgs.msg import ControllerState, GripperCommand, JointCommand, WholeBodyPlan
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import WrenchStamped
from nav_msgs.msg import Odometry
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.lifecycle import LifecycleNode, LifecycleState, TransitionCallbackReturn
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Imu, JointState

from climb_core.errors import ClimbError
from climb_core.params import describe
from climb_core.ros_env import apply_local_dds_env

from .controller import Controller
from .estimator import GroundTruthEstimator
from .params import NODE_NAME, ControllerParams, parse_controller_params

_NS = 1_000_000_000
_PARAM_TYPES = {"bool": Parameter.Type.BOOL, "int": Parameter.Type.INTEGER, "float": Parameter.Type.DOUBLE,
                "str": Parameter.Type.STRING, "str_array": Parameter.Type.STRING_ARRAY,
                "float_array": Parameter.Type.DOUBLE_ARRAY}
_GRIPPER = {"open": GripperCommand.OPEN, "close": GripperCommand.CLOSE, "position": GripperCommand.POSITION}
_QP_STATUS = (ControllerState.QP_OK, ControllerState.QP_FAILED, ControllerState.QP_NOT_RUN)
LATENCY_WINDOW = 20000  # ticks kept for the diagnostics percentiles
DIAGNOSTICS_EVERY = 200  # ticks between two diagnostics messages


def qos(depth: int = 10) -> QoSProfile:
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=depth, reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.VOLATILE)


def _as_array(values) -> np.ndarray:
    """A float64 numpy view of an ``array.array('d')`` message field (a copy for other sequences)."""
    if isinstance(values, array.array) and values.typecode == "d":
        return np.frombuffer(values, dtype=float)
    return np.asarray(values, dtype=float)


def to_ns(stamp: Time) -> int:
    return int(stamp.sec) * _NS + int(stamp.nanosec)


def to_time(stamp_ns: int) -> Time:
    return Time(sec=int(stamp_ns // _NS), nanosec=int(stamp_ns % _NS))


class ControllerNode(LifecycleNode):
    def __init__(self) -> None:
        super().__init__(NODE_NAME)
        for name, info in describe(ControllerParams).items():
            if info.is_array and not info.default:  # rclpy cannot infer the type of []
                self.declare_parameter(name, _PARAM_TYPES[info.type])
            else:
                self.declare_parameter(name, list(info.default) if info.is_array else info.default)
        self.params: ControllerParams | None = None
        self.controller: Controller | None = None
        self.active = False
        self._pubs: list = []
        self._subs: list = []
        self._timer = None
        self._reset_pending = True
        self._latest: dict[str, object] = {}
        self._stamps: dict[str, int] = {}
        self._received_at = 0.0  # [s] perf_counter when the newest complete state arrived
        self._last_stamp = -1
        self.latencies_ms: deque[float] = deque(maxlen=LATENCY_WINDOW)
        self.tick_ms: deque[float] = deque(maxlen=LATENCY_WINDOW)
        self.qp_ms: deque[float] = deque(maxlen=LATENCY_WINDOW)
        #: parts of the latency: state message -> RobotState, command fill + publish call
        self.state_ms: deque[float] = deque(maxlen=LATENCY_WINDOW)
        self.publish_ms: deque[float] = deque(maxlen=LATENCY_WINDOW)
        self.ticks = 0

    # ---------------------------------------------------------------------------- lifecycle
    def on_configure(self, state: LifecycleState) -> TransitionCallbackReturn:
        from climb_core.environment import build_environment
        from climb_core.ladder import load_scenario
        from climb_core.robot import load_robot

        try:
            flat = {name: self.get_parameter(name).value for name in describe(ControllerParams)}
            self.params = parse_controller_params(flat)
            p = self.params
            robot = load_robot(p.robot)
            env = build_environment(load_scenario(p.ladder))
            self.controller = Controller(robot, p, env)
        except (ClimbError, ValueError, OSError) as err:
            self.get_logger().error(f"configure failed: {err}")
            return TransitionCallbackReturn.FAILURE
        self.robot, self.env = robot, env
        self.estimator = GroundTruthEstimator(robot.joint_names)
        self.sensors = tuple(robot.config.ft_sensors)
        self._ft_keys = tuple(f"ft/{s}" for s in self.sensors)
        self.pub_command = self.create_lifecycle_publisher(JointCommand, "joint_command", qos())
        self.pub_gripper = self.create_lifecycle_publisher(GripperCommand, "gripper_command", qos())
        self.pub_state = self.create_lifecycle_publisher(ControllerState, "controller/state", qos())
        self.pub_diag = self.create_lifecycle_publisher(DiagnosticArray, "diagnostics", qos(50))
        self._pubs = [self.pub_command, self.pub_gripper, self.pub_state, self.pub_diag]
        self._subs = [
            self.create_subscription(JointState, "joint_states", self._on_joints, qos()),
            self.create_subscription(Odometry, "sim/base_truth", self._on_base, qos()),
            self.create_subscription(Imu, "imu", self._on_imu, qos()),
            self.create_subscription(WholeBodyPlan, "whole_body_plan", self._on_plan, qos(1)),
        ] + [self.create_subscription(WrenchStamped, f"ft/{s}", self._make_ft_callback(s), qos())
             for s in self.sensors]
        self._names = list(self.controller.joint_names)
        self._mode_code = JointCommand.PWM if p.mode == "compliance" else JointCommand.TORQUE
        self._modes = bytes([self._mode_code] * len(self._names))
        # the outgoing command, allocated once: per tick only the stamp and the values change
        self._cmd = JointCommand()
        self._cmd.names = self._names
        self._cmd.modes = self._modes
        self.get_logger().info(f"configured: {p.robot} on {p.ladder}, mode {p.mode}, {p.execution}")
        # the models, geometries and messages built above live as long as the node: moved out of
        # the collector's generations, the per-tick garbage stays cheap to collect (no full
        # collections walking them mid-tick)
        gc.collect()
        gc.freeze()
        return TransitionCallbackReturn.SUCCESS

    def on_activate(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._reset_pending = True
        self.active = True
        result = super().on_activate(state)  # activates the lifecycle publishers
        if self.params.execution == "realtime":
            self._timer = self.create_timer(self.params.control_period_s, self._on_timer)
        else:  # a lock-step bridge may be waiting for the answer to the state it already sent
            self._try_lockstep_tick()
        return result

    def on_deactivate(self, state: LifecycleState) -> TransitionCallbackReturn:
        self.active = False
        if self._timer is not None:
            self.destroy_timer(self._timer)
            self._timer = None
        return super().on_deactivate(state)

    def _destroy(self) -> None:
        self.active = False
        if self._timer is not None:
            self.destroy_timer(self._timer)
            self._timer = None
        for sub in self._subs:
            self.destroy_subscription(sub)
        for pub in self._pubs:
            self.destroy_lifecycle_publisher(pub)
        self._subs, self._pubs = [], []
        self.controller = None

    def on_cleanup(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._destroy()
        return TransitionCallbackReturn.SUCCESS

    def on_shutdown(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._destroy()
        return TransitionCallbackReturn.SUCCESS

    # ---------------------------------------------------------------------------- inputs
    def _store(self, key: str, msg, stamp: Time) -> None:
        self._latest[key] = msg
        self._stamps[key] = to_ns(stamp)
        if self.active and self.params.execution == "lockstep":
            self._try_lockstep_tick()

    def _on_joints(self, msg: JointState) -> None:
        self._store("joints", msg, msg.header.stamp)

    def _on_base(self, msg: Odometry) -> None:
        self._store("base", msg, msg.header.stamp)

    def _on_imu(self, msg: Imu) -> None:
        self._latest["imu"] = msg  # kept for an IMU-based estimator; ground truth is used in sim

    def _make_ft_callback(self, sensor: str):
        def callback(msg: WrenchStamped) -> None:
            self._store(f"ft/{sensor}", msg, msg.header.stamp)
        return callback

    def _on_plan(self, msg: WholeBodyPlan) -> None:
        from msgs_py.contact import whole_body_plan_from_msg

        if self.controller is None:
            return
        try:
            plan = whole_body_plan_from_msg(msg)
        except (ClimbError, ValueError) as err:
            self.get_logger().error(f"rejected whole_body_plan: {err}")
            return
        self.controller.set_plan(plan)
        self.get_logger().info(f"plan with {len(plan.transitions)} transitions")

    def _complete_stamp(self) -> int | None:
        """The stamp shared by joint_states, base truth and every F/T, if they agree."""
        stamps = self._stamps
        stamp = stamps.get("joints")
        if stamp is None or stamps.get("base") != stamp:
            return None
        for key in self._ft_keys:
            if stamps.get(key) != stamp:
                return None
        return stamp

    def _try_lockstep_tick(self) -> None:
        stamp = self._complete_stamp()
        if stamp is None or stamp <= self._last_stamp:
            return
        self._received_at = time.perf_counter()
        self._tick(stamp)

    def _on_timer(self) -> None:
        stamp = self._complete_stamp()
        if stamp is None or stamp <= self._last_stamp:
            return
        self._received_at = time.perf_counter()
        self._tick(stamp)

    # ---------------------------------------------------------------------------- tick
    def _robot_state(self, stamp: int):
        js: JointState = self._latest["joints"]
        base: Odometry = self._latest["base"]
        pose, tw = base.pose.pose, base.twist.twist
        ft = {}
        for s, key in zip(self.sensors, self._ft_keys):
            w = self._latest[key].wrench
            f, m = w.force, w.torque
            ft[s] = np.array((f.x, f.y, f.z, m.x, m.y, m.z))
        # sequence<double> fields arrive as array.array: numpy views of their buffers, no copy
        return self.estimator.estimate_local(
            stamp * 1e-9, js.name, _as_array(js.position), _as_array(js.velocity),
            np.array([pose.position.x, pose.position.y, pose.position.z]),
            np.array([pose.orientation.x, pose.orientation.y, pose.orientation.z, pose.orientation.w]),
            np.array([tw.linear.x, tw.linear.y, tw.linear.z, tw.angular.x, tw.angular.y, tw.angular.z]),
            ft, stamp)

    def _tick(self, stamp: int) -> None:
        self._last_stamp = stamp
        state = self._robot_state(stamp)
        c = self.controller
        if self._reset_pending:
            from climb_core import fixtures

            stance = fixtures.get(self.params.initial_stance, self.robot, self.env)[0]
            c.reset(state, stance)
            self._reset_pending = False
        t_state = time.perf_counter()
        out = c.tick(state)
        # the command goes out first; everything else (grippers, controller/state, diagnostics,
        # statistics) follows its publish call
        t_cmd = time.perf_counter()
        cmd = self._cmd
        cmd.header.stamp.sec = stamp // _NS
        cmd.header.stamp.nanosec = stamp % _NS
        cmd.values = array.array("d", out.values.tobytes())
        self.pub_command.publish(cmd)
        t_sent = time.perf_counter()
        self.latencies_ms.append((t_sent - self._received_at) * 1e3)
        self.state_ms.append((t_state - self._received_at) * 1e3)
        self.publish_ms.append((t_sent - t_cmd) * 1e3)
        for g in out.grippers:
            msg = GripperCommand(hand=g.hand, command=_GRIPPER[g.command], position=float(g.position))
            msg.header.stamp = to_time(stamp)
            self.pub_gripper.publish(msg)
        self.tick_ms.append(out.status.tick_time_ms)
        self.qp_ms.append(out.status.qp_solve_time_ms)
        self._publish_state(out, stamp)
        self.ticks += 1
        if self.ticks % DIAGNOSTICS_EVERY == 0 or out.status.qp_status == 1:
            self._publish_diagnostics(out, stamp)

    def _publish_state(self, out, stamp: int) -> None:
        s = out.status
        msg = ControllerState(fsm_state=s.fsm_state, mode=s.mode, transition_index=int(s.transition_index),
                              active_contacts=list(s.active_contacts), task_names=list(s.task_names),
                              task_errors=array.array("d", s.task_errors), qp_status=_QP_STATUS[s.qp_status],
                              qp_solve_time_ms=float(s.qp_solve_time_ms), tick_time_ms=float(s.tick_time_ms),
                              qp_failures=int(s.qp_failures))
        msg.header.stamp = to_time(stamp)
        self.pub_state.publish(msg)

    def latency_stats(self) -> dict[str, float]:
        out = {}
        for name, values in (("latency", self.latencies_ms), ("tick", self.tick_ms), ("qp", self.qp_ms),
                             ("state", self.state_ms), ("publish", self.publish_ms)):
            if values:
                a = np.fromiter(values, float)
                out.update({f"{name}_p50_ms": float(np.percentile(a, 50)), f"{name}_p99_ms": float(np.percentile(a, 99)),
                            f"{name}_max_ms": float(a.max())})
        return out

    def _publish_diagnostics(self, out, stamp: int) -> None:
        s = out.status
        level = DiagnosticStatus.ERROR if s.qp_status == 1 else DiagnosticStatus.OK
        values = {"fsm_state": s.fsm_state, "qp_failures": str(s.qp_failures), "ticks": str(self.ticks),
                  "replan_needed": str(s.replan_needed), "fallback": str(s.fallback)}
        values.update({k: f"{v:.4f}" for k, v in self.latency_stats().items()})
        msg = DiagnosticArray()
        msg.header.stamp = to_time(stamp)
        msg.status.append(DiagnosticStatus(level=level, name="controller", hardware_id="controller",
                                           message="QP failed: fallback" if s.qp_status == 1 else s.fsm_state,
                                           values=[KeyValue(key=k, value=v) for k, v in values.items()]))
        self.pub_diag.publish(msg)


def _apply_nice(node: ControllerNode) -> None:
    increment = int(node.get_parameter("nice").value)
    if increment == 0:
        return
    try:
        os.nice(increment)
        node.get_logger().info(f"niceness now {os.nice(0)}")
    except OSError as err:  # no CAP_SYS_NICE: run at the inherited priority
        node.get_logger().warning(f"nice({increment}) refused: {err}")


def main(args: list[str] | None = None) -> int:
    apply_local_dds_env()
    rclpy.init(args=args)
    node = None
    code = 0
    try:
        node = ControllerNode()
        _apply_nice(node)
        if node.get_parameter("autostart").value:
            node.trigger_configure()
            node.trigger_activate()
        # rclpy.experimental.EventsExecutor (Jazzy wheels) was tried: the lifecycle node configures
        # but never answers a lock-step state and ignores SIGINT, so the single-threaded one stays
        executor = SingleThreadedExecutor()
        executor.add_node(node)
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except (ClimbError, ValueError) as err:
        print(f"controller: {err}", file=sys.stderr)
        code = 2
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return code


if __name__ == "__main__":
    sys.exit(main())
