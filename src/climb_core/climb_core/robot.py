"""Robot models: one YAML file per robot (config/robots/<name>.yaml) -> frozen config dataclasses ->
a Pinocchio model with convex-hull collision geometry, plus a PyBullet-ready URDF built from the
same source.

Conventions (every consumer relies on them):

- Units are SI (m, rad, kg, N, N m, V, ohm, A, s). Frames are URDF link frames.
- ``RobotModel.model`` is the URDF with a free-flyer root and the ``locked_joints`` (fingers,
  grippers) removed with ``pin.buildReducedModel`` at their neutral position (clipped to their
  limits); the locked links stay attached, rigidly, to their parent. The whole-body controller
  and the planners work on this model. The simulator keeps the finger joints (the bridge drives
  them).
- Contact surfaces are data attached to a limb frame. ``ContactSurface.T_frame_surface`` is the
  surface frame in the limb frame: origin at the sole polygon centre / the grasp cylinder
  centre; z is the contact normal pointing *out of the robot* (down, out of the sole, for a foot
  standing flat; from the palm toward the grasped rung for a hand); for a grasp, x is the
  cylinder axis; for a polygon, x is the frame's x (forward along the foot).
- Sole vertices are the 4 corners in the limb frame, counter-clockwise seen from above (from the
  foot's +z), all in one plane z = const of the limb frame.
- ``q_reference()`` stands the robot on flat ground: both soles flat with their bottom face at
  world z = 0, the midpoint of the two sole centres at world x = y = 0, the base frame upright
  with yaw 0.
- Every mesh collision geometry is replaced by its qhull convex hull
  (``buildConvexHull(True, "Qt")``): the same hulls are written as OBJ files for the simulator,
  so the planner, the controller and PyBullet collide the same shapes.
- ``sim.foot_box``: the limb frame link of each foot loses its URDF collision elements and gets a
  thin box whose bottom face is the sole polygon (G1: the URDF's 4 corner spheres touch nothing
  when a rung sits under the arch). The Pinocchio collision model and the simulator use the box.
- ``sim.armature``: an armature-like rotational inertia [kg m^2] added, as ``armature * I3``
  about the link's centre of mass, to the child link of every whole-body joint. It is added in
  the simulator's URDF *and* in the Pinocchio model, so the controller's model matches the
  simulated robot (PyBullet has no joint armature; ``a * I3`` is invariant to the URDF inertial
  frame's orientation and to merging fixed links).

The loaded ``RobotModel`` is cached per process: ``load_robot("g1")`` returns the same object on
every call. Its ``data``/``collision_data`` are a convenience workspace: a thread that computes
kinematics concurrently should call ``model.createData()`` itself.
"""
from __future__ import annotations

import fnmatch
import hashlib
import importlib.metadata
import math
import os
import pathlib
import threading
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
import yaml

from climb_core.contact import FEET, HANDS, LIMBS
from climb_core.errors import ClimbError, SpecError
from climb_core.ros_env import project_root

if TYPE_CHECKING:  # pragma: no cover - typing only
    import pinocchio as pin

__all__ = [
    "ROBOTS_DIR", "robots_dir", "share_dir", "robots_config_dir", "available_robots",
    "ContactSurface", "Limb", "PwmGains", "MotorSpec", "MotorParams", "CollisionConfig",
    "FootBox", "SimFixes", "RobotConfig", "RobotModel", "load_robot_config", "parse_robot_config",
    "load_robot",
    "is_ascii_stl",
]

#: Bump when the simulator URDF writer changes (invalidates the on-disk cache).
_SIM_URDF_GENERATOR = "climb_core.robot sim URDF v1"
#: |base_height (YAML) - base height from forward kinematics| above this is a config error [m].
_BASE_HEIGHT_TOLERANCE = 2e-3
#: Soles of the reference posture must be flat within this angle [rad] and level within this height [m].
_FLAT_TOLERANCE = 1e-3
_LEVEL_TOLERANCE = 1e-3
#: PyBullet and Pinocchio total masses must agree within this fraction.
_MASS_TOLERANCE = 0.01

_SURFACE_KINDS = ("sole", "palm", "grasp")
_MOTOR_FIELDS = ("supply_voltage", "resistance", "torque_constant", "gear_ratio", "current_limit",
                 "trip_hold_off_s")
_REQUIRED_SOURCES = ("urdf", "locked_joints", "reference_posture", "base_height", "grip_strength",
                     "capture_range", "limbs", "ft_sensors", "pwm", "motor", "collision", "sim")


# --------------------------------------------------------------------------------------------
# Where the robots live
# --------------------------------------------------------------------------------------------
def robots_dir() -> pathlib.Path:
    """example-robot-data's ``robots/`` folder (``$CLIMB_ROBOTS_DIR`` overrides it)."""
    override = os.environ.get("CLIMB_ROBOTS_DIR")
    if override:
        return pathlib.Path(override)
    try:
        dist = importlib.metadata.distribution("example-robot-data")
        path = pathlib.Path(str(dist.locate_file("cmeel.prefix/share/example-robot-data/robots")))
        if path.is_dir():
            return path
    except importlib.metadata.PackageNotFoundError:
        pass
    raise FileNotFoundError("example-robot-data is not installed (pip install example-robot-data) "
                            "and CLIMB_ROBOTS_DIR is not set")


def share_dir() -> pathlib.Path:
    """The ``share/`` folder that resolves ``package://example-robot-data/...`` mesh paths."""
    return robots_dir().parents[1]


def robots_config_dir() -> pathlib.Path:
    return project_root() / "config" / "robots"


def available_robots() -> list[str]:
    """Names of the robot configs in config/robots/ (sorted)."""
    return sorted(p.stem for p in robots_config_dir().glob("*.yaml"))


def __getattr__(name: str) -> Any:  # module attribute ROBOTS_DIR, resolved on first use
    if name == "ROBOTS_DIR":
        return robots_dir()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


# --------------------------------------------------------------------------------------------
# Config dataclasses
# --------------------------------------------------------------------------------------------
def _frozen_array(values: Any, shape: tuple[int, ...] | None = None) -> np.ndarray:
    arr = np.array(values, dtype=float)
    if shape is not None:
        arr = arr.reshape(shape)
    arr.setflags(write=False)
    return arr


@dataclass(frozen=True, eq=False)
class ContactSurface:
    name: str  # "left_sole", "right_grasp", ...
    frame: str  # URDF link (Pinocchio frame) the surface is attached to
    kind: str  # "sole" | "palm" (planar polygon) | "grasp" (closed hand = cylinder)
    vertices: np.ndarray  # polygon: (4, 3) corners in `frame` [m]; grasp: (0, 3)
    radius: float  # grasp cylinder radius [m] (0 for polygons)
    length: float  # grasp cylinder length [m] (0 for polygons)
    axis: np.ndarray  # grasp cylinder axis in `frame` (unit); zero for polygons
    T_frame_surface: np.ndarray  # 4x4 surface frame in `frame` (z = contact normal out of the robot)

    @property
    def centre(self) -> np.ndarray:
        """Surface origin in the limb frame [m]."""
        return self.T_frame_surface[:3, 3].copy()

    @property
    def normal(self) -> np.ndarray:
        """Contact normal out of the robot, in the limb frame (unit)."""
        return self.T_frame_surface[:3, 2].copy()


@dataclass(frozen=True)
class Limb:
    name: str  # left_foot | right_foot | left_hand | right_hand
    surface: ContactSurface
    ft_sensor: str  # key of RobotConfig.ft_sensors
    joints: tuple[str, ...]  # whole-body joints from the root to the end effector


@dataclass(frozen=True)
class PwmGains:
    """Compliance controller gains (paper eq. 1): duty = kp (q_des - q) - kd dq + f, duty in [-1, 1]."""

    kp: dict[str, float]  # joint -> [duty/rad]
    kd: dict[str, float]  # joint -> [duty s/rad]


@dataclass(frozen=True)
class MotorSpec:
    """DC motor + driver of one joint, quantities at the motor (torque at the joint = k_t N I)."""

    supply_voltage: float  # [V] bus voltage at duty 1
    resistance: float  # [ohm] winding resistance
    torque_constant: float  # [N m/A] motor side (back-EMF constant, V s/rad, has the same value)
    gear_ratio: float  # [-] motor turns per joint turn
    current_limit: float  # [A] driver over-current threshold
    trip_hold_off_s: float  # [s] after an over-current trip, the driver keeps the power cut this long, then restores it

    @property
    def max_joint_torque(self) -> float:
        """Joint torque at the current limit [N m]."""
        return self.torque_constant * self.gear_ratio * self.current_limit

    @property
    def no_load_speed(self) -> float:
        """Joint speed at duty 1 and zero load [rad/s]."""
        return self.supply_voltage / (self.torque_constant * self.gear_ratio)


@dataclass(frozen=True)
class MotorParams:
    default: MotorSpec
    joints: dict[str, MotorSpec]  # every whole-body joint -> its motor (default + overrides applied)

    def for_joint(self, joint: str) -> MotorSpec:
        return self.joints.get(joint, self.default)


@dataclass(frozen=True)
class CollisionConfig:
    ignore_pairs: tuple[tuple[str, str], ...]  # URDF link pairs never checked against each other
    env_links: tuple[str, ...]  # links checked against the environment (ladder, ground, obstacles)


@dataclass(frozen=True)
class FootBox:
    thickness: float  # [m] box height; its bottom face is the limb's sole polygon


@dataclass(frozen=True)
class SimFixes:
    tiny_mass: float  # [kg] mass given to links without <inertial> (or with mass 0) in the sim URDF
    tiny_inertia: float  # [kg m^2] their principal inertia
    armature: float  # [kg m^2] added to the child link of each whole-body joint (sim and Pinocchio)
    finger_armature: float  # [kg m^2] same for the locked (finger / gripper) joints
    foot_box: FootBox | None  # thin box replacing each foot link's collision elements


@dataclass(frozen=True)
class RobotConfig:
    name: str
    urdf_path: pathlib.Path
    package_dirs: tuple[pathlib.Path, ...]
    limbs: dict[str, Limb]
    ft_sensors: dict[str, str]  # sensor name -> URDF joint
    locked_joints: tuple[str, ...]
    reference_posture: dict[str, float]  # whole-body joint -> [rad] (every whole-body joint listed)
    base_height: float  # [m]
    grip_strength: float  # [N]
    capture_range: float  # [m]
    pwm: PwmGains
    motor: MotorParams
    collision: CollisionConfig
    sim: SimFixes
    sources: dict[str, str]
    config_path: pathlib.Path | None = None
    description: str = ""

    @property
    def whole_body_joints(self) -> tuple[str, ...]:
        """Actuated (non-fixed, non-locked) URDF joints, in URDF order."""
        return tuple(self.reference_posture)


# --------------------------------------------------------------------------------------------
# URDF tree (ElementTree, no Pinocchio: config validation stays cheap)
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class _UrdfJoint:
    name: str
    type: str
    parent: str
    child: str
    lower: float
    upper: float
    effort: float
    velocity: float


class _UrdfTree:
    def __init__(self, path: pathlib.Path):
        self.path = path
        try:
            root = ET.parse(path).getroot()
        except ET.ParseError as exc:
            raise SpecError("urdf", f"{path} is not valid XML: {exc}") from exc
        self.links: dict[str, ET.Element] = {el.get("name"): el for el in root.findall("link")}
        self.joints: dict[str, _UrdfJoint] = {}
        for el in root.findall("joint"):
            limit = el.find("limit")

            def lim(attr: str, default: float) -> float:
                if limit is None or limit.get(attr) is None:
                    return default
                return float(limit.get(attr))

            self.joints[el.get("name")] = _UrdfJoint(
                name=el.get("name"), type=el.get("type"), parent=el.find("parent").get("link"),
                child=el.find("child").get("link"), lower=lim("lower", -math.inf),
                upper=lim("upper", math.inf), effort=lim("effort", 0.0), velocity=lim("velocity", 0.0))
        self.parent_joint: dict[str, _UrdfJoint] = {j.child: j for j in self.joints.values()}
        roots = [name for name in self.links if name not in self.parent_joint]
        if len(roots) != 1:
            raise SpecError("urdf", f"{path} must have exactly one root link, found {roots}")
        self.root = roots[0]

    def movable(self) -> list[str]:
        return [j.name for j in self.joints.values() if j.type in ("revolute", "continuous", "prismatic")]

    def chain(self, link: str) -> list[_UrdfJoint]:
        """Joints from the root link down to ``link``."""
        out: list[_UrdfJoint] = []
        while link in self.parent_joint:
            joint = self.parent_joint[link]
            out.append(joint)
            link = joint.parent
        return out[::-1]

    def link_mass(self, link: str) -> float:
        mass = self.links[link].find("inertial/mass")
        return 0.0 if mass is None else float(mass.get("value", 0.0))


# --------------------------------------------------------------------------------------------
# YAML validation helpers: every error names the dotted field and the rule
# --------------------------------------------------------------------------------------------
_MISSING = object()


def _mapping(value: Any, path: str, allowed: tuple[str, ...] | None = None,
             required: tuple[str, ...] = ()) -> dict:
    if not isinstance(value, dict):
        raise SpecError(path, "must be a mapping")
    if allowed is not None:
        for key in value:
            if key not in allowed:
                raise SpecError(f"{path}.{key}" if path else str(key),
                                f"unknown key (allowed: {', '.join(allowed)})")
    for key in required:
        if key not in value:
            raise SpecError(f"{path}.{key}" if path else key, "missing required field")
    return value


def _number(value: Any, path: str, *, positive: bool = False, non_negative: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise SpecError(path, f"must be a number, got {value!r}")
    x = float(value)
    if not math.isfinite(x):
        raise SpecError(path, "must be finite")
    if positive and x <= 0:
        raise SpecError(path, f"must be > 0, got {x}")
    if non_negative and x < 0:
        raise SpecError(path, f"must be >= 0, got {x}")
    return x


def _string(value: Any, path: str) -> str:
    if not isinstance(value, str) or not value:
        raise SpecError(path, "must be a non-empty string")
    return value


def _vector(value: Any, path: str, n: int = 3) -> np.ndarray:
    if not isinstance(value, (list, tuple)) or len(value) != n:
        raise SpecError(path, f"must be a list of {n} numbers")
    return np.array([_number(v, f"{path}[{i}]") for i, v in enumerate(value)])


def _unit(value: Any, path: str) -> np.ndarray:
    v = _vector(value, path)
    norm = np.linalg.norm(v)
    if norm < 1e-9:
        raise SpecError(path, "must be a non-zero vector")
    return v / norm


def _expand_patterns(entries: dict, joints: tuple[str, ...], path: str) -> list[tuple[str, list[str], Any]]:
    """(pattern, matched joints, value) in file order; a pattern must match a whole-body joint."""
    out = []
    for pattern, value in entries.items():
        matched = [j for j in joints if fnmatch.fnmatchcase(j, str(pattern))]
        if not matched:
            raise SpecError(f"{path}.{pattern}", "matches no whole-body joint")
        out.append((str(pattern), matched, value))
    return out


# --------------------------------------------------------------------------------------------
# Config parsing
# --------------------------------------------------------------------------------------------
_TOP_KEYS = ("name", "description", "urdf", "package_dirs", "locked_joints", "reference_posture",
             "base_height", "grip_strength", "capture_range", "limbs", "ft_sensors", "pwm", "motor",
             "collision", "sim", "sources")


def _resolve_config_path(name_or_path: str | os.PathLike) -> pathlib.Path:
    text = os.fspath(name_or_path)
    candidate = pathlib.Path(text)
    looks_like_path = candidate.suffix in (".yaml", ".yml") or os.sep in text or candidate.is_file()
    if looks_like_path:
        if not candidate.is_file():
            raise SpecError("robot", f"config file {text!r} does not exist")
        return candidate.resolve()
    path = robots_config_dir() / f"{text}.yaml"
    if not path.is_file():
        raise SpecError("robot", f"unknown robot {text!r} (available: {', '.join(available_robots())})")
    return path.resolve()


def load_robot_config(name_or_path: str | os.PathLike = "g1") -> RobotConfig:
    """Read and validate config/robots/<name>.yaml (or a YAML file path)."""
    path = _resolve_config_path(name_or_path)
    try:
        data = yaml.load(path.read_text(), Loader=getattr(yaml, "CSafeLoader", yaml.SafeLoader))
    except yaml.YAMLError as exc:
        raise SpecError("robot", f"{path} is not valid YAML: {exc}") from exc
    return parse_robot_config(data, config_path=path)


def parse_robot_config(data: Any, config_path: pathlib.Path | None = None) -> RobotConfig:
    """Validate a robot config mapping (the YAML's content); raises SpecError(field, rule)."""
    _mapping(data, "", _TOP_KEYS, required=tuple(k for k in _TOP_KEYS
                                                  if k not in ("description", "package_dirs")))
    name = _string(data["name"], "name")

    urdf_text = _string(data["urdf"], "urdf")
    urdf_path = pathlib.Path(urdf_text)
    if not urdf_path.is_absolute():
        urdf_path = robots_dir() / urdf_path
    if not urdf_path.is_file():
        raise SpecError("urdf", f"file {urdf_path} does not exist")
    tree = _UrdfTree(urdf_path)

    raw_dirs = data.get("package_dirs") or []
    if not isinstance(raw_dirs, list):
        raise SpecError("package_dirs", "must be a list of folders")
    package_dirs = []
    for i, d in enumerate(raw_dirs):
        p = pathlib.Path(_string(d, f"package_dirs[{i}]"))
        if not p.is_dir():
            raise SpecError(f"package_dirs[{i}]", f"folder {p} does not exist")
        package_dirs.append(p)
    if share_dir() not in package_dirs:
        package_dirs.append(share_dir())

    # Joints ---------------------------------------------------------------------------------
    movable = tree.movable()
    locked_raw = data["locked_joints"] or []
    if not isinstance(locked_raw, list):
        raise SpecError("locked_joints", "must be a list of joint names")
    locked = []
    for i, j in enumerate(locked_raw):
        j = _string(j, f"locked_joints[{i}]")
        if j not in movable:
            raise SpecError(f"locked_joints[{i}]", f"{j!r} is not a movable joint of the URDF")
        locked.append(j)
    whole_body = tuple(j for j in movable if j not in locked)

    posture_raw = _mapping(data["reference_posture"], "reference_posture")
    posture: dict[str, float] = {}
    for j, value in posture_raw.items():
        if j not in whole_body:
            raise SpecError(f"reference_posture.{j}", "not a whole-body joint (unknown or locked)")
    for j in whole_body:
        value = _number(posture_raw[j], f"reference_posture.{j}") if j in posture_raw else 0.0
        uj = tree.joints[j]
        if not (uj.lower - 1e-9 <= value <= uj.upper + 1e-9):
            raise SpecError(f"reference_posture.{j}",
                            f"{value} rad is outside the URDF limits [{uj.lower}, {uj.upper}]"
                            + ("" if j in posture_raw else " (joint not listed: 0 assumed)"))
        posture[j] = value

    base_height = _number(data["base_height"], "base_height", positive=True)
    grip_strength = _number(data["grip_strength"], "grip_strength", positive=True)
    capture_range = _number(data["capture_range"], "capture_range", positive=True)

    # F/T sensors -------------------------------------------------------------------------------
    ft_raw = _mapping(data["ft_sensors"], "ft_sensors")
    ft_sensors: dict[str, str] = {}
    for sensor, joint in ft_raw.items():
        joint = _string(joint, f"ft_sensors.{sensor}")
        if joint not in tree.joints:
            raise SpecError(f"ft_sensors.{sensor}", f"{joint!r} is not a URDF joint")
        if tree.link_mass(tree.joints[joint].child) <= 0:
            raise SpecError(f"ft_sensors.{sensor}",
                            f"child link of {joint!r} has no mass: PyBullet reads 0 on such a joint")
        ft_sensors[str(sensor)] = joint

    # Limbs ----------------------------------------------------------------------------------
    limbs_raw = _mapping(data["limbs"], "limbs", LIMBS, required=LIMBS)
    limbs = {limb: _parse_limb(limb, limbs_raw[limb], tree, ft_sensors, whole_body) for limb in LIMBS}

    # Gains and motors -------------------------------------------------------------------------
    pwm = _parse_pwm(data["pwm"], whole_body)
    motor = _parse_motor(data["motor"], whole_body)

    # Collision ------------------------------------------------------------------------------
    col = _mapping(data["collision"], "collision", ("ignore_pairs", "env_links"),
                   required=("ignore_pairs", "env_links"))
    pairs_raw = col["ignore_pairs"] or []
    if not isinstance(pairs_raw, list):
        raise SpecError("collision.ignore_pairs", "must be a list of [link, link] pairs")
    pairs = []
    for i, pair in enumerate(pairs_raw):
        if not isinstance(pair, list) or len(pair) != 2:
            raise SpecError(f"collision.ignore_pairs[{i}]", "must be a pair [link_a, link_b]")
        for link in pair:
            if link not in tree.links:
                raise SpecError(f"collision.ignore_pairs[{i}]", f"{link!r} is not a URDF link")
        pairs.append((str(pair[0]), str(pair[1])))
    env_raw = col["env_links"]
    if env_raw == "all":
        env_links = tuple(name for name, el in tree.links.items() if el.find("collision") is not None)
    else:
        if not isinstance(env_raw, list):
            raise SpecError("collision.env_links", "must be 'all' or a list of links")
        for i, link in enumerate(env_raw):
            if link not in tree.links:
                raise SpecError(f"collision.env_links[{i}]", f"{link!r} is not a URDF link")
        env_links = tuple(str(link) for link in env_raw)

    # Simulation fixes ------------------------------------------------------------------------
    sim_raw = _mapping(data["sim"], "sim", ("tiny_mass", "tiny_inertia", "armature", "finger_armature",
                                            "foot_box"),
                       required=("tiny_mass", "tiny_inertia", "armature", "finger_armature", "foot_box"))
    foot_box = None
    if sim_raw["foot_box"] is not None:
        fb = _mapping(sim_raw["foot_box"], "sim.foot_box", ("thickness",), required=("thickness",))
        foot_box = FootBox(thickness=_number(fb["thickness"], "sim.foot_box.thickness", positive=True))
        for limb in FEET:
            v = limbs[limb].surface.vertices
            xs, ys = np.unique(np.round(v[:, 0], 9)), np.unique(np.round(v[:, 1], 9))
            if len(xs) != 2 or len(ys) != 2:
                raise SpecError(f"limbs.{limb}.surface.vertices",
                                "sim.foot_box needs an axis-aligned rectangular sole")
    sim = SimFixes(tiny_mass=_number(sim_raw["tiny_mass"], "sim.tiny_mass", positive=True),
                   tiny_inertia=_number(sim_raw["tiny_inertia"], "sim.tiny_inertia", positive=True),
                   armature=_number(sim_raw["armature"], "sim.armature", non_negative=True),
                   finger_armature=_number(sim_raw["finger_armature"], "sim.finger_armature",
                                           non_negative=True),
                   foot_box=foot_box)

    # Sources --------------------------------------------------------------------------------
    src = _mapping(data["sources"], "sources")
    for key in _REQUIRED_SOURCES:
        if key not in src:
            raise SpecError(f"sources.{key}", "missing: say where this number comes from")
    sources = {str(k): _string(v, f"sources.{k}") for k, v in src.items()}

    description = data.get("description") or ""
    if not isinstance(description, str):
        raise SpecError("description", "must be a string")

    return RobotConfig(
        name=name, urdf_path=urdf_path, package_dirs=tuple(package_dirs), limbs=limbs,
        ft_sensors=ft_sensors, locked_joints=tuple(locked), reference_posture=posture,
        base_height=base_height, grip_strength=grip_strength, capture_range=capture_range,
        pwm=pwm, motor=motor, collision=CollisionConfig(tuple(pairs), env_links), sim=sim,
        sources=sources, config_path=config_path, description=description)


def _parse_limb(limb: str, raw: Any, tree: _UrdfTree, ft_sensors: dict[str, str],
                whole_body: tuple[str, ...]) -> Limb:
    path = f"limbs.{limb}"
    raw = _mapping(raw, path, ("frame", "ft_sensor", "surface"), required=("frame", "ft_sensor", "surface"))
    frame = _string(raw["frame"], f"{path}.frame")
    if frame not in tree.links:
        raise SpecError(f"{path}.frame", f"{frame!r} is not a URDF link")
    sensor = _string(raw["ft_sensor"], f"{path}.ft_sensor")
    if sensor not in ft_sensors:
        raise SpecError(f"{path}.ft_sensor", f"{sensor!r} is not a key of ft_sensors")
    chain = tree.chain(frame)
    if ft_sensors[sensor] not in [j.name for j in chain]:
        raise SpecError(f"{path}.ft_sensor",
                        f"joint {ft_sensors[sensor]!r} does not carry {frame!r} (not on its chain)")
    joints = tuple(j.name for j in chain if j.name in whole_body)

    s_path = f"{path}.surface"
    s = _mapping(raw["surface"], s_path)
    kind = _string(s.get("kind"), f"{s_path}.kind")
    if kind not in _SURFACE_KINDS:
        raise SpecError(f"{s_path}.kind", f"must be one of {', '.join(_SURFACE_KINDS)}")
    if limb in FEET and kind != "sole":
        raise SpecError(f"{s_path}.kind", "a foot's surface must be a sole")
    if limb in HANDS and kind == "sole":
        raise SpecError(f"{s_path}.kind", "a hand's surface must be a grasp or a palm")
    name = _string(s.get("name"), f"{s_path}.name")

    if kind in ("sole", "palm"):
        _mapping(s, s_path, ("name", "kind", "vertices"), required=("vertices",))
        verts_raw = s["vertices"]
        if not isinstance(verts_raw, list) or len(verts_raw) != 4:
            raise SpecError(f"{s_path}.vertices", "must be a list of 4 corners [x, y, z]")
        v = np.array([_vector(c, f"{s_path}.vertices[{i}]") for i, c in enumerate(verts_raw)])
        if np.ptp(v[:, 2]) > 1e-9:
            raise SpecError(f"{s_path}.vertices", "corners must share one z (a plane z = const of the frame)")
        area2 = [np.cross(v[(i + 1) % 4, :2] - v[i, :2], v[(i + 2) % 4, :2] - v[(i + 1) % 4, :2])
                 for i in range(4)]
        if min(area2) <= 0:
            raise SpecError(f"{s_path}.vertices", "corners must form a convex polygon, counter-clockwise from +z")
        T = np.eye(4)
        T[:3, :3] = np.diag([1.0, -1.0, -1.0])  # z out of the sole (down), x forward
        T[:3, 3] = v.mean(axis=0)
        return Limb(limb, ContactSurface(name, frame, kind, _frozen_array(v), 0.0, 0.0,
                                         _frozen_array(np.zeros(3)), _frozen_array(T)), sensor, joints)

    _mapping(s, s_path, ("name", "kind", "centre", "axis", "normal", "radius", "length"),
             required=("centre", "axis", "normal", "radius", "length"))
    centre = _vector(s["centre"], f"{s_path}.centre")
    axis = _unit(s["axis"], f"{s_path}.axis")
    normal = _unit(s["normal"], f"{s_path}.normal")
    if abs(float(axis @ normal)) > 1e-6:
        raise SpecError(f"{s_path}.normal", "must be perpendicular to the cylinder axis")
    radius = _number(s["radius"], f"{s_path}.radius", positive=True)
    length = _number(s["length"], f"{s_path}.length", positive=True)
    T = np.eye(4)
    T[:3, 0], T[:3, 1], T[:3, 2] = axis, np.cross(normal, axis), normal
    T[:3, 3] = centre
    return Limb(limb, ContactSurface(name, frame, kind, _frozen_array(np.zeros((0, 3))), radius, length,
                                     _frozen_array(axis), _frozen_array(T)), sensor, joints)


def _parse_pwm(raw: Any, whole_body: tuple[str, ...]) -> PwmGains:
    raw = _mapping(raw, "pwm", ("default", "joints"), required=("default",))
    default = _mapping(raw["default"], "pwm.default", ("kp", "kd"), required=("kp", "kd"))
    kp = {j: _number(default["kp"], "pwm.default.kp", non_negative=True) for j in whole_body}
    kd = {j: _number(default["kd"], "pwm.default.kd", non_negative=True) for j in whole_body}
    entries = _mapping(raw.get("joints") or {}, "pwm.joints")
    for pattern, matched, value in _expand_patterns(entries, whole_body, "pwm.joints"):
        value = _mapping(value, f"pwm.joints.{pattern}", ("kp", "kd"))
        for key, table in (("kp", kp), ("kd", kd)):
            if key in value:
                x = _number(value[key], f"pwm.joints.{pattern}.{key}", non_negative=True)
                table.update({j: x for j in matched})
    return PwmGains(kp=kp, kd=kd)


def _motor_spec(raw: dict, path: str, base: MotorSpec | None) -> MotorSpec:
    _mapping(raw, path, _MOTOR_FIELDS, required=() if base is not None else _MOTOR_FIELDS)
    values = {}
    for f in _MOTOR_FIELDS:
        if f in raw:
            values[f] = _number(raw[f], f"{path}.{f}", non_negative=(f == "trip_hold_off_s"),
                                positive=(f != "trip_hold_off_s"))
        else:
            values[f] = getattr(base, f)
    return MotorSpec(**values)


def _parse_motor(raw: Any, whole_body: tuple[str, ...]) -> MotorParams:
    raw = _mapping(raw, "motor", ("default", "joints"), required=("default",))
    default = _motor_spec(raw["default"], "motor.default", None)
    specs = {j: default for j in whole_body}
    entries = _mapping(raw.get("joints") or {}, "motor.joints")
    for pattern, matched, value in _expand_patterns(entries, whole_body, "motor.joints"):
        value = _mapping(value, f"motor.joints.{pattern}")
        for j in matched:
            specs[j] = _motor_spec(value, f"motor.joints.{pattern}", specs[j])
    return MotorParams(default=default, joints=specs)


# --------------------------------------------------------------------------------------------
# The model
# --------------------------------------------------------------------------------------------
def _foot_box_geometry(config: RobotConfig, limb: str) -> tuple[np.ndarray, np.ndarray]:
    """(size (3,), centre (3,)) of the foot box in the limb frame [m]."""
    assert config.sim.foot_box is not None
    v = config.limbs[limb].surface.vertices
    lo, hi = v.min(axis=0), v.max(axis=0)
    t = config.sim.foot_box.thickness
    size = np.array([hi[0] - lo[0], hi[1] - lo[1], t])
    centre = np.array([(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, lo[2] + t / 2])
    return size, centre


class RobotModel:
    """Pinocchio model (free-flyer, fingers locked) + convex-hull collision model of one robot."""

    def __init__(self, config: RobotConfig, use_sim_cache: bool = True):
        """Build the model; ``use_sim_cache=False`` reloads the source meshes even when the cached
        simulator URDF (which holds the same hulls) is up to date."""
        import coal
        import pinocchio as pin

        self.config = config
        urdf = str(config.urdf_path)
        full = pin.buildModelFromUrdf(urdf, pin.JointModelFreeFlyer())
        self._add_armature(full)
        self._foot_box_names: dict[str, str] = {}
        writer = _SimUrdfWriter(config)
        sim_urdf = writer.cached() if use_sim_cache else None
        if sim_urdf is not None:
            # Fast path: the cached simulator URDF holds the same hulls (OBJ) and foot boxes.
            geom = pin.buildGeomFromUrdf(full, str(sim_urdf), pin.GeometryType.COLLISION,
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

        q_lock = np.clip(pin.neutral(full), full.lowerPositionLimit, full.upperPositionLimit)
        locked_ids = [full.getJointId(name) for name in config.locked_joints]
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
        self._sim_urdf = sim_urdf if sim_urdf is not None else (writer.cached() or writer.write(geom, self.mass))

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
            size, centre = _foot_box_geometry(self.config, limb)
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

    def T_world_surface(self, limb: str, q: np.ndarray, data: "pin.Data | None" = None) -> np.ndarray:
        """4x4 pose of the limb's contact surface frame in the world at configuration q (without
        ``data``: a scratch pin.Data of this thread, createData costing ~0.3 ms for G1)."""
        import pinocchio as pin

        if data is None:
            data = self._scratch_data()
        surface = self.config.limbs[limb].surface
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

    def sim_urdf_path(self) -> pathlib.Path:
        """PyBullet-ready URDF of this robot (finger joints kept), cached under .cache/robots/.

        Load it with ``flags=p.URDF_USE_INERTIA_FROM_FILE`` (PyBullet otherwise recomputes the
        inertia from the collision shapes and loses the armature)."""
        if not self._sim_urdf.is_file():  # deleted behind our back: write it again
            self._sim_urdf = _SimUrdfWriter(self.config).write(self._full_collision_model, self.mass)
        return self._sim_urdf


# --------------------------------------------------------------------------------------------
# Simulator URDF
# --------------------------------------------------------------------------------------------
def is_ascii_stl(path: pathlib.Path | str) -> bool:
    """True for a text STL (PyBullet drops those silently); binary STL size = 84 + 50 n."""
    path = pathlib.Path(path)
    if path.suffix.lower() != ".stl":
        return False
    size = path.stat().st_size
    with open(path, "rb") as f:
        header = f.read(84)
    if len(header) == 84 and 84 + 50 * int.from_bytes(header[80:84], "little") == size:
        return False
    return header[:5].lower() == b"solid"


def _cache_dir() -> pathlib.Path:
    try:
        base = project_root() / ".cache" / "robots"
    except FileNotFoundError:
        base = pathlib.Path.home() / ".cache" / "climb" / "robots"
    base.mkdir(parents=True, exist_ok=True)
    return base


def _atomic_write(path: pathlib.Path, content: str | bytes) -> None:
    tmp = path.with_name(f".{path.name}.{os.getpid()}.{threading.get_ident()}.tmp")
    mode = "wb" if isinstance(content, bytes) else "w"
    with open(tmp, mode) as f:
        f.write(content)
    os.replace(tmp, path)


def _obj_text(points: np.ndarray, triangles: np.ndarray) -> str:
    lines = [f"v {p[0]:.9g} {p[1]:.9g} {p[2]:.9g}" for p in points]
    lines += [f"f {t[0] + 1} {t[1] + 1} {t[2] + 1}" for t in triangles]
    return "\n".join(lines) + "\n"


def _convex_obj(convex: Any) -> str:
    points = np.asarray(convex.points(), dtype=float)
    tris = np.array([[t[0], t[1], t[2]] for t in (convex.polygons(i) for i in range(convex.num_polygons))],
                    dtype=int).reshape(-1, 3)
    return _obj_text(points, tris)


def _mesh_obj(path: pathlib.Path, scale: np.ndarray) -> str:
    """A mesh file (any format coal/assimp reads) as OBJ text, scale applied."""
    import coal

    bvh = coal.MeshLoader().load(str(path), np.asarray(scale, dtype=float))
    points = np.asarray(bvh.vertices(), dtype=float)
    tris = np.array([[t[0], t[1], t[2]] for t in (bvh.tri_indices(i) for i in range(bvh.num_tris))],
                    dtype=int).reshape(-1, 3)
    return _obj_text(points, tris)


class _SimUrdfWriter:
    """Writes <cache>/<name>_<key>_sim.urdf, key = hash of everything the file derives from."""

    def __init__(self, config: RobotConfig):
        self.config = config
        self.cache = _cache_dir()
        key = self._key()
        # The key is in the name: a config edited elsewhere (or a test's variant) never overwrites
        # the file another process is using; the stamp line double-checks it.
        self.out = self.cache / f"{config.name}_{key}_sim.urdf"
        self.stamp = f"<!-- {_SIM_URDF_GENERATOR}; key={key} -->"

    def _key(self) -> str:
        h = hashlib.sha256()
        h.update(_SIM_URDF_GENERATOR.encode())
        h.update(str(self.config.urdf_path).encode())
        h.update(self.config.urdf_path.read_bytes())
        if self.config.config_path is not None:
            h.update(self.config.config_path.read_bytes())
        else:
            h.update(repr(self.config).encode())
        for dist in ("coal", "pin", "example-robot-data"):
            try:
                h.update(importlib.metadata.version(dist).encode())
            except importlib.metadata.PackageNotFoundError:
                pass
        return h.hexdigest()[:16]

    def cached(self) -> pathlib.Path | None:
        """The cached URDF if it is up to date (and every mesh it names exists), else None."""
        if not self.out.is_file():
            return None
        text = self.out.read_text()
        lines = text.split("\n", 2)
        if len(lines) < 2 or lines[1].strip() != self.stamp:
            return None
        for mesh in ET.fromstring(lines[2] if len(lines) > 2 else "<robot/>").iter("mesh"):
            if not pathlib.Path(mesh.get("filename", "")).is_file():
                return None
        return self.out

    def write(self, geom: "pin.GeometryModel", expected_mass: float) -> pathlib.Path:
        text = self._generate(geom)
        _verify_in_pybullet_text(text, expected_mass, self.config.name, self.cache)
        _atomic_write(self.out, text)
        return self.out

    def _write_mesh(self, text: str, stem: str) -> pathlib.Path:
        digest = hashlib.sha256(text.encode()).hexdigest()[:12]
        mesh_dir = self.cache / f"{self.config.name}_meshes"
        mesh_dir.mkdir(parents=True, exist_ok=True)
        path = mesh_dir / f"{stem}_{digest}.obj"
        if not path.is_file():
            _atomic_write(path, text)
        return path

    def _resolve(self, filename: str) -> pathlib.Path:
        if filename.startswith("package://"):
            rel = filename[len("package://"):].lstrip("/")
            for d in self.config.package_dirs:
                if (d / rel).is_file():
                    return (d / rel).resolve()
            raise ClimbError(f"{self.config.name}: cannot resolve {filename} in {self.config.package_dirs}")
        if filename.startswith("file://"):
            filename = filename[len("file://"):]
        p = pathlib.Path(filename)
        return (p if p.is_absolute() else self.config.urdf_path.parent / p).resolve()

    def _generate(self, geom: "pin.GeometryModel") -> str:
        cfg = self.config
        hulls = {obj.name: obj.geometry for obj in geom.geometryObjects}
        tree = ET.parse(cfg.urdf_path)
        root = tree.getroot()
        joints_by_child = {el.find("child").get("link"): el for el in root.findall("joint")}
        locked = set(cfg.locked_joints)
        foot_links = {cfg.limbs[limb].surface.frame: limb for limb in FEET} if cfg.sim.foot_box else {}

        for link in root.findall("link"):
            name = link.get("name")
            self._fix_inertial(link, joints_by_child.get(name), locked)
            for k, col in enumerate(link.findall("collision")):
                if name in foot_links:
                    link.remove(col)
                    continue
                mesh = col.find("geometry/mesh")
                if mesh is None:
                    continue
                hull = hulls.get(f"{name}_{k}")
                if hull is None:
                    raise ClimbError(f"{cfg.name}: no collision hull for {name} element {k}")
                mesh.set("filename", str(self._write_mesh(_convex_obj(hull), f"{name}_{k}")))
                mesh.attrib.pop("scale", None)
            if name in foot_links:
                size, centre = _foot_box_geometry(cfg, foot_links[name])
                col = ET.SubElement(link, "collision", {"name": f"{name}_foot_box"})
                ET.SubElement(col, "origin", {"xyz": " ".join(f"{x:.9g}" for x in centre), "rpy": "0 0 0"})
                geo = ET.SubElement(col, "geometry")
                ET.SubElement(geo, "box", {"size": " ".join(f"{x:.9g}" for x in size)})
            for k, vis in enumerate(link.findall("visual")):
                mesh = vis.find("geometry/mesh")
                if mesh is None:
                    continue
                src = self._resolve(mesh.get("filename"))
                if is_ascii_stl(src):  # PyBullet silently drops text STL: convert
                    scale = np.array([float(x) for x in mesh.get("scale", "1 1 1").split()])
                    mesh.set("filename", str(self._write_mesh(_mesh_obj(src, scale), f"{name}_visual_{k}")))
                    mesh.attrib.pop("scale", None)
                else:
                    mesh.set("filename", str(src))
        for collision_mesh in root.iter("mesh"):
            fn = collision_mesh.get("filename")
            if fn.startswith("package://"):
                collision_mesh.set("filename", str(self._resolve(fn)))
        ET.indent(tree)
        body = ET.tostring(root, encoding="unicode")
        return f'<?xml version="1.0"?>\n{self.stamp}\n{body}\n'

    def _fix_inertial(self, link: ET.Element, parent_joint: ET.Element | None, locked: set[str]) -> None:
        sim = self.config.sim
        inertial = link.find("inertial")
        mass_el = None if inertial is None else inertial.find("mass")
        if inertial is None or mass_el is None or float(mass_el.get("value", 0.0)) <= 0.0:
            if inertial is not None:
                link.remove(inertial)
            inertial = ET.Element("inertial")
            link.insert(0, inertial)
            ET.SubElement(inertial, "origin", {"xyz": "0 0 0", "rpy": "0 0 0"})
            ET.SubElement(inertial, "mass", {"value": f"{sim.tiny_mass:.9g}"})
            i = f"{sim.tiny_inertia:.9g}"
            ET.SubElement(inertial, "inertia", {"ixx": i, "ixy": "0", "ixz": "0", "iyy": i, "iyz": "0", "izz": i})
        if parent_joint is None or parent_joint.get("type") not in ("revolute", "continuous", "prismatic"):
            return
        a = sim.finger_armature if parent_joint.get("name") in locked else sim.armature
        if a <= 0:
            return
        inertia = inertial.find("inertia")
        for key in ("ixx", "iyy", "izz"):
            inertia.set(key, f"{float(inertia.get(key, 0.0)) + a:.9g}")


def _verify_in_pybullet_text(text: str, expected_mass: float, name: str, cache: pathlib.Path) -> None:
    """Load the generated URDF in a private DIRECT client; its total mass must match Pinocchio's."""
    import pybullet as p

    tmp = cache / f".{name}_verify.{os.getpid()}.{threading.get_ident()}.urdf"
    _atomic_write(tmp, text)
    client = p.connect(p.DIRECT)
    try:
        body = p.loadURDF(str(tmp), useFixedBase=False, physicsClientId=client)
        mass = sum(p.getDynamicsInfo(body, link, physicsClientId=client)[0]
                   for link in range(-1, p.getNumJoints(body, physicsClientId=client)))
    except p.error as exc:
        raise ClimbError(f"{name}: PyBullet cannot load the generated URDF: {exc}") from exc
    finally:
        p.disconnect(client)
        tmp.unlink(missing_ok=True)
    if abs(mass - expected_mass) > _MASS_TOLERANCE * expected_mass:
        raise ClimbError(f"{name}: PyBullet mass {mass:.3f} kg != Pinocchio mass {expected_mass:.3f} kg")


# --------------------------------------------------------------------------------------------
# Process-wide cache
# --------------------------------------------------------------------------------------------
_CACHE: dict[pathlib.Path, RobotModel] = {}
_CACHE_LOCK = threading.Lock()


def load_robot(name_or_path: str | os.PathLike = "g1") -> RobotModel:
    """The robot's model, built once per process (the same object is returned on every call)."""
    path = _resolve_config_path(name_or_path)
    with _CACHE_LOCK:
        robot = _CACHE.get(path)
        if robot is None:
            robot = RobotModel(load_robot_config(path))
            _CACHE[path] = robot
        return robot

