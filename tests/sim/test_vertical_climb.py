"""The vertical ladder (issue 18, "the vertical ladder: 2 steps"), planned and executed in process.

config/ladders/vertical.yaml: 90 deg, round rungs every 25 cm, mu 0.25. G1 hangs behind the rungs:
in a one-foot stance its CoM is 19-23 cm behind the rung line the foot stands on, so the rung must
push that foot back toward the robot with 0.22-0.26 of its normal force. A sole level on the rung's
top line gets that push from friction alone (mu 0.25, the QP's cones 0.8 mu): the QP needed 1.1-1.8
of the torque limits there (the hands pressing down to load the foot), its wrists and shoulders
saturated and G1 fell at the first such stance (twenty-fifth to twenty-eighth sessions). The feet
now stand pitched 10 deg toes up on its round rungs (``planning.foot_on_rung_pitch_deg``, set by the ladder's file): the sole is
tangent to the rung where the rung's normal leans back 10 deg, and the normal force itself pushes
the foot back (docs/planner.md). The same stances then need 0.3-0.6.

The climb plans as every climb does (the climb's torque headroom, the ladder file's settings: the
mount slowed where the CoM nears the heels) and executes in lock-step with one period of actuation
latency. Judged on the simulator: both feet on rung 2 and pitched on it as planned, both hands
closed on the rung the plan ends on, nothing fell, no QP failure, every contact inside its friction
cone, the measured CoM in front of the heels while the first hand mounts (at full speed G1 tipped
over them there)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from climb_checks import climb_ladder_to

pytestmark = [pytest.mark.sim, pytest.mark.heavy]

RUNGS = 2
PITCH_DEG = 10.0  # config/ladders/vertical.yaml planning.foot_on_rung_pitch_deg
HEEL_CLEARANCE_M = 0.005  # [m] least measured CoM distance in front of the heels' edge in the first mount


def test_the_vertical_ladder_is_climbed_two_rungs_standing_pitched_on_its_round_rungs(tmp_path):
    from climb_core import holds
    from climb_core.contact import limb_type

    result, _ = climb_ladder_to("vertical", RUNGS, tmp_path)
    try:
        plan = result.plan
        last = plan.transitions[-1].target_stance
        backend, env = result.backend, result.backend.env
        for foot in ("left_foot", "right_foot"):
            hold = next(h for h in last.holds if h.limb == foot)
            assert holds.rung_pitch_deg(hold, env) == pytest.approx(PITCH_DEG, abs=1e-6)
            # the sole really stands pitched toes up on its rung (its forward axis in the simulator)
            measured = math.degrees(math.asin(float(backend.surface_pose(foot)[2, 0])))
            assert abs(measured - PITCH_DEG) < 4.0, (foot, measured)
        # the first hand's mount: the feet alone on the ground carry the robot while a hand goes up
        mount = next(k for k, t in enumerate(plan.transitions) if t.primitive == "mount")
        soles = np.vstack([h.positions for h in plan.transitions[mount].stance.holds if limb_type(h.limb) == "foot"])
        heels_x = float(soles[:, 0].min())  # the ladder faces +x
        starts = {e.values["index"]: e.time for e in result.controller.events_of("transition_started")}
        times, com = np.asarray(result.log.times), np.asarray(result.log.com)
        during = (times >= starts[mount]) & (times <= starts[mount + 1])
        assert during.sum() > 100
        assert com[during, 0].min() - heels_x >= HEEL_CLEARANCE_M, (com[during, 0].min(), heels_x)
    finally:
        result.close()
