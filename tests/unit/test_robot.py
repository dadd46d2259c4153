"""climb_core.robot / robot_config / geometry_cache: configs, Pinocchio models, convex hulls (and their
on-disk cache), reference posture. The simulator's URDF: tests/unit/test_sim_urdf.py."""
from __future__ import annotations

import copy
import math
import pathlib
import xml.etree.ElementTree as ET

import coal
import numpy as np
import pinocchio as pin
import pytest
import yaml
from scipy.spatial import ConvexHull

from climb_core.contact import FEET, HANDS, LIMBS
from climb_core.errors import SpecError
from climb_core.robot import (ROBOTS_DIR, RobotModel, available_robots, load_robot,
                              load_robot_config, parse_robot_config, robots_config_dir, share_dir)

ROBOT_NAMES = ("g1", "talos", "romeo")


@pytest.fixture(scope="module")
def g1() -> RobotModel:
    return load_robot("g1")


@pytest.fixture(scope="module", params=ROBOT_NAMES)
def any_robot(request) -> RobotModel:
    return load_robot(request.param)




def _g1_yaml() -> dict:
    return yaml.safe_load((robots_config_dir() / "g1.yaml").read_text())


def _urdf_joints(path: pathlib.Path) -> dict[str, ET.Element]:
    return {j.get("name"): j for j in ET.parse(path).getroot().findall("joint")}


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
    ("locked_posture", {"left_hand_thumb_1_joint": -1.0}, "locked_posture.left_hand_thumb_1_joint"),  # outside limits
    ("locked_posture", {"left_knee_joint": 0.1}, "locked_posture.left_knee_joint"),  # not a locked joint
    ("locked_posture", {"left_hand_thumb_2_joint": "open"}, "locked_posture.left_hand_thumb_2_joint"),
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
    ("ft_ranges.left_ankle.force", 0.0, "ft_ranges.left_ankle.force"),
    ("ft_ranges.left_wrist", {"force": 300.0}, "ft_ranges.left_wrist.torque"),
    ("ft_ranges.left_knee", {"force": 1.0, "torque": 1.0}, "ft_ranges.left_knee"),    # not a sensor
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


SWUNG_THUMBS = {"left_hand_thumb_1_joint": -0.6, "right_hand_thumb_1_joint": 0.6}  # [rad] thumb_1 at its stop


def test_locked_posture_defaults_to_zero_and_needs_a_source_when_set():
    data = _g1_yaml()
    cfg = parse_robot_config(data)
    assert set(cfg.locked_posture) == set(cfg.locked_joints)
    assert all(v == 0.0 for v in cfg.locked_posture.values())  # every Dex3 joint's range holds 0
    data["locked_posture"] = dict(SWUNG_THUMBS)
    with pytest.raises(SpecError) as err:
        parse_robot_config(data)
    assert err.value.field == "sources.locked_posture"
    data["sources"]["locked_posture"] = "a test"
    cfg = parse_robot_config(data)
    assert cfg.locked_posture["left_hand_thumb_1_joint"] == -0.6 and cfg.locked_posture["left_hand_thumb_2_joint"] == 0.0


def _thumb_reach_past_the_palm_face(robot: RobotModel, q: np.ndarray) -> float:
    """[m] farthest point of the left thumb's tip hull past the palm face (y = -0.0204, normal -y)."""
    data, gdata = robot.model.createData(), pin.GeometryData(robot.collision_model)
    pin.forwardKinematics(robot.model, data, q)
    pin.updateFramePlacements(robot.model, data)
    pin.updateGeometryPlacements(robot.model, data, robot.collision_model, gdata)
    gid = robot.collision_model.getGeometryId("left_hand_thumb_2_link_0")
    M = data.oMf[robot.model.getFrameId("left_hand_palm_link")].inverse() * gdata.oMg[gid]
    points = np.asarray(robot.collision_model.geometryObjects[gid].geometry.points())
    return float((-(points @ M.rotation.T + M.translation)[:, 1]).max() - 0.0204)


def test_the_whole_body_model_holds_the_locked_joints_at_the_locked_posture(g1):
    """The reduced model's thumb hull is where the full model puts it at ``locked_posture``: at the
    URDF zero 97 mm past the palm face, swung back to thumb_1's stop 78 mm."""
    import dataclasses

    swung = RobotModel(dataclasses.replace(g1.config, locked_posture={**g1.config.locked_posture, **SWUNG_THUMBS}))
    full, full_geom = g1.full_model, g1.full_collision_model
    for robot in (g1, swung):
        q_full = pin.neutral(full)
        for name, value in robot.config.locked_posture.items():
            q_full[full.joints[full.getJointId(name)].idx_q] = value
        data_full, gdata_full = full.createData(), pin.GeometryData(full_geom)
        pin.forwardKinematics(full, data_full, q_full)
        pin.updateGeometryPlacements(full, data_full, full_geom, gdata_full)
        q = pin.neutral(robot.model)
        data, gdata = robot.model.createData(), pin.GeometryData(robot.collision_model)
        pin.forwardKinematics(robot.model, data, q)
        pin.updateGeometryPlacements(robot.model, data, robot.collision_model, gdata)
        name = "left_hand_thumb_2_link_0"
        assert np.allclose(gdata_full.oMg[full_geom.getGeometryId(name)].homogeneous,
                           gdata.oMg[robot.collision_model.getGeometryId(name)].homogeneous, atol=1e-9)
    assert _thumb_reach_past_the_palm_face(g1, pin.neutral(g1.model)) == pytest.approx(0.097, abs=0.002)
    assert _thumb_reach_past_the_palm_face(swung, pin.neutral(swung.model)) == pytest.approx(0.078, abs=0.002)


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


# -- the collision geometry cache ---------------------------------------------------------------
def test_cached_collision_geometry_equals_the_hulls_built_from_the_source_meshes(monkeypatch, tmp_path):
    """The fast path (hulls read back from the cached OBJ files) builds the same collision model as
    the slow path (qhull on the source meshes): same objects, same placements, same hull vertices."""
    from climb_core import geometry_cache

    monkeypatch.setattr(geometry_cache, "cache_dir", lambda: tmp_path)
    config = load_robot_config("g1")
    slow = RobotModel(config, use_geometry_cache=False)  # computes the hulls, writes the cache
    assert geometry_cache.CollisionUrdfCache(config).cached() is not None
    fast = RobotModel(config)
    a, b = slow.collision_model.geometryObjects, fast.collision_model.geometryObjects
    assert [o.name for o in a] == [o.name for o in b] and len(a) > 20
    for oa, ob in zip(a, b):
        assert oa.parentJoint == ob.parentJoint
        np.testing.assert_allclose(oa.placement.homogeneous, ob.placement.homogeneous, atol=1e-9)
        if isinstance(oa.geometry, coal.ConvexBase):
            pa = np.sort(np.asarray(oa.geometry.points()), axis=0)
            pb = np.sort(np.asarray(ob.geometry.points()), axis=0)
            assert pa.shape == pb.shape
            np.testing.assert_allclose(pa, pb, atol=1e-7)


def test_collision_cache_key_follows_the_config(monkeypatch, tmp_path):
    from climb_core import geometry_cache

    # loaded first: the first load_robot("talos") of a worker writes its collision cache (into the
    # real cache directory here, not into tmp_path, which must start empty)
    talos = load_robot("talos")
    monkeypatch.setattr(geometry_cache, "cache_dir", lambda: tmp_path)
    cache = geometry_cache.CollisionUrdfCache(talos.config)
    assert cache.cached() is None
    path = cache.write(talos.full_collision_model)
    assert geometry_cache.CollisionUrdfCache(talos.config).cached() == path
    changed = tmp_path / "talos.yaml"
    changed.write_text(talos.config.config_path.read_text().replace("grip_strength: 150.0", "grip_strength: 140.0"))
    other = geometry_cache.CollisionUrdfCache(load_robot_config(changed))
    assert other.out != path and other.cached() is None
    path.write_text(path.read_text().replace("key=", "key=stale", 1))
    assert geometry_cache.CollisionUrdfCache(talos.config).cached() is None
    assert "<visual" not in other.write(talos.full_collision_model).read_text()
