"""Climbing down: the reverse motion of a planned climb.

A quasi-statically feasible plan stays feasible when it is run backwards: every configuration of
a transition is checked on the holds kept during it, whatever the direction, and every contact
switch happens at a configuration where the stance with and without the moving limb is feasible
(Adapt-Primitive requires the moving limb to be removable at both ends of its transfer and the
CoM transfers leave the next moving limb removable). Reversing a climb therefore gives a climb
down that needs no other primitives: a foot placed from rung k to rung k+1 becomes a foot stepping
down from k+1 to k, the hands move down before the feet, and the CoM transfers run backwards.

:func:`descent_plan` reverses the climbing cycles of an up plan (everything after the mount):
it starts where the up plan ends and ends with both feet on the ground and the hands on the rung
they mounted. :func:`plan_descent` plans the climb up with :func:`plan_climb` and returns its
reverse; :func:`up_and_down` concatenates the two (climb N rungs and come back).
"""
from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from climb_core.contact import Stance, Transition, WholeBodyPlan
from climb_core.errors import SpecError

from .adapt import ClimbState
from .climb_planner import ClimbPlanResult, plan_climb

#: primitive names of the transitions that take the robot from the ground onto the ladder
MOUNT_PRIMITIVES = ("mount",)


def reverse_transition(transition: Transition, start_stance: Stance) -> Transition:
    """``transition`` run backwards; ``start_stance`` is the stance it started from (the reverse
    ends there). The kept holds are the same; times are mirrored (the ramps are symmetric)."""
    times = np.asarray(transition.times, dtype=float)
    path = np.asarray(transition.path, dtype=float)
    if len(times) != len(path) or len(path) == 0:
        raise SpecError("transition.times", f"must have one time per configuration ({len(path)}), got {len(times)}")
    return Transition(primitive=transition.primitive, moving_limb=transition.moving_limb, stance=transition.stance,
                      target_stance=start_stance, times=(times[-1] - times[::-1]).copy(), path=path[::-1].copy())


def first_cycle_index(plan: WholeBodyPlan) -> int:
    """Index of the first transition after the last mount transition (0 if the plan has none)."""
    mounts = [i for i, t in enumerate(plan.transitions) if t.primitive in MOUNT_PRIMITIVES]
    return mounts[-1] + 1 if mounts else 0


def descent_plan(up: WholeBodyPlan, first: int | None = None) -> WholeBodyPlan:
    """The plan that undoes ``up.transitions[first:]`` (default: the climbing cycles after the
    mount) in reverse order, starting at the end of ``up``."""
    first = first_cycle_index(up) if first is None else int(first)
    if not 0 <= first < len(up.transitions):
        raise SpecError("first", f"must index a transition of the plan (0..{len(up.transitions) - 1}), got {first}")
    starts = [up.initial_stance] + [t.target_stance for t in up.transitions[:-1]]
    reversed_transitions = [reverse_transition(up.transitions[i], starts[i])
                            for i in range(len(up.transitions) - 1, first - 1, -1)]
    return WholeBodyPlan(robot=up.robot, environment=up.environment, joint_names=list(up.joint_names),
                         initial_stance=up.transitions[-1].target_stance, transitions=reversed_transitions)


def plan_descent(robot: Any, env: Any, steps: int, **kwargs) -> ClimbPlanResult:
    """Plan a climb of ``steps`` cycles (keyword arguments of :func:`plan_climb`) and return the
    descent from its top stance back to the ground. On failure the up plan's result is returned
    (it names the constraint that stopped the climb)."""
    up = plan_climb(robot, env, steps, **kwargs)
    if not up.success or up.plan is None:
        return up
    down = descent_plan(up.plan)
    return dataclasses.replace(up, plan=down, final_state=ClimbState(np.asarray(down.transitions[-1].path[-1]),
                                                                     down.transitions[-1].target_stance),
                               segments=[])


def up_and_down(robot: Any, env: Any, steps: int, **kwargs) -> ClimbPlanResult:
    """Climb ``steps`` cycles and come back down: the up plan followed by its descent
    (``stats["descent_start"]``: the index of the descent's first transition)."""
    up = plan_climb(robot, env, steps, **kwargs)
    if not up.success or up.plan is None:
        return up
    down = descent_plan(up.plan)
    both = dataclasses.replace(up.plan, transitions=list(up.plan.transitions) + list(down.transitions))
    return dataclasses.replace(up, plan=both, final_state=ClimbState(np.asarray(down.transitions[-1].path[-1]),
                                                                     down.transitions[-1].target_stance),
                               segments=[], stats=dict(up.stats, descent_start=len(up.plan.transitions)))
