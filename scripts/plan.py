#!/usr/bin/env python3
"""Plan a ladder climb or a scene, print the JSON summary: motion primitive adaptation under the
multi-step search (the ladder paper), or with --strategy search the free-flyer guide path and the
best-first contact search (the DARPA-tasks paper), then the adaptation.

    scripts/plan.py --scenario default --robot g1 --steps 2 [--timeout 120] [--seed 0] [--out plan.json]
    scripts/plan.py --scenario default --strategy search --start ladder_4_contacts --steps 3

--scenario (alias --ladder) is a name in config/ladders/ or config/scenes/, or a scenario file
(shared/specs/ladder_spec.md, scene_spec.md). The last line on standard output is one JSON object
(ladder_spec.md "Results"; a scene adds scene, goal_reached, goal_distance_m, contacts_used); a
malformed spec or option, or a scene without a ladder with a strategy other than `search`, prints
`error: <field>: <rule>` on standard error and exits with code 2; a climb that could not be
planned exits with 1 (the summary's failure_reason names the constraint that stopped it).
"""
from __future__ import annotations

import argparse
import pathlib
import sys

from climb_core.ros_env import apply_local_dds_env

apply_local_dds_env()  # DDS stays on this machine (loopback profile, private domain)
import time

ROOT = pathlib.Path(__file__).resolve().parents[1]


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenario", "--ladder", dest="scenario", default="default",
                    help="scenario: name in config/ladders/ or config/scenes/, or a YAML file (--ladder: alias)")
    ap.add_argument("--robot", default="g1", help="robot config name (config/robots/<name>.yaml)")
    ap.add_argument("--steps", type=int, default=2, help="climbing cycles after the mount (feet end on rung N)")
    ap.add_argument("--timeout", type=float, default=None, help="planning wall-time limit [s] (default: config)")
    ap.add_argument("--seed", type=int, default=None, help="random seed (default: config)")
    ap.add_argument("--strategy", default=None,
                    help="search: the DARPA-tasks paper's free-flyer guide path + best-first contact search "
                         "(ladders and scenes); otherwise a primitive library (e.g. forward); default: chosen for the "
                         "scenario (scenes and walked ladders such as stairs: search; else config's library), "
                         "the reason in the summary's strategy_reason")
    ap.add_argument("--start", default=None, help="start stance fixture (default: the library's, standing)")
    ap.add_argument("--out", default=None, help="write the whole-body plan (JSON) to this file")
    ap.add_argument("--verify", action="store_true", help="re-check the plan at 4x the discretisation")
    ap.add_argument("--set", action="append", default=[], metavar="GROUP.FIELD=VALUE",
                    help="override a planner setting of config/planner.yaml (repeatable), e.g. "
                         "--set planning.sole_cop_margin=0.02")
    ap.add_argument("--descend", action="store_true",
                    help="plan the climb and then the climb back down (its cycles reversed): feet end on the ground")
    return ap


def summary_base(args: argparse.Namespace) -> dict:
    summary = {"success": False, "failure_reason": "", "robot": args.robot, "ladder": args.scenario,
               "rungs_requested": args.steps, "rungs_reached": 0, "plan_time_s": 0.0, "n_stances": 0,
               "sim_time_s": 0.0, "fell": False, "control_tick_ms": None, "bag": ""}
    summary.update(scene_base(args.scenario))
    return summary


def scene_base(source: str) -> dict:
    """The scene fields of a summary before planning (nothing reached); {} for a ladder or a bad spec."""
    from climb_core.errors import SpecError
    from climb_core.ladder import load_scenario

    try:
        scenario = load_scenario(source)
    except SpecError:
        return {}
    if scenario.scene is None:
        return {}
    out: dict = {"scene": scenario.name, "contacts_used": []}
    if scenario.scene.goal is not None:
        out.update(goal_reached=False, goal_distance_m=None)
    if scenario.ladder is None:
        out.update(rungs_requested=0)
    return out


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    from climb_core.errors import ClimbError, SpecError
    from planner_node.plan_io import summary_line

    summary = summary_base(args)
    t0 = time.perf_counter()
    try:
        if args.steps < 0:
            raise SpecError("steps", f"must be >= 0, got {args.steps}")
        if args.timeout is not None and not args.timeout > 0:
            raise SpecError("timeout", f"must be > 0 [s], got {args.timeout}")
        result, extra = run(args)
    except SpecError as exc:
        print(f"error: {exc}", file=sys.stderr)
        summary["failure_reason"] = f"spec: {exc}"
        print(summary_line(summary))
        return 2
    except ClimbError as exc:
        print(f"error: {exc}", file=sys.stderr)
        summary["failure_reason"] = str(exc)
        summary["plan_time_s"] = round(time.perf_counter() - t0, 3)
        print(summary_line(summary))
        return 1
    s = result.summary()
    summary.update({k: s[k] for k in ("success", "failure_reason", "plan_time_s", "n_stances", "rungs_reached")})
    summary.update({k: v for k, v in s.items() if k not in summary})
    summary.update(extra)
    print(summary_line(summary))
    return 0 if summary["success"] else 1


def scene_fields(scenario, result) -> dict:
    """The scene's summary fields (scene_spec.md "Results") of a plan result."""
    import numpy as np

    plan = result.plan
    contacts: set[str] = set()
    q_last = None
    if plan is not None:
        stances = [plan.initial_stance] + [t.target_stance for t in plan.transitions]
        contacts = {h.env_surface for stance in stances for h in stance.holds}
        q_last = plan.transitions[-1].path[-1] if plan.transitions else None
    out: dict = {"scene": scenario.name, "contacts_used": sorted(contacts)}
    goal = scenario.scene.goal
    if goal is not None:
        distance = None if q_last is None else float(np.linalg.norm(np.asarray(q_last[:3]) - goal.base_position))
        out["goal_distance_m"] = None if distance is None else round(distance, 4)
        out["goal_reached"] = bool(result.success and distance is not None and distance <= goal.tolerance)
    if scenario.ladder is None:  # no rungs: success is reaching the goal
        out.update(rungs_requested=0, rungs_reached=0, success=out["goal_reached"])
        if result.success and not out["goal_reached"]:
            out["failure_reason"] = (f"goal not reached: the plan ends with the base {out['goal_distance_m']} m "
                                     f"from goal.base_position (tolerance {goal.tolerance} m)")
    return out


def _reason(args: argparse.Namespace) -> dict:
    """The summary's ``strategy_reason`` when the strategy was chosen for the scenario."""
    reason = getattr(args, "strategy_reason", "")
    return {"strategy_reason": reason} if reason else {}


def run(args: argparse.Namespace):
    import dataclasses

    from climb_core import fixtures
    from climb_core.environment import build_environment
    from climb_core.ladder import load_scenario
    from climb_core.robot import load_robot
    from climb_core.scene import require_search_strategy
    from planner_node import plan_io
    from planner_node.climb_planner import plan_climb
    from planner_node.primitives import load_library
    from planner_node.settings import (apply_overrides, choose_strategy, load_settings, parse_overrides,
                                       scenario_settings)

    # the scenario file's own planner_overrides, then --set on top
    scenario = load_scenario(args.scenario)
    settings = scenario_settings(load_settings(), scenario)
    settings = apply_overrides(settings, parse_overrides(args.set), where="--set")
    if not args.strategy:  # chosen for the scenario (a scene, stairs: search), the reason in the summary
        chosen, args.strategy_reason = choose_strategy(scenario, settings)
        args.strategy = "search" if chosen == "search" else settings.planning.strategy
        print(f"strategy {args.strategy}: {args.strategy_reason}", file=sys.stderr)
    if args.strategy == "search":
        return run_search(args, settings, scenario)
    if args.strategy:
        settings = dataclasses.replace(settings, planning=dataclasses.replace(settings.planning,
                                                                              strategy=args.strategy))
    require_search_strategy(scenario, settings.planning.strategy)
    env = build_environment(scenario)
    robot = load_robot(args.robot)
    library = load_library(robot.config.name, settings.planning.strategy, settings.planning.primitives_dir,
                           nq=robot.model.nq)
    start = None
    if args.start:
        stance, q = fixtures.get(args.start, robot, env)
        start = (q, stance)
    planner = plan_climb
    if args.descend:
        from planner_node.descend import up_and_down as planner
    # the strategy's libraries, nearest reference ladder first (library.yaml: the start fixture)
    result = planner(robot, env, args.steps, settings=settings, start=start,
                     seed=args.seed, timeout_s=args.timeout)
    extra: dict = {"strategy": settings.planning.strategy, **_reason(args)}
    if args.descend and result.success:
        extra["descent_start_transition"] = int(result.stats["descent_start"])
    if scenario.scene is not None:
        extra.update(scene_fields(scenario, result))
    if args.out and result.plan is not None:
        path = plan_io.save_plan(args.out, result.plan, {
            "ladder": args.scenario, "robot": args.robot, "steps": args.steps, "seed": args.seed,
            "summary": result.summary(), "subtasks": result.subtasks})
        extra["plan_file"] = str(path)
    if args.verify and result.plan is not None:
        from planner_node.verify import verify_plan

        q_start = start[0] if start else fixtures.get(library.initial_fixture, robot, env)[1]
        rep = verify_plan(robot, env, result.plan, q_start=q_start, refine=4,
                          goal_feet_rung=args.steps if result.success and not args.start and not args.descend
                          else None)
        extra["verified"] = rep.ok and (not args.descend or rep.goal_feet_rungs == (0, 0))
        extra["verify"] = rep.summary()
    return result, extra


def run_search(args: argparse.Namespace, settings, scenario):
    """``--strategy search``: guide path -> best-first contact search -> adaptation
    (planner_node.pipeline), from ``--start`` (default: standing at the scenario's start pose);
    the feet end on rung ``--steps`` of a ladder, or the base at a scene's goal."""
    from climb_core import fixtures
    from climb_core.environment import build_environment
    from climb_core.errors import SpecError
    from climb_core.robot import load_robot
    from planner_node import pipeline

    if args.descend:
        raise SpecError("descend", "not with strategy search (a searched plan goes to its goal)")
    env = build_environment(scenario)
    robot = load_robot(args.robot)
    start = None
    if args.start:
        stance, q = fixtures.get(args.start, robot, env)
        start = (q, stance)
    request = pipeline.PlanRequest(id="plan.py", robot=robot.config.name, scenario=scenario.name or "custom",
                                   rungs=max(1, args.steps), seed=args.seed, timeout_s=args.timeout, strategy="search")
    problem = pipeline.Problem(request, robot, scenario, env, None, settings, start=start)
    t0 = time.perf_counter()
    guide = pipeline.guide_path(problem, strategy="search")
    contacts, result, _ = pipeline.search_and_adapt(problem, guide.product)
    # the whole pipeline's wall time (the result's own is the last adaptation round's)
    extra: dict = {"plan_time_s": round(time.perf_counter() - t0, 3), "adaptation_time_s": round(result.plan_time_s, 3),
                   "strategy": "search", **_reason(args), "guide_path": guide.summary,
                   "contact_search": {k: v for k, v in contacts.summary.items() if k != "moves"},
                   "moves": contacts.summary["moves"]}
    if scenario.scene is not None:
        extra.update(scene_fields(scenario, result))
    if args.out and result.plan is not None:
        from planner_node import plan_io

        extra["plan_file"] = str(plan_io.save_plan(args.out, result.plan, {
            "ladder": args.scenario, "robot": args.robot, "steps": args.steps, "seed": args.seed,
            "strategy": "search", "summary": result.summary(), "subtasks": result.subtasks}))
    return result, extra


if __name__ == "__main__":
    sys.exit(main())
