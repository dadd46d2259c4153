"""Rectangular rungs (issue 18): the hand's grasp around a rect bar within the Dex3 hand's size
limit (8 points on the bar's faces and edges), the foot across it (the paper's Fig. 6: the 4
corners of the top face under the sole), the refusal of bars too big for the hand with the field
and the limit, and the 2-step plan of a regular ladder with the 4 x 3 cm rungs of
shared/bench/ladder_grid_rect.yaml (config/ladders/rect_rungs.yaml)."""
from __future__ import annotations

import json
import pathlib
import subprocess
import sys

import numpy as np
import pytest

from climb_core import feasibility, holds
from climb_core.contact import FEET, HANDS
from climb_core.environment import build_environment
from climb_core.errors import SpecError
from climb_core.ladder import load_scenario

ROOT = pathlib.Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def rect():
    return build_environment(load_scenario("rect_rungs"))


def _rect_ladder(depth: float, thickness: float):
    raw = {"ladder": {"type": "regular", "rung": {"shape": "rect", "depth": depth, "thickness": thickness}}}
    return build_environment(load_scenario(raw))


def _local(surface, points):
    """Points in the surface frame (x along the bar, y toward the robot, z up)."""
    T = surface.T_world_surface
    return (np.asarray(points) - T[:3, 3]) @ T[:3, :3]


def test_rect_rungs_of_a_regular_ladder_are_bars_hands_and_feet_may_use(rect):
    rung = rect.rung(3)
    assert (rung.role, rung.shape, rung.bilateral, rung.contact_limbs) == ("rung", "box", True, ("foot", "hand"))
    assert rung.length == pytest.approx(0.50)  # the rung width, along its axis
    assert holds.bar_section(rung) == pytest.approx((0.04, 0.03))
    assert holds.is_bar(rung)
    ship = build_environment(load_scenario("ship"))  # ship / stairs treads stay feet-only flat surfaces
    assert ship.rung(1).role == "tread" and not ship.rung(1).bilateral and not holds.is_bar(ship.rung(1))


def test_dex3_bar_limit_comes_from_the_config(g1):
    for hand in HANDS:
        assert g1.config.limbs[hand].surface.max_bar == (0.047, 0.052)


@pytest.mark.parametrize("limb", HANDS)
def test_grasp_on_a_rect_bar_is_eight_points_on_its_faces_and_edges(g1, rect, limb):
    rung = rect.rung(5)
    hold = holds.make_hold(g1, rect, limb, "rung_5", s=0.1)
    assert hold.bilateral and hold.grip_force_limit == g1.config.grip_strength and len(hold.points) == 8
    local = _local(rung, hold.positions)
    hx, hy, hz = rung.half_extents
    spacing = holds.HoldParams().grasp_ring_spacing
    # two rings of four, grasp_ring_spacing apart along the bar, centred at s
    np.testing.assert_allclose(np.sort(local[:, 0]), [0.1 - spacing / 2] * 4 + [0.1 + spacing / 2] * 4, atol=1e-12)
    ring1, ring2 = local[:4], local[4:]
    # ring 1: the four face centres of the cross-section, normals the face normals
    expected_faces = {(hy, 0.0), (0.0, hz), (-hy, 0.0), (0.0, -hz)}
    assert {(round(y, 9), round(z, 9)) for _, y, z in ring1} == {(round(y, 9), round(z, 9)) for y, z in expected_faces}
    # ring 2: the four edges (corners of the cross-section), normals the diagonals
    assert {(round(y, 9), round(z, 9)) for _, y, z in ring2} == {(round(sy * hy, 9), round(sz * hz, 9))
                                                                 for sy in (1, -1) for sz in (1, -1)}
    R = rung.T_world_surface[:3, :3]
    for p, cp in zip(local, hold.points):
        n_local = R.T @ cp.normal
        assert np.linalg.norm(cp.normal) == pytest.approx(1.0)
        assert abs(n_local[0]) < 1e-12  # across the bar
        # every point on the bar's surface, its normal pointing outward
        assert max(abs(p[1]) - hy, abs(p[2]) - hz) == pytest.approx(0.0, abs=1e-12)
        assert n_local[1:] @ p[1:] > 0.0


@pytest.mark.parametrize("limb", HANDS)
def test_grasp_target_on_a_bar_axis_along_the_bar_palm_on_the_robot_side(g1, rect, limb):
    rung = rect.rung(5)
    hold = holds.make_hold(g1, rect, limb, "rung_5", s=-0.08)
    target = holds.hold_target(g1, rect, hold)
    assert target.kind == "grasp" and target.free_axis_in_surface is not None
    T = target.T_world_surface
    rs = g1.config.limbs[limb].surface
    axis_w = T[:3, :3] @ holds.grasp_axis_in_surface(rs)
    assert abs(axis_w @ rung.axis) == pytest.approx(1.0, abs=1e-9)  # grasp axis along the bar
    np.testing.assert_allclose(_local(rung, T[:3, 3][None])[0], [-0.08, 0.0, 0.0], atol=1e-9)  # on its centre line
    # the palm normal points from the robot's side toward the bar, 30 deg above the horizontal
    normal = T[:3, 2]
    toward_ladder = np.array([1.0, 0.0, 0.0])
    assert normal @ toward_ladder > 0.8
    angle = np.degrees(np.arcsin(-normal[2]))
    assert angle == pytest.approx(holds.HoldParams().grasp_palm_angle_bar_deg, abs=1e-6)
    # the palm (the grasp surface's palm side) is on the robot's side of the bar
    frame_origin = target.T_world_frame[:3, 3]
    assert (frame_origin - rung.position) @ toward_ladder < 0.0


@pytest.mark.parametrize("limb", FEET)
def test_foot_on_a_rect_rung_is_the_four_top_face_corners_under_the_sole(g1, rect, limb):
    rung = rect.rung(2)
    hold = holds.make_hold(g1, rect, limb, "rung_2", s=0.12)
    assert not hold.bilateral and len(hold.points) == 4
    target = holds.hold_target(g1, rect, hold)
    assert target.kind == "sole_bar"
    local = _local(rung, hold.positions)
    hx, hy, hz = rung.half_extents
    _, width = holds.sole_extent(g1.config.limbs[limb].surface)
    # the corners of the top face: across its whole depth, the sole width along the bar around s
    np.testing.assert_allclose(local[:, 2], hz, atol=1e-12)
    assert sorted(np.round(local[:, 1], 12)) == pytest.approx([-hy, -hy, hy, hy])
    assert sorted(np.round(local[:, 0], 12)) == pytest.approx([0.12 - width / 2] * 2 + [0.12 + width / 2] * 2)
    np.testing.assert_allclose(hold.normals, [[0.0, 0.0, 1.0]] * 4, atol=1e-12)
    # the target sole lies on the top face, centred over the bar's centre line at s, and every hold
    # point is under the sole polygon (the core check's contact error is zero there)
    T = target.T_world_surface
    np.testing.assert_allclose(_local(rung, T[:3, 3][None])[0], [0.12, 0.0, hz], atol=1e-9)
    sole = holds.sole_vertices_in_surface(g1.config.limbs[limb].surface)
    in_sole = (hold.positions - T[:3, 3]) @ T[:3, :3]
    assert np.all(np.abs(in_sole[:, 2]) < 1e-9)
    assert np.all((in_sole[:, 0] >= sole[:, 0].min() - 1e-9) & (in_sole[:, 0] <= sole[:, 0].max() + 1e-9))
    assert np.all((in_sole[:, 1] >= sole[:, 1].min() - 1e-9) & (in_sole[:, 1] <= sole[:, 1].max() + 1e-9))


@pytest.mark.parametrize("limb", FEET)
def test_a_foot_on_a_ship_ladder_tread_stands_heel_past_the_nose_on_the_part_it_covers(g1, limb):
    """A tread no deeper than the sole is long (the shipped ship ladder's 17 cm, G1's 17 cm sole)
    takes the Fig. 6 hold too (``sole_bar``), the sole shifted back by ``foot_on_tread_offset``
    (config/feasibility.yaml, 4.5 cm: the heel past the nose, the sole's front under the nose of the
    tread above); its four points span only the depth the sole covers, and the core check's contact
    error is zero at the target. A deeper tread (stairs, 28 cm) stays a flat surface."""
    ship = build_environment(load_scenario("ship"))
    cfg = feasibility.load_config()
    offset = cfg.holds.foot_on_tread_offset
    assert offset == pytest.approx(0.045)
    tread, above = ship.rung(1), ship.rung(2)
    rs = g1.config.limbs[limb].surface
    assert holds.is_sole_bar(tread, rs) and not holds.is_bar(tread)
    hold = holds.make_hold(g1, ship, limb, "rung_1", s=0.12, params=cfg.holds)
    target = holds.hold_target(g1, ship, hold, params=cfg.holds)
    assert target.kind == "sole_bar" and len(hold.points) == 4
    local = _local(tread, hold.positions)  # x along the tread, y toward the robot, z up
    _, hy, hz = tread.half_extents
    length, _ = holds.sole_extent(rs)
    T = target.T_world_surface
    centre = _local(tread, T[:3, 3][None])[0]
    np.testing.assert_allclose(centre, [0.12, offset, hz], atol=1e-9)  # moved back toward the robot
    # the points span the depth the sole covers: from the nose (y = hy) to the sole's front
    assert sorted({round(float(v), 9) for v in local[:, 1]}) == pytest.approx(sorted([hy, offset - length / 2]))
    np.testing.assert_allclose(local[:, 2], hz, atol=1e-12)
    assert offset + length / 2 - hy == pytest.approx(offset)  # the heel past the nose (G1: sole as long as the tread)
    # the sole's front is where the nose of the tread above is, along the ladder
    toe = tread.position + np.asarray(tread.T_world_surface)[:3, 1] * (offset - length / 2)
    above_nose = above.position + np.asarray(above.T_world_surface)[:3, 1] * hy
    forward = holds.ladder_forward(ship)
    assert float((toe - above_nose) @ forward) == pytest.approx(0.0, abs=2e-3)
    # every point under the sole polygon: the core check's contact error is zero at the target
    sole = holds.sole_vertices_in_surface(rs)
    in_sole = (hold.positions - T[:3, 3]) @ T[:3, :3]
    assert np.all(np.abs(in_sole[:, 2]) < 1e-9)
    assert np.all((in_sole[:, 0] >= sole[:, 0].min() - 1e-9) & (in_sole[:, 0] <= sole[:, 0].max() + 1e-9))
    assert np.all((in_sole[:, 1] >= sole[:, 1].min() - 1e-9) & (in_sole[:, 1] <= sole[:, 1].max() + 1e-9))
    stairs = build_environment(load_scenario("stairs"))
    assert not holds.is_sole_bar(stairs.rung(1), rs)
    flat = holds.make_hold(g1, stairs, limb, "rung_1", s=0.0, params=cfg.holds)
    assert holds.hold_kind(g1, stairs, flat) == "sole_flat"


def test_the_four_contact_fixture_holds_the_bars_and_holds_read_back(g1, rect):
    """The ``ladder_4_contacts`` fixture on the rect ladder (feet across a bar, hands around a bar):
    contact error ~0 in the core check, the holds read back from the configuration."""
    from climb_core import fixtures

    stance, q = fixtures.get("ladder_4_contacts", g1, rect)
    assert {holds.hold_kind(g1, rect, h) for h in stance.holds} == {"grasp", "sole_bar"}
    check = feasibility.check(g1, rect, q, stance, collision=False)
    assert check.contact_error < 2e-3, check.summary()
    for h in stance.holds:
        back = holds.hold_from_configuration(g1, rect, q, h.limb, h.env_surface)
        assert np.linalg.norm(back.centre - h.centre) < 3e-3
        assert len(back.points) == len(h.points)


def test_bars_too_big_for_the_hand_are_refused_with_the_field_and_the_limit(g1):
    deep = _rect_ladder(0.08, 0.03)  # the shipped a_frame's 8 cm steps
    with pytest.raises(SpecError) as err:
        holds.make_hold(g1, deep, "left_hand", "rung_3", 0.1)
    assert err.value.field == "ladder.rung.depth"
    assert "0.047 m deep" in err.value.rule and "0.080 m deep" in err.value.rule and "rails" in err.value.rule
    thick = _rect_ladder(0.04, 0.06)
    with pytest.raises(SpecError) as err:
        holds.make_hold(g1, thick, "right_hand", "rung_3", -0.1)
    assert err.value.field == "ladder.rung.thickness" and "0.052 m thick" in err.value.rule
    # the feet still stand on them
    assert len(holds.make_hold(g1, deep, "left_foot", "rung_2", 0.1).points) == 4
    # the rule the searches and the simulator's grasp latch use
    assert not holds.grasp_fits(g1, "left_hand", deep.rung(3))
    assert holds.grasp_fits(g1, "left_hand", _rect_ladder(0.047, 0.052).rung(3))  # the limit itself fits
    ship = build_environment(load_scenario("ship"))
    assert not holds.grasp_fits(g1, "left_hand", ship.rung(2))  # a tread: not bilateral
    with pytest.raises(SpecError) as err:
        holds.check_grasp_fits(g1, "left_hand", ship.rung(2))
    assert err.value.field == "hold.env_surface"


def test_a_hand_without_max_bar_grasps_cylinders_only(rect):
    from climb_core.robot import load_robot

    talos = load_robot("talos")
    assert talos.config.limbs["left_hand"].surface.max_bar is None
    with pytest.raises(SpecError) as err:
        holds.make_hold(talos, rect, "left_hand", "rung_4", 0.1)
    assert err.value.field == "ladder.rung.depth" and "cylinders only" in err.value.rule


def test_max_bar_smaller_than_the_grasp_cylinder_is_refused(tmp_path):
    import yaml

    from climb_core.robot_config import load_robot_config

    src = ROOT / "config" / "robots" / "g1.yaml"
    data = yaml.safe_load(src.read_text())
    data["limbs"]["left_hand"]["surface"]["max_bar"] = {"depth": 0.03, "width": 0.052}
    bad = tmp_path / "g1.yaml"
    bad.write_text(yaml.safe_dump(data))
    with pytest.raises(SpecError) as err:
        load_robot_config(bad)
    assert err.value.field == "limbs.left_hand.surface.max_bar"
    data["limbs"]["left_hand"]["surface"]["max_bar"] = {"depth": 0.05, "widht": 0.052}
    bad.write_text(yaml.safe_dump(data))
    with pytest.raises(SpecError) as err:
        load_robot_config(bad)
    assert err.value.field == "limbs.left_hand.surface.max_bar.widht"


def test_contact_search_offers_bars_to_the_hands_only_when_they_fit(g1, rect):
    from planner_node.contact_search import accepting_surfaces

    names = [s.name for s in accepting_surfaces(g1, rect, "left_hand")]
    assert names == [f"rung_{k}" for k in range(1, rect.n_rungs + 1)]
    assert [s.name for s in accepting_surfaces(g1, _rect_ladder(0.08, 0.03), "left_hand")] == []


def test_plan_script_plans_two_steps_on_rect_rungs(tmp_path):
    """scripts/plan.py --scenario rect_rungs --steps 2 --verify: planned, re-checked at 4x by the
    core check, both feet on rung 2; the plan's rung holds are bar holds."""
    from planner_node import plan_io

    out = tmp_path / "plan.json"
    run = subprocess.run([sys.executable, str(ROOT / "scripts" / "plan.py"), "--scenario", "rect_rungs",
                          "--steps", "2", "--verify", "--out", str(out)], capture_output=True, text=True,
                         timeout=300, cwd=ROOT)
    assert run.returncode == 0, run.stderr[-2000:]
    summary = json.loads(run.stdout.strip().splitlines()[-1])
    assert summary["success"], summary["failure_reason"]
    assert summary["rungs_reached"] == 2 and summary["n_stances"] == 22
    assert summary["verified"], summary["verify"]
    plan, _ = plan_io.load_plan(out)
    final = plan.transitions[-1].target_stance
    assert {h.limb: h.env_surface for h in final.holds if h.limb in FEET} == {"left_foot": "rung_2",
                                                                              "right_foot": "rung_2"}
    for h in final.holds:
        assert len(h.points) == (8 if h.limb in HANDS else 4) and h.bilateral == (h.limb in HANDS)
