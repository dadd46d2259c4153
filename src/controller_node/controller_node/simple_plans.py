"""Hand-made whole-body plans for exercising the controller without the planner.

:func:`limb_transfer` builds one :class:`~climb_core.contact.Transition` moving one limb from its
hold to a new hold, through contact-projection IK way-points (``climb_core.ik``) with the other
holds kept:

    start -> off (limb backed off its hold) -> [mid] -> pre (backed off the target hold) -> target

A hand backs off along its palm normal (``clearance``) and toward the robot, travels behind the
rungs and comes onto the target along its palm normal. A foot lifts (``lift``) and moves back
(``foot_back``) so that its toes clear the next rung, rises behind it (mid), moves over the
target (pre) and comes straight down onto it. This is not a planner: no search, no feasibility check beyond the IK. The
ladder planner (planner_node) produces the real plans with the same data model.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from climb_core import holds, ik
from climb_core.contact import HANDS, Stance, Transition, WholeBodyPlan
from climb_core.errors import InfeasibleError


@dataclass(frozen=True)
class TransferTiming:
    back_off_s: float = 0.8  # [s] start -> off
    travel_s: float = 1.4  # [s] off -> pre
    approach_s: float = 1.0  # [s] pre -> target


def _solve(robot, env, q_seed, targets, what: str, com_target=None) -> np.ndarray:
    result = ik.solve(robot, env, q_seed, targets, com_target=com_target)
    if not result.success:
        raise InfeasibleError("contact", f"{what}: IK residual {result.residual:.4f} m")
    return result.q


def limb_transfer(robot, env, stance: Stance, q_start: np.ndarray, limb: str, target_surface: str,
                  s: float = 0.0, *, clearance: float = 0.08, lift: float = 0.08, back: float = 0.12,
                  foot_back: float = 0.16, foot_com_shift=(-0.03, 0.0, 0.06),
                  timing: TransferTiming = TransferTiming(), target_hold=None) -> Transition:
    """One transition moving ``limb`` onto ``target_surface`` at ``s`` [m] along its axis.

    A foot step also moves the CoM by ``foot_com_shift`` [m] (world; default back and up) so
    that the knee clears the rung above the target (the IK is not collision-aware)."""
    import pinocchio as pin
    kept = stance.without(limb)
    targets = {h.limb: h for h in kept.holds}
    forward = holds.ladder_forward(env)
    T_now = robot.T_world_surface(limb, q_start)
    hold = target_hold if target_hold is not None else holds.make_hold(
        robot, env, limb, target_surface, s, R_world_surface_seed=T_now[:3, :3])
    T_target = holds.hold_target(robot, env, hold, R_world_surface_seed=T_now[:3, :3]).T_world_surface
    T_off = T_now.copy()
    T_pre = T_target.copy()
    T_mid = None
    if limb in HANDS:
        # the palm backs off along its normal and toward the robot, travels behind the rungs and
        # comes onto the target rung along its normal (plus a little from behind)
        T_off[:3, 3] -= clearance * T_now[:3, 2] + back * forward
        T_pre[:3, 3] -= clearance * T_target[:3, 2]
    else:
        up = np.array([0.0, 0.0, 1.0])
        # the toes must clear the target rung on the way up: travel well behind it
        T_off[:3, 3] += lift * up - foot_back * forward
        T_mid = T_target.copy()
        T_mid[:3, 3] += lift * up - foot_back * forward
        T_pre[:3, 3] += lift * up
    com = com_half = None
    if limb not in HANDS and foot_com_shift is not None:
        com0 = pin.centerOfMass(robot.model, robot.model.createData(), np.asarray(q_start, float))
        com = com0 + np.asarray(foot_com_shift, float)
        com_half = com0 + 0.5 * np.asarray(foot_com_shift, float)
    q_off = _solve(robot, env, q_start, {**targets, limb: T_off}, f"{limb} back-off")
    path = [q_start, q_off]
    durations = [timing.back_off_s]
    if T_mid is not None:
        path.append(_solve(robot, env, q_off, {**targets, limb: T_mid}, f"{limb} rise", com_half))
        durations.append(0.6 * timing.travel_s)
    path.append(_solve(robot, env, path[-1], {**targets, limb: T_pre}, f"{limb} pre-contact", com))
    durations.append(timing.travel_s if T_mid is None else 0.4 * timing.travel_s)
    path.append(_solve(robot, env, path[-1], {**targets, limb: hold}, f"{limb} on {target_surface}", com))
    durations.append(timing.approach_s)
    times = np.cumsum([0.0] + durations)
    primitive = "place_hand" if limb in HANDS else "place_foot"
    return Transition(primitive, limb, kept, kept.with_hold(hold), times, np.array(path))


def plan_of(robot, env, stance: Stance, transitions: list[Transition]) -> WholeBodyPlan:
    return WholeBodyPlan(robot.config.name, env.name, list(robot.joint_names), stance, list(transitions))
