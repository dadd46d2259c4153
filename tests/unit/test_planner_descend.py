"""Climbing down as the reverse of a climb: the reversed plan is continuous, keeps the kept holds,
mirrors the timing, and passes the core feasibility re-check at 4x (G1, default ladder)."""
from __future__ import annotations

import numpy as np
import pytest

from climb_core.contact import WholeBodyPlan
from climb_core.errors import SpecError


@pytest.fixture(scope="module")
def up_plan(g1, env):
    from planner_node import plan_io
    from planner_node.climb_planner import plan_climb

    def compute():
        res = plan_climb(g1, env, 1, seed=0)
        return (res.plan if res.success else None), res.summary()

    plan, meta = plan_io.cached_plan(plan_io.source_fingerprint("test_planner_descend", env.scenario, 1, 0), compute)
    assert plan is not None, meta.get("failure_reason")
    return plan


def test_descent_reverses_the_cycles_and_is_feasible(g1, env, up_plan):
    from planner_node.descend import descent_plan, first_cycle_index
    from planner_node.verify import verify_plan

    robot = g1
    first = first_cycle_index(up_plan)
    assert up_plan.transitions[first - 1].primitive == "mount"
    down = descent_plan(up_plan)
    cycle = up_plan.transitions[first:]
    assert len(down.transitions) == len(cycle)
    assert [t.moving_limb for t in down.transitions] == [t.moving_limb for t in reversed(cycle)]
    # starts where the climb ends, ends where the cycles began: feet on the ground, hands on rung 4
    assert np.array_equal(down.transitions[0].path[0], up_plan.transitions[-1].path[-1])
    assert np.array_equal(down.transitions[-1].path[-1], cycle[0].path[0])
    end = {h.limb: h.env_surface for h in down.transitions[-1].target_stance.holds}
    assert end == {"left_foot": "ground", "right_foot": "ground", "left_hand": "rung_4", "right_hand": "rung_4"}
    for orig, rev in zip(reversed(cycle), down.transitions):
        assert rev.stance is orig.stance  # the same holds are kept while the limb moves
        assert rev.times[0] == 0.0 and rev.times[-1] == pytest.approx(orig.times[-1])
        assert np.allclose(np.diff(rev.times), np.diff(orig.times)[::-1])
    report = verify_plan(robot, env, down, refine=4)
    assert report.ok, report.summary()
    assert report.goal_feet_rungs == (0, 0)


def test_descent_of_a_bad_index_is_refused(up_plan):
    from planner_node.descend import descent_plan

    with pytest.raises(SpecError, match="first"):
        descent_plan(up_plan, first=len(up_plan.transitions))
    empty = WholeBodyPlan(robot="g1", environment="default", joint_names=[], initial_stance=up_plan.initial_stance)
    with pytest.raises(SpecError, match="first"):
        descent_plan(empty)
