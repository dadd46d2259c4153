"""A grasp's guarded search creeps out of the palm (controller_node.tracking.PathTracker.approach_direction).

The coarse grid's 84 deg / 23 cm ladder, planned with the climb's planner_overrides (not the steep
ladder's grasp moment cap a climb of it adds since 2026-12-02: this plan is the one that showed the
fault, kept as the test's case): the first hand's mount ends
with a path whose last 20 % runs mostly along the rung, and the hand arrives 2 cm short of the rung.
Searching along that path slid the hand 5 cm along the rung without touching it (``no_contact``, a
replan that did not plan, thirty-first session's sweep). Executed here up to both hands' mounts
(lock-step, QP, one period of latency): each hand finds its rung by force within 2 cm of search,
both hands hold rung 4 in the simulator, nothing fell, no replan."""
from __future__ import annotations

import dataclasses
import pathlib

import pytest

pytestmark = [pytest.mark.sim, pytest.mark.heavy]

ROOT = pathlib.Path(__file__).resolve().parents[2]
COARSE = ROOT.parent / "shared" / "bench" / "ladder_grid_coarse.yaml"
MOUNTS = 7  # transitions 0-6: approach, CoM shifts, the left hand's mount, the right hand's


def test_a_grasp_that_arrives_short_of_its_rung_finds_it_along_the_palm_normal():
    import climb_coordinator.climb as climb_mod
    from climb_coordinator.climb import ClimbRequest, GivenPlanSource, LibraryPlanSource, execute, validate
    from climb_coordinator.settings import apply_planner_overrides, load_climb_settings
    from climb_core.ladder import parse_scenario
    from planner_node.primitives import load_library
    from planner_node.settings import load_settings
    from planner_node.sweep import load_grid, make_tasks, plan_task

    (task,) = make_tasks(load_grid(COARSE), "g1", select=[(84.0, 0.23)])
    cs = load_climb_settings()
    row, planned = plan_task(task, apply_planner_overrides(load_settings(), dict(cs.planner_overrides)))
    assert row["success"], row["failure_detail"]
    plan = planned.result.plan
    assert [t.primitive for t in plan.transitions[5:MOUNTS]] == ["mount", "mount"]
    plan = dataclasses.replace(plan, transitions=list(plan.transitions[:MOUNTS]))
    scenario = parse_scenario(task.spec, name=task.name)
    p = planned.settings.planning
    library = load_library("g1", p.strategy, p.primitives_dir, nq=planned.robot.model.nq)
    req = ClimbRequest(ladder=scenario, robot="g1", rungs=1, mode="qp", bag=False, seed=0, plan_timeout_s=60.0,
                       command_delay_ticks=1, strategy="primitives")
    validate(req)
    events = []
    close = climb_mod.InProcessExecutor.close

    def keep_events(self):  # the controller's events, read before the executor lets it go
        if getattr(self, "controller", None) is not None and not events:
            events.extend(self.controller.events)
        return close(self)

    mp = pytest.MonkeyPatch()
    mp.setattr(climb_mod.InProcessExecutor, "close", keep_events)
    try:
        source = GivenPlanSource(plan, planned.robot, cs, LibraryPlanSource(req, planned.robot, planned.env,
                                                                            planned.settings, cs))
        result = execute(req, source, cs, scenario, library.initial_fixture)
        s = result.summary
        result.close()
    finally:
        mp.undo()
    assert not s.get("fell"), s["failure_reason"]
    assert not s.get("replans"), s["replans"]
    assert s["transitions_done"] == MOUNTS, s["failure_reason"]
    assert s["grasps"] == {"left_hand": "rung_4", "right_hand": "rung_4"}  # latched in the simulator
    kinds = [e.kind for e in events]
    assert "search_exhausted" not in kinds and "replan_needed" not in kinds
    found = {e.values["limb"]: e.values for e in events if e.kind == "contact_detected"}
    for hand in ("left_hand", "right_hand"):
        assert found[hand]["by"] == "force", found
        assert found[hand].get("extra_travel", 0.0) <= 0.02, found  # within 2 cm of search past the plan
