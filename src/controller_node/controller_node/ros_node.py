"""The `controller` lifecycle node: a thin rclpy node around controller_node.controller.Controller
(the executable is controller_node.node.main, which installs the signal handlers first).

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
QoS of every topic from msgs_py.topics (RELIABLE / VOLATILE).

Service ``controller/hold`` (std_srvs/Trigger): the FSM abandons the plan and holds the active
contacts (:meth:`Controller.hold_plan`; the coordinator's cancel); answers success with the FSM
state (``hold``), or success = False with the reason (not active, no state yet, in failure).

Bad input never kills the node (docs/interfaces.md): every callback is guarded (msgs_py.node_kit);
a whole_body_plan is checked (msgs_py.contact, then :func:`plan_check.check_plan` against the
robot and the ladder) and rejected with a diagnostic ``controller/plan`` naming the field, the
current plan kept; a state message that does not decode, has NaN / inf, lengths that disagree or
lacks a robot joint is dropped and reported (``controller/input``); a lifecycle transition that
is invalid in the current state is refused (success = False); set_parameters is validated by the
YAML loader's parser (range, choices, cross-field rules) and refused with the reason, and
refused with "read at configure" while the node is configured (clean up first); ``autostart``,
``nice`` and ``cpu_affinity`` are read_only (start-up only). Defaults: config/nodes/controller.yaml
(the schema's defaults equal it, tests/unit/test_controller_defaults.py). SIGINT / SIGTERM: exit 0
(msgs_py.node_kit.run_node).

Hot path: the state topics are taken as CDR bytes (``raw=True``) and decoded by msgs_py.cdr,
joint_command is published as bytes from a template (the wire bytes are the same as rclpy's):
rclpy's per-field message conversion cost ~0.5 ms per tick (Odometry alone ~160 us). The node
spins rclpy's EventsExecutor with ``spin_once`` (its ``spin()`` in the Jazzy wheels never runs a
callback and ignores SIGINT; ``spin_once`` works and costs about a third of the
SingleThreadedExecutor's ~0.3 ms per message). Parameter ``cpu_affinity`` pins the process (all
its threads) to the given CPUs: in lock-step, the bridge on one core and the controller on the
other keep each other's wake-ups from preempting the publishing thread (the multi-ms tail of the
command's publish call).
"""
from __future__ import annotations

import array
import gc
import os
import struct
import time
from collections import deque

import numpy as np
from builtin_interfaces.msg import Time
from climb_msgs.msg import ControllerState, GripperCommand, JointCommand, WholeBodyPlan
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import WrenchStamped
from nav_msgs.msg import Odometry
from rcl_interfaces.msg import ParameterDescriptor
from rclpy.lifecycle import LifecycleNode, LifecycleState, TransitionCallbackReturn
from rclpy.parameter import Parameter
from rclpy.serialization import deserialize_message, serialize_message
from sensor_msgs.msg import Imu, JointState
from std_srvs.srv import Trigger

from climb_core.errors import ClimbError, SpecError
from climb_core.params import describe, flatten
from climb_core.ros_env import apply_cpu_affinity
from msgs_py import cdr
from msgs_py.node_kit import SHUTDOWN_ERRORS, declare_from_schema, diagnose, guarded, run_node
from msgs_py.topics import qos_for

from .controller import Controller, HoldRefused, PlanRefused
from .estimator import GroundTruthEstimator
from .params import NODE_NAME, ControllerParams, default_params_path, load_controller_params, parse_controller_params
from .plan_check import check_plan

_NS = 1_000_000_000
#: parameters applied at start-up only (read_only: a change at run time is refused by rclpy)
READ_ONLY = ("autostart", "nice")
#: bad state messages reported per topic and second (the rest are counted in the next report)
INPUT_REPORTS_PER_S = 5
#: [s] wall time without a complete state, while active, before the silence is reported
STATE_SILENCE_S = 2.0
#: what decoding / checking a bad message raises (rclpy's deserialize_message: RMWError, a
#: RuntimeError; msgs_py.cdr: CdrError, a ValueError, and struct.error on truncated bytes; the
#: checks: SpecError)
_BAD_INPUT = (ClimbError, ValueError, TypeError, IndexError, RuntimeError, struct.error)
_GRIPPER = {"open": GripperCommand.OPEN, "close": GripperCommand.CLOSE, "position": GripperCommand.POSITION}
_QP_STATUS = (ControllerState.QP_OK, ControllerState.QP_FAILED, ControllerState.QP_NOT_RUN)
LATENCY_WINDOW = 20000  # ticks kept for the diagnostics percentiles
DIAGNOSTICS_EVERY = 200  # ticks between two diagnostics messages
PLANS_AFTER_KEPT = 64  # accepted plans whose after_tick_ns the periodic diagnostics repeat


def default_params() -> ControllerParams:
    """config/nodes/controller.yaml: the defaults of a node started without --params-file (the
    schema's own defaults, equal to it, when the file is not installed)."""
    return load_controller_params() if default_params_path().is_file() else ControllerParams()


def _as_array(values) -> np.ndarray:
    """A float64 numpy view of an ``array.array('d')`` message field (a copy for other sequences)."""
    if isinstance(values, array.array) and values.typecode == "d":
        return np.frombuffer(values, dtype=float)
    return np.asarray(values, dtype=float)


def _vec(*values: float) -> np.ndarray:
    return np.array(values, dtype=float)


class StateDecoder:
    """Raw state messages (CDR bytes) -> msgs_py.cdr data; other encodings through rclpy."""

    def __init__(self) -> None:
        self._joints = cdr.JointStateReader()

    def joints(self, data: bytes) -> cdr.JointStateData:
        try:
            return self._joints.read(data)
        except cdr.CdrError:
            m = deserialize_message(data, JointState)
            return cdr.JointStateData(to_ns(m.header.stamp), list(m.name), _as_array(m.position).copy(),
                                      _as_array(m.velocity).copy(), _as_array(m.effort).copy())

    @staticmethod
    def base(data: bytes) -> cdr.OdometryData:
        try:
            return cdr.read_odometry(data)
        except cdr.CdrError:
            m = deserialize_message(data, Odometry)
            p, o, t = m.pose.pose.position, m.pose.pose.orientation, m.twist.twist
            return cdr.OdometryData(to_ns(m.header.stamp), _vec(p.x, p.y, p.z, o.x, o.y, o.z, o.w),
                                    _vec(t.linear.x, t.linear.y, t.linear.z, t.angular.x, t.angular.y, t.angular.z))

    @staticmethod
    def wrench(data: bytes) -> tuple[int, np.ndarray]:
        try:
            return cdr.read_wrench_stamped(data)
        except cdr.CdrError:
            m = deserialize_message(data, WrenchStamped)
            f, t = m.wrench.force, m.wrench.torque
            return to_ns(m.header.stamp), _vec(f.x, f.y, f.z, t.x, t.y, t.z)

    @staticmethod
    def imu(data: bytes) -> cdr.ImuData:
        try:
            return cdr.read_imu(data)
        except cdr.CdrError:
            m = deserialize_message(data, Imu)
            o, w, a = m.orientation, m.angular_velocity, m.linear_acceleration
            return cdr.ImuData(to_ns(m.header.stamp), _vec(o.x, o.y, o.z, o.w), _vec(w.x, w.y, w.z),
                               _vec(a.x, a.y, a.z))


def to_ns(stamp: Time) -> int:
    return int(stamp.sec) * _NS + int(stamp.nanosec)


def to_time(stamp_ns: int) -> Time:
    return Time(sec=int(stamp_ns // _NS), nanosec=int(stamp_ns % _NS))


class ControllerNode(LifecycleNode):
    def __init__(self) -> None:
        super().__init__(NODE_NAME)
        self.settings = declare_from_schema(self, ControllerParams, default_params(), read_only=READ_ONLY,
                                            node_name=NODE_NAME, on_change=self._on_param_change)
        self.declare_parameter("cpu_affinity", Parameter.Type.INTEGER_ARRAY, ParameterDescriptor(
            name="cpu_affinity", type=Parameter.Type.INTEGER_ARRAY.value, read_only=True,
            description="node: CPUs this process (every thread) runs on, applied at start-up; empty = the "
                        "inherited set [-] each >= 0"))
        # a transition sent by id that is invalid in the current state: refused, not an RCLError
        # that kills the process (rclpy's own handler calls the state machine unchecked)
        self._rclpy_change_state = self._service_change_state.callback
        self._service_change_state.callback = self._on_change_state
        self.create_service(Trigger, "controller/hold", guarded(self, self._on_hold, "hold"))
        diagnose(self, "controller", "started", level=0)  # the diagnostics publisher exists from now on
        self._input_reports: dict[str, list] = {}  # topic -> [window start, reports, dropped]
        self.params: ControllerParams | None = None
        self.controller: Controller | None = None
        self.active = False
        self._pubs: list = []
        self._subs: list = []
        self._timer = None
        self._reset_pending = True
        # a plan received while inactive (or before the first tick of an activation, which resets
        # the controller to the new world's state): started right after that reset
        self._plan_at_activation = None
        self._plans_after: list[str] = []  # [ns] after_tick_ns of the plans accepted (periodic diagnostics)
        self.plans_taken = 0  # plans handed to the controller (controller/state's plans_taken)
        self._latest: dict[str, object] = {}
        self._stamps: dict[str, int] = {}
        self._received_at = 0.0  # [s] perf_counter when the newest complete state arrived
        self._watchdog = None  # 1 Hz timer while active: reports a silent state source
        self._silent = False  # the silence was reported (cleared by the next tick)
        self._last_stamp = -1
        self.latencies_ms: deque[float] = deque(maxlen=LATENCY_WINDOW)
        self.tick_ms: deque[float] = deque(maxlen=LATENCY_WINDOW)
        self.qp_ms: deque[float] = deque(maxlen=LATENCY_WINDOW)
        #: parts of the latency: state message -> RobotState, command fill + publish call
        self.state_ms: deque[float] = deque(maxlen=LATENCY_WINDOW)
        self.publish_ms: deque[float] = deque(maxlen=LATENCY_WINDOW)
        self.ticks = 0

    # ---------------------------------------------------------------------------- parameters
    def lifecycle_state(self) -> str:
        return self._state_machine.current_state[1]

    def _on_param_change(self, new: ControllerParams) -> None:
        """A validated change: taken while unconfigured (read at the next configure); refused
        while configured, since the controller, its models and its QP are built from them."""
        old_flat, new_flat = flatten(self.settings), flatten(new)
        changed = [name for name in new_flat if new_flat[name] != old_flat[name]]
        state = self.lifecycle_state()
        if changed and state != "unconfigured":
            raise SpecError(f"{NODE_NAME}.{changed[0]}", f"read at configure; the node is {state}: deactivate and "
                                                          "clean up, set it, then configure again")
        self.settings = new

    def _read_params(self) -> ControllerParams:
        infos = describe(ControllerParams)
        flat = {}
        for name, info in infos.items():
            value = self.get_parameter(name).value
            flat[name] = list(value) if info.is_array else value
        return parse_controller_params(flat)

    def _on_change_state(self, request, response):
        transition = request.transition
        if not transition.label:
            available = {t[0]: t[1] for t in self._state_machine.available_transitions}
            if transition.id not in available:
                state = self.lifecycle_state()
                text = (f"transition id {transition.id} is not valid in state {state} (valid: "
                        + ", ".join(f"{i} {label}" for i, label in sorted(available.items())) + ")")
                self.get_logger().warning(f"refused: {text}")
                diagnose(self, "controller/lifecycle", f"refused: {text}", level=1)
                response.success = False
                return response
        try:
            return self._rclpy_change_state(request, response)
        except SHUTDOWN_ERRORS as err:  # whatever else the state machine refuses
            self.get_logger().warning(f"refused transition {transition.id} {transition.label!r}: {err}")
            response.success = False
            return response

    # ---------------------------------------------------------------------------- lifecycle
    def on_configure(self, state: LifecycleState) -> TransitionCallbackReturn:
        from climb_core.environment import build_environment
        from climb_core.ladder import load_scenario
        from climb_core.robot import load_robot

        try:
            self.params = self._read_params()
            p = self.params
            robot = load_robot(p.robot)
            env = build_environment(load_scenario(p.ladder))
            self.controller = Controller(robot, p, env)
        except (ClimbError, ValueError, OSError) as err:  # the node stays unconfigured, nothing built
            self.get_logger().error(f"configure failed: {err}")
            diagnose(self, "controller/lifecycle", f"configure failed: {err}", level=2,
                     values={"field": getattr(err, "field", ""), "rule": getattr(err, "rule", str(err))})
            return TransitionCallbackReturn.FAILURE
        self.robot, self.env = robot, env
        self.estimator = GroundTruthEstimator(robot.joint_names)
        self.sensors = tuple(robot.config.ft_sensors)
        self._ft_keys = tuple(f"ft/{s}" for s in self.sensors)
        self.pub_command = self.create_lifecycle_publisher(JointCommand, "joint_command", qos_for("joint_command"))
        self.pub_gripper = self.create_lifecycle_publisher(GripperCommand, "gripper_command",
                                                           qos_for("gripper_command"))
        self.pub_state = self.create_lifecycle_publisher(ControllerState, "controller/state",
                                                         qos_for("controller/state"))
        self.pub_diag = self.create_lifecycle_publisher(DiagnosticArray, "diagnostics", qos_for("diagnostics"))
        self._pubs = [self.pub_command, self.pub_gripper, self.pub_state, self.pub_diag]
        # state topics raw (CDR bytes, decoded by msgs_py.cdr): see the module docstring; every
        # callback guarded (an exception is reported on diagnostics, never kills the node)
        self._decode = StateDecoder()
        self._joint_names_ok = None  # the names tuple last checked (msgs_py.cdr caches it)
        self._subs = [
            self.create_subscription(JointState, "joint_states", guarded(self, self._on_joints, "joint_states"),
                                     qos_for("joint_states"), raw=True),
            self.create_subscription(Odometry, "sim/base_truth", guarded(self, self._on_base, "sim/base_truth"),
                                     qos_for("sim/base_truth"), raw=True),
            self.create_subscription(Imu, "imu", guarded(self, self._on_imu, "imu"), qos_for("imu"), raw=True),
            self.create_subscription(WholeBodyPlan, "whole_body_plan", guarded(self, self._on_plan, "whole_body_plan"),
                                     qos_for("whole_body_plan"), raw=True),  # garbage bytes: rejected, not fatal
        ] + [self.create_subscription(WrenchStamped, f"ft/{s}", guarded(self, self._make_ft_callback(s), f"ft/{s}"),
                                      qos_for(f"ft/{s}"), raw=True)
             for s in self.sensors]
        self._names = list(self.controller.joint_names)
        self._mode_code = JointCommand.PWM if p.mode == "compliance" else JointCommand.TORQUE
        self._modes = bytes([self._mode_code] * len(self._names))
        # the outgoing command, serialized once: per tick only the stamp and the values change
        cmd = JointCommand(names=self._names, modes=self._modes,
                           values=array.array("d", bytes(8 * len(self._names))))
        self._cmd = cdr.Template(serialize_message(cmd), cdr.locate_joint_command)
        self._cmd_values = self._cmd.field("values")
        self._state_writer = cdr.ControllerStateWriter(ControllerState, serialize_message)
        self.get_logger().info(f"configured: {p.robot} on {p.ladder}, mode {p.mode}, {p.execution}")
        # the models, geometries and messages built above live as long as the node: moved out of
        # the collector's generations, the per-tick garbage stays cheap to collect (no full
        # collections walking them mid-tick)
        gc.collect()
        gc.freeze()
        return TransitionCallbackReturn.SUCCESS

    def on_activate(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._reset_pending = True
        # a reset simulator restarts its time at 0: the states of the new world are newer than
        # anything this activation has seen, whatever the previous activation ticked last
        self._last_stamp = -1
        self.active = True
        self._received_at = time.perf_counter()
        self._watchdog = self.create_timer(1.0, guarded(self, self._check_silence, "watchdog"))
        result = super().on_activate(state)  # activates the lifecycle publishers
        if self.params.execution == "realtime":
            self._timer = self.create_timer(self.params.control_period_s, guarded(self, self._on_timer, "tick"))
        else:  # a lock-step bridge may be waiting for the answer to the state it already sent
            self._try_lockstep_tick()
        return result

    def _stop_timers(self) -> None:
        for name in ("_timer", "_watchdog"):
            timer = getattr(self, name)
            if timer is not None:
                self.destroy_timer(timer)
                setattr(self, name, None)

    def on_deactivate(self, state: LifecycleState) -> TransitionCallbackReturn:
        self.active = False
        self._plan_at_activation = None
        self._stop_timers()
        return super().on_deactivate(state)

    def _check_silence(self) -> None:
        """Dead peer: no complete state for STATE_SILENCE_S while active. Nothing to command
        (the bridge damps the joints when the commands stop); reported once per silence."""
        age = time.perf_counter() - self._received_at
        if self.active and not self._silent and age > STATE_SILENCE_S:
            self._silent = True
            text = f"no complete state for {age:.1f} s: no command sent (is the bridge running?)"
            self.get_logger().warning(text)
            diagnose(self, "controller/input", text, level=1, values={"silent_s": f"{age:.1f}"})

    def _destroy(self) -> None:
        self.active = False
        self._plan_at_activation = None
        self._stop_timers()
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
    def _store(self, key: str, value, stamp_ns: int) -> None:
        self._latest[key] = value
        self._stamps[key] = stamp_ns
        if self.active and self.params.execution == "lockstep":
            if key == "base" and stamp_ns == self._last_stamp >= 0:
                # a state answered already, published again by a bridge still awaiting its first
                # command (its reader may have matched after the first answer): the same answer
                self.pub_command.publish(self._cmd.payload())
                return
            self._try_lockstep_tick()

    def _reject_input(self, topic: str, err: Exception) -> None:
        """A bad state message: dropped (the last good one stays) and reported on diagnostics,
        at most INPUT_REPORTS_PER_S per topic and second (the others counted in the next one)."""
        now = time.monotonic()
        window = self._input_reports.setdefault(topic, [now, 0, 0])
        if now - window[0] >= 1.0:
            window[:] = [now, 0, window[2]]
        if window[1] >= INPUT_REPORTS_PER_S:
            window[2] += 1
            return
        window[1] += 1
        dropped, window[2] = window[2], 0
        field = getattr(err, "field", topic)
        text = f"dropped {topic}: {err}"
        self.get_logger().warning(text)
        diagnose(self, "controller/input", text, level=2,
                 values={"topic": topic, "field": field, "error": type(err).__name__, "dropped_unreported": dropped})

    def _on_joints(self, data: bytes) -> None:
        try:
            joints = self._decode.joints(data)
            n = len(joints.names)
            if joints.names is not self._joint_names_ok:
                try:
                    self.estimator._index(joints.names)
                except KeyError as err:
                    raise SpecError("joint_states.name", str(err.args[0])) from None
                if len(set(joints.names)) != n:
                    raise SpecError("joint_states.name", "a joint appears twice")
            if len(joints.position) != n or len(joints.velocity) != n:
                raise SpecError("joint_states", f"{n} names but {len(joints.position)} positions and "
                                                f"{len(joints.velocity)} velocities")
            if not (np.isfinite(joints.position).all() and np.isfinite(joints.velocity).all()):
                raise SpecError("joint_states.position" if not np.isfinite(joints.position).all()
                                else "joint_states.velocity", "must be finite")
        except _BAD_INPUT as err:
            self._reject_input("joint_states", err)
            return
        self._joint_names_ok = joints.names
        self._store("joints", joints, joints.stamp_ns)

    def _on_base(self, data: bytes) -> None:
        try:
            base = self._decode.base(data)
            if not (np.isfinite(base.pose).all() and np.isfinite(base.twist).all()):
                raise SpecError("sim/base_truth.pose" if not np.isfinite(base.pose).all() else "sim/base_truth.twist",
                                "must be finite")
            if not 0.5 < float(np.linalg.norm(base.pose[3:7])) < 2.0:
                raise SpecError("sim/base_truth.pose.orientation", "must be a unit quaternion")
        except _BAD_INPUT as err:
            self._reject_input("sim/base_truth", err)
            return
        self._store("base", base, base.stamp_ns)

    def _on_imu(self, data: bytes) -> None:
        # checked, then kept raw for an IMU-based estimator (StateDecoder.imu); sim uses ground truth
        try:
            imu = self._decode.imu(data)
            for name in ("orientation_xyzw", "angular_velocity", "linear_acceleration"):
                if not np.isfinite(getattr(imu, name)).all():
                    raise SpecError(f"imu.{name}", "must be finite")
        except _BAD_INPUT as err:
            self._reject_input("imu", err)
            return
        self._latest["imu"] = data

    def _make_ft_callback(self, sensor: str):
        key = f"ft/{sensor}"
        decode = self._decode.wrench

        def callback(data: bytes) -> None:
            try:
                stamp, wrench = decode(data)
                if not np.isfinite(wrench).all():
                    raise SpecError(f"{key}.wrench", "must be finite")
            except _BAD_INPUT as err:
                self._reject_input(key, err)
                return
            self._store(key, wrench, stamp)
        return callback

    def _on_plan(self, data: bytes) -> None:
        from msgs_py.contact import whole_body_plan_from_msg

        try:
            msg = deserialize_message(data, WholeBodyPlan)
        except _BAD_INPUT as err:
            self.get_logger().error(f"rejected whole_body_plan: undecodable ({len(data)} bytes): {err}")
            diagnose(self, "controller/plan", f"rejected whole_body_plan: undecodable ({len(data)} bytes): {err}",
                     level=2, values={"field": "whole_body_plan", "rule": "not a WholeBodyPlan"})
            return
        request_id = str(getattr(msg, "request_id", ""))
        if self.controller is None:
            diagnose(self, "controller/plan", "rejected whole_body_plan: the controller is not configured",
                     level=2, values={"request_id": request_id})
            return
        try:
            plan = whole_body_plan_from_msg(msg)
            check_plan(plan, self.robot, self.env)
        except (ClimbError, ValueError) as err:
            self.get_logger().error(f"rejected whole_body_plan: {err}")
            diagnose(self, "controller/plan", f"rejected whole_body_plan: {err}", level=2,
                     values={"field": getattr(err, "field", "whole_body_plan"), "rule": getattr(err, "rule", str(err)),
                             "request_id": request_id})
            return
        when = ""
        if not self.active or self._reset_pending:  # started right after the activation's reset
            self._plan_at_activation = plan
            when = " (starts at activation)"
        else:
            try:
                self.controller.set_plan(plan)
                self.plans_taken += 1
            except PlanRefused as err:
                self.get_logger().error(f"rejected whole_body_plan: {err}")
                diagnose(self, "controller/plan", f"rejected whole_body_plan: {err}", level=2,
                         values={"field": "whole_body_plan", "rule": "busy", "request_id": request_id})
                return
        text = f"accepted whole_body_plan: {len(plan.transitions)} transitions{when}"
        self.get_logger().info(text)
        # after_tick_ns: the stamp of the last tick before the plan (it starts on the next one; empty
        # when it starts at activation): a bag then knows the plan's first tick from sim time alone
        after = "" if when else str(self._last_stamp)
        self._plans_after.append(after or "-1")  # repeated in the periodic diagnostics (below)
        del self._plans_after[:-PLANS_AFTER_KEPT]
        diagnose(self, "controller/plan", text, level=0,
                 values={"request_id": request_id, "transitions": len(plan.transitions), "after_tick_ns": after})

    def _on_hold(self, request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        """controller/hold: abandon the plan, hold the active contacts (Controller.hold_plan)."""
        c = self.controller
        if not self.active or c is None:
            response.success = False
            response.message = f"not active (lifecycle state {self.lifecycle_state()}): nothing to hold"
            return response
        try:
            before = c.hold_plan()
        except HoldRefused as err:
            response.success = False
            response.message = str(err)
            return response
        response.success = True
        response.message = c.fsm.state
        text = f"hold: plan abandoned in {before}, holding {', '.join(sorted(c.contacts)) or 'no contact'}"
        self.get_logger().info(text)
        diagnose(self, "controller/hold", text, level=0, values={"from": before, "contacts": ",".join(sorted(c.contacts))})
        return response

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
        js: cdr.JointStateData = self._latest["joints"]
        base: cdr.OdometryData = self._latest["base"]
        latest = self._latest
        ft = {s: latest[key] for s, key in zip(self.sensors, self._ft_keys)}
        return self.estimator.estimate_local(stamp * 1e-9, js.names, js.position, js.velocity, base.pose[:3],
                                             base.pose[3:], base.twist, ft, stamp)

    def _tick(self, stamp: int) -> None:
        self._last_stamp = stamp
        if self._silent:
            self._silent = False
            diagnose(self, "controller/input", "states back: commanding again", level=0)
        state = self._robot_state(stamp)
        c = self.controller
        if self._reset_pending:
            from climb_core import fixtures

            stance = fixtures.get(self.params.initial_stance, self.robot, self.env)[0]
            c.reset(state, stance)
            self._reset_pending = False
            plan, self._plan_at_activation = self._plan_at_activation, None
            if plan is not None:
                c.set_plan(plan)  # a reset controller is idle: the plan is taken
                self.plans_taken += 1
        t_state = time.perf_counter()
        out = c.tick(state)
        # the command goes out first; everything else (grippers, controller/state, diagnostics,
        # statistics) follows its publish call
        t_cmd = time.perf_counter()
        cmd = self._cmd
        cmd.set_stamp(stamp)
        self._cmd_values[:] = out.values
        self.pub_command.publish(cmd.payload())
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
        s = out.status  # serialized from a template per FSM state / contact set (msgs_py.cdr)
        reason, surface, offset = "", "", (0.0, 0.0, 0.0)
        if s.fsm_state == "replan_needed":  # why, and where the surface was found (contact_offset)
            c = self.controller
            reason = c.replan_reason
            if reason == "contact_offset" and c.placement_offset is not None:
                surface, offset = c.placement_offset[1], tuple(float(x) for x in c.placement_offset[2])
        self.pub_state.publish(self._state_writer.payload(
            stamp, s.fsm_state, s.mode, int(s.transition_index), s.active_contacts, s.task_names, s.task_errors,
            _QP_STATUS[s.qp_status], float(s.qp_solve_time_ms), float(s.tick_time_ms), int(s.qp_failures),
            reason, surface, offset, self.plans_taken))

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
                  "replan_needed": str(s.replan_needed), "fallback": str(s.fallback),
                  # every accepted plan's after_tick_ns (-1: started at an activation), oldest first:
                  # a recorder that missed the acceptance itself (its subscription matched late)
                  # still finds each plan's first tick in sim time
                  "plans_after_tick_ns": ",".join(self._plans_after)}
        values.update({k: f"{v:.4f}" for k, v in self.latency_stats().items()})
        msg = DiagnosticArray()
        msg.header.stamp = to_time(stamp)
        msg.status.append(DiagnosticStatus(level=level, name="controller", hardware_id="controller",
                                           message="QP failed: fallback" if s.qp_status == 1 else s.fsm_state,
                                           values=[KeyValue(key=k, value=v) for k, v in values.items()]))
        self.pub_diag.publish(msg)


def apply_nice(node: ControllerNode) -> None:
    """The node's ``nice`` parameter applied to the process (also used by the composed sim_graph)."""
    increment = int(node.get_parameter("nice").value)
    if increment == 0:
        return
    try:
        os.nice(increment)
        node.get_logger().info(f"niceness now {os.nice(0)}")
    except OSError as err:  # no CAP_SYS_NICE: run at the inherited priority
        node.get_logger().warning(f"nice({increment}) refused: {err}")


def build_node() -> ControllerNode:
    """The node, niceness applied, configured and activated with ``autostart``."""
    node = ControllerNode()
    apply_nice(node)
    if node.get_parameter("autostart").value:
        node.trigger_configure()
        if node.lifecycle_state() == "inactive":
            node.trigger_activate()
    return node


def run(args: list[str] | None = None) -> int:
    """The executable's body (controller_node.node.main installs the signal handlers first)."""
    # after the executor exists: apply_cpu_affinity pins the DDS threads too
    return run_node(build_node, args, name="controller",
                    after_add=lambda nodes, executor: apply_cpu_affinity(nodes[0]))
