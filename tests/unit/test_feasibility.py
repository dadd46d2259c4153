"""climb_core.feasibility: quasi-static feasibility against analytic answers (support polygon,
force and moment balance, grip, friction, torque limits) and the diagnosis of each constraint."""
from __future__ import annotations

import math

import numpy as np
import pinocchio as pin
import pytest

from climb_core import feasibility as fz
from climb_core import fixtures, holds, ik
from climb_core.contact import FEET, HANDS, Stance
from climb_core.errors import SpecError

GRAVITY = 9.81  # [m/s^2] Pinocchio's default gravity magnitude


@pytest.fixture(scope="module")
def cfg():
    return fz.load_config()


@pytest.fixture(scope="module")
def standing(g1, env):
    q = g1.q_reference()
    stance = Stance(tuple(holds.hold_from_configuration(g1, env, q, limb, "ground") for limb in FEET), "standing")
    return stance, q


def _com(robot, q):
    return pin.centerOfMass(robot.model, robot.model.createData(), q)


def _assert_balanced(robot, q, stance, res, external=()):
    """Newton-Euler balance of the whole body, independent of the Jacobians: the contact forces
    (and external forces) cancel gravity, and their moment about the CoM vanishes."""
    c = _com(robot, q)
    weight = np.array([0.0, 0.0, -robot.mass * GRAVITY])
    force, moment = weight.copy(), np.zeros(3)
    for hold in stance.holds:
        f = res.contact_forces[hold.limb]
        force += f.sum(axis=0)
        moment += np.cross(hold.positions - c, f).sum(axis=0)
    for _, point, F in external:
        force += F
        moment += np.cross(np.asarray(point) - c, F)
    np.testing.assert_allclose(force, 0.0, atol=1e-6 * robot.mass * GRAVITY)
    np.testing.assert_allclose(moment, 0.0, atol=1e-6 * robot.mass * GRAVITY)


def _assert_forces_admissible(stance, res, torque_limits, cfg):
    for hold in stance.holds:
        f = res.contact_forces[hold.limb]
        if hold.bilateral:
            assert np.abs(f.sum(axis=0)).max() <= hold.grip_force_limit + 1e-6
            continue
        fn = np.einsum("ij,ij->i", f, hold.normals)
        ft = np.linalg.norm(f - fn[:, None] * hold.normals, axis=1)
        assert (fn >= -1e-6).all()
        assert (ft <= cfg.check.friction_margin * hold.friction * fn + 1e-6).all()
    assert (np.abs(res.joint_torques) <= torque_limits + 1e-6).all()


# --------------------------------------------------------------------------------------------
# feasible stances: balance, cones, limits


def test_standing_is_feasible_and_balanced(g1, env, cfg, standing):
    stance, q = standing
    res = fz.check(g1, env, q, stance, cfg)
    assert res.feasible, res.summary()
    assert res.violated == []
    _assert_balanced(g1, q, stance, res)
    _assert_forces_admissible(stance, res, g1.effort_limits(), cfg)
    # symmetric robot: each foot carries half the weight
    for limb in FEET:
        assert res.contact_forces[limb][:, 2].sum() == pytest.approx(0.5 * g1.mass * GRAVITY, rel=0.01)
    assert res.contact_error < 1e-9 and res.min_distance > 0.0
    assert res.torque_margin == pytest.approx(1.0 - res.most_loaded_ratio)
    assert res.most_loaded_joint in g1.joint_names


def test_ladder_stance_torques_match_rnea_with_the_contact_forces(g1, env, cfg):
    """tau from the LP equals inverse dynamics (rnea, zero velocity) with the contact forces as
    external forces: an independent path through Pinocchio."""
    stance, q = fixtures.get("ladder_4_contacts", g1, env)
    res = fz.check(g1, env, q, stance, cfg)
    assert res.feasible, res.summary()
    _assert_balanced(g1, q, stance, res)
    _assert_forces_admissible(stance, res, g1.effort_limits(), cfg)
    model, data = g1.model, g1.model.createData()
    pin.framesForwardKinematics(model, data, q)
    fext = pin.StdVec_Force()
    for _ in range(model.njoints):
        fext.append(pin.Force.Zero())
    for hold in stance.holds:
        joint = model.frames[g1.frame_id(g1.config.limbs[hold.limb].surface.frame)].parentJoint
        for p, f in zip(hold.positions, res.contact_forces[hold.limb]):
            fext[joint] += data.oMi[joint].actInv(pin.Force(f, np.cross(p, f)))
    zero = np.zeros(model.nv)
    tau = pin.rnea(model, data, q, zero, zero, fext)
    np.testing.assert_allclose(tau[:6], 0.0, atol=1e-6)
    np.testing.assert_allclose(tau[6:], res.joint_torques, atol=1e-6)


def test_daqp_and_highs_agree(g1, env, cfg):
    stance, q = fixtures.get("ladder_no_left_foot", g1, env)
    a = fz.check(g1, env, q, stance, cfg, collision=False)
    b = fz.check(g1, env, q, stance, fz.with_check(cfg, solver="highs"), collision=False)
    assert a.feasible and b.feasible
    # HiGHS solves the pure LP (no regularisation): the same optimal load ratio
    assert a.load_ratio == pytest.approx(b.load_ratio, abs=2e-3)


# --------------------------------------------------------------------------------------------
# support polygon (feet only, flat ground)


def _feasible_with_com(g1, env, cfg, stance, q, com_xy):
    res = ik.solve(g1, env, q, stance, com_target=np.asarray(com_xy))
    assert res.success and res.com_error < 2e-3, (res.residual, res.com_error)
    return fz.check(g1, env, res.q, stance, cfg, collision=False)


@pytest.mark.parametrize("direction", [(1.0, 0.0), (-1.0, 0.0), (0.0, 1.0)])
def test_feet_only_feasible_iff_com_inside_support_polygon(g1, env, cfg, standing, direction):
    stance, q = standing
    corners = np.vstack([h.positions for h in stance.holds])[:, :2]
    d = np.array(direction)
    c0 = _com(g1, q)[:2]
    edge = float(np.max((corners - c0) @ d))  # polygon edge along d, from the CoM [m]
    lo, hi = 0.5 * edge, edge + 0.03
    assert _feasible_with_com(g1, env, cfg, stance, q, c0 + lo * d).feasible
    outside = _feasible_with_com(g1, env, cfg, stance, q, c0 + hi * d)
    assert not outside.feasible and outside.violated == ["equilibrium"]
    for _ in range(6):  # bisection on the CoM offset
        mid = 0.5 * (lo + hi)
        if _feasible_with_com(g1, env, cfg, stance, q, c0 + mid * d).feasible:
            lo = mid
        else:
            hi = mid
    assert abs(0.5 * (lo + hi) - edge) < 0.003  # boundary = the polygon edge within 3 mm


@pytest.mark.parametrize("direction", [(-1.0, 0.0), (0.0, 1.0)])
def test_sole_cop_margin_moves_the_boundary_inside_by_the_margin(g1, env, cfg, standing, direction):
    """``check.sole_cop_margin``: a flat sole's statics count its corners that far inside the sole
    (toward the heel, across the feet): the CoM's limit moves in by the margin, the holds stay."""
    stance, q = standing
    margin = 0.02
    inset = fz.with_check(cfg, sole_cop_margin=margin)
    corners = np.vstack([h.positions for h in stance.holds])[:, :2]
    d = np.array(direction)
    c0 = _com(g1, q)[:2]
    edge = float(np.max((corners - c0) @ d)) - margin
    between = c0 + (edge + 0.5 * margin) * d  # inside the sole, outside its inset polygon
    assert _feasible_with_com(g1, env, cfg, stance, q, between).feasible
    res = ik.solve(g1, env, q, stance, com_target=between)
    refused = fz.check(g1, env, res.q, stance, inset, collision=False)
    assert refused.violated == ["equilibrium"], refused.violated
    lo, hi = 0.0, edge + 0.5 * margin
    for _ in range(6):
        mid = 0.5 * (lo + hi)
        res = ik.solve(g1, env, q, stance, com_target=c0 + mid * d)
        if fz.check(g1, env, res.q, stance, inset, collision=False).feasible:
            lo = mid
        else:
            hi = mid
    assert abs(0.5 * (lo + hi) - edge) < 0.003  # the inset polygon's edge within 3 mm
    # the contact check still compares the sole with the holds' own corners
    assert fz.check(g1, env, q, stance, inset, collision=False).feasible


# --------------------------------------------------------------------------------------------
# hanging from two grasps: grip limits


@pytest.fixture(scope="module")
def hanging(g1, env):
    """Both hands on rung 8, the feet free, the CoM under the grasps (IK)."""
    hs = tuple(holds.make_hold(g1, env, limb, "rung_8", s) for limb, s in (("left_hand", 0.12), ("right_hand", -0.12)))
    stance = Stance(hs, "hang")
    q0 = g1.q_reference()
    for joint, value in {"left_shoulder_pitch_joint": -2.9, "right_shoulder_pitch_joint": -2.9,
                         "left_elbow_joint": 0.0, "right_elbow_joint": 0.0}.items():
        q0[g1.model.joints[g1.model.getJointId(joint)].idx_q] = value
    data = g1.model.createData()
    pin.framesForwardKinematics(g1.model, data, q0)
    centre = 0.5 * (hs[0].centre + hs[1].centre)
    palms = [data.oMf[g1.frame_id(g1.config.limbs[l].surface.frame)].translation for l in HANDS]
    q0[:3] += centre - 0.5 * (palms[0] + palms[1])
    res = ik.solve(g1, env, q0, stance, posture=q0, com_target=centre[:2])
    assert res.success
    return stance, res.q


def _with_grip(g1, env, stance, grip):
    return Stance(tuple(holds.make_hold(g1, env, h.limb, h.env_surface,
                                        float((h.centre - env.surfaces[h.env_surface].T_world_surface[:3, 3])
                                              @ env.surfaces[h.env_surface].T_world_surface[:3, 0]),
                                        grip_force_limit=grip) for h in stance.holds), "hang")


def test_two_grasps_carry_exactly_the_weight(g1, env, cfg, hanging):
    stance, q = hanging
    weight = g1.mass * GRAVITY
    loose = fz.with_check(cfg, torque_limit_fraction=100.0)  # isolate the grasps from the arm torques
    res = fz.check(g1, env, q, _with_grip(g1, env, stance, 0.55 * weight), loose, collision=False)
    assert res.feasible, res.summary()
    vertical = sum(res.contact_forces[limb][:, 2].sum() for limb in HANDS)
    assert vertical == pytest.approx(weight, rel=0.005)
    _assert_balanced(g1, q, stance, res)


def test_grip_below_half_the_weight_is_infeasible(g1, env, cfg, hanging):
    stance, q = hanging
    weight = g1.mass * GRAVITY
    loose = fz.with_check(cfg, torque_limit_fraction=100.0)
    ok = fz.check(g1, env, q, _with_grip(g1, env, stance, 0.505 * weight), loose, collision=False)
    assert ok.feasible, ok.summary()
    bad = fz.check(g1, env, q, _with_grip(g1, env, stance, 0.495 * weight), loose, collision=False)
    assert not bad.feasible
    assert sorted(bad.violated) == ["grip_limit:left_hand", "grip_limit:right_hand"]
    # even the best force distribution needs more than the grip: ratio > 1
    assert min(bad.grip_ratios.values()) > 1.0
    # with the real torque limits the grip is still named among the violations
    real = fz.check(g1, env, q, _with_grip(g1, env, stance, 0.45 * weight), cfg, collision=False)
    assert {"grip_limit:left_hand", "grip_limit:right_hand"} <= set(real.violated)


def test_robot_grip_strength_decides_the_hang(g1, env, cfg, hanging):
    """With the robot's own grip strength: the grasps fail iff the grip is below half the weight."""
    stance, q = hanging
    loose = fz.with_check(cfg, torque_limit_fraction=100.0)
    res = fz.check(g1, env, q, stance, loose, collision=False)
    assert all(h.grip_force_limit == g1.config.grip_strength for h in stance.holds)
    if g1.config.grip_strength < 0.5 * g1.mass * GRAVITY:
        assert sorted(res.violated) == ["grip_limit:left_hand", "grip_limit:right_hand"]
    else:
        assert res.feasible, res.summary()
        assert max(res.grip_ratios.values()) == pytest.approx(0.5 * g1.mass * GRAVITY / g1.config.grip_strength,
                                                             rel=0.01)


def test_grasp_moment_limit_caps_the_moment_each_grasp_carries(g1, env, cfg, hanging):
    """A horizontal push on the pelvis of a robot hanging from two grasps on one rung turns it about
    the rung: only moments at the grasps hold it. The 8 points alone carry it (their boxes allow
    tens of N m); grasp_moment_limit caps each world-axis component about the grasp centre and
    names the grasp when the push needs more."""
    stance, q = hanging
    data = g1.model.createData()
    pin.framesForwardKinematics(g1.model, data, q)
    pelvis = data.oMf[g1.model.getFrameId("pelvis")].translation.copy()
    push = [("pelvis", pelvis, np.array([20.0, 0.0, 0.0]))]
    loose = fz.with_check(cfg, torque_limit_fraction=100.0)

    def moments(res):
        return {h.limb: np.cross(h.positions - h.centre, res.contact_forces[h.limb]).sum(axis=0) for h in stance.holds}

    free = fz.check(g1, env, q, stance, loose, collision=False, external_forces=push)
    assert free.feasible, free.summary()
    need = sum(abs(m[1]) for m in moments(free).values())  # about the rung axis' normal (y: the rung)
    lever = float((0.5 * (stance.holds[0].centre + stance.holds[1].centre) - pelvis)[2])
    assert need == pytest.approx(20.0 * lever, rel=0.05)  # the push's moment about the rung
    capped = fz.check(g1, env, q, stance, fz.with_check(loose, grasp_moment_limit=0.6 * need), collision=False,
                      external_forces=push)
    assert capped.feasible, capped.summary()
    assert all(np.abs(m).max() <= 0.6 * need + 1e-6 for m in moments(capped).values())
    bad = fz.check(g1, env, q, stance, fz.with_check(loose, grasp_moment_limit=0.4 * need), collision=False,
                   external_forces=push)
    assert sorted(bad.violated) == ["grip_limit:left_hand", "grip_limit:right_hand"]
    assert min(bad.grip_ratios.values()) > 1.0


# --------------------------------------------------------------------------------------------
# friction


def _sole_centres(g1, q):
    return {limb: g1.T_world_surface(limb, q)[:3, 3] for limb in FEET}


@pytest.mark.parametrize("angle_deg", [0.0, 30.0, 45.0, 135.0, 260.0])
def test_horizontal_force_beyond_mu_is_infeasible(g1, env, cfg, standing, angle_deg):
    """Feet flat on the ground, a horizontal push on each sole: feasible below the pyramid's
    inscribed bound mu cos(pi/m), infeasible ("friction") beyond mu, in every direction."""
    stance, q = standing
    mu = env.surfaces["ground"].friction
    weight = g1.mass * GRAVITY
    m = cfg.check.friction_pyramid_sides
    direction = np.array([math.cos(math.radians(angle_deg)), math.sin(math.radians(angle_deg)), 0.0])
    frames = {limb: g1.config.limbs[limb].surface.frame for limb in FEET}
    centres = _sole_centres(g1, q)

    def push(total):
        return [(frames[limb], centres[limb], 0.5 * total * direction) for limb in FEET]

    inside = push(0.97 * mu * math.cos(math.pi / m) * weight)
    res = fz.check(g1, env, q, stance, cfg, external_forces=inside)
    assert res.feasible, res.summary()
    _assert_balanced(g1, q, stance, res, inside)
    _assert_forces_admissible(stance, res, g1.effort_limits(), cfg)
    beyond = fz.check(g1, env, q, stance, cfg, external_forces=push(1.03 * mu * weight))
    assert beyond.violated == ["friction"]


# --------------------------------------------------------------------------------------------
# torque limits


def test_load_in_the_hand_exceeds_the_arm_torques(g1, env, cfg, standing):
    """A weight hanging from the left palm: arm joint torques follow from inverse dynamics alone
    (serial chain, no contact on it); the check finds the same torques and names the arm joints
    that exceed their limits."""
    stance, q = standing
    frame = g1.config.limbs["left_hand"].surface.frame
    data = g1.model.createData()
    pin.framesForwardKinematics(g1.model, data, q)
    point = data.oMf[g1.frame_id(frame)].translation
    limits = g1.effort_limits()
    arm = [g1.joint_names.index(j) for j in g1.config.limbs["left_hand"].joints if j.startswith("left_")]
    for mass in (1.0, 20.0):  # [kg]
        load = [(frame, point, np.array([0.0, 0.0, -mass * GRAVITY]))]
        res = fz.check(g1, env, q, stance, cfg, external_forces=load)
        fext = pin.StdVec_Force()
        for _ in range(g1.model.njoints):
            fext.append(pin.Force.Zero())
        joint = g1.model.frames[g1.frame_id(frame)].parentJoint
        F = load[0][2]
        fext[joint] = data.oMi[joint].actInv(pin.Force(F, np.cross(point, F)))
        zero = np.zeros(g1.model.nv)
        tau = pin.rnea(g1.model, data, q, zero, zero, fext)[6:]
        np.testing.assert_allclose(res.joint_torques[arm], tau[arm], atol=1e-6)
        over = {g1.joint_names[i] for i in arm if abs(tau[i]) > limits[i]}
        named = {v.split(":", 1)[1] for v in res.violated if v.startswith("torque_limit:")}
        if mass == 1.0:
            assert res.feasible and not over
        else:
            assert over and over <= named and not res.feasible
            assert all(v.startswith("torque_limit:") for v in res.violated)


# --------------------------------------------------------------------------------------------
# contact, joint limits, collision


def test_contact_violation_is_measured(g1, env, cfg, standing):
    stance, q = standing
    lifted = q.copy()
    lifted[2] += 0.02
    res = fz.check(g1, env, lifted, stance, cfg)
    assert "contact" in res.violated
    assert res.contact_error == pytest.approx(0.02, abs=1e-9)


def test_foot_on_a_rung_may_sit_anywhere_along_the_sole(g1, env, cfg):
    """A sole on a rung is in contact while the rung line is under the sole: sliding the foot
    along itself by 3 cm keeps the contact, by 12 cm (rung beyond the heel) breaks it."""
    stance, q = fixtures.get("ladder_4_contacts", g1, env)
    foot_only = Stance((stance.hold("left_foot"),))
    for shift, ok in ((0.03, True), (-0.03, True), (0.12, False)):
        moved = q.copy()
        moved[0] += shift  # the whole robot slides along the foot's (world x) axis
        res = fz.check(g1, env, moved, foot_only, cfg, collision=False)
        assert ("contact" not in res.violated) == ok, (shift, res.contact_error)


def test_joint_limit_violation_is_named(g1, env, cfg, standing):
    stance, q = standing
    bad = q.copy()
    j = g1.model.getJointId("left_knee_joint")
    bad[g1.model.joints[j].idx_q] = g1.model.upperPositionLimit[g1.model.joints[j].idx_q] + 0.05
    res = fz.check(g1, env, bad, stance, cfg, contact=False)
    assert "joint_limits" in res.violated
    assert res.details["joint_limits"] == ["left_knee_joint"]
    assert res.joint_limit_violation == pytest.approx(0.05)


def test_standing_inside_the_ladder_collides(g1, env, cfg):
    q = g1.q_reference()
    q[0] = env.rung(1).T_world_surface[0, 3] - 0.02  # the shins through rung 1
    stance = Stance(tuple(holds.hold_from_configuration(g1, env, q, limb, "ground") for limb in FEET))
    res = fz.check(g1, env, q, stance, cfg)
    assert res.violated == ["collision"]
    assert res.min_distance < 0.0
    assert any(other == "env:rung_1" for _, other, _ in res.details["collisions"])


def test_bad_input_names_the_field(g1, env, cfg, standing):
    stance, q = standing
    with pytest.raises(SpecError) as err:
        fz.check(g1, env, q[:-1], stance, cfg)
    assert err.value.field == "q"
    with pytest.raises(SpecError) as err:
        fz.check(g1, env, q, list(stance.holds), cfg)
    assert err.value.field == "stance"


def test_compiled_stances_are_shared_by_equal_holds_and_configs(g1, env, cfg, standing):
    """The planner builds new Stance objects from the same holds, and derives equal configs again
    and again: both hit the compiled-stance cache, and the result is the one of a fresh compile."""
    stance, q = standing
    ws = fz.workspace(g1)
    c1 = fz.with_check(cfg, collision_margin=0.004)
    c2 = fz.with_check(cfg, collision_margin=0.004)
    assert c1 is not c2 and c1 == c2
    cs = ws.compiled(env, stance, c1)
    again = Stance(tuple(stance.holds), name="other name")
    assert ws.compiled(env, again, c2) is cs
    assert ws.compiled(env, stance, fz.with_check(cfg, collision_margin=0.005)) is not cs
    moved = holds.hold_from_configuration(g1, env, q, "left_foot", "ground")  # equal content, new object
    assert ws.compiled(env, Stance((moved, stance.holds[1])), c1) is not cs
    cached = fz.check(g1, env, q, again, c2)
    fresh_cs = fz._compile(g1, env, again, c2)
    np.testing.assert_array_equal(fresh_cs.A_static, cs.A_static)
    assert cached.feasible and cached.violated == []
    np.testing.assert_array_equal(cached.joint_torques, fz.check(g1, env, q, stance, c1).joint_torques)
