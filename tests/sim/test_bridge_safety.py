"""Watchdog, bad commands and fall detection with the PyBullet backend behind the bridge logic."""
from __future__ import annotations

import math

import numpy as np
import pytest

from sim_bridge.backend import ResetRequest
from sim_bridge.bridge import SimBridge
from sim_bridge.commands import TORQUE
from sim_bridge.params import load_bridge_params
from sim_bridge.pybullet_backend import PyBulletBackend
from sim_bridge.simple_control import GravityCompensatedPd

pytestmark = pytest.mark.sim


@pytest.fixture(scope="module")
def backend():
    b = PyBulletBackend()
    yield b
    b.close()


def make_bridge(backend, execution: str) -> tuple[SimBridge, GravityCompensatedPd]:
    params = load_bridge_params(execution=execution)
    backend.params = params
    bridge = SimBridge(backend, params)
    bridge.reset(ResetRequest(robot="g1", ladder="default", initial_posture="standing"))
    return bridge, GravityCompensatedPd(backend.robot, backend.robot.q_reference())


def named(cmd, names):
    return list(names), [int(m) for m in cmd.modes], list(cmd.values)


def test_realtime_watchdog_damps_the_robot_then_commands_resume(backend):
    bridge, ctl = make_bridge(backend, "realtime")
    names = backend.joint_names
    wall = 100.0
    state = bridge.state
    for _ in range(20):  # commands every 5 ms
        cmd = ctl(state)
        bridge.offer_command(*named(cmd, names), stamp_ns=0, wall_time=wall)
        state = bridge.step_realtime(wall)
        wall += 0.005
    assert not bridge.watchdog_active and np.allclose(state.tau, np.clip(cmd.values, -ctl.effort, ctl.effort))
    bridge.drain_diagnostics()
    for _ in range(30):  # the controller stalls for 150 ms (wall)
        state = bridge.step_realtime(wall)
        wall += 0.005
    assert bridge.watchdog_active
    gain = bridge.params.actuation.damping_gain
    from sim_bridge.commands import DAMPING

    assert np.all(backend.actuators.command.modes == DAMPING)
    assert np.abs(state.v).max() > 0.05  # [rad/s] the robot sags: something to damp
    assert np.allclose(state.tau, -gain * state.v, atol=0.05)  # viscous, no stiffness left
    diags = [d for d in bridge.drain_diagnostics() if d.name == "sim_bridge/watchdog"]
    edges = [d for d in diags if d.message.startswith("no valid command for")]  # the onset, reported once
    assert len(edges) == 1 and edges[0].level == 2 and "damping every joint" in edges[0].message
    assert all(d.level == 2 for d in diags)  # the ongoing fault is repeated with each periodic summary
    cmd = ctl(state)
    bridge.offer_command(*named(cmd, names), stamp_ns=0, wall_time=wall)
    state = bridge.step_realtime(wall + 0.001)
    assert not bridge.watchdog_active
    assert np.allclose(state.tau, np.clip(cmd.values, -ctl.effort, ctl.effort))
    assert any(d.message == "commands resumed" for d in bridge.drain_diagnostics())


def test_bad_command_keeps_the_robot_on_its_last_valid_command(backend):
    bridge, ctl = make_bridge(backend, "lockstep")
    names = backend.joint_names
    state = bridge.state
    for _ in range(10):
        cmd = ctl(state)
        assert bridge.offer_command(*named(cmd, names), stamp_ns=bridge.stamp_ns).accepted
        state = bridge.step_lockstep()
    last_valid = np.clip(cmd.values, -ctl.effort, ctl.effort)
    bridge.drain_diagnostics()
    bad = list(ctl(state).values)
    bad[3] = math.nan
    verdict = bridge.offer_command(names, [TORQUE] * len(names), bad, stamp_ns=bridge.stamp_ns)
    assert not verdict.accepted and names[3] in verdict.reason
    state = bridge.step_lockstep()
    assert np.allclose(state.tau, last_valid) and not state.fell
    for bad_cmd in ((names[:-1], [TORQUE] * len(names), list(last_valid)),  # wrong length
                    (names, [9] * len(names), list(last_valid)),  # unknown mode
                    (["tail_joint"], [TORQUE], [1.0])):  # unknown joint
        assert not bridge.offer_command(*bad_cmd, stamp_ns=bridge.stamp_ns).accepted
        state = bridge.step_lockstep()
        assert np.allclose(state.tau, last_valid)
    messages = [d.message for d in bridge.drain_diagnostics() if d.name == "sim_bridge/command"]
    assert len(messages) == 4
    assert "must be finite" in messages[0] and "one mode per name" in messages[1]
    assert "unknown mode 9" in messages[2] and "unknown joint 'tail_joint'" in messages[3]


def test_a_robot_left_without_commands_falls_and_it_is_reported_once(backend):
    bridge, _ = make_bridge(backend, "lockstep")
    state = bridge.state
    for _ in range(400):  # 2 s of damping only
        state = bridge.step_lockstep()
        if state.fell:
            break
    assert state.fell and ("base height" in state.fall_reason or "touches the ground" in state.fall_reason)
    for _ in range(20):
        state = bridge.step_lockstep()
    falls = [d for d in bridge.drain_diagnostics() if d.name == "sim_bridge/fall"]
    assert len(falls) == 1 and falls[0].level == 2
