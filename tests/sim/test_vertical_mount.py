"""The vertical ladder's mount (issue 18, "the vertical ladder: 2 steps": its first part), executed.

tests/data/vertical_plan.json is ``scripts/plan.py --scenario vertical --steps 2 --out ...`` (the
forward library, config/planner.yaml; ~160 s of CPU, hence stored). Its first seven transitions are
the approach (two steps up to the ladder) and the mount: each hand goes up in front of the body,
past rungs 2-4, to its rung, the pelvis leaning back while the feet carry the robot alone, the CoM
planned 2.6 cm in front of the heels. At full speed the measured CoM lagged the plan's, went past
it and G1 fell backwards over its heels 5 s into the first hand's mount (twenty-seventh and
twenty-eighth sessions); the plan now slows down where the CoM nears the heels with the soles alone
holding the robot (``timing.edge_slowdown_margin``). The controller executes the seven
transitions in lock-step with PyBullet, QP, one period of latency, and the test checks what the
simulator measured: both hands closed on their rungs, both feet still on the ground, the measured
CoM in front of the heels throughout, nothing fell. What the rest of the plan meets (G1's wrists
and shoulders at their torque cap when the right foot leaves the ground for rung 1) is in docs/planner.md."""
from __future__ import annotations

import pathlib

import numpy as np
import pytest

from climb_checks import check_run

pytestmark = [pytest.mark.sim, pytest.mark.heavy]

STORED_PLAN = pathlib.Path(__file__).resolve().parents[1] / "data" / "vertical_plan.json"
MOUNT_END = 7  # transitions 0-4: the approach; 5, 6: the left, then the right hand's mount
HEEL_CLEARANCE_M = 0.005  # [m] least measured CoM distance in front of the heels' edge in the mount (measured: 1.2 cm; at full speed it went past them)


def test_the_vertical_ladder_is_mounted_from_the_ground_without_tipping_over_the_heels(tmp_path):
    from climb_core.contact import limb_type
    from climb_coordinator.climb import ClimbRequest, run_stored_plan
    from climb_coordinator.settings import load_climb_settings
    from planner_node.plan_io import load_plan

    settings = load_climb_settings()
    plan, _ = load_plan(STORED_PLAN)
    assert plan.environment == "vertical"
    assert [t.primitive for t in plan.transitions[MOUNT_END - 2:MOUNT_END]] == ["mount", "mount"]
    # what `scripts/climb.py --plan tests/data/vertical_plan.json --max-transitions 7 --command-delay 1` runs
    req = ClimbRequest(ladder="vertical", robot="g1", rungs=2, mode="qp", out_dir=tmp_path, strategy="primitives",
                       command_delay_ticks=1, max_transitions=MOUNT_END)
    result = run_stored_plan(req, STORED_PLAN, settings)
    try:
        s = result.summary
        assert s["success"], s["failure_reason"]
        feet, _ = check_run(result, settings, "qp")
        assert feet == {"left_foot": 0, "right_foot": 0}, feet  # both soles on the ground
        mounted = plan.transitions[MOUNT_END - 1].target_stance
        expected = {h.limb: h.env_surface for h in mounted.holds if limb_type(h.limb) == "hand"}
        assert set(expected) == {"left_hand", "right_hand"} and s["grasps"] == expected, (s["grasps"], expected)
        # the measured CoM stayed in front of the heels' edge (the ladder faces +x) while the feet
        # alone carried the robot and one hand went up (the first hand's mount)
        soles = np.vstack([h.positions for h in plan.transitions[MOUNT_END - 2].stance.holds
                           if limb_type(h.limb) == "foot"])
        heels_x = float(soles[:, 0].min())
        start = [e.time for e in result.controller.events_of("transition_started")
                 if e.values["index"] == MOUNT_END - 2][0]
        end = [e.time for e in result.controller.events_of("transition_started")
               if e.values["index"] == MOUNT_END - 1][0]
        times, com = np.asarray(result.log.times), np.asarray(result.log.com)
        during = (times >= start) & (times <= end)
        assert during.sum() > 100
        assert com[during, 0].min() - heels_x >= HEEL_CLEARANCE_M, (com[during, 0].min(), heels_x)
    finally:
        result.close()
