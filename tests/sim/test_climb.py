"""The first real climb: G1 plans a 2-step climb of the default ladder (mount + two cycles) and
executes it in lock-step against PyBullet through the controller library, in QP mode and in PWM
compliance mode. Judged on the simulator's ground truth only: feet standing on rungs (contact
points and sole poses), no fall, unilateral contact forces inside their friction cones, and a
readable bag with the run's topics.

Each test plans the climb (seed 0) and executes all 21 transitions (approach steps, both hands
onto rung 4, then two cycles of foot, foot, hand, hand placements) in about 106 s of sim time."""
from __future__ import annotations

import pytest


pytestmark = pytest.mark.sim
#: make test spreads these climbs over both cores (tests/conftest.py)
XDIST_SPREAD = True

RUNGS = 2
TOPICS = {"joint_states", "sim/base_truth", "joint_command", "controller/state",
          "ft/left_wrist", "ft/right_wrist", "ft/left_ankle", "ft/right_ankle"}


def _climb(mode: str, tmp_path, max_transitions=None, command_delay_ticks=0):
    from climb_coordinator.climb import ClimbRequest, run_climb
    from climb_coordinator.settings import load_climb_settings

    settings = load_climb_settings()
    result = run_climb(ClimbRequest(ladder="default", robot="g1", rungs=RUNGS, mode=mode, out_dir=tmp_path,
                                    seed=0, max_transitions=max_transitions,
                                    command_delay_ticks=command_delay_ticks), settings)
    return result, settings


def _check_run(result, settings, mode: str) -> dict:
    """Checks every executed climb must pass; returns the feet's rungs (simulator contacts)."""
    from climb_coordinator import judge
    from msgs_py.bag import read_bag

    s = result.summary
    backend = result.backend
    assert backend is not None, s["failure_reason"]
    # nothing fell, the controller finished its plan without a QP failure
    assert not s["fell"], s["failure_reason"]
    assert s["fsm_state"] == "hold", s["failure_reason"]
    assert s["qp_failures"] == 0
    assert s["transitions_done"] == s["n_transitions"]
    # unilateral contacts inside their friction cones over the whole run (sampled at the log
    # rate; loads of at least climb.judge.cone_force_min)
    assert sum(len(v) for v in result.cone_samples.values()) > 500
    for limb, samples in result.cone_samples.items():
        for normal, tangential, mu in samples:
            assert normal > 0.0
            assert tangential <= (1.0 + settings.cone_tolerance) * mu * normal, (limb, normal, tangential, mu)
    if mode == "compliance":
        assert not s["motor_trips"]
        assert s["max_current_ratio"] < 1.0
    # the bag: readable, the expected topics, decodable messages spanning the run
    messages = list(read_bag(s["bag"]))
    assert {m.topic for m in messages} >= TOPICS
    last = [m for m in messages if m.topic == "controller/state"][-1].decode()
    assert last.fsm_state == "hold" and last.mode == mode
    joints = [m for m in messages if m.topic == "joint_states"]
    assert (joints[-1].stamp_ns - joints[0].stamp_ns) * 1e-9 > 0.9 * s["sim_time_s"] - 1.5
    assert len(joints[-1].decode().position) == len(result.log.joint_names)
    loads = judge.limb_loads(backend)
    return judge.feet_rungs(backend, settings.foot_force_min, loads), loads


def _assert_standing_on(backend, foot: str, rung: int) -> None:
    from climb_coordinator import judge

    pose = judge.foot_pose_check(backend, foot, rung)
    assert pose["horizontal_offset"] < 0.06, (foot, pose)
    assert -0.01 < pose["height_above_top"] < 0.05, (foot, pose)
    assert abs(pose["along_rung"]) < 0.2, (foot, pose)


@pytest.mark.parametrize("mode, delay", [("qp", 0), ("compliance", 0)], ids=["qp", "compliance"])
def test_two_step_climb_of_the_default_ladder(mode, delay, tmp_path):
    """Mount (both hands on rung 4) and two climbing cycles: both feet end standing on rung 2,
    both hands on rung 6, nothing fell, every unilateral load inside its friction cone.

    (With a one-period actuation latency: test_two_step_climb_replanned_from_the_reached_state.)"""
    result, settings = _climb(mode, tmp_path, command_delay_ticks=delay)
    try:
        s = result.summary
        assert s.get("command_delay_ticks", 0) == delay
        assert result.controller.params.actuation_latency_s == pytest.approx(0.005 * delay)
        feet, loads = _check_run(result, settings, mode)
        assert s["success"], s["failure_reason"]
        assert feet == {"left_foot": RUNGS, "right_foot": RUNGS}, feet
        assert s["rungs_reached"] == RUNGS
        for foot in ("left_foot", "right_foot"):
            _assert_standing_on(result.backend, foot, RUNGS)
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
            _assert_standing_on(result.backend, foot, RUNGS)  # the simulator's (moved) rung 2
        # the two placements onto rung 2 are the last two foot detections
        feet = [e for e in result.controller.events_of("contact_detected") if e.values["limb"] in ("left_foot", "right_foot")]
        assert [e.values["limb"] for e in feet[-2:]] == ["left_foot", "right_foot"]
        assert all(e.values["early"] == (dz > 0) for e in feet[-2:]), [e.values for e in feet[-2:]]
    finally:
        result.close()


def test_climb_one_rung_and_back_down(tmp_path):
    """Climbing down is the climb run backwards (planner_node.descend): mount, one cycle up (feet
    on rung 1), then the cycle reversed (hands down to rung 4, right foot, left foot down to the
    ground). Both feet stood on rung 1 when the descent began and stand on the ground at the end,
    the hands still hold rung 4, nothing fell, the feet found the ground from F/T."""
    from climb_coordinator.climb import ClimbRequest, run_climb
    from climb_coordinator.settings import load_climb_settings

    settings = load_climb_settings()
    result = run_climb(ClimbRequest(ladder="default", robot="g1", rungs=1, mode="qp", out_dir=tmp_path, seed=0,
                                    descend=True), settings)
    try:
        s = result.summary
        feet, loads = _check_run(result, settings, "qp")
        assert s["success"], s["failure_reason"]
        assert s["top_feet_rungs"] == {"left_foot": 1, "right_foot": 1}
        assert feet == {"left_foot": 0, "right_foot": 0}, feet
        assert s["grasps"] == {"left_hand": "rung_4", "right_hand": "rung_4"}
        down = result.plan.transitions[s["descent_start_transition"]:]
        assert [t.moving_limb for t in down if t.moving_limb] == ["right_hand", "left_hand", "right_foot", "left_foot"]
        # every limb placement of the descent was found from F/T too
        detected = result.controller.events_of("contact_detected")
        assert len(detected) == len([t for t in result.plan.transitions if t.moving_limb])
        # the base went up by about a rung and came back ([m], rung spacing 0.3)
        base = result.log.arrays()["base"][:, 2]
        assert base.max() - base[0] > 0.2 and abs(base[-1] - base[0]) < 0.05
    finally:
        result.close()


def test_two_step_climb_replanned_from_the_reached_state(tmp_path):
    """Partially known ladders: the planner plans one cycle at a time; after the first cycle the
    second is planned from the configuration the simulator reached (projected onto the held
    stance), and the robot ends standing on rung 2 as with the plan made at once.

    With a one-period actuation latency: every command acts one control period late, as on a
    robot, and the controller computes each command for the state one period ahead
    (``actuation_latency_s``, set by the request). Without that prediction the 2-step climb ends
    in failure at transition 11 of 21 after 151 infeasible QPs (measured)."""
    from climb_coordinator.climb import ClimbRequest, run_climb
    from climb_coordinator.settings import load_climb_settings

    settings = load_climb_settings()
    result = run_climb(ClimbRequest(ladder="default", robot="g1", rungs=RUNGS, mode="qp", out_dir=None, bag=False,
                                    seed=0, plan_cycles=1, command_delay_ticks=1), settings)
    try:
        s = result.summary
        assert s["success"], s["failure_reason"]
        assert s["command_delay_ticks"] == 1
        assert result.controller.params.actuation_latency_s == pytest.approx(0.005)
        assert not s["fell"] and s["qp_failures"] == 0
        (replan,) = s["replans"]
        assert replan["cycles"] == 1 and "failure_reason" not in replan
        assert replan["start_projection_mm"] < 10.0  # the reached state was a few mm off the plan
        assert s["feet_rungs"] == {"left_foot": RUNGS, "right_foot": RUNGS}
        for foot in ("left_foot", "right_foot"):
            _assert_standing_on(result.backend, foot, RUNGS)
        assert s["transitions_done"] == s["n_transitions"] == len(result.plan.transitions)
    finally:
        result.close()
