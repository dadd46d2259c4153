"""The climb's variants, executed in-process on G1: a rung up and back down. (The 2-step climb
planned one cycle at a time from the reached state, with a one-period actuation latency, runs
perturbed in test_climb_rung_error.py.)"""
from __future__ import annotations

import pytest

from climb_checks import RUNGS, assert_standing_on, check_run

pytestmark = [pytest.mark.sim, pytest.mark.heavy]


def test_climb_one_rung_and_back_down(tmp_path):
    """Climbing down is the climb run backwards (planner_node.descend): mount, one cycle up (feet
    on rung 1), then the cycle reversed (hands down to rung 4, right foot, left foot down to the
    ground). Both feet stood on rung 1 when the descent began and stand on the ground at the end,
    the hands still hold rung 4, nothing fell, the feet found the ground from F/T."""
    from climb_coordinator.climb import ClimbRequest, run_climb
    from climb_coordinator.settings import load_climb_settings

    settings = load_climb_settings()
    result = run_climb(ClimbRequest(ladder="default", robot="g1", rungs=1, mode="qp", out_dir=tmp_path, seed=0,
                                    descend=True), settings)
    try:
        s = result.summary
        feet, loads = check_run(result, settings, "qp")
        assert s["success"], s["failure_reason"]
        assert s["top_feet_rungs"] == {"left_foot": 1, "right_foot": 1}
        assert feet == {"left_foot": 0, "right_foot": 0}, feet
        assert s["grasps"] == {"left_hand": "rung_4", "right_hand": "rung_4"}
        down = result.plan.transitions[s["descent_start_transition"]:]
        assert [t.moving_limb for t in down if t.moving_limb] == ["right_hand", "left_hand", "right_foot", "left_foot"]
        # every limb placement of the descent was found from F/T too
        detected = result.controller.events_of("contact_detected")
        assert len(detected) == len([t for t in result.plan.transitions if t.moving_limb])
        # the base went up by about a rung and came back ([m], rung spacing 0.3)
        base = result.log.arrays()["base"][:, 2]
        assert base.max() - base[0] > 0.2 and abs(base[-1] - base[0]) < 0.05
    finally:
        result.close()
