"""What the controller checks on a whole-body plan before it takes it (ROS-free).

:func:`msgs_py.contact.whole_body_plan_from_msg` checks a plan against itself (finite numbers,
q sizes of 7 + len(joint_names), increasing times, known limb names); :func:`check_plan` checks it
against the robot and the environment the controller runs: the plan's joints are the robot's in
its order, every configuration is a usable Pinocchio q (unit quaternion, joints near their
limits, a base near the environment), every hold names a limb of the robot and a surface of the
environment, every transition has a path and a hold for its moving limb (or frees a limb
that held something). A plan that fails raises
SpecError naming the field (``whole_body_plan.transitions[2].path[5]``) and the rule; the
controller keeps its current plan.
"""
from __future__ import annotations

import numpy as np

from climb_core.contact import Stance, WholeBodyPlan
from climb_core.errors import SpecError

FIELD = "whole_body_plan"
#: [rad] how far a plan's joint position may lie outside the URDF limits (the QP keeps the robot
#: inside them anyway; further out the plan was made for another model)
JOINT_LIMIT_TOLERANCE = 0.2
#: [m] how far a plan's base may be from the world origin
MAX_BASE_DISTANCE = 100.0
#: [s] longest transition accepted
MAX_TRANSITION_DURATION = 600.0
#: [-] accepted |quaternion| range (the reference normalises it)
QUATERNION_NORM = (0.9, 1.1)


def check_plan(plan: WholeBodyPlan, robot, environment=None, field: str = FIELD) -> None:
    """Raise SpecError(field, rule) when ``plan`` cannot be executed by a controller of ``robot``
    (a climb_core.robot.Robot) in ``environment`` (surfaces checked when given)."""
    names = list(plan.joint_names)
    expected = list(robot.joint_names)
    if plan.robot and plan.robot != robot.config.name:
        raise SpecError(f"{field}.robot", f"plan made for {plan.robot!r}, the controller runs {robot.config.name!r}")
    if names != expected:
        unknown = [n for n in names if n not in expected]
        missing = [n for n in expected if n not in names]
        if unknown:
            rule = f"unknown joint {unknown[0]!r} (the robot {robot.config.name} has no such actuated joint)"
        elif missing:
            rule = f"misses the robot's joint {missing[0]!r} ({len(names)} names, the robot has {len(expected)})"
        else:
            i = next(i for i, (a, b) in enumerate(zip(names, expected)) if a != b)
            rule = f"must list the robot's joints in its order: [{i}] is {names[i]!r}, expected {expected[i]!r}"
        raise SpecError(f"{field}.joint_names", rule)
    lower, upper = _joint_limits(robot)
    _check_stance(plan.initial_stance, robot, environment, f"{field}.initial_stance")
    nq = robot.model.nq
    before = plan.initial_stance  # the holds at each transition's start
    for k, t in enumerate(plan.transitions):
        where = f"{field}.transitions[{k}]"
        if t.moving_limb and t.moving_limb not in robot.config.limbs:
            raise SpecError(f"{where}.moving_limb", f"the robot has no limb {t.moving_limb!r}")
        _check_stance(t.stance, robot, environment, f"{where}.stance")
        _check_stance(t.target_stance, robot, environment, f"{where}.target_stance")
        if t.moving_limb and t.target_stance.hold(t.moving_limb) is None and before.hold(t.moving_limb) is None:
            # (a limb that held something before and nothing after is freed for good: FSM "freed")
            raise SpecError(f"{where}.target_stance", f"has no hold for the moving limb {t.moving_limb}, "
                                                      "which held nothing before it either")
        before = t.target_stance
        path = np.asarray(t.path, dtype=float)
        times = np.asarray(t.times, dtype=float).reshape(-1)
        if path.ndim != 2 or path.shape[0] == 0:
            raise SpecError(f"{where}.path", "needs at least one way-point")
        if path.shape[1] != nq:
            raise SpecError(f"{where}.path", f"configurations must have nq = {nq} entries, got {path.shape[1]}")
        if not np.all(np.isfinite(path)):
            i = int(np.argwhere(~np.isfinite(path))[0][0])
            raise SpecError(f"{where}.path[{i}]", "must be finite")
        if times.shape[0] != path.shape[0] or not np.all(np.isfinite(times)):
            raise SpecError(f"{where}.times", "one finite time per way-point [s]")
        if times.size and times[-1] - times[0] > MAX_TRANSITION_DURATION:
            raise SpecError(f"{where}.times", f"a transition lasts at most {MAX_TRANSITION_DURATION:g} s, "
                                              f"got {times[-1] - times[0]:g}")
        for i, q in enumerate(path):
            _check_q(q, lower, upper, expected, f"{where}.path[{i}]")


def _joint_limits(robot) -> tuple[np.ndarray, np.ndarray]:
    model = robot.model
    return (np.asarray(model.lowerPositionLimit[7:], float) - JOINT_LIMIT_TOLERANCE,
            np.asarray(model.upperPositionLimit[7:], float) + JOINT_LIMIT_TOLERANCE)


def _check_q(q: np.ndarray, lower: np.ndarray, upper: np.ndarray, names: list[str], where: str) -> None:
    if np.linalg.norm(q[:3]) > MAX_BASE_DISTANCE:
        raise SpecError(f"{where}", f"base position {q[:3].tolist()} is more than {MAX_BASE_DISTANCE:g} m away")
    norm = float(np.linalg.norm(q[3:7]))
    if not QUATERNION_NORM[0] <= norm <= QUATERNION_NORM[1]:
        raise SpecError(f"{where}", f"base quaternion must be a unit quaternion, |q[3:7]| = {norm:g}")
    joints = q[7:]
    bad = np.flatnonzero((joints < lower) | (joints > upper))
    if bad.size:
        j = int(bad[0])
        raise SpecError(f"{where}", f"joint {names[j]} = {joints[j]:g} rad is outside its limits "
                                    f"[{lower[j] + JOINT_LIMIT_TOLERANCE:g}, {upper[j] - JOINT_LIMIT_TOLERANCE:g}] "
                                    f"by more than {JOINT_LIMIT_TOLERANCE} rad")


def _check_stance(stance: Stance, robot, environment, where: str) -> None:
    for i, hold in enumerate(stance.holds):
        f = f"{where}.holds[{i}]"
        if hold.limb not in robot.config.limbs:
            raise SpecError(f"{f}.limb", f"the robot {robot.config.name} has no limb {hold.limb!r}")
        if environment is not None and hold.env_surface not in environment.surfaces:
            raise SpecError(f"{f}.env_surface", f"unknown surface {hold.env_surface!r} in the environment "
                                                f"{environment.name!r}")
        for j, p in enumerate(hold.points):
            if np.linalg.norm(p.position) > MAX_BASE_DISTANCE:
                raise SpecError(f"{f}.points[{j}].position", f"more than {MAX_BASE_DISTANCE:g} m away")
