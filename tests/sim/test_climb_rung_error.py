"""Rung errors beyond the ladder paper's +-2 cm, executed in process: G1's 2-step climb of the
default ladder (mount + two cycles, 21 transitions, ~106 s of sim time) with the simulator's rung 2
moved 3 cm down, the planner and the controller knowing the nominal ladder, planned one cycle at a
time from the reached state, with a one-period actuation latency. Judged on the simulator's ground
truth with every check of an executed climb (climb_checks.check_run: no fall, no QP failure, loads
inside their friction cones, the bag). Rung 2 3 cm up (the early contact) is the graph's replan
test (tests/ros/test_graph_climb.py: the same session through every node).

Measured before the recovery: at +3 cm the climb ended in a QP failure at transition 19 (the knee
on rung 3, the right foot slipping). Now the first foot on rung 2 finds it off the plan (ankle F/T,
early / late beyond guarded.replan_offset), loads it, holds, and the climb is replanned in a model
with rung 2 where the foot found it.

Rung 3 2 cm deeper (dx, the issue's case) is a 3-rung climb: the feet locate the rung's line
under the sole from the ankle F/T (controller_node.line_contact), no replan.

The nominal climb is executed through the graph (tests/ros/test_graph_climb.py: 1 rung in QP
mode, 2 rungs in compliance mode, judged from topics); in process the 2-step climb runs here,
perturbed, and in test_climb_variants.py (a rung up and back down)."""
from __future__ import annotations

import pytest

from climb_checks import RUNGS, assert_standing_on, check_run

pytestmark = [pytest.mark.sim, pytest.mark.heavy]


def test_climb_planned_a_cycle_at_a_time_with_rung_2_three_centimetres_low_replans_and_completes(tmp_path):
    """Partially known ladders and a rung off the plan, with a robot's one-period actuation
    latency (every command acts one control period late; the controller computes each command
    for the state one period ahead: ``actuation_latency_s``, set by the request).

    The planner plans one cycle at a time: after the mount and the first cycle, the second is
    planned from the configuration the simulator reached (projected onto the held stance). The
    simulator's rung 2 is 3 cm lower than the ladder the planner and the controller know: the left
    foot finds it late, from the ankle F/T in the search past the planned pose, loads it, and the
    controller holds in replan_needed; the session replans from there with rung 2 moved where the
    foot found it, and the climb completes on the real rung: the right foot then lands where the
    corrected plan has it. (Without the latency prediction the nominal 2-step climb ends in failure
    at transition 11 of 21 after 151 infeasible QPs, measured.)"""
    import yaml

    from climb_coordinator.climb import ClimbRequest, run_climb
    from climb_coordinator.settings import load_climb_settings
    from climb_core.ros_env import project_root

    spec = yaml.safe_load((project_root() / "config" / "ladders" / "default_perturbed.yaml").read_text())
    dz = -0.03
    spec["perturbation"] = {"rung_offsets": [{"rung": 2, "dx": 0.0, "dz": dz}], "rails_dy": 0.0, "drops": []}
    settings = load_climb_settings()
    result = run_climb(ClimbRequest(ladder=spec, robot="g1", rungs=RUNGS, mode="qp", out_dir=tmp_path, seed=0,
                                    plan_cycles=1, command_delay_ticks=1), settings)
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
        assert s["command_delay_ticks"] == 1
        assert result.controller.params.actuation_latency_s == pytest.approx(0.005)
        # two replans: the second cycle from the reached state (a few mm off the plan), then,
        # after the left foot loaded rung 2, which it found within 3 mm of the truth, the rest
        cycle, replan = s["replans"]
        assert cycle["cycles"] == 1 and "failure_reason" not in cycle and "why" not in cycle, cycle
        assert cycle["start_projection_mm"] < 10.0
        assert replan["why"] == "contact_offset" and set(replan["surface_offset"]) == {"rung_2"}
        # along the approach and across it (the line under the sole, located from the ankle F/T):
        # with the feet pitched on the rung the approach is tilted 10 deg and alone put the rung
        # 5 mm off along x (measured), where the right foot's plan then rolled it off the rung
        assert replan["surface_offset"]["rung_2"] == pytest.approx([0.0, 0.0, dz], abs=0.003)
        c = result.controller
        (event,) = c.events_of("replan_needed")
        assert event.values == {"limb": "left_foot", "reason": "contact_offset"}
        # the guarded moves found every contact from F/T (one per limb placement, every plan)
        detected = c.events_of("contact_detected")
        assert len(detected) == len([t for t in result.plan.transitions if t.moving_limb])
        feet_on_2 = [e for e in detected if e.values["limb"] in ("left_foot", "right_foot")][-2:]
        assert feet_on_2[0].values["early"] is False  # the left foot: past the planned pose
        offsets = [e.values for e in c.events_of("contact_offset") if e.values["surface"] == "rung_2"]
        assert [o["limb"] for o in offsets] == ["left_foot", "right_foot"]
        # the right foot lands where the corrected model has rung 2 (within the FSM's own bound)
        assert abs(offsets[1]["distance"]) < c.params.guarded.replan_offset, offsets
        # the base rose by the two rungs climbed to the real rung 2 ([m], rung spacing 0.25 on the
        # default ladder; measured 0.442 at dz = -3 cm)
        base = result.log.arrays()["base"]
        assert base[-1, 2] - base[0, 2] > 2 * 0.25 + dz - 0.06
    finally:
        result.close()


def test_climb_of_three_rungs_with_rung_3_two_centimetres_deeper_locates_each_foot_on_it_and_completes(tmp_path):
    """The issue's rung 3 at +2 cm along dx (the ladder base frame's x, away from the robot): the
    feet's guarded descent stops at the planned height, so the approach cannot see the error, but
    the rung's top line is 2 cm further along the sole than planned. Each foot put on rung 3
    locates its line from the ankle F/T while the contact engages (line_contact.py) and the QP
    holds the foot on the line it found. Measured before: the left foot rolled over the rung
    (0.5 rad within 0.15 s of loading) and the robot fell; rung 2 at +2 cm the same."""
    import numpy as np
    import yaml

    from climb_coordinator.climb import ClimbRequest, run_climb
    from climb_coordinator.settings import load_climb_settings
    from climb_core.ros_env import project_root

    rungs, dx = 3, 0.02
    spec = yaml.safe_load((project_root() / "config" / "ladders" / "default_perturbed.yaml").read_text())
    spec["perturbation"] = {"rung_offsets": [{"rung": 3, "dx": dx, "dz": 0.0}], "rails_dy": 0.0, "drops": []}
    settings = load_climb_settings()
    # the plan's 28 transitions, up to the CoM shift after the right foot is on rung 3 (the hands'
    # last moves to rung 7 stay out: the issue's "stop a few seconds after the perturbed contact is
    # re-established"; measured, they completed in 4 of 6 runs of the locator's variants, the
    # others ended with the right foot rolling off rung 3 at the last hand move)
    result = run_climb(ClimbRequest(ladder=spec, robot="g1", rungs=rungs, mode="qp", out_dir=tmp_path, seed=0,
                                    max_transitions=26), settings)
    try:
        s = result.summary
        feet, loads = check_run(result, settings, "qp")  # no fall, no QP failure, cones held, the bag
        assert s["success"], s["failure_reason"]
        assert result.plan.transitions[24].moving_limb == "right_foot"  # its placement on rung 3 ran
        assert feet == {"left_foot": rungs, "right_foot": rungs}, feet
        for foot in ("left_foot", "right_foot"):
            assert_standing_on(result.backend, foot, rungs)  # the simulator's (moved) rung 3
        assert loads["left_foot"].normal_force + loads["right_foot"].normal_force > 150.0  # [N]
        c = result.controller
        located = [e.values for e in c.events_of("contact_line_located")]
        # nothing to locate on the rungs where they were planned: every estimate is on rung 3
        assert {v["surface"] for v in located} == {"rung_3"}, located
        T_rung = result.backend.surface_frame("rung_3")
        axis = T_rung[:3, 0]
        for foot in ("left_foot", "right_foot"):
            total = [v["total"] for v in located if v["limb"] == foot][-1]
            assert total == pytest.approx(dx, abs=0.007), (foot, total)  # measured 15-18 mm
            # the controller's contact line is over the simulator's rung axis (the plan's was 2 cm off)
            centre = c.holds[foot].positions.mean(axis=0)
            d = centre - T_rung[:3, 3]
            d -= (d @ axis) * axis
            assert np.hypot(d[0], d[1]) < 0.008, (foot, d)
    finally:
        result.close()
