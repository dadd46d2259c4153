"""The ladder / scenario spec (shared/specs/ladder_spec.md): every field, every rule, every input form."""
from __future__ import annotations

import copy
import math
import pathlib
import re

import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from climb_core.environment import build_environment
from climb_core.errors import SpecError
from climb_core.ladder import (DEFAULTS, MAX_RUNGS, LadderSpec, Scenario, available_ladders, load_scenario,
                               parse_scenario)

ROOT = pathlib.Path(__file__).resolve().parents[2]
SHARED = ROOT.parent / "shared"
SPEC_MD = SHARED / "specs" / "ladder_spec.md"
GRID = SHARED / "bench" / "ladder_grid.yaml"
SHIPPED = ("default", "default_perturbed", "vertical", "a_frame", "ship", "stairs", "caged")


def valid_doc() -> dict:
    """A complete valid document touching every block (rect treads so that `depth` matters)."""
    return {
        "name": "fixture",
        "ladder": {
            "type": "ship", "inclination_deg": 60.0, "rung_spacing": 0.25, "n_rungs": 8,
            "first_rung_height": 0.25, "rung_width": 0.80,
            "rung": {"shape": "rect", "depth": 0.17, "thickness": 0.04},
            "stringer": {"width": 0.08, "depth": 0.03},
            "rails": [{"side": "left", "height": 1.0, "diameter": 0.04},
                      {"side": "right", "height": 1.0, "diameter": 0.04}],
            "top_platform": {"depth": 1.0},
            "a_frame": {"back_inclination_deg": 75.0},
            "friction": 0.25,
            "pose": {"x": 0.45, "y": 0.0, "yaw_deg": 0.0},
            "obstacles": [{"size": [0.05, 0.9, 2.0], "position": [2.0, 0.0, 1.0], "rpy_deg": [0, 0, 0]}],
        },
        "perturbation": {
            "rung_offsets": [{"rung": 3, "dz": 0.02, "dx": 0.0}],
            "rails_dy": 0.0,
            "drops": [{"mass": 10.0, "radius": 0.12, "speed": 5.5, "at_time": 12.0, "target_link": "torso"}],
        },
    }


DELETE = object()


def mutated(path: str, value) -> dict:
    """valid_doc() with `path` (dotted, with [i] indices) set to `value` (or deleted)."""
    doc = valid_doc()
    tokens = [t for t in re.split(r"\.|\[(\d+)\]", path) if t]
    keys = [int(t) if t.isdigit() else t for t in tokens]
    node = doc
    for key in keys[:-1]:
        node = node[key]
    if value is DELETE:
        del node[keys[-1]]
    else:
        node[keys[-1]] = value
    return doc


# (id, path to change, new value, field named in the error, words of the rule)
RULES = [
    # unknown type
    ("unknown_type", "ladder.type", "rope", "ladder.type", "must be one of"),
    # inclination: ladders (45, 90], stairs [20, 50], vertical = 90
    ("ladder_incl_45", "ladder.inclination_deg", 45.0, "ladder.inclination_deg", "(45, 90]"),
    ("ladder_incl_90.5", "ladder.inclination_deg", 90.5, "ladder.inclination_deg", "(45, 90]"),
    ("ladder_incl_30", "ladder.inclination_deg", 30, "ladder.inclination_deg", "(45, 90]"),
    ("a_frame_back_incl", "ladder.a_frame.back_inclination_deg", 40.0, "ladder.a_frame.back_inclination_deg",
     "(45, 90]"),
    # non-positive sizes
    ("rung_width_0", "ladder.rung_width", 0.0, "ladder.rung_width", "> 0"),
    ("first_rung_height_neg", "ladder.first_rung_height", -0.1, "ladder.first_rung_height", "> 0"),
    ("tread_depth_neg", "ladder.rung.depth", -0.17, "ladder.rung.depth", "> 0"),
    ("tread_thickness_0", "ladder.rung.thickness", 0, "ladder.rung.thickness", "> 0"),
    ("stringer_width_0", "ladder.stringer.width", 0.0, "ladder.stringer.width", "> 0"),
    ("stringer_depth_neg", "ladder.stringer.depth", -0.03, "ladder.stringer.depth", "> 0"),
    ("rail_height_0", "ladder.rails[1].height", 0.0, "ladder.rails[1].height", "> 0"),
    ("rail_diameter_neg", "ladder.rails[0].diameter", -0.04, "ladder.rails[0].diameter", "> 0"),
    ("platform_depth_0", "ladder.top_platform.depth", 0.0, "ladder.top_platform.depth", "> 0"),
    ("obstacle_size_0", "ladder.obstacles[0].size", [0.05, 0.0, 2.0], "ladder.obstacles[0].size[1]", "> 0"),
    ("drop_mass_0", "perturbation.drops[0].mass", 0.0, "perturbation.drops[0].mass", "> 0"),
    ("drop_radius_neg", "perturbation.drops[0].radius", -0.1, "perturbation.drops[0].radius", "> 0"),
    ("drop_speed_0", "perturbation.drops[0].speed", 0.0, "perturbation.drops[0].speed", "> 0"),
    ("drop_time_neg", "perturbation.drops[0].at_time", -1.0, "perturbation.drops[0].at_time", ">= 0"),
    ("drop_transition_neg", "perturbation.drops[0].at_transition", -1, "perturbation.drops[0].at_transition", ">= 0"),
    ("drop_transition_float", "perturbation.drops[0].at_transition", 2.5, "perturbation.drops[0].at_transition",
     "integer"),
    ("drop_direction_zero", "perturbation.drops[0].direction", [0.0, 0.0, 0.0], "perturbation.drops[0].direction",
     "non-zero"),
    ("drop_direction_short", "perturbation.drops[0].direction", [1.0, 0.0], "perturbation.drops[0].direction", "3"),
    # n_rungs >= 2, integer
    ("n_rungs_1", "ladder.n_rungs", 1, "ladder.n_rungs", "[2, "),
    ("n_rungs_float", "ladder.n_rungs", 2.5, "ladder.n_rungs", "integer"),
    ("n_rungs_huge", "ladder.n_rungs", MAX_RUNGS + 1, "ladder.n_rungs", f"{MAX_RUNGS}]"),
    # rung_spacing in [0.15, 0.50]
    ("spacing_low", "ladder.rung_spacing", 0.149, "ladder.rung_spacing", "[0.15, 0.5]"),
    ("spacing_high", "ladder.rung_spacing", 0.51, "ladder.rung_spacing", "[0.15, 0.5]"),
    # rect without depth
    ("rect_without_depth", "ladder.rung", {"shape": "rect", "thickness": 0.04}, "ladder.rung.depth",
     "required when rung.shape is rect"),
    ("unknown_shape", "ladder.rung.shape", "oval", "ladder.rung.shape", "circle, rect"),
    # rails
    ("rail_unknown_side", "ladder.rails[1].side", "middle", "ladder.rails[1].side", "left, right"),
    ("rail_side_twice", "ladder.rails[1].side", "left", "ladder.rails[1].side", "given twice"),
    ("rail_without_side", "ladder.rails[0].side", DELETE, "ladder.rails[0].side", "required"),
    # friction in (0, 2]
    ("friction_0", "ladder.friction", 0.0, "ladder.friction", "(0, 2]"),
    ("friction_neg", "ladder.friction", -0.3, "ladder.friction", "(0, 2]"),
    ("friction_2.01", "ladder.friction", 2.01, "ladder.friction", "(0, 2]"),
    ("ground_friction_3", "ladder.ground_friction", 3.0, "ladder.ground_friction", "(0, 2]"),
    # NaN / inf anywhere
    ("nan_pose", "ladder.pose.x", float("nan"), "ladder.pose.x", "finite"),
    ("inf_rails_dy", "perturbation.rails_dy", float("inf"), "perturbation.rails_dy", "finite"),
    ("neg_inf_in_list", "ladder.obstacles[0].position", [2.0, 0.0, float("-inf")],
     "ladder.obstacles[0].position[2]", "finite"),
    ("nan_friction", "ladder.friction", float("nan"), "ladder.friction", "finite"),
    ("nan_in_ignored_field", "ladder.a_frame.back_inclination_deg", float("nan"),
     "ladder.a_frame.back_inclination_deg", "finite"),
    ("absurd_magnitude", "ladder.pose.y", 1.0e300, "ladder.pose.y", "magnitude"),
    ("absurd_int", "ladder.n_rungs", 10 ** 400, "ladder.n_rungs", "magnitude"),
    # unknown keys, at every level
    ("unknown_top_level", "ladders", {}, "ladders", "unknown key"),
    ("unknown_in_ladder", "ladder.rung_spacng", 0.25, "ladder.rung_spacng", "unknown key"),
    ("unknown_in_rung", "ladder.rung.diamter", 0.04, "ladder.rung.diamter", "unknown key"),
    ("unknown_in_rail", "ladder.rails[1].hieght", 1.0, "ladder.rails[1].hieght", "unknown key"),
    ("unknown_in_pose", "ladder.pose.z", 0.0, "ladder.pose.z", "unknown key"),
    ("unknown_in_drop", "perturbation.drops[0].mas", 5.0, "perturbation.drops[0].mas", "unknown key"),
    ("unknown_in_perturbation", "perturbation.rung_offset", [], "perturbation.rung_offset", "unknown key"),
    # wrong types
    ("string_for_number", "ladder.friction", "0.25", "ladder.friction", "must be a number"),
    ("bool_for_number", "ladder.n_rungs", True, "ladder.n_rungs", "must be a number"),
    ("list_for_mapping", "ladder.rung", [0.04], "ladder.rung", "must be a mapping"),
    ("string_for_mapping", "ladder.pose", "0.45", "ladder.pose", "must be a mapping"),
    ("mapping_for_list", "ladder.rails", {"side": "left"}, "ladder.rails", "must be a list"),
    ("number_for_rail", "ladder.rails[0]", 1.0, "ladder.rails[0]", "must be a mapping"),
    ("short_vector", "ladder.obstacles[0].size", [1.0, 2.0], "ladder.obstacles[0].size", "3 numbers"),
    ("number_for_type", "ladder.type", 3, "ladder.type", "must be one of"),
    ("number_for_link", "perturbation.drops[0].target_link", 7, "perturbation.drops[0].target_link", "string"),
    ("empty_link", "perturbation.drops[0].target_link", " ", "perturbation.drops[0].target_link", "non-empty"),
    ("number_for_name", "name", 12, "name", "string"),
    # required blocks / fields
    ("missing_ladder", "ladder", DELETE, "ladder", "required"),
    ("null_ladder", "ladder", None, "ladder", "required"),
    ("missing_obstacle_position", "ladder.obstacles[0].position", DELETE, "ladder.obstacles[0].position",
     "required"),
    # the project's planner_overrides: dotted names to scalars (the planner checks names and values)
    ("overrides_list", "planner_overrides", ["timing.max_joint_speed"], "planner_overrides", "must be a mapping"),
    ("overrides_undotted", "planner_overrides", {"timeout_s": 10.0}, "planner_overrides.timeout_s", "group.field"),
    ("overrides_nested_value", "planner_overrides", {"timing.max_joint_speed": [0.2]},
     "planner_overrides.timing.max_joint_speed", "a number, a bool or a string"),
    ("overrides_nan", "planner_overrides", {"timing.max_joint_speed": float("nan")},
     "planner_overrides.timing.max_joint_speed", "finite"),
    # perturbation references
    ("offset_rung_above_top", "perturbation.rung_offsets[0].rung", 9, "perturbation.rung_offsets[0].rung",
     "n_rungs = 8"),
    ("offset_rung_0", "perturbation.rung_offsets[0].rung", 0, "perturbation.rung_offsets[0].rung", ">= 1"),
    ("offset_rung_twice", "perturbation.rung_offsets", [{"rung": 2}, {"rung": 2, "dz": 0.01}],
     "perturbation.rung_offsets[1].rung", "given twice"),
]


@pytest.mark.parametrize("path,value,field,rule", [r[1:] for r in RULES], ids=[r[0] for r in RULES])
def test_every_rule_raises_a_spec_error_naming_the_field(path, value, field, rule):
    assert parse_scenario(valid_doc()).ladder.type == "ship"  # the unmutated fixture is valid
    with pytest.raises(SpecError) as info:
        parse_scenario(mutated(path, value))
    assert info.value.field == field
    assert rule in info.value.rule, info.value.rule
    assert str(info.value).startswith(f"{field}: ")


CROSS_RULES = [
    # (id, ladder overrides, field, rule words)
    ("stairs_19.9", {"type": "stairs", "inclination_deg": 19.9}, "ladder.inclination_deg", "[20, 50]"),
    ("stairs_50.1", {"type": "stairs", "inclination_deg": 50.1}, "ladder.inclination_deg", "[20, 50]"),
    ("stairs_75", {"type": "stairs", "inclination_deg": 75.0}, "ladder.inclination_deg", "[20, 50]"),
    ("vertical_85", {"type": "vertical", "inclination_deg": 85.0}, "ladder.inclination_deg", "vertical"),
    ("circle_without_diameter", {"rung": {"shape": "circle"}}, "ladder.rung.diameter",
     "required when rung.shape is circle"),
    ("default_shape_without_diameter", {"rung": {"thickness": 0.04}}, "ladder.rung.diameter", "circle"),
    ("circle_diameter_0", {"rung": {"shape": "circle", "diameter": 0.0}}, "ladder.rung.diameter", "> 0"),
]


@pytest.mark.parametrize("overrides,field,rule", [r[1:] for r in CROSS_RULES], ids=[r[0] for r in CROSS_RULES])
def test_type_and_shape_dependent_rules(overrides, field, rule):
    doc = {"ladder": dict(overrides)}
    with pytest.raises(SpecError) as info:
        parse_scenario(doc)
    assert (info.value.field, rule in info.value.rule) == (field, True), info.value


@pytest.mark.parametrize("ladder_type,inclination", [("stairs", 20.0), ("stairs", 50.0), ("regular", 90.0),
                                                     ("regular", 45.001), ("ship", 60.0), ("vertical", 90.0)])
def test_range_bounds_are_accepted(ladder_type, inclination):
    spec = parse_scenario({"ladder": {"type": ladder_type, "inclination_deg": inclination}}).ladder
    assert spec.inclination_deg == inclination


@pytest.mark.parametrize("text,rule", [
    ("ladder: {type: regular\n", "YAML syntax error"),
    ("ladder:\n  type: regular\n type: ship\n", "YAML syntax error"),
    ("- 1\n- 2\n", "must be a mapping, got list"),
    ("42\n", "must be a mapping, got int"),
    ("just some words: [\n", "YAML syntax error"),
    ("\n", "must be a mapping, got null"),
    ("ladder: {}\n---\nladder: {}\n", "YAML"),
    ("when: 2020-13-45\n", "cannot read YAML"),
])
def test_yaml_problems_are_spec_errors_on_the_document(text, rule):
    with pytest.raises(SpecError) as info:
        load_scenario(text)
    assert info.value.field == "document"
    assert rule in info.value.rule


def test_defaults_fill_every_missing_field():
    spec = parse_scenario({"ladder": {}}).ladder
    assert spec.type == DEFAULTS["ladder.type"] == "regular"
    assert spec.inclination_deg == 75.0
    assert (spec.rung_spacing, spec.n_rungs) == (DEFAULTS["ladder.rung_spacing"], DEFAULTS["ladder.n_rungs"])
    assert spec.first_rung_height == DEFAULTS["ladder.first_rung_height"] == 0.25
    assert spec.rung_width == DEFAULTS["ladder.rung_width"] == 0.50
    assert (spec.rung.shape, spec.rung.diameter, spec.rung.depth) == ("circle", 0.04, None)
    assert (spec.stringer_width, spec.stringer_depth) == (DEFAULTS["ladder.stringer.width"],
                                                          DEFAULTS["ladder.stringer.depth"])
    assert spec.rails == () and spec.obstacles == ()
    assert spec.top_platform_depth is None and spec.back_inclination_deg is None
    assert spec.friction == DEFAULTS["ladder.friction"] == 0.25
    assert spec.ground_friction == DEFAULTS["ladder.ground_friction"] == 0.8
    assert (spec.pose_x, spec.pose_y, spec.pose_yaw_deg) == (0.45, 0.0, 0.0)
    scenario = parse_scenario({"ladder": {}})
    assert scenario.perturbation.is_empty and scenario.name == ""


def test_type_dependent_defaults_and_nested_defaults():
    assert parse_scenario({"ladder": {"type": "vertical"}}).ladder.inclination_deg == 90.0
    assert parse_scenario({"ladder": {"type": "stairs"}}).ladder.inclination_deg == 35.0
    assert parse_scenario({"ladder": {"type": "ship"}}).ladder.inclination_deg == 60.0
    a_frame = parse_scenario({"ladder": {"type": "a_frame"}}).ladder
    assert a_frame.back_inclination_deg == 75.0
    rails = parse_scenario({"ladder": {"rails": [{"side": "right"}]}}).ladder.rails
    assert (rails[0].side, rails[0].height, rails[0].diameter) == ("right", 1.0, 0.04)
    platform = parse_scenario({"ladder": {"top_platform": {}}}).ladder
    assert (platform.top_platform_depth, platform.top_platform_thickness) == (1.0, 0.05)
    rect = parse_scenario({"ladder": {"rung": {"shape": "rect", "depth": 0.17}}}).ladder.rung
    assert (rect.thickness, rect.half_depth, rect.half_height) == (0.04, 0.085, 0.02)
    drop = parse_scenario({"ladder": {}, "perturbation": {"drops": [{}]}}).perturbation.drops[0]
    assert (drop.mass, drop.radius, drop.speed, drop.at_time, drop.target_link) == (10.0, 0.12, 5.5, 0.0, "torso")
    # extension: no direction = the simulator's (down), no at_transition = at at_time
    assert (drop.direction, drop.at_transition, drop.on_transition) == ((), 0, False)
    aimed = parse_scenario({"ladder": {}, "perturbation": {"drops": [{"direction": [3.0, 0.0, -4.0],
                                                                       "at_transition": 10}]}}).perturbation.drops[0]
    assert aimed.direction == pytest.approx((0.6, 0.0, -0.8)) and aimed.on_transition
    # null means "absent" (YAML `key:` with nothing after it)
    nulls = parse_scenario(yaml.safe_load("ladder:\n  friction:\n  rails:\n  top_platform:\nperturbation:\n"))
    assert nulls.ladder.friction == 0.25 and nulls.ladder.rails == () and nulls.ladder.top_platform_depth is None


def test_the_specs_own_example_is_accepted():
    text = SPEC_MD.read_text()
    block = re.search(r"```yaml\n(.*?)```", text, re.S).group(1)
    scenario = load_scenario(block)
    ladder = scenario.ladder
    assert (ladder.type, ladder.inclination_deg, ladder.rung_spacing, ladder.n_rungs) == ("regular", 75.0, 0.25, 8)
    assert (ladder.rung.shape, ladder.rung.diameter, ladder.rung.depth, ladder.rung.thickness) == \
        ("circle", 0.04, 0.17, 0.04)
    assert ladder.rail_sides == ("left", "right") and ladder.top_platform_depth == 1.0
    assert ladder.back_inclination_deg is None  # the a_frame block only applies to a_frame ladders
    assert ladder.obstacles[0].size == (0.05, 0.9, 2.0) and ladder.obstacles[0].position == (0.9, 0.0, 1.5)
    pert = scenario.perturbation
    assert pert.rung_offsets[0].rung == 3 and pert.rung_offsets[0].dz == 0.02
    assert pert.drops[0].mass == 10.0 and pert.drops[0].target_link == "torso"


def test_every_shipped_config_parses_has_a_leading_comment_and_builds():
    assert set(SHIPPED) <= set(available_ladders())
    for name in available_ladders():
        path = ROOT / "config" / "ladders" / f"{name}.yaml"
        assert path.read_text().startswith("# "), f"{name}.yaml needs a leading comment saying what it is"
        scenario = load_scenario(name)
        assert scenario.name == name
        env = build_environment(scenario, perturbed=True)
        assert env.n_rungs == scenario.ladder.n_rungs >= 2


def test_shipped_families_match_their_descriptions():
    ship = load_scenario("ship").ladder
    assert (ship.type, ship.inclination_deg, ship.rung_width, ship.rung.shape, ship.rung.depth,
            ship.rung_spacing) == ("ship", 60.0, 0.80, "rect", 0.17, 0.25)
    assert sorted((r.side, r.height) for r in ship.rails) == [("left", 1.0), ("right", 1.0)]
    assert ship.top_platform_depth is not None
    stairs = load_scenario("stairs").ladder
    assert stairs.type == "stairs" and stairs.inclination_deg == 35.0 and len(stairs.rails) == 2
    assert load_scenario("vertical").ladder.inclination_deg == 90.0
    assert load_scenario("a_frame").ladder.back_inclination_deg is not None
    caged = load_scenario("caged").ladder
    assert caged.type == "vertical" and len(caged.obstacles) >= 8
    default = load_scenario("default").ladder
    assert (default.type, default.inclination_deg, default.rung_spacing, default.n_rungs, default.rung.diameter,
            default.rung_width, default.friction) == ("regular", 75.0, 0.25, 8, 0.04, 0.50, 0.25)
    assert default.top_platform_depth is not None


def test_default_perturbed_is_the_default_ladder_plus_perturbations():
    nominal, perturbed = load_scenario("default"), load_scenario("default_perturbed")
    assert perturbed.ladder == nominal.ladder
    offsets = perturbed.perturbation.rung_offsets
    assert [(o.rung, o.dx, o.dz) for o in offsets] == [(2, 0.0, 0.02)]
    (drop,) = perturbed.perturbation.drops
    assert (drop.mass, drop.speed) == (10.0, 5.5)


def test_bench_grid_base_parses_over_the_whole_grid():
    grid = yaml.safe_load(GRID.read_text())
    count = 0
    for i in range(21):
        for j in range(16):
            doc = copy.deepcopy(grid["base"])
            doc["ladder"]["inclination_deg"] = 70 + i * 1
            doc["ladder"]["rung_spacing"] = 0.20 + j * 0.01  # accumulated rounding stays valid
            spec = parse_scenario(doc).ladder
            assert math.isclose(spec.rung_spacing, 0.20 + j * 0.01)
            count += 1
    assert count == 336
    assert parse_scenario(grid["base"]).ladder.inclination_deg == 75.0  # type default when the grid omits it


def test_every_input_form(tmp_path, monkeypatch):
    by_name = load_scenario("ship")
    path = ROOT / "config" / "ladders" / "ship.yaml"
    assert load_scenario(path) == by_name
    assert load_scenario(str(path)) == by_name
    monkeypatch.chdir(tmp_path)  # relative paths are tried against the project root too
    assert load_scenario("config/ladders/ship.yaml") == by_name
    text = path.read_text()
    from_text = load_scenario(text)
    assert from_text.ladder == by_name.ladder and from_text.name == ""
    assert load_scenario(yaml.safe_load(text)).ladder == by_name.ladder
    assert load_scenario(by_name) is by_name
    assert parse_scenario({"name": "mine", "ladder": {}}).name == "mine"
    assert parse_scenario({"name": "mine", "ladder": {}}, name="given").name == "given"
    copy_path = tmp_path / "my_ladder.yml"
    copy_path.write_text(text)
    assert load_scenario(copy_path).name == "my_ladder"


@pytest.mark.parametrize("source,field,rule", [
    ("no_such_ladder", "source", "no ladder named"),
    ("/nonexistent/dir/ladder.yaml", "source", "file not found"),
    (3.5, "source", "expected a name"),
    (["ladder"], "source", "expected a name"),
])
def test_bad_sources(source, field, rule):
    with pytest.raises(SpecError) as info:
        load_scenario(source)
    assert info.value.field == field and rule in info.value.rule


def test_unreadable_file_is_a_spec_error(tmp_path):
    bad = tmp_path / "latin1.yaml"
    bad.write_bytes(b"ladder: {type: \xe9chelle}\n")
    with pytest.raises(SpecError) as info:
        load_scenario(bad)
    assert info.value.field == "source"


@pytest.mark.parametrize("name", SHIPPED)
def test_round_trip_through_dict_and_yaml(name):
    scenario = load_scenario(name)
    assert parse_scenario(scenario.to_dict()) == scenario
    assert load_scenario(scenario.to_yaml()) == scenario


def test_numpy_and_integer_inputs_are_numbers():
    np = pytest.importorskip("numpy")
    spec = parse_scenario({"ladder": {"n_rungs": np.int64(5), "rung_width": np.float32(0.5), "friction": 1,
                                      "obstacles": [{"size": np.array([1.0, 1.0, 1.0]),
                                                     "position": (3, 0, 0.5)}]}}).ladder
    assert spec.n_rungs == 5 and isinstance(spec.n_rungs, int)
    assert spec.friction == 1.0 and isinstance(spec.friction, float)
    assert spec.obstacles[0].position == (3.0, 0.0, 0.5)
    assert isinstance(spec, LadderSpec)


def test_cyclic_input_is_a_spec_error_not_a_hang():
    doc: dict = {"ladder": {}}
    doc["ladder"]["rung"] = doc  # a cycle, also what YAML `&a [*a]` can build
    with pytest.raises(SpecError) as info:
        parse_scenario(doc)
    assert info.value.field.startswith("ladder.rung")
    assert isinstance(load_scenario(yaml.safe_dump({"ladder": {}})), Scenario)
    with pytest.raises(SpecError):
        load_scenario("ladder: &a [*a]\n")


# ---------------------------------------------------------------------------------------------
# Property tests: garbage in, SpecError (or a valid scenario that builds) out, never anything else.
# ---------------------------------------------------------------------------------------------

KEYS = sorted({part for path in DEFAULTS for part in re.split(r"\.|\[i\]\.?", path) if part}
              | {"ladder", "perturbation", "bogus", ""})
SCALARS = st.one_of(
    st.none(), st.booleans(), st.integers(min_value=-10 ** 30, max_value=10 ** 30),
    st.floats(allow_nan=True, allow_infinity=True), st.floats(min_value=-2, max_value=100),
    st.text(max_size=8), st.sampled_from(["regular", "vertical", "a_frame", "ship", "stairs", "circle", "rect",
                                          "left", "right", "torso"]),
)
GARBAGE = st.recursive(
    SCALARS,
    lambda children: st.one_of(st.lists(children, max_size=4),
                               st.dictionaries(st.one_of(st.sampled_from(KEYS), st.integers(), st.text(max_size=5)),
                                               children, max_size=5)),
    max_leaves=25,
)


def _accept_or_spec_error(document) -> None:
    try:
        scenario = parse_scenario(document)
    except SpecError as exc:
        assert exc.field and exc.rule
        return
    env = build_environment(scenario, perturbed=True)  # whatever validates must also build
    for surface in env.surfaces.values():
        assert all(math.isfinite(v) for v in surface.T_world_surface.ravel())


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(GARBAGE)
def test_random_documents_only_raise_spec_errors(document):
    _accept_or_spec_error(document)
    _accept_or_spec_error({"ladder": document})


LEAF_PATHS = [r[1] for r in RULES if not r[1].startswith("ladders")] + ["ladder", "perturbation",
                                                                        "ladder.rails", "ladder.obstacles[0]"]


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.sampled_from(LEAF_PATHS), GARBAGE)
def test_garbage_anywhere_in_a_valid_document_only_raises_spec_errors(path, value):
    _accept_or_spec_error(mutated(path, value))


YAML_TOKENS = st.sampled_from(["ladder:", "\n", "  ", "type:", " regular", "{", "}", "[", "]", ",", "-", ".nan",
                               "-.inf", "0.25", "n_rungs:", " 3", "rung:", "&a", "*a", "!!set", "? ", "'", '"',
                               "#", "perturbation:", "drops:", "2020-13-45", "~", "\t", "%YAML 1.1", "---"])


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.one_of(st.text(max_size=60), st.lists(YAML_TOKENS, max_size=25).map("".join)))
def test_random_yaml_text_only_raises_spec_errors(text):
    try:
        load_scenario("ladder:\n" + text)
        load_scenario(text)
    except SpecError as exc:
        assert exc.field and exc.rule


@settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(GARBAGE)
def test_random_documents_as_yaml_text_only_raise_spec_errors(document):
    try:
        load_scenario(yaml.safe_dump({"ladder": document}))
    except SpecError as exc:
        assert exc.field and exc.rule
