"""Robot models: a :class:`RobotConfig` (climb_core.robot_config, one YAML per robot) -> a Pinocchio
model with convex-hull collision geometry. The simulator's URDF of the same robot is written by
sim_bridge.sim_urdf from this model's collision geometry.

Conventions (every consumer relies on them):

- Units are SI; frames are URDF link frames (contact surface conventions: climb_core.robot_config).
- ``RobotModel.model`` is the URDF with a free-flyer root and the ``locked_joints`` (fingers,
  grippers) removed with ``pin.buildReducedModel`` at their neutral position (clipped to their
  limits); the locked links stay attached, rigidly, to their parent. The whole-body controller
  and the planners work on this model. The simulator keeps the finger joints (the bridge drives
  them).
- ``q_reference()`` stands the robot on flat ground: both soles flat with their bottom face at
  world z = 0, the midpoint of the two sole centres at world x = y = 0, the base frame upright
  with yaw 0.
- Every mesh collision geometry is replaced by its qhull convex hull
  (``buildConvexHull(True, "Qt")``), cached on disk as OBJ files (climb_core.geometry_cache); the
  simulator's URDF uses the same hulls, so the planner, the controller and PyBullet collide the
  same shapes.
- ``sim.foot_box``: the limb frame link of each foot loses its URDF collision elements and gets a
  thin box whose bottom face is the sole polygon (G1: the URDF's 4 corner spheres touch nothing
  when a rung sits under the arch). The Pinocchio collision model and the simulator use the box.
- ``sim.armature``: an armature-like rotational inertia [kg m^2] added, as ``armature * I3``
  about the link's centre of mass, to the child link of every whole-body joint. It is added in
  the Pinocchio model here *and* in the simulator's URDF, so the controller's model matches the
  simulated robot.

The loaded ``RobotModel`` is cached per process: ``load_robot("g1")`` returns the same object on
every call. Its ``data``/``collision_data`` are a convenience workspace: a thread that computes
kinematics concurrently should call ``model.createData()`` itself.
"""
from __future__ import annotations

import math
import os
import pathlib
import threading
from typing import TYPE_CHECKING, Any

import numpy as np

from climb_core.contact import FEET
from climb_core.errors import SpecError
from climb_core.geometry_cache import CollisionUrdfCache
from climb_core.robot_config import (CollisionConfig, ContactSurface, FootBox, Limb, MotorParams, MotorSpec,
                                     PwmGains, RobotConfig, SimFixes, available_robots, foot_box_geometry,
                                     load_robot_config, parse_robot_config, resolve_config_path, robots_config_dir,
                                     robots_dir, share_dir)

if TYPE_CHECKING:  # pragma: no cover - typing only
    import pinocchio as pin

__all__ = [
    "ROBOTS_DIR", "robots_dir", "share_dir", "robots_config_dir", "available_robots",
    "ContactSurface", "Limb", "PwmGains", "MotorSpec", "MotorParams", "CollisionConfig",
    "FootBox", "SimFixes", "RobotConfig", "RobotModel", "load_robot_config", "parse_robot_config",
    "load_robot",
]

#: |base_height (YAML) - base height from forward kinematics| above this is a config error [m].
_BASE_HEIGHT_TOLERANCE = 2e-3
#: Soles of the reference posture must be flat within this angle [rad] and level within this height [m].
_FLAT_TOLERANCE = 1e-3
_LEVEL_TOLERANCE = 1e-3


def __getattr__(name: str) -> Any:  # module attribute ROBOTS_DIR, resolved on first use
    if name == "ROBOTS_DIR":
        return robots_dir()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


class RobotModel:
    """Pinocchio model (free-flyer, fingers locked) + convex-hull collision model of one robot."""

    def __init__(self, config: RobotConfig, use_geometry_cache: bool = True):
        """Build the model; ``use_geometry_cache=False`` recomputes the hulls from the source meshes
        even when the cached collision URDF (climb_core.geometry_cache) is up to date."""
        import coal
        import pinocchio as pin

        self.config = config
        urdf = str(config.urdf_path)
        full = pin.buildModelFromUrdf(urdf, pin.JointModelFreeFlyer())
        self._add_armature(full)
        self._foot_box_names: dict[str, str] = {}
        cache = CollisionUrdfCache(config)
        cached = cache.cached() if use_geometry_cache else None
        if cached is not None:
            # Fast path: the cached collision URDF holds the same hulls (OBJ) and foot boxes.
            geom = pin.buildGeomFromUrdf(full, str(cached), pin.GeometryType.COLLISION,
                                         package_dirs=[str(p) for p in config.package_dirs])
            if config.sim.foot_box is not None:
                self._name_foot_boxes(full, geom)
        else:
            geom = pin.buildGeomFromUrdf(full, urdf, pin.GeometryType.COLLISION,
                                         package_dirs=[str(p) for p in config.package_dirs])
            if config.sim.foot_box is not None:
                geom = self._with_foot_boxes(full, geom)
        for obj in geom.geometryObjects:
            if isinstance(obj.geometry, coal.BVHModelBase):
                obj.geometry.buildConvexHull(True, "Qt")
                obj.geometry = obj.geometry.convex
                obj.meshScale = np.ones(3)  # the hull's points are already scaled
        geom = self._canonical_order(geom)
        self._full_model = full
        self._full_collision_model = geom

        q_lock = pin.neutral(full)  # only the locked joints' entries are read
        locked_ids = [full.getJointId(name) for name in config.locked_joints]
        for name, jid in zip(config.locked_joints, locked_ids):
            q_lock[full.joints[jid].idx_q] = config.locked_posture[name]
        self.model, self.collision_model = pin.buildReducedModel(full, geom, locked_ids, q_lock)
        self.data = self.model.createData()
        self.joint_names: list[str] = list(self.model.names[2:])
        self.mass: float = float(pin.computeTotalMass(self.model))
        for limb in config.limbs.values():
            if not self.model.existFrame(limb.surface.frame):
                raise SpecError(f"limbs.{limb.name}.frame", f"{limb.surface.frame!r} is not a model frame")
        self._setup_collision_pairs()
        self.collision_data = pin.GeometryData(self.collision_model)
        self.env_geometry_ids: tuple[int, ...] = tuple(
            i for i, obj in enumerate(self.collision_model.geometryObjects)
            if self._link_of(obj) in set(config.collision.env_links))
        self._q_reference = self._compute_reference()
        if cached is None and cache.cached() is None:
            cache.write(geom)

    # -- construction helpers ------------------------------------------------------------------
    def _add_armature(self, full: "pin.Model") -> None:
        import pinocchio as pin

        locked = set(self.config.locked_joints)
        for jid in range(2, full.njoints):
            if full.joints[jid].nv == 0:
                continue
            a = self.config.sim.finger_armature if full.names[jid] in locked else self.config.sim.armature
            if a > 0:
                inertia = full.inertias[jid]
                full.inertias[jid] = pin.Inertia(inertia.mass, inertia.lever, inertia.inertia + a * np.eye(3))

    def _with_foot_boxes(self, full: "pin.Model", geom: "pin.GeometryModel") -> "pin.GeometryModel":
        import coal
        import pinocchio as pin

        foot_links = {self.config.limbs[limb].surface.frame: limb for limb in FEET}
        out = pin.GeometryModel()
        for obj in geom.geometryObjects:
            if full.frames[obj.parentFrame].name not in foot_links:
                out.addGeometryObject(obj)
        for link, limb in foot_links.items():
            fid = full.getFrameId(link)
            frame = full.frames[fid]
            size, centre = foot_box_geometry(self.config, limb)
            placement = frame.placement * pin.SE3(np.eye(3), centre)
            name = f"{link}_foot_box"
            out.addGeometryObject(pin.GeometryObject(name, frame.parentJoint, fid, placement,
                                                     coal.Box(*size)))
            self._foot_box_names[link] = name
        return out

    @staticmethod
    def _canonical_order(geom: "pin.GeometryModel") -> "pin.GeometryModel":
        """Geometry objects sorted by (parent joint, name): the same ids whichever path built them."""
        import pinocchio as pin

        out = pin.GeometryModel()
        for obj in sorted(geom.geometryObjects, key=lambda o: (o.parentJoint, o.name)):
            out.addGeometryObject(obj)
        return out

    def _name_foot_boxes(self, full: "pin.Model", geom: "pin.GeometryModel") -> None:
        foot_links = {self.config.limbs[limb].surface.frame for limb in FEET}
        for obj in geom.geometryObjects:
            link = full.frames[obj.parentFrame].name
            if link in foot_links:
                obj.name = f"{link}_foot_box"
                self._foot_box_names[link] = obj.name

    def _link_of(self, obj: "pin.GeometryObject") -> str:
        return self.model.frames[obj.parentFrame].name

    def _setup_collision_pairs(self) -> None:
        """Self-collision pairs: links on different, non-adjacent joints, minus ignore_pairs."""
        import pinocchio as pin

        ignore = {frozenset(p) for p in self.config.collision.ignore_pairs}
        objs = self.collision_model.geometryObjects
        parents = self.model.parents
        self.collision_model.removeAllCollisionPairs()
        for i in range(len(objs)):
            for j in range(i + 1, len(objs)):
                ji, jj = objs[i].parentJoint, objs[j].parentJoint
                if ji == jj or parents[ji] == jj or parents[jj] == ji:
                    continue
                if frozenset((self._link_of(objs[i]), self._link_of(objs[j]))) in ignore:
                    continue
                self.collision_model.addCollisionPair(pin.CollisionPair(i, j))

    def _compute_reference(self) -> np.ndarray:
        import pinocchio as pin

        cfg = self.config
        q = pin.neutral(self.model)
        for name, value in cfg.reference_posture.items():
            q[self.model.joints[self.model.getJointId(name)].idx_q] = value
        data = self.model.createData()
        pin.framesForwardKinematics(self.model, data, q)
        sole_z, centres = [], []
        for limb in FEET:
            surface = cfg.limbs[limb].surface
            T = data.oMf[self.model.getFrameId(surface.frame)].homogeneous @ surface.T_frame_surface
            tilt = math.acos(float(np.clip(-T[2, 2], -1.0, 1.0)))
            if tilt > _FLAT_TOLERANCE:
                raise SpecError("reference_posture", f"{limb} sole is tilted by {tilt:.4f} rad (feet must be flat)")
            sole_z.append(T[2, 3])
            centres.append(T[:3, 3])
        if abs(sole_z[0] - sole_z[1]) > _LEVEL_TOLERANCE:
            raise SpecError("reference_posture", f"soles at different heights: {sole_z}")
        mid = (centres[0] + centres[1]) / 2
        q[0] -= mid[0]
        q[1] -= mid[1]
        q[2] -= min(sole_z)
        if abs(q[2] - cfg.base_height) > _BASE_HEIGHT_TOLERANCE:
            raise SpecError("base_height", f"{cfg.base_height} m, but the reference posture puts the base "
                                           f"at {q[2]:.4f} m above the soles")
        q.setflags(write=False)
        return q

    # -- public API ----------------------------------------------------------------------------
    @property
    def full_model(self) -> "pin.Model":
        """The full URDF's kinematic model (free-flyer, finger joints kept), for
        :attr:`full_collision_model`."""
        return self._full_model

    @property
    def full_collision_model(self) -> "pin.GeometryModel":
        """Collision geometry (hulls, foot boxes) of the full URDF, finger joints kept: the
        simulator's URDF is written from it (sim_bridge.sim_urdf)."""
        return self._full_collision_model

    @property
    def nq(self) -> int:
        return self.model.nq

    @property
    def nv(self) -> int:
        return self.model.nv

    def q_reference(self) -> np.ndarray:
        """Standing on flat ground at the origin: soles flat at z = 0, pelvis at base_height."""
        return self._q_reference.copy()

    def frame_id(self, name: str) -> int:
        if not self.model.existFrame(name):
            raise SpecError("frame", f"{name!r} is not a frame of {self.config.name}")
        return int(self.model.getFrameId(name))

    def joint_index_v(self, name: str) -> int:
        """Index of a whole-body joint in the velocity vector (6 + actuated index)."""
        if name not in self.joint_names:
            raise SpecError("joint", f"{name!r} is not a whole-body joint of {self.config.name}")
        return int(self.model.joints[self.model.getJointId(name)].idx_v)

    def effort_limits(self) -> np.ndarray:
        """(nv - 6,) URDF effort limits of the whole-body joints, Pinocchio order [N m]."""
        return np.array(self.model.effortLimit[6:], dtype=float)

    def T_world_surface(self, limb: str, q: np.ndarray, data: "pin.Data | None" = None,
                        surface: str | None = None) -> np.ndarray:
        """4x4 pose of the limb's contact surface frame in the world at configuration q: its primary
        surface (a sole, a grasp), or the named one of its surfaces (G1's ``right_hand_back``: a
        hold's ``robot_surface``). Without ``data``: a scratch pin.Data of this thread (createData
        costs ~0.3 ms for G1)."""
        import pinocchio as pin

        if data is None:
            data = self._scratch_data()
        limb_config = self.config.limbs[limb]
        if surface is None or surface == limb_config.surface.name:
            surface = limb_config.surface
        else:
            try:
                surface = limb_config.surfaces[surface]
            except KeyError:
                raise ValueError(f"limb {limb!r} has no contact surface {surface!r} "
                                 f"(it has {', '.join(limb_config.surfaces)})") from None
        fid = self.frame_id(surface.frame)
        pin.framesForwardKinematics(self.model, data, q)
        return data.oMf[fid].homogeneous @ surface.T_frame_surface

    def _scratch_data(self) -> "pin.Data":
        """A pin.Data of this robot's model owned by the calling thread (reused between calls)."""
        import threading

        local = self.__dict__.get("_scratch_local")
        if local is None:
            local = self.__dict__.setdefault("_scratch_local", threading.local())
        data = getattr(local, "data", None)
        if data is None:
            data = local.data = self.model.createData()
        return data


# --------------------------------------------------------------------------------------------
# Process-wide cache
# --------------------------------------------------------------------------------------------
_CACHE: dict[pathlib.Path, RobotModel] = {}
_CACHE_LOCK = threading.Lock()


def load_robot(name_or_path: str | os.PathLike = "g1") -> RobotModel:
    """The robot's model, built once per process (the same object is returned on every call)."""
    path = resolve_config_path(name_or_path)
    with _CACHE_LOCK:
        robot = _CACHE.get(path)
        if robot is None:
            robot = RobotModel(load_robot_config(path))
            _CACHE[path] = robot
        return robot

