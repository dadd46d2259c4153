"""Requests of the primitive_adaptation node (ROS-free core) and contact-plan adaptation."""
from __future__ import annotations

import numpy as np
import pytest

from climb_core.contact import ContactPlan
from climb_core.environment import build_environment
from climb_core.errors import SpecError
from climb_core.ladder import load_scenario
from climb_core.robot import load_robot
from planner_node import plan_io
from planner_node.adaptation_node import AdaptationService, parse_request
from planner_node.climb_planner import contact_plan_steps, plan_climb, plan_from_contact_plan
from planner_node.primitives import load_library
from planner_node.settings import load_settings
from planner_node.verify import verify_plan


def test_requests_are_validated_field_by_field():
    r = parse_request("{ladder: default, steps: 1, seed: 3, timeout_s: 20}")
    assert r == {"ladder": "default", "robot": "g1", "steps": 1, "seed": 3, "timeout_s": 20.0, "start": None, "id": ""}
    assert parse_request("")["steps"] == 2
    for text, field in (("steps: [1, 2", "request"), ("- a\n- b", "request"), ("{steps: -1}", "request.steps"),
                        ("{steps: true}", "request.steps"), ("{seed: 1.5}", "request.seed"),
                        ("{timeout_s: 0}", "request.timeout_s"), ("{timeout_s: soon}", "request.timeout_s"),
                        ("{ladder: 3}", "request.ladder"), ("{rungs: 2}", "request.rungs")):
        with pytest.raises(SpecError) as err:
            parse_request(text)
        assert err.value.field == field, text


def test_service_rejects_an_unknown_ladder_with_a_spec_error():
    service = AdaptationService(load_settings())
    with pytest.raises(SpecError):
        service.plan_request(parse_request("{ladder: no_such_ladder, steps: 1}"))
    bad_spec = {"ladder": {"type": "regular", "inclination_deg": 75.0, "rung_spacing": 0.9, "n_rungs": 8}}
    with pytest.raises(SpecError) as err:
        service.plan_request(parse_request(plan_io.summary_line({"ladder": bad_spec, "steps": 1})))
    assert "rung_spacing" in err.value.field


@pytest.fixture(scope="module")
def one_cycle():
    robot = load_robot("g1")
    env = build_environment(load_scenario("default"))

    def compute():
        res = plan_climb(robot, env, 1, seed=0)
        return (res.plan if res.success else None), res.summary()

    plan, meta = plan_io.cached_plan(plan_io.source_fingerprint("one_cycle", env.scenario, 1, 0), compute)
    assert plan is not None, meta
    return robot, env, plan


def test_a_contact_plan_becomes_a_feasible_whole_body_plan(one_cycle):
    robot, env, plan = one_cycle
    # the stance sequence (and its configurations) of a climb, as the contact search would give it
    stances = [plan.initial_stance] + [t.target_stance for t in plan.transitions]
    qs = [plan.transitions[0].path[0]] + [t.path[-1] for t in plan.transitions]
    cp = ContactPlan("g1", "default", list(robot.joint_names), stances, qs)
    kinds = [s.kind for s in contact_plan_steps(load_library("g1", "forward"), cp)]
    assert kinds.count("limb") == sum(1 for t in plan.transitions if t.moving_limb) and "com" in kinds
    res = plan_from_contact_plan(robot, env, cp, seed=0)
    assert res.success, res.failure_detail
    assert [t.target_stance.limbs for t in res.plan.transitions] == [s.limbs for s in stances[1:]]
    rep = verify_plan(robot, env, res.plan, q_start=qs[0], refine=2)
    assert rep.ok, rep.summary()
    assert np.allclose(res.plan.transitions[-1].path[-1][:3], qs[-1][:3], atol=0.05)


def test_contact_plans_changing_two_holds_at_once_are_rejected(one_cycle):
    robot, env, plan = one_cycle
    a = plan.initial_stance
    b = [t.target_stance for t in plan.transitions if len(t.target_stance.holds) == 4][0]  # both hands added
    cp = ContactPlan("g1", "default", list(robot.joint_names), [a, b], [plan.transitions[0].path[0]] * 2)
    with pytest.raises(SpecError) as err:
        contact_plan_steps(load_library("g1", "forward"), cp)
    assert err.value.field == "contact_plan.stances[1]"


def test_a_scenarios_planner_overrides_are_planned_with_and_a_bad_one_is_named():
    """config/scenes/narrow_passage.yaml carries its planner settings (``planner_overrides``): every
    planning path (the graph's nodes through pipeline.load_problem, plan.py, the in-process climb)
    plans the scene with them; an unknown setting or a bad value names the field."""
    import yaml

    from planner_node import pipeline
    from planner_node.settings import scenario_settings

    base = load_settings()
    problem = pipeline.load_problem(pipeline.PlanRequest(id="t", robot="g1", scenario="narrow_passage", rungs=1), base)
    s = problem.settings
    assert (s.timing.max_joint_speed, s.contact_search.hand_release_min_contacts, s.planning.timeout_s) == (0.2, 2, 1500.0)
    assert base.timing.max_joint_speed == 0.4 and base.contact_search.hand_release_min_contacts == 1
    assert scenario_settings(base, load_scenario("default")) is base  # a ladder without any: unchanged
    doc = load_scenario("narrow_passage").to_dict()
    for overrides, field in (({"timing.max_joint_sped": 0.2}, "scenario.planner_overrides.timing.max_joint_sped"),
                             ({"timing.max_joint_speed": -1.0}, "scenario.planner_overrides.timing.max_joint_speed"),
                             ({"contact_search.repair_rounds": "many"},
                              "scenario.planner_overrides.contact_search.repair_rounds")):
        doc["planner_overrides"] = overrides
        with pytest.raises(SpecError) as err:
            pipeline.load_problem(pipeline.PlanRequest(id="t", robot="g1", scenario=yaml.safe_dump(doc), rungs=1), base)
        assert err.value.field == field, (overrides, err.value)


def test_every_caller_orders_the_settings_of_a_scenario_the_same_way():
    """planner_node.settings.settings_for_scenario (the graph's pipeline and the in-process climb):
    the caller's settings, then for a walked scenario the scene overrides, the scenario file's own
    last; a ladder that is not walked keeps the caller's settings."""
    from planner_node.settings import apply_overrides, read_climb_overrides, settings_for_scenario

    base = load_settings()
    assert settings_for_scenario(base, load_scenario("default")) is base
    scene = settings_for_scenario(base, load_scenario("step_up"))  # config/climb.yaml's scene overrides
    for key, value in read_climb_overrides(key="scene_planner_overrides").items():
        group, name = key.split(".")
        assert getattr(getattr(scene, group), name) == value
    # given overrides replace the file's, and the scenario's own come last (narrow_passage: 0.2 rad/s)
    caller = apply_overrides(base, {"timing.max_joint_speed": 0.3})
    s = settings_for_scenario(caller, load_scenario("narrow_passage"),
                              scene_overrides={"timing.max_joint_speed": 0.35, "pcik.torque_limit_fraction": 0.7})
    assert (s.timing.max_joint_speed, s.pcik.torque_limit_fraction) == (0.2, 0.7)
    with pytest.raises(SpecError) as err:
        settings_for_scenario(base, load_scenario("step_up"), scene_overrides={"timing.nope": 1.0})
    assert err.value.field.endswith("timing.nope")


def test_a_steep_ladder_plans_within_the_controllers_grasp_moments():
    """config/climb.yaml's ``steep_ladder``: a ladder at least its bound steep (the vertical ladder,
    90 deg) plans with its overrides (the grasp moment cap of the controller's QP, planner and IK),
    a shallower one (the default, 75 deg) and a walked one (stairs) do not; the scenario file's own
    overrides still come last; a malformed block names its field."""
    from climb_coordinator.settings import load_climb_settings
    from planner_node.settings import apply_overrides, settings_for_scenario, steep_ladder

    cs = load_climb_settings()
    assert cs.steep_ladder["min_incline_deg"] == 84.0
    base = load_settings()
    vertical = load_scenario("vertical")
    s = settings_for_scenario(base, vertical, steep=cs.steep_ladder)
    for key, value in cs.steep_ladder["planner_overrides"].items():
        group, name = key.split(".")
        assert getattr(getattr(s, group), name) == value > 0
    assert s.planning.foot_on_rung_pitch_deg == 10.0  # vertical.yaml's own overrides kept
    assert settings_for_scenario(base, load_scenario("default"), steep=cs.steep_ladder) is base
    stairs = settings_for_scenario(base, load_scenario("stairs"), steep=cs.steep_ladder)
    assert stairs.planning.grasp_moment_limit == base.planning.grasp_moment_limit == 0.0
    # the bound is inclusive; 0 turns the rule off
    assert steep_ladder(vertical, {"min_incline_deg": 90.0}) and not steep_ladder(vertical, {"min_incline_deg": 0})
    # the scenario's own overrides win over the steep ones
    own = apply_overrides(base, {})
    doc = {"min_incline_deg": 84.0, "planner_overrides": {"timing.edge_slowdown_margin": 0.01}}
    assert settings_for_scenario(own, vertical, steep=doc).timing.edge_slowdown_margin == 0.045
    with pytest.raises(SpecError) as err:
        settings_for_scenario(base, vertical, steep={"min_incline_deg": 84.0, "planner_overrides": {"pcik.nope": 1}})
    assert err.value.field.endswith("pcik.nope")


def test_the_executing_sweep_plans_a_steep_grid_ladder_as_a_climb_does():
    """``sweep.py --execute`` (climb_coordinator.sweep_execute.climb_plan_settings): the coarse grid's
    86 deg ladder with the steep ladder's cap, its 74 deg ladder without, both with the climb's
    torque headroom; a spec that does not parse keeps the climb's settings (plan_task reports it)."""
    import dataclasses
    import pathlib

    from climb_coordinator.settings import load_climb_settings
    from climb_coordinator.sweep_execute import climb_plan_settings
    from planner_node.sweep import load_grid, make_tasks

    cs = load_climb_settings()
    coarse = pathlib.Path(__file__).resolve().parents[2].parent / "shared" / "bench" / "ladder_grid_coarse.yaml"
    shallow, steep = sorted(make_tasks(load_grid(coarse), "g1", select=[(86.0, 0.32), (74.0, 0.26)]),
                            key=lambda t: t.inclination_deg)
    s86, s74 = climb_plan_settings(steep, cs), climb_plan_settings(shallow, cs)
    assert s86.pcik.grasp_moment_limit == s86.planning.grasp_moment_limit == 6.0
    assert s74.pcik.grasp_moment_limit == s74.planning.grasp_moment_limit == 0.0
    assert s86.planning.torque_limit_fraction == s74.planning.torque_limit_fraction \
        == cs.planner_overrides["planning.torque_limit_fraction"]
    broken = dataclasses.replace(steep, spec={"ladder": {"type": "regular"}})
    assert climb_plan_settings(broken, cs).planning.grasp_moment_limit == 0.0


def test_a_malformed_steep_ladder_block_names_its_field(tmp_path):
    import yaml

    from climb_coordinator.settings import load_climb_settings
    from climb_core.ros_env import project_root

    doc = yaml.safe_load((project_root() / "config" / "climb.yaml").read_text())
    for bad, field in (({"planner_overrides": {}}, "climb.steep_ladder.min_incline_deg"),
                       ({"min_incline_deg": "steep", "planner_overrides": {}}, "climb.steep_ladder.min_incline_deg"),
                       ({"min_incline_deg": 84.0, "planner_overrides": [1]}, "climb.steep_ladder")):
        doc["climb"]["steep_ladder"] = bad
        path = tmp_path / "climb.yaml"
        path.write_text(yaml.safe_dump(doc))
        with pytest.raises(SpecError) as err:
            load_climb_settings(path)
        assert err.value.field == field, (bad, err.value)


def test_the_planning_nodes_read_of_the_steep_block_names_its_field_too():
    """planner_node.settings reads climb.steep_ladder itself (the planning nodes do not load the
    climb's settings): a bound that is not a number of degrees, or overrides that are not a
    mapping, are refused there by field, not with a raw ValueError."""
    from planner_node.settings import steep_ladder

    vertical = load_scenario("vertical")
    for bad, field in (({"min_incline_deg": "steep"}, "climb.steep_ladder.min_incline_deg"),
                       ({"min_incline_deg": 120.0}, "climb.steep_ladder.min_incline_deg"),
                       ({"min_incline_deg": True}, "climb.steep_ladder.min_incline_deg"),
                       ({"min_incline_deg": 84.0, "planner_overrides": [1]}, "climb.steep_ladder.planner_overrides"),
                       ([84.0], "climb.steep_ladder")):
        with pytest.raises(SpecError) as err:
            steep_ladder(vertical, bad)
        assert err.value.field == field, (bad, err.value)
    assert steep_ladder(vertical, {"min_incline_deg": None}) is False


def test_every_planning_caller_ranks_the_library_variants_like_the_sweep(tmp_path):
    """A grid ladder at a variant's reference (84 deg / 32 cm): the in-process climb
    (climb_coordinator.climb.plan), the graph's adaptation (pipeline.adapt) and scripts/plan.py
    plan with the nearest library first, every variant after it, as the sweep does (they passed
    the main library alone before 2026-11-30, and planned that ladder in 16.5 s where the sweep took
    4.2 s). One step, a short time limit: only the libraries used are compared."""
    import importlib.util
    import pathlib

    import yaml

    from climb_coordinator.climb import ClimbRequest, plan
    from climb_core.ladder import parse_scenario
    from planner_node import pipeline
    from planner_node.primitives import load_variants

    ladder = {"ladder": {"type": "regular", "inclination_deg": 84.0, "rung_spacing": 0.32, "n_rungs": 8,
                         "first_rung_height": 0.25, "rung_width": 0.5, "rung": {"shape": "circle", "diameter": 0.04},
                         "stringer": {"width": 0.08, "depth": 0.03}, "rails": [], "friction": 0.25,
                         "pose": {"x": 0.45, "y": 0.0, "yaw_deg": 0.0}}}
    settings = load_settings()
    robot = load_robot("g1")
    n_variants = len(load_variants("g1", settings.planning.strategy, settings.planning.primitives_dir))
    assert n_variants >= 2
    req = ClimbRequest(ladder="default", robot="g1", rungs=1, seed=0, plan_timeout_s=2.0)  # plan() reads the last three
    env = build_environment(parse_scenario(ladder, name="grid_84_0.32"))
    in_process = plan(req, robot, env, settings, 1)
    problem = pipeline.load_problem(pipeline.PlanRequest(id="t", robot="g1", scenario=yaml.safe_dump(ladder), rungs=1,
                                                         timeout_s=2.0), settings)
    graph, _ = pipeline.adapt(problem)
    spec_file = tmp_path / "grid_84_0.32.yaml"
    spec_file.write_text(yaml.safe_dump(ladder))
    script = importlib.util.spec_from_file_location(
        "plan_script", pathlib.Path(__file__).resolve().parents[2] / "scripts" / "plan.py")
    plan_py = importlib.util.module_from_spec(script)
    script.loader.exec_module(plan_py)
    from_script, _ = plan_py.run(plan_py.build_parser().parse_args(
        ["--scenario", str(spec_file), "--steps", "1", "--seed", "0", "--timeout", "2"]))
    for res in (in_process, graph, from_script):
        refs = [tuple(r) for r in res.stats["library_references"]]
        assert refs[0] == (84.0, 0.32) and len(refs) == n_variants, refs
