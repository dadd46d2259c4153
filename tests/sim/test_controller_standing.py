"""G1 under the whole-body QP in PyBullet (in-process sim_bridge backend, lock-step): standing
10 s with a 2 kg box dropped on it, and the 4-contact ladder stance held 10 s."""
from __future__ import annotations

import numpy as np
import pytest

from climb_core.contact import FEET
from controller_node.params import load_controller_params
from controller_node.runner import InProcessRunner

pytestmark = pytest.mark.sim


@pytest.fixture
def backend():
    from sim_bridge.pybullet_backend import PyBulletBackend

    b = PyBulletBackend()
    yield b
    b.close()


def test_g1_stands_10s_and_a_2kg_box_dropped_on_it_does_not_topple_it(backend):
    from sim_bridge.commands import PerturbRequest

    runner = InProcessRunner.start(backend, load_controller_params(), posture="standing")
    com0 = runner.controller.wb.data.com[0].copy()
    # the paper's perturbation: a 2 kg box (here a 2 kg, 10 cm ball) falling on the torso at 4 m/s
    backend.request_perturbation(PerturbRequest("drop", mass=2.0, radius=0.1, speed=4.0,
                                                target_link="torso_link", at_time=2.0))
    log = runner.run(10.0)
    state = runner.sim_state
    assert not log.fell, log.fall_reason
    assert state.time == pytest.approx(10.0, abs=0.01)
    assert runner.controller.qp_failures == 0
    assert state.balls and np.linalg.norm(state.balls[0].impulse_on_robot) > 1.0  # [N s] the ball hit
    com = np.array(log.com)
    t = np.array(log.times)
    disturbed = np.max(np.linalg.norm(com[t > 2.0, :2] - com0[:2], axis=1))
    assert disturbed > 1e-3  # the hit moved the CoM [m] ...
    assert np.linalg.norm(com[-1] - com0) < 0.02  # ... and the QP brought it back [m]
    assert min(log.base_height) > state.base.q[2] - 0.05
    # both feet still carry the weight at the end
    total = sum(state.contact_forces[limb][2] for limb in FEET)
    assert total == pytest.approx(backend.robot.mass * 9.81, rel=0.1)


def test_g1_holds_the_4_contact_ladder_stance_10s_with_forces_in_the_cones(backend):
    runner = InProcessRunner.start(backend, load_controller_params(), posture="ladder_4_contacts")
    controller = runner.controller
    mu = {limb: c.friction for limb, c in controller.contacts.items()}
    margin = controller.params.contacts.friction_margin
    feet0 = {limb: backend.surface_pose(limb)[:3, 3].copy() for limb in FEET}
    worst_ratio = []

    def check_cones(sim_state, output):
        result = controller.last_result
        for limb in FEET:
            c = result.contacts[limb]
            contact = controller.contacts[limb]
            for f, n in zip(c.point_forces_in_world, contact.normals_in_world):
                fn = f @ n
                assert fn >= -1e-6
                worst_ratio.append(np.linalg.norm(f - fn * n) / max(fn, 1e-9) / mu[limb])

    runner.on_tick.append(check_cones)
    log = runner.run(10.0)
    state = runner.sim_state
    assert not log.fell, log.fall_reason
    assert controller.qp_failures == 0
    assert max(worst_ratio) <= margin + 1e-6  # planned point forces inside the (margined) cones
    assert state.grasps == {"left_hand": "rung_5", "right_hand": "rung_5"}
    for limb in FEET:  # measured: the feet did not slip on the rung
        assert np.linalg.norm(backend.surface_pose(limb)[:3, 3] - feet0[limb]) < 0.005
        f = state.contact_forces[limb]
        assert f[2] > 50.0  # [N] each foot carries load
        assert np.linalg.norm(f[:2]) <= mu[limb] * f[2] + 1e-6
