"""The first real climb: G1 plans a 2-step climb of the default ladder (mount + two cycles) and
executes it in lock-step against PyBullet through the controller library, in QP mode and in PWM
compliance mode. Judged on the simulator's ground truth only: feet standing on rungs (contact
points and sole poses), no fall, unilateral contact forces inside their friction cones, and a
readable bag with the run's topics.

Each test plans the climb (seed 0) and executes all 21 transitions (approach steps, both hands
onto rung 4, then two cycles of foot, foot, hand, hand placements) in about 106 s of sim time."""
from __future__ import annotations

import pytest

from climb_checks import RUNGS, assert_standing_on, check_run, climb

pytestmark = pytest.mark.sim


@pytest.mark.parametrize("mode, delay", [("qp", 0), ("compliance", 0)], ids=["qp", "compliance"])
def test_two_step_climb_of_the_default_ladder(mode, delay, tmp_path):
    """Mount (both hands on rung 4) and two climbing cycles: both feet end standing on rung 2,
    both hands on rung 6, nothing fell, every unilateral load inside its friction cone.

    (With a one-period actuation latency: test_two_step_climb_replanned_from_the_reached_state.)"""
    result, settings = climb(mode, tmp_path, command_delay_ticks=delay)
    try:
        s = result.summary
        assert s.get("command_delay_ticks", 0) == delay
        assert result.controller.params.actuation_latency_s == pytest.approx(0.005 * delay)
        feet, loads = check_run(result, settings, mode)
        assert s["success"], s["failure_reason"]
        assert feet == {"left_foot": RUNGS, "right_foot": RUNGS}, feet
        assert s["rungs_reached"] == RUNGS
        for foot in ("left_foot", "right_foot"):
            assert_standing_on(result.backend, foot, RUNGS)
        # both feet carry the robot on rung 2 ([N] of the ~340 N weight, hands take the rest)
        assert loads["left_foot"].normal_force + loads["right_foot"].normal_force > 150.0
        assert s["grasps"] == {"left_hand": f"rung_{RUNGS + 4}", "right_hand": f"rung_{RUNGS + 4}"}
        # the guarded moves found every contact from F/T (one per limb placement)
        detected = result.controller.events_of("contact_detected")
        placements = [t for t in result.plan.transitions if t.moving_limb]
        assert len(detected) == len(placements)
        # the base rose by the two rungs climbed ([m], rung spacing 0.3 on the default ladder)
        base = result.log.arrays()["base"]
        assert base[-1, 2] - base[0, 2] > 0.45
    finally:
        result.close()
