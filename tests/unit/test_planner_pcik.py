"""Physics-constrained IK (planner_node.pcik) for G1 on the default ladder."""
from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from climb_core import feasibility, fixtures, holds
from climb_core.contact import Stance
from planner_node import pcik
from planner_node.settings import load_settings


@pytest.fixture(scope="module")
def params():
    return load_settings().pcik


def ladder_stance(robot, env, feet_rung=1, hands_rung=5):
    cfg = feasibility.load_config()
    hs = [holds.make_hold(robot, env, limb, f"rung_{feet_rung}", s, params=cfg.holds)
          for limb, s in (("left_foot", 0.12), ("right_foot", -0.12))]
    hs += [holds.make_hold(robot, env, limb, f"rung_{hands_rung}", s, params=cfg.holds)
           for limb, s in (("left_hand", 0.15), ("right_hand", -0.15))]
    return Stance(tuple(hs), name="test")


def point_jacobian(model, data, frame_id, point):
    J6 = pin.getFrameJacobian(model, data, frame_id, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)
    r = point - data.oMf[frame_id].translation
    skew = np.array([[0, -r[2], r[1]], [r[2], 0, -r[0]], [-r[1], r[0], 0]])
    return J6[:3] - skew @ J6[3:]


def test_ik_reaches_the_holds_with_forces_in_the_cones_and_torques_in_limits(g1, env, params):
    stance = ladder_stance(g1, env)
    # seed: standing on the ground near the ladder, far from the ladder stance
    q_seed = g1.q_reference()
    q_seed[0] += 0.25
    res = pcik.solve(g1, env, q_seed, stance, params=params)
    assert res.success, pcik.describe_failure(res)
    assert res.position_error < 1e-3 and res.angle_error < 1e-2
    # every limb surface on its hold (independent of the solver: forward kinematics)
    for h in stance.holds:
        T = g1.T_world_surface(h.limb, res.q)
        if h.bilateral:
            assert np.linalg.norm(T[:3, 3] - h.centre) < 2e-3
        else:
            assert abs(T[2, 3] - h.centre[2]) < 2e-3  # the sole is on the rung top
    # forces: friction cones (unilateral) and grip limits (grasps) hold
    model, data = g1.model, g1.model.createData()
    pin.computeJointJacobians(model, data, res.q)
    pin.updateFramePlacements(model, data)
    tau = pin.computeGeneralizedGravity(model, data, res.q).copy()
    total = np.zeros(3)
    for h in stance.holds:
        f = res.forces[h.limb]
        assert f.shape == (len(h.points), 3)
        if h.bilateral:
            assert np.linalg.norm(f.sum(axis=0)) <= 1.09 * h.grip_force_limit
        else:
            for fi, n in zip(f, h.normals):
                fn = float(fi @ n)
                assert fn >= -1e-6
                assert np.linalg.norm(fi - fn * n) <= h.friction * fn + 1e-6
        fid = g1.frame_id(g1.config.limbs[h.limb].surface.frame)
        for p, fi in zip(h.positions, f):
            tau -= point_jacobian(model, data, fid, p).T @ fi
        total += f.sum(axis=0)
    # static equilibrium: the forces carry the weight, the base needs no actuation
    assert np.allclose(total, [0.0, 0.0, g1.mass * 9.81], atol=1.0)
    assert np.abs(tau[:6]).max() < 1.0
    assert np.all(np.abs(tau[6:]) <= g1.effort_limits() + 1e-6)
    assert np.allclose(tau[6:], res.torques, atol=1e-3)


def test_unreachable_rung_fails_cleanly_naming_reach(g1, env, params):
    st, q = fixtures.get("standing", g1, env)
    # hands on the top rung (1.94 m) while standing on the ground
    hs = list(st.holds) + [holds.make_hold(g1, env, limb, "rung_8", s) for limb, s in
                           (("left_hand", 0.15), ("right_hand", -0.15))]
    res = pcik.solve(g1, env, q, Stance(tuple(hs)), params=params)
    assert not res.success
    assert {v for v in res.violated} & {"reach:left_hand", "reach:right_hand"}
    assert res.position_error > 0.05


def test_hanging_from_one_hand_names_the_broken_limit(g1, env, params):
    # one grasp cannot hold a 34 kg robot: the grip (100 N) and the arm torques are exceeded
    h = holds.make_hold(g1, env, "left_hand", "rung_5", 0.15)
    _, q = fixtures.get("ladder_4_contacts", g1, env)
    res = pcik.solve(g1, env, q, Stance((h,)), params=params)
    assert not res.success
    # whatever else gave way, the physical limits of the left arm are named
    assert any(v.startswith(("grip_limit:left_hand", "torque_limit:left_")) for v in res.violated), res.violated
    assert not any(v.startswith("torque_limit:right_") for v in res.violated)


def test_floating_contact_lands_on_its_surface(g1, env, params):
    st, q = fixtures.get("ladder_no_left_hand", g1, env)
    rung = env.surfaces["rung_5"]
    preferred = rung.position + 0.18 * rung.axis  # on the rung, left of its centre
    contacts = list(pcik.contacts_from_stance(st)) + [
        pcik.ContactSpec("left_hand", pcik.FLOATING, surface="rung_5", preferred_position=preferred)]
    res = pcik.solve(g1, env, q, contacts, params=params)
    assert res.success, pcik.describe_failure(res)
    T = g1.T_world_surface("left_hand", res.q)
    # grasp centre on the rung axis, grasp axis along the rung
    p0, a = rung.position, rung.axis
    off = T[:3, 3] - p0
    assert np.linalg.norm(off - a * (a @ off)) < 2e-3
    grasp_axis = T[:3, :3] @ holds.grasp_axis_in_surface(g1.config.limbs["left_hand"].surface)
    assert abs(abs(grasp_axis @ a) - 1.0) < 1e-3
    # where on the rung was free: the cost pulled it toward the preferred position
    assert abs(a @ off - 0.18) < 0.03
    # it became a regular hold that the core check accepts
    hold = res.holds["left_hand"]
    assert hold.env_surface == "rung_5" and hold.bilateral
    full = Stance(tuple(st.holds) + (hold,))
    assert feasibility.check(g1, env, res.q, full).feasible


def test_floating_foot_lands_on_the_ground_plane(g1, env, params):
    st, q = fixtures.get("standing", g1, env)
    right = st.hold("right_foot")
    contacts = [pcik.ContactSpec("right_foot", pcik.REGULAR, hold=right),
                pcik.ContactSpec("left_foot", pcik.FLOATING, surface="ground",
                                 preferred_position=np.array([0.1, 0.15, 0.0]))]
    res = pcik.solve(g1, env, q, contacts, params=params)
    assert res.success, pcik.describe_failure(res)
    T = g1.T_world_surface("left_foot", res.q)
    assert abs(T[2, 3]) < 1e-3  # sole on the ground plane
    assert abs(abs(T[2, 2]) - 1.0) < 1e-3  # sole flat
    assert T[0, 3] > 0.03  # moved toward the preferred position


def test_zero_force_contact_is_placed_but_carries_nothing(g1, env, params):
    st, q = fixtures.get("ladder_4_contacts", g1, env)
    contacts = [pcik.ContactSpec(h.limb, pcik.ZERO_FORCE if h.limb == "left_foot" else pcik.REGULAR, hold=h)
                for h in st.holds]
    res = pcik.solve(g1, env, q, contacts, params=params)
    assert res.success, pcik.describe_failure(res)
    assert "left_foot" not in res.forces  # no force variables for it
    T = g1.T_world_surface("left_foot", res.q)
    assert abs(T[2, 3] - st.hold("left_foot").centre[2]) < 2e-3  # but the foot is on its rung
    # the other three limbs alone hold the robot at this configuration
    assert feasibility.check(g1, env, res.q, st.without("left_foot"), collision=False).feasible


def test_contact_spec_validation():
    from climb_core.errors import SpecError

    with pytest.raises(SpecError):
        pcik.ContactSpec("left_hand", "sticky")
    with pytest.raises(SpecError):
        pcik.ContactSpec("left_hand", pcik.REGULAR)
    with pytest.raises(SpecError):
        pcik.ContactSpec("left_hand", pcik.FLOATING)


def test_collision_rows_match_finite_differences_and_repeat_exactly(g1, env, params):
    """The gradient rows (one Jacobian per joint, shared by the pairs on that joint) predict the
    distance change of a small step; a repeated solve (borrowed pin.Data) is bit-identical."""
    stance, q = fixtures.get("ladder_4_contacts", g1, env)
    chk = feasibility.collision_mod.checker(g1, env, feasibility.load_config().collision)
    model = g1.model
    data = model.createData()
    pin.computeJointJacobians(model, data, q)
    excl = [(h.limb, h.env_surface) for h in stance.holds]
    d, G, names = pcik.collision_rows(chk, model, data, q, excl, 0.05)
    assert len(d) > 0 and G.shape == (len(d), model.nv)
    rng = np.random.default_rng(1)
    dq = rng.normal(0.0, 1e-4, model.nv)
    q2 = pin.integrate(model, q, dq)
    full = chk.all_distances(q2)
    moved = np.array([full[chk.pair_index[n]] for n in names])
    np.testing.assert_allclose(moved - d, G @ dq, atol=2e-6)
    a = pcik.solve(g1, env, q, stance, params=params)
    b = pcik.solve(g1, env, q, stance, params=params)
    np.testing.assert_array_equal(a.q, b.q)
    assert a.violated == b.violated and a.iterations == b.iterations
