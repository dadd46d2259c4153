"""climb_core.fixtures: the named stances are feasible, geometrically what they claim, and cached."""
from __future__ import annotations

import numpy as np
import pytest

from climb_core import feasibility as fz
from climb_core import fixtures
from climb_core.contact import FEET, HANDS, LIMBS
from climb_core.environment import build_environment
from climb_core.errors import SpecError
from climb_core.ladder import load_scenario
from climb_core.robot import load_robot


@pytest.mark.parametrize("name", fixtures.NAMES)
def test_every_fixture_is_feasible(g1, env, name):
    cfg = fz.load_config()
    stance, q = fixtures.get(name, g1, env)
    res = fz.check(g1, env, q, stance, cfg)
    assert res.feasible, f"{name}: {res.summary()}"
    assert res.most_loaded_ratio < 1.0 and res.min_distance >= cfg.check.collision_margin
    for hold in stance.holds:
        f = res.contact_forces[hold.limb]
        if hold.bilateral:
            continue
        fn = np.einsum("ij,ij->i", f, hold.normals)
        ft = np.linalg.norm(f - fn[:, None] * hold.normals, axis=1)
        assert (fn >= -1e-6).all() and (ft <= hold.friction * fn + 1e-6).all()


def test_standing_is_the_reference_posture_on_the_ground(g1, env):
    stance, q = fixtures.get("standing", g1, env)
    np.testing.assert_array_equal(q, g1.q_reference())
    assert stance.limbs == FEET and {h.env_surface for h in stance.holds} == {"ground"}
    np.testing.assert_allclose(np.vstack([h.positions for h in stance.holds])[:, 2], 0.0, atol=1e-6)


def test_ladder_4_contacts_geometry(g1, env):
    params = fixtures.load_fixture_params()
    stance, q = fixtures.get("ladder_4_contacts", g1, env)
    assert set(stance.limbs) == set(LIMBS)
    feet_rung, hands_rung = env.rung(params.feet_rung), env.rung(params.hands_rung)
    for limb in FEET:
        hold = stance.hold(limb)
        assert hold.env_surface == f"rung_{params.feet_rung}" and len(hold.points) == 2
        # the sole centre is on top of the rung
        T = g1.T_world_surface(limb, q)
        np.testing.assert_allclose(T[:3, 3], hold.centre, atol=1e-3)
        assert T[2, 3] == pytest.approx(feet_rung.top_z, abs=1e-3)
    for limb in HANDS:
        hold = stance.hold(limb)
        assert hold.env_surface == f"rung_{params.hands_rung}" and hold.bilateral
        np.testing.assert_allclose(g1.T_world_surface(limb, q)[:3, 3], hold.centre, atol=1e-3)
    # left limbs on the left (+y), the robot on its side of the ladder (pelvis behind rung 1)
    assert stance.hold("left_hand").centre[1] > stance.hold("right_hand").centre[1]
    assert stance.hold("left_foot").centre[1] > stance.hold("right_foot").centre[1]
    assert q[0] < feet_rung.T_world_surface[0, 3]
    assert np.linalg.norm(stance.hold("left_hand").centre - stance.hold("right_hand").centre) == pytest.approx(
        params.hand_spacing)


@pytest.mark.parametrize("limb", LIMBS)
def test_three_limb_fixtures_free_one_limb(g1, env, limb):
    four, _ = fixtures.get("ladder_4_contacts", g1, env)
    stance, q = fixtures.get(f"ladder_no_{limb}", g1, env)
    assert set(stance.limbs) == set(LIMBS) - {limb}
    for hold in stance.holds:  # the other holds are the 4-contact ones
        np.testing.assert_allclose(hold.positions, four.hold(hold.limb).positions)
    # the freed limb is off its former rung
    former = four.hold(limb)
    T = g1.T_world_surface(limb, q)
    assert np.linalg.norm(T[:3, 3] - former.centre) > 0.05


def test_api_orders_and_errors(g1, env):
    stance, q = fixtures.get("ladder_no_right_hand", g1, env)
    q2, stance2 = fixtures.stance_configuration("ladder_no_right_hand", robot=g1, env=env)
    np.testing.assert_array_equal(q, q2)
    assert stance2.limbs == stance.limbs
    fx = fixtures.fixture("ladder_no_right_hand", g1, env)
    s3, q3 = fx  # unpacks as (stance, q)
    np.testing.assert_array_equal(q3, q)
    # names / paths resolve like objects
    np.testing.assert_array_equal(fixtures.get("standing", "g1", "default")[1], g1.q_reference())
    with pytest.raises(SpecError) as err:
        fixtures.get("ladder_upside_down", g1, env)
    assert err.value.field == "fixture"


def test_disk_cache_round_trip(g1, env, tmp_path, monkeypatch):
    monkeypatch.setattr(fixtures, "_cache_dir", lambda: tmp_path)
    monkeypatch.setattr(fixtures, "_MEMORY", {})
    built = fixtures.fixture("ladder_no_left_hand", g1, env)
    assert built.result is not None and built.result.feasible
    files = list(tmp_path.glob("g1-ladder_no_left_hand-*.json"))
    assert len(files) == 1 and built.key in files[0].name
    monkeypatch.setattr(fixtures, "_MEMORY", {})
    loaded = fixtures.fixture("ladder_no_left_hand", g1, env)
    assert loaded.result is None  # came from the file
    np.testing.assert_array_equal(loaded.q, built.q)
    for a, b in zip(loaded.stance.holds, built.stance.holds):
        assert a == b
    # a corrupt file is rebuilt, not trusted
    files[0].write_text("{not json")
    monkeypatch.setattr(fixtures, "_MEMORY", {})
    rebuilt = fixtures.fixture("ladder_no_left_hand", g1, env)
    assert rebuilt.result is not None
    np.testing.assert_allclose(rebuilt.q, built.q)


def test_writers_of_one_fixture_at_once_do_not_race(g1, env, tmp_path, monkeypatch):
    """The planning nodes of a graph start at once and may build the same fixture: every writer
    used one temporary file name, so one writer's rename took another's file away
    (FileNotFoundError, a primitive_adaptation request failing with "internal error", measured
    in a fresh clone). Each writer now has its own temporary file; the cache file is whole."""
    import json
    import threading

    monkeypatch.setattr(fixtures, "_cache_dir", lambda: tmp_path)
    built = fixtures.fixture("ladder_no_left_hand", g1, env)
    errors: list[BaseException] = []

    def write() -> None:
        try:
            for _ in range(50):
                fixtures._save_disk(built)
        except BaseException as err:  # noqa: BLE001 - reported below
            errors.append(err)

    threads = [threading.Thread(target=write) for _ in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not errors, errors
    (path,) = tmp_path.glob("g1-ladder_no_left_hand-*.json")
    assert json.loads(path.read_text())["name"] == "ladder_no_left_hand"
    assert not list(tmp_path.glob("*.tmp")) and not list(tmp_path.glob(".*.tmp"))


def test_romeo_wrists_carry_the_ladder_stance_g1_wrists_do_not(g1, env):
    """The same construction (feet on rung 1, hands on rung 5, one foot released) for G1 and Romeo:
    Romeo's wrists (0.6-2.2 N m) are its binding joints, G1's (5-25 N m) are far from theirs."""
    romeo = load_robot("romeo")
    params = fixtures.load_fixture_params()
    ratios = {}
    for robot in (g1, romeo):
        four, q4 = fixtures.ladder_stance(robot, env, params)
        limb = "left_foot"
        stance = four.without(limb)
        res = fz.check(robot, env, q4, stance, collision=False)
        wrist = [i for i, n in enumerate(robot.joint_names) if "wrist" in n.lower()]
        ratios[robot.config.name] = (res, float(np.max(np.abs(res.joint_torques[wrist]) /
                                                       robot.effort_limits()[wrist])))
    g1_res, g1_wrist = ratios["g1"]
    romeo_res, romeo_wrist = ratios["romeo"]
    assert g1_res.feasible and g1_wrist < 0.4
    assert "wrist" in romeo_res.most_loaded_joint.lower()
    assert romeo_wrist > 2.0 * g1_wrist and romeo_wrist > 0.6


def test_ship_ladder_hands_hold_the_rails(g1):
    """Flat treads cannot be grasped: the 4-contact fixture puts the hands on the hand rails."""
    ship = build_environment(load_scenario("ship"))
    stance, q = fixtures.get("ladder_4_contacts", g1, ship)
    assert {stance.hold(l).env_surface for l in HANDS} == {"rail_left", "rail_right"}
    assert stance.hold("left_hand").env_surface == "rail_left"
    assert all(len(stance.hold(l).points) == 4 for l in FEET)  # soles flat on the treads
    res = fz.check(g1, ship, q, stance)
    assert res.feasible, res.summary()
