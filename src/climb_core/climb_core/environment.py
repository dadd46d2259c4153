"""The environment built from one scenario (a ladder, a scene or both): named surfaces in the world
frame, what each may be used for, and their coal collision objects. Planner, controller and
simulator all use this one model (ladder.py and scene.py parse the spec; the simulator's bodies
are built from it by sim_bridge.world_bodies). No simulator code here.

Frames (SI units, world z up, robot starting at the world origin facing +x, or at a scene's
``start.pose``):

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
| rung_1 .. rung_n           | rung (circle, or rect on regular / vertical / a_frame ladders) / tread (rect on ship / stairs) | cylinder / box | rung centre; x = rung axis = L +y (robot's left), y = L -x (toward the robot), z = up; a box's ``length`` = the rung width |
| stringer_left, _right      | stringer | box      | box centre on the stringer line at y = +-(w/2 + stringer.width/2); x = d (up the ladder), y = L +y, z = d x y = ladder-plane normal toward the robot |
| rail_left, rail_right      | rail     | cylinder | axis centre; axes as stringers (x = d = cylinder axis); the axis is the nose line shifted up by ``height`` (vertically) and sideways to y = +-(w/2 + stringer.width/2) (+ rails_dy when perturbed), from t_foot to t_top |
| platform                   | platform | box      | box centre; L axes; top face at the top rung's top (z_n + half_height), front face touching the back of the top rung (x_n + half_depth), ``depth`` along +x |
| stringer_back_left, _right | stringer | box      | a_frame only: from the apex P(t_top) down to the ground at back_inclination b; x = up the back leg (-cos b, 0, sin b), y = L -y, z = (sin b, 0, cos b) (outward) |
| obstacle_0 ..              | obstacle | box      | box centre, world frame (spec ``position``, R = Rz(yaw) Ry(pitch) Rx(roll) of ``rpy_deg``) |
| <scene surface name>       | scene    | box / cylinder | centre, world frame (``position``, ``rpy_deg`` as obstacles); a cylinder's axis is local x |

Without a ladder block there are only the ground and the scene's surfaces (``ladder`` None,
``n_rungs`` 0; ``rung()`` and the stringer direction raise SpecError).

Use of each surface (``Surface.contact_limbs``, ``Surface.bilateral``; one query,
``Environment.contact_surfaces(limb_type)``, serves ladders and scenes):

| role              | contact_limbs | bilateral |
| ----------------- | ------------- | --------- |
| ground            | foot          | no        |
| rung (circle / rect bar) | foot, hand | yes (a rect bar: if it fits the hand, ``climb_core.holds.grasp_fits``) |
| tread (rect, ship / stairs) | foot      | no        |
| rail              | hand          | yes       |
| platform          | foot          | no        |
| stringer, obstacle| none          | no        |
| scene             | the spec's ``contact`` | the spec's ``bilateral`` |

Cylinders: axis = local x, ``radius``, ``length`` (full); ``half_extents`` = (length/2, r, r).
Boxes: ``half_extents`` along local x, y, z. Plane: ``half_extents`` = (G, G, 0), the extent used
for the ground's finite collision box (``GROUND_HALF_SIZE``). All rungs and treads are horizontal.
coal and PyBullet cylinders have their axis along their own z: ``Surface.T_world_primitive()``
(= ``T_world_surface @ R_SURFACE_CYLINDER`` for cylinders) is the frame to give them; the ground is
a coal Box of ``GROUND_COLLISION_THICKNESS`` whose top face is z = 0, and a PyBullet GEOM_PLANE.

Friction: every ladder surface (rungs, treads, rails, stringers, platform, obstacles) has the
spec's ``friction``; a scene surface has its own ``friction``; the ground has the scene's
``ground.friction`` if given, else the ladder's ``ground_friction``, else 0.8
(``Environment.dominant_friction``: the ladder's, or the ground's without one, is what the
simulator's bodies are balanced on: sim_bridge.world_bodies).

Perturbation (``build_environment(..., perturbed=True)``): rung k moves by (dx, 0, dz) in L
(its own offset only; stringers, rails and platform keep their nominal places) and the rails move
by rails_dy along L y. Drops are dynamic objects, thrown by the simulator, not built here.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any, Callable

import numpy as np

from .errors import SpecError
from .ladder import DEFAULTS, LadderSpec, PerturbationSpec, Scenario, load_scenario
from .scene import CONTACT_LIMBS, DEFAULT_GROUND_FRICTION, GoalSpec, SceneSpec, StartSpec

__all__ = [
    "TREAD_LADDERS", "GROUND_HALF_SIZE", "GROUND_COLLISION_THICKNESS", "R_SURFACE_CYLINDER",
    "ROLES", "ROLE_USE", "Surface", "Environment", "build_environment", "rpy_deg_to_matrix",
    "quaternion_xyzw",
]

#: [m] half size of the ground's finite collision box / visual (the PyBullet plane is infinite).
GROUND_HALF_SIZE = 50.0
#: [m] thickness of the ground's coal collision box (top face at z = 0).
GROUND_COLLISION_THICKNESS = 1.0
#: Columns: the coal / PyBullet cylinder primitive axes (x, y, z) in the surface frame. The
#: primitive's z (its axis) is the surface's x.
R_SURFACE_CYLINDER = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
#: Ladder types whose rect rungs are treads (feet only; the hands hold the rails). On the other
#: types a rect rung is a rung: a bar the feet stand on and a hand may close around.
TREAD_LADDERS = ("ship", "stairs")
ROLES = ("ground", "rung", "tread", "rail", "stringer", "platform", "obstacle", "scene")
#: (contact_limbs, bilateral) of the surfaces the project builds itself, per role (scene
#: surfaces take their spec's values).
ROLE_USE: dict[str, tuple[tuple[str, ...], bool]] = {
    "ground": (("foot",), False), "rung": (("foot", "hand"), True), "tread": (("foot",), False),
    "rail": (("hand",), True), "stringer": ((), False), "platform": (("foot",), False), "obstacle": ((), False),
}


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
    length: float = 0.0  # [m] cylinder and rect rung / tread: full length along local x
    half_extents: np.ndarray = field(default_factory=lambda: np.zeros(3))  # [m] along local x, y, z
    friction: float = 0.0  # [-] Coulomb coefficient of robot contacts on this surface
    contact_limbs: tuple[str, ...] = ()  # limb types ("foot", "hand") that may be placed on it
    bilateral: bool = False  # a hand may close around it (no friction cone: a grip limit)

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
        self.T_world_ladder = T_world_ladder  # identity without a ladder
        self.n_rungs = 0 if scenario.ladder is None else scenario.ladder.n_rungs
        self._collision_cache: list | None = None

    @property
    def name(self) -> str:
        return self.scenario.name

    @property
    def ladder(self) -> LadderSpec | None:
        return self.scenario.ladder

    @property
    def scene(self) -> SceneSpec | None:
        return self.scenario.scene

    @property
    def goal(self) -> GoalSpec | None:
        """The scene's explicit goal (base position + tolerance), or None (a ladder's target rung)."""
        return None if self.scene is None else self.scene.goal

    @property
    def start_pose(self) -> StartSpec:
        """Where the robot starts standing (x, y [m], yaw_deg): the scene's ``start.pose``, else the origin."""
        return StartSpec() if self.scene is None else self.scene.start

    def place_at_start(self, q: np.ndarray) -> np.ndarray:
        """A free-flyer configuration standing at the world origin facing +x (Pinocchio layout:
        q[0:3] base position, q[3:7] quaternion x, y, z, w) moved to ``start_pose`` (a copy)."""
        start = self.start_pose
        out = np.array(q, dtype=float)
        R = _rot_z(math.radians(start.yaw_deg))
        out[:2] = (R @ out[:3])[:2] + (start.x, start.y)
        half = 0.5 * math.radians(start.yaw_deg)
        qx, qy, qz, qw = out[3:7]
        cz, sz = math.cos(half), math.sin(half)  # q_yaw * q
        out[3:7] = (cz * qx - sz * qy, cz * qy + sz * qx, cz * qz + sz * qw, cz * qw - sz * qz)
        return out

    def with_surface_offsets(self, offsets: dict[str, Any]) -> "Environment":
        """A copy with surfaces translated (world [m]): ``offsets`` maps a surface name to where the
        surface was found minus where this model has it (a rung a guarded move touched early or
        late). The planner replans in that model; the scenario (and its spec) stay as they were.
        SpecError naming the surface when it is unknown or its offset is not 3 finite numbers."""
        surfaces = dict(self.surfaces)
        for name, offset in offsets.items():
            if name not in surfaces:
                raise SpecError(f"surface_offsets.{name}", f"no surface {name!r} in scenario {self.name!r}")
            d = np.asarray(offset, dtype=float)
            if d.shape != (3,) or not np.all(np.isfinite(d)):
                raise SpecError(f"surface_offsets.{name}", "must be 3 finite numbers [m] (world x, y, z)")
            T = np.array(surfaces[name].T_world_surface)
            T[:3, 3] += d
            surfaces[name] = replace(surfaces[name], T_world_surface=T)
        return Environment(self.scenario, surfaces, self.perturbed, self.T_world_ladder)

    def contact_surfaces(self, limb_type: str) -> list[Surface]:
        """The surfaces a limb of type ``limb_type`` ("foot" or "hand") may be placed on, in build order."""
        if limb_type not in CONTACT_LIMBS:
            raise SpecError("limb_type", f"must be one of {', '.join(CONTACT_LIMBS)}, got {limb_type!r}")
        return [s for s in self.surfaces.values() if limb_type in s.contact_limbs]

    def _need_ladder(self, what: str) -> LadderSpec:
        if self.ladder is None:
            raise SpecError("ladder", f"{what} needs a scenario with a ladder: block ({self.name!r} has none)")
        return self.ladder

    def rung(self, i: int) -> Surface:
        """Rung (or tread) ``i``, 1-based, 1 = lowest."""
        self._need_ladder("rung")
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
        a = math.radians(self._need_ladder("the stringer direction").inclination_deg)
        return self.T_world_ladder[:3, :3] @ np.array([math.cos(a), 0.0, math.sin(a)])

    @property
    def dominant_friction(self) -> float:
        """Friction of the surface the robot mostly touches: the ladder's, or the ground's
        without a ladder (the simulator balances its bodies' coefficients on it)."""
        if self.ladder is not None:
            return float(self.ladder.friction)
        return float(self.surfaces["ground"].friction)

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

    def __repr__(self) -> str:
        kind = "scene" if self.ladder is None else f"type={self.ladder.type}"
        return (f"Environment({self.name!r}, {kind}, n_rungs={self.n_rungs}, "
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
        else:  # a rect bar on a ladder (hands may close around it, if it fits the hand), a tread on ship / stairs
            add(f"rung_{k}", "tread" if lad.type in TREAD_LADDERS else "rung", "box", fr.R_rung, centre,
                length=lad.rung_width,
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
    the default is the nominal ladder the planner sees. Surfaces: the ground, the ladder's (if
    any), then the scene's (if any).
    """
    if isinstance(scenario_or_ladder, LadderSpec):
        scenario = Scenario(name="", ladder=scenario_or_ladder)
    else:
        scenario = load_scenario(scenario_or_ladder)
    lad, scene = scenario.ladder, scenario.scene
    surfaces: dict[str, Surface] = {}

    def add_world(name: str, role: str, shape: str, T_world: np.ndarray, radius: float = 0.0,
                  length: float = 0.0, half_extents=(0.0, 0.0, 0.0), friction: float | None = None,
                  use: tuple[tuple[str, ...], bool] | None = None) -> None:
        contact_limbs, bilateral = ROLE_USE[role] if use is None else use
        mu = friction if friction is not None else lad.friction  # type: ignore[union-attr]  # ladder parts
        surfaces[name] = Surface(name=name, role=role, shape=shape, T_world_surface=T_world, radius=float(radius),
                                 length=float(length), half_extents=np.asarray(half_extents, dtype=float),
                                 friction=float(mu), contact_limbs=tuple(contact_limbs), bilateral=bool(bilateral))

    add_world("ground", "ground", "plane", np.eye(4), half_extents=(GROUND_HALF_SIZE, GROUND_HALF_SIZE, 0.0),
              friction=_ground_friction(scenario))
    T_world_ladder = np.eye(4)
    if lad is not None:
        T_world_ladder = _add_ladder(lad, scenario.perturbation if perturbed else PerturbationSpec(), add_world)
    if scene is not None:
        for spec in scene.surfaces:
            add_world(spec.name, "scene", spec.shape, _homogeneous(rpy_deg_to_matrix(spec.rpy_deg), spec.position),
                      radius=spec.radius or 0.0, length=spec.length or 0.0, half_extents=spec.half_extents,
                      friction=spec.friction, use=(spec.contact, spec.bilateral))
    return Environment(scenario, surfaces, perturbed, T_world_ladder)


def _ground_friction(scenario: Scenario) -> float:
    """The scene's ground.friction if given, else the ladder's ground_friction, else the default."""
    if scenario.scene is not None and scenario.scene.ground_friction is not None:
        return scenario.scene.ground_friction
    return DEFAULT_GROUND_FRICTION if scenario.ladder is None else scenario.ladder.ground_friction


def _add_ladder(lad: LadderSpec, pert: PerturbationSpec, add_world: Callable[..., None]) -> np.ndarray:
    """Add the ladder's surfaces (rungs, stringers, rails, platform, family parts, obstacles);
    returns T_world_ladder."""
    T_world_ladder = _homogeneous(_rot_z(math.radians(lad.pose_yaw_deg)), (lad.pose_x, lad.pose_y, 0.0))

    def add_in_ladder(name: str, role: str, shape: str, R_ladder: np.ndarray, p_ladder: np.ndarray, **kw) -> None:
        add_world(name, role, shape, T_world_ladder @ _homogeneous(R_ladder, p_ladder), **kw)

    frame = _Frame(lad)
    _ladder_surfaces(frame, pert, add_in_ladder)
    for part in _FAMILY_PARTS[lad.type]:
        part(frame, pert, add_in_ladder)
    for i, obstacle in enumerate(lad.obstacles):
        add_world(f"obstacle_{i}", "obstacle", "box", _homogeneous(rpy_deg_to_matrix(obstacle.rpy_deg),
                                                                    obstacle.position),
                  half_extents=0.5 * np.asarray(obstacle.size, dtype=float))
    return T_world_ladder
