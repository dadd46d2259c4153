"""The executing ladder sweep (``scripts/sweep.py --execute``, issue 18): every grid ladder planned
as a climb plans it, and each plan executed in the simulator like ``scripts/climb.py`` executes it.

A task (:class:`planner_node.sweep.SweepTask`) is planned by :func:`planner_node.sweep.plan_task`
with the climb's planner settings (config/planner.yaml under config/climb.yaml's
``planner_overrides``: the torque headroom a climb plans with), then that very plan runs in
process, lock-step, QP, one control period of actuation latency (the controller's FSM and its
recoveries, replans from the same planner and settings). The row gains the execution's columns
(``executed`` and ``exec_*`` of ``planner_node.sweep.CSV_FIELDS``); a ladder that was not planned
is not executed (``executed`` False, ``exec_failure`` "not planned"). Never raises.
"""
from __future__ import annotations

import time

from planner_node.sweep import SweepTask, plan_task

#: one control period of latency: every command acts a period late, as through the graph
COMMAND_DELAY_TICKS = 1


def run_task(task: SweepTask) -> dict:
    """Plan one grid ladder, execute the plan: one CSV row."""
    from .settings import load_climb_settings

    cs = load_climb_settings()
    row, planned = plan_task(task, climb_plan_settings(task, cs))
    row.update(executed=False, exec_failure="", exec_rungs_reached=0, exec_fell=False, exec_replans=0,
               exec_qp_failures=0, exec_sim_time_s=0.0, exec_wall_time_s=0.0, exec_max_joint_error_rad=0.0,
               exec_max_joint_error_at="")
    res = planned.result
    if not row.get("success") or res is None or res.plan is None:
        row["exec_failure"] = "not planned"
        return row
    t0 = time.perf_counter()
    try:
        row.update(execute_plan(task, planned, cs))
    except Exception as exc:  # noqa: BLE001 - a run that raises is a failed execution, reported
        row.update(executed=False, exec_failure=f"error: {type(exc).__name__}: {exc}"[:300])
    row["exec_wall_time_s"] = round(time.perf_counter() - t0, 1)
    return row


def climb_plan_settings(task: SweepTask, cs):
    """The planner settings a climb of ``task``'s ladder plans with: config/planner.yaml, the climb's
    ``planner_overrides``, a steep ladder's (``climb.steep_ladder``), the spec's own; a spec that
    does not parse gets the first two (:func:`planner_node.sweep.plan_task` then reports it)."""
    from climb_core.errors import SpecError
    from climb_core.ladder import parse_scenario
    from planner_node.settings import load_settings, settings_for_scenario

    from .settings import apply_planner_overrides

    settings = apply_planner_overrides(load_settings(), dict(cs.planner_overrides))
    try:
        return settings_for_scenario(settings, parse_scenario(task.spec, name=task.name),
                                     scene_overrides=cs.scene_planner_overrides, steep=cs.steep_ladder)
    except SpecError:
        return settings


def execute_plan(task: SweepTask, planned, cs) -> dict:
    """Run ``planned``'s plan in a fresh simulator: the execution's columns."""
    from climb_core.ladder import parse_scenario
    from planner_node.primitives import load_library

    from .climb import ClimbRequest, GivenPlanSource, LibraryPlanSource, execute, validate

    scenario = parse_scenario(task.spec, name=task.name)
    p = planned.settings.planning
    library = load_library(planned.robot.config.name, p.strategy, p.primitives_dir, nq=planned.robot.model.nq)
    req = ClimbRequest(ladder=scenario, robot=task.robot, rungs=task.steps, mode="qp", bag=False, seed=task.seed,
                       plan_timeout_s=task.timeout_s, command_delay_ticks=COMMAND_DELAY_TICKS, strategy="primitives")
    validate(req)
    replans = LibraryPlanSource(req, planned.robot, planned.env, planned.settings, cs)
    source = GivenPlanSource(planned.result.plan, planned.robot, cs, replans)
    result = execute(req, source, cs, scenario, library.initial_fixture)
    try:
        s = result.summary
    finally:
        result.close()
    ok = bool(s.get("success"))
    return {"executed": ok, "exec_failure": "" if ok else str(s.get("failure_reason", ""))[:300],
            "exec_rungs_reached": int(s.get("rungs_reached", 0)), "exec_fell": bool(s.get("fell")),
            "exec_replans": len(s.get("replans") or []), "exec_qp_failures": int(s.get("qp_failures", 0)),
            "exec_sim_time_s": round(float(s.get("sim_time_s", 0.0)), 2),
            # how far the measured configuration ended from the plan, at the worst transition end
            "exec_max_joint_error_rad": float((s.get("tracking") or {}).get("max_joint_error_rad", 0.0)),
            "exec_max_joint_error_at": str((s.get("tracking") or {}).get("max_joint_error_at", ""))}
