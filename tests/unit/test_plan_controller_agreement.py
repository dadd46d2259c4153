"""The controller can hold, at rest, every stance the planner planned (no simulator).

The planner certifies its configurations with climb_core.feasibility (friction pyramids, grip
polytopes, torque limits); the controller holds them with its QP's contact model. For every
transition of the default 2-step climb (planned with the climb's settings, config/climb.yaml), at
the path's first and last configuration, the least static max |tau| / effort the QP's contact rows
allow must be within the QP's torque limit fraction. (A friction pyramid rotated by 45 deg against
the planner's once made the single-foot stances impossible to hold at rest: ratio 1.34; the QP's
cones at 0.8 mu against the planner's 0.95 did it again on the steep grid ladders: ratio 1.09 on
78 deg / 26 cm, every executed climb fell at its one-foot stance.)
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


#: a steep ladder of the grid (../shared/bench/ladder_grid.yaml's base, 78 deg, 26 cm): its
#: one-foot stance needs the foot's friction up to 0.94 mu; with the QP's cones at 0.8 mu it was
#: not holdable at rest (ratio 1.09) and every executed climb of it fell at transition 10
STEEP = {"ladder": {"type": "regular", "inclination_deg": 78.0, "rung_spacing": 0.26, "n_rungs": 8,
                    "first_rung_height": 0.25, "rung_width": 0.50, "rung": {"shape": "circle", "diameter": 0.04},
                    "stringer": {"width": 0.08, "depth": 0.03}, "rails": [], "friction": 0.25,
                    "pose": {"x": 0.45, "y": 0.0, "yaw_deg": 0.0}}}


def _plan(g1, env, name: str):
    cs = load_climb_settings()
    settings = apply_planner_overrides(load_settings(), cs.planner_overrides)

    def compute():
        res = plan_climb(g1, env, 2, settings=settings, seed=0)
        return (res.plan if res.success else None), res.summary()

    key = plan_io.source_fingerprint("test_plan_controller_agreement", name, env.scenario, 2, 0,
                                     sorted(cs.planner_overrides.items()))
    plan, meta = plan_io.cached_plan(key, compute)
    assert plan is not None, meta.get("failure_reason")
    return plan, cs


@pytest.fixture(scope="module")
def climb_plan(g1, env):
    return _plan(g1, env, "default")


@pytest.fixture(scope="module")
def steep(g1):
    from climb_core.environment import build_environment
    from climb_core.ladder import parse_scenario

    env = build_environment(parse_scenario(STEEP, name="grid_78_0.26"))
    return env, _plan(g1, env, "grid_78_0.26")


def _ratio(g1, env, params, q, stance) -> float:
    controller = Controller(g1, params, env)
    zero = np.zeros(g1.model.nv)
    controller.reset(RobotState(0.0, np.array(q, float), zero), stance)
    return controller_static_ratio(controller)


def _worst(g1, env, plan, params) -> tuple[float, str]:
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
    worst = _worst(g1, env, plan, load_controller_params(**cs.controller_overrides))
    # the single-foot ladder stances are the hard ones; they load some joint to a real share
    assert worst[0] > 0.3, worst


def test_a_steep_grid_ladders_stances_are_holdable_and_were_not_with_the_old_cones(g1, steep):
    env, (plan, cs) = steep
    params = load_controller_params(**cs.controller_overrides)
    worst = _worst(g1, env, plan, params)
    assert worst[0] > 0.5, worst
    old = load_controller_params(**{**cs.controller_overrides, "contacts.friction_margin": 0.8})
    t = next(t for t in plan.transitions if t.primitive == "place_foot" and t.moving_limb == "right_foot"
             and any(h.env_surface.startswith("rung") for h in t.stance.holds if h.limb == "left_foot"))
    assert _ratio(g1, env, old, t.path[0], t.stance) > old.qp.torque_limit_fraction


def test_the_qp_cones_admit_the_planners_own_friction_checks():
    """The QP's cones are no narrower than what the planner certifies its stances with
    (``planning.friction_margin``): a narrower cone made planned stances unholdable."""
    params = load_controller_params(**load_climb_settings().controller_overrides)
    assert params.contacts.friction_margin >= load_settings().planning.friction_margin


def test_a_crippled_contact_model_is_caught(g1, env, climb_plan):
    """Control: with cones 20x narrower than the ladder's friction the same check fails on the
    one-foot-on-a-rung stance (the check can fail)."""
    plan, cs = climb_plan
    params = load_controller_params(**{**cs.controller_overrides, "contacts.friction_margin": 0.05})
    t = next(t for t in plan.transitions if t.primitive == "place_foot" and t.moving_limb == "right_foot"
             and any(h.env_surface.startswith("rung") for h in t.stance.holds if h.limb == "left_foot"))
    assert _ratio(g1, env, params, t.path[0], t.stance) > params.qp.torque_limit_fraction
