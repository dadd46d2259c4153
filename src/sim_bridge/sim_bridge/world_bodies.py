"""The environment's static PyBullet bodies: one per surface of a climb_core Environment, and
the friction the simulator's bodies need.

The core (climb_core.environment) holds the geometry and each surface's friction, no simulator
code. PyBullet combines the two bodies' lateral friction coefficients by *product*, so that a
contact's coefficient is set by both: every robot link gets :func:`robot_lateral_friction`, the
square root of the dominant surface's friction (the ladder's, or the ground's without a ladder),
and each surface :func:`surface_lateral_friction`, its friction divided by the robot's. Every
robot-surface contact then has exactly the surface's friction (ladder: sqrt(mu) on both sides;
ground: 0.8 / sqrt(mu)). Any positive robot value gives the same robot-surface coefficients; the
square root keeps the bodies' values near 1 and gives robot-robot and robot-object contacts
(thrown drops) the dominant surface's coefficient.
"""
from __future__ import annotations

import math
from typing import Any

from climb_core.environment import quaternion_xyzw
from climb_core.errors import SpecError

__all__ = ["ROLE_COLOURS", "DEFAULT_COLOUR", "PYBULLET_FRICTION_COMBINATION", "add_environment", "body_pose",
           "pybullet_friction",
           "robot_lateral_friction", "surface_lateral_friction"]

#: how PyBullet combines two bodies' lateral friction coefficients (btCollisionWorld: product)
PYBULLET_FRICTION_COMBINATION = "product"
#: RGBA of the PyBullet visual shapes, per surface role.
ROLE_COLOURS = {
    "ground": (0.85, 0.85, 0.80, 1.0), "rung": (0.60, 0.60, 0.65, 1.0), "tread": (0.55, 0.55, 0.60, 1.0),
    "rail": (0.90, 0.75, 0.10, 1.0), "stringer": (0.85, 0.45, 0.10, 1.0), "platform": (0.50, 0.50, 0.55, 1.0),
    "obstacle": (0.30, 0.45, 0.75, 1.0), "scene": (0.55, 0.65, 0.55, 1.0),
}
#: RGBA of a role without its own colour.
DEFAULT_COLOUR = (0.7, 0.7, 0.7, 1.0)


def pybullet_friction(mu: float, partner: float | None = None) -> float:
    """Lateral friction to give one PyBullet body so that its contacts have coefficient ``mu``:
    sqrt(mu) when both bodies get the same value (``partner=None``), otherwise mu / partner."""
    if not mu > 0.0:
        raise SpecError("friction", f"must be > 0, got {mu!r}")
    return math.sqrt(mu) if partner is None else mu / partner


def robot_lateral_friction(env: Any) -> float:
    """lateralFriction of every robot link (and of thrown objects): sqrt(dominant friction)."""
    return pybullet_friction(env.dominant_friction)


def surface_lateral_friction(env: Any, surface: Any) -> float:
    """lateralFriction of a surface's body, so that robot contacts on it have its friction."""
    return pybullet_friction(surface.friction, partner=robot_lateral_friction(env))


def body_pose(surface: Any) -> tuple[list[float], list[float]]:
    """(position, quaternion xyzw) of a surface's PyBullet body (a plane: the world origin;
    cylinders have their axis along their own z, ``T_world_primitive``)."""
    T = surface.T_world_surface if surface.shape == "plane" else surface.T_world_primitive()
    return T[:3, 3].tolist(), list(quaternion_xyzw(T[:3, :3]))


def _shapes(pb: Any, surface: Any, rgba: list[float], cid: int) -> tuple[int, int]:
    """(collision shape, visual shape) of one surface."""
    if surface.shape == "plane":
        collision = pb.createCollisionShape(pb.GEOM_PLANE, planeNormal=[0, 0, 1], physicsClientId=cid)
        visual = pb.createVisualShape(pb.GEOM_BOX, halfExtents=[surface.half_extents[0], surface.half_extents[1], 5e-4],
                                      visualFramePosition=[0, 0, -5e-4], rgbaColor=rgba, physicsClientId=cid)
    elif surface.shape == "cylinder":
        collision = pb.createCollisionShape(pb.GEOM_CYLINDER, radius=surface.radius, height=surface.length,
                                            physicsClientId=cid)
        visual = pb.createVisualShape(pb.GEOM_CYLINDER, radius=surface.radius, length=surface.length,
                                      rgbaColor=rgba, physicsClientId=cid)
    else:
        half = surface.primitive_half_extents().tolist()
        collision = pb.createCollisionShape(pb.GEOM_BOX, halfExtents=half, physicsClientId=cid)
        visual = pb.createVisualShape(pb.GEOM_BOX, halfExtents=half, rgbaColor=rgba, physicsClientId=cid)
    return collision, visual


def add_environment(env: Any, client_id: int) -> dict[str, int]:
    """Create one static body (mass 0) per surface of ``env`` in PyBullet client ``client_id``.

    Each body's lateralFriction is :func:`surface_lateral_friction`: PyBullet multiplies the two
    bodies' coefficients, so the caller must give every robot link :func:`robot_lateral_friction`
    for robot contacts to have each surface's spec friction (module docstring).
    Restitution, rolling and spinning friction are 0. Returns surface name -> body id.
    """
    try:
        import pybullet as pb
    except ImportError as exc:  # pragma: no cover - pybullet is a project dependency
        raise ImportError("add_environment needs pybullet: pip install pybullet") from exc

    body_ids: dict[str, int] = {}
    for surface in env.surfaces.values():
        collision, visual = _shapes(pb, surface, list(ROLE_COLOURS.get(surface.role, DEFAULT_COLOUR)), client_id)
        position, quaternion = body_pose(surface)
        body = pb.createMultiBody(baseMass=0.0, baseCollisionShapeIndex=collision, baseVisualShapeIndex=visual,
                                  basePosition=position, baseOrientation=quaternion, physicsClientId=client_id)
        pb.changeDynamics(body, -1, lateralFriction=surface_lateral_friction(env, surface), restitution=0.0,
                          rollingFriction=0.0, spinningFriction=0.0, physicsClientId=client_id)
        body_ids[surface.name] = body
    return body_ids
