"""The simulator's ground truth of the contacts, for a judge that reads topics only (no ROS here).

The node publishes it as ``sim/contacts`` (climb_msgs/SimContacts, sim-only): per limb (LIMBS
order) the total normal and tangential force the environment applies on the limb's links, the
surface carrying most of the normal force and its rung index, whether the hand's grasp is latched,
and the fall flag. Same computation as climb_coordinator.judge.limb_loads (PyBullet contact rows,
the robot as body A: the force on the robot of one point is ``fn n + f1 d1 + f2 d2``, ``n`` the
contact normal on B pointing B -> robot); grasp constraint forces are not contact forces, so a
hand hanging on a latched grasp may carry no normal force: ``grasped`` and ``surface`` say where
it holds.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from climb_core.contact import HANDS, LIMBS


@dataclass(frozen=True)
class LimbContact:
    limb: str
    normal_force: float  # [N] along the force-weighted mean contact normal (surface -> limb), >= 0
    tangential_force: float  # [N] norm of the rest of the total force
    surface: str  # surface carrying most of the limb's normal force; the latched one for a grasp; '' = none
    rung: int  # rung index of that surface (1 = lowest); -1 = ground, not a rung, or none
    grasped: bool  # a hand's grasp is latched on ``surface``


@dataclass(frozen=True)
class ContactsSnapshot:
    stamp_ns: int  # [ns] sim time
    limbs: tuple[LimbContact, ...]  # LIMBS order
    fell: bool
    fall_reason: str

    def limb(self, name: str) -> LimbContact:
        return next(c for c in self.limbs if c.limb == name)


def rung_of(surface: str) -> int:
    """rung_3 -> 3; anything else (ground, rail_left, '') -> -1."""
    if surface.startswith("rung_") and surface[5:].isdigit():
        return int(surface[5:])
    return -1


def contacts_snapshot(backend) -> ContactsSnapshot:
    """The contacts of a PyBulletBackend's current physics state (one getContactPoints call)."""
    names = {body: name for name, body in backend.env_bodies.items()}
    if backend.ground_body >= 0:
        names[backend.ground_body] = "ground"
    link_limb = backend.link_limb
    force = {limb: np.zeros(3) for limb in LIMBS}
    normal = {limb: np.zeros(3) for limb in LIMBS}
    by_surface: dict[str, dict[str, float]] = {limb: {} for limb in LIMBS}
    for c in backend.p.getContactPoints(bodyA=backend.body, physicsClientId=backend.client):
        surface = names.get(c[2])
        limb = link_limb.get(c[3])
        if surface is None or limb not in force:
            continue
        n = np.asarray(c[7])
        force[limb] += c[9] * n + c[10] * np.asarray(c[11]) + c[12] * np.asarray(c[13])
        normal[limb] += c[9] * n
        by_surface[limb][surface] = by_surface[limb].get(surface, 0.0) + c[9]
    latched = backend.grasps.latched_surfaces() if getattr(backend, "grasps", None) is not None else {}
    out = []
    for limb in LIMBS:
        fn = ft = 0.0
        norm = float(np.linalg.norm(normal[limb]))
        surface = ""
        if norm > 1e-9:
            n = normal[limb] / norm
            fn = max(float(force[limb] @ n), 0.0)
            ft = float(np.linalg.norm(force[limb] - (force[limb] @ n) * n))
            surface = max(by_surface[limb], key=by_surface[limb].get)
        grasped = bool(limb in HANDS and latched.get(limb))
        if grasped:
            surface = latched[limb]
        out.append(LimbContact(limb, fn, ft, surface, rung_of(surface), grasped))
    return ContactsSnapshot(int(backend.stamp_ns), tuple(out), bool(backend.fell), str(backend.fall_reason))
