"""``climb/markers``: the climb as a visualization_msgs/MarkerArray for RViz (message building
only, no node; the coordinator publishes it).

Namespaces (each marker in the ``world`` frame):
- ``scene``: the environment's surfaces: rungs and rails as cylinders, treads / platforms /
  obstacles as boxes, the ground as a thin box;
- ``stance_current`` / ``stance_next``: the contact points of the holds of the current stance
  (green) and of the next one (orange, translucent), one sphere list per hold, and the limb name;
- ``forces``: each contact force as an arrow from its point (``force_scale`` m per N) and, for a
  unilateral contact, its friction cone (apex at the point, axis the surface normal, half-angle
  atan(mu), ``cone_height`` m) as a triangle list; a grasp (bilateral) has no cone;
- ``com``: the centre of mass as a sphere and its vertical line to the ground.
The array starts with a DELETEALL marker so that markers of a previous stance never linger.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Iterable, Sequence

import numpy as np

FRAME = "world"
COLORS = {
    "rung": (0.80, 0.60, 0.30, 1.0), "rail": (0.55, 0.35, 0.15, 1.0), "ground": (0.6, 0.6, 0.6, 0.6),
    "current": (0.1, 0.8, 0.2, 1.0), "next": (1.0, 0.55, 0.0, 0.6), "force": (0.9, 0.1, 0.1, 1.0),
    "cone": (0.2, 0.4, 1.0, 0.25), "com": (0.9, 0.0, 0.9, 1.0), "other": (0.5, 0.5, 0.55, 1.0),
}


@dataclass(frozen=True)
class ContactForce:
    """One contact's force for display: the point [m], the force on the robot [N] (world), the
    surface normal toward the robot, mu (0 or ``bilateral``: no cone)."""

    limb: str
    point: np.ndarray
    force: np.ndarray
    normal: np.ndarray
    mu: float = 0.0
    bilateral: bool = False


def _quat_xyzw(R: np.ndarray) -> tuple[float, float, float, float]:
    from climb_core.environment import quaternion_xyzw

    return tuple(float(x) for x in quaternion_xyzw(np.asarray(R, float)))


def _point(xyz) -> Any:
    from geometry_msgs.msg import Point

    x, y, z = (float(v) for v in np.asarray(xyz, float).reshape(3))
    return Point(x=x, y=y, z=z)


def _marker(ns: str, mid: int, mtype: int, color, stamp=None, frame_id: str = FRAME):
    from visualization_msgs.msg import Marker

    m = Marker()
    m.header.frame_id = frame_id
    if stamp is not None:
        m.header.stamp = stamp
    m.ns, m.id, m.type, m.action = ns, int(mid), int(mtype), Marker.ADD
    m.pose.orientation.w = 1.0
    m.color.r, m.color.g, m.color.b, m.color.a = (float(c) for c in color)
    m.scale.x = m.scale.y = m.scale.z = 1.0
    m.frame_locked = False
    return m


def scene_markers(env, stamp=None, frame_id: str = FRAME) -> list:
    """One marker per surface of a climb_core Environment."""
    from visualization_msgs.msg import Marker

    out = []
    for i, (name, s) in enumerate(env.surfaces.items()):
        if s.shape == "cylinder":
            m = _marker("scene", i, Marker.CYLINDER, COLORS.get(s.role, COLORS["other"]), stamp, frame_id)
            T = s.T_world_primitive()  # the cylinder's axis is the primitive's z, as RViz draws it
            m.scale.x = m.scale.y = float(2.0 * s.radius)
            m.scale.z = float(s.length)
        else:
            m = _marker("scene", i, Marker.CUBE, COLORS.get(s.role, COLORS["other"]), stamp, frame_id)
            T = s.T_world_primitive()
            size = 2.0 * np.asarray(s.primitive_half_extents(), float)
            if s.shape == "plane":  # a thin plate just under the surface (its collision box is thick)
                T = s.T_world_surface.copy()
                T[:3, 3] -= 0.001 * T[:3, 2]
                size = np.array([size[0] or 20.0, size[1] or 20.0, 0.002])
            m.scale.x, m.scale.y, m.scale.z = (float(max(v, 1e-4)) for v in size)
        m.pose.position = _point(T[:3, 3])
        qx, qy, qz, qw = _quat_xyzw(T[:3, :3])
        m.pose.orientation.x, m.pose.orientation.y, m.pose.orientation.z, m.pose.orientation.w = qx, qy, qz, qw
        m.text = name
        out.append(m)
    return out


def stance_markers(stance, ns: str, color, stamp=None, frame_id: str = FRAME, radius: float = 0.025) -> list:
    """A sphere list of each hold's contact points and the limb's name above them."""
    from visualization_msgs.msg import Marker

    out = []
    if stance is None:
        return out
    for k, hold in enumerate(stance.holds):
        m = _marker(ns, 2 * k, Marker.SPHERE_LIST, color, stamp, frame_id)
        m.scale.x = m.scale.y = m.scale.z = float(2.0 * radius)
        m.points = [_point(p.position) for p in hold.points]
        m.text = f"{hold.limb} on {hold.env_surface}"
        out.append(m)
        label = _marker(ns, 2 * k + 1, Marker.TEXT_VIEW_FACING, color, stamp, frame_id)
        label.scale.z = 0.05
        centre = np.mean([p.position for p in hold.points], axis=0) if hold.points else np.zeros(3)
        label.pose.position = _point(centre + np.array([0.0, 0.0, 0.06]))
        label.text = f"{hold.limb}: {hold.env_surface}"
        out.append(label)
    return out


def cone_triangles(apex: np.ndarray, normal: np.ndarray, mu: float, height: float, sides: int = 16) -> list[np.ndarray]:
    """Triangles (3 points each, flattened in order) of the lateral surface of a friction cone."""
    n = np.asarray(normal, float)
    n = n / (np.linalg.norm(n) or 1.0)
    a = np.cross(n, [1.0, 0.0, 0.0])
    if np.linalg.norm(a) < 1e-6:
        a = np.cross(n, [0.0, 1.0, 0.0])
    a /= np.linalg.norm(a)
    b = np.cross(n, a)
    r = height * float(mu)
    apex = np.asarray(apex, float)
    rim = [apex + height * n + r * (math.cos(t) * a + math.sin(t) * b)
           for t in np.linspace(0.0, 2.0 * math.pi, sides + 1)]
    out = []
    for k in range(sides):
        out += [apex, rim[k], rim[k + 1]]
    return out


def force_markers(forces: Iterable[ContactForce], stamp=None, frame_id: str = FRAME, force_scale: float = 0.002,
                  cone_height: float = 0.15) -> list:
    """An arrow per contact force (``force_scale`` [m/N]) and the friction cone of each unilateral one."""
    from visualization_msgs.msg import Marker

    out = []
    for k, c in enumerate(forces):
        p = np.asarray(c.point, float)
        f = np.asarray(c.force, float)
        arrow = _marker("forces", 2 * k, Marker.ARROW, COLORS["force"], stamp, frame_id)
        arrow.points = [_point(p), _point(p + force_scale * f)]
        arrow.scale.x, arrow.scale.y, arrow.scale.z = 0.012, 0.025, 0.04  # shaft, head diameters, head length
        arrow.text = f"{c.limb}: {np.linalg.norm(f):.0f} N"
        out.append(arrow)
        if not c.bilateral and c.mu > 0.0:
            cone = _marker("forces", 2 * k + 1, Marker.TRIANGLE_LIST, COLORS["cone"], stamp, frame_id)
            cone.points = [_point(x) for x in cone_triangles(p, c.normal, c.mu, cone_height)]
            cone.text = f"{c.limb}: friction cone mu = {c.mu:.2f}"
            out.append(cone)
    return out


def com_markers(com, stamp=None, frame_id: str = FRAME, ground_z: float = 0.0) -> list:
    """The CoM as a sphere and its vertical projection as a line to the ground."""
    from visualization_msgs.msg import Marker

    if com is None:
        return []
    c = np.asarray(com, float).reshape(3)
    sphere = _marker("com", 0, Marker.SPHERE, COLORS["com"], stamp, frame_id)
    sphere.pose.position = _point(c)
    sphere.scale.x = sphere.scale.y = sphere.scale.z = 0.05
    line = _marker("com", 1, Marker.LINE_LIST, COLORS["com"], stamp, frame_id)
    line.scale.x = 0.005
    line.points = [_point(c), _point([c[0], c[1], ground_z])]
    return [sphere, line]


def forces_from_contacts(limbs: Sequence[str], normal_force: Sequence[float], tangential_force: Sequence[float],
                         stance, env=None, grasped: Sequence[bool] = ()) -> list[ContactForce]:
    """Contact forces to display from sim/contacts' per-limb magnitudes and the stance's holds: at
    the centre of each limb's hold, normal along the hold's contact normal, the tangential part
    (whose direction sim/contacts does not give) drawn along the surface's axis; mu from the hold."""
    out = []
    if stance is None:
        return out
    holds = {h.limb: h for h in stance.holds}
    for k, limb in enumerate(limbs):
        hold = holds.get(limb)
        fn = float(normal_force[k]) if k < len(normal_force) else 0.0
        if hold is None or not hold.points or fn <= 0.0:
            continue
        point = np.mean([p.position for p in hold.points], axis=0)
        n = np.mean([p.normal for p in hold.points], axis=0)
        n = n / (np.linalg.norm(n) or 1.0)
        axis = np.array([1.0, 0.0, 0.0])
        if env is not None and hold.env_surface in getattr(env, "surfaces", {}):
            axis = env.surfaces[hold.env_surface].axis
        t = axis - np.dot(axis, n) * n
        t = t / (np.linalg.norm(t) or 1.0)
        ft = float(tangential_force[k]) if k < len(tangential_force) else 0.0
        is_grasp = bool(grasped[k]) if k < len(grasped) else bool(hold.bilateral)
        out.append(ContactForce(limb, point, fn * n + ft * t, n, float(hold.friction), is_grasp or hold.bilateral))
    return out


def marker_array(env, *, stamp=None, frame_id: str = FRAME, current=None, next_stance=None,
                 forces: Iterable[ContactForce] = (), com=None, force_scale: float = 0.002,
                 cone_height: float = 0.15):
    """The whole MarkerArray: scene, current and next stance, contact forces with their cones, CoM."""
    from visualization_msgs.msg import Marker, MarkerArray

    clear = Marker()
    clear.header.frame_id = frame_id
    clear.action = Marker.DELETEALL
    out = MarkerArray()
    out.markers.append(clear)
    out.markers.extend(scene_markers(env, stamp, frame_id))
    out.markers.extend(stance_markers(current, "stance_current", COLORS["current"], stamp, frame_id))
    out.markers.extend(stance_markers(next_stance, "stance_next", COLORS["next"], stamp, frame_id))
    out.markers.extend(force_markers(forces, stamp, frame_id, force_scale, cone_height))
    ground = env.surfaces.get("ground") if hasattr(env, "surfaces") else None
    out.markers.extend(com_markers(com, stamp, frame_id, float(ground.position[2]) if ground is not None else 0.0))
    return out


_ENVS: dict[str, Any] = {}


def environment_of(scenario_text: str):
    """The (cached) Environment of a scenario (name or spec YAML text), perturbations applied as
    the simulator builds them."""
    from climb_core.environment import build_environment
    from climb_core.ladder import load_scenario

    env = _ENVS.get(scenario_text)
    if env is None:
        env = _ENVS[scenario_text] = build_environment(load_scenario(scenario_text), perturbed=True)
    return env


def build_markers(node, scene: tuple[str, str], **state):
    """What the coordinator calls: ``scene`` = (robot, scenario text); ``state``: ``current``,
    ``next_stance``, ``forces``, ``com`` as in :func:`marker_array`; stamped with the node's clock."""
    stamp = node.get_clock().now().to_msg() if node is not None else None
    return marker_array(environment_of(scene[1]), stamp=stamp, **state)
