"""The environment of scenes: surfaces as data (contact limbs, bilateral, friction) for ladders and
scenes, the start pose, G1 standing collision-free at each shipped scene's start and goal."""
from __future__ import annotations

import json
import math
import pathlib
import subprocess
import sys

import numpy as np
import pytest

from climb_core.collision import checker
from climb_core.environment import ROLES, build_environment
from climb_core.errors import SpecError
from sim_bridge.world_bodies import robot_lateral_friction, surface_lateral_friction
from climb_core.ladder import load_scenario, parse_scenario
from climb_core.robot import load_robot
from climb_core.scene import require_search_strategy

SCENES = ("car_ingress", "narrow_passage", "narrow_passage_step", "stairs_handrail")
#: [m] smallest robot-environment clearance accepted for G1 standing (its knee hulls are 0.033 m
#: above the sole's support plane at the reference posture).
CLEARANCE = 0.02


@pytest.fixture(scope="module")
def g1():
    return load_robot("g1")


def names(surfaces) -> list[str]:
    return [s.name for s in surfaces]


def test_ladder_surfaces_get_the_use_they_had_implicitly():
    env = build_environment("ship")  # rect treads, two rails, a platform
    assert names(env.contact_surfaces("foot")) == ["ground"] + [f"rung_{k}" for k in range(1, env.n_rungs + 1)] \
        + ["platform"]
    assert names(env.contact_surfaces("hand")) == ["rail_left", "rail_right"]
    assert all(s.bilateral for s in env.contact_surfaces("hand")) and not env.rung(1).bilateral
    default = build_environment("default")  # circle rungs
    rungs = [f"rung_{k}" for k in range(1, default.n_rungs + 1)]
    assert names(default.contact_surfaces("hand")) == rungs
    assert names(default.contact_surfaces("foot")) == ["ground"] + rungs + ["platform"]
    assert all(default.rung(k).bilateral and default.rung(k).contact_limbs == ("foot", "hand") for k in (1, 8))
    caged = build_environment("caged")
    for surface in caged.surfaces.values():
        if surface.role in ("stringer", "obstacle"):
            assert surface.contact_limbs == () and not surface.bilateral
    with pytest.raises(SpecError) as info:
        default.contact_surfaces("knee")
    assert info.value.field == "limb_type"


def test_scene_surfaces_carry_their_spec():
    env = build_environment("car_ingress")
    scene = env.scenario.scene
    assert env.ladder is None and env.n_rungs == 0 and env.scene is scene
    for spec in scene.surfaces:
        surface = env.surfaces[spec.name]
        assert surface.role == "scene" and surface.role in ROLES
        assert (surface.contact_limbs, surface.bilateral, surface.friction) == (spec.contact, spec.bilateral,
                                                                              spec.friction)
        np.testing.assert_allclose(surface.position, spec.position)
        np.testing.assert_allclose(surface.half_extents, spec.half_extents)
    assert names(env.contact_surfaces("foot")) == ["ground", "floor", "seat_driver", "seat_passenger"]
    hands = env.contact_surfaces("hand")
    assert "steering_wheel" in names(hands) and "floor" not in names(hands)
    wheel = env.surfaces["steering_wheel"]
    assert wheel.bilateral and 2 * wheel.radius <= 0.04 and wheel.shape == "cylinder"
    for bar in (s for s in hands if s.name.startswith(("a_pillar", "b_pillar", "roof"))):
        assert bar.bilateral and 0.04 <= 2 * bar.radius <= 0.05
    # a roll-cage pillar's geometry: the A-pillar runs from the dash corner up to the roof
    pillar = env.surfaces["a_pillar_driver"]
    ends = [pillar.position + sign * 0.5 * pillar.length * pillar.axis for sign in (-1, 1)]
    np.testing.assert_allclose(sorted(ends, key=lambda p: p[2]), [[0.58, 0.75, 0.45], [0.58, 0.50, 1.85]], atol=1e-6)


def test_narrow_passage_and_stairs_geometry():
    env = build_environment("narrow_passage")
    incline, floor, step = (env.surfaces[n] for n in ("incline", "floor", "step"))
    top = incline.T_world_surface @ np.array([[-incline.half_extents[0], 0, incline.half_extents[2], 1],
                                              [incline.half_extents[0], 0, incline.half_extents[2], 1]]).T
    np.testing.assert_allclose(top[[0, 2]].T, [[0.6, 0.0], [1.6, floor.top_z]], atol=1e-6)  # ground to floor
    assert 0.30 <= step.top_z - floor.top_z <= 0.35  # more than half of G1's ~0.6 m leg
    assert [s.contact_limbs for s in (env.surfaces["wall_left"], env.surfaces["wall_right"])] == [("hand",)] * 2
    assert not env.surfaces["wall_left"].bilateral
    stairs = build_environment("stairs_handrail")
    tops = [stairs.surfaces[n].top_z for n in ("step_1", "step_2", "step_3", "landing")]
    np.testing.assert_allclose(np.diff([0.0] + tops), 0.15)
    for side in ("left", "right"):
        rail = stairs.surfaces[f"handrail_{side}"]
        assert rail.bilateral and 2 * rail.radius == pytest.approx(0.04)
        for k, x_nose in enumerate((0.5, 0.8, 1.1, 1.4), start=1):  # 0.9 m above each nose, vertically
            s = (x_nose - rail.position[0]) / rail.axis[0]
            assert (rail.position + s * rail.axis)[2] - 0.15 * k == pytest.approx(0.9)


def test_no_ladder_methods_raise_and_friction_rule():
    env = build_environment("narrow_passage")
    for call in (lambda: env.rung(1), lambda: env.stringer_direction_in_world):
        with pytest.raises(SpecError) as info:
            call()
        assert info.value.field == "ladder" and "ladder: block" in info.value.rule
    assert env.rails() == {} and env.rungs() == [] and "scene" in repr(env)
    mu_ground = env.surfaces["ground"].friction
    assert robot_lateral_friction(env) == pytest.approx(math.sqrt(mu_ground))
    for surface in env.surfaces.values():  # PyBullet's product gives every surface its own mu
        assert surface_lateral_friction(env, surface) * robot_lateral_friction(env) == pytest.approx(surface.friction)
    ladder_scene = build_environment({"ladder": {"friction": 0.36},
                                      "scene": {"ground": {"friction": 0.5}, "surfaces": [
                                          {"name": "box", "shape": "box", "size": [1, 1, 1], "position": [3, 0, 0.5],
                                           "friction": 0.9, "contact": ["foot"]}]}})
    assert robot_lateral_friction(ladder_scene) == pytest.approx(0.6)  # sqrt(ladder friction), as before
    assert ladder_scene.surfaces["ground"].friction == 0.5  # the scene's explicit ground wins
    assert surface_lateral_friction(ladder_scene, ladder_scene.surfaces["box"]) * 0.6 == pytest.approx(0.9)


def test_place_at_start_moves_and_turns_the_standing_robot(g1):
    q0 = g1.q_reference()
    env = build_environment(parse_scenario({"scene": {"start": {"pose": {"x": 1.0, "y": -2.0, "yaw_deg": 90.0}},
                                                      "goal": {"base_position": [1, 0, 0.8], "tolerance": 0.1}}}))
    q = env.place_at_start(q0)
    assert np.linalg.norm(q[3:7]) == pytest.approx(1.0)
    import pinocchio as pin

    for config in (q0, q):
        data = g1.model.createData()
        pin.framesForwardKinematics(g1.model, data, config)
        if config is q0:
            feet0 = [data.oMf[g1.model.getFrameId(f"{s}_ankle_roll_link")].copy() for s in ("left", "right")]
        else:
            feet = [data.oMf[g1.model.getFrameId(f"{s}_ankle_roll_link")] for s in ("left", "right")]
    Rz = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    for before, after in zip(feet0, feet):
        np.testing.assert_allclose(after.translation, Rz @ before.translation + [1.0, -2.0, 0.0], atol=1e-9)
        np.testing.assert_allclose(after.rotation, Rz @ before.rotation, atol=1e-9)
    np.testing.assert_allclose(build_environment("default").place_at_start(q0), q0)  # ladders: the origin


def _environment_clearance(c, q, support: str) -> tuple[float, tuple[str, str]]:
    """Smallest signed distance robot-environment [m], the feet-support pairs left out."""
    d = c.all_distances(q)
    excluded = set(c.excluded_pairs([("left_foot", support), ("right_foot", support)]))
    env_pairs = [i for i, pair in enumerate(c.pair_names) if pair[1].startswith("env:") and i not in excluded]
    i = min(env_pairs, key=lambda k: d[k])
    return float(d[i]), c.pair_names[i]


def _foot_surface_under(env, point) -> str:
    """The highest foot surface (not the ground) whose top face lies under ``point``."""
    best, best_z = "ground", 0.0
    for s in env.contact_surfaces("foot"):
        if s.shape != "box" or s.normal[2] < 0.999:
            continue
        local = np.linalg.inv(s.T_world_surface) @ np.append(point, 1.0)
        if np.all(np.abs(local[:2]) <= s.half_extents[:2]) and s.top_z > best_z:
            best, best_z = s.name, s.top_z
    return best


@pytest.mark.parametrize("name", SCENES)
def test_g1_stands_collision_free_at_the_start_and_at_the_goal(g1, name):
    env = build_environment(load_scenario(name))
    c = checker(g1, env)
    q0 = g1.q_reference()
    clearance, pair = _environment_clearance(c, env.place_at_start(q0), "ground")
    assert clearance > CLEARANCE, (clearance, pair)
    # the goal: a foot surface under it, G1 standing on that surface has its base within tolerance
    goal = env.goal
    support = _foot_surface_under(env, np.asarray(goal.base_position))
    assert support != "ground"  # every shipped goal is up on the scene
    top = env.surfaces[support].top_z
    assert abs(goal.base_position[2] - (top + q0[2])) <= goal.tolerance
    q_goal = q0.copy()
    q_goal[:3] = (goal.base_position[0], goal.base_position[1], top + q0[2])
    clearance, pair = _environment_clearance(c, q_goal, support)
    assert clearance > CLEARANCE, (clearance, pair)


def test_a_scene_without_a_ladder_needs_the_search_strategy():
    require_search_strategy(load_scenario("default"), "forward")  # ladders: every strategy
    require_search_strategy(load_scenario("narrow_passage"), "search")
    with pytest.raises(SpecError) as info:
        require_search_strategy(load_scenario("narrow_passage"), "forward")
    assert info.value.field == "strategy"
    assert "strategy 'search' needed for a scene without a ladder" in info.value.rule


def test_plan_script_exits_2_with_the_reason_and_the_scene_fields():
    """scripts/plan.py --scenario <scene> with a ladder strategy: exit code 2, the reason on standard
    error (no traceback), the summary with the scene's fields as the last line."""
    root = pathlib.Path(__file__).resolve().parents[2]
    run = subprocess.run([sys.executable, str(root / "scripts" / "plan.py"), "--scenario", "narrow_passage",
                          "--strategy", "forward"], capture_output=True, text=True, timeout=120, cwd=root)
    assert run.returncode == 2, run.stderr
    assert "strategy 'search' needed for a scene without a ladder" in run.stderr and "Traceback" not in run.stderr
    summary = json.loads(run.stdout.strip().splitlines()[-1])
    assert summary["success"] is False and summary["failure_reason"].startswith("spec: strategy:")
    assert (summary["scene"], summary["rungs_requested"], summary["rungs_reached"]) == ("narrow_passage", 0, 0)
    assert summary["goal_reached"] is False and summary["contacts_used"] == []


@pytest.mark.parametrize("item, field", [("planning.sole_cop_margin", "--set"),
                                         ("planning.no_such_setting=1", "--set.planning.no_such_setting"),
                                         ("planning.sole_cop_margin=0.5", "--set.planning.sole_cop_margin")])
def test_plan_script_set_refuses_a_bad_override_naming_it(item, field):
    """scripts/plan.py --set GROUP.FIELD=VALUE: a malformed item, an unknown setting and a value out
    of its range each exit 2 with the field named, before any planning."""
    root = pathlib.Path(__file__).resolve().parents[2]
    run = subprocess.run([sys.executable, str(root / "scripts" / "plan.py"), "--set", item],
                         capture_output=True, text=True, timeout=120, cwd=root)
    assert run.returncode == 2, (run.stdout, run.stderr)
    assert f"error: {field}" in run.stderr and "Traceback" not in run.stderr, run.stderr


def test_plan_script_chooses_the_search_for_a_scene_named_without_a_strategy():
    """scripts/plan.py --scenario step_up (no --strategy): the strategy is chosen for the scenario
    (a scene: the contact search), said on standard error and in the summary, and the scene plans."""
    root = pathlib.Path(__file__).resolve().parents[2]
    run = subprocess.run([sys.executable, str(root / "scripts" / "plan.py"), "--scenario", "step_up"],
                         capture_output=True, text=True, timeout=300, cwd=root)
    assert run.returncode == 0, run.stderr[-2000:]
    assert "strategy search: a scene without a ladder" in run.stderr
    summary = json.loads(run.stdout.strip().splitlines()[-1])
    assert summary["strategy"] == "search" and summary["strategy_reason"].startswith("a scene without a ladder")
    assert summary["success"] and summary["goal_reached"], summary
