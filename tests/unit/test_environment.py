"""Environment geometry from a ladder spec: frames, families, perturbations, coal (PyBullet: test_world_bodies)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from climb_core.environment import GROUND_HALF_SIZE, ROLES, build_environment, quaternion_xyzw, rpy_deg_to_matrix
from climb_core.errors import SpecError
from sim_bridge.world_bodies import (PYBULLET_FRICTION_COMBINATION, pybullet_friction, robot_lateral_friction,
                                     surface_lateral_friction)
from climb_core.ladder import load_scenario, parse_scenario


def yawed_doc(**ladder) -> dict:
    base = {"type": "regular", "inclination_deg": 70.0, "rung_spacing": 0.3, "n_rungs": 6,
            "first_rung_height": 0.3, "rung_width": 0.5, "rung": {"shape": "circle", "diameter": 0.05},
            "pose": {"x": 1.2, "y": -0.4, "yaw_deg": 30.0}}
    base.update(ladder)
    return {"name": "yawed", "ladder": base}


def ladder_point(env, p_ladder) -> np.ndarray:
    """World position of a point given in the ladder base frame."""
    return (env.T_world_ladder @ np.append(np.asarray(p_ladder, dtype=float), 1.0))[:3]


def test_rung_centres_follow_the_documented_frame():
    env = build_environment(yawed_doc())
    a, s, h1 = math.radians(70.0), 0.3, 0.3
    yaw = math.radians(30.0)
    for k in range(1, 7):
        expected = ladder_point(env, [(k - 1) * s * math.cos(a), 0.0, h1 + (k - 1) * s * math.sin(a)])
        np.testing.assert_allclose(env.rung_centre(k), expected, atol=1e-12)
        np.testing.assert_allclose(env.rung(k).axis, [-math.sin(yaw), math.cos(yaw), 0.0], atol=1e-12)  # L +y
        np.testing.assert_allclose(env.rung(k).normal, [0, 0, 1], atol=1e-12)
        assert env.rung(k).role == "rung" and env.rung(k).shape == "cylinder"
        assert env.rung(k).radius == 0.025 and env.rung(k).length == 0.5
    # rung 1 is at the ladder base frame's origin, lifted by h1: x = y = 0 in the ladder frame
    np.testing.assert_allclose(env.rung_centre(1), [1.2, -0.4, 0.3], atol=1e-12)
    # the ladder leans away from the robot: rung 6 is farther along the ladder's x than rung 1
    forward = env.T_world_ladder[:3, 0]
    assert forward @ (env.rung_centre(6) - env.rung_centre(1)) == pytest.approx(5 * s * math.cos(a))
    np.testing.assert_allclose(env.stringer_direction_in_world,
                               [math.cos(a) * math.cos(yaw), math.cos(a) * math.sin(yaw), math.sin(a)], atol=1e-12)
    assert env.n_rungs == 6 and [r.name for r in env.rungs()] == [f"rung_{k}" for k in range(1, 7)]


def test_stringers_reach_the_ground_and_pass_through_the_rungs():
    env = build_environment(yawed_doc())
    lad = env.ladder
    a = math.radians(lad.inclination_deg)
    for side, sign in (("left", 1.0), ("right", -1.0)):
        stringer = env.surfaces[f"stringer_{side}"]
        half_length = stringer.half_extents[0]
        foot = stringer.position - half_length * stringer.axis
        top = stringer.position + half_length * stringer.axis
        y_side = sign * (lad.rung_width / 2 + lad.stringer_width / 2)
        np.testing.assert_allclose(foot, ladder_point(env, [-lad.first_rung_height / math.tan(a), y_side, 0.0]),
                                   atol=1e-12)
        top_station = (lad.n_rungs - 1) * lad.rung_spacing + lad.stringer_top_extension
        np.testing.assert_allclose(top, ladder_point(env, [top_station * math.cos(a), y_side,
                                                           lad.first_rung_height + top_station * math.sin(a)]),
                                   atol=1e-12)
        np.testing.assert_allclose(stringer.axis, env.stringer_direction_in_world, atol=1e-12)
        assert stringer.half_extents[1:] == pytest.approx([lad.stringer_width / 2, lad.stringer_depth / 2])
        # the rung touches the stringer's inner face: rung end = stringer centre - width / 2 laterally
        rung_end = env.rung(3).position + sign * 0.5 * env.rung(3).length * env.rung(3).axis
        lateral = env.T_world_ladder[:3, 1]
        assert lateral @ (stringer.position - rung_end) == pytest.approx(sign * lad.stringer_width / 2)


def test_ship_ladder_rails_are_height_above_the_nose_line_outside_the_treads():
    env = build_environment("ship")
    lad = env.ladder
    rails = env.rails()
    assert sorted(rails) == ["left", "right"]
    for side, rail in rails.items():
        assert rail.role == "rail" and rail.shape == "cylinder" and rail.radius == 0.02
        np.testing.assert_allclose(rail.axis, env.stringer_direction_in_world, atol=1e-12)  # parallel to stringers
        y_rail = (rail.position - env.T_world_ladder[:3, 3]) @ env.T_world_ladder[:3, 1]
        assert abs(y_rail) > lad.rung_width / 2 + rail.radius  # outside the tread width
        assert math.copysign(1.0, y_rail) == (1.0 if side == "left" else -1.0)
        for k in range(1, lad.n_rungs + 1):
            tread = env.rung(k)
            assert tread.role == "tread" and tread.shape == "box"
            nose = ladder_point(env, [(tread.position - env.T_world_ladder[:3, 3]) @ env.T_world_ladder[:3, 0]
                                      - lad.rung.depth / 2, y_rail, tread.position[2] + lad.rung.thickness / 2])
            above = nose + np.array([0.0, 0.0, 1.00])
            off_axis = (above - rail.position) - ((above - rail.position) @ rail.axis) * rail.axis
            assert np.linalg.norm(off_axis) < 1e-9, (side, k)  # the point 1.00 m above the nose is on the rail axis


def test_stairs_treads_are_horizontal_steps_and_platform_is_flush():
    env = build_environment("stairs")
    lad = env.ladder
    a = math.radians(35.0)
    for k in range(1, lad.n_rungs + 1):
        tread = env.rung(k)
        np.testing.assert_allclose(tread.normal, [0, 0, 1], atol=1e-12)
        assert tread.half_extents == pytest.approx([lad.rung_width / 2, lad.rung.depth / 2, lad.rung.thickness / 2])
    rise = env.rung_centre(2)[2] - env.rung_centre(1)[2]
    run = env.rung_centre(2)[0] - env.rung_centre(1)[0]
    assert (rise, run) == pytest.approx((lad.rung_spacing * math.sin(a), lad.rung_spacing * math.cos(a)))
    platform = env.surfaces["platform"]
    lo, hi = platform.aabb()
    top_tread_lo, top_tread_hi = env.rung(lad.n_rungs).aabb()
    assert hi[2] == pytest.approx(top_tread_hi[2])  # flush with the top tread
    assert lo[0] == pytest.approx(top_tread_hi[0])  # starts at the top tread's back edge
    assert hi[0] - lo[0] == pytest.approx(lad.top_platform_depth)


def test_default_platform_at_top_rung_height_beyond_the_ladder():
    env = build_environment("default")
    top = env.rung(8)
    lo, hi = env.surfaces["platform"].aabb()
    assert hi[2] == pytest.approx(top.position[2] + top.radius)
    assert lo[0] == pytest.approx(top.position[0] + top.radius)
    assert hi[2] - lo[2] == pytest.approx(env.ladder.top_platform_thickness)


def test_a_frame_back_leg_meets_the_apex_and_stands_on_the_ground():
    env = build_environment("a_frame")
    lad = env.ladder
    b = math.radians(lad.back_inclination_deg)
    for side in ("left", "right"):
        front, back = env.surfaces[f"stringer_{side}"], env.surfaces[f"stringer_back_{side}"]
        apex = front.position + front.half_extents[0] * front.axis
        back_top = back.position + back.half_extents[0] * back.axis
        back_foot = back.position - back.half_extents[0] * back.axis
        np.testing.assert_allclose(back_top, apex, atol=1e-12)
        assert back_foot[2] == pytest.approx(0.0, abs=1e-12)
        assert back_foot[0] > apex[0]  # the back leg goes away from the robot
        assert math.degrees(math.atan2(apex[2] - back_foot[2], back_foot[0] - apex[0])) == pytest.approx(
            math.degrees(b))
    assert len(env.surfaces_with_role("stringer")) == 4
    assert "stringer_back_left" not in build_environment("default").surfaces


def test_vertical_ladder_rungs_are_stacked():
    env = build_environment("vertical")
    xs = {round(float(env.rung_centre(k)[0]), 12) for k in range(1, env.n_rungs + 1)}
    assert xs == {0.35}
    np.testing.assert_allclose(env.stringer_direction_in_world, [0, 0, 1], atol=1e-12)
    assert env.rung_centre(10)[2] == pytest.approx(0.25 + 9 * 0.25)


def test_caged_obstacles_are_world_boxes():
    env = build_environment("caged")
    obstacles = env.surfaces_with_role("obstacle")
    assert len(obstacles) == len(env.ladder.obstacles) == 13
    for surface, spec in zip(obstacles, env.ladder.obstacles):
        np.testing.assert_allclose(surface.position, spec.position)
        lo, hi = surface.aabb()
        np.testing.assert_allclose(hi - lo, spec.size, atol=1e-12)  # no rotation
    # a yawed obstacle is rotated in the world, not with the ladder
    doc = yawed_doc(obstacles=[{"size": [1.0, 0.2, 0.4], "position": [3.0, 1.0, 0.2], "rpy_deg": [0, 0, 90]}])
    lo, hi = build_environment(doc).surfaces["obstacle_0"].aabb()
    np.testing.assert_allclose(hi - lo, [0.2, 1.0, 0.4], atol=1e-12)


def test_perturbation_moves_only_the_named_rung_and_the_rails():
    nominal = build_environment("default_perturbed")
    perturbed = build_environment("default_perturbed", perturbed=True)
    assert not nominal.perturbed and perturbed.perturbed
    for k in range(1, 9):
        delta = perturbed.rung_centre(k) - nominal.rung_centre(k)
        np.testing.assert_allclose(delta, [0, 0, 0.02] if k == 2 else [0, 0, 0], atol=1e-12)
    np.testing.assert_allclose(nominal.rung_centre(2), build_environment("default").rung_centre(2))
    doc = load_scenario("ship").to_dict()
    doc["perturbation"] = {"rails_dy": 0.03, "rung_offsets": [{"rung": 4, "dx": -0.01, "dz": 0.015}]}
    doc["ladder"]["pose"]["yaw_deg"] = 90.0
    nominal, moved = build_environment(doc), build_environment(doc, perturbed=True)
    for side in ("left", "right"):  # ladder y = world -x after a 90 deg yaw
        np.testing.assert_allclose(moved.surfaces[f"rail_{side}"].position - nominal.surfaces[f"rail_{side}"].position,
                                   [-0.03, 0, 0], atol=1e-12)
        np.testing.assert_allclose(moved.surfaces[f"stringer_{side}"].position,
                                   nominal.surfaces[f"stringer_{side}"].position)
    np.testing.assert_allclose(moved.rung_centre(4) - nominal.rung_centre(4), [0, -0.01, 0.015], atol=1e-12)


def test_friction_and_names():
    env = build_environment("ship")
    assert env.surfaces["ground"].friction == 0.8
    for surface in env.surfaces.values():
        assert surface.role in ROLES
        if surface.role != "ground":
            assert surface.friction == env.ladder.friction == 0.5
    assert PYBULLET_FRICTION_COMBINATION == "product"
    assert pybullet_friction(0.25) == pytest.approx(0.5)
    assert robot_lateral_friction(env) ** 2 == pytest.approx(0.5)
    # product with the robot's sqrt(mu) gives each surface's own coefficient
    for surface in env.surfaces.values():
        assert surface_lateral_friction(env, surface) * robot_lateral_friction(env) == pytest.approx(surface.friction)
    with pytest.raises(SpecError):
        pybullet_friction(0.0)
    with pytest.raises(SpecError) as info:
        env.rung(6)
    assert info.value.field == "rung"
    with pytest.raises(SpecError):
        env.rung(0)


def test_builds_from_a_ladder_spec_and_from_text():
    scenario = load_scenario("default")
    from_spec = build_environment(scenario.ladder)
    from_text = build_environment(scenario.to_yaml())
    np.testing.assert_allclose(from_spec.rung_centre(5), from_text.rung_centre(5))
    assert list(from_spec.surfaces)[:2] == ["ground", "rung_1"]


def test_quaternions_and_rpy():
    for rpy in ([0, 0, 0], [10, -20, 30], [180, 0, 0], [0, 179, 0], [-90, 45, 170]):
        R = rpy_deg_to_matrix(rpy)
        x, y, z, w = quaternion_xyzw(R)
        R_back = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                           [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                           [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])
        np.testing.assert_allclose(R_back, R, atol=1e-12)
    np.testing.assert_allclose(rpy_deg_to_matrix([0, 0, 90]) @ [1, 0, 0], [0, 1, 0], atol=1e-12)


# ------------------------------------------------------------------------------------------------
# coal
# ------------------------------------------------------------------------------------------------

def _distance_to(env, name: str, point) -> float:
    import coal

    objects = {n: (g, T) for n, g, T in env.collision_objects()}
    geometry, T = objects[name]
    result = coal.DistanceResult()
    return coal.distance(geometry, T, coal.Sphere(0.0), coal.Transform3s(np.eye(3), np.asarray(point, float)),
                         coal.DistanceRequest(), result)


def test_coal_distance_to_rung_3_matches_the_analytic_value():
    env = build_environment(yawed_doc())
    assert len(env.collision_objects()) == len(env.surfaces)
    rung = env.rung(3)
    c, axis, r, half = rung.position, rung.axis, rung.radius, rung.length / 2
    towards_robot = -env.T_world_ladder[:3, 0]
    # in front of the rung, within its length: distance to the axis minus the radius
    point = c + 0.3 * axis * half + 0.2 * towards_robot + 0.05 * np.array([0, 0, 1.0])
    assert _distance_to(env, "rung_3", point) == pytest.approx(math.hypot(0.2, 0.05) - r, abs=1e-6)
    # beyond the end cap and outside the radius: distance to the cap's rim
    point = c + (half + 0.1) * axis + 0.15 * np.array([0, 0, 1.0])
    assert _distance_to(env, "rung_3", point) == pytest.approx(math.hypot(0.1, 0.15 - r), abs=1e-6)
    # the ground: a point 0.37 m up
    assert _distance_to(env, "ground", [0.3, -2.0, 0.37]) == pytest.approx(0.37, abs=1e-6)


def test_coal_distance_to_a_tread_box():
    env = build_environment("ship")
    tread = env.rung(3)
    point = tread.position + np.array([0.0, 0.0, tread.half_extents[2] + 0.12])
    assert _distance_to(env, "rung_3", point) == pytest.approx(0.12, abs=1e-6)


def test_ground_extent_constant_is_used():
    env = build_environment("default")
    assert env.surfaces["ground"].half_extents[:2] == pytest.approx([GROUND_HALF_SIZE] * 2)
    assert env.surfaces["ground"].shape == "plane"
    np.testing.assert_allclose(env.surfaces["ground"].normal, [0, 0, 1])


def test_parse_then_build_a_minimal_spec():
    env = build_environment(parse_scenario({"ladder": {"n_rungs": 2}}))
    assert set(env.surfaces) == {"ground", "rung_1", "rung_2", "stringer_left", "stringer_right"}


def test_surface_offsets_move_surfaces_their_collision_objects_and_the_holds_on_them():
    """The replanner's corrected model: a surface found 3 cm higher is moved (its collision object
    too), the others stay, the nominal environment is untouched; a stance's holds on it move."""
    from climb_core.contact import ContactPoint, Hold, Stance

    env = build_environment("default")
    moved = env.with_surface_offsets({"rung_2": [0.0, 0.0, 0.03]})
    assert moved.surfaces["rung_2"].position - env.surfaces["rung_2"].position == pytest.approx([0.0, 0.0, 0.03])
    assert moved.surfaces["rung_2"].top_z == pytest.approx(env.surfaces["rung_2"].top_z + 0.03)
    assert moved.surfaces["rung_3"].position == pytest.approx(env.surfaces["rung_3"].position)
    objects = {name: tf for name, _, tf in moved.collision_objects()}
    assert objects["rung_2"].getTranslation() == pytest.approx(moved.surfaces["rung_2"].T_world_primitive()[:3, 3])
    assert env.surfaces["rung_2"].position[2] == pytest.approx(build_environment("default").surfaces["rung_2"].position[2])
    for bad, rule in (({"rung_99": [0, 0, 0.01]}, "no surface"), ({"rung_2": [0, 0.01]}, "3 finite numbers"),
                      ({"rung_2": [0, 0, float("nan")]}, "3 finite numbers")):
        with pytest.raises(SpecError, match=rule) as err:
            env.with_surface_offsets(bad)
        assert err.value.field == f"surface_offsets.{next(iter(bad))}"
    foot = Hold("left_foot", "left_sole", "rung_2", (ContactPoint([0.5, 0.1, 0.5], [0, 0, 1]),), 0.25)
    hand = Hold("left_hand", "left_grasp", "rung_6", (ContactPoint([0.6, 0.1, 1.5], [0, 0, 1]),), 0.25)
    stance = Stance((foot, hand), name="s").with_surface_offsets({"rung_2": np.array([0.0, 0.0, 0.03])})
    assert stance.hold("left_foot").points[0].position == pytest.approx([0.5, 0.1, 0.53])
    assert stance.hold("left_hand") == hand and stance.name == "s"
