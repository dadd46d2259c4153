"""The climb's variants, executed in-process on G1: a rung up and back down, with noisy F/T
sensors, a 7 kg ball thrown at the robot on the way up and a 2 kg box dropped on it on the way
down. (The 2-step climb planned one cycle at a time from the reached state, with a one-period
actuation latency, runs perturbed in test_climb_rung_error.py.)

One climb carries the three perturbations of issue 19 that need no other ladder: each is judged
on its own events, and the climb completing is judged once (make test time: each of them alone
was a climb of 2-4 minutes)."""
from __future__ import annotations

import pytest

from climb_checks import check_run

pytestmark = [pytest.mark.sim, pytest.mark.heavy]

#: the ladder paper's 10 kg on DRC-Hubo (50 kg) scaled to G1 (~35 kg)
BALL_KG = 7.0
BALL_SPEED = 5.5  # [m/s]
#: the up-and-down plan's transition 10 is a CoM shift with both hands and both feet holding (the
#: hands on rung 4, the left foot on rung 1, the right foot on the ground); 19, on the way down,
#: the same stance
BALL_TRANSITION = 10
BOX_TRANSITION = 19


def test_climb_one_rung_and_back_down_with_two_percent_ft_noise_a_7_kg_ball_and_a_2_kg_box(tmp_path):
    """Climbing down is the climb run backwards (planner_node.descend): mount, one cycle up (feet
    on rung 1), then the cycle reversed (hands down to rung 4, right foot, left foot down to the
    ground). Both feet stood on rung 1 when the descent began and stand on the ground at the end,
    the hands still hold rung 4, nothing fell, the feet found the ground from F/T.

    **F/T noise.** Every F/T has white noise of sigma 2 % of its range and a bias of sigma 1 %
    (issue 19's "F/T noise of 2 %": the ankles' 20 N). The contact threshold rises to ~58 N at the
    ankles, more than a creeping foot pushes (15-20 N measured): such placements are found as a
    stall (the limb held back 15 mm short of its creeping target, confirmed on the 200 ms filter).
    Without the stall rule a 2-step climb under this noise ended in replan_needed at transition 8
    (the left foot's search exhausted on rung 1, measured).

    **The ball.** Half a second into transition 10 (a CoM shift, four contacts) a 7 kg ball at
    5.5 m/s hits the torso from behind and above (30 degrees off the vertical). The controller
    sees the blow on its own sensors (F/T or joint velocities, not the simulator), braces (every
    contact held, the posture stiffened, an infeasible QP ridden out with the relaxed solve),
    finds its contacts where they were and resumes the transition. The impulse the bridge
    measured on the robot is at least 0.9 m v (the ball hit squarely).

    **The box.** Half a second into transition 19 (the same 4-contact stance, on the way down) a
    2 kg box falls on the torso at 4.4 m/s (a 1 m drop), the DARPA-tasks paper's perturbation."""
    import numpy as np
    import yaml

    from climb_coordinator.campaign import BALL_DIRECTION
    from climb_coordinator.climb import ClimbRequest, run_climb
    from climb_coordinator.settings import load_climb_settings
    from climb_core.ros_env import project_root

    settings = load_climb_settings()
    noise = {"sensors.ft_noise_percent": 2.0, "sensors.ft_bias_percent": 1.0}
    spec = yaml.safe_load((project_root() / "config" / "ladders" / "default.yaml").read_text())
    ball = {"mass": BALL_KG, "radius": 0.12, "speed": BALL_SPEED, "target_link": "torso",
            "direction": list(BALL_DIRECTION), "at_transition": BALL_TRANSITION, "at_time": 0.5}
    box = {"mass": 2.0, "radius": 0.12, "speed": 4.4, "at_transition": BOX_TRANSITION, "at_time": 0.5,
           "target_link": "torso"}
    spec["perturbation"] = {"rung_offsets": [], "rails_dy": 0.0, "drops": [ball, box]}
    result = run_climb(ClimbRequest(ladder=spec, robot="g1", rungs=1, mode="qp", out_dir=tmp_path, seed=0,
                                    descend=True, bridge_overrides=noise), settings)
    try:
        s = result.summary
        c = result.controller
        feet, loads = check_run(result, settings, "qp", allow_qp_failures=True)
        assert s["success"], s["failure_reason"]
        assert not s["fell"]
        assert s["top_feet_rungs"] == {"left_foot": 1, "right_foot": 1}
        assert feet == {"left_foot": 0, "right_foot": 0}, feet
        assert s["grasps"] == {"left_hand": "rung_4", "right_hand": "rung_4"}
        down = result.plan.transitions[s["descent_start_transition"]:]
        assert [t.moving_limb for t in down if t.moving_limb] == ["right_hand", "left_hand", "right_foot", "left_foot"]
        # every limb placement of the climb was found from F/T
        detected = c.events_of("contact_detected")
        assert len(detected) == len([t for t in result.plan.transitions if t.moving_limb])
        # the noise was there (the controller's own estimate at the ankles: 5 sigma of the filtered
        # 20 N), and at least one placement needed the stall rule
        ft = c.ft
        assert all(ft.threshold(foot) > 40.0 for foot in ("left_foot", "right_foot"))
        assert "stall" in [e.values["by"] for e in detected]
        # both were thrown in their 4-contact stance and hit the robot: the impulse the bridge
        # measured on the ball is its momentum (m v, it stops on the robot) within 10 %; the box,
        # dropped straight down on the back of a robot leaning into the ladder, glances off it
        # toward the ground (measured 0.88 m v with the feet pitched on the rungs, the torso
        # leaning further in): within 20 %
        thrown = {d["transition"]: d for d in s["drops_thrown"]}
        assert set(thrown) == {BALL_TRANSITION, BOX_TRANSITION}, s["drops_thrown"]
        assert thrown[BALL_TRANSITION]["mass_kg"] == BALL_KG and thrown[BOX_TRANSITION]["mass_kg"] == 2.0
        hit_ball, hit_box = result.backend.balls
        assert np.linalg.norm(hit_ball.impulse_on_robot) >= 0.9 * BALL_KG * BALL_SPEED
        assert np.linalg.norm(hit_box.impulse_on_robot) >= 0.8 * box["mass"] * box["speed"]
        # the ball: detected from the robot's sensors within 0.1 s of the hit, in the 4-contact
        # phase, braced with every contact held, and nothing moved beyond the lost-contact bound
        t_ball = thrown[BALL_TRANSITION]["at_time_s"]
        hit = [e for e in c.events_of("impact_detected") if 0.0 <= e.time - t_ball < 0.1]
        assert hit, [(e.time, e.values) for e in c.events_of("impact_detected")]
        assert hit[0].values["state"] == "move_com" and hit[0].values["source"].split(":")[0] in ("ft", "joint")
        brace = [e for e in c.events_of("brace_started") if e.time >= hit[0].time][0]
        assert brace.values["contacts"] == ["left_foot", "left_hand", "right_foot", "right_hand"]
        ended = [e for e in c.events_of("brace_ended") if e.time >= brace.time][0]
        assert max(ended.values["displacement"].values()) < c.params.impact.contact_lost_distance
        assert c.events_of("brace_resumed") and not c.events_of("contact_lost")
        # the QP answered every tick outside a brace (the relaxed solve answers a blow's ticks)
        braces = list(zip([e.time for e in c.events_of("brace_started")], [e.time for e in c.events_of("brace_ended")]))
        failures = [e.time for e in c.events_of("qp_failure")]
        assert all(any(t0 <= t <= t1 for t0, t1 in braces) for t in failures), (failures, braces)
        # the base went up by about a rung and came back ([m], rung spacing 0.3)
        base = result.log.arrays()["base"][:, 2]
        assert base.max() - base[0] > 0.2 and abs(base[-1] - base[0]) < 0.05
    finally:
        result.close()
