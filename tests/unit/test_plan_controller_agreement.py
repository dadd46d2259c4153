"""The controller can hold, at rest, every stance the planner planned (no simulator).

The planner certifies its configurations with climb_core.feasibility (friction pyramids, grip
polytopes, torque limits); the controller holds them with its QP's contact model. For every
transition of the default 2-step climb (planned with the climb's settings, config/climb.yaml), at
the path's first and last configuration, the least static max |tau| / effort the QP's contact rows
allow must be within the QP's torque limit fraction. (A friction pyramid rotated by 45 deg against
the planner's once made the single-foot stances impossible to hold at rest: ratio 1.34.) On a
steep grid ladder (78 deg, 26 cm) the one-foot stance needs 1.09: the planner's 8-point grasps carry
~30 N m where the QP caps a grasp's moment at 6 N m per axis; planned with the same cap, 0.83.
"""
from __future__ import annotations

import numpy as np
import pytest

from climb_coordinator.settings import apply_planner_overrides, load_climb_settings
from controller_node.agreement import controller_static_ratio
from controller_node.controller import Controller
from controller_node.estimator import RobotState
from controller_node.params import load_controller_params
from planner_node import plan_io
from planner_node.climb_planner import plan_climb
from planner_node.settings import load_settings


def _plan(g1, env, extra: dict | None = None):
    cs = load_climb_settings()
    overrides = {**cs.planner_overrides, **(extra or {})}
    settings = apply_planner_overrides(load_settings(), overrides)

    def compute():
        res = plan_climb(g1, env, 2, settings=settings, seed=0)
        return (res.plan if res.success else None), res.summary()

    key = plan_io.source_fingerprint("test_plan_controller_agreement", env.scenario, 2, 0,
                                     sorted(overrides.items()))
    plan, meta = plan_io.cached_plan(key, compute)
    assert plan is not None, meta.get("failure_reason")
    return plan, cs


@pytest.fixture(scope="module")
def climb_plan(g1, env):
    return _plan(g1, env)


@pytest.fixture(scope="module")
def steep_env():
    """The grid's 78 deg / 26 cm ladder (../shared/bench/ladder_grid.yaml's base)."""
    from climb_core.environment import build_environment
    from climb_core.ladder import parse_scenario

    ladder = {"type": "regular", "n_rungs": 8, "first_rung_height": 0.25, "rung_width": 0.5,
              "rung": {"shape": "circle", "diameter": 0.04}, "stringer": {"width": 0.08, "depth": 0.03},
              "rails": [], "friction": 0.25, "pose": {"x": 0.45, "y": 0.0, "yaw_deg": 0.0},
              "inclination_deg": 78.0, "rung_spacing": 0.26}
    return build_environment(parse_scenario({"ladder": ladder}, name="grid_78_026"))


def _ratio(g1, env, params, q, stance) -> float:
    controller = Controller(g1, params, env)
    zero = np.zeros(g1.model.nv)
    controller.reset(RobotState(0.0, np.array(q, float), zero), stance)
    return controller_static_ratio(controller)


def _worst(g1, env, plan, cs):
    params = load_controller_params(**cs.controller_overrides)
    limit = params.qp.torque_limit_fraction
    worst = (0.0, "")
    for i, t in enumerate(plan.transitions):
        for where, q in (("start", t.path[0]), ("end", t.path[-1])):
            r = _ratio(g1, env, params, q, t.stance)
            assert r <= limit, (i + 1, t.primitive, t.moving_limb, where, r)
            worst = max(worst, (r, f"{i + 1}:{t.primitive}:{where}"))
    return worst


def test_every_planned_stance_is_holdable_under_the_qp_contact_model(g1, env, climb_plan):
    plan, cs = climb_plan
    worst = _worst(g1, env, plan, cs)
    # the single-foot ladder stances are the hard ones; they load some joint to a real share
    assert worst[0] > 0.3, worst


def test_a_crippled_contact_model_is_caught(g1, env, climb_plan):
    """Control: with cones 20x narrower than the ladder's friction the same check fails on the
    one-foot-on-a-rung stance (the check can fail)."""
    plan, cs = climb_plan
    params = load_controller_params(**{**cs.controller_overrides, "contacts.friction_margin": 0.05})
    t = next(t for t in plan.transitions if t.primitive == "place_foot" and t.moving_limb == "right_foot"
             and any(h.env_surface.startswith("rung") for h in t.stance.holds if h.limb == "left_foot"))
    assert _ratio(g1, env, params, t.path[0], t.stance) > params.qp.torque_limit_fraction


def test_a_steep_ladders_stances_are_holdable_with_the_grasp_moment_cap(g1, steep_env):
    """78 deg: the one-foot stance leans on the grasps' moments. Planned with the controller's
    per-axis cap (planning / pcik.grasp_moment_limit 6 N m; off by default, docs/planner.md) every
    stance is holdable (without it: 1.09 at the one-foot stance). Measured with the grasps' roll free
    between configurations, as it was then (``projection.latch_grasps`` false): with latched grasps
    and the cap this ladder does not plan in the time limit (sub-task 9, hip-pitch torque)."""
    plan, cs = _plan(g1, steep_env, {"planning.grasp_moment_limit": 6.0, "pcik.grasp_moment_limit": 6.0,
                                     "projection.latch_grasps": False})
    worst = _worst(g1, steep_env, plan, cs)
    assert worst[0] > 0.5, worst  # the hard stance loads some joint to a real share
