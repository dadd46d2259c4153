"""Saving and loading whole-body plans (JSON), and the JSON summary of scripts/plan.py.

File format (``format: climb_whole_body_plan``, ``version: 1``): the fields of
:class:`climb_core.contact.WholeBodyPlan`, holds as lists of points (world frame [m]),
configurations in Pinocchio's layout (base xyz [m], quaternion x y z w, joints [rad] in
``joint_names`` order), times [s]. Plain JSON so that any tool (and the controller's tests) can
read it; ``metadata`` carries the planner's record (seed, ladder, timings, primitive names).
"""
from __future__ import annotations

import json
import math
import pathlib
from typing import Any

import numpy as np

from climb_core.contact import ContactPoint, Hold, Stance, Transition, WholeBodyPlan
from climb_core.errors import SpecError
from climb_core.geometry_cache import atomic_write

FORMAT = "climb_whole_body_plan"
VERSION = 1


def hold_to_dict(hold: Hold) -> dict:
    return {
        "limb": hold.limb,
        "robot_surface": hold.robot_surface,
        "env_surface": hold.env_surface,
        "points": [{"position": p.position.tolist(), "normal": p.normal.tolist()} for p in hold.points],
        "friction": float(hold.friction),
        "bilateral": bool(hold.bilateral),
        "grip_force_limit": float(hold.grip_force_limit),
    }


def hold_from_dict(d: dict, field: str = "hold") -> Hold:
    try:
        points = tuple(ContactPoint(np.asarray(p["position"], float), np.asarray(p["normal"], float))
                       for p in d["points"])
        return Hold(limb=str(d["limb"]), robot_surface=str(d["robot_surface"]), env_surface=str(d["env_surface"]),
                    points=points, friction=float(d["friction"]), bilateral=bool(d.get("bilateral", False)),
                    grip_force_limit=float(d.get("grip_force_limit", 0.0)))
    except (KeyError, TypeError, ValueError) as exc:
        raise SpecError(field, f"malformed hold: {exc}") from None


def stance_to_dict(stance: Stance) -> dict:
    return {"name": stance.name, "holds": [hold_to_dict(h) for h in stance.holds]}


def stance_from_dict(d: dict, field: str = "stance") -> Stance:
    if not isinstance(d, dict) or "holds" not in d:
        raise SpecError(field, "a stance is a mapping with `holds`")
    return Stance(tuple(hold_from_dict(h, f"{field}.holds[{i}]") for i, h in enumerate(d["holds"])),
                  name=str(d.get("name", "")))


def transition_to_dict(t: Transition) -> dict:
    return {
        "primitive": t.primitive,
        "moving_limb": t.moving_limb,
        "stance": stance_to_dict(t.stance),
        "target_stance": stance_to_dict(t.target_stance),
        "times": np.asarray(t.times, float).tolist(),
        "path": np.asarray(t.path, float).tolist(),
    }


def transition_from_dict(d: dict, nq: int | None = None, field: str = "transition") -> Transition:
    try:
        times = np.asarray(d["times"], dtype=float)
        path = np.asarray(d["path"], dtype=float)
    except (KeyError, TypeError, ValueError) as exc:
        raise SpecError(field, f"malformed transition: {exc}") from None
    if path.ndim != 2 or len(times) != len(path):
        raise SpecError(f"{field}.path", "must be an (n, nq) array with one time per row")
    if nq is not None and path.shape[1] != nq:
        raise SpecError(f"{field}.path", f"rows must have nq = {nq} values, got {path.shape[1]}")
    if not (np.all(np.isfinite(times)) and np.all(np.isfinite(path))):
        raise SpecError(field, "times and path must be finite")
    if np.any(np.diff(times) < 0):
        raise SpecError(f"{field}.times", "must be non-decreasing")
    return Transition(primitive=str(d.get("primitive", "")), moving_limb=str(d.get("moving_limb", "")),
                      stance=stance_from_dict(d["stance"], f"{field}.stance"),
                      target_stance=stance_from_dict(d["target_stance"], f"{field}.target_stance"),
                      times=times, path=path)


def plan_to_dict(plan: WholeBodyPlan, metadata: dict | None = None) -> dict:
    return {
        "format": FORMAT,
        "version": VERSION,
        "robot": plan.robot,
        "environment": plan.environment,
        "joint_names": list(plan.joint_names),
        "initial_stance": stance_to_dict(plan.initial_stance),
        "transitions": [transition_to_dict(t) for t in plan.transitions],
        "metadata": _jsonable(metadata or {}),
    }


def plan_from_dict(d: dict) -> tuple[WholeBodyPlan, dict]:
    if not isinstance(d, dict) or d.get("format") != FORMAT:
        raise SpecError("plan.format", f"must be {FORMAT!r}")
    if int(d.get("version", -1)) != VERSION:
        raise SpecError("plan.version", f"must be {VERSION}, got {d.get('version')!r}")
    for key, kind in (("robot", str), ("environment", str), ("joint_names", list), ("initial_stance", dict),
                      ("transitions", list)):
        if not isinstance(d.get(key), kind):
            raise SpecError(f"plan.{key}", f"required, a {'string' if kind is str else kind.__name__}")
    joint_names = [str(j) for j in d["joint_names"]]
    nq = 7 + len(joint_names)
    transitions = [transition_from_dict(t, nq, f"plan.transitions[{i}]") for i, t in enumerate(d["transitions"])]
    plan = WholeBodyPlan(robot=str(d["robot"]), environment=str(d["environment"]), joint_names=joint_names,
                         initial_stance=stance_from_dict(d["initial_stance"], "plan.initial_stance"),
                         transitions=transitions)
    return plan, dict(d.get("metadata", {}))


def save_plan(path: str | pathlib.Path, plan: WholeBodyPlan, metadata: dict | None = None) -> pathlib.Path:
    path = pathlib.Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write(path, json.dumps(plan_to_dict(plan, metadata)))
    return path


def load_plan(path: str | pathlib.Path) -> tuple[WholeBodyPlan, dict]:
    path = pathlib.Path(path)
    if not path.is_file():
        raise SpecError("plan", f"file {path} not found")
    try:
        data = json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise SpecError("plan", f"{path} is not JSON: {exc}") from None
    return plan_from_dict(data)


def _jsonable(x: Any) -> Any:
    if isinstance(x, dict):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return x.tolist()
    if isinstance(x, (np.floating, float)):
        v = float(x)
        return v if math.isfinite(v) else None
    if isinstance(x, (np.integer,)):
        return int(x)
    if isinstance(x, (np.bool_,)):
        return bool(x)
    return x


def summary_line(summary: dict) -> str:
    """One JSON line (ladder_spec.md "Results")."""
    return json.dumps(_jsonable(summary), sort_keys=False)


# --------------------------------------------------------------------------------------------
# disk cache of expensive planning results (tests, sweeps): <project>/.cache/planner/


def source_fingerprint(*extra: Any) -> str:
    """Hash of everything a plan depends on: the planner and core library sources, the planner,
    feasibility, robot and primitive configuration files, plus ``extra`` (scenario, steps, seed)."""
    import hashlib

    from climb_core.ros_env import project_root

    root = project_root()
    h = hashlib.sha256()
    files = sorted((root / "src" / "planner_node" / "planner_node").glob("*.py"))
    files += sorted((root / "src" / "climb_core" / "climb_core").glob("*.py"))
    files += [root / "config" / "planner.yaml", root / "config" / "feasibility.yaml"]
    files += sorted((root / "config" / "robots").glob("*.yaml"))
    files += sorted((root / "config" / "primitives").glob("*/*/library.yaml"))
    for f in files:
        if f.is_file():
            h.update(f.name.encode())
            h.update(f.read_bytes())
    for x in extra:
        h.update(repr(x).encode())
    return h.hexdigest()[:24]


def cache_dir() -> pathlib.Path:
    from climb_core.ros_env import project_root

    return project_root() / ".cache" / "planner"


def cached_plan(key: str, compute) -> tuple[WholeBodyPlan | None, dict]:
    """(plan, metadata) from .cache/planner/<key>.json, else ``compute()`` -> (plan or None,
    metadata) stored there."""
    path = cache_dir() / f"{key}.json"
    if path.is_file():
        try:
            data = json.loads(path.read_text())
            meta = dict(data.get("metadata", {}))
            if data.get("plan") is None:
                return None, meta
            return plan_from_dict(data["plan"])[0], meta
        except (ValueError, KeyError, SpecError):
            pass
    plan, meta = compute()
    path.parent.mkdir(parents=True, exist_ok=True)
    try:  # a private temporary file per writer (processes may plan the same request at once)
        atomic_write(path, json.dumps({"metadata": _jsonable(meta),
                                       "plan": None if plan is None else plan_to_dict(plan)}))
    except OSError:  # a cache that cannot be written costs time, never the plan
        pass
    return plan, meta


def retimed(plan: WholeBodyPlan, model: Any, timing: Any) -> WholeBodyPlan:
    """The same paths, each transition's way-points timed again under ``timing``
    (:class:`planner_node.settings.TimingParams`: joint / base speed limits, ramps, least duration,
    the soles' edges), as the planner times them (:func:`planner_node.interpolation.time_transition`)."""
    import dataclasses

    from .interpolation import time_transition

    transitions = [dataclasses.replace(t, times=time_transition(model, list(t.path), t.stance, timing))
                   for t in plan.transitions]
    return dataclasses.replace(plan, transitions=transitions)
