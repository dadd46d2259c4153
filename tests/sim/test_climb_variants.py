"""The climb's variants, executed in-process on G1: a rung up and back down, and a 2-step climb
planned one cycle at a time from the reached state with a one-period actuation latency."""
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


def test_two_step_climb_replanned_from_the_reached_state(tmp_path):
    """Partially known ladders: the planner plans one cycle at a time; after the first cycle the
    second is planned from the configuration the simulator reached (projected onto the held
    stance), and the robot ends standing on rung 2 as with the plan made at once.

    With a one-period actuation latency: every command acts one control period late, as on a
    robot, and the controller computes each command for the state one period ahead
    (``actuation_latency_s``, set by the request). Without that prediction the 2-step climb ends
    in failure at transition 11 of 21 after 151 infeasible QPs (measured)."""
    from climb_coordinator.climb import ClimbRequest, run_climb
    from climb_coordinator.settings import load_climb_settings

    settings = load_climb_settings()
    result = run_climb(ClimbRequest(ladder="default", robot="g1", rungs=RUNGS, mode="qp", out_dir=None, bag=False,
                                    seed=0, plan_cycles=1, command_delay_ticks=1), settings)
    try:
        s = result.summary
        assert s["success"], s["failure_reason"]
        assert s["command_delay_ticks"] == 1
        assert result.controller.params.actuation_latency_s == pytest.approx(0.005)
        assert not s["fell"] and s["qp_failures"] == 0
        (replan,) = s["replans"]
        assert replan["cycles"] == 1 and "failure_reason" not in replan
        assert replan["start_projection_mm"] < 10.0  # the reached state was a few mm off the plan
        assert s["feet_rungs"] == {"left_foot": RUNGS, "right_foot": RUNGS}
        for foot in ("left_foot", "right_foot"):
            assert_standing_on(result.backend, foot, RUNGS)
        assert s["transitions_done"] == s["n_transitions"] == len(result.plan.transitions)
    finally:
        result.close()
