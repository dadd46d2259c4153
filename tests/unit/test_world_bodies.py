"""The environment's static PyBullet bodies (sim_bridge.world_bodies.add_environment): one body per
surface with the surface's pose, size and friction, for ladders and scenes (moved from
test_environment.py with the PyBullet code)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from climb_core.environment import build_environment
from sim_bridge.world_bodies import ROLE_COLOURS, add_environment, robot_lateral_friction, surface_lateral_friction

pytestmark = pytest.mark.sim


def yawed_doc(**ladder) -> dict:
    base = {"type": "regular", "inclination_deg": 70.0, "rung_spacing": 0.3, "n_rungs": 6,
            "first_rung_height": 0.3, "rung_width": 0.5, "rung": {"shape": "circle", "diameter": 0.05},
            "pose": {"x": 1.2, "y": -0.4, "yaw_deg": 30.0}}
    base.update(ladder)
    return {"name": "yawed", "ladder": base}


@pytest.fixture
def bullet():
    pb = pytest.importorskip("pybullet")
    client = pb.connect(pb.DIRECT)
    yield pb, client
    pb.disconnect(physicsClientId=client)


def test_pybullet_bodies_match_the_surfaces(bullet):
    pb, client = bullet
    env = build_environment("ship")
    ids = add_environment(env, client)
    assert pb.getNumBodies(physicsClientId=client) == len(ids) == len(env.surfaces)
    assert set(ids) == set(env.surfaces)
    for name, body in ids.items():
        assert pb.getDynamicsInfo(body, -1, physicsClientId=client)[0] == 0.0  # static
        friction = pb.getDynamicsInfo(body, -1, physicsClientId=client)[1]
        assert friction == pytest.approx(surface_lateral_friction(env, env.surfaces[name]))
    assert pb.getDynamicsInfo(ids["rung_2"], -1, physicsClientId=client)[1] == pytest.approx(math.sqrt(0.5))
    assert pb.getDynamicsInfo(ids["ground"], -1, physicsClientId=client)[1] == pytest.approx(0.8 / math.sqrt(0.5))
    for name in ("rung_3", "rail_left", "platform", "stringer_right"):
        lo, hi = pb.getAABB(ids[name], physicsClientId=client)
        expected_lo, expected_hi = env.surfaces[name].aabb()
        np.testing.assert_allclose(lo, expected_lo, atol=1e-6)
        np.testing.assert_allclose(hi, expected_hi, atol=1e-6)


def test_pybullet_rung_3_aabb_default_and_yawed(bullet):
    pb, client = bullet
    env = build_environment("default")
    ids = add_environment(env, client)
    rung = env.rung(3)
    lo, hi = pb.getAABB(ids["rung_3"], physicsClientId=client)
    extent = np.array([rung.radius, rung.length / 2, rung.radius])  # axis along world y
    np.testing.assert_allclose(lo, rung.position - extent, atol=1e-6)
    np.testing.assert_allclose(hi, rung.position + extent, atol=1e-6)
    yawed = build_environment(yawed_doc())
    ids = add_environment(yawed, client)
    rung = yawed.rung(3)
    lo, hi = (np.array(v) for v in pb.getAABB(ids["rung_3"], physicsClientId=client))
    tight = np.abs(rung.axis) * rung.length / 2 + rung.radius * np.sqrt(1 - rung.axis ** 2)  # exact cylinder AABB
    np.testing.assert_allclose((lo + hi) / 2, rung.position, atol=1e-6)
    assert np.all((hi - lo) / 2 >= tight - 1e-6)
    np.testing.assert_allclose((hi - lo) / 2, (rung.aabb()[1] - rung.aabb()[0]) / 2, atol=1e-6)


def _slide(pb, client, env, position, push_ratio: float, mu: float) -> float:
    """Push a 1 kg box resting at `position` with push_ratio * mu * m * g; return how far it slid [m]."""
    half = 0.05
    shape = pb.createCollisionShape(pb.GEOM_BOX, halfExtents=[half] * 3, physicsClientId=client)
    box = pb.createMultiBody(1.0, shape, -1, [position[0], position[1], position[2] + half], physicsClientId=client)
    pb.changeDynamics(box, -1, lateralFriction=robot_lateral_friction(env), physicsClientId=client)
    for _ in range(60):  # settle
        pb.stepSimulation(physicsClientId=client)
    start = np.array(pb.getBasePositionAndOrientation(box, physicsClientId=client)[0])
    force = push_ratio * mu * 1.0 * 9.81
    for _ in range(240):  # 1 s at 240 Hz
        pb.applyExternalForce(box, -1, [0.0, force, 0.0], start.tolist(), pb.WORLD_FRAME, physicsClientId=client)
        pb.stepSimulation(physicsClientId=client)
    end = np.array(pb.getBasePositionAndOrientation(box, physicsClientId=client)[0])
    pb.removeBody(box, physicsClientId=client)
    return float(np.linalg.norm(end[:2] - start[:2]))


def test_pybullet_contacts_have_the_spec_friction(bullet):
    """With the robot-side friction sqrt(mu), a push just under mu m g holds and just over slides."""
    pb, client = bullet
    pb.setGravity(0, 0, -9.81, physicsClientId=client)
    env = build_environment("default")
    add_environment(env, client)
    platform = env.surfaces["platform"]
    on_platform = platform.position + np.array([0.2, 0.0, platform.half_extents[2]])
    on_ground = np.array([-1.0, 0.0, 0.0])
    for where, mu in ((on_platform, env.ladder.friction), (on_ground, env.ladder.ground_friction)):
        assert _slide(pb, client, env, where, 0.85, mu) < 0.002
        assert _slide(pb, client, env, where, 1.15, mu) > 0.1


def test_a_scene_has_one_body_per_surface_with_its_pose_and_friction(bullet):
    """car_ingress (no ladder): every surface one static body, the AABBs of the core's model,
    and robot-side sqrt(mu_ground) times body friction = each surface's own coefficient."""
    pb, client = bullet
    env = build_environment("car_ingress")
    ids = add_environment(env, client)
    assert set(ids) == set(env.surfaces) and pb.getNumBodies(physicsClientId=client) == len(env.surfaces)
    assert robot_lateral_friction(env) == pytest.approx(math.sqrt(env.surfaces["ground"].friction))
    for name, body in ids.items():
        surface = env.surfaces[name]
        mass, friction = pb.getDynamicsInfo(body, -1, physicsClientId=client)[:2]
        assert mass == 0.0
        assert friction * robot_lateral_friction(env) == pytest.approx(surface.friction)
        if surface.shape == "plane":
            continue
        lo, hi = (np.array(v) for v in pb.getAABB(body, physicsClientId=client))
        expected_lo, expected_hi = surface.aabb()
        np.testing.assert_allclose((lo + hi) / 2, (expected_lo + expected_hi) / 2, atol=1e-6)
        if surface.shape == "box":  # PyBullet's cylinder AABB is its own bound, boxes are exact
            np.testing.assert_allclose(hi - lo, expected_hi - expected_lo, atol=1e-6)
    assert pb.getVisualShapeData(ids["steering_wheel"], physicsClientId=client)[0][7] == \
        pytest.approx(ROLE_COLOURS["scene"])


def test_scene_contacts_have_each_surface_friction(bullet):
    """A box with the robot's friction, pushed just under / over mu m g on car_ingress's seat
    (mu 0.6) and on the ground (mu 0.8), holds / slides."""
    pb, client = bullet
    pb.setGravity(0, 0, -9.81, physicsClientId=client)
    env = build_environment("car_ingress")
    add_environment(env, client)
    seat = env.surfaces["seat_driver"]
    on_seat = seat.position + np.array([0.0, 0.0, seat.half_extents[2]])
    assert seat.friction != env.surfaces["ground"].friction
    for where, mu in ((on_seat, seat.friction), (np.array([-1.0, 0.0, 0.0]), env.surfaces["ground"].friction)):
        assert _slide(pb, client, env, where, 0.85, mu) < 0.002
        assert _slide(pb, client, env, where, 1.15, mu) > 0.1
