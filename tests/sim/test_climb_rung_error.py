"""The ladder paper's +-2 cm rung error, executed in process: G1's 2-step climb of the default
ladder (mount + two cycles, 21 transitions, ~106 s of sim time) with the simulator's rung 2 moved
up / down, the planner and the controller knowing the nominal ladder. Judged on the simulator's
ground truth with every check of an executed climb (climb_checks.check_run: no fall, no QP
failure, loads inside their friction cones, the bag).

The nominal climb is executed through the graph (tests/ros/test_graph_climb.py: 3 rungs in QP
mode, 2 rungs in compliance mode, judged from topics); in process the same 2-step climb runs
here, perturbed, and in test_climb_variants.py (planned a cycle at a time, with latency)."""
from __future__ import annotations

import pytest

from climb_checks import RUNGS, assert_standing_on, check_run

pytestmark = [pytest.mark.sim, pytest.mark.heavy]


@pytest.mark.parametrize("dz", [0.02, -0.02])
def test_climb_with_rung_2_two_centimetres_off(dz, tmp_path):
    """The paper's +-2 cm rung error: the simulator's rung 2 is 2 cm higher / lower than the
    ladder the planner and the controller know. The feet find it from the ankle F/T (early contact
    in the planned approach / late, in the search past it) and the climb completes on the real rung."""
    import yaml

    from climb_coordinator.climb import ClimbRequest, run_climb
    from climb_coordinator.settings import load_climb_settings
    from climb_core.ros_env import project_root

    spec = yaml.safe_load((project_root() / "config" / "ladders" / "default_perturbed.yaml").read_text())
    spec["perturbation"] = {"rung_offsets": [{"rung": 2, "dx": 0.0, "dz": dz}], "rails_dy": 0.0, "drops": []}
    settings = load_climb_settings()
    result = run_climb(ClimbRequest(ladder=spec, robot="g1", rungs=RUNGS, mode="qp", out_dir=tmp_path, seed=0),
                       settings)
    try:
        s = result.summary
        feet, loads = check_run(result, settings, "qp")
        assert s["success"], s["failure_reason"]
        assert feet == {"left_foot": RUNGS, "right_foot": RUNGS}, feet
        assert s["rungs_reached"] == RUNGS
        for foot in ("left_foot", "right_foot"):
            assert_standing_on(result.backend, foot, RUNGS)  # the simulator's (moved) rung 2
        # both feet carry the robot on rung 2 ([N] of the ~340 N weight, hands take the rest)
        assert loads["left_foot"].normal_force + loads["right_foot"].normal_force > 150.0
        assert s["grasps"] == {"left_hand": f"rung_{RUNGS + 4}", "right_hand": f"rung_{RUNGS + 4}"}
        # the guarded moves found every contact from F/T (one per limb placement)
        detected = result.controller.events_of("contact_detected")
        assert len(detected) == len([t for t in result.plan.transitions if t.moving_limb])
        # the base rose by the two rungs climbed ([m], rung spacing 0.3 on the default ladder)
        base = result.log.arrays()["base"]
        assert base[-1, 2] - base[0, 2] > 0.45
        # the two placements onto rung 2 are the last two foot detections
        feet = [e for e in detected if e.values["limb"] in ("left_foot", "right_foot")]
        assert [e.values["limb"] for e in feet[-2:]] == ["left_foot", "right_foot"]
        assert all(e.values["early"] == (dz > 0) for e in feet[-2:]), [e.values for e in feet[-2:]]
    finally:
        result.close()
