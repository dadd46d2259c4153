"""Whole-body QP (controller_node.qp / constraints / tasks / wholebody) on the G1 model, no sim."""
from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from climb_core.contact import Stance
from climb_core.holds import hold_from_configuration
from climb_core.robot import load_robot
from controller_node.constraints import (CollisionAvoidance, contact_from_hold, friction_generators,
                                         joint_acceleration_bounds)
from controller_node.params import load_controller_params
from controller_node.qp import (DaqpSolver, ProxsuiteSolver, QpFailure, QpProblem, load_metadata, load_problem,
                                save_problem, solve_with_qpsolvers)
from controller_node.tasks import BaseOrientationTask, ComTask, FrameTask, PostureTask
from controller_node.wholebody import WholeBodyQP

G = 9.81  # [m/s^2]


@pytest.fixture(scope="module")
def robot():
    return load_robot("g1")


@pytest.fixture(scope="module")
def params():
    return load_controller_params()


def standing(robot, env, params, **overrides):
    """WholeBodyQP at the reference posture with both soles on the ground and the 3 base tasks."""
    p = params.replace(**overrides) if overrides else params
    wb = WholeBodyQP(robot.model, robot.effort_limits(), p)
    q = robot.q_reference()
    v = np.zeros(robot.nv)
    wb.update(q, v)
    contacts = []
    for limb in ("left_foot", "right_foot"):
        hold = hold_from_configuration(robot, env, q, limb, "ground")
        fid = robot.frame_id(robot.config.limbs[limb].surface.frame)
        ft_force_range = robot.config.ft_ranges[robot.config.limbs[limb].ft_sensor][0]
        contacts.append(contact_from_hold(hold, fid, wb.data.oMf[fid], robot.config.limbs[limb].surface.T_frame_surface,
                                          force_limit=p.contacts.unilateral_force_limit_ft_range * ft_force_range,
                                          min_normal_force=p.contacts.min_normal_force,
                                          friction_margin=p.contacts.friction_margin))
    com = ComTask(p.tasks.com, wb.data.com[0].copy())
    posture = PostureTask(p.tasks.posture, robot.nv)
    posture.set_target(q[7:])
    base = BaseOrientationTask(p.tasks.base_orientation, robot.nv)
    return wb, contacts, [com, posture, base], q


def test_friction_generators_span_an_inner_pyramid_of_the_cone():
    n = np.array([0.3, -0.2, 0.93])
    n /= np.linalg.norm(n)
    mu = 0.4
    edges = friction_generators(n, mu, 4)
    rng = np.random.default_rng(0)
    for _ in range(200):
        f = edges @ rng.uniform(0.0, 10.0, 4)
        fn = f @ n
        ft = np.linalg.norm(f - fn * n)
        assert fn >= 0.0
        assert ft <= mu * fn + 1e-9
    # every edge lies exactly on the cone surface
    for e in edges.T:
        assert np.linalg.norm(e - (e @ n) * n) == pytest.approx(mu * (e @ n), rel=1e-9)


def test_daqp_solves_a_small_known_problem_and_reports_failure_with_the_problem(tmp_path):
    # min (x0-1)^2 + (x1-2)^2  s.t. x0 + x1 = 1, x >= 0  ->  x = (0, 1)
    problem = QpProblem(H=2 * np.eye(2), g=np.array([-2.0, -4.0]), lb=np.zeros(2), ub=np.full(2, np.inf),
                        A=np.array([[1.0, 1.0]]), lower=np.array([1.0]), upper=np.array([1.0]),
                        is_eq=np.array([True]), variable_blocks=[("x", 0, 2)], row_blocks=[("sum", 0, 1)])
    solution = DaqpSolver().solve(problem)
    assert solution.x == pytest.approx([0.0, 1.0], abs=1e-9)
    assert solve_with_qpsolvers(problem, "proxqp").x == pytest.approx([0.0, 1.0], abs=1e-6)
    # x0 + x1 = -1 with x >= 0 is infeasible: the exception carries the problem, which replays
    bad = QpProblem(problem.H, problem.g, problem.lb, problem.ub, problem.A, np.array([-1.0]), np.array([-1.0]),
                    problem.is_eq, problem.variable_blocks, problem.row_blocks)
    with pytest.raises(QpFailure) as info:
        DaqpSolver().solve(bad)
    assert info.value.problem is bad
    path = save_problem(info.value.problem, tmp_path / "failure.npz", solver="daqp", status=info.value.status)
    replayed = load_problem(path)
    assert np.array_equal(replayed.A, bad.A) and np.array_equal(replayed.upper, bad.upper)
    assert replayed.row_blocks == bad.row_blocks
    assert load_metadata(path)["solver"] == "daqp"
    with pytest.raises(QpFailure):
        DaqpSolver().solve(replayed)


def test_standing_qp_balances_gravity_with_forces_in_the_cones(robot, env, params):
    wb, contacts, tasks, q = standing(robot, env, params)
    result = wb.solve(contacts, tasks)
    total = sum(c.wrench_in_world[:3] for c in result.contacts.values())
    a_com = wb.data.Jcom @ result.qdd + wb.data.acom[0]
    # Newton: the feet carry the weight (plus m a_com, negligible at rest)
    assert total == pytest.approx(robot.mass * (a_com + np.array([0.0, 0.0, G])), abs=1e-6 * robot.mass * G)
    assert total[2] == pytest.approx(robot.mass * G, rel=1e-3)
    assert np.max(np.abs(result.qdd)) < 1e-2  # at rest: (almost) no acceleration [rad/s^2]
    mu = params.contacts.friction_margin * contacts[0].friction
    for c in result.contacts.values():
        for f, n in zip(c.point_forces_in_world, np.array([[0, 0, 1.0]] * len(c.point_forces_in_world))):
            fn = f @ n
            assert fn >= params.contacts.min_normal_force - 1e-6
            assert np.linalg.norm(f - fn * n) <= mu * fn + 1e-6
    # the recovered torques satisfy the full dynamics: M qdd + h = S' tau + J' f
    data = wb.data
    generalized = data.M @ result.qdd + data.nle
    contact_part = np.zeros(robot.nv)
    for c, sl, phi, Jc in wb._contact_layout:
        contact_part += Jc.T @ (phi @ result.solution.x[sl])
    residual = generalized - contact_part - np.concatenate([np.zeros(6), result.tau])
    assert np.max(np.abs(residual)) < 1e-6
    assert np.all(np.abs(result.tau) <= wb.tau_max + 1e-9)


def test_torque_limits_are_hard_constraints(robot, env, params):
    # ask for a fast CoM drop: the knees would need large torques; with 20 % of the effort
    # limits the QP must saturate the torques instead of exceeding them
    def com_drop(fraction):
        wb, contacts, tasks, q = standing(robot, env, params, **{"qp.torque_limit_fraction": fraction})
        tasks[0].set_target(wb.data.com[0] + np.array([0.0, 0.0, -0.3]))
        result = wb.solve(contacts, tasks)
        return wb, result, (wb.data.Jcom @ result.qdd + wb.data.acom[0])[2]

    wb_full, full, a_full = com_drop(1.0)
    wb, weak, a_weak = com_drop(0.2)
    assert np.max(np.abs(full.tau) / wb.tau_max) > 1.0  # the full-strength answer needs > 20 %
    assert np.all(np.abs(weak.tau) <= wb.tau_max + 1e-6)  # the weak robot stays within its limits
    assert np.max(np.abs(weak.tau) / wb.tau_max) > 0.95  # ... with the limit binding


def test_infeasible_torque_limits_raise_with_a_replayable_problem(robot, env, params, tmp_path):
    # 1 % of the effort limits cannot hold G1 up, and the acceleration bounds forbid falling
    wb, contacts, tasks, q = standing(robot, env, params, **{"qp.torque_limit_fraction": 0.01,
                                                             "qp.joint_acceleration_bound": 1.0,
                                                             "qp.base_acceleration_bound": 1.0})
    with pytest.raises(QpFailure) as info:
        wb.solve(contacts, tasks)
    path = save_problem(info.value.problem, tmp_path / "standing_weak.npz")
    with pytest.raises(QpFailure):
        DaqpSolver().solve(load_problem(path))
    blocks = dict((name, (a, b)) for name, a, b in info.value.problem.row_blocks)
    assert "torque_limits" in blocks and "dynamics_base" in blocks


def test_release_ramp_cap_moves_the_load_to_the_other_foot(robot, env, params):
    wb, contacts, tasks, q = standing(robot, env, params)
    # shift the CoM over the right foot first so that single support is feasible
    right = contacts[1]
    com_over_right = wb.data.oMf[right.frame_id].act(right.reference_in_frame)
    tasks[0].set_target(np.array([com_over_right[0], com_over_right[1], wb.data.com[0][2]]))
    contacts[0].ramp_cap = 0.0  # left foot fully unloaded
    contacts[0].scale = 0.0
    result = wb.solve(contacts, tasks)
    assert result.contacts["left_foot"].normal_force < 1e-6
    assert result.contacts["right_foot"].normal_force == pytest.approx(robot.mass * G, rel=0.05)


def test_proxsuite_warm_started_matches_daqp(robot, env, params):
    wb, contacts, tasks, q = standing(robot, env, params)
    problem = wb.build(contacts, tasks)
    x_daqp = DaqpSolver().solve(problem).x
    prox = ProxsuiteSolver(iter_limit=10000, eps_abs=1e-9)
    first = prox.solve(problem)
    second = prox.solve(problem)  # same dimensions: warm start from the previous result
    scale = np.maximum(np.abs(x_daqp), 1.0)
    assert np.max(np.abs(first.x - x_daqp) / scale) < 1e-4
    assert second.iterations <= first.iterations


def test_joint_acceleration_bounds_push_back_and_stay_ordered():
    rng = np.random.default_rng(1)
    lower, upper = np.full(50, -1.0), np.full(50, 1.0)
    vmax = np.full(50, 10.0)
    q = rng.uniform(-1.3, 1.3, 50)  # some outside the limits
    v = rng.uniform(-12.0, 12.0, 50)  # some beyond the velocity limit
    lo, hi = joint_acceleration_bounds(q, v, lower, upper, vmax, 0.1, 400.0, 0.0)
    assert np.all(lo <= hi)
    # a joint at its upper limit moving toward it must be decelerated
    lo1, hi1 = joint_acceleration_bounds(np.array([0.99]), np.array([1.0]), lower[:1], upper[:1], vmax[:1],
                                         0.1, 400.0, 0.0)
    assert hi1[0] < 0.0
    # in the middle at rest: the velocity limit reached within the horizon binds (10 / 0.1)
    lo2, hi2 = joint_acceleration_bounds(np.zeros(1), np.zeros(1), lower[:1], upper[:1], vmax[:1], 0.1, 400.0, 0.0)
    assert lo2[0] == pytest.approx(-100.0) and hi2[0] == pytest.approx(100.0)


def _hand_task_toward(robot, params, wb, limb, direction, gain_distance=0.3):
    fid = robot.frame_id(robot.config.limbs[limb].surface.frame)
    offset = robot.config.limbs[limb].surface.T_frame_surface[:3, 3]
    task = FrameTask(params.tasks.contact_body, fid, offset, name=limb)
    T = task.current(wb.view)
    task.set_target(pin.SE3(T.rotation, T.translation + gain_distance * direction))
    return task


def test_velocity_damper_allows_approach_and_brakes_fast_approach(robot, env, params):
    """FIELD_NOTES trap: the damper is  d_dot + dt d_ddot >= -xi (d - ds)/(di - ds).

    A box sits in front of the right palm at mid influence distance. At rest the hand may still
    approach (the literal paper sign would forbid it); moving fast toward it, the hand is braked
    so that the next-step approach speed respects the bound."""
    import coal

    c = params.collision
    wb0, contacts, tasks, q = standing(robot, env, params)
    limb = "right_hand"
    palm = "right_hand_palm_link"
    geometries = {}
    for obj in robot.collision_model.geometryObjects:
        link = robot.model.frames[obj.parentFrame].name
        geometries.setdefault(link, []).append((obj.geometry, obj.parentJoint, obj.placement))
    # where is the palm hull's forward-most point (+x)? place a box face beyond it
    M = wb0.data.oMi[geometries[palm][0][1]] * geometries[palm][0][2]
    vertices = np.asarray(geometries[palm][0][0].points()) @ M.rotation.T + M.translation
    d_mid = 0.5 * (c.influence_distance + c.security_distance)
    face_x = vertices[:, 0].max() + d_mid
    half = np.array([0.05, 0.3, 0.3])
    box = coal.Box(*(2 * half))
    tf = coal.Transform3s(np.eye(3), np.array([face_x + half[0], vertices[:, 1].mean(), vertices[:, 2].mean()]))
    dampers = CollisionAvoidance(geometries, (palm,), [("wall", box, tf)], (), c.influence_distance,
                                 c.security_distance, c.damping, c.broadphase_margin, c.max_braking)
    wb = WholeBodyQP(robot.model, robot.effort_limits(), params, dampers)
    dt = params.control_period_s
    forward = np.array([1.0, 0.0, 0.0])

    def run(v):
        wb.update(q, v)
        hand = _hand_task_toward(robot, params, wb, limb, forward)
        return wb.solve(contacts, tasks + [hand])

    at_rest = run(np.zeros(robot.nv))
    rows = [d for d in at_rest.dampers if d.name.startswith(palm)]
    assert len(rows) == 1 and rows[0].distance == pytest.approx(d_mid, abs=2e-3)
    row = rows[0]
    d_ddot = row.row @ at_rest.qdd + row.drift
    assert d_ddot < -1.0  # approaching is allowed at rest [m/s^2] (the literal sign would forbid it)
    assert row.distance_rate + dt * d_ddot >= row.bound - 1e-6
    # the right arm swinging toward the wall faster than the damper allows gets braked
    v = np.zeros(robot.nv)
    v[robot.joint_index_v("right_shoulder_pitch_joint")] = -0.6  # [rad/s]
    fast = run(v)
    row = [d for d in fast.dampers if d.name.startswith(palm)][0]
    assert row.distance_rate < row.bound  # too fast now
    d_ddot = row.row @ fast.qdd + row.drift
    assert d_ddot > 0.0  # braking
    required = (row.bound - row.distance_rate) / dt
    assert d_ddot >= min(required, c.max_braking) - 1e-6
    # without the damper the same task would keep accelerating toward the wall
    free = WholeBodyQP(robot.model, robot.effort_limits(), params)
    free.update(q, v)
    hand = _hand_task_toward(robot, params, free, limb, forward)
    unconstrained = free.solve(contacts, tasks + [hand])
    assert row.row @ unconstrained.qdd + row.drift < d_ddot


def test_witness_point_jacobian_and_drift_match_finite_differences(robot):
    """The damper rows use J_pB and Jdot_pB v of a point fixed in a body (eq. 7-8)."""
    from controller_node.constraints import point_jacobian_and_drift

    model = robot.model
    data = model.createData()
    rng = np.random.default_rng(0)
    q = robot.q_reference()
    q[7:] += rng.normal(0.0, 0.2, model.nq - 7)
    v = rng.normal(0.0, 1.0, model.nv)
    pin.computeJointJacobians(model, data, q)
    pin.forwardKinematics(model, data, q, v, np.zeros(model.nv))
    joint = model.getJointId("right_wrist_yaw_joint")
    point = data.oMi[joint].act(np.array([0.05, 0.02, -0.01]))
    J, drift = point_jacobian_and_drift(model, data, joint, point)
    local = data.oMi[joint].actInv(point)

    def position(qq):
        d = model.createData()
        pin.forwardKinematics(model, d, qq)
        return d.oMi[joint].act(local)

    eps = 1e-5
    ahead, behind = position(pin.integrate(model, q, v * eps)), position(pin.integrate(model, q, -v * eps))
    assert J @ v == pytest.approx((ahead - behind) / (2 * eps), abs=1e-6)  # [m/s]
    assert drift == pytest.approx((ahead - 2 * position(q) + behind) / eps ** 2, abs=2e-3)  # [m/s^2]


def test_workspace_build_matches_the_reference_build(robot, env, params):
    """The preallocated workspace + batched dampers give the QP of the straightforward build:
    4-contact ladder stance (knees near the rungs: damper rows), perturbed states over several
    ticks (the workspace and the coherence budgets are reused), then the hips rolled inward
    (the feet within the influence distance of each other: a self pair)."""
    from climb_core import fixtures
    from controller_node.controller import Controller
    from controller_node.estimator import RobotState

    stance, q0 = fixtures.get("ladder_4_contacts", robot, env)
    controller = Controller(robot, params, env)
    rng = np.random.default_rng(3)
    controller.reset(RobotState(0.0, q0.copy(), np.zeros(robot.nv)), stance)
    wb = controller.wb
    roll_l, roll_r = robot.joint_index_v("left_hip_roll_joint") + 1, robot.joint_index_v("right_hip_roll_joint") + 1  # q
    cases = []
    for tick in range(6):
        q = q0.copy()
        q[7:] += rng.normal(0.0, 0.003, robot.nq - 7)
        cases.append((q, rng.normal(0.0, 0.02, robot.nv)))
    q = q0.copy()
    q[roll_l] -= 0.1  # hip roll inward: the feet 5 cm apart (a self pair)
    q[roll_r] += 0.1
    cases.append((q, np.zeros(robot.nv)))
    seen_rows, seen_self = 0, False
    solver = DaqpSolver()
    for q, v in cases:
        wb.update(q, v)
        controller.state = RobotState(0.0, q, v)
        contacts = list(controller.contacts.values())
        disabled = controller._disabled_pairs()
        fast = wb.build(contacts, controller.active_tasks, disabled)
        fast_rows = [d.name for d in wb._dampers]
        reference = wb.build_reference(contacts, controller.active_tasks, disabled)
        assert fast_rows == [d.name for d in wb._dampers]
        assert fast.row_blocks == reference.row_blocks and np.array_equal(fast.is_eq, reference.is_eq)
        for name in ("H", "g", "A", "lb", "ub", "lower", "upper"):
            a = np.clip(getattr(fast, name), -1e30, 1e30)
            b = np.clip(getattr(reference, name), -1e30, 1e30)
            assert np.allclose(a, b, rtol=1e-12, atol=1e-9), name
        x_ref = solver.solve(reference).x
        x_fast = solver.solve(fast).x
        assert np.allclose(x_fast, x_ref, rtol=1e-6, atol=1e-6)
        # the hot path (daqp on the workspace arrays) gives the same solution and leaves them intact
        result = wb.solve(contacts, controller.active_tasks, disabled)
        assert np.allclose(result.solution.x, x_ref, rtol=1e-6, atol=1e-6)
        assert np.array_equal(result.problem.A, fast.A) and np.array_equal(result.problem.upper, fast.upper)
        seen_rows = max(seen_rows, len(fast_rows))
        seen_self |= any(name.count("_link") == 2 for name in fast_rows)
    assert seen_rows >= 2 and seen_self
    # a result's problem is not silently replaced by a later tick's
    result = wb.solve(contacts, controller.active_tasks, disabled)
    wb.build(contacts, controller.active_tasks, disabled)
    with pytest.raises(RuntimeError):
        result.problem
