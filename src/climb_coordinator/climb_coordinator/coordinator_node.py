"""The `climb_coordinator` node: the climb through the ROS 2 graph.

Serves
  - service ``climb`` (climb_msgs/srv/Climb): checks the request at once (unknown robot, invalid
    spec with the field and the rule, a target rung the ladder cannot give that robot, a
    command delay the running bridge does not have, a climb already running) and answers
    ``accepted`` + id, or the reason; the climb then runs in a worker thread;
  - action ``climb`` (climb_msgs/action/Climb): the same climb with feedback (phase, stage,
    transition k of n, FSM state, progress) and the summary as the result; cancel supported;
  - service ``climb/cancel`` (climb_msgs/srv/Cancel).
Publishes ``climb/status`` (ClimbStatus), ``climb/request`` (latched std_msgs/String: the accepted
request as JSON, scenario text included), ``robot_description`` (latched URDF text) and
``climb/markers`` (visualization_msgs/MarkerArray, ``markers_period_s``).

A climb (climb_coordinator.session.ClimbSession with the ROS adapters below):
  1. the controller (lifecycle node ``controller``): deactivated / cleaned up if needed, its
     parameters set for the request (robot, ladder, mode, initial stance, config/climb.yaml's
     controller overrides, the actuation latency of a command delay), configured;
  2. ``sim/reset`` (robot, scenario text, the library's start fixture, seed): the new world waits
     at t = 0 for its first command (the bridge's ``lockstep.reset_wait_s`` in config/graph.yaml);
  3. ``plan/request`` (JSON) -> guide_path -> contact_search -> primitive_adaptation ->
     ``whole_body_plan``; stage statuses and times are followed; the configured controller keeps
     the plan, and is activated once the plan exists: it starts the plan on its first tick (the
     planners get the machine instead of a lock-step pair holding a standing robot);
  4. ``controller/state`` is watched (heartbeat): at ``replan_needed`` a new plan from the measured
     state (joint_states + sim/base_truth) is requested (bounded), on a fall (``sim/contacts``), an
     FSM failure or a silent controller (no state for ``heartbeat_timeout_s`` of wall time: the
     controller or, when ``sim/contacts`` is silent too, the bridge) the run stops and says which;
  5. a cancel sends ``controller/hold`` (std_srvs/Trigger): the controller holds its contacts, the
     bridge keeps running;
  6. judged from topics only: ``sim/contacts`` (feet on rungs, grasps, falls), controller/state.
"""
from __future__ import annotations

import json
import math
import re
import threading
import time
import uuid
from dataclasses import dataclass
from typing import Any

import numpy as np

from climb_core.errors import ClimbError, SpecError
from climb_core.params import param

from .session import (MAX_FORCED_REPLANS, ClimbRequest, ClimbSession, ExecStatus, PlanOutcome, stance_feet_rung,
                      check_request, controller_overrides, ladder_name, scene_goal, with_chosen_strategy)

NODE_NAME = "climb_coordinator"
#: [s] wait for guide_path's subscription to plan/request before a request is published
PLAN_REQUEST_MATCH_S = 10.0
PLAN_STAGES = ("guide_path", "contact_search", "primitive_adaptation")
#: climb/status phase while a stage works on the climb's plan request
PLAN_PHASES = {"guide_path": "guide_path", "contact_search": "contact_search", "primitive_adaptation": "adaptation"}
PLANNING = ("guide_path", "contact_search", "adaptation", "replanning")
#: lifecycle transition ids (lifecycle_msgs/msg/Transition)
CONFIGURE, CLEANUP, ACTIVATE, DEACTIVATE = 1, 2, 3, 4


#: bad messages reported on diagnostics per input topic and second (the others are counted)
INPUT_REPORTS_PER_S = 5


@dataclass(frozen=True)
class CoordinatorParams:
    """The node's parameters (config/nodes/climb_coordinator.yaml holds the same defaults; regenerate it
    with climb_core.params.to_yaml(CoordinatorParams(), "climb_coordinator")). :data:`READ_ONLY` ones
    are read at start-up; the others apply from the next climb (or the next wait) on."""

    robot: str = param("g1", unit="-", description=(
        "robot of a climb request that names none (a robot of config/robots/)"))
    heartbeat_timeout_s: float = param(1.0, unit="s", min=0.05, max=60.0, description=(
        "wall time without controller/state, while sim/contacts goes on, after which the controller is "
        "declared dead (5 times as long, and at least 5 s, with both silent: the bridge)"))
    service_timeout_s: float = param(30.0, unit="s", min=0.1, max=3600.0, description=(
        "wall time one service call of a climb may take (the controller's lifecycle and parameters, "
        "sim/reset), waiting for the service included"))
    plan_wait_margin_s: float = param(300.0, unit="s", min=0.0, max=86400.0, description=(
        "wall time beyond the planning timeout allowed to the whole pipeline for one plan (a loaded machine)"))
    markers_period_s: float = param(1.0, unit="s", min=0.05, max=60.0, description=(
        "wall period of climb/markers (read at start-up)"))
    max_forced_replans: int = param(MAX_FORCED_REPLANS, unit="-", min=0, max=100, description=(
        "replans from the measured state per climb after the controller asks for one (replan_needed)"))
    controller: str = param("controller", unit="-", description=(
        "name of the controller lifecycle node (read at start-up)"))
    bridge: str = param("sim_bridge", unit="-", description="name of the sim_bridge node (read at start-up)")
    bag: str = param("", unit="-", description="path of the graph's bag, reported in the summary (empty: none)")
    reset_sim: bool = param(True, unit="-", description="call sim/reset at the start of each climb (simulation)")


#: parameters the node reads once at start-up (clients, timer): refused at run time
READ_ONLY = ("markers_period_s", "controller", "bridge")
_NODE_NAME_RE = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*(/[A-Za-z_][A-Za-z0-9_]*)*$")


def check_params(p: CoordinatorParams) -> CoordinatorParams:
    """The rules the schema cannot say: a known robot, node names ROS accepts. SpecError naming
    ``climb_coordinator.<parameter>`` and the rule."""
    from climb_core.robot import available_robots

    known = available_robots()
    if p.robot not in known:
        raise SpecError(f"{NODE_NAME}.robot", f"unknown robot {p.robot!r} (known: {', '.join(known)})")
    for name in ("controller", "bridge"):
        value = getattr(p, name)
        if not _NODE_NAME_RE.match(value):
            raise SpecError(f"{NODE_NAME}.{name}", f"must be a ROS node name (letters, digits, _ and /, "
                                                   f"not starting with a digit), got {value!r}")
    return p


def check_controller_state(msg: Any) -> None:
    """A controller/state the coordinator can use (SpecError naming the field otherwise)."""
    if not math.isfinite(msg.tick_time_ms):  # the summary's control_tick_ms figures
        raise SpecError("controller/state.tick_time_ms", "must be finite")


def check_contacts(msg: Any) -> None:
    """A sim/contacts the judge can read: one entry per limb in every array, finite forces."""
    n = len(msg.limbs)
    for name in ("normal_force", "tangential_force", "surface", "rung", "grasped"):
        size = len(getattr(msg, name))
        if size != n:
            raise SpecError(f"sim/contacts.{name}", f"must have one entry per limb ({n}), has {size}")
    for name in ("normal_force", "tangential_force"):
        if not all(math.isfinite(v) for v in getattr(msg, name)):
            raise SpecError(f"sim/contacts.{name}", "must be finite")


def scenario_source(scenario: str) -> tuple[str, str]:
    """(name, text) of a request's scenario: a shipped ladder or scene name stays a name (its file's text is the
    text), a file path becomes its text, YAML text stays text (name "custom" or its `name`)."""
    import pathlib

    from climb_core.ladder import (available_ladders, available_scenes, ladder_config_dir, parse_yaml,
                                   scene_config_dir)

    s = scenario.strip()
    if "\n" not in scenario and s in available_ladders():
        return s, (ladder_config_dir() / f"{s}.yaml").read_text()
    if "\n" not in scenario and s in available_scenes():
        return s, (scene_config_dir() / f"{s}.yaml").read_text()
    if "\n" not in scenario and s.lower().endswith((".yaml", ".yml")):
        path = pathlib.Path(s).expanduser()
        if not path.is_file():
            from climb_core.ros_env import project_root

            path = project_root() / s
        try:
            return path.stem, path.read_text()
        except OSError as exc:
            raise SpecError("scenario", f"cannot read {s}: {exc}") from None
    try:
        doc = parse_yaml(scenario)
        name = str(doc.get("name") or "custom") if isinstance(doc, dict) else "custom"
    except SpecError:
        name = "custom"
    return name, scenario


def request_from_msg(msg: Any, default_robot: str, max_forced_replans: int = MAX_FORCED_REPLANS) -> ClimbRequest:
    """A ClimbRequest from a srv/Climb request or an action goal (same fields)."""
    scenario = msg.scenario or msg.ladder or "default"
    return ClimbRequest(ladder=scenario, robot=msg.robot or default_robot, rungs=int(msg.rungs),
                        mode=msg.controller_mode or "qp", seed=int(msg.seed), bag=False,
                        plan_timeout_s=float(msg.planning_timeout_s) or None, descend=bool(msg.descend),
                        plan_cycles=int(msg.plan_cycles) or None, command_delay_ticks=int(msg.command_delay_ticks),
                        max_forced_replans=max_forced_replans, strategy=getattr(msg, "strategy", ""),
                        start_posture=getattr(msg, "start_posture", ""))


def main(args: list[str] | None = None) -> int:
    from msgs_py.node_kit import run_node

    def executor():
        from rclpy.executors import MultiThreadedExecutor

        return MultiThreadedExecutor(num_threads=4)

    return run_node(lambda: _make_node(), args, executor=executor, name=NODE_NAME)


def _make_node():
    import rclpy
    from climb_msgs.action import Climb as ClimbAction
    from climb_msgs.msg import ClimbStatus, ControllerState, SimContacts, WholeBodyPlan
    from climb_msgs.srv import Cancel, Climb, SimReset
    from diagnostic_msgs.msg import DiagnosticArray
    from lifecycle_msgs.srv import ChangeState, GetState
    from rcl_interfaces.msg import Parameter as ParameterMsg
    from rcl_interfaces.srv import GetParameters, SetParameters
    from rclpy.action import ActionServer, CancelResponse, GoalResponse
    from rclpy.callback_groups import ReentrantCallbackGroup
    from rclpy.node import Node
    from rclpy.parameter import Parameter
    from std_msgs.msg import String
    from std_srvs.srv import Trigger
    from visualization_msgs.msg import MarkerArray

    from msgs_py import cdr
    from msgs_py.node_kit import (SHUTDOWN_ERRORS, SPIN_PERIOD_S, Worker, declare_from_schema, decode, diagnose,
                                  guarded, make_executor, running, safe_publish, set_diagnostics_publisher)
    from msgs_py.stamps import make_header
    from msgs_py.topics import qos_for

    from .settings import load_climb_settings

    class Cancelled(Exception):
        pass

    class ClimbRun:
        """What one climb shares between the worker, the callbacks and the action."""

        def __init__(self, climb_id: str, req: ClimbRequest):
            self.id = climb_id
            self.req = req
            self.cancel = threading.Event()
            self.done = threading.Event()
            self.summary: dict | None = None
            self.phase = "idle"
            self.stage = ""
            self.text = ""
            self.session: ClimbSession | None = None
            self.accepted_at = time.monotonic()
            self.first_command_at: float | None = None

    class CoordinatorNode(Node):
        def __init__(self) -> None:
            super().__init__(NODE_NAME)
            self.group = ReentrantCallbackGroup()
            g = self.group
            # descriptors from the schema; a set_parameters is checked by the schema (type, range)
            # and check_params (known robot, node names) and refused with the reason; READ_ONLY
            # ones are refused at run time (rclpy)
            self.params: CoordinatorParams = check_params(declare_from_schema(
                self, CoordinatorParams, read_only=READ_ONLY, on_change=self._on_params))
            self.cs = load_climb_settings()
            self.worker = Worker(self, "climb")
            self.run: ClimbRun | None = None
            self._lock = threading.Lock()
            self._cond = threading.Condition()
            # latest inputs
            self.state: Any = None  # the newest good controller/state (ControllerState)
            self.state_at = 0.0  # [s] monotonic arrival of the newest controller/state
            self.state_count = 0
            self.contacts: Any = None
            self.contacts_at = 0.0
            self.cone_use: Any = None  # judge.ConeUse of the running climb (fed by sim/contacts)
            self.plans: dict[str, Any] = {}  # request id -> WholeBodyPlan msg
            self.stage_status: dict[str, dict[str, Any]] = {}  # request id -> stage -> (phase, text, t)
            self.tick_ms: list[float] = []
            self._js_reader = cdr.JointStateReader()
            # interfaces
            self.pub_status = self.create_publisher(ClimbStatus, "climb/status", qos_for("climb/status"))
            self.pub_request = self.create_publisher(String, "climb/request", qos_for("climb/request"))
            self.pub_plan_request = self.create_publisher(String, "plan/request", qos_for("plan/request"))
            self.pub_markers = self.create_publisher(MarkerArray, "climb/markers", qos_for("climb/markers"))
            self.pub_description = self.create_publisher(String, "robot_description", qos_for("robot_description"))
            set_diagnostics_publisher(self, self.create_publisher(DiagnosticArray, "diagnostics",
                                                                  qos_for("diagnostics")))
            self._input_reports: dict[str, list] = {}  # topic -> [window start, reported, unreported]
            self._reports_lock = threading.Lock()
            # every subscription raw: bytes that do not decode, or a message that cannot be used,
            # are dropped and reported on diagnostics (_reject_input), never fatal
            self._make_stream_node()
            self._subscribe(ControllerState, "controller/state", self._on_state, check_controller_state,
                            node=self._stream_node)
            self._subscribe(SimContacts, "sim/contacts", self._on_contacts, check_contacts, node=self._stream_node)
            self._subscribe(WholeBodyPlan, "whole_body_plan", self._on_plan)
            for stage in PLAN_STAGES:
                self._subscribe(ClimbStatus, f"{stage}/status", lambda m, s=stage: self._on_stage(s, m))
            self.create_service(Climb, "climb", guarded(self, self._on_climb, "climb"), callback_group=g)
            self.create_service(Cancel, "climb/cancel", guarded(self, self._on_cancel, "cancel"), callback_group=g)
            self.action = ActionServer(self, ClimbAction, "climb", self._execute, callback_group=g,
                                       goal_callback=self._on_goal, cancel_callback=lambda h: CancelResponse.ACCEPT)
            ctl, bridge = self.params.controller, self.params.bridge
            self.cli_change = self.create_client(ChangeState, f"{ctl}/change_state", callback_group=g)
            self.cli_get = self.create_client(GetState, f"{ctl}/get_state", callback_group=g)
            self.cli_set = self.create_client(SetParameters, f"{ctl}/set_parameters", callback_group=g)
            self.cli_hold = self.create_client(Trigger, f"{ctl}/hold", callback_group=g)
            self.cli_reset = self.create_client(SimReset, "sim/reset", callback_group=g)
            self.cli_bridge_params = self.create_client(GetParameters, f"{bridge}/get_parameters", callback_group=g)
            self._ParameterMsg, self._Parameter = ParameterMsg, Parameter
            self._types = {"ChangeState": ChangeState, "GetState": GetState, "SetParameters": SetParameters,
                           "Trigger": Trigger, "SimReset": SimReset, "GetParameters": GetParameters}
            self._marker_scene = None
            self._make_measured_node()
            self.create_timer(self.params.markers_period_s, guarded(self, self._publish_markers, "markers"),
                              callback_group=g)
            try:  # the rung check's primitive library, loaded once now (requests are checked at once)
                check_request(ClimbRequest(robot=self.params.robot, rungs=1))
            except ClimbError as exc:
                self.get_logger().warning(f"default request does not check: {exc}")
            self.status("idle", "ready", climb_id="")
            self.get_logger().info("climb_coordinator ready: service and action `climb`")

        def _on_params(self, params: CoordinatorParams) -> None:
            """A validated change (declare_from_schema's on_change): SpecError refuses it."""
            self.params = check_params(params)

        # ------------------------------------------------------------------ inputs
        def _subscribe(self, cls, topic: str, handle, check=None, node=None) -> None:
            """A raw subscription of ``topic`` (on ``node``, default this one): ``handle(msg)`` for
            each message that decodes as ``cls`` and passes ``check(msg)`` (SpecError otherwise);
            the others are rejected."""

            def received(data: bytes) -> None:
                try:
                    msg = decode(data, cls)
                    if check is not None:
                        check(msg)
                except ValueError as err:  # undecodable (node_kit.decode) or SpecError
                    self._reject_input(topic, err)
                    return
                handle(msg)

            if node is None:
                self.create_subscription(cls, topic, guarded(self, received, topic), qos_for(topic), raw=True,
                                         callback_group=self.group)
            else:
                node.create_subscription(cls, topic, guarded(self, received, topic), qos_for(topic), raw=True)

        # -- the control-rate streams (controller/state, sim/contacts: 200 Hz each) live on a node of
        #    their own, spun by an EventsExecutor in a thread of its own: the main executor
        #    (multi-threaded: the action's execute callback blocks for the whole climb) rebuilds its
        #    wait set of ~40 entities for every message it takes; with the streams on it the
        #    coordinator used ~2.5 ms of CPU per control tick, 35 s over a 70 s climb (measured,
        #    py-spy: 58 % in wait_for_ready_callbacks, 4 % in the callbacks)
        def _make_stream_node(self) -> None:
            self._stream_node = Node(f"{NODE_NAME}_stream", context=self.context, start_parameter_services=False)
            self._stream_exec = make_executor()
            self._stream_exec.add_node(self._stream_node)
            self._stream_thread = threading.Thread(target=self._spin_stream, name="streams", daemon=True)
            self._stream_thread.start()

        def _spin_stream(self) -> None:
            while running(self.context):
                try:
                    self._stream_exec.spin_once(timeout_sec=SPIN_PERIOD_S)
                except SHUTDOWN_ERRORS:  # the context is going away
                    return

        def destroy_node(self) -> None:
            self._stream_thread.join(timeout=2.0)  # running() is False once the process stops
            for step in (lambda: self._stream_exec.shutdown(timeout_sec=1.0), self._stream_node.destroy_node):
                try:
                    step()
                except SHUTDOWN_ERRORS:
                    pass
            super().destroy_node()

        def _reject_input(self, topic: str, err: Exception, level: int = 2) -> None:
            """A bad message: dropped (the last good one stays) and reported on diagnostics as
            ``climb_coordinator/input``, at most INPUT_REPORTS_PER_S per topic and second (the
            others are counted in the next report)."""
            now = time.monotonic()
            with self._reports_lock:
                window = self._input_reports.setdefault(topic, [now, 0, 0])
                if now - window[0] >= 1.0:
                    window[0], window[1] = now, 0
                if window[1] >= INPUT_REPORTS_PER_S:
                    window[2] += 1
                    return
                window[1] += 1
                unreported, window[2] = window[2], 0
            text = f"dropped {topic}: {err}"
            self.get_logger().warning(text)
            diagnose(self, f"{NODE_NAME}/input", text, level=level,
                     values={"topic": topic, "field": getattr(err, "field", topic), "error": type(err).__name__,
                             "dropped_unreported": unreported})

        def _on_state(self, msg) -> None:
            with self._cond:
                self.state = msg
                self.state_at = time.monotonic()
                self.state_count += 1
                self._cond.notify_all()

        def _on_contacts(self, msg) -> None:
            with self._cond:
                self.contacts = msg
                self.contacts_at = time.monotonic()
                if self.cone_use is not None:
                    self.cone_use.add_contacts(msg)
                self._cond.notify_all()

        # -- the measured state (joint_states, sim/base_truth at 200 Hz) is read only when needed
        #    (a sim reset, a replan): its subscriptions live on a second node that only the
        #    worker spins, with its own executor (DDS keeps the newest messages meanwhile; no
        #    subscription is made or destroyed while the main executor spins)
        def _make_measured_node(self) -> None:
            from nav_msgs.msg import Odometry
            from rclpy.executors import SingleThreadedExecutor
            from sensor_msgs.msg import JointState

            self._measured_node = Node(f"{NODE_NAME}_measured", context=self.context)
            self._measured: dict[str, bytes] = {}
            self._measured_count = {"joint_states": 0, "sim/base_truth": 0}
            for topic, kind in (("joint_states", JointState), ("sim/base_truth", Odometry)):
                self._measured_node.create_subscription(
                    kind, topic, guarded(self, lambda d, t=topic: self._on_measured(t, d), topic), qos_for(topic),
                    raw=True)
            self._measured_exec = SingleThreadedExecutor(context=self.context)
            self._measured_exec.add_node(self._measured_node)

        def _on_measured(self, topic: str, data: bytes) -> None:
            try:  # read as the climb reads it (measured_q): bad bytes never replace a good state
                if topic == "joint_states":
                    self._js_reader.read(data)
                else:
                    cdr.read_odometry(data)
            except ValueError as err:  # cdr.CdrError
                self._reject_input(topic, err)
                return
            self._measured[topic] = data
            self._measured_count[topic] += 1

        def drain_measured(self) -> None:
            """Take every measured-state message queued now (the newest one stays)."""
            for _ in range(200):
                n = sum(self._measured_count.values())
                self._measured_exec.spin_once(timeout_sec=0.0)
                if sum(self._measured_count.values()) == n:
                    return

        def wait_message(self, topic: str, timeout: float, accept=None) -> bytes:
            """The newest message of ``topic`` received from now on (raw bytes) for which
            ``accept(bytes)`` holds (default: any)."""
            count0 = self._measured_count[topic]
            deadline = time.monotonic() + timeout
            while True:
                self._measured_exec.spin_once(timeout_sec=0.02)
                self.drain_measured()
                data = self._measured.get(topic)
                if self._measured_count[topic] > count0 and (accept is None or accept(data)):
                    return data
                if time.monotonic() > deadline:
                    raise ClimbError(f"no {topic} within {timeout:.1f} s (is the sim_bridge running?)")

        def _ours(self, request_id: str) -> bool:
            """A plan request id of the running climb (``<climb id>-<attempt>``): products and
            statuses of other requests are not kept."""
            run = self.run
            return run is not None and not run.done.is_set() and request_id.startswith(run.id + "-")

        def _on_plan(self, msg) -> None:
            if not self._ours(msg.request_id):  # the controller may take it: worth a warning
                self._reject_input("whole_body_plan", SpecError(
                    "whole_body_plan.request_id", f"{msg.request_id!r} is no plan request of the running climb"),
                    level=1)
                return
            with self._cond:
                self.plans[msg.request_id] = msg
                self._cond.notify_all()

        def _on_stage(self, stage: str, msg) -> None:
            if not self._ours(msg.id):
                return
            with self._cond:
                self.stage_status.setdefault(msg.id, {})[stage] = (msg.phase, msg.text, time.monotonic())
                self._cond.notify_all()
            run = self.run
            if run is not None:
                run.stage = stage
                if msg.phase not in ("done", "failed") and run.phase in PLANNING:
                    phase = "replanning" if run.phase == "replanning" else PLAN_PHASES[stage]
                    self.status(phase, f"{stage}: {msg.text}"[:200], step=msg.step, n=msg.n_steps,
                                progress=msg.progress)

        def controller_state(self):
            """The newest good controller/state (None before the first one)."""
            return self.state

        # ------------------------------------------------------------------ status
        def status(self, phase: str, text: str = "", climb_id: str | None = None, step: int = 0, n: int = 0,
                   progress: float = 0.0) -> None:
            run = self.run
            cid = climb_id if climb_id is not None else (run.id if run is not None else "")
            if run is not None and climb_id is None:
                run.phase, run.text = phase, text
            msg = ClimbStatus(header=make_header(self.get_clock().now().nanoseconds * 1e-9), id=cid, phase=phase,
                              step=int(step), n_steps=int(n), progress=float(progress), text=text[:20000])
            safe_publish(self.pub_status, msg)

        # ------------------------------------------------------------------ requests
        def check(self, req: ClimbRequest) -> None:
            """Every refusal at once (SpecError with the field and the rule)."""
            scenario = check_request(req)
            for i, drop in enumerate(scenario.perturbation.drops):
                if drop.on_transition or drop.direction:
                    field = "at_transition" if drop.on_transition else "direction"
                    raise SpecError(f"perturbation.drops[{i}].{field}", "drops triggered by a transition or thrown "
                                    "in a direction of their own run in process only (scripts/climb.py --graph "
                                    "inprocess, scripts/campaign.py); through the graph a drop falls straight down "
                                    "at its at_time")
            if req.command_delay_ticks:
                delay = self._bridge_param("lockstep.command_delay_ticks")
                if delay is not None and int(delay) != req.command_delay_ticks:
                    raise SpecError("command_delay_ticks", f"the running bridge has lockstep.command_delay_ticks "
                                                           f"{delay}; start the graph with {req.command_delay_ticks}")

        def _bridge_param(self, name: str):
            req = self._types["GetParameters"].Request(names=[name])
            try:
                res = self.call(self.cli_bridge_params, req, timeout=2.0)
            except ClimbError:
                return None
            if not res.values:
                return None
            v = res.values[0]
            return v.integer_value if v.type == 2 else None

        def start_climb(self, req: ClimbRequest) -> tuple[bool, str, str]:
            """(accepted, id, error): checks, then the climb in the worker."""
            if self.worker.busy:
                running = self.run.id if self.run is not None else "?"
                return False, "", f"busy: climb {running} is running (cancel it with climb/cancel)"
            try:
                req = with_chosen_strategy(req)
                self.check(req)
            except ClimbError as exc:
                return False, "", str(exc)
            if req.strategy_reason:
                self.get_logger().info(f"strategy {req.strategy}: {req.strategy_reason}")
            climb_id = time.strftime("climb-%H%M%S-") + uuid.uuid4().hex[:6]
            run = ClimbRun(climb_id, req)
            with self._lock:
                if self.worker.busy:
                    return False, "", f"busy: climb {self.run.id if self.run else '?'} is running"
                self.run = run
                if not self.worker.submit(lambda: self._climb(run), climb_id):
                    return False, "", "busy: a climb is running"
            return True, climb_id, ""

        def _on_climb(self, request, response):
            req = request_from_msg(request, self.params.robot, self.params.max_forced_replans)
            ok, cid, error = self.start_climb(req)
            response.accepted, response.id, response.error = ok, cid, error
            if not ok:
                self.get_logger().warning(f"climb refused: {error}")
                self.status("failed", f"refused: {error}", climb_id="")
            return response

        def _on_cancel(self, request, response):
            run = self.run
            if run is None or run.done.is_set() or (request.id and request.id != run.id):
                response.accepted = False
                response.error = f"no running climb {request.id!r}" if request.id else "no climb is running"
                return response
            run.cancel.set()
            response.accepted = True
            return response

        # ------------------------------------------------------------------ action
        def _on_goal(self, goal) -> Any:
            return GoalResponse.REJECT if self.worker.busy else GoalResponse.ACCEPT

        def _execute(self, goal_handle):
            goal = goal_handle.request
            req = request_from_msg(goal, self.params.robot, self.params.max_forced_replans)
            ok, cid, error = self.start_climb(req)
            result = ClimbAction.Result()
            if not ok:
                self.status("failed", f"refused: {error}", climb_id="")
                result.failure_reason = f"refused: {error}"
                result.robot, result.mode, result.ladder = req.robot, req.mode, ladder_name(req.ladder)
                result.summary_json = json.dumps({"success": False, "failure_reason": result.failure_reason})
                goal_handle.abort()
                return result
            run = self.run
            while not run.done.wait(0.5):
                if goal_handle.is_cancel_requested:
                    run.cancel.set()
                fb = ClimbAction.Feedback(id=run.id, phase=run.phase, stage=run.stage, text=run.text[:2000])
                s = run.session
                st = self.controller_state() if run.phase in ("executing", "replanning") else None
                if st is not None and s is not None:
                    fb.fsm_state = st.fsm_state
                    fb.stance_index = int(s.done_before + st.transition_index + 1)
                    fb.n_stances = int(s.n_transitions + 1)
                    fb.progress = float(s.progress(st.transition_index))
                try:
                    goal_handle.publish_feedback(fb)
                except Exception:  # noqa: BLE001 - the goal went away
                    pass
            summary = run.summary or {"success": False, "failure_reason": "no summary"}
            fill_result(result, run.id, summary)
            if summary.get("cancelled") and goal_handle.is_cancel_requested:
                goal_handle.canceled()
            elif summary.get("success"):
                goal_handle.succeed()
            else:
                goal_handle.abort()
            return result

        # ------------------------------------------------------------------ service calls
        def call(self, client, request, timeout: float | None = None):
            timeout = self.params.service_timeout_s if timeout is None else timeout
            name = client.srv_name
            if not client.wait_for_service(timeout_sec=timeout):  # a node still starting: its time
                raise ClimbError(f"service {name} is not available (within {timeout:.0f} s)")
            future = client.call_async(request)
            deadline = time.monotonic() + timeout
            while not future.done():
                if time.monotonic() > deadline:
                    client.remove_pending_request(future)
                    raise ClimbError(f"service {name}: no answer within {timeout:.0f} s")
                time.sleep(0.005)
            if future.exception() is not None:
                raise ClimbError(f"service {name}: {future.exception()}")
            return future.result()

        def lifecycle_state(self) -> str:
            return self.call(self.cli_get, self._types["GetState"].Request()).current_state.label

        def change(self, transition: int, what: str) -> None:
            req = self._types["ChangeState"].Request()
            req.transition.id = transition
            if not self.call(self.cli_change, req).success:
                raise ClimbError(f"controller: {what} failed (see the controller's log)")

        def set_controller_params(self, values: dict) -> None:
            from climb_core.params import describe
            from controller_node.params import ControllerParams

            infos = describe(ControllerParams)
            values = {k: (float(v) if k in infos and infos[k].type == "float" and not isinstance(v, bool) else v)
                      for k, v in values.items()}
            params = [self._Parameter(k, value=v).to_parameter_msg() for k, v in values.items()]
            res = self.call(self.cli_set, self._types["SetParameters"].Request(parameters=params))
            for (k, _), r in zip(values.items(), res.results):
                if not r.successful:
                    raise ClimbError(f"controller parameter {k}: {r.reason}")

        # ------------------------------------------------------------------ the climb
        def _climb(self, run: ClimbRun) -> None:
            req = run.req
            summary = None
            try:
                summary = self._climb_steps(run)
            except Cancelled:
                summary = dict(run.session.summary if run.session else {}, success=False, cancelled=True,
                               failure_reason="cancelled")
            except ClimbError as exc:
                self.get_logger().error(f"climb {run.id}: {exc}")
                base = run.session.summary if run.session else {}
                summary = dict(base, success=False, failure_reason=str(exc))
            except Exception as exc:  # noqa: BLE001 - the node keeps serving
                self.get_logger().error(f"climb {run.id} crashed: {type(exc).__name__}: {exc}")
                summary = {"success": False, "failure_reason": f"internal error: {type(exc).__name__}: {exc}"}
            finally:
                if summary is None:
                    summary = {"success": False, "failure_reason": "ended early (shutting down)"}
                from .session import base_summary

                full = base_summary(req)
                full.update(summary)
                full["id"] = run.id
                full["bag"] = full.get("bag") or self.params.bag
                run.summary = full
                phase = "cancelled" if full.get("cancelled") else ("done" if full.get("success") else "failed")
                self.status(phase, json.dumps(full), progress=1.0 if full.get("success") else 0.0)
                self.get_logger().info(f"climb {run.id}: {phase} {full.get('failure_reason', '')}")
                run.done.set()

        def _climb_steps(self, run: ClimbRun) -> dict:
            from climb_core import fixtures  # noqa: F401 - fail early when the core is broken
            from controller_node.params import load_controller_params

            req = run.req
            name, text = scenario_source(req.ladder)
            accepted = {"id": run.id, "robot": req.robot, "scenario": text, "scenario_name": name,
                        "rungs": req.rungs, "mode": req.mode, "seed": req.seed, "descend": req.descend,
                        "plan_cycles": req.plan_cycles or 0, "command_delay_ticks": req.command_delay_ticks,
                        "planning_timeout_s": req.plan_timeout_s or 0.0, "strategy": req.strategy,
                        "start_posture": req.start_posture, "stamp": time.time()}
            safe_publish(self.pub_request, String(data=json.dumps(accepted)))
            self._publish_description(req.robot)
            self._marker_scene = (req.robot, text)
            self.status("idle", "preparing: the controller and the simulator")
            fixture = self._start_fixture(req)
            period = load_controller_params().control_period_s
            overrides = controller_overrides(req, self.cs, period)
            overrides.update({"robot": req.robot, "ladder": text, "initial_stance": fixture})
            self._prepare_controller(overrides)
            if run.cancel.is_set():
                raise Cancelled()
            if self.params.reset_sim:
                self._reset_sim(req, text, fixture)
            plans = RosPlanSource(self, run, name if name in _shipped() else text)
            # the controller is activated once the first plan exists (as the in-process executor
            # starts its runner then): meanwhile the reset world waits at t = 0 for its first
            # command (the bridge's lockstep.reset_wait_s) instead of a lock-step pair spinning a
            # standing robot at full speed on the cores the planners need
            executor = RosExecutor(self, run, start=lambda: self._activate(run))
            self.cone_use = cone_use_for(text, self.cs.cone_force_min)
            judge = RosJudge(self)
            session = ClimbSession(req, self.cs, plans, executor, judge,
                                   say=lambda m: self.get_logger().info(m), on_phase=self._on_phase(run))
            from climb_core.ladder import load_scenario

            goal = scene_goal(load_scenario(text))
            if goal is not None:  # a scene without a ladder: judged on its goal (scene_spec.md)
                session.goal = goal
            run.session = session
            executor.session = session
            return session.run()

        def _reset_sim(self, req: ClimbRequest, text: str, fixture: str) -> None:
            """The simulator reset to the climb's world, its first state (t = 0) published."""
            self.drain_measured()
            res = self.call(self.cli_reset, self._types["SimReset"].Request(
                robot=req.robot, ladder=text, initial_posture=fixture, seed=int(req.seed or 0)))
            if not res.success:
                raise ClimbError(f"sim/reset refused: {res.error}")
            # the new world's first state must reach the controller before it activates (it
            # resets its contacts on the first state it ticks)
            self.wait_message("joint_states", 5.0,
                              accept=lambda d: self._js_reader.read(d).stamp_ns < 500_000_000)
            time.sleep(0.05)

        def _activate(self, run: ClimbRun) -> None:
            """Activate the configured controller: it ticks on the reset world's first state and
            starts the plan it received while inactive on that tick."""
            if run.cancel.is_set():
                raise Cancelled()
            count0 = self.state_count
            self.change(ACTIVATE, "activate")
            self._wait_heartbeat(count0, run)

        def _on_phase(self, run: ClimbRun):
            names = {"planning": "guide_path"}

            def on_phase(phase: str, text: str) -> None:
                if phase in ("done", "failed", "cancelled"):
                    return  # the final status carries the summary
                if phase == "executing":
                    run.stage = "controller"
                self.status(names.get(phase, phase), text)
            return on_phase

        def _start_fixture(self, req: ClimbRequest) -> str:
            """The stance the climb starts in: the request's, else standing (search) or the
            primitive library's start."""
            from planner_node.primitives import load_library
            from planner_node.settings import load_settings

            if req.start_posture:
                return req.start_posture
            if req.strategy == "search":
                return "standing"
            p = load_settings().planning
            return load_library(req.robot, p.strategy, p.primitives_dir).initial_fixture

        def fixture_start(self, req: ClimbRequest):
            """(q, stance) of the request's start posture fixture on the request's scenario."""
            from climb_core import fixtures
            from climb_core.environment import build_environment
            from climb_core.robot import load_robot

            robot = load_robot(req.robot)
            stance, q = fixtures.get(req.start_posture, robot, build_environment(scenario_source(req.ladder)[1]))
            return q, stance

        def _prepare_controller(self, overrides: dict) -> None:
            state = self.lifecycle_state()
            if state == "active":
                self.change(DEACTIVATE, "deactivate")
                state = "inactive"
            if state == "inactive":
                self.change(CLEANUP, "cleanup")
                state = "unconfigured"
            if state != "unconfigured":
                raise ClimbError(f"controller is {state}: cannot configure it")
            self.set_controller_params(overrides)
            self.change(CONFIGURE, "configure")

        def _wait_heartbeat(self, count0: int, run: ClimbRun) -> None:
            timeout = max(5.0, 4 * self.params.heartbeat_timeout_s)
            deadline = time.monotonic() + timeout
            with self._cond:
                while self.state_count <= count0:
                    left = deadline - time.monotonic()
                    if left <= 0:
                        raise ClimbError(f"dead node: no controller/state within {timeout:.1f} s of the "
                                         f"controller's activation (controller or sim_bridge; or a controller "
                                         f"that ignores the states of a reset simulator, whose time restarts at 0)")
                    self._cond.wait(min(left, 0.1))
            st = self.controller_state()
            if st is not None and st.header.stamp.sec > 2:
                raise ClimbError("the controller did not restart with the simulator (its states did not restart "
                                 "near t = 0 after sim/reset)")

        def hold(self) -> str:
            try:
                res = self.call(self.cli_hold, self._types["Trigger"].Request(), timeout=5.0)
                return "" if res.success else res.message
            except ClimbError as exc:
                return str(exc)

        def measured_q(self, joint_names: list[str]) -> np.ndarray:
            self.drain_measured()
            js = self.wait_message("joint_states", 3.0)
            base = self.wait_message("sim/base_truth", 3.0)
            j = self._js_reader.read(js)
            b = cdr.read_odometry(base)
            index = {n: i for i, n in enumerate(j.names)}
            missing = [n for n in joint_names if n not in index]
            if missing:
                raise ClimbError(f"joint_states lacks {missing[0]}")
            q = np.empty(7 + len(joint_names))
            q[:7] = b.pose[:7]
            q[7:] = [j.position[index[n]] for n in joint_names]
            return q

        # ------------------------------------------------------------------ visualisation
        def _publish_description(self, robot: str) -> None:
            from climb_core.robot import load_robot_config

            try:
                urdf = load_robot_config(robot).urdf_path.read_text()
            except (OSError, ClimbError) as exc:
                self.get_logger().warning(f"robot_description: {exc}")
                return
            safe_publish(self.pub_description, String(data=urdf))

        def _publish_markers(self) -> None:
            scene = self._marker_scene
            if scene is None:
                return
            state: dict = {}
            run = self.run
            session = run.session if run is not None else None
            st = self.controller_state() if session is not None and session.current is not None else None
            if st is not None and session.current.transitions:
                t = session.current.transitions[min(int(st.transition_index), len(session.current.transitions) - 1)]
                state["current"], state["next_stance"] = t.stance, t.target_stance
                c = self.contacts
                if c is not None:
                    try:
                        from .markers import environment_of, forces_from_contacts

                        state["forces"] = forces_from_contacts(c.limbs, c.normal_force, c.tangential_force, t.stance,
                                                               environment_of(scene[1]), c.grasped)
                    except ImportError:
                        pass
            msg = build_markers(self, scene, state)
            if msg is not None:
                safe_publish(self.pub_markers, msg)

    # ---------------------------------------------------------------------------- the ports
    class RosPlanSource:
        """Plan source port: plan/request -> guide_path -> contact_search -> primitive_adaptation ->
        whole_body_plan (the controller takes the plan from the same topic)."""

        def __init__(self, node: CoordinatorNode, run: ClimbRun, scenario: str):
            self.node, self.run, self.scenario = node, run, scenario
            self.attempt = 0

        def plan(self, steps: int, start=None, surface_offsets=None) -> PlanOutcome:
            from msgs_py.contact import whole_body_plan_from_msg
            from planner_node.plan_io import stance_to_dict

            node, run, req = self.node, self.run, self.run.req
            self.attempt += 1
            rid = f"{run.id}-{self.attempt}"
            request = {"id": rid, "robot": req.robot, "scenario": self.scenario, "rungs": int(steps),
                       "seed": req.seed, "timeout_s": req.plan_timeout_s, "descend": bool(req.descend),
                       "strategy": req.strategy}
            if start is None and req.strategy == "search" and req.start_posture not in ("", "standing"):
                start = node.fixture_start(req)  # the search starts where the simulator put the robot
            elif start is not None and req.strategy == "search":  # a replan: `steps` rungs above its feet
                request["rungs"] = stance_feet_rung(start[1]) + int(steps)
            if start is not None:
                q, stance = start
                request["start"] = {"q": [float(x) for x in q], "stance": stance_to_dict(stance)}
            if surface_offsets:  # where execution found surfaces: every stage plans in that model
                request["surface_offsets"] = {k: [float(x) for x in v] for k, v in surface_offsets.items()}
            # plan/request is VOLATILE: a request published before guide_path's reader matched is
            # lost (measured once in a fresh-clone run: no stage answered the cancel test's first
            # climb). Wait, bounded, for the match on this side, and let it settle on the other.
            match_by = time.monotonic() + PLAN_REQUEST_MATCH_S
            if node.pub_plan_request.get_subscription_count() == 0:
                while node.pub_plan_request.get_subscription_count() == 0 and time.monotonic() < match_by:
                    time.sleep(0.05)
                time.sleep(0.3)
            t0 = time.monotonic()
            safe_publish(node.pub_plan_request, String(data=json.dumps(request)))
            from planner_node.settings import load_settings

            limit = (req.plan_timeout_s or load_settings().planning.timeout_s) \
                + node.params.plan_wait_margin_s
            deadline = t0 + limit
            failure = ""
            msg = None
            with node._cond:
                while True:
                    msg = node.plans.pop(rid, None)
                    if msg is not None:
                        break
                    stages = node.stage_status.get(rid, {})
                    failed = [(s, t) for s, (ph, t, _) in stages.items() if ph == "failed"]
                    if failed:
                        failure = f"{failed[0][0]}: {failed[0][1]}"
                        break
                    if run.cancel.is_set():
                        raise Cancelled()
                    left = deadline - time.monotonic()
                    if left <= 0:
                        silent = [s for s in PLAN_STAGES if s not in stages]
                        failure = (f"no whole_body_plan within {limit:.0f} s"
                                   + (f" (no status from {', '.join(silent)}: is the node running?)" if silent else ""))
                        break
                    node._cond.wait(min(left, 0.1))
                stages = dict(node.stage_status.pop(rid, {}))
            t_plan = time.monotonic()
            stage_times, prev = {}, t0
            for s in PLAN_STAGES:
                if s in stages and stages[s][0] == "done":
                    stage_times[s] = max(0.0, stages[s][2] - prev)
                    prev = stages[s][2]
            stats: dict = {}
            done = stages.get("primitive_adaptation")
            if done is not None and done[0] == "done":
                try:
                    stats = json.loads(done[1])
                except ValueError:
                    stats = {}
            if "descent_start_transition" in stats:
                stats["descent_start"] = stats["descent_start_transition"]
            if msg is None:
                return PlanOutcome(False, None, t_plan - t0, failure=failure or "no plan", stats=stats,
                                   stages_s=stage_times)
            try:
                plan = whole_body_plan_from_msg(msg)
            except (ClimbError, ValueError) as exc:
                return PlanOutcome(False, None, t_plan - t0, failure=f"whole_body_plan: {exc}")
            stage_times.setdefault("primitive_adaptation", max(0.0, t_plan - prev))
            return PlanOutcome(True, plan, t_plan - t0, 1 + len(plan.transitions), stats=stats,
                               stages_s=stage_times, start_projection_mm=stats.get("start_projection_mm"))

    class RosExecutor:
        """Executor port: the controller node executes the plan it took from whole_body_plan; this
        watches controller/state (heartbeat, FSM, transitions) and sim/contacts (falls)."""

        def __init__(self, node: CoordinatorNode, run: ClimbRun, start=None):
            self.node, self.climb = node, run
            self._start_execution = start  # called once, with the first plan (reset + activate)
            self.session: ClimbSession | None = None
            self.plan = None
            self.t0_wall = time.monotonic()
            self.t0_sim: float | None = None
            self.last = ExecStatus()
            self.ticks: list[float] = []  # [ms] controller tick times (sampled from controller/state)
            self._seen = -1

        def start(self, plan) -> None:
            if self._start_execution is not None:
                start, self._start_execution = self._start_execution, None
                start()
                self.t0_wall = time.monotonic()  # the run's wall time counts from its first command
            self.plan = plan
            self._picked = False
            self._index = -1
            self._start_sim = None

        def _poll(self) -> ExecStatus | None:
            """The newest controller/state as a status (None when none yet)."""
            st = self.node.controller_state()
            if st is None:
                return None
            t = st.header.stamp.sec + st.header.stamp.nanosec * 1e-9
            if self.node.state_count != self._seen:
                self._seen = self.node.state_count
                self.ticks.append(float(st.tick_time_ms))
            if self.t0_sim is None:
                self.t0_sim = t
            c = self.node.contacts
            fell = bool(c.fell) if c is not None else False
            s = ExecStatus(sim_time_s=t, fsm_state=st.fsm_state, transition_index=int(st.transition_index),
                           fell=fell, fall_reason=c.fall_reason if fell else "", qp_failures=int(st.qp_failures))
            if st.fsm_state == "replan_needed":
                s.replan_reason = st.replan_reason
                if st.replan_reason == "contact_offset" and st.offset_surface:
                    s.surface_offset = (st.offset_surface, tuple(float(x) for x in st.surface_offset))
            self.last = s
            return s

        def _wait(self, done, budget_s: float | None) -> ExecStatus:
            node, run = self.node, self.climb
            dead_after = node.params.heartbeat_timeout_s
            seen = node.state_count
            suspect = None  # [s] when the controller first looked dead
            while True:
                with node._cond:
                    if node.state_count == seen:
                        node._cond.wait(0.05)
                    seen = node.state_count
                now = time.monotonic()
                s = self._poll() or ExecStatus()
                if self._start_sim is None:
                    self._start_sim = s.sim_time_s
                if run.cancel.is_set():
                    why = node.hold()
                    s.cancelled = True
                    s.fault = "cancelled" + (f" (controller/hold: {why})" if why else "")
                    return s
                silent = now - node.state_at
                # the controller is dead when the bridge went on without it (in lock-step the
                # bridge steps on alone only once it declared the controller lost); both silent
                # long: the bridge (a machine this loaded is slow, not dead, for a while)
                if silent > dead_after and node.contacts_at > node.state_at + 0.5 * dead_after:
                    # confirmed once the callbacks had time to drain (this thread may have been the
                    # one starved on a loaded machine)
                    if suspect is None:
                        suspect = now
                    elif now - suspect >= 0.2:
                        s.fault = (f"dead node: controller: no controller/state for {silent:.1f} s while the "
                                   f"sim_bridge runs on (heartbeat bound {dead_after:.1f} s)")
                        return s
                else:
                    suspect = None
                if silent > max(5.0, 5.0 * dead_after):
                    s.fault = (f"dead node: sim_bridge (or both): no controller/state and no sim/contacts for "
                               f"{silent:.1f} s")
                    return s
                if s.fell:
                    return s
                if self.session is not None and s.transition_index != self._index and s.fsm_state not in (
                        "idle", "hold", "replan_needed"):
                    self._index = s.transition_index
                    self.session.on_transition(s.transition_index, s.sim_time_s)
                if done(s):
                    return s
                if budget_s is not None and s.sim_time_s - self._start_sim > budget_s:
                    return s

        def run(self, budget_s: float, stop: tuple[str, ...]) -> ExecStatus:
            def done(s: ExecStatus) -> bool:
                if s.fsm_state not in stop and s.fsm_state != "idle":
                    self._picked = True
                    if self.climb.first_command_at is None:  # the controller acts on the first plan
                        self.climb.first_command_at = time.monotonic()
                return s.fsm_state == "failure" or (self._picked and s.fsm_state in stop)
            return self._wait(done, budget_s)

        def settle(self, duration_s: float) -> ExecStatus:
            t_end = [None]

            def done(s: ExecStatus) -> bool:
                if t_end[0] is None:
                    t_end[0] = s.sim_time_s + duration_s
                return s.sim_time_s >= t_end[0]
            return self._wait(done, None)

        def measured_q(self) -> np.ndarray:
            return self.node.measured_q(list(self.plan.joint_names))

        def hold(self) -> None:
            self.node.hold()

        def throw(self, drop, at_time: float) -> None:  # refused up front (ClimbNode.check)
            raise ClimbError("a drop triggered by a transition runs in process only")

        def report(self) -> dict:
            wall = time.monotonic() - self.t0_wall
            sim = self.last.sim_time_s - (self.t0_sim or 0.0)
            r = {"wall_time_s": round(wall, 2), "real_time_factor": round(sim / wall, 3) if wall > 0 else 0.0,
                 "graph": True}
            if self.ticks:
                a = np.asarray(self.ticks)
                r["control_tick_ms"] = {"p50": round(float(np.percentile(a, 50)), 3),
                                        "p99": round(float(np.percentile(a, 99)), 3), "max": round(float(a.max()), 3)}
            cone_use = self.node.cone_use
            if cone_use is not None and cone_use.samples:
                # largest tangential / (mu normal) of each unilateral contact (cone: <= 1)
                r["max_cone_use"] = cone_use.summary()
            run = self.climb
            if run.first_command_at is not None:
                r["coordinator_overhead_s"] = round(run.first_command_at - run.accepted_at, 3)
            return r

    class RosJudge:
        """Judge port: the bridge's sim/contacts (ground truth, sim-only topic)."""

        def __init__(self, node: CoordinatorNode):
            self.node = node

        def _limbs(self) -> dict:
            c = self.node.contacts
            if c is None:
                return {}
            return {limb: (c.normal_force[i], c.surface[i], c.grasped[i]) for i, limb in enumerate(c.limbs)}

        def feet_rungs(self) -> dict:
            from climb_core.contact import FEET

            from .judge import rung_index

            limbs = self._limbs()
            out = {}
            for foot in FEET:
                v = limbs.get(foot)
                out[foot] = rung_index(v[1]) if v is not None and v[0] >= self.node.cs.foot_force_min and v[1] else None
            return out

        def grasps(self) -> dict:
            from climb_core.contact import HANDS

            limbs = self._limbs()
            return {h: (limbs[h][1] if limbs[h][2] else "") for h in HANDS if h in limbs}

        def base(self) -> tuple[np.ndarray, float]:
            """The simulator's base position [m] and linear speed [m/s]: the newest sim/base_truth
            (ground truth, sim-only; NaN when none arrives within 3 s)."""
            from msgs_py import cdr

            try:
                b = cdr.read_odometry(self.node.wait_message("sim/base_truth", 3.0))
            except ClimbError:
                return np.full(3, np.nan), float("nan")
            return np.asarray(b.pose[:3], float), float(np.linalg.norm(b.twist[:3]))

    def _shipped() -> list[str]:
        from climb_core.ladder import available_ladders

        return available_ladders()

    node = CoordinatorNode()
    # the summary's tick figures: controller/state tick_time_ms, sampled by the executor's polls
    return node


def fill_result(result: Any, climb_id: str, summary: dict) -> Any:
    """The action result's typed fields from the JSON summary (+ summary_json)."""
    result.id = climb_id
    result.success = bool(summary.get("success", False))
    result.cancelled = bool(summary.get("cancelled", False))
    result.failure_reason = str(summary.get("failure_reason", ""))
    result.robot = str(summary.get("robot", ""))
    result.ladder = str(summary.get("ladder", ""))
    result.mode = str(summary.get("mode", ""))
    result.rungs_requested = int(summary.get("rungs_requested", 0) or 0)
    result.rungs_reached = int(summary.get("rungs_reached", 0) or 0)
    result.plan_time_s = float(summary.get("plan_time_s", 0.0) or 0.0)
    result.n_stances = int(summary.get("n_stances", 0) or 0)
    result.sim_time_s = float(summary.get("sim_time_s", 0.0) or 0.0)
    result.fell = bool(summary.get("fell", False))
    replans = summary.get("replans", [])
    result.replans = len(replans) if isinstance(replans, list) else int(replans or 0)
    result.bag = str(summary.get("bag", ""))
    result.summary_json = json.dumps(summary)
    return result


def build_markers(node: Any, scene: tuple[str, str], state: dict | None = None):
    """climb/markers: climb_coordinator.markers (the scene, the current and next stance, the
    contact forces with their cones) when present, else the scene's surfaces alone."""
    try:
        from . import markers
    except ImportError:
        markers = None
    if markers is not None and hasattr(markers, "build_markers"):
        try:
            return markers.build_markers(node, scene, **(state or {}))
        except TypeError:
            return markers.build_markers(node, scene)
    return scene_markers(node, scene[1])


_SCENE_CACHE: dict[str, Any] = {}


def cone_use_for(scenario_text: str, force_min: float):
    """A judge.ConeUse with the friction of every surface of the scenario (as simulated)."""
    from .judge import ConeUse
    from .markers import environment_of

    env = environment_of(scenario_text)
    return ConeUse({name: float(s.friction) for name, s in env.surfaces.items()}, force_min)


def scene_markers(node: Any, scenario_text: str):
    """A MarkerArray of the scenario's surfaces (cylinders and boxes in the world frame)."""
    from visualization_msgs.msg import Marker, MarkerArray

    from climb_core.environment import build_environment
    from climb_core.environment import quaternion_xyzw
    from climb_core.ladder import load_scenario

    env = _SCENE_CACHE.get(scenario_text)
    if env is None:
        env = _SCENE_CACHE[scenario_text] = build_environment(load_scenario(scenario_text), perturbed=True)
    out = MarkerArray()
    stamp = node.get_clock().now().to_msg()
    for i, (name, s) in enumerate(sorted(env.surfaces.items())):
        if s.shape == "plane":
            continue
        m = Marker()
        m.header.frame_id = "world"
        m.header.stamp = stamp
        m.ns = "scene"
        m.id = i
        m.action = Marker.ADD
        T = s.T_world_primitive()
        m.type = Marker.CYLINDER if s.shape == "cylinder" else Marker.CUBE
        size = 2.0 * s.primitive_half_extents()
        m.scale.x, m.scale.y, m.scale.z = float(size[0]), float(size[1]), float(size[2])
        p = T[:3, 3]
        m.pose.position.x, m.pose.position.y, m.pose.position.z = float(p[0]), float(p[1]), float(p[2])
        qx, qy, qz, qw = quaternion_xyzw(T[:3, :3])
        m.pose.orientation.x, m.pose.orientation.y, m.pose.orientation.z, m.pose.orientation.w = qx, qy, qz, qw
        m.color.r, m.color.g, m.color.b, m.color.a = (0.8, 0.6, 0.3, 1.0) if s.role == "rung" else (0.5, 0.5, 0.5, 1.0)
        out.markers.append(m)
    return out


if __name__ == "__main__":
    import sys

    sys.exit(main())
