"""Actuation latency compensation (``actuation_latency_s``): each tick computes its command for the
state predicted one latency ahead, so a command that acts one period late acts on the state it was
computed for (the sim tests run transfers and climbs with the bridge's one-period delay)."""
from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from climb_core import fixtures
from controller_node.controller import Controller
from controller_node.estimator import RobotState
from controller_node.params import load_controller_params

L = 0.005  # [s] one control period


@pytest.fixture(scope="module")
def controller(g1, env):
    return Controller(g1, load_controller_params(actuation_latency_s=L), env)


def _moving_state(g1, env, seed: int) -> RobotState:
    _stance, q = fixtures.get("ladder_4_contacts", g1, env)
    rng = np.random.default_rng(seed)
    v = rng.uniform(-1.0, 1.0, g1.model.nv)  # base [m/s, rad/s] and joints [rad/s]
    ft = {"left_wrist": np.arange(6.0)}
    return RobotState(1.25, q.copy(), v, ft, stamp_ns=1_250_000_000)


def _integrated(model, q, v, a, horizon, steps=2000):
    """The same motion integrated finely: explicit Euler on the configuration manifold."""
    dt = horizon / steps
    q, v = q.copy(), v.copy()
    for _ in range(steps):
        q = pin.integrate(model, q, v * dt)
        v = v + a * dt
    return q, v


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_prediction_follows_the_motion_at_the_held_acceleration(g1, env, controller, seed):
    state = _moving_state(g1, env, seed)
    a = np.random.default_rng(100 + seed).uniform(-20.0, 20.0, g1.model.nv)
    controller._qdd_held = a
    predicted = controller.predict(state, L)
    q_ref, v_ref = _integrated(g1.model, state.q, state.v, a, L)
    assert np.abs(pin.difference(g1.model, q_ref, predicted.q)).max() < 1e-6  # [m, rad]; Euler's own error ~1e-7
    assert np.allclose(predicted.v, v_ref, atol=1e-9)
    assert np.linalg.norm(predicted.q[3:7]) == pytest.approx(1.0, abs=1e-12)  # still a unit quaternion
    # what was measured stays what was measured
    assert (predicted.time, predicted.stamp_ns) == (state.time, state.stamp_ns)
    assert predicted.ft is state.ft
    assert np.abs(predicted.q[7:] - state.q[7:]).max() > 1e-3  # it did move (|v| up to 1 rad/s)


def test_without_a_solved_qp_the_prediction_holds_the_velocity(g1, env, controller):
    state = _moving_state(g1, env, 3)
    controller._qdd_held = None
    predicted = controller.predict(state, L)
    assert np.array_equal(predicted.v, state.v)
    assert np.allclose(predicted.q[7:], state.q[7:] + L * state.v[6:], atol=1e-12)


def test_a_tick_with_latency_solves_for_the_predicted_state_and_keeps_the_stamp(g1, env):
    stance, q = fixtures.get("ladder_4_contacts", g1, env)
    delayed = Controller(g1, load_controller_params(actuation_latency_s=L), env)
    still = RobotState(0.0, q.copy(), np.zeros(g1.model.nv), {}, stamp_ns=0)
    delayed.reset(still, stance)
    delayed.tick(still)
    a1 = delayed._qdd_held.copy()  # the first tick's solved accelerations
    assert np.abs(a1).max() > 0.0
    moving = RobotState(0.005, q.copy(), np.full(g1.model.nv, 0.2), {}, stamp_ns=5_000_000)
    out = delayed.tick(moving)
    assert (out.stamp_ns, out.time) == (moving.stamp_ns, moving.time)  # answers the measured state
    # the tick ran (kinematics, QP, FSM) on the state one latency ahead at the held accelerations
    assert np.allclose(delayed.state.v, moving.v + L * a1, atol=1e-12)
    q_pred = pin.integrate(g1.model, moving.q, moving.v * L + 0.5 * L * L * a1)
    assert np.allclose(delayed.state.q, q_pred, atol=1e-12)
    assert np.allclose(delayed.wb.view.q, q_pred, atol=1e-12)
    assert not np.allclose(delayed.state.q, moving.q)
