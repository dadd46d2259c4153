"""Variant libraries: per-variant design overrides (design.yaml `variants:`), `same_as` primitive
copies, partial variants (`fallback: main`) that the loader accepts and the planner completes from
the main library. Pure data tests (no IK): well under a second."""
from __future__ import annotations

import importlib.util
import pathlib

import pytest

from climb_core.errors import SpecError
from planner_node.primitives import library_dir, load_design, load_library, load_variants, rank_variants

ROOT = pathlib.Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def mk():
    spec = importlib.util.spec_from_file_location("make_primitives", ROOT / "scripts" / "make_primitives.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_variant_overrides_merge_only_for_their_reference(mk):
    design = {"holds": {"mount_rung": 4, "hand_s": 0.12},
              "primitives": {"a": {"kind": "com", "base_above_feet": [0, 0, 0.7], "com_offset": [-0.1, 0.0]}},
              "variants": {"85/0.3": {"holds": {"mount_rung": 3},
                                      "primitives": {"a": {"base_above_feet": None, "com_offset": [-0.2, 0.0]}}}}}
    over = mk.variant_overrides(design, "85/0.30")  # numeric key match: 0.3 == 0.30
    merged = mk.merge_design(design, over)
    assert merged["holds"] == {"mount_rung": 3, "hand_s": 0.12}  # mapping merged key by key
    assert "base_above_feet" not in merged["primitives"]["a"]  # null deletes
    assert merged["primitives"]["a"]["com_offset"] == [-0.2, 0.0]  # lists replaced
    assert mk.variant_overrides(design, "") == {}  # the main library never reads the section
    assert mk.variant_overrides(design, "80/0.30") == {}
    assert design["holds"]["mount_rung"] == 4  # the input design is not modified
    with pytest.raises(SpecError, match="reference"):
        mk.variant_overrides(design, "85/x")


def test_same_as_copies_a_primitive_and_rejects_cycles(mk):
    design = {"primitives": {"p": {"kind": "limb", "limb": "left_foot", "via": [1]},
                             "p_first": {"same_as": "p", "via": [2]},
                             "loop_a": {"same_as": "loop_b"}, "loop_b": {"same_as": "loop_a"}}}
    assert mk.primitive_spec(design, "p_first") == {"kind": "limb", "limb": "left_foot", "via": [2]}
    with pytest.raises(SpecError, match="same_as"):
        mk.primitive_spec(design, "loop_a")
    with pytest.raises(SpecError, match="not defined"):
        mk.primitive_spec(design, "missing")


def test_main_design_has_no_effect_on_the_main_library_build(mk):
    """Building the main library (no --reference) drops the `variants` section entirely."""
    design = load_design("g1", "forward")
    assert mk.variant_overrides(design, "") == {}
    base = {k: v for k, v in design.items() if k != "variants"}
    assert mk.merge_design(base, {}) == base


def test_every_shipped_variant_loads_and_the_main_library_ranks_first_on_the_default_ladder():
    libs = load_variants("g1", "forward")
    assert libs[0].path.name == "library.yaml"
    main_names = set(libs[0].primitives)
    for lib in libs[1:]:
        # a variant (possibly partial) only holds primitives the main library's sequence knows
        assert set(lib.primitives) <= main_names | {n for n in lib.primitives if n.endswith("_first")}
    assert rank_variants(libs, 75.0, 0.25)[0].path.name == "library.yaml"


def test_partial_variant_file_loads_without_sequences(tmp_path):
    main = library_dir("g1", "forward") / "library.yaml"
    text = main.read_text()
    # cut the sequences to nothing: a variant may be partial, the main library may not
    import yaml

    data = yaml.safe_load(text)
    data["sequences"] = {}
    data["primitives"] = {k: v for k, v in data["primitives"].items() if k.startswith("place_")}
    (tmp_path / "library_80_0.25.yaml").write_text(yaml.safe_dump(data))
    lib = load_library(path=tmp_path / "library_80_0.25.yaml")
    assert lib.sequences == {} and all(n.startswith("place_") for n in lib.primitives)
    (tmp_path / "library.yaml").write_text(yaml.safe_dump(data))
    with pytest.raises(SpecError, match="mount"):
        load_library(path=tmp_path / "library.yaml")


def test_partial_variant_without_its_mount_keeps_no_sequence(mk):
    design = {"approach": ["a1"], "mount": ["m1", "m2"], "cycle": ["c1", "c2"]}
    # a variant that lost a mount primitive: the planner must take the main library's sequence
    assert mk._stored_sequences(design, {"a1": 0, "m1": 0, "c1": 0, "c2": 0}, variant=True) == {}
    whole = mk._stored_sequences(design, {"a1": 0, "m1": 0, "m2": 0, "c1": 0, "c2": 0}, variant=True)
    assert whole == {"approach": ("a1",), "mount": ("m1", "m2"), "cycle": ("c1", "c2")}
    # only feet / CoM primitives: no sequence either
    assert mk._stored_sequences(design, {"c1": 0}, variant=True) == {}


def test_wide_rung_variants_shipped_and_ranked_for_wide_ladders():
    libs = {lib.path.name: lib for lib in load_variants("g1", "forward")}
    wide = libs["library_75_0.35.yaml"]
    assert wide.holds["hands_above_feet_rungs"] == 3 and wide.holds["mount_rung"] == 3
    assert wide.sequences.get("cycle") and wide.sequences.get("mount")
    steep = libs["library_84_0.32.yaml"]  # partial: no hand placement of its own, no cycle (the main one's runs)
    assert not steep.sequences.get("cycle") and "place_left_hand" not in steep.primitives
    assert "place_right_foot" in steep.primitives
    assert rank_variants(list(libs.values()), 74.0, 0.35)[0].path.name == "library_75_0.35.yaml"
    assert rank_variants(list(libs.values()), 84.0, 0.33)[0].path.name == "library_84_0.32.yaml"
