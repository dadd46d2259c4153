"""Replanning from a measured state (partially known ladders: plan k cycles, execute them, plan the
next k from where the robot really is).

A measured configuration is a few millimetres off the planner's contact manifold (the controller
holds the contacts where the F/T found them, the estimator has its own noise), so it is first
projected onto the stance's contact constraints (:class:`planner_node.adapt.ContactProjector`,
minimum-norm Gauss-Newton steps) and re-checked with the planner's feasibility check; the plan then
starts there. A measured state the check refuses (a knee resting against the rung above after a
foot found its rung higher than planned: inside the planner's collision margin) is repaired by the
physics-constrained IK on the same stance, seeded and pulled toward it; the controller blends the
difference out along the plan's first transition.
"""
from __future__ import annotations

from typing import Any

import numpy as np

from climb_core.contact import Stance
from climb_core.errors import InfeasibleError

from . import pcik
from .adapt import AdaptContext, ContactProjector, failure_name
from .climb_planner import ClimbPlanResult, plan_climb
from .settings import PlannerSettings, load_settings


#: [m] the projection may move the base this far at most: farther, the robot is not in that stance
MAX_BASE_PROJECTION = 0.05


def measured_start(robot: Any, env: Any, q_measured: np.ndarray, stance: Stance,
                   settings: PlannerSettings | None = None, max_base_projection: float = MAX_BASE_PROJECTION
                   ) -> np.ndarray:
    """``q_measured`` projected onto ``stance``'s contact constraints; InfeasibleError naming the
    violated constraint when the projection fails, moves the base more than
    ``max_base_projection`` [m] (the robot is not in that stance), or the projected state is not
    feasible."""
    settings = settings or load_settings()
    ctx = AdaptContext(robot, env, None, settings)
    q = np.asarray(q_measured, dtype=float)
    if q.shape != (robot.model.nq,) or not np.all(np.isfinite(q)):
        raise InfeasibleError("q_measured", f"must be {robot.model.nq} finite numbers, got shape {q.shape}")
    q_proj = ContactProjector(ctx, stance, q)(q)
    if q_proj is None:
        raise InfeasibleError("reach", "the measured configuration does not project onto the stance's holds")
    moved = float(np.linalg.norm(q_proj[:3] - q[:3]))
    if moved > max_base_projection:
        raise InfeasibleError("start_projection", f"the measured base is {moved:.3f} m from the stance's "
                                                  f"contact manifold (at most {max_base_projection} m)")
    res = ctx.check(q_proj, stance)
    if res.feasible:
        return q_proj
    repaired = _repair(ctx, q_proj, stance)
    if repaired is None or float(np.linalg.norm(repaired[:3] - q[:3])) > max_base_projection:
        raise InfeasibleError(failure_name(res), "the measured state is not a feasible start (and the "
                                                 "IK found none within reach of it)")
    return repaired


def _repair(ctx: AdaptContext, q: np.ndarray, stance: Stance) -> np.ndarray | None:
    """The nearest feasible configuration on ``stance`` the physics-constrained IK finds from
    ``q`` (seeded and pulled toward it), projected and checked; None when there is none."""
    pr = pcik.solve(ctx.robot, ctx.env, q, stance, q_target=q, params=ctx.settings.pcik,
                    feasibility_cfg=ctx.check_cfg, self_margin=ctx.settings.planning.self_collision_margin)
    if not pr.success:
        return None
    q_c = ContactProjector(ctx, stance, pr.q)(pr.q)
    if q_c is None or not ctx.check(q_c, stance).feasible:
        return None
    return q_c


def plan_from_measured(robot: Any, env: Any, q_measured: np.ndarray, stance: Stance, steps: int,
                       **kwargs) -> ClimbPlanResult:
    """Plan ``steps`` more cycles (keyword arguments of :func:`plan_climb`) from a measured state."""
    q0 = measured_start(robot, env, q_measured, stance, kwargs.get("settings"))
    return plan_climb(robot, env, steps, start=(q0, stance), **kwargs)
