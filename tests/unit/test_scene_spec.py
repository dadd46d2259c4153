"""The scene spec (shared/specs/scene_spec.md): every rule rejected with the field named, the shipped
scenes, YAML round trips, ladder + scene scenarios."""
from __future__ import annotations

import copy
import math
import re

import numpy as np
import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from climb_core.environment import build_environment
from climb_core.errors import SpecError
from sim_bridge.world_bodies import robot_lateral_friction
from climb_core.ladder import available_ladders, available_scenes, load_scenario, parse_scenario
from climb_core.scene import BILATERAL_MAX_WIDTH, ladder_surface_names

SHIPPED_SCENES = ("car_ingress", "narrow_passage", "narrow_passage_step", "stairs_handrail", "step_up")
DELETE = object()


def good_doc() -> dict:
    """A valid scene document touching every field (box, bilateral cylinder, ground, start, goal)."""
    return {
        "name": "fixture",
        "description": "every scene field",
        "scene": {
            "ground": {"friction": 0.9},
            "surfaces": [
                {"name": "block_left", "shape": "box", "size": [1.2, 0.4, 0.9], "position": [1.5, 0.55, 0.45],
                 "rpy_deg": [0.0, 0.0, 10.0], "friction": 0.6, "contact": ["foot", "hand"], "bilateral": False},
                {"name": "handle", "shape": "cylinder", "size": {"radius": 0.02, "length": 0.8},
                 "position": [1.0, 0.4, 0.95], "contact": ["hand"], "bilateral": True},
                {"name": "bar_box", "shape": "box", "size": [1.0, 0.04, 0.05], "position": [1.0, -0.4, 0.95],
                 "contact": ["hand"], "bilateral": True},
            ],
            "start": {"pose": {"x": 0.1, "y": -0.2, "yaw_deg": 15.0}},
            "goal": {"base_position": [3.0, 0.0, 1.30], "tolerance": 0.15},
        },
    }


def _walk(doc: dict, path: str) -> tuple[object, object]:
    """(container, key) of a dotted path with [i] indices."""
    parts = [int(p) if p.isdigit() else p for p in re.findall(r"[^.\[\]]+", path)]
    node = doc
    for part in parts[:-1]:
        node = node[part]
    return node, parts[-1]


def mutated(path: str, value: object, doc: dict | None = None) -> dict:
    doc = copy.deepcopy(doc or good_doc())
    node, key = _walk(doc, path)
    if value is DELETE:
        del node[key]
    else:
        node[key] = value
    return doc


# (id, path to change, new value, field named by the error, words of the rule)
RULES = [
    # unknown keys at every level
    ("unknown_scene_key", "scene.lights", [], "scene.lights", "unknown key"),
    ("unknown_surface_key", "scene.surfaces[0].colour", "red", "scene.surfaces[0].colour", "unknown key"),
    ("typo_surface_key", "scene.surfaces[0].frictoin", 0.5, "scene.surfaces[0].frictoin", "did you mean 'friction'"),
    ("unknown_ground_key", "scene.ground.mu", 0.5, "scene.ground.mu", "unknown key"),
    ("unknown_start_key", "scene.start.posture", "standing", "scene.start.posture", "unknown key"),
    ("unknown_pose_key", "scene.start.pose.z", 0.0, "scene.start.pose.z", "unknown key"),
    ("unknown_goal_key", "scene.goal.orientation", [0, 0, 0], "scene.goal.orientation", "unknown key"),
    ("unknown_cylinder_size_key", "scene.surfaces[1].size.diameter", 0.04, "scene.surfaces[1].size.diameter",
     "unknown key"),
    # required fields
    ("missing_name", "scene.surfaces[0].name", DELETE, "scene.surfaces[0].name", "required"),
    ("missing_shape", "scene.surfaces[0].shape", DELETE, "scene.surfaces[0].shape", "required"),
    ("missing_size", "scene.surfaces[1].size", DELETE, "scene.surfaces[1].size", "required"),
    ("missing_position", "scene.surfaces[0].position", DELETE, "scene.surfaces[0].position", "required"),
    ("null_position", "scene.surfaces[0].position", None, "scene.surfaces[0].position", "required"),
    # names
    ("name_uppercase", "scene.surfaces[0].name", "Block", "scene.surfaces[0].name", "[a-z0-9_]+"),
    ("name_dash", "scene.surfaces[0].name", "block-left", "scene.surfaces[0].name", "[a-z0-9_]+"),
    ("name_empty", "scene.surfaces[0].name", "", "scene.surfaces[0].name", "[a-z0-9_]+"),
    ("name_number", "scene.surfaces[0].name", 3, "scene.surfaces[0].name", "[a-z0-9_]+"),
    ("name_duplicate", "scene.surfaces[1].name", "block_left", "scene.surfaces[1].name", "given twice"),
    ("name_ground", "scene.surfaces[2].name", "ground", "scene.surfaces[2].name", "clashes with the ground"),
    # shapes and sizes
    ("unknown_shape", "scene.surfaces[0].shape", "sphere", "scene.surfaces[0].shape", "must be one of box, cylinder"),
    ("box_size_two_numbers", "scene.surfaces[0].size", [1.0, 2.0], "scene.surfaces[0].size", "3 numbers"),
    ("box_size_zero", "scene.surfaces[0].size", [1.0, 0.0, 1.0], "scene.surfaces[0].size[1]", "> 0"),
    ("box_size_negative", "scene.surfaces[0].size", [1.0, 1.0, -0.1], "scene.surfaces[0].size[2]", "> 0"),
    ("box_size_string", "scene.surfaces[0].size", [1.0, "1", 1.0], "scene.surfaces[0].size[1]", "must be a number"),
    ("box_size_mapping", "scene.surfaces[0].size", {"radius": 0.1, "length": 1.0}, "scene.surfaces[0].size",
     "list of 3 numbers"),
    ("cylinder_size_list", "scene.surfaces[1].size", [0.02, 0.8, 0.1], "scene.surfaces[1].size", "mapping"),
    ("cylinder_radius_zero", "scene.surfaces[1].size.radius", 0.0, "scene.surfaces[1].size.radius", "> 0"),
    ("cylinder_length_negative", "scene.surfaces[1].size.length", -1.0, "scene.surfaces[1].size.length", "> 0"),
    ("cylinder_without_length", "scene.surfaces[1].size.length", DELETE, "scene.surfaces[1].size.length",
     "required"),
    # vectors
    ("position_two_numbers", "scene.surfaces[0].position", [1.0, 2.0], "scene.surfaces[0].position", "3 numbers"),
    ("position_string", "scene.surfaces[0].position", "1 2 3", "scene.surfaces[0].position", "3 numbers"),
    ("position_boolean", "scene.surfaces[0].position", [1.0, True, 0.0], "scene.surfaces[0].position[1]",
     "must be a number"),
    ("rpy_four_numbers", "scene.surfaces[0].rpy_deg", [0, 0, 0, 0], "scene.surfaces[0].rpy_deg", "3 numbers"),
    ("goal_position_two_numbers", "scene.goal.base_position", [3.0, 0.0], "scene.goal.base_position", "3 numbers"),
    ("start_x_string", "scene.start.pose.x", "zero", "scene.start.pose.x", "must be a number"),
    # NaN / inf anywhere
    ("position_nan", "scene.surfaces[0].position", [float("nan"), 0.0, 0.0], "scene.surfaces[0].position[0]",
     "finite"),
    ("rpy_inf", "scene.surfaces[0].rpy_deg", [0.0, float("inf"), 0.0], "scene.surfaces[0].rpy_deg[1]", "finite"),
    ("size_inf", "scene.surfaces[1].size.radius", float("-inf"), "scene.surfaces[1].size.radius", "finite"),
    ("start_yaw_nan", "scene.start.pose.yaw_deg", float("nan"), "scene.start.pose.yaw_deg", "finite"),
    ("goal_position_inf", "scene.goal.base_position", [3.0, float("inf"), 1.3], "scene.goal.base_position[1]",
     "finite"),
    ("tolerance_nan", "scene.goal.tolerance", float("nan"), "scene.goal.tolerance", "finite"),
    ("friction_nan", "scene.ground.friction", float("nan"), "scene.ground.friction", "finite"),
    ("huge_number", "scene.surfaces[0].position", [1e300, 0.0, 0.0], "scene.surfaces[0].position[0]", "magnitude"),
    # friction
    ("friction_zero", "scene.surfaces[0].friction", 0.0, "scene.surfaces[0].friction", "(0, 2]"),
    ("friction_above_two", "scene.surfaces[1].friction", 2.5, "scene.surfaces[1].friction", "(0, 2]"),
    ("ground_friction_zero", "scene.ground.friction", 0.0, "scene.ground.friction", "(0, 2]"),
    ("ground_friction_above_two", "scene.ground.friction", 3.0, "scene.ground.friction", "(0, 2]"),
    # contact
    ("contact_knee", "scene.surfaces[0].contact", ["foot", "knee"], "scene.surfaces[0].contact[1]",
     "unknown limb type 'knee'"),
    ("contact_string", "scene.surfaces[0].contact", "foot", "scene.surfaces[0].contact", "must be a list"),
    ("contact_twice", "scene.surfaces[0].contact", ["hand", "hand"], "scene.surfaces[0].contact[1]", "twice"),
    # bilateral
    ("bilateral_without_hand", "scene.surfaces[1].contact", ["foot"], "scene.surfaces[1].bilateral", "'hand'"),
    ("bilateral_obstacle", "scene.surfaces[1].contact", [], "scene.surfaces[1].bilateral", "'hand'"),
    ("bilateral_thick_cylinder", "scene.surfaces[1].size.radius", 0.045, "scene.surfaces[1].bilateral",
     "diameter 0.09 m is above 0.08"),
    ("bilateral_wide_box", "scene.surfaces[2].size", [1.0, 0.09, 0.05], "scene.surfaces[2].bilateral",
     "second largest size 0.09 m is above 0.08"),
    ("bilateral_block", "scene.surfaces[0].bilateral", True, "scene.surfaces[0].bilateral", "above 0.08"),
    ("bilateral_string", "scene.surfaces[1].bilateral", "yes", "scene.surfaces[1].bilateral", "true or false"),
    # goal
    ("tolerance_zero", "scene.goal.tolerance", 0.0, "scene.goal.tolerance", "> 0"),
    ("tolerance_negative", "scene.goal.tolerance", -0.1, "scene.goal.tolerance", "> 0"),
    ("goal_without_tolerance", "scene.goal.tolerance", DELETE, "scene.goal.tolerance", "required"),
    ("goal_without_position", "scene.goal.base_position", DELETE, "scene.goal.base_position", "required"),
    ("no_goal_no_ladder", "scene.goal", DELETE, "scene.goal", "without a ladder"),
    ("goal_not_mapping", "scene.goal", [3.0, 0.0, 1.3], "scene.goal", "must be a mapping"),
    # blocks of the wrong type
    ("scene_list", "scene", [], "scene", "must be a mapping"),
    ("surfaces_mapping", "scene.surfaces", {"name": "a"}, "scene.surfaces", "must be a list"),
    ("ground_number", "scene.ground", 0.8, "scene.ground", "must be a mapping"),
]


def test_the_good_document_parses_with_every_field():
    scenario = parse_scenario(good_doc())
    scene = scenario.scene
    assert scenario.ladder is None and scenario.name == "fixture"
    assert [s.name for s in scene.surfaces] == ["block_left", "handle", "bar_box"]
    block, handle, bar = scene.surfaces
    assert block.size == (1.2, 0.4, 0.9) and block.rpy_deg == (0.0, 0.0, 10.0) and block.contact == ("foot", "hand")
    assert (handle.radius, handle.length, handle.size, handle.friction) == (0.02, 0.8, None, 0.6)  # default friction
    assert handle.bilateral and handle.grasp_width == pytest.approx(0.04) and bar.grasp_width == pytest.approx(0.05)
    assert (scene.start.x, scene.start.y, scene.start.yaw_deg) == (0.1, -0.2, 15.0)
    assert scene.goal.base_position == (3.0, 0.0, 1.3) and scene.goal.tolerance == 0.15
    assert scene.ground_friction == 0.9


@pytest.mark.parametrize("case", RULES, ids=[r[0] for r in RULES])
def test_every_rule_is_rejected_with_the_field_named(case):
    _, path, value, field, words = case
    with pytest.raises(SpecError) as info:
        parse_scenario(mutated(path, value))
    assert info.value.field == field, info.value
    assert words in info.value.rule, info.value
    # the same error through YAML text (what the scripts and the service receive), NaN included
    text = yaml.safe_dump(mutated(path, value), sort_keys=False)
    with pytest.raises(SpecError) as info:
        load_scenario(text)
    assert info.value.field == field


def test_bilateral_limit_is_inclusive_and_defaults():
    doc = mutated("scene.surfaces[2].size", [1.0, BILATERAL_MAX_WIDTH, BILATERAL_MAX_WIDTH])
    doc = mutated("scene.surfaces[1].size.radius", BILATERAL_MAX_WIDTH / 2, doc)
    scene = parse_scenario(doc).scene
    assert scene.surface("bar_box").bilateral and scene.surface("handle").bilateral
    minimal = parse_scenario({"scene": {"surfaces": [{"name": "b", "shape": "box", "size": [1, 1, 1],
                                                      "position": [2, 0, 0.5]}],
                                        "goal": {"base_position": [2, 0, 1.8], "tolerance": 0.1}}}).scene
    surface = minimal.surfaces[0]
    assert (surface.contact, surface.bilateral, surface.friction, surface.rpy_deg) == ((), False, 0.6, (0, 0, 0))
    assert (minimal.start.x, minimal.start.y, minimal.start.yaw_deg) == (0.0, 0.0, 0.0)
    assert minimal.ground_friction is None
    assert build_environment(parse_scenario({"scene": {"goal": {"base_position": [1, 0, 0.8], "tolerance": 0.1}}})
                             ).surfaces["ground"].friction == 0.8


def test_a_scenario_needs_a_ladder_or_a_scene():
    for doc in ({}, {"name": "x"}, {"ladder": None, "scene": None}):
        with pytest.raises(SpecError) as info:
            parse_scenario(doc)
        assert info.value.field == "ladder" and "a scene: block" in info.value.rule
    with pytest.raises(SpecError) as info:
        parse_scenario({"scene": good_doc()["scene"], "perturbation": {"rung_offsets": [{"rung": 1, "dz": 0.01}]}})
    assert info.value.field == "perturbation.rung_offsets" and "ladder" in info.value.rule
    with pytest.raises(SpecError) as info:
        parse_scenario({"scene": good_doc()["scene"], "perturbation": {"rails_dy": 0.01}})
    assert info.value.field == "perturbation.rails_dy"
    drops = parse_scenario({"scene": good_doc()["scene"], "perturbation": {"drops": [{"at_time": 2.0}]}})
    assert drops.perturbation.drops[0].at_time == 2.0  # thrown objects need no ladder


# ---------------------------------------------------------------------------------------------
# Ladder + scene.
# ---------------------------------------------------------------------------------------------

def ladder_and_cage() -> dict:
    """The default ladder with a scene adding a cage bar and a landing beyond the top rung."""
    return {"name": "caged_landing",
            "ladder": {"n_rungs": 6, "top_platform": None},
            "scene": {"surfaces": [
                {"name": "cage_bar", "shape": "cylinder", "size": {"radius": 0.02, "length": 1.0},
                 "position": [1.3, 0.0, 1.6], "rpy_deg": [0, 0, 90], "contact": ["hand"], "bilateral": True},
                {"name": "landing", "shape": "box", "size": [1.0, 1.0, 0.05], "position": [1.4, 0.0, 1.5],
                 "contact": ["foot"], "friction": 0.7}],
                "start": {"pose": {"x": -0.1, "y": 0.0, "yaw_deg": 0.0}}}}


def test_ladder_plus_scene_builds_both_and_checks_names():
    scenario = parse_scenario(ladder_and_cage())
    assert scenario.ladder.n_rungs == 6 and scenario.scene.goal is None  # the goal may come from the request
    env = build_environment(scenario)
    assert list(env.surfaces)[:2] == ["ground", "rung_1"] and list(env.surfaces)[-2:] == ["cage_bar", "landing"]
    assert env.n_rungs == 6 and env.goal is None and env.start_pose.x == -0.1
    assert env.surfaces["landing"].role == "scene" and env.surfaces["landing"].friction == 0.7
    assert robot_lateral_friction(env) == pytest.approx(math.sqrt(0.25))  # the ladder's rule is unchanged
    # every name the ladder builds is reserved, names it does not build are free
    for name in ("rung_6", "stringer_left", "ground"):
        doc = mutated("scene.surfaces[1].name", name, ladder_and_cage())
        with pytest.raises(SpecError) as info:
            parse_scenario(doc)
        assert info.value.field == "scene.surfaces[1].name" and "clashes" in info.value.rule
    for name in ("rung_7", "rail_left", "platform", "obstacle_0"):  # not built for this ladder
        parse_scenario(mutated("scene.surfaces[1].name", name, ladder_and_cage()))
    caged = load_scenario("caged").to_dict()
    caged["scene"] = {"surfaces": [{"name": "obstacle_0", "shape": "box", "size": [1, 1, 1], "position": [5, 0, 0.5]}]}
    with pytest.raises(SpecError) as info:
        parse_scenario(caged)
    assert info.value.field == "scene.surfaces[0].name"


@pytest.mark.parametrize("name", available_ladders())
def test_reserved_names_are_the_names_the_ladder_builds(name):
    scenario = load_scenario(name)
    assert set(ladder_surface_names(scenario.ladder)) == set(build_environment(scenario, perturbed=True).surfaces)


# ---------------------------------------------------------------------------------------------
# Shipped scenes and round trips.
# ---------------------------------------------------------------------------------------------

def test_shipped_scenes_are_listed():
    assert tuple(available_scenes()) == SHIPPED_SCENES
    assert not set(available_scenes()) & set(available_ladders())  # a name resolves to one file


@pytest.mark.parametrize("name", SHIPPED_SCENES)
def test_shipped_scenes_parse_build_and_round_trip(name):
    scenario = load_scenario(name)
    assert scenario.name == name and scenario.ladder is None and scenario.description
    assert scenario.scene.goal is not None and scenario.scene.goal.tolerance > 0
    env = build_environment(scenario)
    assert set(env.surfaces) == {"ground"} | {s.name for s in scenario.scene.surfaces}
    assert parse_scenario(yaml.safe_load(scenario.to_yaml()), name=name) == scenario
    assert load_scenario(scenario.to_yaml()) == scenario  # the document's own name field


def test_round_trips_keep_every_field():
    for doc in (good_doc(), ladder_and_cage()):
        scenario = parse_scenario(doc)
        again = load_scenario(scenario.to_yaml())
        assert again == scenario
        assert again.to_dict() == scenario.to_dict()
    ladder_only = load_scenario("default")
    assert "scene" not in ladder_only.to_dict()  # ladder documents are unchanged
    assert load_scenario(ladder_only.to_yaml()) == ladder_only


# ---------------------------------------------------------------------------------------------
# Garbage anywhere in a valid scene: a SpecError naming a field, or a scenario that builds.
# ---------------------------------------------------------------------------------------------

SCALARS = st.one_of(st.none(), st.booleans(), st.integers(min_value=-10 ** 20, max_value=10 ** 20),
                    st.floats(allow_nan=True, allow_infinity=True), st.floats(min_value=-1, max_value=3),
                    st.text(max_size=6), st.sampled_from(["box", "cylinder", "foot", "hand", "ground", "handle"]))
GARBAGE = st.recursive(SCALARS, lambda children: st.one_of(
    st.lists(children, max_size=4),
    st.dictionaries(st.one_of(st.sampled_from(["radius", "length", "name", "x", "friction", "pose", "tolerance"]),
                              st.text(max_size=4)), children, max_size=4)), max_leaves=12)
PATHS = [r[1] for r in RULES if r[2] is not DELETE] + ["scene.surfaces[0]", "scene.start", "scene.goal"]


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.sampled_from(PATHS), GARBAGE)
def test_garbage_anywhere_in_a_scene_only_raises_spec_errors(path, value):
    try:
        scenario = parse_scenario(mutated(path, value))
    except SpecError as exc:
        assert exc.field.startswith(("scene", "ladder")) and exc.rule
        return
    env = build_environment(scenario)
    for surface in env.surfaces.values():
        assert np.all(np.isfinite(surface.T_world_surface)) and np.all(surface.half_extents >= 0)
