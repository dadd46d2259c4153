"""Holds from a robot contact surface and an environment surface, and their target poses.

A hold (see :mod:`climb_core.contact`) is the set of point contacts between one limb and one
environment surface. This module builds them from the robot model (its contact surfaces) and the
environment (its rungs, rails, treads, ground), and gives back the pose the limb must take so
that the contact is made, for the IK.

Geometry (all world frame):

- hand ``grasp`` on a cylinder (rung, rail): 8 points on the cylinder surface, two rings of four
  around the grasp centre (the rings ``grasp_ring_spacing`` apart along the axis, the second ring
  turned by 45 deg), normals radially outward; bilateral, ``grip_force_limit`` = the robot's grip
  strength. Target: the grasp cylinder axis along the environment cylinder axis, its centre on
  the axis at ``s``; the roll of the hand about the axis puts the palm on the robot's side of
  the rung, ``grasp_palm_angle_deg`` above the horizontal (the IK leaves that roll free); of the
  two axis directions, the one with the limb frame (wrist side) lowest, or closest to a seed.
- ``sole`` on a flat surface (ground plane, tread, platform, any box top): the sole corners of the
  target pose, normal = the surface's up normal; unilateral.
- ``palm`` (a hand pushing, unilateral) on a flat or cylindrical surface: as a sole (its polygon
  corners / 2 points on the top line), the palm's normal against the surface; kinds ``palm_flat``
  and ``palm_cylinder``. Which surface a hand uses follows one rule, :func:`hand_surface_for`:
  the grasp on a bilateral surface, the palm on any other.
- ``sole`` on a cylinder: 2 points on the rung (the rung line under the sole), spaced by
  the sole width, normals from the rung axis toward the foot; unilateral. Target: the sole
  tangent to the rung on its top line, its centre (shifted by ``foot_on_rung_offset`` along the
  foot's forward axis) above the axis, the foot pointing along the ladder's forward direction.
  With ``foot_on_rung_pitch_deg`` the foot is pitched toes up by that angle about the rung axis
  and touches the rung where its normal leans back toward the robot by the same angle (a flat
  sole on a cylinder touches it along the line where it is tangent): the rung then pushes the foot
  back as well as up. A hold keeps its pitch in its normals; :func:`hold_target` reads it there.
- rectangular rungs (``is_bar``: a box of role ``rung``, the rect rungs of regular, vertical and
  A-frame ladders; treads are for feet only, and a tread deeper than the sole is long - stairs -
  is a flat surface, the whole sole on it). A hand ``grasp`` on a bar (any
  bilateral box) that fits the hand (:func:`check_grasp_fits`: with the palm on the bar's face
  toward the robot, its depth within the grasp surface's ``max_bar.depth``, its thickness within
  ``max_bar.width``; else a SpecError naming ``ladder.rung.depth`` / ``ladder.rung.thickness``
  and the limit): 8 points, two
  rings of four around the grasp centre as on a cylinder, ring 1 on the four face centres of the
  bar's cross-section (normals the face normals), ring 2 on its four edges (normals the
  diagonals); bilateral. Target: as on a cylinder (grasp axis along the bar, centre on its centre
  line, palm on the robot's side), the palm ``grasp_palm_angle_bar_deg`` above the horizontal
  (config/feasibility.yaml: 30, as on a cylinder, the roll the primitives were designed with; the
  IK leaves the roll free on a bar as on a cylinder). A ``sole`` on a bar, kind ``sole_bar`` (the
  ladder paper's Fig. 6 foot hold): the four corners of the bar's top face under the sole (along
  the bar: the sole width apart, or ``foot_on_rung_spacing``; across: the part of the bar's depth
  the sole covers), normals up; unilateral. Target: as on a cylinder, the sole on the top face
  above the centre line, shifted back by ``foot_on_rung_offset``. A tread no deeper than the sole
  is long (:func:`is_sole_bar`: a ship ladder's) takes the same hold, its centre shifted back by
  ``foot_on_tread_offset``: the ball of the foot on the tread and the heel past its nose, as people
  stand on ship ladders, so that the toes are not under the tread above.

``s`` is the position along the surface axis (local x of the surface; cylinders are along local
x) measured from the surface centre [m]. On the ground plane the sole centre is given by
``position`` (world) and the foot heading by ``yaw`` (rad, about world z).

Robot surface frames (climb_core.robot.ContactSurface.T_frame_surface): origin at the sole centre
/ grasp centre, z axis = the contact normal out of the robot (sole: from the foot into what it
stands on, checked once per robot on the reference posture, :func:`sole_normal_sign`; grasp: out
of the palm toward the grasped axis), grasp cylinder axis = ``ContactSurface.axis``.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from .contact import HANDS, LIMBS, ContactPoint, Hold
from .errors import SpecError
from .params import param

WORLD_UP = np.array([0.0, 0.0, 1.0])


@dataclass(frozen=True)
class HoldParams:
    grasp_ring_spacing: float = param(0.04, unit="m", min=0.0, description=(
        "distance along the cylinder axis between the two rings of four grasp points"))
    grasp_palm_angle_deg: float = param(30.0, unit="deg", min=-90.0, max=90.0, description=(
        "roll of a grasp about the cylinder axis: the palm sits on the robot's side of the rung, "
        "this far above the horizontal through the axis (90 = palm on top)"))
    foot_on_rung_offset: float = param(0.0, unit="m", description=(
        "sole centre shift along the foot's forward axis from the rung's top line (positive: "
        "back toward the robot, the ball of the foot on the rung)"))
    foot_on_tread_offset: float = param(0.045, unit="m", min=0.0, description=(
        "the same shift on a tread no deeper than the sole is long (a ship ladder's, is_sole_bar): "
        "the heel this far past the tread's nose (0.045: the shipped ship ladder's 17 cm treads "
        "overhang the one below by 4.5 cm, so G1's 17 cm sole then ends under the nose of the tread "
        "above; centred, its toes were under it and every step up backed the foot off first)"))
    foot_on_rung_pitch_deg: float = param(0.0, unit="deg", min=-30.0, max=30.0, description=(
        "pitch of a sole on a round rung about the rung axis, toes up: the flat sole is tangent to the "
        "rung where the rung's normal leans this far back toward the robot, so the rung pushes the foot "
        "back as well as up (a robot hanging behind a steep rung needs that push; 0 = the sole level on "
        "the rung's top line)"))
    foot_on_rung_spacing: float = param(0.0, unit="m", min=0.0, description=(
        "distance between the 2 points of a foot on a cylindrical rung (the 2 pairs of corners on a "
        "rect rung); 0 = the sole width"))
    grasp_palm_angle_bar_deg: float = param(30.0, unit="deg", min=-90.0, max=90.0, description=(
        "nominal roll of a grasp around a rectangular bar: the palm on the robot's side, this far above "
        "the horizontal (0 = flat on the bar's face toward the robot)"))
    push_friction_fraction: float = param(0.5, unit="-", min=0.05, max=1.0, description=(
        "share of a surface's friction a hand pushing on it (a palm-kind surface: G1's back of the "
        "hand) counts on: its contact is small and domed, and a plan standing at the cone's edge "
        "there slides (narrow_passage_step: tangential/normal 0.69-0.70 on mu 0.7, then a fall)"))


@dataclass(frozen=True)
class HoldTarget:
    """Where a limb must be for its hold: pose of the robot contact surface and of the limb frame."""

    limb: str
    frame: str  # robot frame the surface is attached to
    T_world_surface: np.ndarray  # 4x4 target pose of the robot contact surface frame
    T_world_frame: np.ndarray  # 4x4 target pose of `frame`
    free_axis_in_surface: np.ndarray | None  # unit axis (surface frame) about which rotation is free (grasp), or None
    kind: str  # sole_flat | sole_cylinder | sole_bar | palm_flat | palm_cylinder | grasp
    robot_surface: str = ""  # name of the robot contact surface ("" = the limb's primary one)


# --------------------------------------------------------------------------------------------
# small geometry helpers


def _unit(v: np.ndarray) -> np.ndarray:
    n = float(np.linalg.norm(v))
    if n < 1e-12:
        raise SpecError("holds.geometry", "degenerate direction (zero vector)")
    return v / n


def _pose(R: np.ndarray, p: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = p
    return T


def _inv(T: np.ndarray) -> np.ndarray:
    R = T[:3, :3]
    return _pose(R.T, -R.T @ T[:3, 3])


def _perp(v: np.ndarray, axis: np.ndarray) -> np.ndarray:
    """Component of v perpendicular to the unit axis."""
    return v - axis * float(axis @ v)


def _frame_from_zx(z: np.ndarray, x_hint: np.ndarray) -> np.ndarray:
    """Rotation whose z column is z and whose x column is x_hint made orthogonal to z."""
    z = _unit(z)
    x = _unit(_perp(x_hint, z))
    return np.column_stack([x, np.cross(z, x), z])


def _rot_about(axis: np.ndarray, angle: float) -> np.ndarray:
    a = _unit(axis)
    K = np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])
    return np.eye(3) + math.sin(angle) * K + (1.0 - math.cos(angle)) * (K @ K)


# --------------------------------------------------------------------------------------------
# robot / environment lookups


def limb_surface(robot: Any, limb: str, robot_surface: str | None = None) -> Any:
    """The robot ContactSurface ``robot_surface`` of ``limb`` (default: its primary one, a foot's
    sole, a hand's grasp); SpecError for an unknown limb or surface."""
    if limb not in LIMBS:
        raise SpecError("hold.limb", f"must be one of {', '.join(LIMBS)}; got {limb!r}")
    limbs = robot.config.limbs
    if limb not in limbs:
        raise SpecError("hold.limb", f"robot {robot.config.name!r} has no limb {limb!r}")
    if not robot_surface:
        return limbs[limb].surface
    surfaces = limbs[limb].surfaces
    if robot_surface not in surfaces:
        raise SpecError("hold.robot_surface", f"{robot.config.name} {limb} has no surface {robot_surface!r} "
                                              f"(it has {', '.join(surfaces)})")
    return surfaces[robot_surface]


def hold_surface(robot: Any, hold: Hold) -> Any:
    """The robot ContactSurface a hold is made with (``hold.robot_surface``)."""
    return limb_surface(robot, hold.limb, hold.robot_surface or None)


def hand_surface_for(robot: Any, limb: str, sf: Any, *, required: bool = True) -> Any:
    """THE rule for a hand on an environment surface ``sf``: on a bilateral one (a rung, a bar, a
    handle) it closes its grasp; on any other it pushes with its palm (unilateral). SpecError
    (None with ``required=False``) when the hand has no surface of that kind."""
    if limb not in HANDS:
        raise SpecError("hold.limb", f"must be a hand ({', '.join(HANDS)}); got {limb!r}")
    limb_surface(robot, limb)  # limb checks
    kind = "grasp" if getattr(sf, "bilateral", False) else "palm"
    surface = robot.config.limbs[limb].surface_of_kind(kind)
    if surface is None and required:
        why = "is bilateral (a grasp)" if kind == "grasp" else "is not bilateral (a palm push)"
        raise SpecError("hold.robot_surface", f"{robot.config.name} {limb} has no {kind} surface; "
                                              f"{getattr(sf, 'name', sf)!r} {why}")
    return surface


def robot_surface_for(robot: Any, limb: str, sf: Any, *, required: bool = True) -> Any:
    """The robot surface ``limb`` touches ``sf`` with: a foot its sole, a hand per
    :func:`hand_surface_for`."""
    if limb in HANDS:
        return hand_surface_for(robot, limb, sf, required=required)
    return limb_surface(robot, limb)


def env_surface(env: Any, surface_name: str) -> Any:
    if surface_name not in env.surfaces:
        raise SpecError("hold.env_surface", f"unknown surface {surface_name!r}; the environment has "
                                            f"{', '.join(sorted(env.surfaces))}")
    return env.surfaces[surface_name]


def ladder_forward(env: Any) -> np.ndarray:
    """Horizontal unit vector from the robot toward the ladder (the ladder base frame's x)."""
    try:
        yaw = math.radians(float(env.scenario.ladder.pose_yaw_deg))
    except AttributeError:
        yaw = 0.0
    return np.array([math.cos(yaw), math.sin(yaw), 0.0])


_SIGN_CACHE: dict[int, dict[str, float]] = {}


def sole_normal_sign(robot: Any, limb: str) -> float:
    """+1 if the sole surface z points out of the sole (into the ground) at the reference
    posture, -1 if it points into the foot. Cached per robot."""
    per_robot = _SIGN_CACHE.setdefault(id(robot), {})
    if limb not in per_robot:
        import pinocchio as pin

        surface = limb_surface(robot, limb)
        q = robot.q_reference()
        data = robot.model.createData()
        pin.framesForwardKinematics(robot.model, data, q)
        R_world_frame = data.oMf[robot.frame_id(surface.frame)].rotation
        z_world = R_world_frame @ np.asarray(surface.T_frame_surface)[:3, 2]
        per_robot[limb] = 1.0 if z_world[2] < 0.0 else -1.0
    return per_robot[limb]


def sole_extent(surface: Any) -> tuple[float, float]:
    """(length along the surface x, width along the surface y) of a sole polygon [m]."""
    v = np.asarray(surface.vertices, dtype=float).reshape(-1, 3)
    if len(v) < 3:
        raise SpecError(f"robot.{surface.name}.vertices", "a sole needs at least 3 corners")
    T_sf = np.asarray(surface.T_frame_surface)
    # vertices are given in the frame; express them in the surface frame
    v_s = (v - T_sf[:3, 3]) @ T_sf[:3, :3]
    return float(np.ptp(v_s[:, 0])), float(np.ptp(v_s[:, 1]))


def sole_vertices_in_surface(surface: Any) -> np.ndarray:
    """(n,3) sole corners in the surface frame [m]."""
    v = np.asarray(surface.vertices, dtype=float).reshape(-1, 3)
    T_sf = np.asarray(surface.T_frame_surface)
    return (v - T_sf[:3, 3]) @ T_sf[:3, :3]


def grasp_axis_in_surface(surface: Any) -> np.ndarray:
    T_sf = np.asarray(surface.T_frame_surface)
    return _unit(T_sf[:3, :3].T @ np.asarray(surface.axis, dtype=float))


def _cylinder_axis(sf: Any) -> tuple[np.ndarray, np.ndarray]:
    T = np.asarray(sf.T_world_surface)
    return T[:3, 3].copy(), _unit(T[:3, 0].copy())


def _flat_top(sf: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(centre of the top face, its up normal, its in-plane x axis) of a plane or box surface."""
    T = np.asarray(sf.T_world_surface)
    R = T[:3, :3]
    # the face whose normal points most upward
    k = int(np.argmax(np.abs(R[2, :])))
    n = R[:, k] * np.sign(R[2, k])
    half = 0.0 if sf.shape == "plane" else float(np.asarray(sf.half_extents)[k])
    centre = T[:3, 3] + n * half
    x_axis = R[:, 0] if k != 0 else R[:, 1]
    return centre, n, x_axis


def _top_normal(axis: np.ndarray) -> np.ndarray:
    """Unit direction perpendicular to a cylinder axis, closest to world up."""
    return _unit(_perp(WORLD_UP, axis))


def is_bar(sf: Any) -> bool:
    """A rectangular rung (a box of role ``rung``): feet stand across it (``sole_bar``), hands hold
    it along its axis (local x) like a cylinder when it fits them."""
    return getattr(sf, "shape", "") == "box" and getattr(sf, "role", "") == "rung"


def is_sole_bar(sf: Any, rs: Any) -> bool:
    """A sole stands across ``sf`` like on a rect rung (``sole_bar``, the paper's Fig. 6 hold): a
    rect rung, or a tread no deeper than the sole is long (a ship ladder's 17 cm treads under G1's
    17 cm sole: the sole may overhang its nose, the contact polygon being the tread's top under the
    sole); a deeper tread (stairs) is a flat surface the whole sole stands on."""
    if getattr(rs, "kind", "") != "sole" or getattr(sf, "shape", "") != "box":
        return False
    if is_bar(sf):
        return True
    return getattr(sf, "role", "") == "tread" and bar_section(sf)[0] <= sole_extent(rs)[0] + 1e-6


def held_along_axis(sf: Any, rs: Any) -> bool:
    """Whether the robot surface ``rs`` holds ``sf`` at a position ``s`` along its local x axis (a
    cylinder; a rect rung, for a sole or a grasp; a tread no deeper than the sole, for a sole:
    :func:`is_sole_bar`) rather than at a free position on a face (a palm on a bar, a sole on a
    plane or a deeper tread)."""
    return sf.shape == "cylinder" or (is_bar(sf) and rs.kind != "palm") or is_sole_bar(sf, rs)


def bar_section(sf: Any) -> tuple[float, float]:
    """(depth, thickness) [m] of a box's cross-section across its local x: its size along local y
    (a rect rung's depth, toward the robot) and local z (its thickness, up)."""
    h = np.asarray(sf.half_extents, dtype=float)
    return 2.0 * float(h[1]), 2.0 * float(h[2])


def _bar_fields(sf: Any) -> tuple[str, str]:
    """Spec fields of a bar's depth and thickness, for error messages."""
    if getattr(sf, "role", "") in ("rung", "tread"):
        return "ladder.rung.depth", "ladder.rung.thickness"
    return f"scene.surfaces.{sf.name}.size", f"scene.surfaces.{sf.name}.size"


def _bar_roll(params: HoldParams) -> float:
    return math.radians(params.grasp_palm_angle_bar_deg)


def check_grasp_fits(robot: Any, limb: str, sf: Any, robot_surface: str | None = None) -> None:
    """SpecError unless the hand's grasp can close around ``sf``: a bilateral cylinder, or a
    bilateral box whose cross-section is within the grasp surface's ``max_bar`` with the palm on
    the face toward the robot (the bar's depth, local y, away from the palm: ``max_bar.depth``; its
    thickness, local z, along the palm: ``max_bar.width``). The error names the spec field
    (``ladder.rung.depth`` / ``ladder.rung.thickness``) and the limit."""
    rs = limb_surface(robot, limb, robot_surface)
    name = getattr(sf, "name", "?")
    bilateral = bool(getattr(sf, "bilateral", True))
    if sf.shape not in ("cylinder", "box") or not bilateral:
        raise SpecError("hold.env_surface", f"a hand grasp ({rs.name}) needs a bilateral cylinder or bar (rung, "
                                            f"rail, bar); {name!r} is a {sf.shape}"
                                            + ("" if bilateral else ", not bilateral: a hand pushes on it "
                                               "with its palm"))
    if sf.shape == "cylinder":
        return
    depth, thickness = bar_section(sf)
    f_depth, f_thick = _bar_fields(sf)
    if rs.max_bar is None:
        raise SpecError(f_depth, f"{robot.config.name} {limb} ({rs.name}) closes around cylinders only (its "
                                 f"config has no limbs.{limb}.surface.max_bar); {name!r} is a "
                                 f"{depth:.3f} x {thickness:.3f} m rect bar")
    max_depth, max_width = rs.max_bar
    where = (f"a {robot.config.name} hand ({rs.name}) closes around rect bars up to {max_depth:.3f} m deep "
             f"(away from the palm) and {max_width:.3f} m thick (along the palm), limbs.{limb}.surface.max_bar "
             f"of its config; deeper treads are for feet, the hands hold rails")
    if depth > max_depth + 1e-9:
        raise SpecError(f_depth, f"{where}; {name!r} is {depth:.3f} m deep")
    if thickness > max_width + 1e-9:
        raise SpecError(f_thick, f"{where}; {name!r} is {thickness:.3f} m thick")


def grasp_fits(robot: Any, limb: str, sf: Any) -> bool:
    """Whether ``limb``'s grasp can close around ``sf`` (:func:`check_grasp_fits` without the error)."""
    try:
        check_grasp_fits(robot, limb, sf)
    except SpecError:
        return False
    return True


# --------------------------------------------------------------------------------------------
# target poses


def surface_target_pose(robot: Any, env: Any, limb: str, surface_name: str, s: float = 0.0, *,
                        position: np.ndarray | None = None, yaw: float | None = None,
                        params: HoldParams | None = None, R_world_surface_seed: np.ndarray | None = None,
                        robot_surface: str | None = None) -> tuple[np.ndarray, str]:
    """(T_world_surface target of the limb's contact surface frame, kind).

    kind: ``grasp`` | ``sole_cylinder`` | ``sole_bar`` | ``sole_flat`` | ``palm_cylinder`` | ``palm_flat``.
    ``R_world_surface_seed`` (optional, the current orientation of the robot surface) picks
    between the two grasp axis directions. robot_surface: the limb's surface (default primary).
    """
    params = params or HoldParams()
    rs = limb_surface(robot, limb, robot_surface)
    sf = env_surface(env, surface_name)
    forward = ladder_forward(env)
    if not math.isfinite(s):
        raise SpecError("hold.s", f"must be finite, got {s}")
    if rs.kind == "grasp":
        check_grasp_fits(robot, limb, sf, rs.name)
        _check_along(sf, s, surface_name, axis_length=_axis_length(sf))
        p0, a = _cylinder_axis(sf)
        centre = p0 + s * a
        # the palm sits on the robot's side of the rung, grasp_palm_angle_deg above the horizontal;
        # the surface normal (out of the palm, toward the rung axis) points from the palm to the axis
        back = _unit(_perp(-forward, a))
        up = _perp(_perp(WORLD_UP, a), back)
        if np.linalg.norm(up) < 1e-9:
            up = np.cross(a, back)
            up = -up if up[2] < 0.0 else up
        up = _unit(up)
        ang = math.radians(params.grasp_palm_angle_deg) if sf.shape == "cylinder" else _bar_roll(params)
        normal_w = -(math.cos(ang) * back + math.sin(ang) * up)
        axis_s = grasp_axis_in_surface(rs)
        normal_s = _unit(_perp(np.array([0.0, 0.0, 1.0]), axis_s))
        S = np.column_stack([axis_s, np.cross(normal_s, axis_s), normal_s])
        T_fs = np.asarray(rs.T_frame_surface)
        frame_origin_s = -(T_fs[:3, :3].T @ T_fs[:3, 3])
        candidates = []
        for sign in (1.0, -1.0):
            W = np.column_stack([sign * a, np.cross(normal_w, sign * a), normal_w])
            R = W @ S.T
            if R_world_surface_seed is not None:
                score = float(np.trace(R.T @ np.asarray(R_world_surface_seed)))
            else:  # the arm comes from below: the limb frame (wrist side) lowest
                score = -float((R @ frame_origin_s)[2])
            candidates.append((score, sign, R))
        _, _, R = max(candidates, key=lambda c: (c[0], c[1]))
        return _pose(R, centre), "grasp"

    if rs.kind not in ("sole", "palm"):
        raise SpecError(f"robot.{rs.name}.kind", f"unknown contact surface kind {rs.kind!r}")
    sign = sole_normal_sign(robot, limb) if rs.kind == "sole" else 1.0
    if sf.shape == "cylinder" or is_sole_bar(sf, rs):
        _check_along(sf, s, surface_name, axis_length=_axis_length(sf))
        p0, a = _cylinder_axis(sf)
        n = _top_normal(a)
        fwd = _perp(forward, n)
        fwd = _unit(_perp(fwd, a)) if np.linalg.norm(_perp(fwd, a)) > 1e-9 else _unit(np.cross(a, n))
        if sf.shape == "cylinder" and rs.kind == "sole" and params.foot_on_rung_pitch_deg:
            n, fwd = _pitched(n, fwd, params.foot_on_rung_pitch_deg)
        offset = params.foot_on_tread_offset if getattr(sf, "role", "") == "tread" else params.foot_on_rung_offset
        centre = p0 + s * a + n * _top_height(sf) - fwd * offset
        R = _frame_from_zx(-sign * n, fwd)
        return _pose(R, centre), (f"{rs.kind}_cylinder" if sf.shape == "cylinder" else "sole_bar")
    if sf.shape in ("plane", "box"):
        top, n, x_axis = _flat_top(sf)
        if sf.shape == "plane":
            if position is None:
                raise SpecError("hold.position", "a foot on a plane needs the sole centre position")
            p = np.asarray(position, dtype=float).reshape(3)
            centre = p - n * float(n @ (p - top))
        else:
            _check_along(sf, s, surface_name, axis_length=2.0 * float(np.asarray(sf.half_extents)[0]))
            centre = top + s * _unit(_perp(x_axis, n))
            if position is not None:
                p = np.asarray(position, dtype=float).reshape(3)
                centre = p - n * float(n @ (p - top))
        if yaw is None:
            heading = _perp(forward, n)
        else:
            heading = _perp(np.array([math.cos(yaw), math.sin(yaw), 0.0]), n)
        R = _frame_from_zx(-sign * n, heading)
        return _pose(R, centre), f"{rs.kind}_flat"
    raise SpecError("hold.env_surface", f"cannot stand on a {sf.shape} ({surface_name!r})")


def _pitched(n: np.ndarray, fwd: np.ndarray, pitch_deg: float) -> tuple[np.ndarray, np.ndarray]:
    """(contact normal, sole forward) of a sole pitched ``pitch_deg`` toes up on a round rung whose
    top normal is ``n`` (the foot pointing along ``fwd``): both turned about the rung axis, the normal
    leaning back toward the robot (against ``fwd``)."""
    c, s = math.cos(math.radians(pitch_deg)), math.sin(math.radians(pitch_deg))
    return c * n - s * fwd, c * fwd + s * n


def rung_pitch_deg(hold: Hold, env: Any) -> float:
    """[deg] the toes-up pitch a sole hold on a round rung was made with (from its normals: 0 for a
    level sole on the rung's top line)."""
    sf = env_surface(env, hold.env_surface)
    _, a = _cylinder_axis(sf)
    n = _top_normal(a)
    fwd = _unit(np.cross(a, n))
    fwd = fwd if fwd @ ladder_forward(env) >= 0.0 else -fwd
    m = np.asarray(hold.points[0].normal, float)
    return math.degrees(math.atan2(-float(m @ fwd), float(m @ n)))


def _axis_length(sf: Any) -> float:
    """[m] full length of a cylinder or a box along its local x."""
    return float(sf.length) if sf.shape == "cylinder" else 2.0 * float(np.asarray(sf.half_extents)[0])


def _top_height(sf: Any) -> float:
    """[m] top line / face of a cylinder or a bar above its centre line."""
    return float(sf.radius) if sf.shape == "cylinder" else float(np.asarray(sf.half_extents)[2])


def _check_along(sf: Any, s: float, surface_name: str, axis_length: float | None = None) -> None:
    length = float(sf.length) if axis_length is None else axis_length
    if length > 0.0 and abs(s) > 0.5 * length + 1e-9:
        raise SpecError("hold.s", f"must lie on {surface_name!r}: |s| <= {0.5 * length:.3f} m, got {s}")


def frame_pose_from_surface(robot: Any, limb: str, T_world_surface: np.ndarray,
                            robot_surface: str | None = None) -> np.ndarray:
    """Pose of the limb's frame for a given pose of its contact surface frame."""
    rs = limb_surface(robot, limb, robot_surface)
    return np.asarray(T_world_surface) @ _inv(np.asarray(rs.T_frame_surface))


# --------------------------------------------------------------------------------------------
# holds


def make_hold(robot: Any, env: Any, limb: str, surface_name: str, s: float = 0.0, *,
              position: np.ndarray | None = None, yaw: float | None = None,
              friction: float | None = None, grip_force_limit: float | None = None,
              params: HoldParams | None = None, R_world_surface_seed: np.ndarray | None = None,
              robot_surface: str | None = None) -> Hold:
    """The hold of ``limb`` on the environment surface ``surface_name``.

    s: position along the surface axis from its centre [m] (rungs, rails, treads); position /
    yaw: sole (palm) centre [m] and heading [rad] on a plane or box top. friction defaults to the
    surface's (a hand's push: ``push_friction_fraction`` of it), grip_force_limit to the robot's grip strength [N]. robot_surface: the limb's
    surface making the hold (default: the primary one; :func:`robot_surface_for` gives the rule).
    """
    params = params or HoldParams()
    rs = limb_surface(robot, limb, robot_surface)
    sf = env_surface(env, surface_name)
    T, kind = surface_target_pose(robot, env, limb, surface_name, s, position=position, yaw=yaw,
                                  params=params, R_world_surface_seed=R_world_surface_seed,
                                  robot_surface=rs.name)
    mu = float(sf.friction if friction is None else friction)
    if friction is None and rs.kind == "palm":
        mu *= params.push_friction_fraction
    if not (math.isfinite(mu) and mu > 0.0):
        raise SpecError("hold.friction", f"must be a positive finite number, got {mu}")
    if kind == "grasp":
        p0, a = _cylinder_axis(sf)
        centre = T[:3, 3]
        pts = []
        rings = (-0.5 * params.grasp_ring_spacing, 0.5 * params.grasp_ring_spacing)
        if sf.shape == "cylinder":
            r = float(sf.radius)
            u = _top_normal(a)
            w = np.cross(a, u)
            for ring, along in enumerate(rings):
                for k in range(4):
                    ang = 0.5 * math.pi * k + 0.25 * math.pi * ring
                    nrm = math.cos(ang) * u + math.sin(ang) * w
                    pts.append(ContactPoint(centre + along * a + r * nrm, nrm))
        else:  # a bar: ring 1 on the 4 face centres of the cross-section, ring 2 on its 4 edges
            R_sf = np.asarray(sf.T_world_surface)[:3, :3]
            y, z = R_sf[:, 1], R_sf[:, 2]
            hy, hz = (float(v) for v in np.asarray(sf.half_extents)[1:])
            faces = [(hy * y, y), (hz * z, z), (-hy * y, -y), (-hz * z, -z)]
            edges = [(sy * hy * y + sz * hz * z, _unit(sy * y + sz * z))
                     for sy, sz in ((1.0, 1.0), (-1.0, 1.0), (-1.0, -1.0), (1.0, -1.0))]
            for ring, (along, offsets) in enumerate(zip(rings, (faces, edges))):
                for off, nrm in offsets:
                    pts.append(ContactPoint(centre + along * a + off, nrm))
        grip = float(robot.config.grip_strength if grip_force_limit is None else grip_force_limit)
        if not (math.isfinite(grip) and grip >= 0.0):
            raise SpecError("hold.grip_force_limit", f"must be a non-negative finite force [N], got {grip}")
        if limb not in HANDS:
            raise SpecError("hold.limb", f"only hands grasp; got {limb!r}")
        return Hold(limb=limb, robot_surface=rs.name, env_surface=surface_name, points=tuple(pts),
                    friction=mu, bilateral=True, grip_force_limit=grip)
    if kind.endswith("_cylinder") or kind == "sole_bar":
        p0, a = _cylinder_axis(sf)
        n = _top_normal(a)
        if kind == "sole_cylinder" and params.foot_on_rung_pitch_deg:  # where the pitched sole is tangent
            n = -sole_normal_sign(robot, limb) * T[:3, 2]
        centre_line = p0 + a * float(a @ (T[:3, 3] - p0)) + n * _top_height(sf)
        _, width = sole_extent(rs)
        half = 0.5 * (params.foot_on_rung_spacing or width)
        if kind == "sole_bar":  # the paper's Fig. 6: the 4 corners of the top face under the sole
            y = np.asarray(sf.T_world_surface)[:3, 1]
            hy = float(np.asarray(sf.half_extents)[1])
            # the part of the top face's depth the sole covers (a sole shifted off the centre line of a
            # tread as deep as the sole, foot_on_tread_offset: its heel past the nose)
            sole_y = (sole_vertices_in_surface(rs) @ T[:3, :3].T + T[:3, 3] - centre_line) @ y
            lo, hi = max(-hy, float(sole_y.min())), min(hy, float(sole_y.max()))
            if hi - lo < 1e-3:
                raise SpecError("hold.position", f"the {limb} sole does not cover {surface_name!r} (shifted "
                                                 f"{float((T[:3, 3] - centre_line) @ y):.3f} m off its centre line)")
            pts = tuple(ContactPoint(centre_line + sa * half * a + sc * y, n)
                        for sa, sc in ((-1.0, lo), (1.0, lo), (1.0, hi), (-1.0, hi)))
        else:
            pts = tuple(ContactPoint(centre_line + sgn * half * a, n) for sgn in (-1.0, 1.0))
        return Hold(limb=limb, robot_surface=rs.name, env_surface=surface_name, points=pts, friction=mu)
    # flat sole: the corners at the target pose, normal = surface up
    _, n, _ = _flat_top(sf)
    corners = sole_vertices_in_surface(rs) @ T[:3, :3].T + T[:3, 3]
    # put the corners exactly on the surface plane
    corners = corners - np.outer((corners - T[:3, 3]) @ n, n)
    pts = tuple(ContactPoint(c, n) for c in corners)
    return Hold(limb=limb, robot_surface=rs.name, env_surface=surface_name, points=pts, friction=mu)


def hold_from_configuration(robot: Any, env: Any, q: np.ndarray, limb: str, surface_name: str, *,
                            params: HoldParams | None = None, robot_surface: str | None = None,
                            **kwargs: Any) -> Hold:
    """The hold of ``limb`` on ``surface_name`` closest to where the limb is at ``q`` (its contact
    surface, default the primary one, projected on the environment surface)."""
    import pinocchio as pin

    rs = limb_surface(robot, limb, robot_surface)
    kwargs["robot_surface"] = rs.name
    sf = env_surface(env, surface_name)
    data = robot.model.createData()
    pin.framesForwardKinematics(robot.model, data, np.asarray(q, dtype=float))
    T_wf = data.oMf[robot.frame_id(rs.frame)].homogeneous
    T_ws = T_wf @ np.asarray(rs.T_frame_surface)
    if held_along_axis(sf, rs):
        p0, a = _cylinder_axis(sf)
        s = float(a @ (T_ws[:3, 3] - p0))
        half = 0.5 * _axis_length(sf)
        s = min(max(s, -half), half) if half > 0 else s
        return make_hold(robot, env, limb, surface_name, s, params=params,
                         R_world_surface_seed=T_ws[:3, :3], **kwargs)
    _, n, _ = _flat_top(sf)
    heading = _perp(T_ws[:3, 0], n)
    yaw = math.atan2(heading[1], heading[0])
    if sf.shape == "box":
        return make_hold(robot, env, limb, surface_name, 0.0, position=T_ws[:3, 3], yaw=yaw, params=params,
                         **kwargs)
    return make_hold(robot, env, limb, surface_name, position=T_ws[:3, 3], yaw=yaw, params=params, **kwargs)


def hold_kind(robot: Any, env: Any, hold: Hold) -> str:
    """grasp | sole_cylinder | sole_bar | sole_flat | palm_cylinder | palm_flat."""
    rs = hold_surface(robot, hold)
    sf = env_surface(env, hold.env_surface)
    if rs.kind == "grasp":
        return "grasp"
    if is_sole_bar(sf, rs):
        return "sole_bar"
    return f"{rs.kind}_cylinder" if sf.shape == "cylinder" else f"{rs.kind}_flat"


def polygon_normal_sign(robot: Any, limb: str, surface: Any) -> float:
    """+1 if a polygon surface's z points out of the robot (palms, most soles), -1 if a sole's z
    points into the foot (:func:`sole_normal_sign`)."""
    return sole_normal_sign(robot, limb) if surface.kind == "sole" else 1.0


def hold_target(robot: Any, env: Any, hold: Hold, *, params: HoldParams | None = None,
                R_world_surface_seed: np.ndarray | None = None) -> HoldTarget:
    """The limb pose that realises ``hold`` (reconstructed from its points)."""
    rs = hold_surface(robot, hold)
    sf = env_surface(env, hold.env_surface)
    kind = hold_kind(robot, env, hold)
    params = params or HoldParams()
    if kind == "sole_cylinder":  # the pitch the hold was made with, whatever the parameters say now
        params = dataclasses.replace(params, foot_on_rung_pitch_deg=rung_pitch_deg(hold, env))
    if kind == "grasp" or kind.endswith("_cylinder") or kind == "sole_bar":
        p0, a = _cylinder_axis(sf)
        s = float(a @ (hold.centre - p0))
        T, _ = surface_target_pose(robot, env, hold.limb, hold.env_surface, s, params=params,
                                   R_world_surface_seed=R_world_surface_seed, robot_surface=rs.name)
    else:
        T = _fit_sole_pose(robot, hold, rs)
    free = grasp_axis_in_surface(rs) if kind == "grasp" else None
    return HoldTarget(limb=hold.limb, frame=rs.frame, T_world_surface=T,
                      T_world_frame=frame_pose_from_surface(robot, hold.limb, T, rs.name),
                      free_axis_in_surface=free, kind=kind, robot_surface=rs.name)


def _fit_sole_pose(robot: Any, hold: Hold, rs: Any) -> np.ndarray:
    """Rigid pose mapping the sole corners (surface frame) onto the hold points (Kabsch)."""
    v = sole_vertices_in_surface(rs)
    P = hold.positions
    if len(P) != len(v):
        raise SpecError("hold.points", f"a flat sole hold needs {len(v)} points (one per sole corner), "
                                       f"got {len(P)}")
    cv, cp = v.mean(axis=0), P.mean(axis=0)
    H = (v - cv).T @ (P - cp)
    U, _, Vt = np.linalg.svd(H)
    d = np.sign(np.linalg.det(Vt.T @ U.T))
    R = Vt.T @ np.diag([1.0, 1.0, d]) @ U.T
    return _pose(R, cp - R @ cv)


def target_frame_pose(robot: Any, env: Any, limb: str, surface_name: str, s: float = 0.0,
                      **kwargs: Any) -> np.ndarray:
    """T_world_frame of the limb's end-effector frame for a hold on ``surface_name`` at ``s``."""
    params = kwargs.pop("params", None)
    T, _ = surface_target_pose(robot, env, limb, surface_name, s, params=params, **kwargs)
    return frame_pose_from_surface(robot, limb, T, kwargs.get("robot_surface"))

