"""climb_core.robot: configs, Pinocchio models, convex hulls, reference posture, simulator URDF."""
from __future__ import annotations

import copy
import math
import pathlib
import xml.etree.ElementTree as ET

import coal
import numpy as np
import pinocchio as pin
import pybullet as p
import pytest
import yaml
from scipy.spatial import ConvexHull

from climb_core import robot as robot_mod
from climb_core.contact import FEET, HANDS, LIMBS
from climb_core.errors import SpecError
from climb_core.robot import (ROBOTS_DIR, RobotModel, available_robots, is_ascii_stl, load_robot,
                              load_robot_config, parse_robot_config, robots_config_dir, share_dir)

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


def _g1_yaml() -> dict:
    return yaml.safe_load((robots_config_dir() / "g1.yaml").read_text())


def _urdf_joints(path: pathlib.Path) -> dict[str, ET.Element]:
    return {j.get("name"): j for j in ET.parse(path).getroot().findall("joint")}


def _load_sim(robot: RobotModel, client: int, fixed: bool = False, flags: int = 0) -> tuple[int, dict, dict]:
    flags |= p.URDF_USE_INERTIA_FROM_FILE  # else PyBullet derives inertia from the collision shapes
    body = p.loadURDF(str(robot.sim_urdf_path()), [0, 0, 2], useFixedBase=fixed, flags=flags,
                      physicsClientId=client)
    joints, links = {}, {p.getBodyInfo(body, physicsClientId=client)[0].decode(): -1}
    for j in range(p.getNumJoints(body, physicsClientId=client)):
        info = p.getJointInfo(body, j, physicsClientId=client)
        joints[info[1].decode()] = j
        links[info[12].decode()] = j
    return body, joints, links


# -- lookup -----------------------------------------------------------------------------------
def test_available_robots_and_robots_dir():
    assert set(ROBOT_NAMES) <= set(available_robots())
    assert (ROBOTS_DIR / "g1_description" / "urdf" / "g1_29dof_with_hand_rev_1_0.urdf").is_file()
    assert load_robot_config("g1").urdf_path.parent.parent.parent == ROBOTS_DIR


def test_config_lookup_by_name_and_by_path(g1):
    path = robots_config_dir() / "g1.yaml"
    by_name, by_path = load_robot_config("g1"), load_robot_config(str(path))
    assert by_name.urdf_path == by_path.urdf_path and by_name.reference_posture == by_path.reference_posture
    assert load_robot("g1") is g1 and load_robot(path) is g1  # one model per process
    with pytest.raises(SpecError) as err:
        load_robot_config("no_such_robot")
    assert err.value.field == "robot" and "g1" in err.value.rule


# -- dimensions, limits -----------------------------------------------------------------------
def test_g1_dimensions(g1):
    assert (g1.model.nq, g1.model.nv) == (36, 35)
    assert g1.mass == pytest.approx(34.4, abs=0.5)
    assert g1.joint_names == list(g1.model.names[2:]) and len(g1.joint_names) == 29
    assert not any("hand" in name for name in g1.joint_names)  # Dex3 fingers locked
    assert len(g1.config.limbs["left_foot"].joints) == 6
    assert g1.config.limbs["left_hand"].joints[:3] == ("waist_yaw_joint", "waist_roll_joint", "waist_pitch_joint")
    assert g1.config.limbs["left_hand"].joints[-1] == "left_wrist_yaw_joint"


def test_all_robots_load_with_consistent_sizes(any_robot):
    cfg = any_robot.config
    assert any_robot.model.nv - 6 == len(any_robot.joint_names) == len(cfg.whole_body_joints)
    assert set(any_robot.joint_names) == set(cfg.whole_body_joints)
    assert not set(cfg.locked_joints) & set(any_robot.joint_names)
    for limb in LIMBS:
        assert any_robot.frame_id(cfg.limbs[limb].surface.frame) < any_robot.model.nframes
        assert cfg.ft_sensors[cfg.limbs[limb].ft_sensor]  # sensor exists
    assert any_robot.mass > 30.0


def test_effort_limits_match_urdf(any_robot):
    urdf = _urdf_joints(any_robot.config.urdf_path)
    expected = [float(urdf[name].find("limit").get("effort")) for name in any_robot.joint_names]
    np.testing.assert_allclose(any_robot.effort_limits(), expected)
    assert any_robot.effort_limits().shape == (any_robot.model.nv - 6,)


def test_g1_arm_effort_limits(g1):
    tau = g1.effort_limits()
    for side in ("left", "right"):
        for joint in ("shoulder_pitch", "shoulder_roll", "shoulder_yaw", "elbow", "wrist_roll"):
            assert tau[g1.joint_index_v(f"{side}_{joint}_joint") - 6] == 25.0
        for joint in ("wrist_pitch", "wrist_yaw"):
            assert tau[g1.joint_index_v(f"{side}_{joint}_joint") - 6] == 5.0


def test_frame_and_joint_lookup_errors(g1):
    assert g1.model.frames[g1.frame_id("left_hand_palm_link")].name == "left_hand_palm_link"
    with pytest.raises(SpecError) as err:
        g1.frame_id("no_such_link")
    assert err.value.field == "frame"
    with pytest.raises(SpecError):
        g1.joint_index_v("left_hand_index_0_joint")  # locked


# -- reference posture ------------------------------------------------------------------------
def test_q_reference_soles_flat_at_ground_level(any_robot):
    q = any_robot.q_reference()
    assert np.linalg.norm(q[3:7]) == pytest.approx(1.0)
    data = any_robot.model.createData()
    pin.framesForwardKinematics(any_robot.model, data, q)
    centres = []
    for limb in FEET:
        surface = any_robot.config.limbs[limb].surface
        T_world_frame = data.oMf[any_robot.frame_id(surface.frame)]
        corners = (T_world_frame.rotation @ surface.vertices.T).T + T_world_frame.translation
        np.testing.assert_allclose(corners[:, 2], 0.0, atol=1e-6)  # bottom face exactly on the ground
        T = any_robot.T_world_surface(limb, q)
        np.testing.assert_allclose(T[:3, 2], [0.0, 0.0, -1.0], atol=1e-3)  # normal out of the sole: down
        centres.append(T[:3, 3])
    np.testing.assert_allclose((centres[0] + centres[1])[:2] / 2, 0.0, atol=1e-9)
    assert q[2] == pytest.approx(any_robot.config.base_height, abs=2e-3)
    # left foot on the left
    assert centres[0][1] > 0.05 and centres[1][1] < -0.05


def test_q_reference_com_above_support_polygon(any_robot):
    q = any_robot.q_reference()
    data = any_robot.model.createData()
    com = pin.centerOfMass(any_robot.model, data, q)
    pin.framesForwardKinematics(any_robot.model, data, q)
    corners = []
    for limb in FEET:
        s = any_robot.config.limbs[limb].surface
        T = data.oMf[any_robot.frame_id(s.frame)]
        corners += [T.rotation @ v + T.translation for v in s.vertices]
    hull = ConvexHull(np.array(corners)[:, :2])
    margin = -np.max(hull.equations[:, :2] @ com[:2] + hull.equations[:, 2])  # distance to the nearest edge
    assert margin > 0.02, f"CoM {com[:2]} only {margin:.3f} m inside the support polygon"
    assert com[2] > 0.4


def test_g1_reference_knees_bent_arms_down(g1):
    q = g1.q_reference()
    knee = q[g1.model.joints[g1.model.getJointId("left_knee_joint")].idx_q]
    assert 0.2 < knee < 0.8
    data = g1.model.createData()
    pin.framesForwardKinematics(g1.model, data, q)
    for side in ("left", "right"):
        palm = data.oMf[g1.frame_id(f"{side}_hand_palm_link")].translation
        shoulder = data.oMf[g1.frame_id(f"{side}_shoulder_pitch_link")].translation
        assert palm[2] < shoulder[2] - 0.25  # hands hang below the shoulders


def test_reference_posture_self_collision_free(any_robot):
    q = any_robot.q_reference()
    gm = any_robot.collision_model
    gd = pin.GeometryData(gm)
    pin.computeDistances(any_robot.model, any_robot.model.createData(), gm, gd, q)
    distances = np.array([r.min_distance for r in gd.distanceResults])
    assert len(distances) > 100
    worst = int(np.argmin(distances))
    pair = gm.collisionPairs[worst]
    assert distances[worst] > 0.0, (gm.geometryObjects[pair.first].name, gm.geometryObjects[pair.second].name)


# -- collision geometry -------------------------------------------------------------------------
def test_collision_meshes_are_convex_hulls(any_robot):
    kinds = {type(obj.geometry).__name__ for obj in any_robot.collision_model.geometryObjects}
    assert "Convex" in kinds
    assert kinds <= {"Convex", "Box", "Cylinder", "Sphere", "Capsule"}
    assert set(any_robot.env_geometry_ids) == set(range(any_robot.collision_model.ngeoms))


def test_hull_distance_equals_raw_mesh_distance(g1):
    """Rungs 5 cm in front of / behind / below the shin, the forearm and the palm: hull and raw mesh
    agree within 1 mm. Diagonally, where a rung faces a concave patch, the hull is conservative
    (closer), never farther."""
    q = g1.q_reference()
    data = g1.model.createData()
    pin.framesForwardKinematics(g1.model, data, q)
    pin.updateGeometryPlacements(g1.model, data, g1.collision_model, g1.collision_data, q)
    urdf_root = ET.parse(g1.config.urdf_path).getroot()
    rung = coal.Cylinder(0.02, 0.6)  # [m] axis = local z, turned onto world y below
    R_rung = pin.rpy.rpyToMatrix(math.pi / 2, 0, 0)
    directions = [np.array(d, dtype=float) for d in ((1, 0, 0), (-1, 0, 0), (0, 0, -1), (1, 0, -1))]
    n_pairs = 0
    for link in ("left_knee_link", "left_elbow_link", "left_hand_palm_link"):
        gid = g1.collision_model.getGeometryId(f"{link}_0")
        obj = g1.collision_model.geometryObjects[gid]
        assert isinstance(obj.geometry, coal.Convex)
        oMg = g1.collision_data.oMg[gid]
        tf = coal.Transform3s(oMg.rotation, oMg.translation)
        hull_points = np.asarray(obj.geometry.points()) @ oMg.rotation.T + oMg.translation
        mesh_file = urdf_root.find(f"link[@name='{link}']/collision/geometry/mesh").get("filename")
        raw = coal.MeshLoader().load(str(share_dir() / mesh_file.replace("package://", "")), np.ones(3))
        assert raw.num_vertices > obj.geometry.num_points  # really a different shape
        for d in directions:
            d = d / np.linalg.norm(d)
            # rung axis along world y, 5 cm beyond the link's extent in direction d
            reach = np.max((hull_points - hull_points.mean(axis=0)) @ d)
            T_rung = coal.Transform3s(R_rung, hull_points.mean(axis=0) + (reach + 0.05 + 0.02) * d)
            d_raw = coal.distance(raw, tf, rung, T_rung, coal.DistanceRequest(), coal.DistanceResult())
            d_hull = coal.distance(obj.geometry, tf, rung, T_rung, coal.DistanceRequest(), coal.DistanceResult())
            assert 0.05 - 1e-6 <= d_hull < 0.15  # beyond the support plane, never closer
            assert d_hull <= d_raw + 1e-6
            if np.count_nonzero(d) == 1:
                assert abs(d_hull - d_raw) < 1e-3, (link, d, d_hull, d_raw)
                n_pairs += 1
    assert n_pairs == 9


def test_g1_grasp_cylinder_sits_in_the_palm(g1):
    """The 4 cm rung of the grasp surface touches the palm face without entering it."""
    q = g1.q_reference()
    data = g1.model.createData()
    pin.framesForwardKinematics(g1.model, data, q)
    pin.updateGeometryPlacements(g1.model, data, g1.collision_model, g1.collision_data, q)
    for limb in HANDS:
        s = g1.config.limbs[limb].surface
        assert s.kind == "grasp" and s.radius == pytest.approx(0.02)
        T = g1.T_world_surface(limb, q)
        np.testing.assert_allclose(T[:3, :3].T @ T[:3, :3], np.eye(3), atol=1e-9)
        # coal cylinders run along local z: rotate surface x (the grasp axis) onto z
        R = T[:3, :3] @ pin.rpy.rpyToMatrix(0, math.pi / 2, 0)
        gid = g1.collision_model.getGeometryId(f"{s.frame}_0")
        oMg = g1.collision_data.oMg[gid]
        d = coal.distance(coal.Cylinder(s.radius, s.length), coal.Transform3s(R, T[:3, 3]),
                          g1.collision_model.geometryObjects[gid].geometry,
                          coal.Transform3s(oMg.rotation, oMg.translation),
                          coal.DistanceRequest(), coal.DistanceResult())
        assert -0.003 < d < 0.003, (limb, d)


def test_g1_foot_box_replaces_the_sole_spheres(g1):
    """The sole polygon spans the URDF's corner spheres, its plane is their bottom."""
    urdf_root = ET.parse(g1.config.urdf_path).getroot()
    for limb in FEET:
        s = g1.config.limbs[limb].surface
        spheres = urdf_root.findall(f"link[@name='{s.frame}']/collision")
        centres = np.array([[float(x) for x in c.find("origin").get("xyz").split()] for c in spheres])
        radii = [float(c.find("geometry/sphere").get("radius")) for c in spheres]
        assert len(spheres) == 4
        np.testing.assert_allclose(s.vertices[:, 2], centres[:, 2] - radii, atol=1e-9)
        lo, hi = s.vertices.min(axis=0), s.vertices.max(axis=0)
        np.testing.assert_allclose([lo[0], hi[0]], [centres[:, 0].min(), centres[:, 0].max()])
        np.testing.assert_allclose([lo[1], hi[1]], [centres[:, 1].min(), centres[:, 1].max()])
        box = g1.collision_model.geometryObjects[g1.collision_model.getGeometryId(f"{s.frame}_foot_box")]
        np.testing.assert_allclose(2 * box.geometry.halfSide, [0.17, 0.06, g1.config.sim.foot_box.thickness])
        names = [o.name for o in g1.collision_model.geometryObjects if o.name.startswith(s.frame)]
        assert names == [f"{s.frame}_foot_box"]  # the spheres are gone


def test_armature_in_model_matches_urdf_plus_armature(g1):
    a = g1.config.sim.armature
    link = ET.parse(g1.config.urdf_path).getroot().find("link[@name='left_knee_link']/inertial/inertia")
    I_urdf = np.array([[float(link.get(k)) for k in row] for row in
                       (("ixx", "ixy", "ixz"), ("ixy", "iyy", "iyz"), ("ixz", "iyz", "izz"))])
    I_model = g1.model.inertias[g1.model.getJointId("left_knee_joint")].inertia
    np.testing.assert_allclose(I_model, I_urdf + a * np.eye(3), atol=1e-12)


# -- config numbers -------------------------------------------------------------------------------
def test_motor_models_reach_the_urdf_limits(any_robot):
    urdf = _urdf_joints(any_robot.config.urdf_path)
    for name in any_robot.joint_names:
        m = any_robot.config.motor.for_joint(name)
        limit = urdf[name].find("limit")
        assert m.max_joint_torque == pytest.approx(float(limit.get("effort")), rel=0.01), name
        assert m.no_load_speed >= float(limit.get("velocity")), name
        assert m.supply_voltage / m.resistance > m.current_limit, name  # full duty at stall trips the driver
        assert m.trip_hold_off_s > 0


def test_pwm_gains_legs_stiff_arms_decreasing_toward_wrist(any_robot):
    cfg = any_robot.config
    kp = cfg.pwm.kp
    shared = set(cfg.limbs["left_hand"].joints) & set(cfg.limbs["right_hand"].joints)  # torso
    leg_kp = [kp[j] for limb in FEET for j in cfg.limbs[limb].joints]
    for limb in HANDS:
        arm = [j for j in cfg.limbs[limb].joints if j not in shared]
        gains = [kp[j] for j in arm]
        assert all(a >= b for a, b in zip(gains, gains[1:])), (limb, gains)
        assert gains[0] > gains[-1]
        assert min(leg_kp) > max(gains)
    assert set(kp) == set(cfg.pwm.kd) == set(any_robot.joint_names)


def test_every_number_section_has_a_source(any_robot):
    for key in ("base_height", "grip_strength", "capture_range", "motor", "pwm", "reference_posture", "sim"):
        assert len(any_robot.config.sources[key]) > 10
    assert any_robot.config.grip_strength > 0 and 0 < any_robot.config.capture_range < 0.1


# -- simulator URDF -----------------------------------------------------------------------------
def test_sim_urdf_loads_in_pybullet_with_matching_mass(any_robot, bullet):
    path = any_robot.sim_urdf_path()
    assert path == any_robot.sim_urdf_path() and path.parent.name == "robots"
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
    monkeypatch.setattr(robot_mod, "_cache_dir", lambda: tmp_path)
    writer = robot_mod._SimUrdfWriter(talos.config)
    assert writer.cached() is None
    path = writer.write(talos._full_collision_model, talos.mass)
    assert robot_mod._SimUrdfWriter(talos.config).cached() == path
    # another config (same name, one number changed) -> another file; the original stays valid
    changed = tmp_path / "talos.yaml"
    changed.write_text(talos.config.config_path.read_text().replace("grip_strength: 150.0", "grip_strength: 140.0"))
    other = robot_mod._SimUrdfWriter(load_robot_config(changed))
    assert other.out != path and other.cached() is None
    # a stale stamp is not reused
    path.write_text(path.read_text().replace("key=", "key=stale", 1))
    assert robot_mod._SimUrdfWriter(talos.config).cached() is None


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
    obj.write_text(robot_mod._mesh_obj(ascii_stl, np.ones(3)))
    shape = p.createCollisionShape(p.GEOM_MESH, fileName=str(obj), physicsClientId=bullet)
    assert shape >= 0


# -- validation ---------------------------------------------------------------------------------
def _set(data: dict, dotted: str, value) -> None:
    keys = dotted.split(".")
    for k in keys[:-1]:
        data = data[k]
    data[keys[-1]] = value


@pytest.mark.parametrize("path, value, field", [
    ("grip_strenght", 100.0, "grip_strenght"),                                     # typo: unknown key
    ("grip_strength", -5.0, "grip_strength"),
    ("capture_range", "far", "capture_range"),
    ("base_height", float("nan"), "base_height"),
    ("urdf", "g1_description/urdf/nope.urdf", "urdf"),
    ("locked_joints", ["left_hand_thumb_0_joint", "not_a_joint"], "locked_joints[1]"),
    ("reference_posture.left_knee_joint", 3.5, "reference_posture.left_knee_joint"),   # outside limits
    ("reference_posture.left_hand_index_0_joint", 0.1, "reference_posture.left_hand_index_0_joint"),
    ("limbs.left_foot.frame", "left_foot_link", "limbs.left_foot.frame"),
    ("limbs.left_foot.surface.kind", "grasp", "limbs.left_foot.surface.kind"),
    ("limbs.left_foot.surface.vertices", [[0, 0, 0], [0.1, 0.1, 0], [0.1, 0, 0], [0, 0.1, 0]],
     "limbs.left_foot.surface.vertices"),                                           # not convex
    ("limbs.left_hand.surface.normal", [0.0, 0.0, 1.0], "limbs.left_hand.surface.normal"),  # along the axis
    ("limbs.left_hand.ft_sensor", "left_ankle", "limbs.left_hand.ft_sensor"),       # not on the arm
    ("limbs.left_hand.colour", "red", "limbs.left_hand.colour"),
    ("ft_sensors.left_wrist", "d435_joint", "ft_sensors.left_wrist"),               # massless child
    ("pwm.joints", {"*_elbow_joint": {"kp": -1.0}}, "pwm.joints.*_elbow_joint.kp"),
    ("motor.joints", {"*_tail_joint": {"resistance": 1.0}}, "motor.joints.*_tail_joint"),
    ("motor.default.resistance", 0.0, "motor.default.resistance"),
    ("collision.ignore_pairs", [["pelvis", "nope_link"]], "collision.ignore_pairs[0]"),
    ("sim.foot_box", {"thickness": 0.01, "height": 0.02}, "sim.foot_box.height"),
    ("sources", {"urdf": "x"}, "sources.locked_joints"),
])
def test_bad_config_raises_spec_error_naming_the_field(path, value, field):
    data = _g1_yaml()
    _set(data, path, value)
    with pytest.raises(SpecError) as err:
        parse_robot_config(data)
    assert err.value.field == field, str(err.value)


def test_missing_limb_is_named():
    data = _g1_yaml()
    del data["limbs"]["right_hand"]
    with pytest.raises(SpecError) as err:
        parse_robot_config(data)
    assert err.value.field == "limbs.right_hand"


def test_model_checks_base_height_and_flat_feet():
    data = yaml.safe_load((robots_config_dir() / "romeo.yaml").read_text())
    wrong_height = copy.deepcopy(data)
    wrong_height["base_height"] += 0.05
    with pytest.raises(SpecError) as err:
        RobotModel(parse_robot_config(wrong_height))
    assert err.value.field == "base_height" and "0.84" in err.value.rule
    tilted = copy.deepcopy(data)
    tilted["reference_posture"]["LAnklePitch"] = -0.2
    with pytest.raises(SpecError) as err:
        RobotModel(parse_robot_config(tilted))
    assert err.value.field == "reference_posture" and "tilted" in err.value.rule
