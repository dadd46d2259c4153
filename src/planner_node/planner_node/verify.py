"""Independent re-check of a whole-body plan with the core feasibility check.

:func:`verify_plan` re-runs :func:`climb_core.feasibility.check` (the frozen config/feasibility.yaml
settings by default, not the planner's margins) on every configuration of the plan *and* on
``refine - 1`` configurations interpolated between consecutive ones (``refine = 4``: 4x the
planner's discretisation), and checks what a controller relies on:

- joint continuity: each transition starts exactly where the previous one ended (the first one
  at the start configuration), and no step between consecutive configurations exceeds the
  planner's ``max_step`` (same norm as the planner);
- contact drift: the worst distance between a held limb and its hold over the whole plan;
- stances: a configuration is checked on the holds kept during its transition; the first and last
  configurations of a transition also on the stance before / after it; the moving limb may touch
  the surface it leaves / reaches only inside the release / approach zone
  (:func:`planner_node.adapt.zone_exclusions`);
- timing: times start at 0, increase, and respect the planner's speed limits;
- the goal stance (optional): both feet on rung >= ``goal_feet_rung`` at the end.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pinocchio as pin

from climb_core import feasibility
from climb_core.contact import FEET, Stance, WholeBodyPlan

from . import interpolation as interp
from . import pcik
from .adapt import AdaptContext, rung_index, zone_exclusions
from .settings import PlannerSettings, load_settings


@dataclass
class VerifyReport:
    n_checked: int = 0
    failures: list[tuple[int, int, str]] = field(default_factory=list)  # (transition, sample, violated)
    max_contact_drift: float = 0.0  # [m] worst hold error of a kept limb
    max_step: float = 0.0  # [rad] largest step between consecutive plan configurations
    max_joint_speed: float = 0.0  # [rad/s]
    continuity_error: float = 0.0  # [rad] worst mismatch between consecutive transitions
    min_distance: float = float("inf")  # [m] smallest collision distance seen
    max_load_ratio: float = 0.0  # [-] worst torque / grip ratio seen
    goal_feet_rungs: tuple[int, int] = (0, 0)
    problems: list[str] = field(default_factory=list)  # non-feasibility problems (continuity, timing, goal)

    @property
    def ok(self) -> bool:
        return not self.failures and not self.problems

    def summary(self) -> str:
        first = "".join(f", transition {ti} sample {k}: {what or '?'}" for ti, k, what in self.failures[:2])
        state = "ok" if self.ok else f"{len(self.failures)} infeasible samples{first}, problems: {self.problems[:3]}"
        return (f"{state}; {self.n_checked} configurations checked; drift {self.max_contact_drift * 1e3:.2f} mm; "
                f"max step {self.max_step:.3f} rad; min distance {self.min_distance * 1e3:.1f} mm; "
                f"max load ratio {self.max_load_ratio:.2f}; feet on rungs {self.goal_feet_rungs}")


def verify_plan(robot: Any, env: Any, plan: WholeBodyPlan, *, q_start: np.ndarray | None = None,
                refine: int = 4, cfg: feasibility.FeasibilityConfig | None = None,
                settings: PlannerSettings | None = None, goal_feet_rung: int | None = None,
                max_failures: int = 20) -> VerifyReport:
    """Re-check ``plan`` (see the module docstring); never raises for an infeasible plan."""
    cfg = cfg or feasibility.load_config()
    settings = settings or load_settings()
    ctx = AdaptContext(robot, env, None, settings, cfg)  # zone rule + hold geometry only
    model = robot.model
    ip, tp = settings.interpolation, settings.timing
    rep = VerifyReport()
    prev_stance: Stance = plan.initial_stance
    prev_q = None if q_start is None else np.asarray(q_start, dtype=float)

    def check(q: np.ndarray, stance: Stance, limb: str, zone: list, ti: int, k: int) -> None:
        excl = zone_exclusions(ctx, q, limb, zone) if limb else []
        res = pcik.check_with_exclusions(robot, env, q, stance, cfg, extra_exclusions=excl)
        rep.n_checked += 1
        rep.max_contact_drift = max(rep.max_contact_drift, res.contact_error)
        rep.min_distance = min(rep.min_distance, res.min_distance)
        if np.isfinite(res.load_ratio):
            rep.max_load_ratio = max(rep.max_load_ratio, res.load_ratio)
        if not res.feasible and len(rep.failures) < max_failures:
            rep.failures.append((ti, k, ",".join(res.violated)))

    for ti, tr in enumerate(plan.transitions):
        path = np.asarray(tr.path, dtype=float)
        times = np.asarray(tr.times, dtype=float)
        if len(path) == 0:
            rep.problems.append(f"transition {ti}: empty path")
            continue
        if prev_q is not None:
            err = interp.step_norm(pin.difference(model, prev_q, path[0]))
            rep.continuity_error = max(rep.continuity_error, err)
            if err > 1e-6:
                rep.problems.append(f"transition {ti}: starts {err:.2e} rad away from the previous end")
        if len(times) != len(path) or abs(times[0]) > 1e-9 or np.any(np.diff(times) <= 0.0):
            rep.problems.append(f"transition {ti}: times must start at 0 and increase")
        limb = tr.moving_limb
        zone = [h for h in (prev_stance.hold(limb) if limb else None, tr.target_stance.hold(limb) if limb else None)
                if h is not None]
        # end points also on the stances around the transition
        check(path[0], prev_stance, "", [], ti, 0)
        check(path[-1], tr.target_stance, "", [], ti, (len(path) - 1) * refine)
        for i in range(len(path) - 1):
            dv = pin.difference(model, path[i], path[i + 1])
            step = interp.step_norm(dv, ip.base_scale)
            rep.max_step = max(rep.max_step, step)
            dt = times[i + 1] - times[i] if len(times) == len(path) else 0.0
            if dt > 0:
                rep.max_joint_speed = max(rep.max_joint_speed, float(np.abs(dv[6:]).max() / dt))
            for j in range(refine):
                q = path[i] if j == 0 else pin.interpolate(model, path[i], path[i + 1], j / refine)
                check(q, tr.stance, limb, zone, ti, i * refine + j)
        check(path[-1], tr.stance, limb, zone, ti, (len(path) - 1) * refine)
        if rep.max_step > ip.max_step * (1.0 + 1e-6):
            rep.problems.append(f"transition {ti}: step {rep.max_step:.3f} rad > max_step {ip.max_step}")
        prev_stance, prev_q = tr.target_stance, path[-1]
    if rep.max_joint_speed > tp.max_joint_speed * (1.0 + 1e-6):
        rep.problems.append(f"joint speed {rep.max_joint_speed:.3f} rad/s > {tp.max_joint_speed}")
    feet = tuple(rung_index(prev_stance.hold(f).env_surface) if prev_stance.hold(f) else -1 for f in FEET)
    rep.goal_feet_rungs = feet  # type: ignore[assignment]
    if goal_feet_rung is not None and min(feet) < goal_feet_rung:
        rep.problems.append(f"goal: feet on rungs {feet}, expected >= {goal_feet_rung}")
    return rep
