"""A climb planned without any motion primitive, executed: the default ladder's contact plan for G1
(1 rung: approach steps, both hands onto rung 4, a cycle of foot, foot, hand, hand placements) made
whole-body by generic contact-body paths only (planner_node.contact_path, an empty primitive
library), then executed in lock-step against PyBullet by the QP controller in process. Judged on
the simulator's ground truth (tests/sim/climb_checks.py): the feet stand on rung 1, nothing fell,
unilateral loads inside their friction cones.

Opt-in (CLIMB_SLOW_TESTS=1: 77 s of sim time, 200-240 s wall on this machine): make test executes
generic paths through tests/sim/test_climb_search.py (a searched rung, no primitives, 50-70 s)."""
from __future__ import annotations

import os
import time

import pytest

from climb_checks import assert_standing_on, check_run

pytestmark = [pytest.mark.sim, pytest.mark.heavy,
              pytest.mark.skipif(os.environ.get("CLIMB_SLOW_TESTS") != "1",
                                 reason="a 1-rung generic climb from the ground (200-240 s): set CLIMB_SLOW_TESTS=1")]

RUNGS = 1


class GenericPlanSource:
    """Plan source port of the climb session: the pipeline's contact plan adapted with an empty
    primitive library (every step a generic path). It plans once; a replan is refused."""

    def __init__(self, psettings):
        self.psettings = psettings
        self.result = None

    def plan(self, steps: int, start=None, surface_offsets=None):
        from climb_coordinator.climb import clip_plan_to_limits
        from climb_coordinator.session import PlanOutcome
        from climb_coordinator.settings import load_climb_settings
        from planner_node.climb_planner import plan_from_contact_plan
        from planner_node.contact_path import empty_library
        from planner_node.pipeline import PlanRequest, contact_search, guide_path, load_problem

        if start is not None:
            return PlanOutcome(False, None, failure="replan: this test executes its one generic plan")
        t0 = time.perf_counter()
        pb = load_problem(PlanRequest(id="generic-sim", robot="g1", scenario="default", rungs=steps), self.psettings)
        cp = contact_search(pb, guide_path(pb).product).product
        res = plan_from_contact_plan(pb.robot, pb.env, cp, library=empty_library(pb.robot), settings=self.psettings,
                                     seed=0)
        self.result = res
        ok = bool(res.success and res.plan is not None)
        margin = load_climb_settings().plan_joint_limit_margin
        return PlanOutcome(ok, clip_plan_to_limits(res.plan, pb.robot, margin) if ok else res.plan,
                           time.perf_counter() - t0, res.n_stances,
                           "" if ok else f"{res.failure_constraint}: {res.failure_detail}", dict(res.stats))


def test_a_climb_of_generic_paths_is_executed_by_the_controller(tmp_path):
    from climb_coordinator.climb import ClimbRequest, execute
    from climb_coordinator.settings import apply_planner_overrides, load_climb_settings
    from climb_core.ladder import load_scenario
    from planner_node.settings import load_settings

    settings = load_climb_settings()
    plans = GenericPlanSource(apply_planner_overrides(load_settings(), settings.planner_overrides))
    req = ClimbRequest(ladder="default", robot="g1", rungs=RUNGS, mode="qp", out_dir=tmp_path, seed=0)
    result = execute(req, plans, settings, load_scenario("default"), "standing")
    try:
        s = result.summary
        assert plans.result is not None and plans.result.success, s["failure_reason"]
        print(f"\ngeneric plan: {s['n_stances']} stances in {s['plan_time_s']} s; executed {s['sim_time_s']} s "
              f"of sim time in {result.wall_time_s:.0f} s wall")
        feet, loads = check_run(result, settings, "qp")
        assert s["success"], s["failure_reason"]
        assert feet == {"left_foot": RUNGS, "right_foot": RUNGS}, feet
        for foot in ("left_foot", "right_foot"):
            assert_standing_on(result.backend, foot, RUNGS)
        assert s["grasps"] == {"left_hand": f"rung_{RUNGS + 4}", "right_hand": f"rung_{RUNGS + 4}"}
        # every placement was found by the guarded move (one contact per limb placement)
        placements = [t for t in result.plan.transitions if t.moving_limb]
        assert len(result.controller.events_of("contact_detected")) == len(placements)
    finally:
        result.close()
