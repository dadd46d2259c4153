"""Scene specification: parse and validate the ``scene:`` block of specs/scene_spec.md.

A scene is a set of named static surfaces (boxes and cylinders) that the robot may touch or must
avoid, a start pose and a goal. :func:`parse_scene` is called by
:func:`climb_core.ladder.parse_scenario` for a scenario's ``scene:`` block (with the scenario's
ladder, if any, so that scene names cannot clash with the ladder's own surfaces); the surfaces
are built by :func:`climb_core.environment.build_environment` (role ``scene``).

Units and frames: metres, degrees, world frame z up; R = Rz(yaw) Ry(pitch) Rx(roll) of
``rpy_deg``; a box's ``size`` is its full extents along its local x, y, z; a cylinder's axis is
its local x.

| field                              | default           | unit | rule                               |
| ---------------------------------- | ----------------- | ---- | ---------------------------------- |
| scene.ground.friction              | ladder's ground_friction, else 0.8 | | (0, 2]                 |
| scene.surfaces                     | []                |      | list of mappings                   |
| scene.surfaces[i].name             | required          |      | [a-z0-9_]+, unique, not ``ground`` nor a ladder surface's name |
| scene.surfaces[i].shape            | required          |      | box, cylinder                      |
| scene.surfaces[i].size             | required          | m    | box: 3 numbers > 0; cylinder: {radius, length} > 0 |
| scene.surfaces[i].position         | required          | m    | 3 finite numbers, world frame      |
| scene.surfaces[i].rpy_deg          | [0, 0, 0]         | deg  | 3 finite numbers                   |
| scene.surfaces[i].friction         | 0.6               |      | (0, 2]                             |
| scene.surfaces[i].contact          | [] (obstacle)     |      | list of foot, hand (each once)     |
| scene.surfaces[i].bilateral        | false             |      | true needs hand in contact and a graspable size (see below) |
| scene.start.pose.x, .y, .yaw_deg   | 0, 0, 0           | m, m, deg | finite                        |
| scene.goal                         | none; required without a ladder: block |  | mapping           |
| scene.goal.base_position           | required with goal | m   | 3 finite numbers, world frame      |
| scene.goal.tolerance               | required with goal | m   | > 0                                |

Graspable (``bilateral: true``): a cylinder of diameter <= ``BILATERAL_MAX_WIDTH`` or a box
whose two smaller sizes are both <= ``BILATERAL_MAX_WIDTH``. The rules shared with the ladder
(numbers finite and bounded, unknown keys rejected at every level, the first violation reported
as ``SpecError(field, rule)`` with the dotted field path) are climb_core.ladder's.
"""
from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Any, Iterator, Mapping

from .errors import SpecError
from .ladder import (_REQUIRED, FRICTION, POSITIVE_M, Block, Custom, Enum, LadderSpec, ListOf, Num, Range, Vec3,
                     _parse_block, _parse_value, _type_name)

__all__ = ["SURFACE_SHAPES", "CONTACT_LIMBS", "BILATERAL_MAX_WIDTH", "DEFAULT_SURFACE_FRICTION",
           "DEFAULT_GROUND_FRICTION", "SurfaceSpec", "StartSpec", "GoalSpec", "SceneSpec", "parse_scene",
           "scene_to_dict", "ladder_surface_names", "SEARCH_STRATEGY", "require_search_strategy"]

SURFACE_SHAPES = ("box", "cylinder")
#: Limb types that may be placed on a surface.
CONTACT_LIMBS = ("foot", "hand")
#: [m] largest width a hand can close around (cylinder diameter, box's two smaller sizes).
BILATERAL_MAX_WIDTH = 0.08
#: Coulomb coefficient of a scene surface without ``friction``.
DEFAULT_SURFACE_FRICTION = 0.6
#: Coulomb coefficient of the ground when neither the scene nor a ladder gives one.
DEFAULT_GROUND_FRICTION = 0.8
_NAME_RE = re.compile(r"^[a-z0-9_]+$")


def _name(value: Any, path: str) -> str:
    if not isinstance(value, str) or not _NAME_RE.match(value):
        raise SpecError(path, f"must match [a-z0-9_]+, got {_type_name(value)} {value!r}"[:200])
    return value


def _flag(value: Any, path: str) -> bool:
    if not isinstance(value, bool):
        raise SpecError(path, f"must be true or false, got {_type_name(value)} {value!r}"[:200])
    return value


def _contact(value: Any, path: str) -> tuple[str, ...]:
    if not isinstance(value, (list, tuple)):
        raise SpecError(path, f"must be a list of limb types ({', '.join(CONTACT_LIMBS)}), got {_type_name(value)}")
    out: list[str] = []
    for i, limb in enumerate(value):
        if not isinstance(limb, str) or limb not in CONTACT_LIMBS:
            raise SpecError(f"{path}[{i}]", f"unknown limb type {limb!r}: must be one of "
                                            f"{', '.join(CONTACT_LIMBS)}"[:200])
        if limb in out:
            raise SpecError(f"{path}[{i}]", f"limb type {limb!r} given twice")
        out.append(limb)
    return tuple(out)


_CYLINDER_SIZE = Block({"radius": Num(_REQUIRED, POSITIVE_M), "length": Num(_REQUIRED, POSITIVE_M)})
_BOX_SIZE = Vec3(None, POSITIVE_M)

_SCENE_SCHEMA = Block({
    "ground": Block({"friction": Num(None, FRICTION)}, default=None),
    "surfaces": ListOf(Block({
        "name": Custom(_name, _REQUIRED),
        "shape": Enum(SURFACE_SHAPES, _REQUIRED),
        "size": Custom(lambda value, path: value, _REQUIRED),  # checked against the shape
        "position": Vec3(_REQUIRED, Range(unit="m")),
        "rpy_deg": Vec3((0.0, 0.0, 0.0), Range(unit="deg")),
        "friction": Num(DEFAULT_SURFACE_FRICTION, FRICTION),
        "contact": Custom(_contact, ()),
        "bilateral": Custom(_flag, False),
    })),
    "start": Block({
        "pose": Block({
            "x": Num(0.0, Range(unit="m")),
            "y": Num(0.0, Range(unit="m")),
            "yaw_deg": Num(0.0, Range(unit="deg")),
        }, default={}),
    }, default={}),
    "goal": Block({
        "base_position": Vec3(_REQUIRED, Range(unit="m")),
        "tolerance": Num(_REQUIRED, Range(0.0, None, lo_open=True, unit="m")),
    }, default=None),
})


# --------------------------------------------------------------------------------------------
# The typed result.
# --------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class SurfaceSpec:
    name: str
    shape: str  # box | cylinder
    position: tuple[float, float, float]  # [m] centre, world frame
    rpy_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)  # [deg] R = Rz(yaw) Ry(pitch) Rx(roll)
    size: tuple[float, float, float] | None = None  # [m] box: full extents along local x, y, z
    radius: float | None = None  # [m] cylinder
    length: float | None = None  # [m] cylinder, along local x
    friction: float = DEFAULT_SURFACE_FRICTION  # [-] Coulomb, with the robot
    contact: tuple[str, ...] = ()  # limb types that may be placed on it; () = obstacle only
    bilateral: bool = False  # a hand may close around it

    @property
    def half_extents(self) -> tuple[float, float, float]:
        """[m] half sizes along the local x, y, z (cylinder: length / 2, r, r)."""
        if self.shape == "cylinder":
            return 0.5 * self.length, self.radius, self.radius  # type: ignore[operator,return-value]
        return tuple(0.5 * v for v in self.size)  # type: ignore[union-attr,return-value]

    @property
    def grasp_width(self) -> float:
        """[m] what a closing hand spans: the diameter, or a box's second largest size."""
        if self.shape == "cylinder":
            return 2.0 * self.radius  # type: ignore[operator]
        return sorted(self.size)[1]  # type: ignore[arg-type]


@dataclass(frozen=True)
class StartSpec:
    x: float = 0.0  # [m] robot base, world frame, standing on the ground
    y: float = 0.0  # [m]
    yaw_deg: float = 0.0  # [deg] about world z


@dataclass(frozen=True)
class GoalSpec:
    base_position: tuple[float, float, float]  # [m] robot base frame origin, world frame
    tolerance: float  # [m] distance within which the goal counts as reached


@dataclass(frozen=True)
class SceneSpec:
    surfaces: tuple[SurfaceSpec, ...] = ()
    start: StartSpec = StartSpec()
    goal: GoalSpec | None = None
    ground_friction: float | None = None  # [-] None: not given (the ladder's, else DEFAULT_GROUND_FRICTION)

    def surface(self, name: str) -> SurfaceSpec:
        for s in self.surfaces:
            if s.name == name:
                return s
        raise SpecError("scene.surfaces", f"no surface named {name!r}")


# --------------------------------------------------------------------------------------------
# Parsing.
# --------------------------------------------------------------------------------------------

def ladder_surface_names(ladder: LadderSpec | None) -> tuple[str, ...]:
    """The names environment.build_environment gives a ladder's own surfaces (and ``ground``)."""
    names = ["ground"]
    if ladder is None:
        return tuple(names)
    names += [f"rung_{k}" for k in range(1, ladder.n_rungs + 1)]
    names += ["stringer_left", "stringer_right"] + [f"rail_{r.side}" for r in ladder.rails]
    if ladder.top_platform_depth is not None:
        names.append("platform")
    if ladder.type == "a_frame":
        names += ["stringer_back_left", "stringer_back_right"]
    names += [f"obstacle_{i}" for i in range(len(ladder.obstacles))]
    return tuple(names)


def _size(shape: str, value: Any, path: str) -> dict[str, Any]:
    """{"size": box extents} or {"radius", "length"} of a cylinder."""
    if shape == "cylinder":
        if not isinstance(value, Mapping):
            raise SpecError(path, f"a cylinder's size must be a mapping {{radius, length}} of numbers > 0, "
                                  f"got {_type_name(value)}")
        return _parse_block(_CYLINDER_SIZE, value, path)
    if not isinstance(value, (list, tuple)):
        raise SpecError(path, f"a box's size must be a list of 3 numbers > 0 (full extents along local x, y, z), "
                              f"got {_type_name(value)}")
    return {"size": _parse_value(_BOX_SIZE, value, path)}


def _surface_rules(surfaces: list[SurfaceSpec], reserved: tuple[str, ...]) -> Iterator[tuple[str, str]]:
    seen: set[str] = set()
    for i, s in enumerate(surfaces):
        path = f"scene.surfaces[{i}]"
        if s.name in reserved:
            what = "the ground plane" if s.name == "ground" else "a surface of the ladder: block"
            yield f"{path}.name", f"name {s.name!r} clashes with {what}"
        if s.name in seen:
            yield f"{path}.name", f"name {s.name!r} given twice"
        seen.add(s.name)
        if s.bilateral and "hand" not in s.contact:
            yield f"{path}.bilateral", "true needs 'hand' in contact (only a hand closes around a surface)"
        if s.bilateral and s.grasp_width > BILATERAL_MAX_WIDTH + 1e-12:
            what = "diameter" if s.shape == "cylinder" else "second largest size"
            yield (f"{path}.bilateral", f"true needs a surface a hand can close around: its {what} "
                                        f"{s.grasp_width:g} m is above {BILATERAL_MAX_WIDTH:g} m")


def parse_scene(data: Any, ladder: LadderSpec | None = None) -> SceneSpec:
    """Validate a ``scene:`` block (NaN / inf already rejected by the caller, see ladder.py) and
    return the frozen :class:`SceneSpec`; ``ladder`` is the scenario's ladder (names, goal rule)."""
    doc = _parse_block(_SCENE_SCHEMA, data, "scene")
    surfaces = []
    for i, s in enumerate(doc["surfaces"]):
        size = _size(s["shape"], s["size"], f"scene.surfaces[{i}].size")
        surfaces.append(SurfaceSpec(name=s["name"], shape=s["shape"], position=s["position"], rpy_deg=s["rpy_deg"],
                                    friction=s["friction"], contact=s["contact"], bilateral=s["bilateral"], **size))
    for path, rule in _surface_rules(surfaces, ladder_surface_names(ladder)):
        raise SpecError(path, rule)
    if doc["goal"] is None and ladder is None:
        raise SpecError("scene.goal", "required field is missing: a scene without a ladder: block needs a goal")
    pose = doc["start"]["pose"]
    goal = None if doc["goal"] is None else GoalSpec(doc["goal"]["base_position"], doc["goal"]["tolerance"])
    return SceneSpec(surfaces=tuple(surfaces), start=StartSpec(pose["x"], pose["y"], pose["yaw_deg"]), goal=goal,
                     ground_friction=None if doc["ground"] is None else doc["ground"]["friction"])


def scene_to_dict(scene: SceneSpec) -> dict[str, Any]:
    """The ``scene:`` block with every field explicit; ``parse_scene`` of it gives ``scene`` back."""
    surfaces = []
    for s in scene.surfaces:
        size: Any = (list(s.size) if s.shape == "box"  # type: ignore[arg-type]
                     else {"radius": s.radius, "length": s.length})
        surfaces.append({"name": s.name, "shape": s.shape, "size": size, "position": list(s.position),
                         "rpy_deg": list(s.rpy_deg), "friction": s.friction, "contact": list(s.contact),
                         "bilateral": s.bilateral})
    out: dict[str, Any] = {}
    if scene.ground_friction is not None:
        out["ground"] = {"friction": scene.ground_friction}
    out["surfaces"] = surfaces
    out["start"] = {"pose": {"x": scene.start.x, "y": scene.start.y, "yaw_deg": scene.start.yaw_deg}}
    if scene.goal is not None:
        out["goal"] = {"base_position": list(scene.goal.base_position), "tolerance": scene.goal.tolerance}
    return out


#: The planning strategy that plans scenes without a ladder (guide path + contact search).
SEARCH_STRATEGY = "search"


def require_search_strategy(scenario: Any, strategy: str) -> None:
    """SpecError('strategy', ...) when a scenario without a ladder is to be planned by a strategy
    other than ``search`` (the primitive libraries only climb ladders)."""
    if getattr(scenario, "ladder", None) is None and strategy != SEARCH_STRATEGY:
        raise SpecError("strategy", f"strategy {SEARCH_STRATEGY!r} needed for a scene without a ladder "
                                    f"(scenario {getattr(scenario, 'name', '')!r}, strategy {strategy!r})")
