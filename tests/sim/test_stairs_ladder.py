"""The stairs ladder (issue 18, "stairs with rails: 3 steps"): config/ladders/stairs.yaml (35 deg,
17 cm rise, a rail on each side) climbed 3 steps by G1 holding both rails, planned by the
DARPA-tasks paper's method (``strategy: search``) and executed in-process, lock-step, QP, one
period of actuation latency (what ``scripts/climb.py --scenario stairs --strategy search`` runs).

Stairs are walked, not climbed: the guide path's milestones stand upright on the treads
(``guide_path.walk_max_incline_deg``) and the search's IK keeps the CoM over the held feet
(``contact_search.com_over_feet_*``), so that a hand lets go of its rail with the feet carrying
the robot. Before, the searched stances hung 18-25 cm behind the soles on the rails and the robot
fell backwards at the first re-grasp. The test checks what the simulator measured: both feet on
tread 3, both hands on the rails, every hand re-grasped further up the rail with the measured CoM
over the feet when its gripper opened, the loads in their cones, nothing fallen."""
from __future__ import annotations

import numpy as np
import pytest

from climb_checks import check_run

pytestmark = [pytest.mark.sim, pytest.mark.heavy]

COM_OVER_FEET_M = 0.10  # [m] measured CoM to the held feet's centroid (along the stairs) when a grip opens


def test_the_stairs_ladder_is_walked_up_3_treads_holding_the_rails(tmp_path):
    from climb_coordinator.climb import ClimbRequest, run_climb
    from climb_coordinator.settings import load_climb_settings
    from climb_core.contact import limb_type

    settings = load_climb_settings()
    result = run_climb(ClimbRequest(ladder="stairs", robot="g1", rungs=3, mode="qp", out_dir=tmp_path,
                                    strategy="search", command_delay_ticks=1), settings)
    try:
        s = result.summary
        assert s["success"], s["failure_reason"]
        assert s["rungs_reached"] == 3 and s["feet_rungs"] == {"left_foot": 3, "right_foot": 3}, s
        assert s["grasps"] == {"left_hand": "rail_left", "right_hand": "rail_right"}, s
        feet, _ = check_run(result, settings, "qp")
        assert feet == {"left_foot": 3, "right_foot": 3}
        plan = result.plan
        # the hands hold nothing but the rails, and each is let go of and grasped further up
        hand_holds = {(h.limb, h.env_surface) for t in plan.transitions for h in t.target_stance.holds
                      if limb_type(h.limb) == "hand"}
        assert hand_holds == {("left_hand", "rail_left"), ("right_hand", "rail_right")}, hand_holds
        c = result.controller
        gripper = c.events_of("gripper")
        for hand in ("left_hand", "right_hand"):
            closes = [e for e in gripper if e.values["hand"] == hand and e.values["command"] == "close"]
            assert len(closes) >= 2, (hand, closes)  # the first grasp and at least one re-grasp
        # when a grip opened, the measured CoM stood over the feet (the stairs' x: along the stairs)
        times = np.asarray(result.log.times)
        com = np.asarray(result.log.com)
        # a re-grasp: a hand placed while it held the rail before (the FSM unloads and opens it first)
        regrasps = [k for k, t in enumerate(plan.transitions) if k and t.moving_limb in ("left_hand", "right_hand")
                    and plan.transitions[k - 1].target_stance.hold(t.moving_limb) is not None]
        assert len(regrasps) >= 2, [(t.primitive, t.moving_limb) for t in plan.transitions]
        for k in regrasps:
            t = plan.transitions[k]
            start = [e.time for e in c.events_of("transition_started") if e.values["index"] == k]
            assert start, k
            opened = [e.time for e in gripper if e.values["hand"] == t.moving_limb and e.values["command"] == "open"
                      and start[0] <= e.time <= start[0] + 3.0]
            assert opened, (k, t.moving_limb)
            feet_x = np.mean([h.centre[0] for h in t.stance.holds if limb_type(h.limb) == "foot"])
            com_x = com[int(np.argmin(np.abs(times - opened[0]))), 0]
            assert abs(com_x - feet_x) <= COM_OVER_FEET_M, (k, t.moving_limb, com_x, feet_x)
    finally:
        result.close()

