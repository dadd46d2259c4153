"""Rectangular rungs, executed in process on G1 (issue 18): the 2-step climb of a regular ladder
whose rungs are the 4 cm deep x 3 cm thick square tubes of ``shared/bench/ladder_grid_rect.yaml``
(config/ladders/rect_rungs.yaml: the default ladder with those rungs). The hands close around the
bars (climb_core.holds: the 8-point grasp on the bar's faces and edges, within the Dex3 hand's
``max_bar``), the feet stand across them (the paper's Fig. 6 foot hold, ``sole_bar``: the 4 corners
of the bar's top face under the sole). Judged on the simulator's ground truth with every check of an
executed climb (climb_checks.check_run: no fall, no QP failure, loads inside their friction cones,
the bag)."""
from __future__ import annotations

import pytest

from climb_checks import RUNGS, assert_standing_on, check_run

pytestmark = [pytest.mark.sim, pytest.mark.heavy]


def test_climb_two_steps_on_rectangular_rungs(tmp_path):
    """Mount and two cycles on rect rungs: both feet end on rung 2 (simulator contacts, standing on
    its top face), both hands latched on the bar rung 6, the feet carry the robot, every limb
    placement found from F/T, nothing fell."""
    from climb_coordinator.climb import ClimbRequest, run_climb
    from climb_coordinator.settings import load_climb_settings

    settings = load_climb_settings()
    result = run_climb(ClimbRequest(ladder="rect_rungs", robot="g1", rungs=RUNGS, mode="qp", out_dir=tmp_path,
                                    seed=0), settings)
    try:
        s = result.summary
        env = result.backend.env
        assert env.rung(2).shape == "box" and env.rung(2).role == "rung"  # the bars the climb used
        # every hold of the plan on a rung is a bar hold: 8 grasp points, 4 sole corners
        for t in result.plan.transitions:
            for hold in t.target_stance.holds:
                if hold.env_surface.startswith("rung_"):
                    assert len(hold.points) == (8 if hold.limb.endswith("hand") else 4), hold
        feet, loads = check_run(result, settings, "qp")
        assert s["success"], s["failure_reason"]
        assert feet == {"left_foot": RUNGS, "right_foot": RUNGS}, feet
        assert s["rungs_reached"] == RUNGS
        for foot in ("left_foot", "right_foot"):
            assert_standing_on(result.backend, foot, RUNGS)
        # both feet carry the robot on rung 2 ([N] of the ~340 N weight, the hands take the rest)
        assert loads["left_foot"].normal_force + loads["right_foot"].normal_force > 150.0
        assert s["grasps"] == {"left_hand": f"rung_{RUNGS + 4}", "right_hand": f"rung_{RUNGS + 4}"}
        detected = result.controller.events_of("contact_detected")
        assert len(detected) == len([t for t in result.plan.transitions if t.moving_limb])
        # every transition ended where its plan ends: the base within 3 cm, every joint within 0.5 rad
        # (measured with one period of latency before grasps were latched: 1.2 cm, 0.24 rad, a wrist
        # yaw; the steep ladders that fell then left 0.7-1.0 rad)
        tracking = s["tracking"]
        assert len(tracking["per_transition"]) == len(result.plan.transitions), tracking
        assert tracking["max_base_error_m"] < 0.03 and tracking["max_joint_error_rad"] < 0.5, tracking
        # the base rose by about the two rungs climbed ([m], spacing 0.25 along a 75 deg stringer)
        base = result.log.arrays()["base"]
        assert base[-1, 2] - base[0, 2] > 2 * 0.25 * 0.966 - 0.06
    finally:
        result.close()
