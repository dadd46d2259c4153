"""Unilateral hand contacts (issue 17): G1's push surfaces (kind ``palm``: the back of the hand, as
the Dex3 thumb stands proud of the palm face), a hand pushing on narrow_passage's palm block
through the physics-constrained IK and the core feasibility check, and the rule that a hand
grasps only bilateral surfaces and cannot pull with its push surface."""
from __future__ import annotations

import dataclasses

import numpy as np
import pinocchio as pin
import pytest
from scipy.spatial import Delaunay

from climb_core import feasibility, holds
from climb_core.contact import Hold, Stance
from climb_core.environment import build_environment
from climb_core.errors import SpecError
from climb_core.robot import load_robot
from planner_node import pcik
from planner_node.settings import load_settings

GRAVITY = 9.81
BLOCK_TOP_Z = 0.80  # narrow_passage.yaml: palm_block top (floor 0.12 + 0.68)
BLOCK_X, BLOCK_Y = (2.0, 3.4), (-0.40, -0.20)  # its top face's extent [m]


@pytest.fixture(scope="module")
def passage():
    return build_environment("narrow_passage")


def _hand_hulls_in_palm_frame(robot, side: str) -> dict[str, np.ndarray]:
    """Collision hull vertices (n, 3) of every link of the hand (palm, fingers and thumb at the
    locked posture, from the full URDF) in the palm link frame."""
    full, geom = robot.full_model, robot.full_collision_model
    data = full.createData()
    gdata = pin.GeometryData(geom)
    pin.forwardKinematics(full, data, pin.neutral(full))
    pin.updateFramePlacements(full, data)
    pin.updateGeometryPlacements(full, data, geom, gdata)
    T_palm = data.oMf[full.getFrameId(f"{side}_hand_palm_link")]
    out = {}
    for i, g in enumerate(geom.geometryObjects):
        if g.name.startswith(f"{side}_hand_") and hasattr(g.geometry, "num_points"):
            pts = np.array([g.geometry.points(k) for k in range(g.geometry.num_points)])
            M = T_palm.inverse() * gdata.oMg[i]
            out[g.name] = pts @ M.rotation.T + M.translation
    return out


@pytest.mark.parametrize("side", ["left", "right"])
def test_g1_push_surface_is_the_back_of_the_hand(g1, side):
    limb = g1.config.limbs[f"{side}_hand"]
    back, grasp = limb.surfaces[f"{side}_hand_back"], limb.surface
    assert grasp.kind == "grasp" and back.kind == "palm" and back.frame == f"{side}_hand_palm_link"
    assert list(limb.surfaces) == [f"{side}_grasp", f"{side}_hand_back"]
    n, c = back.normal, back.centre
    assert np.allclose(n, -grasp.normal)  # out of the back of the hand
    hulls = _hand_hulls_in_palm_frame(g1, side)
    hull = hulls[f"{side}_hand_palm_link_0"]
    height = (hull - c) @ n  # signed height of every hull vertex above the polygon's plane
    assert abs(height.max()) <= 1e-4  # the plane touches the palm link's hull, which is all behind it
    # nothing of the hand (fingers, thumb) stands beyond the plane: a flat surface meets the back
    # of the hand first. (On the palm side the thumb stands >= 29 mm proud of the palm face.)
    for name, pts in hulls.items():
        assert ((pts - c) @ n).max() <= 1e-4, f"{name} passes the push plane"
    assert max(((pts - c) @ -n).max() for name, pts in hulls.items() if "thumb" in name) > 0.029 + 0.04
    # every corner lies on the hull's face: inside the outline of its vertices within 2 mm of the plane
    corners = back.vertices
    assert np.allclose((corners - c) @ n, 0.0, atol=1e-9)
    face = hull[height > height.max() - 2e-3]
    e1 = back.T_frame_surface[:3, 0]
    e2 = np.cross(n, e1)
    outline = Delaunay(np.column_stack([(face - c) @ e1, (face - c) @ e2]))
    assert (outline.find_simplex(np.column_stack([(corners - c) @ e1, (corners - c) @ e2])) >= 0).all()
    area = np.linalg.norm(np.cross(corners[1] - corners[0], corners[3] - corners[0]))
    assert 1e-3 < area < 6e-3  # [m^2] hand-sized (Dex3 palm link 0.087 x 0.088 m)


def test_rule_grasp_on_bilateral_palm_elsewhere(g1, env, passage):
    block, rung = passage.surfaces["palm_block"], env.surfaces["rung_3"]
    assert holds.hand_surface_for(g1, "right_hand", block).name == "right_hand_back"
    assert holds.hand_surface_for(g1, "right_hand", rung).name == "right_grasp"
    assert holds.robot_surface_for(g1, "left_foot", block).name == "left_sole"
    with pytest.raises(SpecError) as err:  # talos has no palm: it cannot push on the block
        holds.hand_surface_for(load_robot("talos"), "right_hand", block)
    assert err.value.field == "hold.robot_surface" and "not bilateral" in str(err.value)
    assert holds.hand_surface_for(load_robot("talos"), "right_hand", block, required=False) is None


def test_a_grasp_on_the_block_is_refused(g1, passage):
    with pytest.raises(SpecError) as err:
        holds.make_hold(g1, passage, "right_hand", "palm_block", position=np.array([2.3, -0.3, 0.8]), yaw=0.0,
                        robot_surface="right_grasp")
    assert err.value.field == "hold.env_surface" and "not bilateral" in str(err.value)
    spec = pcik.ContactSpec("right_hand", pcik.FLOATING, surface="palm_block", robot_surface="right_grasp")
    with pytest.raises(SpecError, match="not bilateral"):
        pcik.solve(g1, passage, _seed(g1), [spec], physics=False, collision=False)
    with pytest.raises(SpecError) as err:
        holds.make_hold(g1, passage, "right_hand", "palm_block", robot_surface="right_elbow")
    assert err.value.field == "hold.robot_surface"


def _seed(robot) -> np.ndarray:
    q = robot.q_reference()
    q[0], q[2] = 2.15, q[2] + 0.12  # standing on the floor before the step
    return q


@pytest.fixture(scope="module")
def palm_push(g1, passage):
    """Left foot on the floor, right foot lifted 2 cm over the step (zero force), the right hand
    floating onto the block (the IK picks its hold), then pushing on it: the CoM target between
    the foot and the block loads the hand."""
    hp = feasibility.load_config().holds
    left = holds.make_hold(g1, passage, "left_foot", "floor", position=np.array([2.2, 0.15, 0.12]), yaw=0.0,
                           params=hp)
    right = holds.make_hold(g1, passage, "right_foot", "step", position=np.array([2.5, -0.10, 0.45]), yaw=0.0,
                            params=hp)
    T_right = holds.hold_target(g1, passage, right, params=hp).T_world_surface.copy()
    T_right[2, 3] += 0.02
    contacts = [pcik.ContactSpec("left_foot", pcik.REGULAR, hold=left),
                pcik.ContactSpec("right_foot", pcik.ZERO_FORCE, pose=T_right),
                pcik.ContactSpec("right_hand", pcik.FLOATING, surface="palm_block",
                                 preferred_position=np.array([2.25, -0.27, BLOCK_TOP_Z]))]
    found = pcik.solve(g1, passage, _seed(g1), contacts, params=load_settings().pcik)
    assert found.success, pcik.describe_failure(found)
    # the hand found its hold with zero force (the CoM over the left sole); now it carries load:
    # the hold regular, the CoM pulled between the left sole and the block
    contacts[2] = pcik.ContactSpec("right_hand", pcik.REGULAR, hold=found.holds["right_hand"])
    params = dataclasses.replace(load_settings().pcik, com_weight=1000.0)
    res = pcik.solve(g1, passage, found.q, contacts, params=params, com_target=np.array([2.2, 0.0]))
    assert res.success, pcik.describe_failure(res)
    return res, left


def _palm_forces(check: feasibility.FeasibilityResult, hold: Hold) -> tuple[np.ndarray, np.ndarray]:
    """(normal, tangential) force magnitude per palm point [N]."""
    f = check.contact_forces[hold.limb]
    fn = np.einsum("ij,ij->i", f, hold.normals)
    return fn, np.linalg.norm(f - fn[:, None] * hold.normals, axis=1)


def test_palm_pushes_on_the_block_with_a_tenth_of_the_weight(g1, passage, palm_push):
    res, left = palm_push
    palm = res.holds["right_hand"]
    assert (palm.robot_surface, palm.env_surface, palm.bilateral, len(palm.points)) == \
        ("right_hand_back", "palm_block", False, 4)
    # forward kinematics: the palm polygon lies on the block's top face, its normal into the block
    data = g1.model.createData()
    pin.framesForwardKinematics(g1.model, data, res.q)
    rs = g1.config.limbs["right_hand"].surfaces["right_hand_back"]
    T_frame = data.oMf[g1.frame_id(rs.frame)].homogeneous
    corners = rs.vertices @ T_frame[:3, :3].T + T_frame[:3, 3]
    assert np.abs(corners[:, 2] - BLOCK_TOP_Z).max() < 2e-3
    assert (corners[:, 0] > BLOCK_X[0]).all() and (corners[:, 0] < BLOCK_X[1]).all()
    assert (corners[:, 1] > BLOCK_Y[0]).all() and (corners[:, 1] < BLOCK_Y[1]).all()
    assert (T_frame @ rs.T_frame_surface)[2, 2] < -np.cos(np.radians(3.0))  # push normal points down
    sole = g1.T_world_surface("right_foot", res.q)[2, 3]
    assert 0.01 < sole - 0.45 < 0.03  # the right foot is over the step, unloaded
    # the frozen core check on the stance left foot + right palm, collisions included
    check = feasibility.check(g1, passage, res.q, Stance((left, palm)))
    assert check.feasible, check.summary()
    weight = pin.computeTotalMass(g1.model) * GRAVITY
    fn, ft = _palm_forces(check, palm)
    assert fn.sum() >= 0.10 * weight, f"palm carries {fn.sum():.1f} N of {weight:.1f} N"
    assert (fn >= -1e-6).all() and (ft <= palm.friction * fn + 1e-6).all()  # pushes, inside its cone
    total = sum(f.sum(axis=0) for f in check.contact_forces.values())
    assert abs(total[2] - weight) < 1e-3 * weight


def test_a_palm_cannot_pull(g1, passage, palm_push):
    res, left = palm_push
    palm = res.holds["right_hand"]
    stance = Stance((left, palm))
    pelvis = g1.model.frames[g1.frame_id("pelvis")]
    data = g1.model.createData()
    pin.framesForwardKinematics(g1.model, data, res.q)
    base = data.oMf[g1.frame_id(pelvis.name)].translation

    def with_load(side: float, newtons: float) -> feasibility.FeasibilityResult:
        """A mass rigidly carried ``side`` m beside the pelvis (toward the block: negative)."""
        point = base + np.array([0.0, side, 0.0])
        return feasibility.check_equilibrium(g1, res.q, stance, env=passage,
                                             external_forces=[(pelvis.name, point, np.array([0.0, 0.0, -newtons]))])

    # on the block's side the hand pushes harder (2 kg; from 4 kg the wrist yaw joint passes its
    # torque limit: the push goes through the wrist, with half the block's friction counted) ...
    unloaded = feasibility.check_equilibrium(g1, res.q, stance, env=passage)
    toward = with_load(-0.4, 20.0)
    assert toward.feasible, toward.summary()
    assert _palm_forces(toward, palm)[0].sum() > _palm_forces(unloaded, palm)[0].sum() + 5.0
    # ... on the far side (30 kg 0.5 m out: the whole CoM beyond the left sole's outer edge), only
    # a pull on the hand would hold the robot
    away = with_load(+0.5, 300.0)
    assert not away.feasible and set(away.violated) & {"equilibrium", "friction"}, away.violated
    # and a palm hold cannot be declared bilateral
    pulling = Hold(palm.limb, palm.robot_surface, palm.env_surface, palm.points, palm.friction, bilateral=True,
                   grip_force_limit=200.0)
    with pytest.raises(SpecError) as err:
        feasibility.check_equilibrium(g1, res.q, Stance((left, pulling)), env=passage)
    assert err.value.field == "stance.right_hand.bilateral"


def _g1_data() -> dict:
    import yaml

    from climb_core.robot_config import resolve_config_path

    return yaml.safe_load(resolve_config_path("g1").read_text())


@pytest.mark.parametrize("change, field, rule", [
    (lambda e: e.update(kind="sole"), "limbs.left_hand.extra_surfaces[0].kind", "grasp or a palm"),
    (lambda e: e.update(kind="grasp"), "limbs.left_hand.extra_surfaces[0].vertices", "unknown key"),
    (lambda e: e.update(name="left_grasp"), "limbs.left_hand.extra_surfaces[0].name", "already a surface"),
    (lambda e: e.pop("normal"), "limbs.left_hand.extra_surfaces[0].normal", "missing"),
    (lambda e: e["vertices"][0].__setitem__(1, -0.03), "limbs.left_hand.extra_surfaces[0].vertices", "one plane"),
    (lambda e: e["vertices"].reverse(), "limbs.left_hand.extra_surfaces[0].vertices", "counter-clockwise"),
    (lambda e: e.update(normal=[0.0, 0.0, 0.0]), "limbs.left_hand.extra_surfaces[0].normal", "non-zero"),
])
def test_extra_surfaces_are_validated(change, field, rule):
    from climb_core.robot_config import parse_robot_config

    data = _g1_data()
    change(data["limbs"]["left_hand"]["extra_surfaces"][0])
    with pytest.raises(SpecError) as err:
        parse_robot_config(data)
    assert err.value.field == field and rule in err.value.rule


def test_one_surface_per_kind_and_limb_and_feet_only_soles():
    from climb_core.robot_config import parse_robot_config

    data = _g1_data()
    extra = data["limbs"]["left_hand"]["extra_surfaces"]
    extra.append(dict(extra[0], name="left_palm_2"))
    with pytest.raises(SpecError) as err:
        parse_robot_config(data)
    assert err.value.field == "limbs.left_hand.extra_surfaces[1].kind" and "one surface per kind" in err.value.rule
    data = _g1_data()
    data["limbs"]["left_foot"]["extra_surfaces"] = [dict(data["limbs"]["left_hand"]["extra_surfaces"][0])]
    with pytest.raises(SpecError) as err:
        parse_robot_config(data)
    assert err.value.field == "limbs.left_foot.extra_surfaces[0].kind" and "sole" in err.value.rule
    data = _g1_data()
    data["limbs"]["left_hand"]["extra_surfaces"] = {"name": "x"}
    with pytest.raises(SpecError) as err:
        parse_robot_config(data)
    assert err.value.field == "limbs.left_hand.extra_surfaces"


def test_the_zone_rule_measures_a_palm_hold_from_the_palm(g1, passage, palm_push):
    """A hand landing on / leaving the block with its back may touch the block near the hold
    (planner_node.adapt.zone_exclusions): the distance is the palm surface's to where the hold puts
    it, not the grasp surface's (6 cm away on G1's Dex3: the landing configuration's wrist then
    counted as a collision in verify_plan, -5.5 mm on narrow_passage's plan)."""
    from planner_node.adapt import AdaptContext, zone_exclusions

    res, _ = palm_push
    palm = res.holds["right_hand"]
    T_palm = g1.T_world_surface("right_hand", res.q, surface="right_hand_back")
    T_grasp = g1.T_world_surface("right_hand", res.q)
    assert np.allclose(T_grasp, g1.T_world_surface("right_hand", res.q, surface="right_grasp"))
    assert np.linalg.norm(T_palm[:3, 3] - T_grasp[:3, 3]) > 0.05
    ctx = AdaptContext(g1, passage, None, load_settings(), feasibility.load_config())
    assert np.linalg.norm(T_palm[:3, 3] - ctx.hold_origin(palm)) < 2e-3
    assert zone_exclusions(ctx, res.q, "right_hand", [palm]) == [("right_hand", "palm_block")]
    with pytest.raises(ValueError, match="no contact surface"):
        g1.T_world_surface("right_hand", res.q, surface="left_sole")
