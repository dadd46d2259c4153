"""Ladder / scenario specification: parse and validate the YAML format of specs/ladder_spec.md.

A *scenario* is one YAML document (or an equivalent dict) with a ``ladder:`` block (the
nominal ladder the planner sees), a ``scene:`` block (surfaces, start and goal beyond a ladder:
specs/scene_spec.md, parsed by :mod:`climb_core.scene`) or both, an optional ``perturbation:``
block (what the simulator changes at execution time) and two optional project fields, ``name``
and ``description``. :func:`load_scenario` accepts a name in ``config/ladders/`` or
``config/scenes/``, a file path, YAML text or a dict and returns a frozen :class:`Scenario`; the
geometry is built from it by :func:`climb_core.environment.build_environment`.

Frames and units (SI; angles in degrees in the spec, as written by people): world z up; the
*ladder base frame* sits on the ground (z = 0) at the middle of the first rung's projection,
x from the robot toward the ladder, y to the robot's left. ``pose`` places that frame in the
world (``x``, ``y`` [m], ``yaw_deg`` about world z); the robot starts at the world origin.
``obstacles`` are given in the world frame. ``perturbation.rung_offsets`` (``dx``, ``dz``) and
``rails_dy`` are in the ladder base frame. See environment.py for the surfaces built from this.

Defaults (a missing field, or a field set to ``null``, takes this value; a block that is absent
takes the defaults of its fields, except where noted). Fields marked (+) are project additions,
allowed by the spec ("the project may add fields").

| field                                  | default                   | unit | rule                       |
| -------------------------------------- | ------------------------- | ---- | -------------------------- |
| name (+), description (+)              | "" (name: see load)       |      | string                     |
| planner_overrides (+)                  | {} (none)                 |      | mapping GROUP.FIELD -> number, bool or string: planner settings this scenario plans with (names and values checked by planner_node.settings) |
| ladder                                 | none; a ladder or a scene is required |  | mapping           |
| scene                                  | none (scene.py has its own table) |  | mapping                |
| ladder.type                            | regular                   |      | regular, vertical, a_frame, ship, stairs |
| ladder.inclination_deg                 | by type: regular 75, a_frame 75, ship 60, stairs 35, vertical 90 | deg | ladders (45, 90], stairs [20, 50], vertical = 90 |
| ladder.rung_spacing                    | 0.25                      | m    | [0.15, 0.50], along the stringer |
| ladder.n_rungs                         | 8                         |      | integer in [2, 1000]       |
| ladder.first_rung_height               | 0.25                      | m    | > 0                        |
| ladder.rung_width                      | 0.50                      | m    | > 0, clear width between the stringers |
| ladder.rung (block absent)             | {shape: circle, diameter: 0.04} |  |                            |
| ladder.rung.shape                      | circle                    |      | circle, rect               |
| ladder.rung.diameter                   | none                      | m    | > 0; required for circle   |
| ladder.rung.depth                      | none                      | m    | > 0; required for rect     |
| ladder.rung.thickness                  | 0.04                      | m    | > 0 (rect)                 |
| ladder.stringer.width                  | 0.08                      | m    | > 0, lateral (y) size      |
| ladder.stringer.depth                  | 0.03                      | m    | > 0, size normal to the ladder plane |
| ladder.stringer.top_extension (+)      | 0.10                      | m    | >= 0, beyond the top rung along the stringer |
| ladder.rails                           | [] (none)                 |      | list of mappings, each side at most once |
| ladder.rails[i].side                   | required                  |      | left, right                |
| ladder.rails[i].height                 | 1.00                      | m    | > 0, vertically above the tread nose line |
| ladder.rails[i].diameter               | 0.04                      | m    | > 0                        |
| ladder.top_platform (block absent)     | none (no platform)        |      | mapping                    |
| ladder.top_platform.depth              | 1.0                       | m    | > 0, along +x beyond the top rung |
| ladder.top_platform.width (+)          | rung_width + 2 stringer.width | m | > 0                      |
| ladder.top_platform.thickness (+)      | 0.05                      | m    | > 0                        |
| ladder.a_frame.back_inclination_deg    | 75.0 (used by a_frame only) | deg | (45, 90]                  |
| ladder.friction                        | 0.25                      |      | (0, 2], every ladder surface |
| ladder.ground_friction (+)             | 0.8                       |      | (0, 2], the ground         |
| ladder.pose.x, .y, .yaw_deg            | 0.45, 0.0, 0.0            | m, m, deg | finite                |
| ladder.obstacles                       | []                        |      | list of mappings           |
| ladder.obstacles[i].size               | required                  | m    | 3 numbers > 0 (full sizes) |
| ladder.obstacles[i].position           | required                  | m    | 3 numbers, world frame     |
| ladder.obstacles[i].rpy_deg            | [0, 0, 0]                 | deg  | 3 numbers; R = Rz(yaw) Ry(pitch) Rx(roll) |
| perturbation                           | none                      |      | mapping                    |
| perturbation.rung_offsets              | []                        |      | list of mappings, each rung at most once |
| perturbation.rung_offsets[i].rung      | required                  |      | integer in [1, n_rungs]    |
| perturbation.rung_offsets[i].dx, .dz   | 0.0, 0.0                  | m    | finite, ladder base frame  |
| perturbation.rails_dy                  | 0.0                       | m    | finite, ladder base frame y |
| perturbation.drops[i].mass             | 10.0                      | kg   | > 0                        |
| perturbation.drops[i].radius           | 0.12                      | m    | > 0                        |
| perturbation.drops[i].speed            | 5.5                       | m/s  | > 0                        |
| perturbation.drops[i].at_time          | 0.0                       | s    | >= 0, simulated time       |
| perturbation.drops[i].target_link      | torso                     |      | non-empty string           |
| perturbation.drops[i].direction        | the bridge's (down)       |      | 3 numbers, not all zero: world direction of flight (extension) |
| perturbation.drops[i].at_transition    | 0                         |      | integer >= 0; > 0: thrown at_time after the climb's transition N (1-based) starts, 0: at at_time (extension) |

Rules applied everywhere: every number must be a real number (not a string, not a boolean), finite
and with magnitude at most ``MAX_ABS_VALUE`` (a sanity bound that also catches ``1e308``-style
garbage); a mapping is expected where the table shows a block and a list where it shows a list;
unknown keys are rejected at every level (typos must not pass silently). Closed range bounds
accept a rounding slack of ``RANGE_TOLERANCE`` so that values computed in sweeps
(``0.2 + 15 * 0.01``) stay valid. Shape-specific fields of the other shape (``depth`` on a
circle rung, the ``a_frame`` block on another type) are validated and then ignored, so the
spec's own example, which lists them all, is accepted.

Every error is a :class:`climb_core.errors.SpecError` whose ``field`` is the dotted path of the
offending field (``ladder.rung.diameter``, ``ladder.rails[1].side``; ``document`` for YAML
syntax errors and non-mapping documents, ``source`` for a name or file that cannot be found) and
whose ``rule`` says which rule it broke. The first violation found is reported.
"""
from __future__ import annotations

import dataclasses
import difflib
import math
import numbers
import pathlib
import re
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Callable, Iterator, Mapping

from .errors import SpecError

if TYPE_CHECKING:  # scene.py imports this module's schema types
    from .scene import SceneSpec

__all__ = [
    "LADDER_TYPES", "STAIR_TYPES", "RUNG_SHAPES", "RAIL_SIDES", "DEFAULTS", "MAX_RUNGS",
    "MAX_ABS_VALUE", "RANGE_TOLERANCE", "INCLINATION_DEFAULT_DEG",
    "RungSpec", "RailSpec", "ObstacleSpec", "LadderSpec", "RungOffset", "DropSpec",
    "PerturbationSpec", "Scenario", "load_scenario", "parse_scenario", "parse_yaml",
    "ladder_config_dir", "scene_config_dir", "available_ladders", "available_scenes", "scenario_to_dict",
]

LADDER_TYPES = ("regular", "vertical", "a_frame", "ship", "stairs")
STAIR_TYPES = ("stairs",)
RUNG_SHAPES = ("circle", "rect")
RAIL_SIDES = ("left", "right")

#: Inclination used when ``inclination_deg`` is missing [deg], per ladder type.
INCLINATION_DEFAULT_DEG = {"regular": 75.0, "a_frame": 75.0, "ship": 60.0, "stairs": 35.0,
                           "vertical": 90.0}
#: Largest accepted number of rungs (memory / build time bound).
MAX_RUNGS = 1000
#: Largest accepted magnitude of any number in a spec [m, deg, kg, s, ...].
MAX_ABS_VALUE = 1.0e4
#: Slack on closed range bounds (rounding in computed sweeps).
RANGE_TOLERANCE = 1.0e-9
#: The rung used when the ``rung:`` block is absent.
DEFAULT_RUNG = {"shape": "circle", "diameter": 0.04}


# --------------------------------------------------------------------------------------------
# The schema: a small declarative table of field types, defaults and rules.
# --------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class Range:
    """An interval rule; ``None`` bounds are unbounded, ``*_open`` excludes the bound."""

    lo: float | None = None
    hi: float | None = None
    lo_open: bool = False
    hi_open: bool = False
    unit: str = ""

    def contains(self, v: float) -> bool:
        if self.lo is not None:
            if self.lo_open and not v > self.lo:
                return False
            if not self.lo_open and v < self.lo - RANGE_TOLERANCE:
                return False
        if self.hi is not None:
            if self.hi_open and not v < self.hi:
                return False
            if not self.hi_open and v > self.hi + RANGE_TOLERANCE:
                return False
        return True

    def describe(self) -> str:
        unit = f" {self.unit}" if self.unit else ""
        if self.lo is not None and self.hi is not None:
            return (f"must be in {'(' if self.lo_open else '['}{self.lo:g}, {self.hi:g}"
                    f"{')' if self.hi_open else ']'}{unit}")
        if self.lo is not None:
            return f"must be {'>' if self.lo_open else '>='} {self.lo:g}{unit}"
        if self.hi is not None:
            return f"must be {'<' if self.hi_open else '<='} {self.hi:g}{unit}"
        return "any finite number"


ANY = Range()
POSITIVE_M = Range(0.0, None, lo_open=True, unit="m")
NON_NEGATIVE_M = Range(0.0, None, unit="m")
FRICTION = Range(0.0, 2.0, lo_open=True)
LADDER_INCLINATION = Range(45.0, 90.0, lo_open=True, unit="deg")
STAIRS_INCLINATION = Range(20.0, 50.0, unit="deg")

_REQUIRED = object()  # marker: the field has no default and must be given


@dataclass(frozen=True)
class Num:
    default: Any = None
    range: Range = ANY
    integer: bool = False


@dataclass(frozen=True)
class Enum:
    choices: tuple[str, ...]
    default: Any = None


@dataclass(frozen=True)
class Text:
    default: Any = ""
    non_empty: bool = False


@dataclass(frozen=True)
class Vec3:
    default: Any = None
    range: Range = ANY


@dataclass(frozen=True)
class Block:
    fields: Mapping[str, Any]
    default: Any = None  # value parsed when absent: None (block stays None), a dict, or _REQUIRED


@dataclass(frozen=True)
class ListOf:
    item: Block


@dataclass(frozen=True)
class Custom:
    """A field validated by ``parse(value, path)`` (value not None); raises SpecError."""

    parse: Callable[[Any, str], Any]
    default: Any = None


SCHEMA = Block({
    "name": Text(""),
    "description": Text(""),
    "ladder": Block({
        "type": Enum(LADDER_TYPES, "regular"),
        "inclination_deg": Num(None),  # default and range depend on the type (_CROSS_RULES)
        "rung_spacing": Num(0.25, Range(0.15, 0.50, unit="m")),
        "n_rungs": Num(8, Range(2, MAX_RUNGS), integer=True),
        "first_rung_height": Num(0.25, POSITIVE_M),
        "rung_width": Num(0.50, POSITIVE_M),
        "rung": Block({
            "shape": Enum(RUNG_SHAPES, "circle"),
            "diameter": Num(None, POSITIVE_M),
            "depth": Num(None, POSITIVE_M),
            "thickness": Num(0.04, POSITIVE_M),
        }, default=DEFAULT_RUNG),
        "stringer": Block({
            "width": Num(0.08, POSITIVE_M),
            "depth": Num(0.03, POSITIVE_M),
            "top_extension": Num(0.10, NON_NEGATIVE_M),
        }, default={}),
        "rails": ListOf(Block({
            "side": Enum(RAIL_SIDES, _REQUIRED),
            "height": Num(1.00, POSITIVE_M),
            "diameter": Num(0.04, POSITIVE_M),
        })),
        "top_platform": Block({
            "depth": Num(1.0, POSITIVE_M),
            "width": Num(None, POSITIVE_M),
            "thickness": Num(0.05, POSITIVE_M),
        }, default=None),
        "a_frame": Block({
            "back_inclination_deg": Num(75.0, LADDER_INCLINATION),
        }, default={}),
        "friction": Num(0.25, FRICTION),
        "ground_friction": Num(0.8, FRICTION),
        "pose": Block({
            "x": Num(0.45, Range(unit="m")),
            "y": Num(0.0, Range(unit="m")),
            "yaw_deg": Num(0.0, Range(unit="deg")),
        }, default={}),
        "obstacles": ListOf(Block({
            "size": Vec3(_REQUIRED, POSITIVE_M),
            "position": Vec3(_REQUIRED),
            "rpy_deg": Vec3((0.0, 0.0, 0.0)),
        })),
    }, default=None),  # a scenario needs a ladder or a scene (parse_scenario)
    "scene": Custom(lambda value, path: value, default=None),  # validated by scene.parse_scene
    "planner_overrides": Custom(lambda value, path: _planner_overrides(value, path), default=()),
    "perturbation": Block({
        "rung_offsets": ListOf(Block({
            "rung": Num(_REQUIRED, Range(1, None), integer=True),
            "dx": Num(0.0, Range(unit="m")),
            "dz": Num(0.0, Range(unit="m")),
        })),
        "rails_dy": Num(0.0, Range(unit="m")),
        "drops": ListOf(Block({
            "mass": Num(10.0, Range(0.0, None, lo_open=True, unit="kg")),
            "radius": Num(0.12, POSITIVE_M),
            "speed": Num(5.5, Range(0.0, None, lo_open=True, unit="m/s")),
            "at_time": Num(0.0, Range(0.0, None, unit="s")),
            "target_link": Text("torso", non_empty=True),
            "direction": Vec3(None),
            "at_transition": Num(0, Range(0, None), integer=True),
        })),
    }, default={}),
})


def _flat_defaults(block: Block, prefix: str = "") -> dict[str, Any]:
    out: dict[str, Any] = {}
    for key, spec in block.fields.items():
        path = f"{prefix}{key}"
        if isinstance(spec, Block):
            out.update(_flat_defaults(spec, path + "."))
        elif isinstance(spec, ListOf):
            out[path] = []
            out.update(_flat_defaults(spec.item, path + "[i]."))
        else:
            out[path] = "required" if spec.default is _REQUIRED else spec.default
    return out


#: Flat view of the schema: dotted field path -> default ("required", or None = absent).
DEFAULTS: dict[str, Any] = _flat_defaults(SCHEMA)


def _type_name(value: Any) -> str:
    if value is None:
        return "null"
    return {dict: "mapping", list: "list", str: "string", bool: "boolean"}.get(type(value),
                                                                               type(value).__name__)


def _is_number(value: Any) -> bool:
    return isinstance(value, numbers.Real) and not isinstance(value, bool)


def _check_number(value: Any, spec: Num | Vec3, path: str) -> float | int:
    if not _is_number(value):
        raise SpecError(path, f"must be a number, got {_type_name(value)} {value!r}"[:200])
    if isinstance(value, numbers.Integral):
        number: float | int = int(value)
        if abs(number) > MAX_ABS_VALUE:
            raise SpecError(path, f"must be finite with magnitude <= {MAX_ABS_VALUE:g}, got {number}"[:200])
    else:
        number = float(value)
        if not math.isfinite(number) or abs(number) > MAX_ABS_VALUE:
            raise SpecError(path, f"must be finite with magnitude <= {MAX_ABS_VALUE:g}, got {number!r}")
    if isinstance(spec, Num) and spec.integer:
        if isinstance(number, float):
            if not number.is_integer():
                raise SpecError(path, f"must be an integer, got {number!r}")
            number = int(number)
    elif isinstance(number, int):
        number = float(number)
    if not spec.range.contains(number):
        raise SpecError(path, f"{spec.range.describe()}, got {number!r}")
    return number


def _parse_value(spec: Any, value: Any, path: str) -> Any:
    """Validate ``value`` against ``spec`` (value is not None) and return the clean value."""
    if isinstance(spec, Num):
        return _check_number(value, spec, path)
    if isinstance(spec, Enum):
        if not isinstance(value, str) or value not in spec.choices:
            raise SpecError(path, f"unknown value {value!r}: must be one of {', '.join(spec.choices)}"[:300])
        return value
    if isinstance(spec, Text):
        if not isinstance(value, str):
            raise SpecError(path, f"must be a string, got {_type_name(value)}")
        if spec.non_empty and not value.strip():
            raise SpecError(path, "must be a non-empty string")
        return value
    if isinstance(spec, Vec3):
        if hasattr(value, "tolist") and not isinstance(value, (str, bytes)):  # numpy array
            value = value.tolist()
        if not isinstance(value, (list, tuple)) or len(value) != 3:
            raise SpecError(path, f"must be a list of 3 numbers, got {_type_name(value)}"
                            + (f" of length {len(value)}" if isinstance(value, (list, tuple)) else ""))
        return tuple(float(_check_number(v, spec, f"{path}[{i}]")) for i, v in enumerate(value))
    if isinstance(spec, Block):
        return _parse_block(spec, value, path)
    if isinstance(spec, ListOf):
        if not isinstance(value, (list, tuple)):
            raise SpecError(path, f"must be a list of mappings, got {_type_name(value)}")
        return [_parse_block(spec.item, item, f"{path}[{i}]") for i, item in enumerate(value)]
    if isinstance(spec, Custom):
        return spec.parse(value, path)
    raise TypeError(f"bad schema entry at {path}: {spec!r}")  # pragma: no cover - programming error


def _key_path(path: str, key: Any) -> str:
    """Dotted path of ``key`` under ``path``; odd keys (empty, not a string) are shown as repr."""
    name = key if isinstance(key, str) and key.strip() and key == key.strip() else repr(key)
    return f"{path}.{name}" if path else name


def _parse_block(block: Block, value: Any, path: str) -> dict[str, Any]:
    if not isinstance(value, Mapping):
        raise SpecError(path or "document", f"must be a mapping, got {_type_name(value)}")
    prefix = f"{path}." if path else ""
    for key in value:
        if not isinstance(key, str) or key not in block.fields:
            close = difflib.get_close_matches(str(key), list(block.fields), n=1)
            hint = f"did you mean {close[0]!r}? " if close else ""
            known = ", ".join(block.fields)
            raise SpecError(_key_path(path, key)[:200], f"unknown key ({hint}known keys here: {known})"[:400])
    out: dict[str, Any] = {}
    for key, spec in block.fields.items():
        field_path = f"{prefix}{key}"
        given = value.get(key)
        if given is not None:
            out[key] = _parse_value(spec, given, field_path)
            continue
        # absent or null: the default
        default = [] if isinstance(spec, ListOf) else spec.default
        if default is _REQUIRED:
            raise SpecError(field_path, "required field is missing")
        if isinstance(spec, Block) and default is not None:
            default = _parse_block(spec, default, field_path)
        out[key] = default
    return out


def _reject_non_finite(document: Any) -> None:
    """The 'NaN or infinite numbers anywhere' rule, over the raw document (cycle-safe)."""
    stack: list[tuple[Any, str]] = [(document, "")]
    seen: set[int] = set()
    while stack:
        value, path = stack.pop()
        if isinstance(value, float) and not math.isfinite(value):
            raise SpecError(path or "document", f"must be a finite number, got {value!r}")
        if isinstance(value, (dict, list, tuple)):
            if id(value) in seen:
                continue
            seen.add(id(value))
            if isinstance(value, dict):
                for key, item in value.items():
                    stack.append((item, _key_path(path, key)[:200]))
            else:
                for i, item in enumerate(value):
                    stack.append((item, f"{path}[{i}]"))


# --------------------------------------------------------------------------------------------
# Cross-field rules: (field, applies(doc), holds(doc), rule). ``doc`` is the parsed document.
# --------------------------------------------------------------------------------------------

def _incl(doc: dict) -> float:
    return doc["ladder"]["inclination_deg"]


def _type(doc: dict) -> str:
    return doc["ladder"]["type"]


_CROSS_RULES: tuple[tuple[str, Callable[[dict], bool], Callable[[dict], bool], str], ...] = (
    ("ladder.inclination_deg", lambda d: _type(d) == "vertical",
     lambda d: abs(_incl(d) - 90.0) <= RANGE_TOLERANCE, "a vertical ladder must have inclination_deg 90"),
    ("ladder.inclination_deg", lambda d: _type(d) in STAIR_TYPES,
     lambda d: STAIRS_INCLINATION.contains(_incl(d)), f"stairs: {STAIRS_INCLINATION.describe()}"),
    ("ladder.inclination_deg", lambda d: _type(d) not in STAIR_TYPES,
     lambda d: LADDER_INCLINATION.contains(_incl(d)), f"ladders: {LADDER_INCLINATION.describe()}"),
    ("ladder.rung.diameter", lambda d: d["ladder"]["rung"]["shape"] == "circle",
     lambda d: d["ladder"]["rung"]["diameter"] is not None, "required when rung.shape is circle"),
    ("ladder.rung.depth", lambda d: d["ladder"]["rung"]["shape"] == "rect",
     lambda d: d["ladder"]["rung"]["depth"] is not None, "required when rung.shape is rect"),
)


def _lookup(doc: dict, path: str) -> Any:
    node: Any = doc
    for key in path.split("."):
        node = node[key]
    return node


def _duplicates(items: list[dict], key: str, path: str) -> Iterator[tuple[str, str]]:
    seen: set[Any] = set()
    for i, item in enumerate(items):
        if item[key] in seen:
            yield f"{path}[{i}].{key}", f"{key} {item[key]!r} given twice"
        seen.add(item[key])


#: Rules over lists: each yields (field, rule) violations.
_LIST_RULES: tuple[Callable[[dict], Iterator[tuple[str, str]]], ...] = (
    lambda d: _duplicates(d["ladder"]["rails"], "side", "ladder.rails"),
    lambda d: _duplicates(d["perturbation"]["rung_offsets"], "rung", "perturbation.rung_offsets"),
    lambda d: ((f"perturbation.rung_offsets[{i}].rung", f"must be in [1, n_rungs = {d['ladder']['n_rungs']}]")
               for i, o in enumerate(d["perturbation"]["rung_offsets"]) if o["rung"] > d["ladder"]["n_rungs"]),
)


def _ladder_perturbation_without_ladder(d: dict) -> Iterator[tuple[str, str]]:
    """Without a ladder, rung offsets and a rails shift have nothing to move."""
    if d["perturbation"]["rung_offsets"]:
        yield "perturbation.rung_offsets", "needs a ladder: block (rung offsets move rungs)"
    if d["perturbation"]["rails_dy"] != 0.0:
        yield "perturbation.rails_dy", "needs a ladder: block (it moves the ladder's rails)"


_LIST_RULES_NO_LADDER: tuple[Callable[[dict], Iterator[tuple[str, str]]], ...] = (_ladder_perturbation_without_ladder,)


# --------------------------------------------------------------------------------------------
# The typed result.
# --------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class RungSpec:
    shape: str  # circle | rect
    diameter: float | None  # [m] circle
    depth: float | None  # [m] rect: tread size along the ladder x (front to back)
    thickness: float  # [m] rect: vertical size

    @property
    def half_depth(self) -> float:
        """[m] half size of the rung along ladder x (radius, or half the tread depth)."""
        return 0.5 * (self.diameter if self.shape == "circle" else self.depth)  # type: ignore[operator]

    @property
    def half_height(self) -> float:
        """[m] half size of the rung along z (radius, or half the tread thickness)."""
        return 0.5 * (self.diameter if self.shape == "circle" else self.thickness)  # type: ignore[operator]


@dataclass(frozen=True)
class RailSpec:
    side: str  # left | right
    height: float  # [m] vertically above the tread nose line
    diameter: float  # [m]


@dataclass(frozen=True)
class ObstacleSpec:
    size: tuple[float, float, float]  # [m] full box sizes
    position: tuple[float, float, float]  # [m] box centre in world
    rpy_deg: tuple[float, float, float]  # [deg] R_world_box = Rz(yaw) Ry(pitch) Rx(roll)


@dataclass(frozen=True)
class LadderSpec:
    type: str
    inclination_deg: float  # [deg] stringers vs ground
    rung_spacing: float  # [m] along the stringer
    n_rungs: int
    first_rung_height: float  # [m] first rung centre line above the ground
    rung_width: float  # [m] clear width between the stringers
    rung: RungSpec
    stringer_width: float  # [m] lateral (y) size
    stringer_depth: float  # [m] size normal to the ladder plane
    rails: tuple[RailSpec, ...]
    top_platform_depth: float | None  # [m] None = no platform
    back_inclination_deg: float | None  # [deg] a_frame only, None otherwise
    friction: float  # [-] Coulomb, every ladder surface
    pose_x: float  # [m] ladder base frame in world
    pose_y: float  # [m]
    pose_yaw_deg: float  # [deg]
    obstacles: tuple[ObstacleSpec, ...]
    # project additions
    ground_friction: float = 0.8  # [-]
    stringer_top_extension: float = 0.10  # [m]
    top_platform_width: float | None = None  # [m] None = rung_width + 2 stringer_width
    top_platform_thickness: float = 0.05  # [m]

    @property
    def is_stairs(self) -> bool:
        return self.type in STAIR_TYPES

    @property
    def rail_sides(self) -> tuple[str, ...]:
        return tuple(r.side for r in self.rails)


@dataclass(frozen=True)
class RungOffset:
    rung: int  # 1-based
    dx: float = 0.0  # [m] ladder base frame
    dz: float = 0.0  # [m]


@dataclass(frozen=True)
class DropSpec:
    mass: float = 10.0  # [kg]
    radius: float = 0.12  # [m]
    speed: float = 5.5  # [m/s]
    at_time: float = 0.0  # [s] simulated time (after the start of transition at_transition when > 0)
    target_link: str = "torso"
    direction: tuple[float, ...] = ()  # world direction of flight (unit); (): the simulator's default (down)
    at_transition: int = 0  # > 0: thrown at_time after the climb's transition N (1-based) starts

    @property
    def on_transition(self) -> bool:
        return self.at_transition > 0


@dataclass(frozen=True)
class PerturbationSpec:
    rung_offsets: tuple[RungOffset, ...] = ()
    rails_dy: float = 0.0  # [m] ladder base frame y
    drops: tuple[DropSpec, ...] = ()

    @property
    def is_empty(self) -> bool:
        return not self.rung_offsets and self.rails_dy == 0.0 and not self.drops

    def rung_offset(self, rung: int) -> tuple[float, float]:
        """(dx, dz) [m] of rung ``rung`` (1-based), zeros when not perturbed."""
        for offset in self.rung_offsets:
            if offset.rung == rung:
                return offset.dx, offset.dz
        return 0.0, 0.0


@dataclass(frozen=True)
class Scenario:
    name: str
    ladder: LadderSpec | None  # None: a scene without a ladder
    perturbation: PerturbationSpec = field(default_factory=PerturbationSpec)
    description: str = ""
    scene: SceneSpec | None = None  # scene.py
    #: (("group.field", value), ...): planner settings this scenario is planned with (the scene's
    #: tuning, measured and argued in its file); the planner applies and checks them
    planner_overrides: tuple[tuple[str, Any], ...] = ()

    def to_dict(self) -> dict[str, Any]:
        return scenario_to_dict(self)

    def to_yaml(self) -> str:
        import yaml

        return yaml.safe_dump(self.to_dict(), sort_keys=False)


# --------------------------------------------------------------------------------------------
# Entry points.
# --------------------------------------------------------------------------------------------

def parse_scenario(data: Any, name: str = "") -> Scenario:
    """Validate a scenario document (a mapping) and return the frozen :class:`Scenario`.

    ``name`` wins over the document's ``name`` field. Raises :class:`SpecError` only.
    """
    _reject_non_finite(data)
    doc = _parse_block(SCHEMA, data, "")
    ladder = doc["ladder"]
    if ladder is None:
        if doc["scene"] is None:
            raise SpecError("ladder", "required field is missing: a scenario needs a ladder: block, "
                                      "a scene: block or both")
    elif ladder["inclination_deg"] is None:
        ladder["inclination_deg"] = INCLINATION_DEFAULT_DEG[ladder["type"]]
    for path, applies, holds, rule in _CROSS_RULES:
        if doc["ladder"] is not None and applies(doc) and not holds(doc):
            value = _lookup(doc, path)
            raise SpecError(path, rule if value is None else f"{rule}, got {value!r}")
    for list_rule in _LIST_RULES if doc["ladder"] is not None else _LIST_RULES_NO_LADDER:
        for path, rule in list_rule(doc):
            raise SpecError(path, rule)
    scenario = _build(doc, name or doc["name"])
    if doc["scene"] is not None:
        from .scene import parse_scene

        scene = parse_scene(doc["scene"], scenario.ladder)
        scenario = dataclasses.replace(scenario, scene=scene)
    return scenario


_OVERRIDE_KEY = re.compile(r"^[a-z_][a-z0-9_]*\.[a-z_][a-z0-9_]*$")


def _planner_overrides(value: Any, path: str) -> tuple[tuple[str, Any], ...]:
    """``planner_overrides``: a mapping of dotted ``group.field`` names to scalars (the planner
    checks that each names a setting and that the value is valid for it)."""
    if not isinstance(value, dict):
        raise SpecError(path, f"must be a mapping of planner settings (group.field: value), got {type(value).__name__}")
    out = []
    for key, v in value.items():
        if not isinstance(key, str) or not _OVERRIDE_KEY.match(key):
            raise SpecError(_key_path(path, key), "must be a dotted planner setting name group.field")
        if isinstance(v, (dict, list)) or v is None:
            raise SpecError(f"{path}.{key}", f"must be a number, a bool or a string, got {v!r}"[:200])
        out.append((key, v))
    return tuple(out)


def _unit_direction(v, path: str) -> tuple[float, ...]:
    if v is None:
        return ()
    n = math.sqrt(sum(float(x) ** 2 for x in v))
    if n < 1e-9:
        raise SpecError(path, f"must be a non-zero direction, got {list(v)}")
    return (float(v[0]) / n, float(v[1]) / n, float(v[2]) / n)


def _build(doc: dict, name: str) -> Scenario:
    pert = doc["perturbation"]
    perturbation = PerturbationSpec(
        rung_offsets=tuple(RungOffset(o["rung"], o["dx"], o["dz"]) for o in pert["rung_offsets"]),
        rails_dy=pert["rails_dy"],
        drops=tuple(DropSpec(d["mass"], d["radius"], d["speed"], d["at_time"], d["target_link"],
                             _unit_direction(d["direction"], f"perturbation.drops[{i}].direction"),
                             d["at_transition"])
                    for i, d in enumerate(pert["drops"])),
    )
    ladder = None if doc["ladder"] is None else _build_ladder(doc["ladder"])
    return Scenario(name=name, ladder=ladder, perturbation=perturbation, description=doc["description"],
                    planner_overrides=doc["planner_overrides"])


def _build_ladder(lad: dict) -> LadderSpec:
    rung, stringer, pose, platform = lad["rung"], lad["stringer"], lad["pose"], lad["top_platform"]
    ladder = LadderSpec(
        type=lad["type"],
        inclination_deg=float(lad["inclination_deg"]),
        rung_spacing=lad["rung_spacing"],
        n_rungs=lad["n_rungs"],
        first_rung_height=lad["first_rung_height"],
        rung_width=lad["rung_width"],
        rung=RungSpec(rung["shape"], rung["diameter"], rung["depth"], rung["thickness"]),
        stringer_width=stringer["width"],
        stringer_depth=stringer["depth"],
        rails=tuple(RailSpec(r["side"], r["height"], r["diameter"]) for r in lad["rails"]),
        top_platform_depth=None if platform is None else platform["depth"],
        back_inclination_deg=lad["a_frame"]["back_inclination_deg"] if lad["type"] == "a_frame" else None,
        friction=lad["friction"],
        pose_x=pose["x"], pose_y=pose["y"], pose_yaw_deg=pose["yaw_deg"],
        obstacles=tuple(ObstacleSpec(o["size"], o["position"], o["rpy_deg"]) for o in lad["obstacles"]),
        ground_friction=lad["ground_friction"],
        stringer_top_extension=stringer["top_extension"],
        top_platform_width=None if platform is None else platform["width"],
        top_platform_thickness=(DEFAULTS["ladder.top_platform.thickness"] if platform is None
                                else platform["thickness"]),
    )
    return ladder


def parse_yaml(text: str) -> Any:
    """YAML text -> Python data; any YAML problem becomes ``SpecError('document', ...)``."""
    import yaml

    try:
        return yaml.safe_load(text)
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
        raise SpecError("document", f"YAML syntax error{where}: {exc.problem or exc}") from None
    except Exception as exc:  # YAMLError, bad timestamps (ValueError), very deep nesting, ...
        raise SpecError("document", f"cannot read YAML: {type(exc).__name__}: {exc}"[:300]) from None


def ladder_config_dir() -> pathlib.Path:
    from .ros_env import project_root

    return project_root() / "config" / "ladders"


def scene_config_dir() -> pathlib.Path:
    from .ros_env import project_root

    return project_root() / "config" / "scenes"


def available_ladders() -> list[str]:
    """Names of the shipped ladder scenarios (config/ladders/*.yaml)."""
    return sorted(p.stem for p in ladder_config_dir().glob("*.yaml"))


def available_scenes() -> list[str]:
    """Names of the shipped scene scenarios (config/scenes/*.yaml)."""
    return sorted(p.stem for p in scene_config_dir().glob("*.yaml"))


_NAME_RE = re.compile(r"^[A-Za-z0-9_.\-]+$")


def load_scenario(source: Any) -> Scenario:
    """A scenario from a name in config/ladders/ or config/scenes/, a file path, YAML text, a dict
    or a Scenario.

    A string is read as: YAML text if it contains a newline; else a shipped name if
    ``config/ladders/<source>.yaml`` or else ``config/scenes/<source>.yaml`` exists; else a file
    path if it names an existing file or ends in .yaml/.yml (relative paths: the working directory, then the project root); else YAML
    text when it contains ``:``, ``{`` or ``[``; else an unknown name (``SpecError('source', ...)``). The
    scenario is named after the file stem for names and paths, and after the document's
    ``name`` field (or "") otherwise.
    """
    if isinstance(source, Scenario):
        return source
    if isinstance(source, Mapping):
        return parse_scenario(source)
    if isinstance(source, pathlib.Path):
        return _load_file(source)
    if not isinstance(source, str):
        raise SpecError("source", f"expected a name, a path, YAML text or a mapping, got {_type_name(source)}")
    if "\n" in source:
        return parse_scenario(parse_yaml(source))
    text = source.strip()
    if _NAME_RE.match(text) and not text.lower().endswith((".yaml", ".yml")):
        for directory in (ladder_config_dir(), scene_config_dir()):
            candidate = directory / f"{text}.yaml"
            if candidate.is_file():
                return _load_file(candidate)
    if text.lower().endswith((".yaml", ".yml")) or pathlib.Path(text).is_file():
        path = pathlib.Path(text).expanduser()
        if not path.is_absolute() and not path.is_file():
            from .ros_env import project_root

            if (project_root() / path).is_file():
                path = project_root() / path
        return _load_file(path)
    if any(c in text for c in ":{["):
        return parse_scenario(parse_yaml(source))
    raise SpecError("source", f"no ladder named {text!r} in {ladder_config_dir()} nor scene in {scene_config_dir()} "
                              f"(known: {', '.join(available_ladders() + available_scenes())})"[:500])


def _load_file(path: pathlib.Path) -> Scenario:
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise SpecError("source", f"file not found: {path}") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise SpecError("source", f"cannot read {path}: {exc}") from None
    return parse_scenario(parse_yaml(text), name=path.stem)


def scenario_to_dict(scenario: Scenario) -> dict[str, Any]:
    """The full spec document (every field explicit); ``parse_scenario`` of it gives it back."""
    pert = scenario.perturbation
    doc: dict[str, Any] = {"name": scenario.name, "description": scenario.description}
    if scenario.ladder is not None:
        doc["ladder"] = _ladder_to_dict(scenario.ladder)
    if scenario.scene is not None:
        from .scene import scene_to_dict

        doc["scene"] = scene_to_dict(scenario.scene)
    if scenario.planner_overrides:
        doc["planner_overrides"] = dict(scenario.planner_overrides)
    doc["perturbation"] = {
        "rung_offsets": [{"rung": o.rung, "dx": o.dx, "dz": o.dz} for o in pert.rung_offsets],
        "rails_dy": pert.rails_dy,
        "drops": [{"mass": d.mass, "radius": d.radius, "speed": d.speed, "at_time": d.at_time,
                   "target_link": d.target_link, "at_transition": d.at_transition,
                   **({"direction": list(d.direction)} if d.direction else {})} for d in pert.drops],
    }
    return doc


def _ladder_to_dict(lad: LadderSpec) -> dict[str, Any]:
    rung: dict[str, Any] = {"shape": lad.rung.shape, "thickness": lad.rung.thickness}
    if lad.rung.diameter is not None:
        rung["diameter"] = lad.rung.diameter
    if lad.rung.depth is not None:
        rung["depth"] = lad.rung.depth
    ladder: dict[str, Any] = {
        "type": lad.type,
        "inclination_deg": lad.inclination_deg,
        "rung_spacing": lad.rung_spacing,
        "n_rungs": lad.n_rungs,
        "first_rung_height": lad.first_rung_height,
        "rung_width": lad.rung_width,
        "rung": rung,
        "stringer": {"width": lad.stringer_width, "depth": lad.stringer_depth,
                     "top_extension": lad.stringer_top_extension},
        "rails": [{"side": r.side, "height": r.height, "diameter": r.diameter} for r in lad.rails],
        "friction": lad.friction,
        "ground_friction": lad.ground_friction,
        "pose": {"x": lad.pose_x, "y": lad.pose_y, "yaw_deg": lad.pose_yaw_deg},
        "obstacles": [{"size": list(o.size), "position": list(o.position), "rpy_deg": list(o.rpy_deg)}
                      for o in lad.obstacles],
    }
    if lad.top_platform_depth is not None:
        platform: dict[str, Any] = {"depth": lad.top_platform_depth, "thickness": lad.top_platform_thickness}
        if lad.top_platform_width is not None:
            platform["width"] = lad.top_platform_width
        ladder["top_platform"] = platform
    if lad.back_inclination_deg is not None:
        ladder["a_frame"] = {"back_inclination_deg": lad.back_inclination_deg}
    return ladder
