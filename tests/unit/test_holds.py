"""climb_core.holds: hold point geometry and the limb target poses, against the surface geometry."""
from __future__ import annotations

import math

import numpy as np
import pinocchio as pin
import pytest

from climb_core import holds
from climb_core.contact import FEET, HANDS
from climb_core.environment import build_environment
from climb_core.errors import SpecError
from climb_core.ladder import load_scenario


@pytest.fixture(scope="module")
def ladder():
    return build_environment(load_scenario("default"))


@pytest.fixture(scope="module")
def ship():
    return build_environment(load_scenario("ship"))


def _axis(surface):
    return surface.T_world_surface[:3, 0], surface.T_world_surface[:3, 3]


def _distance_to_axis(points, surface):
    a, p0 = _axis(surface)
    d = points - p0
    return np.linalg.norm(d - np.outer(d @ a, a), axis=1)


@pytest.mark.parametrize("limb", HANDS)
def test_grasp_is_eight_bilateral_points_on_the_rung(g1, ladder, limb):
    rung = ladder.rung(5)
    hold = holds.make_hold(g1, ladder, limb, "rung_5", s=0.1)
    P, N = hold.positions, hold.normals
    assert len(hold.points) == 8 and hold.bilateral
    assert hold.grip_force_limit == pytest.approx(g1.config.grip_strength)
    assert hold.friction == pytest.approx(rung.friction)
    # every point on the cylinder surface, normal radial and outward
    np.testing.assert_allclose(_distance_to_axis(P, rung), rung.radius, atol=1e-12)
    a, p0 = _axis(rung)
    radial = (P - p0) - np.outer((P - p0) @ a, a)
    np.testing.assert_allclose(N, radial / np.linalg.norm(radial, axis=1)[:, None], atol=1e-12)
    # the grasp centre on the axis at s, the two rings symmetric about it
    np.testing.assert_allclose(hold.centre, p0 + 0.1 * a, atol=1e-12)
    along = (P - p0) @ a - 0.1
    np.testing.assert_allclose(sorted(along), [-0.02] * 4 + [0.02] * 4, atol=1e-12)
    # 8 distinct angles around the axis: the points span every radial direction
    angles = np.sort(np.arctan2(radial @ np.cross(a, N[0]), radial @ N[0]))
    np.testing.assert_allclose(np.diff(angles), math.pi / 4, atol=1e-9)


def test_grip_limit_override_and_validation(g1, ladder):
    hold = holds.make_hold(g1, ladder, "left_hand", "rung_4", grip_force_limit=42.0)
    assert hold.grip_force_limit == 42.0
    with pytest.raises(SpecError) as err:
        holds.make_hold(g1, ladder, "left_hand", "rung_4", grip_force_limit=-1.0)
    assert err.value.field == "hold.grip_force_limit"


@pytest.mark.parametrize("limb", FEET)
def test_foot_on_cylindrical_rung_is_two_points_on_its_top_line(g1, ladder, limb):
    rung = ladder.rung(1)
    hold = holds.make_hold(g1, ladder, limb, "rung_1", s=-0.1)
    assert len(hold.points) == 2 and not hold.bilateral
    a, p0 = _axis(rung)
    top = p0 + np.array([0.0, 0.0, rung.radius])
    np.testing.assert_allclose(hold.normals, [[0.0, 0.0, 1.0]] * 2, atol=1e-12)
    np.testing.assert_allclose(hold.positions[:, 2], top[2], atol=1e-12)
    np.testing.assert_allclose(_distance_to_axis(hold.positions, rung), rung.radius, atol=1e-12)
    # spaced by the sole width, centred at s
    verts = np.asarray(g1.config.limbs[limb].surface.vertices)
    width = np.ptp(verts[:, 1])
    assert np.linalg.norm(hold.positions[1] - hold.positions[0]) == pytest.approx(width, abs=1e-12)
    assert float((hold.centre - p0) @ a) == pytest.approx(-0.1, abs=1e-12)


@pytest.mark.parametrize("limb", FEET)
def test_foot_on_cylindrical_rung_target_centres_the_sole_on_the_rung(g1, ladder, limb):
    rung = ladder.rung(1)
    T = holds.surface_target_pose(g1, ladder, limb, "rung_1", 0.05)[0]
    # sole centre on top of the rung, sole normal (out of the sole) pointing down into the rung,
    # the foot pointing toward the ladder (+x: the default ladder has yaw 0)
    a, p0 = _axis(rung)
    np.testing.assert_allclose(T[:3, 3], p0 + 0.05 * a + [0.0, 0.0, rung.radius], atol=1e-12)
    np.testing.assert_allclose(T[:3, 2], [0.0, 0.0, -1.0], atol=1e-12)
    np.testing.assert_allclose(T[:3, 0], [1.0, 0.0, 0.0], atol=1e-12)
    # the limb frame sits above the sole by the sole's depth below the ankle frame
    T_frame = holds.target_frame_pose(g1, ladder, limb, "rung_1", 0.05)
    surface = g1.config.limbs[limb].surface
    np.testing.assert_allclose(T_frame @ surface.T_frame_surface, T, atol=1e-12)


@pytest.mark.parametrize("limb", FEET)
def test_foot_on_ground_is_four_sole_corners(g1, ladder, limb):
    hold = holds.make_hold(g1, ladder, limb, "ground", position=[0.3, -0.2, 0.5], yaw=math.radians(30))
    assert len(hold.points) == 4 and not hold.bilateral
    assert hold.friction == pytest.approx(ladder.surfaces["ground"].friction)
    np.testing.assert_allclose(hold.positions[:, 2], 0.0, atol=1e-12)
    np.testing.assert_allclose(hold.normals, [[0.0, 0.0, 1.0]] * 4, atol=1e-12)
    # a 0.17 m x 0.06 m rectangle (the config's sole), centred on the sole centre, turned by the yaw
    verts = np.asarray(g1.config.limbs[limb].surface.vertices)
    centre = verts.mean(axis=0)
    np.testing.assert_allclose(hold.centre[:2], [0.3, -0.2], atol=1e-12)
    heading = np.array([math.cos(math.radians(30)), math.sin(math.radians(30)), 0.0])
    extent_along = np.ptp(hold.positions @ heading)
    assert extent_along == pytest.approx(np.ptp(verts[:, 0]), abs=1e-12)
    # corner-by-corner: the sole at the target pose puts its corners on the hold points
    T = holds.hold_target(g1, ladder, hold).T_world_surface
    surface = g1.config.limbs[limb].surface
    T_fs = np.asarray(surface.T_frame_surface)
    corners_in_surface = (verts - T_fs[:3, 3]) @ T_fs[:3, :3]
    np.testing.assert_allclose(corners_in_surface @ T[:3, :3].T + T[:3, 3], hold.positions, atol=1e-9)
    assert np.allclose(centre[:2], [0.035, 0.0])


def test_foot_on_rect_tread_is_four_points_on_its_top_face(g1, ship):
    tread = ship.rung(2)
    hold = holds.make_hold(g1, ship, "left_foot", "rung_2", s=0.1)
    assert len(hold.points) == 4
    top = tread.T_world_surface[2, 3] + tread.half_extents[2]
    np.testing.assert_allclose(hold.positions[:, 2], top, atol=1e-12)
    np.testing.assert_allclose(hold.normals, [[0.0, 0.0, 1.0]] * 4, atol=1e-12)
    # centred at s along the tread axis
    a = tread.T_world_surface[:3, 0]
    assert float((hold.centre - tread.T_world_surface[:3, 3]) @ a) == pytest.approx(0.1, abs=1e-12)


@pytest.mark.parametrize("limb", HANDS)
def test_grasp_target_puts_the_grasp_cylinder_on_the_rung_axis(g1, ladder, limb):
    rung = ladder.rung(4)
    T = holds.surface_target_pose(g1, ladder, limb, "rung_4", -0.12)[0]
    a, p0 = _axis(rung)
    surface = g1.config.limbs[limb].surface
    axis_world = T[:3, :3] @ holds.grasp_axis_in_surface(surface)
    assert abs(float(axis_world @ a)) == pytest.approx(1.0, abs=1e-12)
    np.testing.assert_allclose(T[:3, 3], p0 - 0.12 * a, atol=1e-12)
    # palm on the robot's side of the rung: the surface normal (out of the palm) points toward the ladder
    assert T[0, 2] > 0.5
    # the wrist side (limb frame origin) is lower than the grasp centre: the arm comes from below
    T_frame = holds.frame_pose_from_surface(g1, limb, T)
    assert T_frame[2, 3] < T[2, 3]


@pytest.mark.parametrize("pitch_deg", [10.0, -5.0])
def test_a_sole_pitched_on_a_round_rung_touches_it_where_it_is_tangent_and_keeps_its_pitch(g1, ladder, pitch_deg):
    """Toes up by the pitch: the points lie on the rung where its normal leans back toward the robot
    (-x: the default ladder faces +x) by the same angle, the sole's own normal is the contact normal,
    and the hold remembers its pitch: hold_target rebuilds the pitched pose with default parameters."""
    import dataclasses

    rung = ladder.rung(1)
    params = dataclasses.replace(holds.HoldParams(), foot_on_rung_pitch_deg=pitch_deg)
    hold = holds.make_hold(g1, ladder, "left_foot", "rung_1", s=0.1, params=params)
    phi = math.radians(pitch_deg)
    n = np.array([-math.sin(phi), 0.0, math.cos(phi)])
    np.testing.assert_allclose(hold.normals, [n, n], atol=1e-12)
    np.testing.assert_allclose(_distance_to_axis(hold.positions, rung), rung.radius, atol=1e-12)
    a, p0 = _axis(rung)
    np.testing.assert_allclose((hold.positions - p0) - np.outer((hold.positions - p0) @ a, a),
                               [rung.radius * n] * 2, atol=1e-12)
    T = holds.surface_target_pose(g1, ladder, "left_foot", "rung_1", 0.1, params=params)[0]
    np.testing.assert_allclose(T[:3, 2], -n, atol=1e-12)  # the sole's normal (into the rung)
    assert T[2, 0] == pytest.approx(math.sin(phi), abs=1e-12)  # the toes up by the pitch
    assert holds.rung_pitch_deg(hold, ladder) == pytest.approx(pitch_deg, abs=1e-9)
    np.testing.assert_allclose(holds.hold_target(g1, ladder, hold).T_world_surface, T, atol=1e-12)
    level = holds.make_hold(g1, ladder, "left_foot", "rung_1", s=0.1)
    assert holds.rung_pitch_deg(level, ladder) == pytest.approx(0.0, abs=1e-12)


def test_hold_target_round_trips_make_hold(g1, ladder):
    for limb, surface, s in (("left_hand", "rung_5", 0.15), ("right_foot", "rung_1", -0.12)):
        hold = holds.make_hold(g1, ladder, limb, surface, s)
        T_direct = holds.surface_target_pose(g1, ladder, limb, surface, s)[0]
        np.testing.assert_allclose(holds.hold_target(g1, ladder, hold).T_world_surface, T_direct, atol=1e-12)


def test_hold_from_configuration_projects_the_standing_soles(g1, ladder):
    q = g1.q_reference()
    data = g1.model.createData()
    pin.framesForwardKinematics(g1.model, data, q)
    for limb in FEET:
        hold = holds.hold_from_configuration(g1, ladder, q, limb, "ground")
        surface = g1.config.limbs[limb].surface
        oMf = data.oMf[g1.frame_id(surface.frame)]
        corners = np.array([oMf.act(v) for v in np.asarray(surface.vertices)])
        np.testing.assert_allclose(hold.positions, corners, atol=1e-6)  # soles flat at z = 0


def test_bad_holds_name_the_field(g1, ladder):
    cases = [
        (dict(limb="left_hand", surface_name="ground"), "hold.env_surface"),
        (dict(limb="left_hand", surface_name="no_such_rung"), "hold.env_surface"),
        (dict(limb="left_elbow", surface_name="rung_2"), "hold.limb"),
        (dict(limb="left_foot", surface_name="rung_2", s=0.4), "hold.s"),
        (dict(limb="left_foot", surface_name="ground"), "hold.position"),
        (dict(limb="left_foot", surface_name="rung_2", s=float("nan")), "hold.s"),
    ]
    for kwargs, field in cases:
        with pytest.raises(SpecError) as err:
            holds.make_hold(g1, ladder, **kwargs)
        assert err.value.field == field, kwargs
