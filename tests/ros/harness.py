"""Helpers for the ROS tests that start node processes and talk to them from the test process.

``NodeProcess`` starts an executable (``python -m module`` or an installed script) with the
loopback DDS environment, its output in a file (a full pipe would block the node), and stops it
with a signal, checking the exit code. ``Client`` is an rclpy node in a private Context of the
test process: service calls, publishers (also raw bytes), subscriptions that collect, spinning
until a predicate holds, all with generous timeouts (the machine is shared and slow).
"""
from __future__ import annotations

import os
import pathlib
import signal
import subprocess
import sys
import tempfile
import time
from typing import Any, Callable

ROOT = pathlib.Path(__file__).resolve().parents[2]
PARAMS = ROOT / "config" / "nodes"


class NodeProcess:
    """A node process; ``output()`` is what it printed so far."""

    def __init__(self, argv: list[str], env: dict[str, str] | None = None, name: str = "node"):
        from climb_core.ros_env import local_dds_env

        self.name = name
        self.argv = argv
        self._log = tempfile.NamedTemporaryFile(prefix=f"{name}_", suffix=".log", delete=False)
        self.proc = subprocess.Popen(argv, env=env or local_dds_env(), cwd=ROOT, stdout=self._log,
                                     stderr=subprocess.STDOUT, start_new_session=True)

    @classmethod
    def module(cls, module: str, *ros_args: str, name: str | None = None, env=None) -> "NodeProcess":
        argv = [sys.executable, "-m", module]
        if ros_args:
            argv += ["--ros-args", *ros_args]
        return cls(argv, env=env, name=name or module.rsplit(".", 1)[-1])

    @property
    def pid(self) -> int:
        return self.proc.pid

    def alive(self) -> bool:
        return self.proc.poll() is None

    def output(self) -> str:
        try:
            return pathlib.Path(self._log.name).read_text(errors="replace")
        except OSError:
            return ""

    def tail(self, n: int = 3000) -> str:
        return f"--- {self.name} (rc {self.proc.poll()}) ---\n" + self.output()[-n:]

    def stop(self, sig: int = signal.SIGINT, timeout: float = 20.0) -> int:
        """Signal the process, wait; kill it after ``timeout``. Returns the exit code."""
        if self.proc.poll() is None:
            try:
                self.proc.send_signal(sig)
                self.proc.wait(timeout=timeout)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        return self.proc.returncode

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait()

    def close(self) -> None:
        self.kill()
        try:
            self._log.close()
            os.unlink(self._log.name)
        except OSError:
            pass


class Client:
    """An rclpy node of the test process, in its own Context (call ``close()``)."""

    def __init__(self, name: str = "test_client"):
        import rclpy
        from rclpy.executors import SingleThreadedExecutor

        self.rclpy = rclpy
        self.context = rclpy.Context()
        rclpy.init(context=self.context)
        self.node = rclpy.create_node(name, context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self._clients: dict[tuple[Any, str], Any] = {}
        self._pubs: dict[tuple[Any, str], Any] = {}

    def close(self) -> None:
        try:
            self.node.destroy_node()
        finally:
            self.rclpy.try_shutdown(context=self.context)

    # -- spinning
    def spin(self, seconds: float) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self.executor.spin_once(timeout_sec=min(0.05, max(0.0, end - time.monotonic())))

    def spin_until(self, predicate: Callable[[], bool], timeout: float, watch: list[NodeProcess] = ()) -> bool:
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            if predicate():
                return True
            self.executor.spin_once(timeout_sec=0.05)
            for proc in watch:
                assert proc.alive(), proc.tail()
        return predicate()

    # -- topics
    def qos(self, topic: str):
        from msgs_py.topics import qos_for

        return qos_for(topic)

    def subscribe(self, msg_type, topic: str, depth: int | None = None, raw: bool = False) -> list:
        from rclpy.qos import QoSProfile

        qos = self.qos(topic)
        if depth is not None:
            qos = QoSProfile(history=qos.history, depth=depth, reliability=qos.reliability,
                             durability=qos.durability)
        received: list = []
        self.node.create_subscription(msg_type, topic, received.append, qos, raw=raw)
        return received

    def publisher(self, msg_type, topic: str):
        key = (msg_type, topic)
        if key not in self._pubs:
            self._pubs[key] = self.node.create_publisher(msg_type, topic, self.qos(topic))
        return self._pubs[key]

    def wait_matched(self, msg_type, topic: str, timeout: float = 30.0, watch=()) -> bool:
        pub = self.publisher(msg_type, topic)
        ok = self.spin_until(lambda: pub.get_subscription_count() > 0, timeout, watch)
        self.spin(0.3)  # the match settles on the other side too
        return ok

    def publish(self, msg_type, topic: str, msg) -> None:
        """``msg`` an instance of ``msg_type`` or raw CDR bytes."""
        self.publisher(msg_type, topic).publish(msg)

    # -- services
    def client(self, srv_type, name: str):
        key = (srv_type, name)
        if key not in self._clients:
            self._clients[key] = self.node.create_client(srv_type, name)
        return self._clients[key]

    def wait_service(self, srv_type, name: str, timeout: float = 30.0) -> bool:
        client = self.client(srv_type, name)
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            if client.service_is_ready():
                return True
            self.executor.spin_once(timeout_sec=0.1)
        return client.service_is_ready()

    def call(self, srv_type, name: str, request=None, timeout: float = 30.0):
        """The response, or None after ``timeout`` (the node did not answer)."""
        client = self.client(srv_type, name)
        assert self.wait_service(srv_type, name, timeout), f"service {name} not available"
        future = client.call_async(request if request is not None else srv_type.Request())
        self.executor.spin_until_future_complete(future, timeout_sec=timeout)
        if not future.done():
            client.remove_pending_request(future)
            return None
        return future.result()

    # -- parameters (rcl_interfaces services of the node ``target``)
    def describe_parameters(self, target: str, names: list[str] | None = None) -> dict[str, Any]:
        from rcl_interfaces.srv import DescribeParameters, ListParameters

        if names is None:
            listed = self.call(ListParameters, f"{target}/list_parameters", ListParameters.Request())
            assert listed is not None, f"{target}/list_parameters did not answer"
            names = list(listed.result.names)
        response = self.call(DescribeParameters, f"{target}/describe_parameters",
                             DescribeParameters.Request(names=names))
        assert response is not None, f"{target}/describe_parameters did not answer"
        return {d.name: d for d in response.descriptors}

    def get_parameters(self, target: str, names: list[str]) -> dict[str, Any]:
        from rcl_interfaces.srv import GetParameters
        from rclpy.parameter import parameter_value_to_python

        response = self.call(GetParameters, f"{target}/get_parameters", GetParameters.Request(names=names))
        assert response is not None, f"{target}/get_parameters did not answer"
        return {n: parameter_value_to_python(v) for n, v in zip(names, response.values)}

    def set_parameters(self, target: str, values: dict[str, Any]) -> list:
        """SetParametersResult per parameter (each set separately, as ``ros2 param set`` does)."""
        from rcl_interfaces.srv import SetParameters
        from rclpy.parameter import Parameter

        params = [Parameter(name, value=value).to_parameter_msg() for name, value in values.items()]
        response = self.call(SetParameters, f"{target}/set_parameters", SetParameters.Request(parameters=params))
        assert response is not None, f"{target}/set_parameters did not answer"
        return list(response.results)

    def set_parameter_msgs(self, target: str, params: list) -> list:
        """SetParameters with raw rcl_interfaces/Parameter messages (wrong types on purpose)."""
        from rcl_interfaces.srv import SetParameters

        response = self.call(SetParameters, f"{target}/set_parameters", SetParameters.Request(parameters=params))
        assert response is not None, f"{target}/set_parameters did not answer"
        return list(response.results)
