"""A scene without a ladder, planned by the DARPA-tasks paper's method and executed in-process on
G1 (issue 17): narrow_passage_step, the 0.33 m step of narrow_passage with a block beside it.

The free-flyer guide path, the best-first contact search and the generic contact-body paths plan
the whole scene (tests/data/narrow_passage_step_plan.json: ``scripts/plan.py --scenario
narrow_passage_step --strategy search --out ...``, the planner's own settings): the right hand
pushes on the block with the back of the hand while the feet step up to the step and the right
foot goes onto it, then the hand leaves it for good and the feet walk onto the step, one at a
time. The controller executes the whole plan - 19 transitions, the single-support steps included
- in lock-step with PyBullet, to the scene's goal, and the test checks what the simulator
measured. (Before ``planning.sole_cop_margin``, the first single-support step tipped over the heel:
its planned CoM stood 3 cm inside the sole's edge, the CoP measured at the edge.)"""
from __future__ import annotations

import os
import pathlib

import numpy as np
import pytest

from climb_checks import check_run, execute_stored_scene_plan, touched_surfaces

pytestmark = [pytest.mark.sim, pytest.mark.heavy]

STORED_PLAN = pathlib.Path(__file__).resolve().parents[1] / "data" / "narrow_passage_step_plan.json"


def test_the_stored_plan_of_the_step_is_executed_to_the_goal_with_the_hand_on_the_block_carrying_weight(tmp_path):
    """The stored plan (the planner's output, deterministic to execute), every transition."""
    result, settings = execute_stored_scene_plan("narrow_passage_step", STORED_PLAN, tmp_path, 15)
    _check_the_scene(result, settings)


@pytest.mark.skipif(os.environ.get("CLIMB_SLOW_TESTS") != "1",
                    reason="plans the scene in the test; measured 2026-11-29 (twenty-second session): not "
                           "planned within 300 s (sub-task 9-11, with and without the palm-zone fix; "
                           "docs/benchmarks.md): set CLIMB_SLOW_TESTS=1")
def test_the_step_is_planned_whole_body_then_executed(tmp_path):
    import dataclasses

    from climb_coordinator.climb import ClimbRequest, run_climb
    from climb_coordinator.settings import load_climb_settings

    # planned with the planner's own torque shares (config/planner.yaml), not config/climb.yaml's
    # ladder headroom (pcik 0.6): with it, G1's wrists push too little on the block and the
    # adaptation runs out of time (time_limit at sub-task 13 of 24, 300 s)
    settings = dataclasses.replace(load_climb_settings(), planner_overrides={})
    result = run_climb(ClimbRequest(ladder="narrow_passage_step", robot="g1", rungs=1, mode="qp", out_dir=tmp_path,
                                    seed=0, strategy="search", command_delay_ticks=1, plan_timeout_s=300.0),
                       settings)
    assert set(result.summary["plan_stages_s"]) == {"guide_path", "contact_search", "adaptation"}
    _check_the_scene(result, settings)


def _check_the_scene(result, settings) -> None:
    try:
        s = result.summary
        assert s["success"], s["failure_reason"]
        # the scene's goal: the base within its tolerance, standing still, nothing fallen
        assert s["goal_reached"] and s["goal_distance_m"] <= 0.15, s
        assert s["settle_base_speed_max_m_s"] < 0.02
        assert {"ground", "palm_block", "step"} <= set(s["contacts_used"])
        assert s["scene"] == "narrow_passage_step" and s["rungs_requested"] == 0
        feet, loads = check_run(result, settings, "qp")
        moves = [(t.primitive, t.moving_limb) for t in result.plan.transitions]
        assert moves[:3] == [("com_to_foot", ""), ("place_hand", "right_hand"), ("place_foot", "right_foot")], moves
        assert ("free_hand", "right_hand") in moves
        # every placement found by F/T (the hand's push included), no gripper closed
        c = result.controller
        placed = [limb for primitive, limb in moves if primitive.startswith("place_")]
        assert [e.values["limb"] for e in c.events_of("contact_detected")] == placed
        assert not [e for e in c.events_of("gripper") if e.values["command"] == "close"]
        # while a foot was in the air with the hand on the block, the hand carried >= 10 % of the weight
        weight = 9.81 * result.backend.robot.mass
        log = result.log.loads
        hand_while_a_foot_up = [h[0] for h, lf, rf in zip(log["right_hand"], log["left_foot"], log["right_foot"])
                                if h is not None and h[2] == "palm_block"
                                and (lf is None or lf[0] < 1.0 or rf is None or rf[0] < 1.0)]
        assert len(hand_while_a_foot_up) > 50  # samples of the steps with the hand down (log rate)
        assert max(hand_while_a_foot_up) >= 0.10 * weight, (max(hand_while_a_foot_up), weight)
        # at the end: both feet carry the robot on the step, the hands touch nothing
        assert loads["left_foot"].surface == loads["right_foot"].surface == "step", loads
        # (the plan ends with the left foot placed, the CoM still over the right one: 13 N against 320 N, measured)
        assert min(loads["left_foot"].normal_force, loads["right_foot"].normal_force) > 5.0, loads
        assert loads["left_foot"].normal_force + loads["right_foot"].normal_force > 0.9 * weight, loads
        assert set(loads) == {"left_foot", "right_foot"}, loads
        step_top = 0.33
        for foot in ("left_foot", "right_foot"):
            sole = result.backend.surface_pose(foot)[:3, 3]
            assert abs(sole[2] - step_top) < 0.02 and 0.5 < sole[0] < 1.5, (foot, sole)
        # nothing but the hands and the feet touched the scene (the walls included)
        touched = touched_surfaces(result.backend)
        assert touched <= {"ground", "step", "palm_block"}, touched
        # the base went up the step: 0.33 m higher, about a metre forward
        base = result.log.arrays()["base"]
        assert np.all(np.isfinite(base))
        assert base[-1, 2] - base[0, 2] > 0.28 and base[-1, 0] - base[0, 0] > 0.9, (base[0, :3], base[-1, :3])
    finally:
        result.close()


NARROW_PASSAGE_PLAN = pathlib.Path(__file__).resolve().parents[1] / "data" / "narrow_passage_plan.json"


@pytest.mark.heavy
@pytest.mark.long  # make test-long: 603 s of motion, 61 transitions, ~10 min wall
@pytest.mark.timeout(1800)  # ~1x real time alone, slower beside other work
def test_the_whole_narrow_passage_is_executed_to_the_goal(tmp_path):
    """The whole scene of the paper's Fig. 3 (config/scenes/narrow_passage.yaml): the corridor, the
    inclined floor, the flat floor, the 0.33 m step with the block beside it. Planned by guide path +
    contact search + generic paths with the scene's own planner settings (its ``planner_overrides``:
    tests/data/narrow_passage_plan.json is ``scripts/plan.py --scenario narrow_passage --out ...``,
    ~6.5 min; at the planner's default speeds the first single-support step tipped G1 over its
    toe, the scene is timed at half of them). Executed from standing to the goal: 61 transitions,
    the feet on the ground, the incline, the floor and the step, the back of the right hand on the
    block carrying >= 10 % of the weight while a foot is up."""
    result, settings = execute_stored_scene_plan("narrow_passage", NARROW_PASSAGE_PLAN, tmp_path, 50)
    try:
        s = result.summary
        assert s["success"], s["failure_reason"]
        assert s["goal_reached"] and s["goal_distance_m"] <= 0.15 and not s["fell"], s
        assert s["transitions_done"] == s["n_transitions"] >= 50 and s["qp_failures"] == 0
        assert {"ground", "incline", "floor", "palm_block", "step"} <= set(s["contacts_used"])
        feet, loads = check_run(result, settings, "qp")  # loads in their cones, nothing fallen
        weight = 9.81 * result.backend.robot.mass
        log = result.log.loads
        hand_while_a_foot_up = [h[0] for h, lf, rf in zip(log["right_hand"], log["left_foot"], log["right_foot"])
                                if h is not None and h[2] == "palm_block"
                                and (lf is None or lf[0] < 1.0 or rf is None or rf[0] < 1.0)]
        assert hand_while_a_foot_up and max(hand_while_a_foot_up) >= 0.10 * weight, (hand_while_a_foot_up[:3], weight)
        assert loads["left_foot"].surface == loads["right_foot"].surface == "step", loads
        assert set(loads) == {"left_foot", "right_foot"}, loads
        for foot in ("left_foot", "right_foot"):
            sole = result.backend.surface_pose(foot)[:3, 3]
            assert abs(sole[2] - 0.45) < 0.02 and 2.4 < sole[0] < 3.4, (foot, sole)
        assert touched_surfaces(result.backend) <= {"step", "palm_block"}
        base = result.log.arrays()["base"]
        assert base[-1, 2] - base[0, 2] > 0.40 and base[-1, 0] - base[0, 0] > 2.9, (base[0, :3], base[-1, :3])
    finally:
        result.close()
