"""Grasps as force-limited constraints (the documented modelling assumption, docs/sim_bridge.md).

A CLOSE request on a hand whose grasp centre is within the robot's ``capture_range`` of a rung or
rail axis (a rect rung's centre line, when the bar fits the hand) latches the grasp: a PyBullet fixed constraint between the hand's surface link and the
rung body, anchored on the axis (``grasp.snap_to_axis``) with the hand's current orientation.
The grip strength bounds the norm of the grasp's force: PyBullet caps each constraint row
separately (one ``maxForce`` for every row), which alone would let a diagonal load through up to
sqrt(3) times the grip strength. After every physics step the cap is therefore set to the grip
strength times the largest row share of the last applied force's direction, max_i |f_i| / |f|
(between 1/sqrt(3) and 1): a load in a steady direction saturates exactly when its norm reaches
the grip strength, and an overloaded grasp slides. When the grasp centre has slid farther than the capture
range from its anchor, the fingers have lost the rung: the grasp is reported as slipped and
released. The fingers are driven closed (finger joints, position servo) but they never carry the
load; collisions between the hand's links and the grasped body are off while latched and come
back once they no longer overlap after release.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from climb_core import holds

from . import frames
from .params import GraspParams

if TYPE_CHECKING:  # pragma: no cover
    from .pybullet_backend import PyBulletBackend

GRASPABLE_ROLES = ("rung", "rail", "scene")  # roles a hand may close around (when bilateral): a ladder's, a scene's


def graspable(surface) -> bool:
    """A hand may close around ``surface``: a bilateral ladder rung or rail, or a scene surface
    tagged ``bilateral`` (a handrail, a roll-cage bar: scene_spec.md). Whether the hand fits
    around it is :func:`climb_core.holds.grasp_fits`."""
    return bool(getattr(surface, "bilateral", False)) and surface.role in GRASPABLE_ROLES


@dataclass
class Grasp:
    hand: str
    surface: str  # environment surface name
    body: int  # PyBullet body of the surface
    constraint: int  # PyBullet constraint id
    anchor_in_body: np.ndarray  # (3,) [m] the anchor point in the surface body's frame
    distance_at_latch: float  # [m] grasp centre to axis when it latched
    anchor_in_world: np.ndarray | None = None  # (3,) [m] cache of anchor_world() (None: to compute)
    row_cap: float = 0.0  # [N] the constraint's maxForce now (norm_cap())


@dataclass
class GraspManager:
    backend: "PyBulletBackend"
    params: GraspParams
    latched: dict[str, Grasp] = field(default_factory=dict)
    _filtered: list[tuple[str, int]] = field(default_factory=list)  # (hand, body) collisions to restore

    # -- geometry -----------------------------------------------------------------------------
    def nearest_axis_point(self, hand: str) -> tuple[str, np.ndarray, float]:
        """(surface name, closest point on its axis segment [m], distance [m]) over every rung, rail
        and bilateral scene surface the hand closes around (a round one, or a rect bar within the hand's ``max_bar``:
        ``climb_core.holds.grasp_fits``; the axis of a bar is its centre line); ("", centre, inf)
        when the ladder has none."""
        b = self.backend
        centre = b.surface_pose(hand)[:3, 3]
        best = ("", centre, float("inf"))
        for name, surface in b.env.surfaces.items():
            if not graspable(surface) or not holds.grasp_fits(b.robot, hand, surface):
                continue
            T = b.surface_frame(name)
            axis = T[:3, 0]
            s = float(np.clip(axis @ (centre - T[:3, 3]), -0.5 * surface.length, 0.5 * surface.length))
            point = T[:3, 3] + s * axis
            dist = float(np.linalg.norm(centre - point))
            if dist < best[2]:
                best = (name, point, dist)
        return best

    # -- requests -----------------------------------------------------------------------------
    def close(self, hand: str, fraction: float) -> None:
        b = self.backend
        b.set_finger_target(hand, fraction)
        if hand in self.latched:
            return
        name, point, dist = self.nearest_axis_point(hand)
        capture = b.robot.config.capture_range
        if dist > capture:
            where = f"nearest graspable surface {name} is {dist * 100:.1f} cm away" if name else "no rung or rail"
            b._emit("grasp_failed", f"{hand}: close without latching: {where} (capture range "
                    f"{capture * 100:.1f} cm)", 1, hand=hand, distance_m=f"{dist:.4f}")
            return
        self._latch(hand, name, point if self.params.snap_to_axis else b.surface_pose(hand)[:3, 3], dist)

    def open(self, hand: str) -> None:
        self.backend.set_finger_target(hand, 0.0)
        self.release(hand, "opened")

    def position(self, hand: str, fraction: float) -> None:
        self.backend.set_finger_target(hand, fraction)
        if fraction < self.params.release_position:
            self.release(hand, f"fingers opened to {fraction:.2f}")

    # -- constraint ---------------------------------------------------------------------------
    def _latch(self, hand: str, surface: str, anchor_world: np.ndarray, dist: float) -> None:
        b = self.backend
        p, cid = b.p, b.client
        link = b.limb_link[hand]
        body = b.env_bodies[surface]
        T_inertial_surface = frames.inverse(b.T_link_inertial[link]) @ b.T_link_surface[hand]
        pos, orn = p.getBasePositionAndOrientation(body, physicsClientId=cid)
        T_world_body = frames.pose_matrix(pos, orn)
        R_world_hand_surface = b.surface_pose(hand)[:3, :3]
        anchor_in_body = T_world_body[:3, :3].T @ (anchor_world - T_world_body[:3, 3])
        R_body_frame = T_world_body[:3, :3].T @ R_world_hand_surface
        constraint = p.createConstraint(
            b.body, link, body, -1, p.JOINT_FIXED, [0.0, 0.0, 0.0],
            parentFramePosition=T_inertial_surface[:3, 3].tolist(),
            childFramePosition=anchor_in_body.tolist(),
            parentFrameOrientation=frames.matrix_to_quat(T_inertial_surface[:3, :3]).tolist(),
            childFrameOrientation=frames.matrix_to_quat(R_body_frame).tolist(), physicsClientId=cid)
        p.changeConstraint(constraint, maxForce=b.grip_strength, erp=self.params.constraint_erp, physicsClientId=cid)
        self._set_hand_collision(hand, body, False)
        self._filtered = [(h, bd) for h, bd in self._filtered if not (h == hand and bd == body)]
        self.latched[hand] = Grasp(hand, surface, body, constraint, anchor_in_body, dist, row_cap=b.grip_strength)
        b._emit("grasp", f"{hand} latched on {surface} ({dist * 100:.1f} cm from its axis, grip "
                f"{b.grip_strength:.0f} N)", 0, hand=hand, surface=surface, distance_m=f"{dist:.4f}")

    def release(self, hand: str, why: str) -> None:
        grasp = self.latched.pop(hand, None)
        if grasp is None:
            return
        b = self.backend
        b.p.removeConstraint(grasp.constraint, physicsClientId=b.client)
        self._filtered.append((hand, grasp.body))
        kind = "slip" if why.startswith("slipped") else "release"
        b._emit(kind, f"{hand} released {grasp.surface}: {why}", 2 if kind == "slip" else 0,
                hand=hand, surface=grasp.surface)

    def set_max_force(self, newtons: float) -> None:
        """A new grip strength [N] (the backend's ``grip_strength``): the caps follow it."""
        for grasp in self.latched.values():
            self._set_row_cap(grasp, newtons)
            self.norm_cap(grasp)

    def _set_row_cap(self, grasp: Grasp, newtons: float) -> None:
        b = self.backend
        b.p.changeConstraint(grasp.constraint, maxForce=newtons, physicsClientId=b.client)
        grasp.row_cap = newtons

    def norm_cap(self, grasp: Grasp) -> None:
        """Cap the constraint's rows so that the norm of its force stays within the grip strength:
        ``maxForce`` = grip strength * max_i |f_i| / |f| for the direction of the last applied
        force f (its three linear rows); the grip strength itself while f is under 1 N. Changed
        only when it moves by more than 1 %."""
        b = self.backend
        limit = b.grip_strength
        f = b.p.getConstraintState(grasp.constraint, physicsClientId=b.client)[:3]
        norm = math.sqrt(f[0] * f[0] + f[1] * f[1] + f[2] * f[2])
        cap = limit * max(abs(f[0]), abs(f[1]), abs(f[2])) / norm if norm > 1.0 else limit
        if abs(cap - grasp.row_cap) > 0.01 * limit:
            self._set_row_cap(grasp, cap)

    def surface_moved(self, name: str, offset: np.ndarray) -> None:
        """A rung / rail was moved: its anchors are in its body frame and follow it."""
        for grasp in self.latched.values():
            if grasp.surface == name:
                grasp.anchor_in_world = None

    def anchor_world(self, grasp: Grasp) -> np.ndarray:
        """(3,) [m] the grasp's anchor in the world (read-only: cached, the rungs and rails are
        static bodies that only move through surface_moved())."""
        if grasp.anchor_in_world is None:
            b = self.backend
            pos, orn = b.p.getBasePositionAndOrientation(grasp.body, physicsClientId=b.client)
            grasp.anchor_in_world = frames.pose_matrix(pos, orn)[:3, :3] @ grasp.anchor_in_body + np.asarray(pos)
        return grasp.anchor_in_world

    def slide(self, hand: str) -> float:
        """[m] distance between the hand's grasp centre and its anchor."""
        return self._slide(self.latched[hand], self.backend.surface_pose(hand))

    def _slide(self, grasp: Grasp, T_world_surface: np.ndarray) -> float:
        """[m] slide() given the hand's current T_world_surface."""
        d = T_world_surface[:3, 3] - self.anchor_world(grasp)
        return math.sqrt(d.dot(d))  # = np.linalg.norm(d), without its argument checks

    def cap_norms(self) -> None:
        """After every physics step: each latched grasp's row cap for the norm (norm_cap())."""
        for grasp in self.latched.values():
            self.norm_cap(grasp)

    def update(self) -> None:
        """Once per tick: slipped grasps are lost; released hands get their collisions back."""
        b = self.backend
        capture = b.robot.config.capture_range
        hands = list(self.latched)
        for hand, T_world_surface in zip(hands, b.surface_poses(hands) if hands else ()):
            grasp = self.latched[hand]
            slide = self._slide(grasp, T_world_surface)
            if slide > capture + grasp.distance_at_latch:
                self.release(hand, f"slipped {slide * 100:.1f} cm (grip strength {b.grip_strength:.0f} N exceeded)")
        still = []
        for hand, body in self._filtered:
            if hand in self.latched and self.latched[hand].body == body:
                continue
            if self._overlaps(hand, body):
                still.append((hand, body))
            else:
                self._set_hand_collision(hand, body, True)
        self._filtered = still

    def _overlaps(self, hand: str, body: int) -> bool:
        b = self.backend
        return any(b.p.getClosestPoints(b.body, body, 0.0, linkIndexA=link, physicsClientId=b.client)
                   for link in b.limb_links[hand])

    def _set_hand_collision(self, hand: str, body: int, enable: bool) -> None:
        b = self.backend
        for link in b.limb_links[hand]:
            b.p.setCollisionFilterPair(b.body, body, link, -1, int(enable), physicsClientId=b.client)

    def latched_surfaces(self) -> dict[str, str]:
        return {hand: (self.latched[hand].surface if hand in self.latched else "") for hand in ("left_hand", "right_hand")}

    def constraint_force(self, hand: str) -> np.ndarray:
        """The constraint's applied force/torque of a latched grasp (PyBullet getConstraintState)."""
        grasp = self.latched[hand]
        return np.asarray(self.backend.p.getConstraintState(grasp.constraint, physicsClientId=self.backend.client))
