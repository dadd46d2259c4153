"""Holds, stances and plans as plain dataclasses (the library side of climb_msgs).

Frames: every position and normal is in the world frame, SI units. A hold is a set of point
contacts between one robot contact surface and one environment surface:
- hand grasp on a rung or rail: 8 points around the cylinder, bilateral (no friction cone, a
  grip-force limit instead);
- foot on a rectangular tread or on flat ground: 4 sole corners, unilateral;
- foot on a cylindrical rung: 2 points along the rung line under the sole, unilateral.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

#: Limb names used everywhere (robot configs, holds, FSM, messages).
LIMBS = ("left_foot", "right_foot", "left_hand", "right_hand")
FEET = ("left_foot", "right_foot")
HANDS = ("left_hand", "right_hand")


def limb_type(limb: str) -> str:
    """``foot`` or ``hand``: the limb type a surface's ``contact`` list names (SpecError otherwise)."""
    if limb in FEET:
        return "foot"
    if limb in HANDS:
        return "hand"
    from climb_core.errors import SpecError

    raise SpecError("limb", f"must be one of {', '.join(LIMBS)}; got {limb!r}")


@dataclass(frozen=True)
class ContactPoint:
    position: np.ndarray  # [m] world frame, shape (3,)
    normal: np.ndarray  # unit normal of the environment surface toward the robot, shape (3,)

    def __post_init__(self) -> None:
        object.__setattr__(self, "position", np.asarray(self.position, dtype=float).reshape(3))
        n = np.asarray(self.normal, dtype=float).reshape(3)
        norm = np.linalg.norm(n)
        object.__setattr__(self, "normal", n / norm if norm > 0 else n)

    def __eq__(self, other: object) -> bool:
        return (isinstance(other, ContactPoint) and np.allclose(self.position, other.position)
                and np.allclose(self.normal, other.normal))

    __hash__ = None  # type: ignore[assignment]


@dataclass(frozen=True)
class Hold:
    limb: str  # one of LIMBS
    robot_surface: str  # e.g. "left_sole", "right_grasp"
    env_surface: str  # e.g. "rung_3", "rail_left", "ground"
    points: tuple[ContactPoint, ...]
    friction: float  # Coulomb coefficient [-]
    bilateral: bool = False  # closed grasp: pull allowed, no friction cone
    grip_force_limit: float = 0.0  # [N] max force through the grasp (bilateral only)
    # a closed grasp as it latched: T_world_surface (4x4, nested tuples) of the robot's grasp surface.
    # A grasp's roll about its rung is free while the hand comes to it (the IK chooses it); once the
    # hand has closed, the roll is fixed and every later configuration holding it keeps this pose.
    # None: not latched (the roll stays free). Planning-time only: not serialised, not compared.
    pose: tuple | None = field(default=None, compare=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "points", tuple(self.points))

    @property
    def positions(self) -> np.ndarray:
        """(n, 3) contact point positions [m]."""
        return np.array([p.position for p in self.points]).reshape(-1, 3)

    @property
    def normals(self) -> np.ndarray:
        return np.array([p.normal for p in self.points]).reshape(-1, 3)

    @property
    def centre(self) -> np.ndarray:
        return self.positions.mean(axis=0)


@dataclass(frozen=True)
class Stance:
    holds: tuple[Hold, ...]
    name: str = ""

    def __post_init__(self) -> None:
        object.__setattr__(self, "holds", tuple(self.holds))
        limbs = [h.limb for h in self.holds]
        if len(set(limbs)) != len(limbs):
            raise ValueError(f"stance {self.name!r}: a limb appears in two holds: {limbs}")

    @property
    def limbs(self) -> tuple[str, ...]:
        return tuple(h.limb for h in self.holds)

    def hold(self, limb: str) -> Hold | None:
        for h in self.holds:
            if h.limb == limb:
                return h
        return None

    def without(self, limb: str) -> "Stance":
        return Stance(tuple(h for h in self.holds if h.limb != limb), name=f"{self.name}-{limb}")

    def with_hold(self, hold: Hold) -> "Stance":
        return Stance(tuple(h for h in self.holds if h.limb != hold.limb) + (hold,), name=self.name)

    def with_surface_offsets(self, offsets: dict[str, Any]) -> "Stance":
        """The holds on surfaces of ``offsets`` (name -> world translation [m], see
        ``Environment.with_surface_offsets``) moved with their surface; the others as they are."""
        holds = []
        for h in self.holds:
            d = offsets.get(h.env_surface)
            if d is not None:
                d = np.asarray(d, dtype=float)
                h = replace(h, points=tuple(replace(p, position=np.asarray(p.position, float) + d) for p in h.points))
            holds.append(h)
        return Stance(tuple(holds), name=self.name)


@dataclass
class GuidePath:
    robot: str
    environment: str
    joint_names: list[str]
    milestones: list[np.ndarray]  # Pinocchio configurations (nq,)


@dataclass
class ContactPlan:
    robot: str
    environment: str
    joint_names: list[str]
    stances: list[Stance]
    transition_configurations: list[np.ndarray]  # same length as stances


@dataclass
class Transition:
    primitive: str  # mount | com_to_foot | com_to_centre | place_foot | place_hand | dismount | ...
    moving_limb: str  # "" for a CoM shift
    stance: Stance  # holds kept during the path
    target_stance: Stance  # stance reached at the end
    times: np.ndarray  # [s] (n,)
    path: np.ndarray  # (n, nq) Pinocchio configurations


@dataclass
class WholeBodyPlan:
    robot: str
    environment: str
    joint_names: list[str]
    initial_stance: Stance
    transitions: list[Transition] = field(default_factory=list)
