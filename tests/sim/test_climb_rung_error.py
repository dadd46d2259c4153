"""The ladder paper's +-2 cm rung error, executed: G1's 2-step climb of the default ladder with the
simulator's rung 2 moved up / down, the planner and the controller knowing the nominal ladder."""
from __future__ import annotations

import pytest

from climb_checks import RUNGS, assert_standing_on

pytestmark = pytest.mark.sim


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
    result = run_climb(ClimbRequest(ladder=spec, robot="g1", rungs=RUNGS, mode="qp", out_dir=None, bag=False,
                                    seed=0), settings)
    try:
        s = result.summary
        assert s["success"], s["failure_reason"]
        assert not s["fell"] and s["qp_failures"] == 0
        for foot in ("left_foot", "right_foot"):
            assert_standing_on(result.backend, foot, RUNGS)  # the simulator's (moved) rung 2
        # the two placements onto rung 2 are the last two foot detections
        feet = [e for e in result.controller.events_of("contact_detected") if e.values["limb"] in ("left_foot", "right_foot")]
        assert [e.values["limb"] for e in feet[-2:]] == ["left_foot", "right_foot"]
        assert all(e.values["early"] == (dz > 0) for e in feet[-2:]), [e.values for e in feet[-2:]]
    finally:
        result.close()
