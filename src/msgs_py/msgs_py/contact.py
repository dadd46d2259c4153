"""climb_msgs plan messages <-> climb_core.contact dataclasses.

``<thing>_to_msg(obj, ...)`` and ``<thing>_from_msg(msg, ...)`` for ContactPoint, Hold, Stance,
Configuration (a Pinocchio q), GuidePath, ContactPlan, Transition and WholeBodyPlan. Every
``_from_msg`` validates what arrived (limb names, finite numbers, matching lengths, q sizes of
7 + len(joint_names)) and raises SpecError naming the offending field, e.g.
``whole_body_plan.transitions[2].path[5]``. Positions and normals are in the world frame; the
headers written carry ``stamp`` [s] and the frame ``world``.
"""
from __future__ import annotations

import array

import numpy as np
from climb_msgs.msg import Configuration as ConfigurationMsg
from climb_msgs.msg import ContactPlan as ContactPlanMsg
from climb_msgs.msg import ContactPoint as ContactPointMsg
from climb_msgs.msg import GuidePath as GuidePathMsg
from climb_msgs.msg import Hold as HoldMsg
from climb_msgs.msg import Stance as StanceMsg
from climb_msgs.msg import Transition as TransitionMsg
from climb_msgs.msg import WholeBodyPlan as WholeBodyPlanMsg

from climb_core.contact import (LIMBS, ContactPlan, ContactPoint, GuidePath, Hold, Stance,
                                Transition, WholeBodyPlan)
from climb_core.errors import SpecError

from ._check import finite_float, finite_vector, one_of
from .geometry import point_from_msg, point_to_msg, vector3_from_msg, vector3_to_msg
from .stamps import WORLD_FRAME, make_header

#: Free-flyer part of a Pinocchio configuration: base position (3) + quaternion x y z w (4).
FREE_FLYER_NQ = 7


# --- ContactPoint, Hold, Stance -------------------------------------------------------------

def contact_point_to_msg(point: ContactPoint, field: str = "contact_point") -> ContactPointMsg:
    return ContactPointMsg(position=point_to_msg(point.position, f"{field}.position"),
                           normal=vector3_to_msg(point.normal, f"{field}.normal"))


def contact_point_from_msg(msg: ContactPointMsg, field: str = "contact_point") -> ContactPoint:
    position = finite_vector(point_from_msg(msg.position), f"{field}.position", 3)
    normal = finite_vector(vector3_from_msg(msg.normal), f"{field}.normal", 3)
    if np.linalg.norm(normal) < 1e-9:
        raise SpecError(f"{field}.normal", "must be a non-zero vector")
    return ContactPoint(position=position, normal=normal)


def _check_hold(hold: Hold, field: str) -> None:
    one_of(hold.limb, LIMBS, f"{field}.limb")
    if not hold.points:
        raise SpecError(f"{field}.points", "a hold needs at least one contact point")
    if finite_float(hold.friction, f"{field}.friction") < 0.0:
        raise SpecError(f"{field}.friction", f"must be >= 0, got {hold.friction}")
    if finite_float(hold.grip_force_limit, f"{field}.grip_force_limit") < 0.0:
        raise SpecError(f"{field}.grip_force_limit", f"must be >= 0 [N], got {hold.grip_force_limit}")


def hold_to_msg(hold: Hold, field: str = "hold") -> HoldMsg:
    _check_hold(hold, field)
    return HoldMsg(limb=hold.limb, robot_surface=hold.robot_surface, env_surface=hold.env_surface,
                   points=[contact_point_to_msg(p, f"{field}.points[{i}]") for i, p in enumerate(hold.points)],
                   friction=float(hold.friction), bilateral=bool(hold.bilateral),
                   grip_force_limit=float(hold.grip_force_limit))


def hold_from_msg(msg: HoldMsg, field: str = "hold") -> Hold:
    hold = Hold(limb=msg.limb, robot_surface=msg.robot_surface, env_surface=msg.env_surface,
                points=tuple(contact_point_from_msg(p, f"{field}.points[{i}]") for i, p in enumerate(msg.points)),
                friction=msg.friction, bilateral=msg.bilateral, grip_force_limit=msg.grip_force_limit)
    _check_hold(hold, field)
    return hold


def stance_to_msg(stance: Stance, field: str = "stance") -> StanceMsg:
    return StanceMsg(name=stance.name,
                     holds=[hold_to_msg(h, f"{field}.holds[{i}]") for i, h in enumerate(stance.holds)])


def stance_from_msg(msg: StanceMsg, field: str = "stance") -> Stance:
    holds = tuple(hold_from_msg(h, f"{field}.holds[{i}]") for i, h in enumerate(msg.holds))
    seen: dict[str, int] = {}
    for i, h in enumerate(holds):
        if h.limb in seen:
            raise SpecError(f"{field}.holds[{i}].limb", f"{h.limb} already holds in holds[{seen[h.limb]}]")
        seen[h.limb] = i
    return Stance(holds=holds, name=msg.name)


# --- Configurations -------------------------------------------------------------------------

def _check_q(q: np.ndarray, joint_names: list[str] | None, field: str) -> np.ndarray:
    nq = None if joint_names is None else FREE_FLYER_NQ + len(joint_names)
    q = finite_vector(q, field)
    if nq is not None and q.shape[0] != nq:
        raise SpecError(field, f"must have 7 + len(joint_names) = {nq} entries, got {q.shape[0]}")
    return q


def configuration_to_msg(q: np.ndarray, joint_names: list[str] | None = None,
                         field: str = "configuration") -> ConfigurationMsg:
    """Pinocchio q (base xyz, quaternion xyzw, joints [rad]) -> Configuration; the size is checked
    against ``joint_names`` when given."""
    q = _check_q(q, joint_names, field)
    return ConfigurationMsg(q=array.array("d", q.tobytes()))


def configuration_from_msg(msg: ConfigurationMsg, joint_names: list[str] | None = None,
                           field: str = "configuration") -> np.ndarray:
    return _check_q(np.frombuffer(msg.q, dtype=float).copy(), joint_names, field)


def _check_joint_names(joint_names: list[str], field: str) -> list[str]:
    names = list(joint_names)
    if len(set(names)) != len(names):
        dup = next(n for n in names if names.count(n) > 1)
        raise SpecError(field, f"joint {dup!r} appears twice")
    return names


# --- GuidePath, ContactPlan -----------------------------------------------------------------

def guide_path_to_msg(path: GuidePath, stamp: float = 0.0, frame_id: str = WORLD_FRAME) -> GuidePathMsg:
    f = "guide_path"
    names = _check_joint_names(path.joint_names, f"{f}.joint_names")
    return GuidePathMsg(header=make_header(stamp, frame_id), robot=path.robot, environment=path.environment,
                        joint_names=names,
                        milestones=[configuration_to_msg(q, names, f"{f}.milestones[{i}]")
                                    for i, q in enumerate(path.milestones)])


def guide_path_from_msg(msg: GuidePathMsg) -> GuidePath:
    f = "guide_path"
    names = _check_joint_names(msg.joint_names, f"{f}.joint_names")
    return GuidePath(robot=msg.robot, environment=msg.environment, joint_names=names,
                     milestones=[configuration_from_msg(c, names, f"{f}.milestones[{i}]")
                                 for i, c in enumerate(msg.milestones)])


def _check_plan_lengths(n_stances: int, n_configurations: int, field: str) -> None:
    if n_stances != n_configurations:
        raise SpecError(f"{field}.transition_configurations",
                        f"must have one configuration per stance ({n_stances}), got {n_configurations}")


def contact_plan_to_msg(plan: ContactPlan, stamp: float = 0.0, frame_id: str = WORLD_FRAME) -> ContactPlanMsg:
    f = "contact_plan"
    names = _check_joint_names(plan.joint_names, f"{f}.joint_names")
    _check_plan_lengths(len(plan.stances), len(plan.transition_configurations), f)
    return ContactPlanMsg(
        header=make_header(stamp, frame_id), robot=plan.robot, environment=plan.environment, joint_names=names,
        stances=[stance_to_msg(s, f"{f}.stances[{i}]") for i, s in enumerate(plan.stances)],
        transition_configurations=[configuration_to_msg(q, names, f"{f}.transition_configurations[{i}]")
                                   for i, q in enumerate(plan.transition_configurations)])


def contact_plan_from_msg(msg: ContactPlanMsg) -> ContactPlan:
    f = "contact_plan"
    names = _check_joint_names(msg.joint_names, f"{f}.joint_names")
    _check_plan_lengths(len(msg.stances), len(msg.transition_configurations), f)
    return ContactPlan(
        robot=msg.robot, environment=msg.environment, joint_names=names,
        stances=[stance_from_msg(s, f"{f}.stances[{i}]") for i, s in enumerate(msg.stances)],
        transition_configurations=[configuration_from_msg(c, names, f"{f}.transition_configurations[{i}]")
                                   for i, c in enumerate(msg.transition_configurations)])


# --- Transition, WholeBodyPlan --------------------------------------------------------------

def _check_times(times: np.ndarray, n_path: int, field: str) -> np.ndarray:
    times = finite_vector(times, f"{field}.times")
    if times.shape[0] != n_path:
        raise SpecError(f"{field}.path", f"must have one way-point per time ({times.shape[0]}), got {n_path}")
    steps = np.diff(times)
    if steps.size and steps.min() <= 0.0:
        i = int(np.argmin(steps)) + 1
        raise SpecError(f"{field}.times[{i}]", "times must increase strictly [s]")
    return times


def transition_to_msg(transition: Transition, joint_names: list[str] | None = None,
                      field: str = "transition") -> TransitionMsg:
    """Transition -> message; ``joint_names`` (when given) fixes nq = 7 + len(joint_names)."""
    if transition.moving_limb:
        one_of(transition.moving_limb, LIMBS, f"{field}.moving_limb")
    path = np.asarray(transition.path, dtype=float)
    path = path.reshape(len(path), -1) if path.size else path.reshape(0, 0)
    times = _check_times(transition.times, path.shape[0], field)
    return TransitionMsg(
        primitive=transition.primitive, moving_limb=transition.moving_limb,
        stance=stance_to_msg(transition.stance, f"{field}.stance"),
        target_stance=stance_to_msg(transition.target_stance, f"{field}.target_stance"),
        times=array.array("d", times.tobytes()),
        path=[configuration_to_msg(q, joint_names, f"{field}.path[{i}]") for i, q in enumerate(path)])


def transition_from_msg(msg: TransitionMsg, joint_names: list[str] | None = None,
                        field: str = "transition") -> Transition:
    """Message -> Transition; ``path`` is an (n, nq) array, (0, nq) when empty."""
    if msg.moving_limb:
        one_of(msg.moving_limb, LIMBS, f"{field}.moving_limb")
    rows = [configuration_from_msg(c, joint_names, f"{field}.path[{i}]") for i, c in enumerate(msg.path)]
    if rows and len({r.shape[0] for r in rows}) != 1:
        i = next(i for i, r in enumerate(rows) if r.shape[0] != rows[0].shape[0])
        raise SpecError(f"{field}.path[{i}]",
                        f"must have {rows[0].shape[0]} entries like path[0], got {rows[i].shape[0]}")
    nq = FREE_FLYER_NQ + len(joint_names) if joint_names is not None else 0
    path = np.array(rows) if rows else np.zeros((0, nq))
    times = _check_times(np.frombuffer(msg.times, dtype=float).copy(), path.shape[0], field)
    return Transition(primitive=msg.primitive, moving_limb=msg.moving_limb,
                      stance=stance_from_msg(msg.stance, f"{field}.stance"),
                      target_stance=stance_from_msg(msg.target_stance, f"{field}.target_stance"),
                      times=times, path=path)


def whole_body_plan_to_msg(plan: WholeBodyPlan, stamp: float = 0.0,
                           frame_id: str = WORLD_FRAME) -> WholeBodyPlanMsg:
    f = "whole_body_plan"
    names = _check_joint_names(plan.joint_names, f"{f}.joint_names")
    return WholeBodyPlanMsg(
        header=make_header(stamp, frame_id), robot=plan.robot, environment=plan.environment, joint_names=names,
        initial_stance=stance_to_msg(plan.initial_stance, f"{f}.initial_stance"),
        transitions=[transition_to_msg(t, names, f"{f}.transitions[{i}]") for i, t in enumerate(plan.transitions)])


def whole_body_plan_from_msg(msg: WholeBodyPlanMsg) -> WholeBodyPlan:
    f = "whole_body_plan"
    names = _check_joint_names(msg.joint_names, f"{f}.joint_names")
    return WholeBodyPlan(
        robot=msg.robot, environment=msg.environment, joint_names=names,
        initial_stance=stance_from_msg(msg.initial_stance, f"{f}.initial_stance"),
        transitions=[transition_from_msg(t, names, f"{f}.transitions[{i}]") for i, t in enumerate(msg.transitions)])
