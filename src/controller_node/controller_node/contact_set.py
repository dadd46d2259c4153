"""The controller's active contact set: which limb holds what, and the force ramps between.

A :class:`ContactSet` keeps, per limb, the QP's :class:`~controller_node.constraints.ActiveContact`,
the :class:`~climb_core.contact.Hold` it was made from, the limb's last solved load, and a
:class:`Ramp` while a contact engages (its share of the load grows from 0 to 1 over
``contacts.engage_ramp_s``) or is released (its force cap falls from the load it carried to 0
over ``contacts.release_ramp_s``). Time is passed in, so the set is tested without a controller
(tests/unit/test_contact_set.py); the controller builds the ActiveContacts (they need the robot's
kinematics) and reports the events.
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any, Iterable

import numpy as np

from climb_core.contact import LIMBS, Hold

from .constraints import ActiveContact


@dataclass
class Ramp:
    kind: str  # release | engage
    start: float  # [s]
    duration: float  # [s]
    cap0: Any = None  # release: load at the start (N or per-component wrench)

    def fraction(self, t: float) -> float:
        return 1.0 if self.duration <= 0 else min(max((t - self.start) / self.duration, 0.0), 1.0)


def mean_normal(contact: ActiveContact) -> np.ndarray:
    """Unit mean of a unilateral contact's normals in world axes (+z without points)."""
    if len(contact.normals_in_world) == 0:
        return np.array([0.0, 0.0, 1.0])
    n = contact.normals_in_world.mean(axis=0)
    return n / np.linalg.norm(n)


class ContactSet:
    def __init__(self) -> None:
        self.active: dict[str, ActiveContact] = {}  # limb -> the QP's contact
        self.holds: dict[str, Hold] = {}  # limb -> the hold it was made from
        self.ramps: dict[str, Ramp] = {}  # limb -> engage / release ramp in progress
        self.last_loads: dict[str, np.ndarray] = {}  # limb -> last solved wrench in world axes

    # -- queries
    def has(self, limb: str) -> bool:
        return limb in self.active

    def limbs(self) -> tuple[str, ...]:
        """The limbs in contact, in the fixed LIMBS order (the QP's variable order)."""
        return tuple(limb for limb in LIMBS if limb in self.active)

    def ordered(self) -> list[ActiveContact]:
        return [self.active[limb] for limb in LIMBS if limb in self.active]

    def ready(self, limb: str, now: float) -> bool:
        """No ramp, or the limb's ramp has run its course."""
        ramp = self.ramps.get(limb)
        return ramp is None or ramp.fraction(now) >= 1.0

    def release_done(self, limb: str, now: float) -> bool:
        ramp = self.ramps.get(limb)
        return ramp is None or (ramp.kind == "release" and ramp.fraction(now) >= 1.0)

    # -- changes
    def clear(self) -> None:
        """No contact, no ramp (the last loads stay: a release cap starts from them)."""
        self.active.clear()
        self.holds.clear()
        self.ramps.clear()

    def put(self, limb: str, hold: Hold, contact: ActiveContact, now: float, engage_s: float = 0.0) -> None:
        """``contact`` becomes the limb's, carrying nothing at first when ``engage_s`` > 0."""
        if engage_s > 0:
            contact.scale = 0.0
            self.ramps[limb] = Ramp("engage", now, engage_s)
        self.active[limb] = contact
        self.holds[limb] = hold

    def begin_release(self, limb: str, now: float, duration: float) -> bool:
        """Start lowering the limb's force cap from the load it carries (plus a margin) to 0.
        False when the limb has no contact."""
        contact = self.active.get(limb)
        if contact is None:
            return False
        load = self.last_loads.get(limb)
        if contact.bilateral:
            # (force norm, largest moment component) carried now, plus a margin
            cap0 = (np.array([np.linalg.norm(load[:3]) + 1.0, np.max(np.abs(load[3:])) + 0.5])
                    if load is not None else np.array([contact.force_limit, contact.torque_limit]))
        else:
            cap0 = float(np.dot(load[:3], mean_normal(contact))) + 1.0 if load is not None else contact.force_limit
        self.ramps[limb] = Ramp("release", now, duration, cap0)
        return True

    def remove(self, limb: str) -> bool:
        """The limb's contact and ramp are gone; False when it had none."""
        if self.active.pop(limb, None) is None:
            return False
        self.ramps.pop(limb, None)
        return True

    def advance(self, now: float) -> None:
        """Each ramp's scale / force cap at ``now``; finished engage ramps end."""
        for limb, ramp in list(self.ramps.items()):
            contact = self.active.get(limb)
            if contact is None:
                del self.ramps[limb]
                continue
            f = ramp.fraction(now)
            if ramp.kind == "engage":
                contact.scale = f
                contact.ramp_cap = None
                if f >= 1.0:
                    del self.ramps[limb]
            else:
                remaining = 1.0 - f
                contact.scale = remaining if not contact.bilateral else 1.0
                contact.ramp_cap = ramp.cap0 * remaining

    def shift(self, limb: str, in_frame: np.ndarray, in_world: np.ndarray, friction_margin: float,
              generators_per_point: int, normal: np.ndarray | None = None) -> None:
        """Move a unilateral contact's points (and its hold's) by ``in_frame`` in the limb frame /
        ``in_world``, and give every point the unit ``normal`` (world) when one is given: the contact
        found elsewhere under the limb than planned; its ramp goes on."""
        c, hold = self.active[limb], self.holds[limb]
        normals = c.normals_in_world if normal is None else np.tile(normal, (len(c.normals_in_world), 1))
        # a new object: the QP's workspace caches each contact's reference point by identity
        c = replace(c, points_in_frame=c.points_in_frame + in_frame, reference_in_frame=c.reference_in_frame + in_frame,
                    normals_in_world=normals)
        c.setup_generators(friction_margin, generators_per_point)
        self.active[limb] = c
        points = tuple(type(p)(np.asarray(p.position, float) + in_world, p.normal if normal is None else normal)
                       for p in hold.points)
        self.holds[limb] = Hold(hold.limb, hold.robot_surface, hold.env_surface, points, hold.friction,
                                hold.bilateral, hold.grip_force_limit)

    def restore(self, contacts: dict[str, ActiveContact], holds: dict[str, Hold]) -> None:
        """Contacts of an earlier snapshot that are gone come back (a plan abandoned mid-release)."""
        for limb, contact in contacts.items():
            if limb not in self.active:
                self.active[limb] = contact
                self.holds[limb] = holds[limb]

    def cancel(self, kinds: Iterable[str] = ("release",)) -> list[str]:
        """Ramps of these kinds end with their contacts at full share; returns their limbs."""
        kinds = tuple(kinds)
        limbs = [limb for limb, ramp in self.ramps.items() if ramp.kind in kinds]
        for limb in limbs:
            del self.ramps[limb]
            contact = self.active.get(limb)
            if contact is not None:
                contact.scale, contact.ramp_cap = 1.0, None
        return limbs
