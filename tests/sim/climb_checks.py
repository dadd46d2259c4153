"""Shared by the in-process climb tests (test_climb*.py): the 2-step climb of the default ladder,
and the checks every executed climb must pass (judged on the simulator's ground truth)."""
from __future__ import annotations

RUNGS = 2
TOPICS = {"joint_states", "sim/base_truth", "joint_command", "controller/state",
          "ft/left_wrist", "ft/right_wrist", "ft/left_ankle", "ft/right_ankle"}


def climb(mode: str, tmp_path, max_transitions=None, command_delay_ticks=0):
    from climb_coordinator.climb import ClimbRequest, run_climb
    from climb_coordinator.settings import load_climb_settings

    settings = load_climb_settings()
    result = run_climb(ClimbRequest(ladder="default", robot="g1", rungs=RUNGS, mode=mode, out_dir=tmp_path,
                                    seed=0, max_transitions=max_transitions,
                                    command_delay_ticks=command_delay_ticks), settings)
    return result, settings


def climb_ladder_to(ladder: str, rungs: int, tmp_path):
    """A ladder climbed ``rungs`` rungs in process as every climb plans and executes it (QP, one
    period of actuation latency) and judged: success, :func:`check_run`, both feet standing on rung
    ``rungs``, both hands closed on the surfaces the plan ends on. Returns (result, settings): the
    caller closes the result."""
    from climb_core.contact import limb_type
    from climb_coordinator.climb import ClimbRequest, run_climb
    from climb_coordinator.settings import load_climb_settings

    settings = load_climb_settings()
    result = run_climb(ClimbRequest(ladder=ladder, robot="g1", rungs=rungs, mode="qp", out_dir=tmp_path, seed=0,
                                    command_delay_ticks=1), settings)
    try:
        s = result.summary
        assert s["success"], s["failure_reason"]
        feet, _ = check_run(result, settings, "qp")
        assert feet == {"left_foot": rungs, "right_foot": rungs}, feet
        for foot in ("left_foot", "right_foot"):
            assert_standing_on(result.backend, foot, rungs)
        last = result.plan.transitions[-1].target_stance
        expected = {h.limb: h.env_surface for h in last.holds if limb_type(h.limb) == "hand"}
        assert set(expected) == {"left_hand", "right_hand"} and s["grasps"] == expected, (s["grasps"], expected)
    except BaseException:
        result.close()
        raise
    return result, settings


def check_run(result, settings, mode: str, allow_qp_failures: bool = False) -> dict:
    """Checks every executed climb must pass; returns the feet's rungs (simulator contacts).
    ``allow_qp_failures``: a blow's infeasible QPs, answered by the brace's relaxed solve, are
    allowed (the caller asserts they fell inside a brace)."""
    from climb_coordinator import judge
    from msgs_py.bag import read_bag

    s = result.summary
    backend = result.backend
    assert backend is not None, s["failure_reason"]
    # nothing fell, the controller finished its plan without a QP failure
    assert not s["fell"], s["failure_reason"]
    assert s["fsm_state"] == "hold", s["failure_reason"]
    assert allow_qp_failures or s["qp_failures"] == 0
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


def assert_standing_on(backend, foot: str, rung: int) -> None:
    from climb_coordinator import judge

    pose = judge.foot_pose_check(backend, foot, rung)
    assert pose["horizontal_offset"] < 0.06, (foot, pose)
    assert -0.01 < pose["height_above_top"] < 0.05, (foot, pose)
    assert abs(pose["along_rung"]) < 0.2, (foot, pose)


def execute_stored_scene_plan(scene: str, plan_path, tmp_path, min_transitions: int):
    """A scene's stored whole-body plan (scripts/plan.py --out) executed in process from standing,
    QP mode, lock-step with one period of latency: (result, settings)."""
    from climb_core.ladder import load_scenario
    from climb_core.robot import load_robot
    from climb_coordinator.climb import ClimbRequest, StoredPlanSource, execute
    from climb_coordinator.settings import load_climb_settings

    settings = load_climb_settings()
    req = ClimbRequest(ladder=scene, robot="g1", rungs=1, mode="qp", out_dir=tmp_path, strategy="search",
                       command_delay_ticks=1)
    plans = StoredPlanSource(plan_path, load_robot("g1"), settings)
    assert plans.plan_.environment == scene and len(plans.plan_.transitions) >= min_transitions
    return execute(req, plans, settings, load_scenario(scene), "standing"), settings


def touched_surfaces(backend) -> set:
    """The scene's surfaces the robot touches now (simulator contact points)."""
    from climb_coordinator import judge

    names = judge._surface_names(backend)
    return {names.get(cp[2]) for cp in backend.p.getContactPoints(bodyA=backend.body, physicsClientId=backend.client)
            if cp[2] != backend.body}
