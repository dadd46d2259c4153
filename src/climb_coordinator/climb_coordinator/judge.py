"""Physical judgement of a climb from the simulator's ground truth (never from the plan or the
controller): which rung each foot stands on, and the contact forces against their friction cones.

Contact rows are PyBullet's (getContactPoints with the robot as body A): the force on the robot of
one point is ``fn n + f1 d1 + f2 d2`` with ``n`` the contact normal on B (pointing B -> robot).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from climb_core.contact import FEET, LIMBS


@dataclass(frozen=True)
class LimbLoad:
    limb: str
    surface: str  # environment surface carrying most of the limb's normal force
    force_in_world: np.ndarray  # (3,) [N] total force of the environment on the limb
    normal_in_world: np.ndarray  # (3,) force-weighted mean contact normal (surface -> limb)
    normal_force: float  # [N] force along that normal (>= 0: unilateral)
    tangential_force: float  # [N]

    @property
    def friction_ratio(self) -> float:
        """[-] tangential / normal force (the cone holds when <= mu)."""
        return self.tangential_force / self.normal_force if self.normal_force > 1e-9 else 0.0


def _surface_names(backend) -> dict[int, str]:
    names = {body: name for name, body in backend.env_bodies.items()}
    names[backend.ground_body] = "ground"
    return names


def limb_loads(backend) -> dict[str, LimbLoad]:
    """Per limb (links of the limb's subtree): the environment's force, its mean normal and the
    normal / tangential split; limbs without contact are absent."""
    p = backend.p
    names = _surface_names(backend)
    link_limb = backend.link_limb
    acc: dict[str, dict] = {}
    for c in p.getContactPoints(bodyA=backend.body, physicsClientId=backend.client):
        surface = names.get(c[2])
        limb = link_limb.get(c[3])
        if surface is None or limb not in LIMBS:
            continue
        n = np.asarray(c[7])
        f = c[9] * n + c[10] * np.asarray(c[11]) + c[12] * np.asarray(c[13])
        a = acc.setdefault(limb, {"f": np.zeros(3), "n": np.zeros(3), "by_surface": {}})
        a["f"] += f
        a["n"] += c[9] * n
        a["by_surface"][surface] = a["by_surface"].get(surface, 0.0) + c[9]
    out = {}
    for limb, a in acc.items():
        norm = np.linalg.norm(a["n"])
        if norm < 1e-9:
            continue
        n = a["n"] / norm
        fn = float(a["f"] @ n)
        ft = float(np.linalg.norm(a["f"] - fn * n))
        surface = max(a["by_surface"], key=a["by_surface"].get)
        out[limb] = LimbLoad(limb, surface, a["f"].copy(), n, fn, ft)
    return out


class ConeUse:
    """Largest friction-cone use (tangential / (mu normal), <= 1 inside the cone) of each limb's
    unilateral contact over a run, from per-limb loads as sim/contacts carries them (or as
    :func:`limb_loads` measures them in process). Grasped hands (bilateral) and loads under
    ``force_min`` [N] (touch transients) are not judged; a surface without a friction is skipped."""

    def __init__(self, surface_mu: dict[str, float], force_min: float):
        self.surface_mu = dict(surface_mu)
        self.force_min = float(force_min)
        self.max_use: dict[str, float] = {}
        self.samples = 0

    def add(self, limb: str, normal: float, tangential: float, surface: str, grasped: bool) -> bool:
        """One load [N] of ``limb`` on ``surface``; True when it was judged."""
        mu = self.surface_mu.get(surface)
        if grasped or not mu or normal < self.force_min:
            return False
        use = tangential / (mu * normal)
        if use > self.max_use.get(limb, -1.0):
            self.max_use[limb] = use
        self.samples += 1
        return True

    def add_contacts(self, msg) -> None:
        """One climb_msgs/SimContacts."""
        for i, limb in enumerate(msg.limbs):
            self.add(limb, float(msg.normal_force[i]), float(msg.tangential_force[i]), msg.surface[i],
                     bool(msg.grasped[i]))

    def summary(self) -> dict[str, float]:
        """limb -> largest cone use [-] (rounded as in the climb summary)."""
        return {limb: round(v, 3) for limb, v in sorted(self.max_use.items())}


def rung_index(surface: str) -> int | None:
    """rung_3 -> 3, ground -> 0, anything else -> None."""
    if surface == "ground":
        return 0
    if surface.startswith("rung_") and surface[5:].isdigit():
        return int(surface[5:])
    return None


def feet_rungs(backend, foot_force_min: float, loads: dict[str, LimbLoad] | None = None) -> dict[str, int | None]:
    """foot -> the rung (0 = ground) it stands on with at least ``foot_force_min`` [N] of
    normal force, None when it is not standing on a rung or the ground."""
    loads = limb_loads(backend) if loads is None else loads
    out = {}
    for foot in FEET:
        load = loads.get(foot)
        if load is None or load.normal_force < foot_force_min:
            out[foot] = None
        else:
            out[foot] = rung_index(load.surface)
    return out


def rungs_reached(feet: dict[str, int | None]) -> int:
    """Highest rung with both feet on it (0: none / the ground)."""
    values = [feet.get(f) for f in FEET]
    if any(v is None for v in values) or values[0] != values[1]:
        return 0
    return int(values[0])


def foot_pose_check(backend, foot: str, rung: int) -> dict:
    """Sole centre relative to the rung: horizontal offset from the rung axis across the ladder
    [m] and height above the rung top [m] (the test's pose check, independent of the contacts)."""
    T_rung = backend.surface_frame(f"rung_{rung}")
    surface = backend.env.surfaces[f"rung_{rung}"]
    sole = backend.surface_pose(foot)[:3, 3]
    axis = T_rung[:3, 0]
    d = sole - T_rung[:3, 3]
    d_perp = d - (d @ axis) * axis
    return {"horizontal_offset": float(np.hypot(d_perp[0], d_perp[1])),
            "height_above_top": float(sole[2] - (T_rung[2, 3] + surface.radius)),
            "along_rung": float(d @ axis)}
