"""The environment's static PyBullet bodies: one per surface of a climb_core Environment.

The core (climb_core.environment) holds the geometry and the friction rule, no simulator code;
this module turns each surface into a static PyBullet body with the friction that rule gives.
"""
from __future__ import annotations

from typing import Any

__all__ = ["ROLE_COLOURS", "DEFAULT_COLOUR", "add_environment"]

#: RGBA of the PyBullet visual shapes, per surface role.
ROLE_COLOURS = {
    "ground": (0.85, 0.85, 0.80, 1.0), "rung": (0.60, 0.60, 0.65, 1.0), "tread": (0.55, 0.55, 0.60, 1.0),
    "rail": (0.90, 0.75, 0.10, 1.0), "stringer": (0.85, 0.45, 0.10, 1.0), "platform": (0.50, 0.50, 0.55, 1.0),
    "obstacle": (0.30, 0.45, 0.75, 1.0), "scene": (0.55, 0.65, 0.55, 1.0),
}
#: RGBA of a role without its own colour.
DEFAULT_COLOUR = (0.7, 0.7, 0.7, 1.0)


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

    Each body's lateralFriction is ``env.pybullet_lateral_friction(surface)``: PyBullet multiplies
    the two bodies' coefficients, so the caller must give every robot link
    ``env.robot_lateral_friction`` for robot contacts to have each surface's spec friction.
    Restitution, rolling and spinning friction are 0. Returns surface name -> body id.
    """
    try:
        import pybullet as pb
    except ImportError as exc:  # pragma: no cover - pybullet is a project dependency
        raise ImportError("add_environment needs pybullet: pip install pybullet") from exc

    body_ids: dict[str, int] = {}
    for surface in env.surfaces.values():
        collision, visual = _shapes(pb, surface, list(ROLE_COLOURS.get(surface.role, DEFAULT_COLOUR)), client_id)
        position, quaternion = surface.pybullet_pose()
        body = pb.createMultiBody(baseMass=0.0, baseCollisionShapeIndex=collision, baseVisualShapeIndex=visual,
                                  basePosition=position, baseOrientation=quaternion, physicsClientId=client_id)
        pb.changeDynamics(body, -1, lateralFriction=env.pybullet_lateral_friction(surface), restitution=0.0,
                          rollingFriction=0.0, spinningFriction=0.0, physicsClientId=client_id)
        body_ids[surface.name] = body
    return body_ids
