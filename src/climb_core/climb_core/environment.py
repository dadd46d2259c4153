"""The environment built from one ladder scenario: named surfaces in the world frame, their coal
collision objects, and static PyBullet bodies. Planner, controller and simulator all use this one
model (ladder.py parses the spec).

Frames (SI units, world z up, robot starting at the world origin facing +x):

* Ladder base frame L: on the ground (z = 0) at the middle of the first rung's projection,
  x from the robot toward the ladder, y to the robot's left, z up. ``T_world_ladder`` is
  ``Trans(pose.x, pose.y, 0) @ Rz(pose.yaw_deg)``.
* Stringer direction d = (cos a, 0, sin a) in L (a = inclination): the ladder leans AWAY from
  the robot. The *station* of parameter t [m] is P(t) = (0, 0, h1) + t d, h1 = first_rung_height.
  Rung k (1 = lowest) is centred at P((k - 1) s), s = rung_spacing: rung 1 is at x = 0, z = h1
  (this is what "middle of the first rung's projection" means), rung k at
  x = (k-1) s cos a, z = h1 + (k-1) s sin a. The stringer centre lines pass through the rung
  centres; they start on the ground at t_foot = -h1 / sin a (x = -h1 / tan a, i.e. the feet of
  the stringers are h1 cot a closer to the robot than rung 1) and end at
  t_top = (n-1) s + stringer.top_extension.
* Tread nose line: the rung's front top edge, N(t) = P(t) + (-half_depth, 0, +half_height)
  (circle: the top of the rung, (0, 0, r); rect: (-depth/2, 0, thickness/2)).

Surfaces (``Environment.surfaces``, in this order) and their local frames ``T_world_surface``:

| name                       | role     | shape    | frame origin / axes |
| -------------------------- | -------- | -------- | ------------------- |
| ground                     | ground   | plane    | world origin, world axes; z = plane normal; the plane is z = 0 |
| rung_1 .. rung_n           | rung (circle) / tread (rect) | cylinder / box | rung centre; x = rung axis = L +y (robot's left), y = L -x (toward the robot), z = up |
| stringer_left, _right      | stringer | box      | box centre on the stringer line at y = +-(w/2 + stringer.width/2); x = d (up the ladder), y = L +y, z = d x y = ladder-plane normal toward the robot |
| rail_left, rail_right      | rail     | cylinder | axis centre; axes as stringers (x = d = cylinder axis); the axis is the nose line shifted up by ``height`` (vertically) and sideways to y = +-(w/2 + stringer.width/2) (+ rails_dy when perturbed), from t_foot to t_top |
| platform                   | platform | box      | box centre; L axes; top face at the top rung's top (z_n + half_height), front face touching the back of the top rung (x_n + half_depth), ``depth`` along +x |
| stringer_back_left, _right | stringer | box      | a_frame only: from the apex P(t_top) down to the ground at back_inclination b; x = up the back leg (-cos b, 0, sin b), y = L -y, z = (sin b, 0, cos b) (outward) |
| obstacle_0 ..              | obstacle | box      | box centre, world frame (spec ``position``, R = Rz(yaw) Ry(pitch) Rx(roll) of ``rpy_deg``) |

Cylinders: axis = local x, ``radius``, ``length`` (full); ``half_extents`` = (length/2, r, r).
Boxes: ``half_extents`` along local x, y, z. Plane: ``half_extents`` = (G, G, 0), the extent used
for the ground's finite collision box (``GROUND_HALF_SIZE``). All rungs and treads are horizontal.
coal and PyBullet cylinders have their axis along their own z: ``Surface.T_world_primitive()``
(= ``T_world_surface @ R_SURFACE_CYLINDER`` for cylinders) is the frame to give them; the ground is
a coal Box of ``GROUND_COLLISION_THICKNESS`` whose top face is z = 0, and a PyBullet GEOM_PLANE.

Friction: every ladder surface (rungs, treads, rails, stringers, platform, obstacles) has the
spec's ``friction``; the ground has ``ground_friction`` (default 0.8). PyBullet combines the two
bodies' lateral friction coefficients by *product* (``PYBULLET_FRICTION_COMBINATION``). The
robot's links must all be given ``Environment.robot_lateral_friction`` = sqrt(spec friction)
(see :func:`pybullet_friction`), and each surface gets ``friction / robot_lateral_friction``,
so every robot-surface contact has exactly the surface's ``friction`` (ladder: sqrt(mu) on both
sides; ground: 0.8 / sqrt(mu)).

Perturbation (``build_environment(..., perturbed=True)``): rung k moves by (dx, 0, dz) in L
(its own offset only; stringers, rails and platform keep their nominal places) and the rails move
by rails_dy along L y. Drops are dynamic objects, thrown by the simulator, not built here.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np

from .errors import SpecError
from .ladder import DEFAULTS, LadderSpec, PerturbationSpec, Scenario, load_scenario

__all__ = [
    "PYBULLET_FRICTION_COMBINATION", "GROUND_HALF_SIZE", "GROUND_COLLISION_THICKNESS", "R_SURFACE_CYLINDER",
    "ROLES", "Surface", "Environment", "build_environment", "pybullet_friction", "rpy_deg_to_matrix",
    "quaternion_xyzw",
]

#: How PyBullet combines the lateral friction of two touching bodies.
PYBULLET_FRICTION_COMBINATION = "product"
#: [m] half size of the ground's finite collision box / visual (the PyBullet plane is infinite).
GROUND_HALF_SIZE = 50.0
#: [m] thickness of the ground's coal collision box (top face at z = 0).
GROUND_COLLISION_THICKNESS = 1.0
#: Columns: the coal / PyBullet cylinder primitive axes (x, y, z) in the surface frame. The
#: primitive's z (its axis) is the surface's x.
R_SURFACE_CYLINDER = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
ROLES = ("ground", "rung", "tread", "rail", "stringer", "platform", "obstacle")
#: RGBA of the PyBullet visual shapes, per role.
ROLE_COLOURS = {
    "ground": (0.85, 0.85, 0.80, 1.0), "rung": (0.60, 0.60, 0.65, 1.0), "tread": (0.55, 0.55, 0.60, 1.0),
    "rail": (0.90, 0.75, 0.10, 1.0), "stringer": (0.85, 0.45, 0.10, 1.0), "platform": (0.50, 0.50, 0.55, 1.0),
    "obstacle": (0.30, 0.45, 0.75, 1.0),
}


def pybullet_friction(mu: float, partner: float | None = None) -> float:
    """Lateral friction to give one PyBullet body so that its contacts have coefficient ``mu``.

    PyBullet multiplies the two bodies' coefficients. With ``partner=None`` both bodies get the
    same value, sqrt(mu); otherwise this body gets mu / partner.
    """
    if not mu > 0.0:
        raise SpecError("friction", f"must be > 0, got {mu!r}")
    return math.sqrt(mu) if partner is None else mu / partner


# --------------------------------------------------------------------------------------------
# Small rotation helpers (no scipy import on this path).
# --------------------------------------------------------------------------------------------

def _rot_z(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _rot_y(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def _rot_x(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def rpy_deg_to_matrix(rpy_deg) -> np.ndarray:
    """R = Rz(yaw) Ry(pitch) Rx(roll) (fixed axes, as PyBullet's getQuaternionFromEuler)."""
    roll, pitch, yaw = (math.radians(float(v)) for v in rpy_deg)
    return _rot_z(yaw) @ _rot_y(pitch) @ _rot_x(roll)


def _homogeneous(R: np.ndarray, p) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = np.asarray(p, dtype=float)
    return T


def quaternion_xyzw(R: np.ndarray) -> tuple[float, float, float, float]:
    """Unit quaternion (x, y, z, w) of a rotation matrix (PyBullet order)."""
    m = np.asarray(R, dtype=float)
    trace = m[0, 0] + m[1, 1] + m[2, 2]
    if trace > 0.0:
        s = 2.0 * math.sqrt(trace + 1.0)
        q = ((m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s, 0.25 * s)
    elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
        s = 2.0 * math.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2])
        q = (0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s, (m[2, 1] - m[1, 2]) / s)
    elif m[1, 1] > m[2, 2]:
        s = 2.0 * math.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2])
        q = ((m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s, (m[0, 2] - m[2, 0]) / s)
    else:
        s = 2.0 * math.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1])
        q = ((m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s, (m[1, 0] - m[0, 1]) / s)
    norm = math.sqrt(sum(v * v for v in q))
    return tuple(v / norm for v in q)  # type: ignore[return-value]


# --------------------------------------------------------------------------------------------
# Surfaces.
# --------------------------------------------------------------------------------------------

@dataclass(frozen=True, eq=False)
class Surface:
    name: str  # ground, rung_1..rung_n (1 = lowest), rail_left, stringer_left, platform, obstacle_0, ...
    role: str  # one of ROLES
    shape: str  # cylinder | box | plane
    T_world_surface: np.ndarray  # 4x4, see the module docstring for each role's axes
    radius: float = 0.0  # [m] cylinder
    length: float = 0.0  # [m] cylinder, full length along local x
    half_extents: np.ndarray = field(default_factory=lambda: np.zeros(3))  # [m] along local x, y, z
    friction: float = 0.0  # [-] Coulomb coefficient of robot contacts on this surface

    def __post_init__(self) -> None:
        for name in ("T_world_surface", "half_extents"):
            array = np.array(getattr(self, name), dtype=float)
            array.setflags(write=False)  # frozen means frozen: the arrays too
            object.__setattr__(self, name, array)

    @property
    def position(self) -> np.ndarray:
        """[m] origin of the surface frame in world (the centre of a rung, rail or box)."""
        return self.T_world_surface[:3, 3].copy()

    @property
    def rotation(self) -> np.ndarray:
        return self.T_world_surface[:3, :3].copy()

    @property
    def axis(self) -> np.ndarray:
        """Local x in world: the cylinder axis of rungs and rails (rungs point to the left)."""
        return self.T_world_surface[:3, 0].copy()

    @property
    def normal(self) -> np.ndarray:
        """Local z in world (up for ground, rungs, treads and platform)."""
        return self.T_world_surface[:3, 2].copy()

    @property
    def top_z(self) -> float:
        """[m] highest point of the surface (rung top, tread top face, ...)."""
        return float(self.aabb()[1][2])

    def T_world_primitive(self) -> np.ndarray:
        """Frame of the coal / PyBullet primitive (cylinder axis = its z; ground box centre)."""
        if self.shape == "cylinder":
            T = self.T_world_surface.copy()
            T[:3, :3] = T[:3, :3] @ R_SURFACE_CYLINDER
            return T
        if self.shape == "plane":
            return self.T_world_surface @ _homogeneous(np.eye(3), (0.0, 0.0, -0.5 * GROUND_COLLISION_THICKNESS))
        return self.T_world_surface.copy()

    def primitive_half_extents(self) -> np.ndarray:
        """[m] half sizes of the primitive's bounding box along the primitive's own axes."""
        if self.shape == "cylinder":
            return np.array([self.radius, self.radius, 0.5 * self.length])
        if self.shape == "plane":
            return np.array([self.half_extents[0], self.half_extents[1], 0.5 * GROUND_COLLISION_THICKNESS])
        return np.asarray(self.half_extents, dtype=float).copy()

    def aabb(self) -> tuple[np.ndarray, np.ndarray]:
        """[m] world axis-aligned box around the primitive's oriented bounding box."""
        T = self.T_world_primitive()
        extent = np.abs(T[:3, :3]) @ self.primitive_half_extents()
        return T[:3, 3] - extent, T[:3, 3] + extent

    def coal_geometry(self):
        import coal

        if self.shape == "cylinder":
            return coal.Cylinder(self.radius, self.length)
        return coal.Box(*(2.0 * self.primitive_half_extents()))

    def pybullet_pose(self) -> tuple[list[float], list[float]]:
        """(position, quaternion xyzw) of the PyBullet body (plane: the world origin)."""
        T = self.T_world_surface if self.shape == "plane" else self.T_world_primitive()
        return T[:3, 3].tolist(), list(quaternion_xyzw(T[:3, :3]))


# --------------------------------------------------------------------------------------------
# The environment.
# --------------------------------------------------------------------------------------------

class Environment:
    """Named surfaces of one scenario in the world frame (build with :func:`build_environment`)."""

    def __init__(self, scenario: Scenario, surfaces: dict[str, Surface], perturbed: bool,
                 T_world_ladder: np.ndarray):
        self.scenario = scenario
        self.surfaces = surfaces
        self.perturbed = perturbed
        self.T_world_ladder = T_world_ladder
        self.n_rungs = scenario.ladder.n_rungs
        self._collision_cache: list | None = None

    @property
    def name(self) -> str:
        return self.scenario.name

    @property
    def ladder(self) -> LadderSpec:
        return self.scenario.ladder

    def rung(self, i: int) -> Surface:
        """Rung (or tread) ``i``, 1-based, 1 = lowest."""
        if not isinstance(i, (int, np.integer)) or not 1 <= i <= self.n_rungs:
            raise SpecError("rung", f"must be an integer in [1, {self.n_rungs}], got {i!r}")
        return self.surfaces[f"rung_{int(i)}"]

    def rung_centre(self, i: int) -> np.ndarray:
        """[m] centre of rung ``i`` (middle of its axis / tread box centre) in world."""
        return self.rung(i).position

    def rungs(self) -> list[Surface]:
        return [self.surfaces[f"rung_{k}"] for k in range(1, self.n_rungs + 1)]

    def rails(self) -> dict[str, Surface]:
        """side (left / right) -> rail surface."""
        return {s.name.removeprefix("rail_"): s for s in self.surfaces.values() if s.role == "rail"}

    def surfaces_with_role(self, role: str) -> list[Surface]:
        return [s for s in self.surfaces.values() if s.role == role]

    @property
    def stringer_direction_in_world(self) -> np.ndarray:
        """Unit vector up the (front) stringers, in world."""
        a = math.radians(self.ladder.inclination_deg)
        return self.T_world_ladder[:3, :3] @ np.array([math.cos(a), 0.0, math.sin(a)])

    @property
    def robot_lateral_friction(self) -> float:
        """PyBullet lateralFriction the robot's links must have (sqrt of the spec friction)."""
        return pybullet_friction(self.ladder.friction)

    def pybullet_lateral_friction(self, surface: Surface) -> float:
        """PyBullet lateralFriction of a surface, so that robot contacts on it have its friction."""
        return pybullet_friction(surface.friction, partner=self.robot_lateral_friction)

    def collision_objects(self) -> list[tuple[str, Any, Any]]:
        """(surface name, coal.CollisionGeometry, coal.Transform3s of the primitive) per surface."""
        if self._collision_cache is None:
            import coal

            objects = []
            for s in self.surfaces.values():
                T = s.T_world_primitive()
                objects.append((s.name, s.coal_geometry(), coal.Transform3s(T[:3, :3].copy(), T[:3, 3].copy())))
            self._collision_cache = objects
        return list(self._collision_cache)

    def add_to_pybullet(self, client_id: int) -> dict[str, int]:
        """Create one static body (mass 0) per surface in PyBullet client ``client_id``.

        Each body's lateralFriction is ``pybullet_lateral_friction(surface)`` (sqrt(mu) for the
        ladder): PyBullet multiplies the two bodies' coefficients
        (``PYBULLET_FRICTION_COMBINATION``), so the caller must give every robot link
        ``robot_lateral_friction`` = sqrt(mu) for robot contacts to have the spec's mu.
        Restitution, rolling and spinning friction are 0. Returns surface name -> body id.
        """
        try:
            import pybullet as pb
        except ImportError as exc:  # pragma: no cover - pybullet is a project dependency
            raise ImportError("add_to_pybullet needs pybullet: pip install pybullet") from exc

        body_ids: dict[str, int] = {}
        for s in self.surfaces.values():
            rgba = list(ROLE_COLOURS.get(s.role, (0.7, 0.7, 0.7, 1.0)))
            if s.shape == "plane":
                collision = pb.createCollisionShape(pb.GEOM_PLANE, planeNormal=[0, 0, 1], physicsClientId=client_id)
                visual = pb.createVisualShape(pb.GEOM_BOX, halfExtents=[s.half_extents[0], s.half_extents[1], 5e-4],
                                              visualFramePosition=[0, 0, -5e-4], rgbaColor=rgba,
                                              physicsClientId=client_id)
            elif s.shape == "cylinder":
                collision = pb.createCollisionShape(pb.GEOM_CYLINDER, radius=s.radius, height=s.length,
                                                    physicsClientId=client_id)
                visual = pb.createVisualShape(pb.GEOM_CYLINDER, radius=s.radius, length=s.length, rgbaColor=rgba,
                                              physicsClientId=client_id)
            else:
                half = s.primitive_half_extents().tolist()
                collision = pb.createCollisionShape(pb.GEOM_BOX, halfExtents=half, physicsClientId=client_id)
                visual = pb.createVisualShape(pb.GEOM_BOX, halfExtents=half, rgbaColor=rgba,
                                              physicsClientId=client_id)
            position, quaternion = s.pybullet_pose()
            body = pb.createMultiBody(baseMass=0.0, baseCollisionShapeIndex=collision,
                                      baseVisualShapeIndex=visual, basePosition=position,
                                      baseOrientation=quaternion, physicsClientId=client_id)
            pb.changeDynamics(body, -1, lateralFriction=self.pybullet_lateral_friction(s), restitution=0.0,
                              rollingFriction=0.0, spinningFriction=0.0, physicsClientId=client_id)
            body_ids[s.name] = body
        return body_ids

    def __repr__(self) -> str:
        return (f"Environment({self.name!r}, type={self.ladder.type}, n_rungs={self.n_rungs}, "
                f"surfaces={len(self.surfaces)}, perturbed={self.perturbed})")


# --------------------------------------------------------------------------------------------
# Construction.
# --------------------------------------------------------------------------------------------

class _Frame:
    """Ladder-frame geometry of one spec (see the module docstring for the definitions)."""

    def __init__(self, ladder: LadderSpec):
        self.ladder = ladder
        self.a = math.radians(ladder.inclination_deg)
        self.d = np.array([math.cos(self.a), 0.0, math.sin(self.a)])  # stringer direction in L
        self.t_foot = -ladder.first_rung_height / math.sin(self.a)
        self.t_top = (ladder.n_rungs - 1) * ladder.rung_spacing + ladder.stringer_top_extension
        self.y_side = 0.5 * ladder.rung_width + 0.5 * ladder.stringer_width  # stringer / rail |y|
        self.nose = np.array([-ladder.rung.half_depth, 0.0, ladder.rung.half_height])
        # rungs: x = L y, y = -L x, z = L z; stringers and rails: x = d, y = L y, z = d x y
        self.R_rung = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
        self.R_stringer = np.column_stack([self.d, [0.0, 1.0, 0.0], np.cross(self.d, [0.0, 1.0, 0.0])])

    def station(self, t: float) -> np.ndarray:
        return np.array([0.0, 0.0, self.ladder.first_rung_height]) + t * self.d

    def rung_station(self, k: int) -> float:
        return (k - 1) * self.ladder.rung_spacing


_SIDE_SIGN = {"left": 1.0, "right": -1.0}


def _ladder_surfaces(fr: _Frame, pert: PerturbationSpec, add: Callable[..., None]) -> None:
    lad = fr.ladder
    # rungs / treads
    for k in range(1, lad.n_rungs + 1):
        dx, dz = pert.rung_offset(k)
        centre = fr.station(fr.rung_station(k)) + np.array([dx, 0.0, dz])
        if lad.rung.shape == "circle":
            r = 0.5 * lad.rung.diameter
            add(f"rung_{k}", "rung", "cylinder", fr.R_rung, centre, radius=r, length=lad.rung_width,
                half_extents=(0.5 * lad.rung_width, r, r))
        else:
            add(f"rung_{k}", "tread", "box", fr.R_rung, centre,
                half_extents=(0.5 * lad.rung_width, 0.5 * lad.rung.depth, 0.5 * lad.rung.thickness))
    # stringers (front)
    length = fr.t_top - fr.t_foot
    mid = fr.station(0.5 * (fr.t_foot + fr.t_top))
    for side, sign in _SIDE_SIGN.items():
        add(f"stringer_{side}", "stringer", "box", fr.R_stringer, mid + np.array([0.0, sign * fr.y_side, 0.0]),
            half_extents=(0.5 * length, 0.5 * lad.stringer_width, 0.5 * lad.stringer_depth))
    # rails: the nose line lifted by `height`, over the stringer span
    for rail in lad.rails:
        y = _SIDE_SIGN[rail.side] * fr.y_side + pert.rails_dy
        centre = mid + fr.nose + np.array([0.0, y, rail.height])
        r = 0.5 * rail.diameter
        add(f"rail_{rail.side}", "rail", "cylinder", fr.R_stringer, centre, radius=r, length=length,
            half_extents=(0.5 * length, r, r))
    # top platform: top face flush with the top rung's top, front face at the top rung's back
    if lad.top_platform_depth is not None:
        top = fr.station(fr.rung_station(lad.n_rungs))
        width = lad.top_platform_width or (lad.rung_width + 2.0 * lad.stringer_width)
        centre = np.array([top[0] + lad.rung.half_depth + 0.5 * lad.top_platform_depth, 0.0,
                           top[2] + lad.rung.half_height - 0.5 * lad.top_platform_thickness])
        add("platform", "platform", "box", np.eye(3), centre,
            half_extents=(0.5 * lad.top_platform_depth, 0.5 * width, 0.5 * lad.top_platform_thickness))


def _a_frame_back_leg(fr: _Frame, pert: PerturbationSpec, add: Callable[..., None]) -> None:
    lad = fr.ladder
    back = lad.back_inclination_deg
    if back is None:  # a hand-built LadderSpec: the spec default
        back = DEFAULTS["ladder.a_frame.back_inclination_deg"]
    b = math.radians(back)
    apex = fr.station(fr.t_top)
    up = np.array([-math.cos(b), 0.0, math.sin(b)])  # from the back foot up to the apex
    length = apex[2] / math.sin(b)
    R = np.column_stack([up, [0.0, -1.0, 0.0], [math.sin(b), 0.0, math.cos(b)]])
    for side, sign in _SIDE_SIGN.items():
        centre = apex - 0.5 * length * up + np.array([0.0, sign * fr.y_side, 0.0])
        add(f"stringer_back_{side}", "stringer", "box", R, centre,
            half_extents=(0.5 * length, 0.5 * lad.stringer_width, 0.5 * lad.stringer_depth))


#: Family-specific parts on top of the common ladder (rungs, stringers, rails, platform).
_FAMILY_PARTS: dict[str, tuple[Callable[[_Frame, PerturbationSpec, Callable[..., None]], None], ...]] = {
    "regular": (), "vertical": (), "ship": (), "stairs": (), "a_frame": (_a_frame_back_leg,),
}


def build_environment(scenario_or_ladder: Any, perturbed: bool = False) -> Environment:
    """Build the surfaces of a Scenario, a LadderSpec, or anything ``load_scenario`` accepts.

    ``perturbed=True`` applies the scenario's rung offsets and rails shift (execution model);
    the default is the nominal ladder the planner sees.
    """
    if isinstance(scenario_or_ladder, LadderSpec):
        scenario = Scenario(name="", ladder=scenario_or_ladder)
    else:
        scenario = load_scenario(scenario_or_ladder)
    lad = scenario.ladder
    pert = scenario.perturbation if perturbed else PerturbationSpec()
    T_world_ladder = _homogeneous(_rot_z(math.radians(lad.pose_yaw_deg)), (lad.pose_x, lad.pose_y, 0.0))
    surfaces: dict[str, Surface] = {}

    def add_world(name: str, role: str, shape: str, T_world: np.ndarray, radius: float = 0.0,
                  length: float = 0.0, half_extents=(0.0, 0.0, 0.0), friction: float | None = None) -> None:
        surfaces[name] = Surface(name=name, role=role, shape=shape, T_world_surface=T_world, radius=float(radius),
                                 length=float(length), half_extents=np.asarray(half_extents, dtype=float),
                                 friction=float(lad.friction if friction is None else friction))

    def add_in_ladder(name: str, role: str, shape: str, R_ladder: np.ndarray, p_ladder: np.ndarray, **kw) -> None:
        add_world(name, role, shape, T_world_ladder @ _homogeneous(R_ladder, p_ladder), **kw)

    add_world("ground", "ground", "plane", np.eye(4), half_extents=(GROUND_HALF_SIZE, GROUND_HALF_SIZE, 0.0),
              friction=lad.ground_friction)
    frame = _Frame(lad)
    _ladder_surfaces(frame, pert, add_in_ladder)
    for part in _FAMILY_PARTS[lad.type]:
        part(frame, pert, add_in_ladder)
    for i, obstacle in enumerate(lad.obstacles):
        add_world(f"obstacle_{i}", "obstacle", "box", _homogeneous(rpy_deg_to_matrix(obstacle.rpy_deg),
                                                                    obstacle.position),
                  half_extents=0.5 * np.asarray(obstacle.size, dtype=float))
    return Environment(scenario, surfaces, perturbed, T_world_ladder)
