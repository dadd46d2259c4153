"""Issue 20 row 10: every socket of every node process is bound to loopback.

Every executable of the graph (tests/ros/node_execs.py) is started with the environment the
Makefile and .ci/run export (ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST and the project's Fast DDS
profile): the node's own climb_core.ros_env must turn it into the settings that keep every socket
on 127.0.0.1. A bare rclpy node gets what project scripts pass to a child (ros_env.local_dds_env).
Each process's UDP and TCP sockets (v4 and v6) are read from /proc/<pid>/net/ twice, a few seconds
apart (discovery creates some late); any local address that is not loopback fails the test.
"""
from __future__ import annotations

import os
import pathlib
import subprocess
import sys
import tempfile
import time

import pytest

from node_execs import EXECUTABLES, Socket, executable_status, is_loopback, sockets

pytestmark = pytest.mark.ros

ROOT = pathlib.Path(__file__).resolve().parents[2]
START_TIMEOUT_S = 120.0  # [s] every process has its DDS participant, on a busy 2-core machine
SETTLE_S = 3.0  # [s] between the two reads of the sockets
BARE_NODE = ("import rclpy, time\nfrom std_msgs.msg import String\nrclpy.init()\n"
             "node = rclpy.create_node('bare_socket_probe')\npub = node.create_publisher(String, 'bare_probe', 10)\n"
             "while True:\n    pub.publish(String(data='x'))\n    rclpy.spin_once(node, timeout_sec=0.2)\n")


def project_shell_env() -> dict[str, str]:
    """The environment `make test` / .ci/run give a process (before the process's own ros_env)."""
    env = dict(os.environ)
    env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    env["FASTRTPS_DEFAULT_PROFILES_FILE"] = str(ROOT / "config" / "fastdds_localhost.xml")
    env["RMW_IMPLEMENTATION"] = "rmw_fastrtps_cpp"
    env.pop("_ROS_WHEELS_BOOTSTRAP_COMPLETE", None)  # a child venv Python bootstraps itself
    return env


def rtps_listener(pid: int, domain_id: int) -> bool:
    base = 7400 + 250 * domain_id
    return any(s.table == "udp" and base <= s.port < base + 250 for s in sockets(pid))


@pytest.fixture(scope="module")
def processes():
    from climb_core.ros_env import local_dds_env

    domain_id = int(os.environ["ROS_DOMAIN_ID"])
    workdir = tempfile.mkdtemp(prefix="sockets_")
    procs: dict[str, subprocess.Popen] = {}
    logs: dict[str, pathlib.Path] = {}

    def start(key: str, argv: list[str], env: dict[str, str]) -> None:
        logs[key] = pathlib.Path(workdir) / f"{key.replace('/', '_')}.log"
        procs[key] = subprocess.Popen(argv, env=env, cwd=workdir, stdout=logs[key].open("w"),
                                      stderr=subprocess.STDOUT, start_new_session=True)

    try:
        for exe in EXECUTABLES:
            if executable_status(exe) == "installed":
                extra = ["-p", f"bag_path:={workdir}/bag"] if exe.name == "recorder" else []
                start(str(exe), exe.argv(*extra), project_shell_env())
        start("bare rclpy node", [sys.executable, "-c", BARE_NODE], local_dds_env(project_shell_env()))
        deadline = time.monotonic() + START_TIMEOUT_S
        while time.monotonic() < deadline and not all(
                p.poll() is not None or rtps_listener(p.pid, domain_id) for p in procs.values()):
            time.sleep(0.5)
        first = {k: set(sockets(p.pid)) for k, p in procs.items() if p.poll() is None}
        time.sleep(SETTLE_S)
        seen = {k: first.get(k, set()) | (set(sockets(p.pid)) if p.poll() is None else set())
                for k, p in procs.items()}
        yield {k: (procs[k], seen[k], logs[k]) for k in procs}
    finally:
        for p in procs.values():
            if p.poll() is None:
                p.terminate()
        for p in procs.values():
            try:
                p.wait(timeout=20)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()


def check(processes, key: str) -> None:
    proc, seen, log = processes[key]
    alive = proc.poll() is None
    assert alive or seen, f"{key} exited ({proc.returncode}) before its sockets could be read:\n" + \
        log.read_text(errors="replace")[-3000:]
    assert seen, f"{key}: no socket at all"
    bad: list[Socket] = [s for s in seen if not is_loopback(s)]
    assert not bad, f"{key}: sockets not bound to loopback: {sorted(map(str, bad))} (all: {sorted(map(str, seen))})"


@pytest.mark.parametrize("exe", EXECUTABLES, ids=str)
def test_node_sockets_are_loopback_only(processes, exe):
    status = executable_status(exe)
    if status == "undeclared":
        pytest.skip(f"{exe}: no such executable and no setup.py entry point declares it")
    assert status == "installed", f"{exe} is declared in src/{exe.package}/setup.py but not installed " \
                                  f"at {exe.path} (make setup)"
    check(processes, str(exe))


def test_bare_rclpy_node_sockets_are_loopback_only(processes):
    check(processes, "bare rclpy node")
