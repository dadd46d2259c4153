"""Robot configurations: one YAML file per robot (config/robots/<name>.yaml) -> frozen dataclasses,
validated against the robot's URDF (ElementTree only: no Pinocchio, so validation stays cheap).

Units are SI (m, rad, kg, N, N m, V, ohm, A, s); frames are URDF link frames. Contact surfaces are
data attached to a limb frame: ``ContactSurface.T_frame_surface`` is the surface frame in the limb
frame (origin at the sole polygon centre / the grasp cylinder centre; z the contact normal pointing
out of the robot; for a grasp, x is the cylinder axis). Sole vertices are the 4 corners in the limb
frame, counter-clockwise seen from the foot's +z, in one plane z = const. Every error is a
:class:`SpecError` naming the dotted field and the rule. :mod:`climb_core.robot` builds the
Pinocchio model from a :class:`RobotConfig`.
"""
from __future__ import annotations

import fnmatch
import importlib.metadata
import math
import os
import pathlib
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from typing import Any

import numpy as np
import yaml

from climb_core.contact import FEET, HANDS, LIMBS
from climb_core.errors import SpecError
from climb_core.ros_env import project_root

__all__ = [
    "ROBOTS_DIR", "robots_dir", "share_dir", "robots_config_dir", "available_robots",
    "ContactSurface", "Limb", "PwmGains", "MotorSpec", "MotorParams", "CollisionConfig",
    "FootBox", "SimFixes", "RobotConfig", "load_robot_config", "parse_robot_config", "resolve_config_path",
    "foot_box_geometry",
]

_SURFACE_KINDS = ("sole", "palm", "grasp")
_MOTOR_FIELDS = ("supply_voltage", "resistance", "torque_constant", "gear_ratio", "current_limit",
                 "trip_hold_off_s")
_REQUIRED_SOURCES = ("urdf", "locked_joints", "reference_posture", "base_height", "grip_strength",
                     "capture_range", "limbs", "ft_sensors", "ft_ranges", "pwm", "motor", "collision", "sim")


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
    # grasp only: the largest rectangular bar the closed hand goes around [m], (depth along the
    # contact normal, i.e. away from the palm; width along the palm across the finger axes); None
    # = the hand closes around cylinders only (config ``max_bar: {depth, width}``)
    max_bar: tuple[float, float] | None = None

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
    surface: ContactSurface  # the primary surface (a foot's sole, a hand's grasp)
    ft_sensor: str  # key of RobotConfig.ft_sensors
    joints: tuple[str, ...]  # whole-body joints from the root to the end effector
    extra_surfaces: tuple[ContactSurface, ...] = ()  # more surfaces on the same frame (a hand's palm)

    @property
    def surfaces(self) -> dict[str, ContactSurface]:
        """Every contact surface of the limb by name, the primary first."""
        return {s.name: s for s in (self.surface,) + self.extra_surfaces}

    def surface_of_kind(self, kind: str) -> ContactSurface | None:
        """The limb's surface of ``kind`` (sole | palm | grasp), or None (one per kind)."""
        return next((s for s in self.surfaces.values() if s.kind == kind), None)


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
    ft_ranges: dict[str, tuple[float, float]]  # sensor name -> (force [N], torque [N m]) measuring range
    locked_joints: tuple[str, ...]
    #: locked joint -> its position [rad] in the whole-body model and the bridge's open hand
    #: (every locked joint listed; the config's ``locked_posture``, 0 clipped to the limits otherwise)
    locked_posture: dict[str, float]
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
_TOP_KEYS = ("name", "description", "urdf", "package_dirs", "locked_joints", "locked_posture", "reference_posture",
             "base_height", "grip_strength", "capture_range", "limbs", "ft_sensors", "ft_ranges", "pwm",
             "motor", "collision", "sim", "sources")


def resolve_config_path(name_or_path: str | os.PathLike) -> pathlib.Path:
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
    path = resolve_config_path(name_or_path)
    try:
        data = yaml.load(path.read_text(), Loader=getattr(yaml, "CSafeLoader", yaml.SafeLoader))
    except yaml.YAMLError as exc:
        raise SpecError("robot", f"{path} is not valid YAML: {exc}") from exc
    return parse_robot_config(data, config_path=path)


def parse_robot_config(data: Any, config_path: pathlib.Path | None = None) -> RobotConfig:
    """Validate a robot config mapping (the YAML's content); raises SpecError(field, rule)."""
    _mapping(data, "", _TOP_KEYS, required=tuple(k for k in _TOP_KEYS
                                                  if k not in ("description", "package_dirs", "locked_posture")))
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
    lock_raw = _mapping(data.get("locked_posture") or {}, "locked_posture", tuple(locked))
    locked_posture: dict[str, float] = {}
    for j in locked:
        uj = tree.joints[j]
        if j in lock_raw:
            value = _number(lock_raw[j], f"locked_posture.{j}")
            if not (uj.lower - 1e-9 <= value <= uj.upper + 1e-9):
                raise SpecError(f"locked_posture.{j}", f"{value} rad is outside the URDF limits [{uj.lower}, {uj.upper}]")
        else:
            value = min(max(0.0, uj.lower), uj.upper)
        locked_posture[j] = value

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
    # measuring range of each sensor (force [N], torque [N m]): sensor noise is given in % of it
    ranges_raw = _mapping(data["ft_ranges"], "ft_ranges", tuple(ft_sensors), required=tuple(ft_sensors))
    ft_ranges: dict[str, tuple[float, float]] = {}
    for sensor, raw in ranges_raw.items():
        where = f"ft_ranges.{sensor}"
        raw = _mapping(raw, where, ("force", "torque"), required=("force", "torque"))
        ft_ranges[sensor] = (_number(raw["force"], f"{where}.force", positive=True),
                             _number(raw["torque"], f"{where}.torque", positive=True))

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
    for key in _REQUIRED_SOURCES + (("locked_posture",) if data.get("locked_posture") else ()):
        if key not in src:
            raise SpecError(f"sources.{key}", "missing: say where this number comes from")
    sources = {str(k): _string(v, f"sources.{k}") for k, v in src.items()}

    description = data.get("description") or ""
    if not isinstance(description, str):
        raise SpecError("description", "must be a string")

    return RobotConfig(
        name=name, urdf_path=urdf_path, package_dirs=tuple(package_dirs), limbs=limbs,
        ft_sensors=ft_sensors, ft_ranges=ft_ranges, locked_joints=tuple(locked),
        locked_posture=locked_posture, reference_posture=posture,
        base_height=base_height, grip_strength=grip_strength, capture_range=capture_range,
        pwm=pwm, motor=motor, collision=CollisionConfig(tuple(pairs), env_links), sim=sim,
        sources=sources, config_path=config_path, description=description)


def _parse_limb(limb: str, raw: Any, tree: _UrdfTree, ft_sensors: dict[str, str],
                whole_body: tuple[str, ...]) -> Limb:
    path = f"limbs.{limb}"
    raw = _mapping(raw, path, ("frame", "ft_sensor", "surface", "extra_surfaces"),
                   required=("frame", "ft_sensor", "surface"))
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
    primary = _parse_surface(limb, raw["surface"], f"{path}.surface", frame)
    extras_raw = raw.get("extra_surfaces") or []
    if not isinstance(extras_raw, list):
        raise SpecError(f"{path}.extra_surfaces", "must be a list of surfaces")
    extras: list[ContactSurface] = []
    for i, e in enumerate(extras_raw):
        e_path = f"{path}.extra_surfaces[{i}]"
        surface = _parse_surface(limb, e, e_path, frame)
        for other in [primary] + extras:
            if other.name == surface.name:
                raise SpecError(f"{e_path}.name", f"{surface.name!r} is already a surface of {limb}")
            if other.kind == surface.kind:
                raise SpecError(f"{e_path}.kind", f"{limb} already has a {surface.kind} ({other.name!r}): "
                                                  "one surface per kind and limb")
        extras.append(surface)
    return Limb(limb, primary, sensor, joints, tuple(extras))


def _parse_surface(limb: str, raw: Any, s_path: str, frame: str) -> ContactSurface:
    """One contact surface of ``limb`` (attached to the limb's frame) from its YAML mapping."""
    s = _mapping(raw, s_path)
    kind = _string(s.get("kind"), f"{s_path}.kind")
    if kind not in _SURFACE_KINDS:
        raise SpecError(f"{s_path}.kind", f"must be one of {', '.join(_SURFACE_KINDS)}")
    if limb in FEET and kind != "sole":
        raise SpecError(f"{s_path}.kind", "a foot's surface must be a sole")
    if limb in HANDS and kind == "sole":
        raise SpecError(f"{s_path}.kind", "a hand's surface must be a grasp or a palm")
    name = _string(s.get("name"), f"{s_path}.name")
    if kind == "sole":
        _mapping(s, s_path, ("name", "kind", "vertices"), required=("vertices",))
        v = _quad(s["vertices"], f"{s_path}.vertices")
        if np.ptp(v[:, 2]) > 1e-9:
            raise SpecError(f"{s_path}.vertices", "corners must share one z (a plane z = const of the frame)")
        _check_convex(v, np.array([0.0, 0.0, 1.0]), f"{s_path}.vertices", "counter-clockwise from +z")
        T = np.eye(4)
        T[:3, :3] = np.diag([1.0, -1.0, -1.0])  # z out of the sole (down), x forward
        T[:3, 3] = v.mean(axis=0)
        return ContactSurface(name, frame, kind, _frozen_array(v), 0.0, 0.0, _frozen_array(np.zeros(3)),
                              _frozen_array(T))
    if kind == "palm":
        return _parse_palm(s, s_path, name, frame)

    _mapping(s, s_path, ("name", "kind", "centre", "axis", "normal", "radius", "length", "max_bar"),
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
    max_bar = None
    if s.get("max_bar") is not None:
        mb = _mapping(s["max_bar"], f"{s_path}.max_bar", ("depth", "width"), required=("depth", "width"))
        max_bar = (_number(mb["depth"], f"{s_path}.max_bar.depth", positive=True),
                   _number(mb["width"], f"{s_path}.max_bar.width", positive=True))
        if max_bar[0] < 2.0 * radius or max_bar[1] < 2.0 * radius:
            raise SpecError(f"{s_path}.max_bar", f"must be at least the grasp cylinder's diameter "
                                                 f"({2.0 * radius} m): a hand around that cylinder goes around "
                                                 "a bar as deep and wide")
    return ContactSurface(name, frame, kind, _frozen_array(np.zeros((0, 3))), radius, length,
                          _frozen_array(axis), _frozen_array(T), max_bar)


def _parse_palm(s: dict, s_path: str, name: str, frame: str) -> ContactSurface:
    """A palm: 4 coplanar corners and the normal out of the palm (unilateral, like a sole). The
    surface frame: origin at the corners' centroid, z = normal, x along the first edge."""
    _mapping(s, s_path, ("name", "kind", "vertices", "normal"), required=("vertices", "normal"))
    v = _quad(s["vertices"], f"{s_path}.vertices")
    normal = _unit(s["normal"], f"{s_path}.normal")
    centre = v.mean(axis=0)
    if np.max(np.abs((v - centre) @ normal)) > 1e-6:
        raise SpecError(f"{s_path}.vertices", "corners must lie in one plane perpendicular to the normal")
    _check_convex(v, normal, f"{s_path}.vertices", "counter-clockwise seen from the normal's side")
    x = (v[1] - v[0]) - normal * float((v[1] - v[0]) @ normal)
    x /= np.linalg.norm(x)
    T = np.eye(4)
    T[:3, 0], T[:3, 1], T[:3, 2] = x, np.cross(normal, x), normal
    T[:3, 3] = centre
    return ContactSurface(name, frame, "palm", _frozen_array(v), 0.0, 0.0, _frozen_array(np.zeros(3)),
                          _frozen_array(T))


def _quad(value: Any, path: str) -> np.ndarray:
    if not isinstance(value, list) or len(value) != 4:
        raise SpecError(path, "must be a list of 4 corners [x, y, z]")
    return np.array([_vector(c, f"{path}[{i}]") for i, c in enumerate(value)])


def _check_convex(v: np.ndarray, normal: np.ndarray, path: str, orientation: str) -> None:
    """The corners ``v`` (4, 3) form a convex polygon, counter-clockwise about ``normal``."""
    turns = [float(np.cross(v[(i + 1) % 4] - v[i], v[(i + 2) % 4] - v[(i + 1) % 4]) @ normal) for i in range(4)]
    if min(turns) <= 0:
        raise SpecError(path, f"corners must form a convex polygon, {orientation}")


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



def foot_box_geometry(config: RobotConfig, limb: str) -> tuple[np.ndarray, np.ndarray]:
    """(size (3,), centre (3,)) of the foot box in the limb frame [m]."""
    assert config.sim.foot_box is not None
    v = config.limbs[limb].surface.vertices
    lo, hi = v.min(axis=0), v.max(axis=0)
    t = config.sim.foot_box.thickness
    size = np.array([hi[0] - lo[0], hi[1] - lo[1], t])
    centre = np.array([(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, lo[2] + t / 2])
    return size, centre

