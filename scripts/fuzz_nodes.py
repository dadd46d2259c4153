#!/usr/bin/env python3
"""Fuzz the graph's nodes through their ROS interfaces (issue 20): every subscription and service of
every node gets random well-typed messages (NaN, inf, huge, empty, wrong lengths, unknown names;
hypothesis-generated from the message definitions, and mutations of a valid message) and raw byte
garbage (bytes published on the topic's type). Each node must stay alive, answer every service
call (an error response says why: success False with a message), report bad topic input on
``diagnostics``, and keep serving good input afterwards (a per-node check: the bridge still steps
in lock-step with a live controller, the controller still takes a valid plan, ...).

    .venv/bin/python scripts/fuzz_nodes.py [--nodes sim_bridge,controller] [--examples 200]
                                           [--garbage 50] [--budget-s 600] [--seed 1]

The last line printed is a JSON object of the figures (per node: messages, garbage, calls,
reports, alive, serving, failures; ok). tests/ros/test_fuzz.py runs the same engine with a small
budget. The node table (:data:`NODES`) has one entry per executable; a node is fuzzed when its
entry point exists in its package's setup.py. Inputs are discovered from the running graph
(``get_subscriber_names_and_types_by_node`` / ``get_service_names_and_types_by_node``), minus the
parameter services (tests/ros/test_parameters.py) and the exclusions of the entry.
"""
from __future__ import annotations

import argparse
import importlib
import json
import math
import os
import pathlib
import random
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from typing import Any, Callable

ROOT = pathlib.Path(__file__).resolve().parents[1]
PARAMS = ROOT / "config" / "nodes"

#: rclpy's own services of every node: not fuzzed here (tests/ros/test_parameters.py covers them)
PARAMETER_SERVICES = ("describe_parameters", "get_parameters", "get_parameter_types", "list_parameters",
                      "set_parameters", "set_parameters_atomically", "get_type_description")
#: lifecycle transitions that finalize a node for good (its process must then be restarted):
#: change_state requests carrying them are not sent
FINAL_TRANSITIONS = (5, 6, 7)  # unconfigured / inactive / active -> shutdown


# ----------------------------------------------------------------------------------- the table
@dataclass
class NodeEntry:
    executable: str
    package: str
    node: str
    args: tuple[str, ...] = ()  # ROS arguments; "{tmp}" -> a temporary directory
    exclude: tuple[str, ...] = ()  # regexes of topic / service names not fuzzed
    #: (graph, client) -> None, raises AssertionError when the node no longer serves good input
    serving: Callable[["Graph", "FuzzClient"], None] | None = None
    #: run once the graph is up, before fuzzing, and again before the serving checks (e.g. bring
    #: a lifecycle node back to active after the fuzzed transitions)
    prepare: Callable[["Graph", "FuzzClient"], None] | None = None
    #: ClimbStatus topics on which the node answers bad input too (besides ``diagnostics``)
    status_topics: tuple[str, ...] = ()
    #: False for a node to which no byte string is bad input (the recorder stores any)
    garbage_is_bad: bool = True
    #: True: every bad input must be refused by a check, none may reach the callback guard
    #: (an exception caught by node_kit.guarded fails the node)
    checks_all_input: bool = False


def _bridge_serving(graph: "Graph", c: "FuzzClient") -> None:
    """The bridge still steps and publishes joint_states in lock-step with the live controller
    (answered: controller/state follows; stamps restart at 0 after a fuzzed sim/reset)."""
    n, m = c.count("joint_states"), c.count("controller/state")
    assert c.spin_until(lambda: c.count("joint_states") > n + 40 and c.count("controller/state") > m + 40, 60.0), \
        f"joint_states {c.count('joint_states') - n} / controller/state {c.count('controller/state') - m} in 60 s"


def _controller_prepare(graph: "Graph", c: "FuzzClient") -> None:
    c.ensure_active("controller")


def _controller_serving(graph: "Graph", c: "FuzzClient") -> None:
    """The controller (brought back to active) still answers each state, holds on request, and
    takes a valid plan from there (a plan while a fuzzed one runs is refused: busy)."""
    from climb_msgs.msg import ControllerState, WholeBodyPlan
    from std_srvs.srv import Trigger

    c.ensure_active("controller")
    m = c.count("controller/state")
    assert c.spin_until(lambda: c.count("controller/state") > m + 40, 60.0), "controller/state stopped"
    held = c.call(Trigger, "controller/hold", Trigger.Request())
    if held is not None and not held.success and "failure" in held.message:
        # a fuzzed plan drove the QP into failure: the operator's way out is the lifecycle
        from lifecycle_msgs.msg import Transition
        from lifecycle_msgs.srv import ChangeState

        for step in (Transition.TRANSITION_DEACTIVATE, Transition.TRANSITION_CLEANUP):
            c.call(ChangeState, "controller/change_state", ChangeState.Request(transition=Transition(id=step)), 60.0)
        c.ensure_active("controller")
        assert c.spin_until(lambda: c.count("controller/state") > m + 80, 60.0), "controller/state stopped"
        held = c.call(Trigger, "controller/hold", Trigger.Request())
    assert held is not None and held.success, f"controller/hold: {held.message if held else 'no answer'}"
    # a plan starts from idle, hold or replan_needed: the hold's own jolt may read as a blow on the
    # F/T (measured once under load: brace 0.2 s after the hold, the plan refused as busy), and a
    # brace ends by itself within impact.brace_max_s, so wait for a state that takes a plan
    ready = ("idle", "hold", "replan_needed")
    fsm = lambda: getattr(c.last(ControllerState, "controller/state"), "fsm_state", "")  # noqa: E731
    for _ in range(3):
        assert c.spin_until(lambda: fsm() in ready, 30.0), f"controller in {fsm()!r} for 30 s after the hold"
        n = len(c.reports("controller", "controller/plan"))
        c.publish(WholeBodyPlan, "whole_body_plan", valid_message(WholeBodyPlan))
        assert c.spin_until(lambda: len(c.reports("controller", "controller/plan")) > n, 30.0), "no answer to a plan"
        last = c.reports("controller", "controller/plan")[-1]
        if "accepted" in last.message or "a plan starts from" not in last.message:
            break  # taken, or refused for another reason than busy (a failure below)
    assert last.level == b"\x00" and "accepted" in last.message, last.message


def _status_serving(node: str, topic: str, request_topic: str, request: Callable[[str], str]):
    """A stage answers a new request on its status topic with that request's id."""

    def check(graph: "Graph", c: "FuzzClient") -> None:
        from std_msgs.msg import String

        rid = f"fuzz-check-{random.randrange(1 << 30)}"
        c.publish(String, request_topic, String(data=request(rid)))
        assert c.spin_until(lambda: any(s.id == rid for s in c.statuses(topic)), 60.0), \
            f"{node}: no status for request {rid} on {topic}"
    return check


NODES: list[NodeEntry] = [
    NodeEntry("sim_bridge", "sim_bridge", "sim_bridge",
              ("--params-file", str(PARAMS / "sim_bridge.yaml"), "-p", "initial_posture:=ladder_4_contacts",
               "-p", "max_ticks:=100000000"),
              serving=_bridge_serving),
    NodeEntry("controller", "controller_node", "controller",
              ("--params-file", str(PARAMS / "controller.yaml"), "-p", "initial_stance:=ladder_4_contacts"),
              prepare=_controller_prepare, serving=_controller_serving, checks_all_input=True),
    NodeEntry("primitive_adaptation", "planner_node", "primitive_adaptation",
              serving=_status_serving("primitive_adaptation", "primitive_adaptation/status",
                                      "primitive_adaptation/request",
                                      lambda rid: json.dumps({"id": rid, "steps": -1})),
              status_topics=("primitive_adaptation/status",)),
    NodeEntry("guide_path", "planner_node", "guide_path", status_topics=("guide_path/status",)),
    NodeEntry("contact_search", "planner_node", "contact_search", status_topics=("contact_search/status",)),
    NodeEntry("climb_coordinator", "climb_coordinator", "climb_coordinator",
              exclude=(r"/_action/",), status_topics=("climb/status",)),
    NodeEntry("recorder", "climb_coordinator", "recorder",
              ("-p", "bag_path:={tmp}/bag", "-p", "topics:=[/joint_states]"), garbage_is_bad=False),
]


def entry_point(entry: NodeEntry) -> tuple[str, str] | None:
    """(module, function) of the executable's console script in src/<package>/setup.py, or None."""
    text = (ROOT / "src" / entry.package / "setup.py").read_text()
    m = re.search(rf"[\"']\s*{re.escape(entry.executable)}\s*=\s*([\w.]+)\s*:\s*(\w+)\s*[\"']", text)
    return (m.group(1), m.group(2)) if m else None


def available(names: list[str] | None = None) -> list[NodeEntry]:
    return [e for e in NODES if entry_point(e) is not None and (names is None or e.executable in names)]


# ------------------------------------------------------------------------------ message values
_INT_RANGES = {"int8": (-2 ** 7, 2 ** 7 - 1), "uint8": (0, 2 ** 8 - 1), "int16": (-2 ** 15, 2 ** 15 - 1),
               "uint16": (0, 2 ** 16 - 1), "int32": (-2 ** 31, 2 ** 31 - 1), "uint32": (0, 2 ** 32 - 1),
               "int64": (-2 ** 63, 2 ** 63 - 1), "uint64": (0, 2 ** 64 - 1)}
_NASTY_FLOATS = (math.nan, math.inf, -math.inf, 1e308, -1e308, 1e-308, 0.0, -0.0, 3.4e38)
MAX_SEQ = 12  # typical sequence length drawn (a few draws are huge, HUGE_SEQ)
HUGE_SEQ = 5000


def _vocabulary() -> list[str]:
    """Names a node may know or not: joints of the G1, limbs, surfaces, modes, empty, junk."""
    words = ["", "g1", "talos", "default", "standing", "ladder_4_contacts", "left_hand", "right_hand",
             "left_foot", "right_foot", "third_arm", "rung_1", "rung_6", "rung_99", "rail_left", "ground",
             "qp", "compliance", "banana", "configure", "activate", "../../etc/passwd", "x" * 300,
             "{\"id\": \"fuzz\"}", "{id: 1, steps: 1e9}", "[]", "null", "\u00e9\u4e2d"]
    try:
        from climb_core.robot import load_robot

        words += list(load_robot("g1").joint_names)[:12]
    except Exception:  # noqa: BLE001 - a vocabulary without the joints still fuzzes
        pass
    return words


def _message_class(type_name: str):
    """'pkg/Type' (or 'pkg/msg/Type') -> the message class."""
    parts = type_name.split("/")
    pkg, name = parts[0], parts[-1]
    return getattr(importlib.import_module(f"{pkg}.msg"), name)


_SEQ = re.compile(r"^sequence<(.+?)(?:,\s*(\d+))?>$")
_ARR = re.compile(r"^(.+)\[(\d+)\]$")
_STR = re.compile(r"^w?string(?:<=?(\d+))?$")


def strategy_for(cls, depth: int = 0):
    """A hypothesis strategy of messages of ``cls`` (random values in every field)."""
    from hypothesis import strategies as st

    fields = cls.get_fields_and_field_types()
    parts = {name: _field_strategy(t, depth) for name, t in fields.items()}

    def build(values: dict):
        msg = cls()
        for name, value in values.items():
            try:
                setattr(msg, name, value)
            except (TypeError, ValueError, AssertionError, OverflowError):
                pass  # rclpy refused that value for the field: the default stays
        return msg

    return st.fixed_dictionaries(parts).map(build)


def _field_strategy(t: str, depth: int):
    from hypothesis import strategies as st

    m = _SEQ.match(t)
    if m:
        inner, bound = m.group(1), m.group(2)
        elem = _field_strategy(inner, depth + 1)
        nested = "/" in inner
        size = 3 if nested else MAX_SEQ
        if bound:
            size = min(size, int(bound))
        lists = st.lists(elem, max_size=size if depth < 2 else 1)
        if not nested and not bound:
            lists = st.one_of(lists, st.lists(elem, min_size=HUGE_SEQ, max_size=HUGE_SEQ)
                              if inner not in ("string", "wstring") else lists)
        return lists
    m = _ARR.match(t)
    if m:
        return st.lists(_field_strategy(m.group(1), depth + 1), min_size=int(m.group(2)), max_size=int(m.group(2)))
    m = _STR.match(t)
    if m:
        limit = int(m.group(1)) if m.group(1) else 400
        text = st.text(st.characters(blacklist_categories=("Cs",), blacklist_characters="\x00"), max_size=min(limit, 40))
        return st.one_of(st.sampled_from([w[:limit] for w in _vocabulary()]), text)
    if t in ("double", "float"):
        return st.one_of(st.sampled_from(_NASTY_FLOATS), st.floats(allow_nan=True, allow_infinity=True,
                                                                   width=64 if t == "double" else 32))
    if t in _INT_RANGES:
        lo, hi = _INT_RANGES[t]
        return st.one_of(st.sampled_from([lo, hi, 0, 1]), st.integers(lo, hi))
    if t == "boolean":
        return st.booleans()
    if t in ("octet", "byte"):
        return st.binary(min_size=1, max_size=1)
    if t == "char":
        return st.integers(0, 255)
    if "/" in t:
        if depth > 4:
            return st.just(_message_class(t)())
        return strategy_for(_message_class(t), depth + 1)
    return st.nothing()


_VALID_CACHE: dict[str, bytes] = {}


def valid_message(cls):
    """A valid message of the types the project knows (a plan the controller takes, a state, a
    command...), the default message otherwise: the seed of the mutations (a fresh copy each call)."""
    from rclpy.serialization import deserialize_message, serialize_message

    name = f"{cls.__module__.split('.')[0]}/{cls.__name__}"
    maker = _VALID.get(name)
    if maker is None:
        return cls()
    if name not in _VALID_CACHE:
        _VALID_CACHE[name] = serialize_message(maker())
    return deserialize_message(_VALID_CACHE[name], cls)


def _g1_env():
    from climb_core.environment import build_environment
    from climb_core.ladder import load_scenario
    from climb_core.robot import load_robot

    return load_robot("g1"), build_environment(load_scenario("default"))


def _valid_plan():
    from climb_core import fixtures
    from controller_node.simple_plans import limb_transfer, plan_of
    from msgs_py.contact import whole_body_plan_to_msg

    robot, env = _g1_env()
    stance, q = fixtures.get("ladder_4_contacts", robot, env)
    return whole_body_plan_to_msg(plan_of(robot, env, stance, [limb_transfer(robot, env, stance, q, "right_hand",
                                                                             "rung_6", -0.15)]))


def _valid_joint_state():
    from sensor_msgs.msg import JointState

    robot, _ = _g1_env()
    n = len(robot.joint_names)
    return JointState(name=list(robot.joint_names), position=[0.0] * n, velocity=[0.0] * n, effort=[0.0] * n)


def _valid_joint_command():
    from climb_msgs.msg import JointCommand

    robot, _ = _g1_env()
    n = len(robot.joint_names)
    return JointCommand(names=list(robot.joint_names), modes=bytes([JointCommand.DAMPING] * n)
                        if hasattr(JointCommand, "DAMPING") else bytes(n), values=[0.0] * n)


def _valid_contact_plan():
    from climb_core import fixtures
    from climb_core.contact import ContactPlan
    from msgs_py.contact import contact_plan_to_msg

    robot, env = _g1_env()
    stance, q = fixtures.get("ladder_4_contacts", robot, env)
    return contact_plan_to_msg(ContactPlan(robot="g1", environment="default", joint_names=list(robot.joint_names),
                                           stances=[stance], transition_configurations=[q]))


_VALID: dict[str, Callable[[], Any]] = {
    "climb_msgs/WholeBodyPlan": _valid_plan,
    "climb_msgs/ContactPlan": _valid_contact_plan,
    "sensor_msgs/JointState": _valid_joint_state,
    "climb_msgs/JointCommand": _valid_joint_command,
}


def _leaves(msg, path=()) -> list[tuple]:
    """(path, type) of every field of a message, nested messages and sequences of messages walked
    (path entries: field names and sequence indices)."""
    out = []
    for name, t in msg.get_fields_and_field_types().items():
        value = getattr(msg, name)
        p = path + (name,)
        if "/" in t and not t.startswith("sequence"):
            out += _leaves(value, p)
        elif t.startswith("sequence<") and "/" in t:
            out.append((p, t))
            for i, item in enumerate(value):
                out += _leaves(item, p + (i,))
        else:
            out.append((p, t))
    return out


def mutations(cls):
    """A strategy of valid messages of ``cls`` with 1-3 fields replaced by nasty values (a NaN in a
    plan's configuration, a joint name unknown, a sequence cut or stretched, ...)."""
    from hypothesis import strategies as st

    seed = valid_message(cls)
    leaves = _leaves(seed)
    if not leaves:
        return st.just(seed)

    @st.composite
    def mutate(draw):
        import copy

        msg = copy.deepcopy(seed)
        for _ in range(draw(st.integers(1, 3))):
            path, t = draw(st.sampled_from(leaves))
            try:
                parent = msg
                for key in path[:-1]:
                    parent = parent[key] if isinstance(key, int) else getattr(parent, key)
                name = path[-1]
                current = getattr(parent, name)
                m = _SEQ.match(t)
                if m and "/" not in m.group(1) and len(current) and draw(st.booleans()):
                    values = list(current)  # one element nasty, or the length changed
                    how = draw(st.sampled_from(["element", "cut", "stretch", "empty"]))
                    if how == "element":
                        values[draw(st.integers(0, len(values) - 1))] = draw(_field_strategy(m.group(1), 3))
                    elif how == "cut":
                        values = values[: draw(st.integers(0, len(values) - 1))]
                    elif how == "stretch":
                        values = values + values[: draw(st.integers(1, len(values)))]
                    else:
                        values = []
                    setattr(parent, name, values)
                elif m:  # a sequence of messages: cut, emptied, or one duplicated
                    items = list(current)
                    how = draw(st.sampled_from(["cut", "empty", "duplicate"]))
                    if how == "cut" and items:
                        items = items[: draw(st.integers(0, len(items) - 1))]
                    elif how == "empty":
                        items = []
                    elif items:
                        items.append(copy.deepcopy(items[draw(st.integers(0, len(items) - 1))]))
                    setattr(parent, name, items)
                else:
                    setattr(parent, name, draw(_field_strategy(t, 3)))
            except (TypeError, ValueError, AssertionError, OverflowError, IndexError, AttributeError):
                pass
        return msg

    return mutate()


# ---------------------------------------------------------------------------------- the graph
class Graph:
    """The node processes under test (output in files), started together."""

    def __init__(self, entries: list[NodeEntry], env: dict[str, str] | None = None):
        from climb_core.ros_env import local_dds_env

        self.entries = entries
        self.tmp = tempfile.mkdtemp(prefix="fuzz_")
        self.env = env or local_dds_env()
        self.procs: dict[str, subprocess.Popen] = {}
        self.logs: dict[str, pathlib.Path] = {}
        for e in entries:
            module, function = entry_point(e)
            argv = [sys.executable, "-c", f"import sys; from {module} import {function} as main; sys.exit(main())"]
            args = [a.replace("{tmp}", self.tmp) for a in e.args]
            if args:
                argv += ["--ros-args", *args]
            log = pathlib.Path(self.tmp) / f"{e.executable}.log"
            self.logs[e.executable] = log
            self.procs[e.executable] = subprocess.Popen(argv, env=self.env, cwd=ROOT, stdout=open(log, "wb"),
                                                        stderr=subprocess.STDOUT, start_new_session=True)

    def alive(self, executable: str) -> bool:
        return self.procs[executable].poll() is None

    def tail(self, executable: str, n: int = 2500) -> str:
        try:
            text = self.logs[executable].read_text(errors="replace")
        except OSError:
            text = ""
        return f"--- {executable} (rc {self.procs[executable].poll()}) ---\n{text[-n:]}"

    def close(self) -> dict[str, int]:
        """SIGINT every process, wait; the exit codes."""
        codes = {}
        for name, proc in self.procs.items():
            if proc.poll() is None:
                proc.send_signal(signal.SIGINT)
        for name, proc in self.procs.items():
            try:
                proc.wait(timeout=20)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
            codes[name] = proc.returncode
        return codes

    def cleanup(self) -> None:
        shutil.rmtree(self.tmp, ignore_errors=True)


class FuzzClient:
    """The fuzzer's rclpy node: raw subscriptions only (the fuzz garbage reaches it too), raw
    publishers, service clients."""

    def __init__(self, name: str = "fuzzer"):
        import rclpy
        from rclpy.executors import SingleThreadedExecutor

        self.rclpy = rclpy
        self.context = rclpy.Context()
        rclpy.init(context=self.context)
        self.node = rclpy.create_node(name, context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self._pubs: dict[str, Any] = {}
        self._clients: dict[str, Any] = {}
        self._raw: dict[str, list[bytes]] = {}  # topic -> bytes not decoded yet
        self._counts: dict[str, int] = {}  # topic -> messages received
        self._last: dict[str, bytes] = {}  # topic -> the last message received (raw)
        self._decoded: dict[tuple[str, Any], list] = {}
        from climb_msgs.msg import ClimbStatus, ControllerState
        from diagnostic_msgs.msg import DiagnosticArray
        from sensor_msgs.msg import JointState

        self.watch(DiagnosticArray, "diagnostics")
        self.watch(JointState, "joint_states", keep=False)
        self.watch(ControllerState, "controller/state", keep=False)
        self._status_cls = ClimbStatus

    def close(self) -> None:
        try:
            self.node.destroy_node()
        finally:
            self.rclpy.try_shutdown(context=self.context)

    def _qos(self, topic: str, depth: int | None = None):
        from rclpy.qos import QoSProfile

        from msgs_py.topics import qos_for

        try:
            q = qos_for(topic)
        except KeyError:
            q = qos_for("diagnostics")
        return q if depth is None else QoSProfile(history=q.history, depth=depth, reliability=q.reliability,
                                                   durability=q.durability)

    def watch(self, cls, topic: str, depth: int = 500, keep: bool = True) -> None:
        """Raw subscription; ``keep``: the bytes are kept for :meth:`decoded` (else only counted)."""
        if topic in self._counts:
            return
        self._counts[topic] = 0
        buf: list[bytes] = []
        self._raw[topic] = buf

        def received(data: bytes) -> None:
            self._counts[topic] += 1
            self._last[topic] = data
            if keep:
                buf.append(data)
        self.node.create_subscription(cls, topic, received, self._qos(topic, depth), raw=True)

    def count(self, topic: str) -> int:
        return self._counts.get(topic, 0)

    def last(self, cls, topic: str):
        """The last message of ``topic`` decoded (None: none yet, or the last was garbage)."""
        from rclpy.serialization import deserialize_message

        data = self._last.get(topic)
        try:
            return None if data is None else deserialize_message(data, cls)
        except Exception:  # noqa: BLE001 - the fuzz garbage is on these topics too
            return None

    def decoded(self, cls, topic: str) -> list:
        """The messages of ``topic`` received so far (garbage skipped), decoded once."""
        from rclpy.serialization import deserialize_message

        out = self._decoded.setdefault((topic, cls), [])
        buf = self._raw.get(topic, [])
        pending, buf[:] = list(buf), []
        for data in pending:
            try:
                out.append(deserialize_message(data, cls))
            except Exception:  # noqa: BLE001 - the fuzz garbage is on these topics too
                pass
        return out

    def reports(self, node: str, name: str | None = None) -> list:
        """Diagnostic statuses of ``node`` (hardware_id = the node, or a name under ``node/``)."""
        from diagnostic_msgs.msg import DiagnosticArray

        return [s for d in self.decoded(DiagnosticArray, "diagnostics") for s in d.status
                if (s.hardware_id == node or s.name.startswith(node + "/")) and (name is None or s.name == name)]

    def answers(self, entry: "NodeEntry") -> int:
        """How many reports the node gave so far: diagnostics, and failed statuses on its topics."""
        return len(self.reports(entry.node)) + sum(
            1 for t in entry.status_topics for m in self.statuses(t) if m.phase == "failed")

    def statuses(self, topic: str) -> list:
        self.watch(self._status_cls, topic)
        return self.decoded(self._status_cls, topic)

    def spin(self, seconds: float) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self.executor.spin_once(timeout_sec=min(0.02, max(0.0, end - time.monotonic())))

    def spin_until(self, predicate: Callable[[], bool], timeout: float) -> bool:
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            if predicate():
                return True
            self.executor.spin_once(timeout_sec=0.05)
        return predicate()

    def publisher(self, cls, topic: str):
        if topic not in self._pubs:
            self._pubs[topic] = self.node.create_publisher(cls, topic, self._qos(topic))
        return self._pubs[topic]

    def publish(self, cls, topic: str, msg) -> None:
        self.publisher(cls, topic).publish(msg)

    def call(self, srv_cls, name: str, request, timeout: float = 20.0):
        """The response, or None when the service did not answer within ``timeout``."""
        client = self._clients.get(name)
        if client is None:
            client = self._clients[name] = self.node.create_client(srv_cls, name)
        if not client.wait_for_service(timeout_sec=timeout):
            return None
        future = client.call_async(request)
        self.executor.spin_until_future_complete(future, timeout_sec=timeout)
        if not future.done():
            client.remove_pending_request(future)
            return None
        return future.result()

    def lifecycle_state(self, node: str) -> str:
        from lifecycle_msgs.srv import GetState

        r = self.call(GetState, f"{node}/get_state", GetState.Request())
        return r.current_state.label if r is not None else "?"

    def ensure_active(self, node: str, timeout: float = 90.0) -> None:
        """Drive a lifecycle node to active (configure / activate as needed)."""
        from lifecycle_msgs.msg import Transition
        from lifecycle_msgs.srv import ChangeState

        end = time.monotonic() + timeout
        while time.monotonic() < end:
            state = self.lifecycle_state(node)
            if state == "active":
                return
            step = {"unconfigured": Transition.TRANSITION_CONFIGURE,
                    "inactive": Transition.TRANSITION_ACTIVATE}.get(state)
            if step is None:
                self.spin(0.2)
                continue
            self.call(ChangeState, f"{node}/change_state", ChangeState.Request(transition=Transition(id=step)), 60.0)
        raise AssertionError(f"{node} not active: {self.lifecycle_state(node)}")

    def node_interfaces(self, node: str) -> tuple[list[tuple[str, str]], list[tuple[str, str]]]:
        """(topic, type) of the node's subscriptions and (service, type) of its services, with
        those of its helper node ``<node>_stream`` when it has one (climb_coordinator's 200 Hz
        streams live on a node of their own, in the same process)."""
        subs = [(t, types[0]) for t, types in self.node.get_subscriber_names_and_types_by_node(node, "/")]
        srvs = [(s, types[0]) for s, types in self.node.get_service_names_and_types_by_node(node, "/")]
        helper = f"{node}_stream"
        if helper in self.node.get_node_names():
            subs += [(t, types[0]) for t, types in self.node.get_subscriber_names_and_types_by_node(helper, "/")]
        return subs, srvs


def _service_class(type_name: str):
    pkg, _, name = type_name.split("/")
    return getattr(importlib.import_module(f"{pkg}.srv"), name)


# ---------------------------------------------------------------------------------- the engine
@dataclass
class NodeResult:
    messages: int = 0
    garbage: int = 0
    calls: int = 0
    reports: int = 0
    topics: list[str] = field(default_factory=list)
    services: list[str] = field(default_factory=list)
    alive: bool = True
    serving: bool = True
    failures: list[str] = field(default_factory=list)
    #: distinct exceptions the node's callback guard caught (node_kit.guarded reports them with an
    #: ``exception`` value): survived, but worth a look (a check that should have refused earlier)
    exceptions: list[str] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return self.alive and self.serving and not self.failures


def _garbage(rng: random.Random) -> bytes:
    """Raw bytes: random, a CDR header with random bytes, a truncated or lying header."""
    kind = rng.randrange(4)
    n = rng.choice([0, 1, 3, 17, 64, 1000])
    body = bytes(rng.getrandbits(8) for _ in range(n))
    if kind == 0:
        return body
    if kind == 1:
        return b"\x00\x01\x00\x00" + body
    if kind == 2:
        return b"\x00\x01\x00\x00" + b"\xff\xff\xff\x7f" + body  # a huge sequence / string length
    return b"\x00\x00\x00\x00" + body  # big-endian encapsulation


def fuzz(entries: list[NodeEntry], examples: int = 10, garbage: int = 3, seed: int = 0,
         budget_s: float = 120.0, log: Callable[[str], None] = print, env: dict[str, str] | None = None
         ) -> dict[str, Any]:
    """Start the nodes, fuzz each one's subscriptions and services, check each still serves.
    ``examples`` well-typed messages (half random, half mutations of a valid one) and ``garbage``
    raw byte strings per topic, ``examples`` requests per service, within ``budget_s`` of wall
    time (spread over the inputs). Returns the figures (``ok`` False on any failure)."""
    from hypothesis import HealthCheck, Phase, given, settings
    from hypothesis import seed as hypothesis_seed
    from hypothesis import strategies as st

    t0 = time.monotonic()
    rng = random.Random(seed)
    graph = Graph(entries, env=env)
    client = FuzzClient()
    results: dict[str, NodeResult] = {e.executable: NodeResult() for e in entries}
    for e in entries:
        for topic in e.status_topics:
            client.statuses(topic)  # subscribed from the start
    try:
        # the graph is up when every node lists its parameters
        from rcl_interfaces.srv import ListParameters

        for e in entries:
            up = client.call(ListParameters, f"{e.node}/list_parameters", ListParameters.Request(), timeout=180.0)
            if up is None:
                results[e.executable].alive = graph.alive(e.executable)
                results[e.executable].failures.append(f"never came up\n{graph.tail(e.executable)}")
        for e in entries:
            if e.prepare is not None and not results[e.executable].failures:
                e.prepare(graph, client)
        client.spin(1.0)
        interfaces = {}
        for e in entries:
            subs, srvs = client.node_interfaces(e.node)
            skip = [re.compile(x) for x in e.exclude]
            subs = [(t, ty) for t, ty in subs if not any(x.search(t) for x in skip)]
            srvs = [(s, ty) for s, ty in srvs if s.rsplit("/", 1)[-1] not in PARAMETER_SERVICES
                    and not any(x.search(s) for x in skip)]
            interfaces[e.executable] = (subs, srvs)
            results[e.executable].topics = [t for t, _ in subs]
            results[e.executable].services = [s for s, _ in srvs]
        n_inputs = sum(len(a) + len(b) for a, b in interfaces.values()) or 1
        per_input_s = max(1.0, (budget_s - (time.monotonic() - t0)) / n_inputs)
        for e in entries:
            r = results[e.executable]
            if r.failures:
                continue
            subs, srvs = interfaces[e.executable]
            for topic, type_name in subs:
                if not graph.alive(e.executable):
                    break
                cls = _message_class(type_name)
                pub = client.publisher(cls, topic)
                client.spin_until(lambda: pub.get_subscription_count() > 0, 10.0)
                reports_before = client.answers(e)
                deadline = time.monotonic() + per_input_s
                sent = {"n": 0}

                @settings(max_examples=examples, deadline=None, database=None, phases=[Phase.generate],
                          suppress_health_check=list(HealthCheck))
                @hypothesis_seed(seed)
                @given(st.one_of(strategy_for(cls), mutations(cls)))
                def send(msg):
                    if time.monotonic() > deadline:
                        return
                    try:
                        pub.publish(msg)
                        sent["n"] += 1
                    except Exception:  # noqa: BLE001 - rclpy refused to serialize it: not sent
                        return
                    client.spin(0.005)

                send()
                r.messages += sent["n"]
                for _ in range(garbage):
                    pub.publish(_garbage(rng))
                    r.garbage += 1
                    client.spin(0.01)
                if garbage and e.garbage_is_bad and \
                        not client.spin_until(lambda: client.answers(e) > reports_before, 8.0):
                    r.failures.append(f"{topic}: {garbage} garbage messages, no diagnostic / failed status "
                                      f"from {e.node}")
                client.spin(0.2)
                if not graph.alive(e.executable):
                    r.alive = False
                    r.failures.append(f"died on {topic}\n{graph.tail(e.executable)}")
                    break
                r.reports += client.answers(e) - reports_before
            for service, type_name in srvs:
                if not graph.alive(e.executable):
                    break
                srv = _service_class(type_name)
                deadline = time.monotonic() + per_input_s
                calls = {"n": 0}

                @settings(max_examples=examples, deadline=None, database=None, phases=[Phase.generate],
                          suppress_health_check=list(HealthCheck))
                @hypothesis_seed(seed)
                @given(st.one_of(strategy_for(srv.Request), mutations(srv.Request)))
                def call(request):
                    if time.monotonic() > deadline:
                        return
                    if type_name == "lifecycle_msgs/srv/ChangeState" and request.transition.id in FINAL_TRANSITIONS:
                        request.transition.id = 255  # never finalize the node: an invalid id instead
                    try:
                        response = client.call(srv, service, request, timeout=30.0)
                    except Exception:  # noqa: BLE001 - rclpy refused to serialize the request
                        return
                    calls["n"] += 1
                    if response is None:
                        r.failures.append(f"{service}: no answer to {str(request)[:300]}")
                        return
                    if getattr(response, "success", True) is False:
                        text = getattr(response, "message", "") or getattr(response, "error", "")
                        if not text and type_name != "lifecycle_msgs/srv/ChangeState":
                            r.failures.append(f"{service}: refused without a reason: {str(request)[:300]}")

                call()
                r.calls += calls["n"]
                if not graph.alive(e.executable):
                    r.alive = False
                    r.failures.append(f"died on {service}\n{graph.tail(e.executable)}")
            log(f"{e.executable}: {r.messages} messages, {r.garbage} garbage, {r.calls} calls, "
                f"{r.reports} reports, {len(r.failures)} failures")
        # every node still serves good input (lifecycle nodes first brought back to active)
        for e in entries:
            if e.prepare is not None and graph.alive(e.executable):
                try:
                    e.prepare(graph, client)
                except AssertionError as err:
                    results[e.executable].failures.append(f"cannot be brought back: {err}")
        for e in entries:
            r = results[e.executable]
            r.alive = r.alive and graph.alive(e.executable)
            if not r.alive:
                r.serving = False
                continue
            try:
                if e.serving is not None:
                    e.serving(graph, client)
                else:
                    up = client.call(ListParameters, f"{e.node}/list_parameters", ListParameters.Request())
                    assert up is not None, "list_parameters does not answer"
            except AssertionError as err:
                r.serving = False
                r.failures.append(f"not serving good input: {err}\n{graph.tail(e.executable)}")
        for e in entries:
            seen = []
            for status in client.reports(e.node):
                if any(kv.key == "exception" for kv in status.values):
                    text = f"{status.name}: {status.message[:160]}"
                    if text not in seen:
                        seen.append(text)
            results[e.executable].exceptions = seen
            if seen and e.checks_all_input:
                results[e.executable].failures.append("exceptions reached the callback guard: " + "; ".join(seen))
    finally:
        client.close()
        codes = graph.close()
        graph.cleanup()
    for name, code in codes.items():
        if code != 0 and results[name].alive:
            results[name].failures.append(f"exit code {code} on SIGINT")
    figures = {"nodes": {name: {"messages": r.messages, "garbage": r.garbage, "calls": r.calls, "reports": r.reports,
                                "topics": r.topics, "services": r.services, "alive": r.alive, "serving": r.serving,
                                "exit_code": codes.get(name), "failures": r.failures, "exceptions": r.exceptions}
                         for name, r in results.items()},
               "seconds": round(time.monotonic() - t0, 1), "seed": seed, "examples": examples, "garbage": garbage}
    figures["ok"] = all(r.ok for r in results.values()) and all(c == 0 for c in codes.values())
    return figures


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--nodes", default="", help="comma-separated executables (default: every available one)")
    parser.add_argument("--examples", type=int, default=200, help="well-typed messages per topic / calls per service")
    parser.add_argument("--garbage", type=int, default=50, help="raw garbage messages per topic")
    parser.add_argument("--budget-s", type=float, default=900.0, help="wall-time budget of the fuzzing")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    from climb_core.ros_env import apply_local_dds_env

    apply_local_dds_env()
    names = [n for n in args.nodes.split(",") if n] or None
    entries = available(names)
    if not entries:
        print("no node to fuzz", file=sys.stderr)
        return 2
    figures = fuzz(entries, args.examples, args.garbage, args.seed, args.budget_s,
                   log=lambda text: print(text, flush=True))
    for name, f in figures["nodes"].items():
        for failure in f["failures"]:
            print(f"FAIL {name}: {failure}", flush=True)
    print(json.dumps(figures))
    return 0 if figures["ok"] else 1


if __name__ == "__main__":
    sys.exit(main())
