"""Settings of the in-process climb: config/climb.yaml (units in the file's comments)."""
from __future__ import annotations

import pathlib
from dataclasses import dataclass, field
from typing import Any

import yaml

from climb_core.errors import SpecError
from climb_core.ros_env import project_root


@dataclass(frozen=True)
class ClimbSettings:
    extra_time_s: float  # [s]
    settle_time_s: float  # [s]
    plan_joint_limit_margin: float  # [rad]
    controller_overrides: dict = field(default_factory=dict)
    compliance_overrides: dict = field(default_factory=dict)
    planner_overrides: dict = field(default_factory=dict)  # dotted planner settings (section.field)
    #: applied after planner_overrides when the scenario is a scene without a ladder
    scene_planner_overrides: dict = field(default_factory=dict)
    #: a ladder at least ``min_incline_deg`` steep plans with its ``planner_overrides`` after the
    #: climb's (planner_node.settings.settings_for_scenario); {}: none
    steep_ladder: dict = field(default_factory=dict)
    bag_rate_hz: float = 50.0  # [Hz]
    log_rate_hz: float = 50.0  # [Hz]
    foot_force_min: float = 20.0  # [N]
    cone_tolerance: float = 0.05  # [-]
    cone_force_min: float = 20.0  # [N]
    snapshot_count: int = 8
    snapshot_width: int = 320  # [px]
    snapshot_height: int = 400  # [px]
    camera_distance: float = 2.4  # [m]
    #: [s] sim time the session waits, after the controller entered failure, for it to recover
    #: (the hold QP solving again: replan_needed, reason qp_failure); 0: a failure ends the climb
    failure_recovery_s: float = 3.0
    camera_yaw_deg: float = 60.0  # [deg]
    camera_pitch_deg: float = -10.0  # [deg]


def _num(d: dict, key: str, path: str, low: float = 0.0, positive: bool = False) -> float:
    if key not in d:
        raise SpecError(f"{path}.{key}", "is required")
    v = d[key]
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise SpecError(f"{path}.{key}", f"must be a number, got {v!r}")
    if v < low or (positive and v <= 0):
        raise SpecError(f"{path}.{key}", f"must be {'>' if positive else '>='} {low}, got {v}")
    return float(v)


def _block(d: Any, key: str, path: str) -> dict:
    v = d.get(key) if isinstance(d, dict) else None
    if not isinstance(v, dict):
        raise SpecError(f"{path}.{key}", "must be a mapping")
    return v


def load_climb_settings(path: str | pathlib.Path | None = None) -> ClimbSettings:
    path = pathlib.Path(path) if path is not None else project_root() / "config" / "climb.yaml"
    try:
        doc = yaml.safe_load(path.read_text())
    except OSError as exc:
        raise SpecError("climb_settings", f"cannot read {path}: {exc}") from None
    root = _block(doc, "climb", str(path.name))
    run = _block(root, "run", "climb")
    plan = _block(root, "plan", "climb")
    record = _block(root, "record", "climb")
    judge = _block(root, "judge", "climb")
    snap = _block(root, "snapshots", "climb")
    overrides = root.get("controller_overrides") or {}
    compliance = root.get("compliance_overrides") or {}
    planner = root.get("planner_overrides") or {}
    scene_planner = root.get("scene_planner_overrides") or {}
    if not isinstance(overrides, dict) or not isinstance(compliance, dict) or not isinstance(planner, dict):
        raise SpecError("climb.controller_overrides", "must be mappings of dotted parameter names")
    if not isinstance(scene_planner, dict):
        raise SpecError("climb.scene_planner_overrides", "must be a mapping of dotted planner settings")
    steep = root.get("steep_ladder") or {}
    if not isinstance(steep, dict) or not isinstance(steep.get("planner_overrides") or {}, dict):
        raise SpecError("climb.steep_ladder", "must be a mapping with min_incline_deg and planner_overrides")
    if steep:
        _num(steep, "min_incline_deg", "climb.steep_ladder")
    return ClimbSettings(
        extra_time_s=_num(run, "extra_time_s", "climb.run"),
        settle_time_s=_num(run, "settle_time_s", "climb.run"),
        failure_recovery_s=_num(run, "failure_recovery_s", "climb.run") if "failure_recovery_s" in run else 3.0,
        plan_joint_limit_margin=_num(plan, "joint_limit_margin", "climb.plan"),
        controller_overrides=dict(overrides), compliance_overrides=dict(compliance), planner_overrides=dict(planner),
        scene_planner_overrides=dict(scene_planner), steep_ladder=dict(steep),
        bag_rate_hz=_num(record, "bag_rate_hz", "climb.record", positive=True),
        log_rate_hz=_num(record, "log_rate_hz", "climb.record", positive=True),
        foot_force_min=_num(judge, "foot_force_min", "climb.judge"),
        cone_tolerance=_num(judge, "cone_tolerance", "climb.judge"),
        cone_force_min=_num(judge, "cone_force_min", "climb.judge"),
        snapshot_count=int(_num(snap, "count", "climb.snapshots", positive=True)),
        snapshot_width=int(_num(snap, "width", "climb.snapshots", positive=True)),
        snapshot_height=int(_num(snap, "height", "climb.snapshots", positive=True)),
        camera_distance=_num(snap, "camera_distance", "climb.snapshots", positive=True),
        camera_yaw_deg=float(snap.get("camera_yaw_deg", 60.0)),
        camera_pitch_deg=float(snap.get("camera_pitch_deg", -10.0)),
    )


def apply_planner_overrides(settings, overrides: dict):
    """planner_node settings with dotted ``section.field`` values replaced, each checked like the
    planner's YAML (SpecError ``climb.planner_overrides.<key>`` names an unknown field or a bad value)."""
    from planner_node.settings import apply_overrides

    return apply_overrides(settings, overrides, where="climb.planner_overrides")
