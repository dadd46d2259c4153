"""Perturbations in PyBullet: dropped balls (impulse), rung offsets, rails shift, the spec's
perturbation block and the run-time requests (headless)."""
from __future__ import annotations

import numpy as np
import pytest

from sim_bridge.backend import ResetRequest
from sim_bridge.commands import PerturbRequest
from sim_bridge.pybullet_backend import PyBulletBackend
from sim_bridge.simple_control import GravityCompensatedPd

pytestmark = pytest.mark.sim


@pytest.fixture(scope="module")
def backend():
    b = PyBulletBackend()
    yield b
    b.close()


def test_ball_impulse_matches_its_momentum_change(backend):
    state = backend.reset(ResetRequest(robot="g1", ladder="default", initial_posture="standing"))
    ctl = GravityCompensatedPd(backend.robot, backend.robot.q_reference())
    backend.request_perturbation(PerturbRequest("drop", mass=10.0, radius=0.12, speed=5.5, target_link="torso",
                                                at_time=0.05))
    launched = None
    for _ in range(20):
        state = backend.step(ctl(state))
        if state.balls and launched is None:
            launched = state.balls[0]
    assert launched is not None and launched.launch_time == pytest.approx(0.05)
    assert np.linalg.norm(launched.launch_velocity) == pytest.approx(5.5, rel=0.01)
    ball = state.balls[0]
    g = np.array([0.0, 0.0, -backend.params.physics.gravity])
    window = state.time - ball.launch_time
    # momentum the contacts took from the ball (gravity's share removed)
    dp_contacts = ball.mass * (ball.velocity - ball.launch_velocity) - ball.mass * g * window
    assert np.linalg.norm(dp_contacts) > 0.5 * ball.mass * 5.5  # a real hit, not a graze
    # every contact of the ball was with the robot: the robot received the opposite impulse
    assert np.linalg.norm(ball.impulse_on_robot + dp_contacts) < 0.10 * np.linalg.norm(dp_contacts)
    assert ball.impulse_on_robot[2] < 0  # pushed down
    drops = [e for e in backend.drain_events() if e.kind == "drop"]
    assert drops and "10.0 kg" in drops[0].message


def test_rung_offset_at_run_time_moves_the_rung(backend):
    backend.reset(ResetRequest(robot="g1", ladder="default", initial_posture="standing"))
    before = backend.surface_frame("rung_3")[:3, 3]
    backend.request_perturbation(PerturbRequest("rung_offset", rung=3, dx=0.01, dz=0.02, at_time=0.01))
    backend.step()
    assert np.allclose(backend.surface_frame("rung_3")[:3, 3], before)  # not yet (t = 0.005)
    backend.step()
    backend.step()
    after = backend.surface_frame("rung_3")[:3, 3]
    assert np.allclose(after - before, [0.01, 0.0, 0.02], atol=1e-9)  # ladder yaw 0: ladder x = world x
    assert np.allclose(backend.surface_frame("rung_4")[:3, 3], backend.env.rung_centre(4))  # others stay
    backend.request_perturbation(PerturbRequest("rung_offset", rung=42, dz=0.02))
    backend.step()
    events = backend.drain_events()
    assert any("rung 3 moved" in e.message for e in events)
    assert any("no rung 42" in e.message and e.level == 2 for e in events)


def test_the_spec_perturbation_block_builds_the_perturbed_ladder(backend):
    from climb_core.environment import build_environment
    from climb_core.ladder import load_scenario

    backend.reset(ResetRequest(robot="g1", ladder="default_perturbed", initial_posture="standing"))
    nominal = build_environment(load_scenario("default_perturbed"), perturbed=False)
    offset = backend.surface_frame("rung_2")[:3, 3] - nominal.rung_centre(2)
    assert np.allclose(offset, [0.0, 0.0, 0.02], atol=1e-9)  # the planner does not know about it
    assert np.allclose(backend.surface_frame("rung_3")[:3, 3], nominal.rung_centre(3))
    drops = [r for r in backend.pending_requests() if isinstance(r, PerturbRequest)]
    assert [(d.kind, d.mass, d.at_time, d.target_link) for d in drops] == [("drop", 10.0, 43.0, "torso")]


def test_rails_shift(backend):
    backend.reset(ResetRequest(robot="g1", ladder="ship", initial_posture="standing"))
    rails = [name for name in backend.env_bodies if name.startswith("rail_")]
    assert rails
    before = {name: backend.surface_frame(name)[:3, 3] for name in rails}
    backend.request_perturbation(PerturbRequest("rails_shift", dy=0.03))
    backend.step()
    ladder_y = backend.env.T_world_ladder[:3, 1]
    for name in rails:
        assert np.allclose(backend.surface_frame(name)[:3, 3] - before[name], 0.03 * ladder_y, atol=1e-9)
    assert any("rails shifted" in e.message for e in backend.drain_events())
