"""climb_core.ik: contact-projection IK (limbs onto their holds, joint limits, CoM, restarts)."""
from __future__ import annotations

import dataclasses

import numpy as np
import pinocchio as pin
import pytest

from climb_core import fixtures, holds, ik
from climb_core.contact import FEET, HANDS, Stance
from climb_core.errors import SpecError


@pytest.fixture(scope="module")
def ladder_stance(g1, env):
    side = {"left_foot": 0.12, "right_foot": -0.12, "left_hand": 0.15, "right_hand": -0.15}
    hs = [holds.make_hold(g1, env, limb, "rung_1", side[limb]) for limb in FEET]
    hs += [holds.make_hold(g1, env, limb, "rung_5", side[limb]) for limb in HANDS]
    return Stance(tuple(hs), "ladder")


def _seed(g1, env):
    q = g1.q_reference()
    q[0] = env.rung(1).T_world_surface[0, 3] - 0.18
    q[2] += env.rung(1).top_z
    for joint, value in {"left_shoulder_pitch_joint": -1.2, "right_shoulder_pitch_joint": -1.2,
                         "left_elbow_joint": 0.6, "right_elbow_joint": 0.6}.items():
        q[g1.model.joints[g1.model.getJointId(joint)].idx_q] = value
    return q


def test_ladder_stance_is_reached(g1, env, ladder_stance):
    params = ik.load_ik_params()
    res = ik.solve(g1, env, _seed(g1, env), ladder_stance)
    q, ok, residual = res  # unpacks as (q, success, residual)
    assert ok and res.position_error <= params.position_tolerance and res.angle_error <= params.angle_tolerance
    assert residual == pytest.approx(max(res.position_error, params.orientation_weight * res.angle_error))
    # independent check with the robot model's own surface poses
    for hold in ladder_stance.holds:
        T = g1.T_world_surface(hold.limb, q)
        surface = g1.config.limbs[hold.limb].surface
        if hold.bilateral:  # grasp centre on the hold centre, grasp axis along the rung
            assert np.linalg.norm(T[:3, 3] - hold.centre) < 2 * params.position_tolerance
            axis = T[:3, :3] @ (surface.T_frame_surface[:3, :3].T @ surface.axis)
            rung_axis = env.surfaces[hold.env_surface].T_world_surface[:3, 0]
            assert abs(axis @ rung_axis) > np.cos(2 * params.angle_tolerance)
        else:  # sole centre on the rung top, sole normal along the contact normal
            assert np.linalg.norm(T[:3, 3] - hold.centre) < 2 * params.position_tolerance
            assert -T[:3, 2] @ hold.normals[0] > np.cos(2 * params.angle_tolerance)
    lo, hi = g1.model.lowerPositionLimit[7:], g1.model.upperPositionLimit[7:]
    assert ((q[7:] >= lo) & (q[7:] <= hi)).all()
    assert np.linalg.norm(q[3:7]) == pytest.approx(1.0)


def test_joint_limits_hold_when_the_target_pulls_beyond_them(g1, env):
    """A sole target 0.3 m above the standing one: the leg folds against its limits, never past."""
    q0 = g1.q_reference()
    T = g1.T_world_surface("left_foot", q0)
    T[2, 3] += 0.3
    res = ik.solve(g1, env, q0, {"left_foot": T, "right_foot": g1.T_world_surface("right_foot", q0)},
                   params=dataclasses.replace(ik.load_ik_params(), restarts=0))
    lo, hi = g1.model.lowerPositionLimit[7:], g1.model.upperPositionLimit[7:]
    margin = ik.load_ik_params().joint_limit_margin
    assert ((res.q[7:] >= lo + margin - 1e-9) & (res.q[7:] <= hi - margin + 1e-9)).all()


def test_com_target_is_reached_with_the_feet_kept(g1, env):
    q0 = g1.q_reference()
    stance = Stance(tuple(holds.hold_from_configuration(g1, env, q0, limb, "ground") for limb in FEET))
    com0 = pin.centerOfMass(g1.model, g1.model.createData(), q0)
    target = com0[:2] + np.array([0.03, -0.04])
    res = ik.solve(g1, env, q0, stance, com_target=target)
    assert res.success and res.com_error < ik.load_ik_params().com_tolerance + 1e-9
    com = pin.centerOfMass(g1.model, g1.model.createData(), res.q)
    np.testing.assert_allclose(com[:2], target, atol=1.5e-3)
    for limb in FEET:  # the soles did not move
        np.testing.assert_allclose(g1.T_world_surface(limb, res.q), g1.T_world_surface(limb, q0), atol=1e-3)


def test_unreachable_holds_fail_after_the_restarts_deterministically(g1, env):
    """Feet on rung 1 and hands on rung 8 (1.7 m above): out of reach for G1."""
    stance = Stance((holds.make_hold(g1, env, "left_foot", "rung_1", 0.12),
                     holds.make_hold(g1, env, "right_foot", "rung_1", -0.12),
                     holds.make_hold(g1, env, "left_hand", "rung_8", 0.15),
                     holds.make_hold(g1, env, "right_hand", "rung_8", -0.15)))
    params = dataclasses.replace(ik.load_ik_params(), restarts=3, max_iterations=20)
    a = ik.solve(g1, env, _seed(g1, env), stance, params=params)
    b = ik.solve(g1, env, _seed(g1, env), stance, params=params)
    assert not a.success and a.attempts == params.restarts + 1
    assert a.residual > 0.05
    np.testing.assert_array_equal(a.q, b.q)  # the restart perturbations come from a fixed seed


def test_fixture_stance_is_a_fixed_point(g1, env):
    stance, q = fixtures.get("ladder_4_contacts", g1, env)
    res = ik.solve(g1, env, q, stance)
    assert res.success and res.iterations == 0 and res.attempts == 1
    # unchanged up to the quaternion's renormalisation (1 ulp with today's wheels)
    np.testing.assert_allclose(res.q, q, rtol=0.0, atol=1e-12)


def test_bad_input_names_the_field(g1, env, ladder_stance):
    q = g1.q_reference()
    with pytest.raises(SpecError) as err:
        ik.solve(g1, env, q[:10], ladder_stance)
    assert err.value.field == "ik.q_seed"
    with pytest.raises(SpecError) as err:
        ik.solve(g1, env, q, ladder_stance, com_target=[0.0, 0.0, 0.0, 1.0])
    assert err.value.field == "ik.com_target"
    with pytest.raises(SpecError) as err:
        ik.solve(g1, None, q, ladder_stance)
    assert err.value.field == "ik.targets"


def test_repeated_solves_are_identical(g1, env, ladder_stance):
    """Scratch pin.Data objects are reused between calls and foot targets are cached per hold:
    a second solve from the same seed gives the same configuration bit for bit."""
    stance = ladder_stance
    q0 = _seed(g1, env)
    first = ik.solve(g1, env, q0, stance)
    second = ik.solve(g1, env, q0, stance)
    assert first.success and second.success
    np.testing.assert_array_equal(first.q, second.q)
    assert first.iterations == second.iterations
    # the task weights follow w_ang: errors with another weight scale the angular rows only
    tasks = ik.contact_tasks(g1, env, q0, stance, None)
    data = g1.model.createData()
    pin.computeJointJacobians(g1.model, data, q0)
    e1, J1, _ = ik.task_errors(g1.model, data, tasks, 0.3, with_jacobian=True)
    e2, J2, _ = ik.task_errors(g1.model, data, tasks, 0.6, with_jacobian=True)
    lin = np.concatenate([np.arange(len(t.rows)) < 3 for t in tasks])
    np.testing.assert_array_equal(e1[lin], e2[lin])
    np.testing.assert_allclose(2.0 * e1[~lin], e2[~lin], rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(2.0 * J1[~lin], J2[~lin], rtol=1e-12, atol=1e-15)
