"""Controller.hold_plan (the controller/hold service, a cancel) in-process, lock-step: mid-way
through a limb transfer the plan is abandoned and the robot holds the contacts it has, nothing
falls; a new plan is taken afterwards. Case: the right foot being unloaded (its contact stays: the
unload state's teardown would have dropped it); the hand in flight is held 10 s through ROS in
tests/ros/test_sim_graph.py."""
from __future__ import annotations

import numpy as np
import pytest

from climb_core import fixtures
from controller_node.controller import HoldRefused
from controller_node.params import load_controller_params
from controller_node.runner import InProcessRunner
from controller_node.simple_plans import limb_transfer, plan_of

pytestmark = pytest.mark.sim

HOLD_S = 4.0  # [s] of sim time held (the ROS lock-step test holds 10 s)


@pytest.fixture
def backend():
    from sim_bridge.pybullet_backend import PyBulletBackend

    b = PyBulletBackend()
    yield b
    b.close()


@pytest.mark.parametrize("limb, target, s, hold_in", [("right_foot", "rung_2", -0.12, "unload")],
                         ids=["foot_unloading"])  # the hand in flight: tests/ros/test_sim_graph.py (10 s held)
def test_hold_mid_transition_keeps_the_contacts_and_nothing_falls(backend, limb, target, s, hold_in):
    runner = InProcessRunner.start(backend, load_controller_params(), posture="ladder_4_contacts")
    robot, env = backend.robot, backend.env
    stance, q = fixtures.get("ladder_4_contacts", robot, env)
    c = runner.controller
    c.set_plan(plan_of(robot, env, stance, [limb_transfer(robot, env, stance, q, limb, target, s)]))
    log = runner.run(6.0, until=lambda o: o.status.fsm_state == hold_in and c.fsm.current.elapsed(c) > 0.2)
    assert c.fsm.state == hold_in and not log.fell, log.fsm_states[-1]
    contacts = set(c.contacts)
    grasps = dict(runner.sim_state.grasps)
    assert c.hold_plan() == hold_in
    assert c.fsm.state == "hold" and c.plan is None and set(c.contacts) == contacts
    assert not c.contact_set.ramps or all(r.kind == "engage" for r in c.contact_set.ramps.values())
    z0 = float(runner.sim_state.base.q[2])
    seen = []
    runner.on_tick.append(lambda sim, out: seen.append((out.status.fsm_state, out.status.active_contacts)))
    log = runner.run(HOLD_S)
    assert not log.fell, log.fall_reason
    assert {state for state, _ in seen} == {"hold"}
    assert {frozenset(active) for _, active in seen} == {frozenset(contacts)}
    assert dict(runner.sim_state.grasps) == grasps
    assert abs(float(runner.sim_state.base.q[2]) - z0) < 0.03
    assert c.qp_failures == 0
    assert any(e.kind == "plan_abandoned" for e in c.events)
    # a hold in hold is fine; a new plan is taken from there
    assert c.hold_plan() == "hold"
    c.set_plan(plan_of(robot, env, stance, []))
    runner.run(0.05)
    assert c.fsm.state == "hold" and np.isfinite(runner.last_output.values).all()
    # in failure the fallback holds already: refused with the reason
    c.fsm.fire(c, "qp_failure")
    with pytest.raises(HoldRefused, match="failure"):
        c.hold_plan()
