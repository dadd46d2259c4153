"""sim_bridge.sim_urdf: the simulator's URDF of each robot (hull collision geometry, foot boxes,
armature, finger joints kept) loads in PyBullet with Pinocchio's mass and behaves like the model."""
from __future__ import annotations

import pathlib
import xml.etree.ElementTree as ET

import numpy as np
import pybullet as p
import pytest

from climb_core.contact import FEET
from climb_core.robot import RobotModel, load_robot, load_robot_config, share_dir
from sim_bridge import sim_urdf
from sim_bridge.sim_urdf import SimUrdfWriter, is_ascii_stl, mesh_obj, sim_urdf_path

ROBOT_NAMES = ("g1", "talos", "romeo")
GRAVITY = 9.81  # [m/s^2]


@pytest.fixture(scope="module")
def g1() -> RobotModel:
    return load_robot("g1")


@pytest.fixture(scope="module", params=ROBOT_NAMES)
def any_robot(request) -> RobotModel:
    return load_robot(request.param)


@pytest.fixture
def bullet():
    client = p.connect(p.DIRECT)
    yield client
    p.disconnect(client)


def _load_sim(robot: RobotModel, client: int, fixed: bool = False, flags: int = 0) -> tuple[int, dict, dict]:
    flags |= p.URDF_USE_INERTIA_FROM_FILE  # else PyBullet derives inertia from the collision shapes
    body = p.loadURDF(str(sim_urdf_path(robot)), [0, 0, 2], useFixedBase=fixed, flags=flags,
                      physicsClientId=client)
    joints, links = {}, {p.getBodyInfo(body, physicsClientId=client)[0].decode(): -1}
    for j in range(p.getNumJoints(body, physicsClientId=client)):
        info = p.getJointInfo(body, j, physicsClientId=client)
        joints[info[1].decode()] = j
        links[info[12].decode()] = j
    return body, joints, links


def test_sim_urdf_loads_in_pybullet_with_matching_mass(any_robot, bullet):
    path = sim_urdf_path(any_robot)
    assert path == sim_urdf_path(any_robot) and path.parent.name == "robots"
    text = path.read_text()
    assert "package://" not in text
    for mesh in ET.fromstring(text.split("\n", 2)[2]).iter("mesh"):
        assert pathlib.Path(mesh.get("filename")).is_absolute() and pathlib.Path(mesh.get("filename")).is_file()
    body, joints, _ = _load_sim(any_robot, bullet)
    n = p.getNumJoints(body, physicsClientId=bullet)
    mass = sum(p.getDynamicsInfo(body, link, physicsClientId=bullet)[0] for link in range(-1, n))
    assert mass == pytest.approx(any_robot.mass, rel=0.01)
    movable = {name for name, j in joints.items()
               if p.getJointInfo(body, j, physicsClientId=bullet)[2] != p.JOINT_FIXED}
    assert movable == set(any_robot.joint_names) | set(any_robot.config.locked_joints)  # fingers kept


def test_g1_sim_urdf_has_foot_boxes_and_armature(g1, bullet):
    body, joints, links = _load_sim(g1, bullet)
    for limb in FEET:
        shapes = p.getCollisionShapeData(body, links[g1.config.limbs[limb].surface.frame], physicsClientId=bullet)
        assert len(shapes) == 1 and shapes[0][2] == p.GEOM_BOX
        np.testing.assert_allclose(shapes[0][3], [0.17, 0.06, 0.01], atol=1e-9)
    # PyBullet diagonalises the URDF inertia: compare principal moments
    link = ET.parse(g1.config.urdf_path).getroot().find("link[@name='left_knee_link']/inertial/inertia")
    I_urdf = np.array([[float(link.get(k)) for k in row] for row in
                       (("ixx", "ixy", "ixz"), ("ixy", "iyy", "iyz"), ("ixz", "iyz", "izz"))])
    expected = np.linalg.eigvalsh(I_urdf + g1.config.sim.armature * np.eye(3))
    got = np.sort(p.getDynamicsInfo(body, links["left_knee_link"], physicsClientId=bullet)[2])
    np.testing.assert_allclose(got, expected, rtol=1e-4)


def test_sim_self_collision_free_at_reference_after_ignore_pairs(any_robot, bullet):
    flags = p.URDF_USE_SELF_COLLISION | p.URDF_USE_SELF_COLLISION_EXCLUDE_PARENT
    body, joints, links = _load_sim(any_robot, bullet, flags=flags)
    for name, value in any_robot.config.reference_posture.items():
        p.resetJointState(body, joints[name], value, physicsClientId=bullet)
    for a, b in any_robot.config.collision.ignore_pairs:
        p.setCollisionFilterPair(body, body, links[a], links[b], 0, physicsClientId=bullet)
    p.performCollisionDetection(physicsClientId=bullet)
    names = {i: n for n, i in links.items()}
    deep = [(names[c[3]], names[c[4]], c[8]) for c in p.getContactPoints(body, body, physicsClientId=bullet)
            if c[8] < -5e-4]
    assert not deep


def test_ft_sensor_joints_read_the_distal_weight(any_robot, bullet):
    """Fixed base in the air, joints held: each sensor reads the weight of what hangs below it."""
    p.setGravity(0, 0, -GRAVITY, physicsClientId=bullet)
    body, joints, _ = _load_sim(any_robot, bullet, fixed=True)
    n = p.getNumJoints(body, physicsClientId=bullet)
    for name, value in any_robot.config.reference_posture.items():
        p.resetJointState(body, joints[name], value, physicsClientId=bullet)
    movable = [j for j in range(n) if p.getJointInfo(body, j, physicsClientId=bullet)[2] != p.JOINT_FIXED]
    targets = [p.getJointState(body, j, physicsClientId=bullet)[0] for j in movable]
    p.setJointMotorControlArray(body, movable, p.POSITION_CONTROL, targetPositions=targets,
                                forces=[1000.0] * len(movable), physicsClientId=bullet)
    for joint in any_robot.config.ft_sensors.values():
        p.enableJointForceTorqueSensor(body, joints[joint], True, physicsClientId=bullet)
    for _ in range(100):
        p.stepSimulation(physicsClientId=bullet)
    parent = {j: p.getJointInfo(body, j, physicsClientId=bullet)[16] for j in range(n)}

    def subtree_mass(link: int) -> float:
        return p.getDynamicsInfo(body, link, physicsClientId=bullet)[0] + sum(
            subtree_mass(c) for c, par in parent.items() if par == link)

    for sensor, joint in any_robot.config.ft_sensors.items():
        force = np.array(p.getJointState(body, joints[joint], physicsClientId=bullet)[2][:3])
        expected = subtree_mass(joints[joint]) * GRAVITY
        assert expected > 1.0
        assert np.linalg.norm(force) == pytest.approx(expected, rel=0.03), sensor


def test_sim_urdf_cache_key_and_regeneration(monkeypatch, tmp_path):
    talos = load_robot("talos")
    monkeypatch.setattr(sim_urdf, "cache_dir", lambda: tmp_path)
    writer = SimUrdfWriter(talos.config)
    assert writer.cached() is None
    path = writer.write(talos.full_collision_model, talos.mass)
    assert SimUrdfWriter(talos.config).cached() == path
    # another config (same name, one number changed) -> another file; the original stays valid
    changed = tmp_path / "talos.yaml"
    changed.write_text(talos.config.config_path.read_text().replace("grip_strength: 150.0", "grip_strength: 140.0"))
    other = SimUrdfWriter(load_robot_config(changed))
    assert other.out != path and other.cached() is None
    # a stale stamp is not reused
    path.write_text(path.read_text().replace("key=", "key=stale", 1))
    assert SimUrdfWriter(talos.config).cached() is None


def test_no_ascii_stl_in_the_robots_and_ascii_is_detected(tmp_path, bullet):
    for name in ROBOT_NAMES:
        cfg = load_robot_config(name)
        for mesh in ET.parse(cfg.urdf_path).getroot().iter("mesh"):
            f = share_dir() / mesh.get("filename").replace("package://", "").lstrip("/")
            assert f.is_file() and not is_ascii_stl(f), f
    ascii_stl = tmp_path / "tet.stl"
    corners = [(0, 0, 0), (0.1, 0, 0), (0, 0.1, 0), (0, 0, 0.1)]
    faces = [(0, 2, 1), (0, 1, 3), (0, 3, 2), (1, 2, 3)]
    ascii_stl.write_text("solid tet\n" + "".join(
        "facet normal 0 0 0\nouter loop\n" + "".join(f"vertex {x} {y} {z}\n" for x, y, z in (corners[i] for i in f))
        + "endloop\nendfacet\n" for f in faces) + "endsolid tet\n")
    assert is_ascii_stl(ascii_stl)
    obj = tmp_path / "tet.obj"
    obj.write_text(mesh_obj(ascii_stl, np.ones(3)))
    shape = p.createCollisionShape(p.GEOM_MESH, fileName=str(obj), physicsClientId=bullet)
    assert shape >= 0
