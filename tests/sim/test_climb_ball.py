"""A ball on the climbing robot (issue 19): the ladder paper's drop test, executed in process on
G1 (default ladder, QP, lock-step PyBullet)."""
from __future__ import annotations

import numpy as np
import pytest

from climb_checks import check_run

pytestmark = [pytest.mark.sim, pytest.mark.heavy]

#: the ladder paper's 10 kg on DRC-Hubo (50 kg) scaled to G1 (~35 kg)
BALL_KG = 7.0
SPEED = 5.5  # [m/s]
#: the 1-rung climb's transition 10 is a CoM shift with both hands and both feet holding
FOUR_CONTACTS_TRANSITION = 10


def test_a_7_kg_ball_on_the_back_with_four_contacts_is_braced_and_the_climb_completes(tmp_path):
    """A 7 kg ball at 5.5 m/s hits the torso from behind and above (30 degrees off the vertical)
    0.5 s into transition 10 (a CoM shift, four contacts). The controller sees the blow on its
    own sensors (F/T or joint velocities, not the simulator), braces (every contact held, the
    posture stiffened, an infeasible QP ridden out with the relaxed solve), finds its contacts
    where they were and resumes the transition; the climb completes with nothing fallen.
    The impulse the bridge measured on the robot is at least 0.9 m v (the ball hit squarely)."""
    from climb_coordinator.campaign import BALL_DIRECTION
    from climb_coordinator.climb import ClimbRequest, run_climb
    from climb_coordinator.settings import load_climb_settings
    import yaml

    from climb_core.ros_env import project_root

    spec = yaml.safe_load((project_root() / "config" / "ladders" / "default_perturbed.yaml").read_text())
    spec["perturbation"] = {"rung_offsets": [], "rails_dy": 0.0, "drops": [
        {"mass": BALL_KG, "radius": 0.12, "speed": SPEED, "target_link": "torso", "direction": list(BALL_DIRECTION),
         "at_transition": FOUR_CONTACTS_TRANSITION, "at_time": 0.5}]}
    settings = load_climb_settings()
    noise = {"sensors.ft_noise_percent": 0.5, "sensors.ft_bias_percent": 0.25}
    result = run_climb(ClimbRequest(ladder=spec, robot="g1", rungs=1, mode="qp", out_dir=tmp_path, seed=0,
                                    bridge_overrides=noise), settings)
    try:
        s = result.summary
        c = result.controller
        # the ball was thrown at the transition and hit squarely
        assert s["drops_thrown"] and s["drops_thrown"][0]["transition"] == FOUR_CONTACTS_TRANSITION
        (ball,) = result.backend.balls
        impulse = float(np.linalg.norm(ball.impulse_on_robot))
        assert impulse >= 0.9 * BALL_KG * SPEED, impulse
        # detected from the robot's sensors within a tick or two of the hit, in the 4-contact phase
        (hit,) = c.events_of("impact_detected")
        assert hit.values["state"] == "move_com" and hit.values["source"].split(":")[0] in ("ft", "joint")
        assert 0.0 <= hit.time - s["drops_thrown"][0]["at_time_s"] < 0.1
        (brace,) = c.events_of("brace_started")
        assert brace.values["contacts"] == ["left_foot", "left_hand", "right_foot", "right_hand"]
        (ended,) = c.events_of("brace_ended")
        assert max(ended.values["displacement"].values()) < c.params.impact.contact_lost_distance
        assert c.events_of("brace_resumed") and not c.events_of("contact_lost")
        # the climb completed: feet on rung 1, hands on rung 5, nothing fell; the QP answered
        # every tick outside the brace
        assert s["success"], s["failure_reason"]
        assert not s["fell"]
        assert s["feet_rungs"] == {"left_foot": 1, "right_foot": 1}
        assert s["grasps"] == {"left_hand": "rung_5", "right_hand": "rung_5"}
        failures = [e.time for e in c.events_of("qp_failure")]
        assert all(brace.time <= t <= ended.time for t in failures), failures
        # grasps and unilateral contacts stayed within their limits (the bridge's honest grip:
        # a grasp past its strength slides, and a slid grasp is a lost contact above)
        for limb, samples in result.cone_samples.items():
            for normal, tangential, mu in samples:
                assert tangential <= (1.0 + settings.cone_tolerance) * mu * normal, (limb, normal, tangential, mu)
    finally:
        result.close()
