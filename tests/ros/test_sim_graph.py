"""The `sim_graph` executable: the bridge and the controller composed in one process, in lock-step.

The observer of test_controller_node.py (that file run as a script) drives the controller's
lifecycle through its services, sends the hand-transfer plan (right hand rung 5 -> rung 6) and
records what the graph publishes; the same physical assertions hold for the composed graph.
"""
from __future__ import annotations

import json
import pathlib
import subprocess
import sys

import pytest
from test_controller_node import TICKS, check_hand_transfer_run

pytestmark = pytest.mark.ros

ROOT = pathlib.Path(__file__).resolve().parents[2]
OBSERVER = ROOT / "tests" / "ros" / "test_controller_node.py"


def test_composed_graph_runs_a_hand_transfer_in_lockstep(tmp_path):
    from climb_core.ros_env import local_dds_env

    env = local_dds_env()
    out = tmp_path / "observer.json"
    graph = subprocess.Popen(
        [sys.executable, "-m", "climb_coordinator.sim_graph", "--ros-args",
         "--params-file", str(ROOT / "config" / "nodes" / "sim_bridge.yaml"),
         "--params-file", str(ROOT / "config" / "nodes" / "controller.yaml"),
         "-p", f"max_ticks:={TICKS}", "-p", "initial_posture:=ladder_4_contacts",
         "-p", "initial_stance:=ladder_4_contacts", "-p", "execution:=lockstep", "-p", "autostart:=false"],
        env=env, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    observer = subprocess.Popen([sys.executable, str(OBSERVER), str(out)], env=env, cwd=ROOT,
                                stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    try:
        o_out, _ = observer.communicate(timeout=150)
        g_out, _ = graph.communicate(timeout=30)
    finally:
        for proc in (observer, graph):
            if proc.poll() is None:
                proc.kill()
                proc.wait()
    assert observer.returncode == 0, o_out.decode()[-3000:]
    assert graph.returncode == 0, g_out.decode()[-3000:]
    check_hand_transfer_run(json.loads(out.read_text()))
