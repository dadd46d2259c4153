"""msgs_py.node_kit and msgs_py.topics: parameters from a schema, guarded callbacks, the worker,
run_node's exit codes and its signal handling (in child processes), the QoS table."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import threading
import time
from dataclasses import dataclass

import pytest

from climb_core.errors import SpecError
from climb_core.params import group, param

TIMEOUT_S = 60.0  # [s] generous bound on a child's life on a busy 2-core machine


@dataclass(frozen=True)
class Inner:
    gain: float = param(2.0, unit="N m/rad", description="a gain", min=0.0, max=10.0)
    names: tuple[str, ...] = param((), unit="-", description="an empty string list")


@dataclass(frozen=True)
class Schema:
    rate_hz: float = param(200.0, unit="Hz", description="loop rate", min=1.0)
    count: int = param(3, unit="-", description="a count", min=0, max=5)
    delay: int = param(0, unit="-", description="a choice of integers", choices=(0, 1))
    mode: str = param("qp", unit="-", description="the mode", choices=("qp", "compliance"))
    flag: bool = param(False, unit="-", description="a flag")
    inner: Inner = group(Inner, "a group")

    def __post_init__(self) -> None:
        if self.mode == "compliance" and self.count == 0:
            raise SpecError("schema.count", "must be > 0 in compliance mode")


@pytest.fixture()
def context():
    import rclpy

    ctx = rclpy.Context()
    rclpy.init(context=ctx)
    yield ctx
    rclpy.try_shutdown(context=ctx)


def make_node(context, name="kit_test", overrides=()):
    import rclpy
    from rclpy.parameter import Parameter

    return rclpy.create_node(name, context=context,
                             parameter_overrides=[Parameter(n, value=v) for n, v in overrides])


def set_param(node, name, value):
    from rclpy.parameter import Parameter

    return node.set_parameters([Parameter(name, value=value)])[0]


# ------------------------------------------------------------------------------------- topics
def test_qos_table():
    from rclpy.qos import DurabilityPolicy, ReliabilityPolicy

    from msgs_py.topics import QOS_TABLE, lookup, qos_for

    assert {q.reliability for q in QOS_TABLE.values()} == {"reliable"}
    latched = {name for name, q in QOS_TABLE.items() if q.durability == "transient_local"}
    assert latched == {"climb/request", "robot_description"}
    assert qos_for("climb/request").durability == DurabilityPolicy.TRANSIENT_LOCAL
    assert qos_for("joint_states").durability == DurabilityPolicy.VOLATILE
    assert qos_for("joint_states").reliability == ReliabilityPolicy.RELIABLE
    assert lookup("ft/left_wrist") is QOS_TABLE["ft/<sensor>"]
    assert lookup("guide_path/status") is QOS_TABLE["<stage>/status"]
    assert lookup("/replay/joint_states") is QOS_TABLE["joint_states"]  # under a namespace
    assert qos_for("/clock").depth == 1
    with pytest.raises(KeyError, match="no_such_topic"):
        lookup("no_such_topic")


# ---------------------------------------------------------------------------------- parameters
def test_descriptors_carry_unit_range_choices(context):
    from rcl_interfaces.msg import ParameterType

    from msgs_py.node_kit import declare_from_schema

    node = make_node(context)
    try:
        settings = declare_from_schema(node, Schema, read_only=("flag",))
        assert settings == Schema()
        d = node.describe_parameters(["rate_hz", "count", "mode", "flag", "inner.gain", "inner.names"])
        rate, count, mode, flag, gain, names = d
        assert "[Hz]" in rate.description and rate.type == ParameterType.PARAMETER_DOUBLE
        assert rate.floating_point_range[0].from_value == 1.0
        assert rate.floating_point_range[0].to_value == float("inf")
        assert (count.integer_range[0].from_value, count.integer_range[0].to_value) == (0, 5)
        assert "qp" in mode.additional_constraints and "compliance" in mode.description
        assert flag.read_only and not rate.read_only
        assert "[N m/rad]" in gain.description and gain.floating_point_range[0].to_value == 10.0
        assert names.type == ParameterType.PARAMETER_STRING_ARRAY
        # an empty array is initialized (rclpy's get_parameters service answers nothing at all for
        # a request naming an uninitialized parameter)
        assert [list(p.value) for p in node.get_parameters(["inner.names"])] == [[]]
        delay = node.describe_parameters(["delay"])[0]  # numeric choices give the range too
        assert (delay.integer_range[0].from_value, delay.integer_range[0].to_value) == (0, 1)
    finally:
        node.destroy_node()


def test_overrides_are_parsed_and_bad_overrides_refused(context):
    from rclpy.exceptions import ParameterException

    from msgs_py.node_kit import declare_from_schema

    node = make_node(context, "kit_over", [("rate_hz", 50.0), ("inner.names", ["a", "b"])])
    try:
        settings = declare_from_schema(node, Schema, Schema(count=4))
        assert settings.rate_hz == 50.0 and settings.count == 4 and settings.inner.names == ("a", "b")
    finally:
        node.destroy_node()
    # a cross-field rule (the schema's __post_init__) at start-up: SpecError, not a half-made node
    node = make_node(context, "kit_bad", [("mode", "compliance"), ("count", 0)])
    try:
        with pytest.raises(SpecError, match="compliance"):
            declare_from_schema(node, Schema)
    finally:
        node.destroy_node()
    node = make_node(context, "kit_range", [("count", 9)])
    try:
        with pytest.raises((SpecError, ParameterException)):
            declare_from_schema(node, Schema)
    finally:
        node.destroy_node()


def test_set_parameters_validated_like_the_yaml(context):
    from msgs_py.node_kit import declare_from_schema

    changes = []
    node = make_node(context, "kit_set")
    try:
        declare_from_schema(node, Schema, read_only=("flag",), on_change=changes.append)
        ok = set_param(node, "rate_hz", 100.0)
        assert ok.successful, ok.reason
        assert changes[-1].rate_hz == 100.0
        for name, value, words in [("rate_hz", -5.0, "rate_hz"), ("rate_hz", float("nan"), "rate_hz"),
                                   ("mode", "banana", "one of"), ("count", 7, "count"),
                                   ("rate_hz", "fast", "type"), ("flag", True, "flag"),
                                   ("inner.gain", 11.0, "inner.gain")]:
            result = set_param(node, name, value)
            assert not result.successful, (name, value)
            assert words in result.reason, (name, value, result.reason)
        # a cross-field rule of the schema, as the YAML loader applies it
        assert set_param(node, "count", 0).successful
        result = set_param(node, "mode", "compliance")
        assert not result.successful and "compliance mode" in result.reason
        assert node.get_parameter("mode").value == "qp" and node.get_parameter("rate_hz").value == 100.0
        # parameters of other schemas / the node's own are left to their owners
        node.declare_parameter("other", 1)
        assert set_param(node, "other", 2).successful
    finally:
        node.destroy_node()


def test_prefix_and_two_schemas_on_one_node(context):
    from msgs_py.node_kit import declare_from_schema

    node = make_node(context, "kit_prefix")
    try:
        a = declare_from_schema(node, Inner, prefix="left.")
        b = declare_from_schema(node, Schema, read_only=True)
        assert a == Inner() and b == Schema()
        assert not set_param(node, "left.gain", -1.0).successful
        assert set_param(node, "left.gain", 3.0).successful
        assert "read-only" in set_param(node, "rate_hz", 10.0).reason.lower()
        assert node.describe_parameters(["inner.names"])[0].read_only  # an empty array read-only too
        assert "read-only" in set_param(node, "inner.names", ["x"]).reason.lower()
    finally:
        node.destroy_node()


# ------------------------------------------------------------------------------- guarded, worker
def test_guarded_callbacks_report_and_survive(context):
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.executors import SingleThreadedExecutor
    from std_srvs.srv import Trigger

    from msgs_py.node_kit import guarded

    node = make_node(context, "kit_guard")
    seen = []
    try:
        node.create_subscription(DiagnosticArray, "diagnostics", seen.append, 50)
        sub_cb = guarded(node, lambda msg: 1 / 0, "on_thing")
        assert sub_cb("message") is None
        srv_cb = guarded(node, lambda req, res: [][1], "on_service")
        response = srv_cb(Trigger.Request(), Trigger.Response(success=True))
        assert response.success is False and "IndexError" in response.message
        assert guarded(node, lambda x: x + 1, "fine")(1) == 2
        executor = SingleThreadedExecutor(context=context)
        executor.add_node(node)
        deadline = time.monotonic() + 10
        while len(seen) < 2 and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.1)
        executor.shutdown()
        names = [s.name for msg in seen for s in msg.status]
        assert names == ["kit_guard/on_thing", "kit_guard/on_service"], names
        assert "ZeroDivisionError" in seen[0].status[0].message
    finally:
        node.destroy_node()


def test_worker_one_job_at_a_time():
    from msgs_py.node_kit import Worker

    errors = []
    worker = Worker(on_error=lambda rid, err: errors.append((rid, type(err).__name__)))
    release = threading.Event()
    assert not worker.busy and worker.current_id is None
    assert worker.submit(release.wait, "first")
    assert worker.busy and worker.current_id == "first"
    assert not worker.submit(lambda: None, "second")  # refused while busy: the caller names "second"
    assert worker.current_id == "first"
    release.set()
    assert worker.join(10.0) and not worker.busy and worker.current_id is None
    assert worker.submit(lambda: 1 / 0, "bad")
    assert worker.join(10.0)
    assert errors == [("bad", "ZeroDivisionError")]
    assert worker.submit(lambda: None, "after") and worker.join(10.0)


def test_safe_publish_after_shutdown():
    import rclpy
    from std_msgs.msg import String

    from msgs_py import node_kit

    ctx = rclpy.Context()
    rclpy.init(context=ctx)
    node = rclpy.create_node("kit_pub", context=ctx)
    pub = node.create_publisher(String, "kit_pub_topic", 10)
    assert node_kit.safe_publish(pub, String(data="a"))
    node.destroy_node()
    rclpy.try_shutdown(context=ctx)
    # the default context is not up in this process: rclpy.ok() is False -> swallowed
    assert node_kit.safe_publish(pub, String(data="b")) is False


# ------------------------------------------------------------------------- run_node (children)
CHILD = textwrap.dedent("""
    import sys, time, threading
    from climb_core.ros_env import install_signal_handlers
    install_signal_handlers()  # first: what follows stands for an executable's heavy imports
    mode = sys.argv[1]
    if mode == "slow_import":
        print("ready", flush=True)
        time.sleep(3.0)
    from msgs_py import node_kit
    from climb_core.errors import SpecError
    import rclpy
    from std_msgs.msg import String
    from rclpy.node import Node

    class Talker(Node):
        def __init__(self):
            super().__init__("kit_child")
            self.pub = self.create_publisher(String, "kit_child_chatter", 10)
            self.create_timer(0.001, lambda: self.pub.publish(String(data="x" * 1000)))
            # a thread that keeps publishing through the shutdown (the race of issue 20, row 1)
            threading.Thread(target=self.spam, daemon=True).start()
            print("ready", flush=True)

        def spam(self):
            while True:
                node_kit.safe_publish(self.pub, String(data="y"))

    def factory():
        if mode == "climb_error":
            raise SpecError("kit_child.robot", "unknown robot 'banana'")
        if mode == "bug":
            raise RuntimeError("a bug")
        if mode == "slow_factory":
            print("ready", flush=True)
            time.sleep(3.0)
        if mode == "busy_thread":  # a long job in a non-daemon thread (an executor pool's callback)
            threading.Thread(target=time.sleep, args=(120.0,), daemon=False).start()
            worker = node_kit.Worker(name="planner")
            worker.submit(lambda: time.sleep(120.0), "long")
        return Talker()

    sys.exit(node_kit.run_node(factory, sys.argv, name="kit_child"))
""")


def run_child(mode, sig=None, delay=0.0, timeout=TIMEOUT_S, ros_args=()):
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    env.pop("_ROS_WHEELS_BOOTSTRAP_COMPLETE", None)
    child = subprocess.Popen([sys.executable, "-c", CHILD, mode, *ros_args], stdout=subprocess.PIPE,
                             stderr=subprocess.PIPE, text=True, env=env)
    try:
        if sig is not None:
            line = child.stdout.readline()
            assert line.strip() == "ready", (line, child.stderr.read() if child.poll() is not None else "")
            time.sleep(delay)
            child.send_signal(sig)
        out, err = child.communicate(timeout=timeout)
    finally:
        if child.poll() is None:
            child.kill()
            child.wait()
    return child.returncode, err


def test_run_node_exit_codes():
    code, err = run_child("climb_error")
    assert code == 2 and "kit_child: kit_child.robot: unknown robot 'banana'" in err and "Traceback" not in err
    code, err = run_child("bug")
    assert code == 1 and "RuntimeError: a bug" in err
    code, err = run_child("talk", ros_args=("--ros-args", "-p", "no_value_here"))
    assert code == 2 and "kit_child: cannot start ROS" in err and "Traceback" not in err


@pytest.mark.parametrize("sig,delay,mode", [(signal.SIGINT, 0.05, "talk"), (signal.SIGTERM, 0.3, "talk"),
                                            (signal.SIGTERM, 0.5, "slow_factory"),
                                            (signal.SIGINT, 0.0, "slow_factory"),
                                            (signal.SIGINT, 0.2, "slow_import"),
                                            (signal.SIGTERM, 0.2, "slow_import"),
                                            (signal.SIGTERM, 0.3, "busy_thread")])
def test_run_node_signal_exits_zero(sig, delay, mode):
    code, err = run_child(mode, sig, delay, timeout=40.0)  # a thread still running must not hold the exit
    assert code == 0, err
    assert "Traceback" not in err, err
