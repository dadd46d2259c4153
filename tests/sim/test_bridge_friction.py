"""Effective Coulomb friction of a robot contact: a G1 foot pressed on a rung and dragged along it
has the ladder spec's mu, although PyBullet multiplies the two bodies' coefficients."""
from __future__ import annotations

import numpy as np
import pytest

from sim_bridge.backend import ResetRequest
from sim_bridge.commands import POSITION, ActuatorCommand
from sim_bridge.pybullet_backend import PyBulletBackend

pytestmark = pytest.mark.sim

SLIDE_SPEED = 0.1  # [m/s] along the rung axis


def ladder_with_friction(mu: float) -> dict:
    from climb_core.ladder import load_scenario

    spec = load_scenario("default").to_dict()
    spec["ladder"]["friction"] = mu
    return spec


@pytest.mark.parametrize("mu_spec", [0.25, 0.15])
def test_a_foot_sliding_on_a_rung_has_the_spec_mu(mu_spec):
    backend = PyBulletBackend()
    try:
        backend.reset(ResetRequest(robot="g1", ladder=ladder_with_friction(mu_spec), initial_posture="standing"))
        p, cid = backend.p, backend.client
        rung = backend.env.rung(1)
        mu = backend.env.ladder.friction
        assert mu == mu_spec
        # PyBullet multiplies: neither body alone carries the spec's mu
        robot_mu = p.getDynamicsInfo(backend.body, backend.limb_link["right_foot"], physicsClientId=cid)[1]
        rung_mu = p.getDynamicsInfo(backend.env_bodies["rung_1"], -1, physicsClientId=cid)[1]
        assert robot_mu * rung_mu == pytest.approx(mu) and robot_mu != pytest.approx(mu)
        # rigid robot (position servos), right sole 0.5 mm into the rung top, base held by a constraint
        q = backend.robot.q_reference()
        sole = backend.robot.T_world_surface("right_foot", q)[:3, 3]
        top = rung.position + np.array([0.0, 0.1, rung.top_z - rung.position[2]])
        q[:3] += top - sole + np.array([0.0, 0.0, -0.0005])
        backend.set_state(q)
        base = np.array(p.getBasePositionAndOrientation(backend.body, physicsClientId=cid)[0])
        hold = p.createConstraint(backend.body, -1, -1, -1, p.JOINT_FIXED, [0, 0, 0], [0, 0, 0], base.tolist(),
                                  physicsClientId=cid)
        cmd = ActuatorCommand.uniform(POSITION, q[7:])
        ratios, normals = [], []
        dt = backend.params.physics.control_period_s
        for k in range(100):
            pivot = base + rung.axis * (-SLIDE_SPEED * dt * max(k - 30, 0))  # rest 0.15 s, then slide
            p.changeConstraint(hold, pivot.tolist(), maxForce=5000.0, physicsClientId=cid)
            backend.step(cmd)
            if k > 50:
                contacts = p.getContactPoints(backend.body, backend.env_bodies["rung_1"], physicsClientId=cid)
                normal = sum(c[9] for c in contacts)
                tangential = sum(c[10] * np.asarray(c[11]) + c[12] * np.asarray(c[13]) for c in contacts)
                normals.append(normal)
                ratios.append(np.linalg.norm(tangential) / normal)
                assert tangential @ rung.axis > 0  # friction opposes the foot's motion (-axis)
        assert min(normals) > 50.0  # [N] pressed down
        assert np.median(ratios) == pytest.approx(mu, rel=0.03)
        slid = backend.surface_pose("right_foot")[:3, 3] @ rung.axis
        assert slid < (top @ rung.axis) - 0.03  # [m] it really slid along the rung (3.5 cm commanded)
    finally:
        backend.close()
