"""Motion primitives as data: config/primitives/<robot>/<strategy>/.

A library folder holds

- ``design.yaml``: the hand-written design cues (seed holds, way-point offsets of the moving limb,
  sequences) - the "human expert" part of ladder_climbing_drc_hubo.txt III-B;
- ``library.yaml``: what scripts/make_primitives.py produced from it: the reference ladder, the
  joint names, the sequences and, per primitive, its seed hold rule, the reference anchors and
  the way-point configurations (q̄s, q̄1..q̄k, q̄e) designed on the reference ladder.

Way-point configurations are stored in the ladder base frame L (base position [m] and quaternion
x y z w of the pelvis in L, then the joint angles [rad] in ``joint_names`` order), so a ladder
placed elsewhere in the world reuses them unchanged (:func:`to_world` / :func:`to_ladder`).

Primitive kinds:

- ``limb``: one hold change (limb transfer): ``limb`` breaks contact and makes a new one on the
  target given by ``target`` (``surface``: ground | rung; ``rule``: next | mount | above_feet);
- ``com``: no stance change, the end configuration must also hold with ``unload`` (a limb)
  carrying no force (CoM transfer before that limb moves).
"""
from __future__ import annotations

import pathlib
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pinocchio as pin
import yaml

from climb_core.contact import LIMBS
from climb_core.errors import SpecError
from climb_core.geometry_cache import atomic_write

LIBRARY_FILE = "library.yaml"
#: extra libraries designed on other reference ladders: library_<inclination>_<spacing>.yaml
VARIANT_GLOB = "library_*.yaml"
DESIGN_FILE = "design.yaml"
FORMAT = "climb_primitive_library"
VERSION = 1
KINDS = ("limb", "com")
TARGET_RULES = ("next", "mount", "above_feet", "")
SEQUENCE_NAMES = ("approach", "mount", "first_cycle", "cycle")


@dataclass(frozen=True)
class TargetSpec:
    surface: str = ""  # ground | rung ("" for com primitives)
    rule: str = ""  # rung rule: next (current rung + 1) | mount (rung nearest mount_height) | above_feet


@dataclass(frozen=True)
class Primitive:
    name: str
    kind: str  # limb | com
    type: str  # plan transition name: place_foot | place_hand | mount | com_to_foot | com_to_centre | dismount
    limb: str = ""  # moving limb (limb primitives)
    unload: str = ""  # com primitives: limb that must be free of force at the end ("" none)
    com_over: str = ""  # com primitives on the ground: left_foot | right_foot | centre | ""
    target: TargetSpec = TargetSpec()
    via: tuple = ()  # design cues: ({"from": start|target, "offset": [x, y, z]}, ...)
    #: way-points in the ladder frame, (k + 2, nq): q̄s, q̄1..q̄k, q̄e
    waypoints: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    #: [m] ladder frame: mean hold centre of the start / end stance on the reference ladder
    anchor_start: np.ndarray = field(default_factory=lambda: np.zeros(3))
    anchor_end: np.ndarray = field(default_factory=lambda: np.zeros(3))
    #: [m] ladder frame: reference target hold centre (limb primitives)
    target_centre: np.ndarray = field(default_factory=lambda: np.zeros(3))
    #: [m] |position along the rung| of the seed hold (signed by the limb's side)
    seed_s: float = 0.0
    #: limbs each of which must be removable at the end configuration (the stance minus that limb
    #: stays feasible): the moving limb lands without force, the next moving limb can leave
    end_unload: tuple[str, ...] = ()

    @property
    def is_limb(self) -> bool:
        return self.kind == "limb"


@dataclass(frozen=True)
class PrimitiveLibrary:
    robot: str
    strategy: str
    facing: str
    reference_ladder: dict  # scenario dict of the reference ladder
    joint_names: tuple[str, ...]
    sequences: dict[str, tuple[str, ...]]
    primitives: dict[str, Primitive]
    holds: dict[str, float]  # design hold parameters (foot_s, hand_s, ground_foot_x, ground_foot_y, ...)
    #: [m] reference ladder: height of the mount rung above the ground, and hand - foot height while climbing
    mount_height: float
    hands_above_feet_height: float
    initial_fixture: str = "standing"
    path: pathlib.Path | None = None
    generated_by: str = ""

    def sequence(self, name: str) -> list[Primitive]:
        if name not in self.sequences:
            raise SpecError("primitives.sequences", f"library {self.robot}/{self.strategy} has no sequence {name!r}")
        return [self.primitives[p] for p in self.sequences[name]]


# --------------------------------------------------------------------------------------------
# ladder frame <-> world


def T_world_ladder(env: Any) -> np.ndarray:
    return np.asarray(env.T_world_ladder, dtype=float)


def _transform_q(q: np.ndarray, T: np.ndarray) -> np.ndarray:
    out = np.asarray(q, dtype=float).copy()
    M = pin.SE3(T) * pin.XYZQUATToSE3(out[:7])
    out[:7] = pin.SE3ToXYZQUAT(M)
    return out


def to_world(env: Any, q_ladder: np.ndarray) -> np.ndarray:
    """Configuration with its base given in the ladder frame -> world frame."""
    return _transform_q(q_ladder, T_world_ladder(env))


def to_ladder(env: Any, q_world: np.ndarray) -> np.ndarray:
    return _transform_q(q_world, np.linalg.inv(T_world_ladder(env)))


def point_to_world(env: Any, p_ladder: np.ndarray) -> np.ndarray:
    T = T_world_ladder(env)
    return T[:3, :3] @ np.asarray(p_ladder, dtype=float) + T[:3, 3]


def point_to_ladder(env: Any, p_world: np.ndarray) -> np.ndarray:
    T = T_world_ladder(env)
    return T[:3, :3].T @ (np.asarray(p_world, dtype=float) - T[:3, 3])


def vector_to_world(env: Any, v_ladder: np.ndarray) -> np.ndarray:
    return T_world_ladder(env)[:3, :3] @ np.asarray(v_ladder, dtype=float)


# --------------------------------------------------------------------------------------------
# loading / saving


def library_dir(robot: str, strategy: str, root: str | pathlib.Path | None = None) -> pathlib.Path:
    from climb_core.ros_env import project_root

    base = pathlib.Path(root) if root is not None else project_root() / "config" / "primitives"
    if not base.is_absolute():
        base = project_root() / base
    return base / robot / strategy


#: libyaml's loader when PyYAML was built with it (a library file parses in ~0.1 s instead of 0.5 s)
_YAML_LOADER = getattr(yaml, "CSafeLoader", yaml.SafeLoader)


def _load_yaml(text: str):
    return yaml.load(text, Loader=_YAML_LOADER)


def load_design(robot: str, strategy: str, root: str | pathlib.Path | None = None) -> dict:
    path = library_dir(robot, strategy, root) / DESIGN_FILE
    if not path.is_file():
        raise SpecError("primitives.design", f"no design file {path}")
    data = _load_yaml(path.read_text())
    if not isinstance(data, dict):
        raise SpecError("primitives.design", f"{path} must be a mapping")
    return data


def parse_primitive(name: str, d: dict, nq: int | None = None, field_: str = "primitives") -> Primitive:
    where = f"{field_}.{name}"
    if not isinstance(d, dict):
        raise SpecError(where, "must be a mapping")
    kind = d.get("kind")
    if kind not in KINDS:
        raise SpecError(f"{where}.kind", f"must be one of {', '.join(KINDS)}; got {kind!r}")
    limb = str(d.get("limb", ""))
    unload = str(d.get("unload", ""))
    if kind == "limb" and limb not in LIMBS:
        raise SpecError(f"{where}.limb", f"must be one of {', '.join(LIMBS)}; got {limb!r}")
    if unload and unload not in LIMBS:
        raise SpecError(f"{where}.unload", f"must be a limb or empty; got {unload!r}")
    t = d.get("target", {}) or {}
    target = TargetSpec(surface=str(t.get("surface", "")), rule=str(t.get("rule", "")))
    if kind == "limb":
        if target.surface not in ("ground", "rung"):
            raise SpecError(f"{where}.target.surface", f"must be ground or rung; got {target.surface!r}")
        if target.surface == "rung" and target.rule not in ("next", "mount", "above_feet"):
            raise SpecError(f"{where}.target.rule", f"must be next, mount or above_feet; got {target.rule!r}")
    end_unload = tuple(str(x) for x in (d.get("end_unload") or ((limb,) if kind == "limb" else
                                                                   ((unload,) if unload else ()))))
    for x in end_unload:
        if x not in LIMBS:
            raise SpecError(f"{where}.end_unload", f"must list limbs; got {x!r}")
    wp = np.asarray(d.get("waypoints", []), dtype=float)
    if wp.size:
        if wp.ndim != 2 or (nq is not None and wp.shape[1] != nq) or len(wp) < 2:
            raise SpecError(f"{where}.waypoints", f"must be at least 2 configurations of {nq} numbers")
        if not np.isfinite(wp).all():
            raise SpecError(f"{where}.waypoints", "must be finite")
    else:
        wp = np.zeros((0, nq or 0))
    return Primitive(
        name=name, kind=kind, type=str(d.get("type", kind)), limb=limb, unload=unload,
        com_over=str(d.get("com_over", "")), target=target, via=tuple(d.get("via", ()) or ()), waypoints=wp,
        anchor_start=np.asarray(d.get("anchor_start", [0, 0, 0]), dtype=float),
        anchor_end=np.asarray(d.get("anchor_end", [0, 0, 0]), dtype=float),
        target_centre=np.asarray(d.get("target_centre", [0, 0, 0]), dtype=float),
        seed_s=float(d.get("seed_s", 0.0)), end_unload=end_unload)


def primitive_to_dict(p: Primitive) -> dict:
    out: dict[str, Any] = {"kind": p.kind, "type": p.type}
    if p.limb:
        out["limb"] = p.limb
    if p.kind == "com":
        out["unload"] = p.unload
        out["com_over"] = p.com_over
    if p.kind == "limb":
        out["target"] = {"surface": p.target.surface, "rule": p.target.rule}
        out["via"] = [dict(v) for v in p.via]
        out["target_centre"] = [round(float(x), 6) for x in p.target_centre]
        out["seed_s"] = round(float(p.seed_s), 6)
    out["end_unload"] = list(p.end_unload)
    out["anchor_start"] = [round(float(x), 6) for x in p.anchor_start]
    out["anchor_end"] = [round(float(x), 6) for x in p.anchor_end]
    out["waypoints"] = [[round(float(x), 6) for x in q] for q in p.waypoints]
    return out


def variant_file_name(inclination_deg: float, rung_spacing: float) -> str:
    return f"library_{inclination_deg:g}_{rung_spacing:.2f}.yaml"


def reference_key(lib: "PrimitiveLibrary") -> tuple[float, float]:
    """(inclination [deg], rung spacing [m]) of the ladder a library was designed on."""
    lad = lib.reference_ladder.get("ladder", {})
    return float(lad.get("inclination_deg", 75.0)), float(lad.get("rung_spacing", 0.25))


def load_variants(robot: str = "g1", strategy: str = "forward", root: str | pathlib.Path | None = None,
                  nq: int | None = None) -> list["PrimitiveLibrary"]:
    """The main library followed by every variant designed on another reference ladder."""
    main = load_library(robot, strategy, root, nq)
    out = [main]
    for path in sorted(library_dir(robot, strategy, root).glob(VARIANT_GLOB)):
        out.append(load_library(robot, strategy, root, nq, path=path))
    return out


def rank_variants(variants: list["PrimitiveLibrary"], inclination_deg: float, rung_spacing: float,
                  deg_scale: float = 10.0, spacing_scale: float = 0.05) -> list["PrimitiveLibrary"]:
    """Variants ordered by the distance of their reference ladder to (inclination, spacing)."""
    def dist(lib):
        a, s = reference_key(lib)
        return abs(a - inclination_deg) / deg_scale + abs(s - rung_spacing) / spacing_scale
    return sorted(variants, key=dist)


#: parsed libraries by (path, modification time, size): a library file parses in ~0.1 s, and a
#: sweep worker or a planning node plans many times with the same files
_LIBRARY_CACHE: dict[tuple[str, int, int], PrimitiveLibrary] = {}


def load_library(robot: str = "g1", strategy: str = "forward", root: str | pathlib.Path | None = None,
                 nq: int | None = None, path: pathlib.Path | None = None) -> PrimitiveLibrary:
    """The library of ``robot`` / ``strategy`` (SpecError naming the field when malformed).

    Parsed once per version of the file (its arrays are read-only: the library is shared)."""
    folder = library_dir(robot, strategy, root)
    path = path or folder / LIBRARY_FILE
    if not path.is_file():
        raise SpecError("primitives", f"no primitive library {path}; produce it with "
                                      f"scripts/make_primitives.py --robot {robot} --strategy {strategy}")
    st = path.stat()
    key = (str(path.resolve()), st.st_mtime_ns, st.st_size)
    lib = _LIBRARY_CACHE.get(key)
    if lib is None:
        lib = _parse_library(path)
        if len(_LIBRARY_CACHE) >= 64:
            _LIBRARY_CACHE.clear()
        _LIBRARY_CACHE[key] = lib
    if nq is not None and nq != 7 + len(lib.joint_names):
        raise SpecError("primitives.joint_names", f"{path} has {len(lib.joint_names)} joints, the robot {nq - 7}")
    return lib


def _parse_library(path: pathlib.Path) -> PrimitiveLibrary:
    try:
        data = _load_yaml(path.read_text())
    except yaml.YAMLError as exc:
        raise SpecError("primitives", f"{path}: invalid YAML: {exc}") from None
    if not isinstance(data, dict) or data.get("format") != FORMAT:
        raise SpecError("primitives.format", f"{path} must have format: {FORMAT}")
    if int(data.get("version", 0)) != VERSION:
        raise SpecError("primitives.version", f"{path}: version must be {VERSION}")
    joint_names = tuple(str(j) for j in data["joint_names"])
    nq_file = 7 + len(joint_names)
    prims = {name: parse_primitive(name, d, nq_file) for name, d in (data.get("primitives") or {}).items()}
    for prim in prims.values():
        for arr in (prim.waypoints, prim.anchor_start, prim.anchor_end, prim.target_centre):
            arr.setflags(write=False)
    seqs: dict[str, tuple[str, ...]] = {}
    for sname, names in (data.get("sequences") or {}).items():
        for n in names:
            if n not in prims:
                raise SpecError(f"primitives.sequences.{sname}", f"unknown primitive {n!r}")
        seqs[str(sname)] = tuple(names)
    # a variant may be partial (design.yaml `fallback: main`): the planner takes the sub-task
    # sequence from the main library and any primitive a variant lacks from the next library
    for required in (("mount", "cycle") if path.name == LIBRARY_FILE else ()):
        if required not in seqs:
            raise SpecError("primitives.sequences", f"needs a `{required}` sequence")
    return PrimitiveLibrary(
        robot=str(data["robot"]), strategy=str(data["strategy"]), facing=str(data.get("facing", "forward")),
        reference_ladder=dict(data["reference_ladder"]), joint_names=joint_names, sequences=seqs, primitives=prims,
        holds={k: float(v) for k, v in (data.get("holds") or {}).items()},
        mount_height=float(data["mount_height"]), hands_above_feet_height=float(data["hands_above_feet_height"]),
        initial_fixture=str(data.get("initial_fixture", "standing")), path=path,
        generated_by=str(data.get("generated_by", "")))


def save_library(lib: PrimitiveLibrary, folder: pathlib.Path, header: str = "", file_name: str = LIBRARY_FILE
                 ) -> pathlib.Path:
    folder.mkdir(parents=True, exist_ok=True)
    doc = {
        "format": FORMAT, "version": VERSION, "robot": lib.robot, "strategy": lib.strategy, "facing": lib.facing,
        "generated_by": lib.generated_by, "initial_fixture": lib.initial_fixture,
        "reference_ladder": lib.reference_ladder, "joint_names": list(lib.joint_names),
        "holds": {k: float(v) for k, v in lib.holds.items()},
        "mount_height": round(float(lib.mount_height), 6),
        "hands_above_feet_height": round(float(lib.hands_above_feet_height), 6),
        "sequences": {k: list(v) for k, v in lib.sequences.items()},
        "primitives": {name: primitive_to_dict(p) for name, p in lib.primitives.items()},
    }
    path = folder / file_name
    text = yaml.safe_dump(doc, sort_keys=False, width=200, default_flow_style=None)
    atomic_write(path, header + text)
    return path
