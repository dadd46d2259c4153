#!/usr/bin/env python3
"""Benchmark of the ladder planner: plan_climb on the default ladder and a few fixed grid ladders.

For each ladder: --runs plans (fresh environment each, seed 0, 2 steps), the median wall and CPU
time, the feasibility checks per second, and the split of the search time between the contact
IK (Algorithm 1), the physics-constrained IK and the path checks (AdaptStats of the result).
Baseline measured in the same run: the configurations of the default ladder's plan re-checked
with the planner's feasibility check as it runs (bounding-volume culling before the coal hull
distances) and with the culling disabled (every one of the ~1466 hull pairs through coal).
Then the DARPA-tasks paper's planners (``strategy: search``): the free-flyer guide path of the
default ladder (3 rungs) and of narrow_passage (best of 3), and the best-first contact search of
3 rungs of the default ladder from standing on the ground, through the guide path's milestones,
with the primitive library made unloadable (no hints): its time, nodes expanded, IK calls and IK
calls per second (--search-runs runs, the median; --no-search skips it).
The last line is one JSON object (units in the keys).

    .venv/bin/python scripts/bench_planner.py [--runs 3] [--ladders default,72/0.23,70/0.32] [--timeout 120]
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import pathlib
import statistics
import sys

from climb_core.ros_env import apply_local_dds_env

apply_local_dds_env()  # DDS stays on this machine (loopback profile, private domain)
import time

ROOT = pathlib.Path(__file__).resolve().parents[1]
GRID = ROOT.parent / "shared" / "bench" / "ladder_grid.yaml"
DEFAULT_LADDERS = "default,72/0.23,70/0.32"


def scenario_of(ladder: str, grid_file: pathlib.Path):
    """The scenario of a ladder name (config/ladders) or of a grid point "<incl_deg>/<spacing_m>"
    (built as scripts/sweep.py builds it)."""
    from climb_core.errors import SpecError
    from climb_core.ladder import load_scenario, parse_scenario
    from planner_node.sweep import load_grid, make_tasks

    if "/" not in ladder:
        return load_scenario(ladder)
    try:
        incl, spacing = (float(x) for x in ladder.split("/"))
    except ValueError as exc:
        raise SpecError("ladders", f"a grid point is <inclination_deg>/<rung_spacing_m>, got {ladder!r}") from exc
    (task,) = make_tasks(load_grid(grid_file), "g1", select=[(incl, spacing)])
    return parse_scenario(task.spec, name=task.name)


def plan_once(robot, ladder: str, args, settings) -> dict:
    from climb_core.environment import build_environment
    from planner_node.climb_planner import plan_climb

    env = build_environment(scenario_of(ladder, args.grid))  # a fresh environment: fresh distance caches
    t0, c0 = time.perf_counter(), time.process_time()
    res = plan_climb(robot, env, args.steps, settings=settings, seed=0, timeout_s=args.timeout)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    st = res.stats
    return {"wall_s": wall, "cpu_s": cpu, "success": res.success, "failure": res.failure_constraint,
            "attempts": res.report.n_attempts if res.report else 0, "checks": st.get("checks", 0),
            "time_check_s": st.get("time_check_s", 0.0), "time_ik_s": st.get("time_ik_s", 0.0),
            "time_pcik_s": st.get("time_pcik_s", 0.0), "pcik_calls": st.get("pcik_calls", 0),
            "search_s": st.get("search_s", wall), "result": res, "env": env}


def check_baseline(robot, env, plan, settings, max_configs: int) -> dict:
    """ms per feasibility check of the plan's configurations, culled vs every pair through coal."""
    from climb_core import feasibility

    frozen = feasibility.load_config()
    p = settings.planning
    cfg = feasibility.with_check(frozen, collision_margin=max(frozen.check.collision_margin, p.collision_margin),
                                 torque_limit_fraction=min(frozen.check.torque_limit_fraction,
                                                           p.torque_limit_fraction))
    no_cull = dataclasses.replace(cfg, collision=dataclasses.replace(cfg.collision, cull_distance=1.0e6))
    items = [(q, t.stance) for t in plan.transitions for q in t.path]
    step = max(1, len(items) // max_configs)
    items = items[::step][:max_configs]
    out = {"configs": len(items)}
    for name, c in (("culled", cfg), ("no_cull", no_cull)):
        feasibility.check(robot, env, items[0][0], items[0][1], c)  # build the checker outside the timing
        c0 = time.process_time()
        n_feasible = sum(feasibility.check(robot, env, q, s, c).feasible for q, s in items)
        out[name] = 1e3 * (time.process_time() - c0) / len(items)
        out[name + "_feasible"] = n_feasible
    return out


def search_figures(robot, runs: int) -> dict:
    """Guide path and contact search figures (``strategy: search``, G1, default ladder 3 rungs)."""
    from climb_core import fixtures
    from climb_core.environment import build_environment
    from planner_node import contact_search, guide_path, primitives

    out = dict(guide_path.bench_figures())
    env = build_environment("default")
    stance0, q0 = fixtures.get("standing", robot, env)
    path = guide_path.plan_for_environment(robot, env, q0, rungs=3).path

    def no_library(*args, **kwargs):
        raise RuntimeError("the contact search read the primitive library")

    real, primitives.load_library = primitives.load_library, no_library
    try:
        rows = []
        for _ in range(runs):
            t0 = time.perf_counter()
            res = contact_search.search(robot, env, q0, stance0, path)
            rows.append((time.perf_counter() - t0, res.stats))
    finally:
        primitives.load_library = real
    wall = statistics.median(r[0] for r in rows)
    st = rows[len(rows) // 2][1]
    print(f"guide path: default ladder 3 rungs {out['guide_path_default_s']:.3f} s, narrow_passage "
          f"{out['guide_path_narrow_passage_s']:.3f} s | contact search 3 rungs (no primitives, {len(path.milestones)} "
          f"milestones): median {wall:.1f} s over {runs}, {st.nodes_expanded} nodes expanded, {st.ik_calls} IK calls, "
          f"{st.ik_calls_per_s:.1f} IK calls/s", flush=True)
    out.update(contact_search_3_rungs_s=round(wall, 2), contact_search_nodes_expanded=st.nodes_expanded,
               contact_search_ik_calls=st.ik_calls, contact_search_ik_calls_per_s=round(st.ik_calls_per_s, 2))
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--runs", type=int, default=3, help="plans per ladder (the medians are over these)")
    ap.add_argument("--ladders", default=DEFAULT_LADDERS,
                    help="comma list: ladder names (config/ladders) or grid points <incl_deg>/<spacing_m>")
    ap.add_argument("--robot", default="g1")
    ap.add_argument("--steps", type=int, default=2, help="climbing cycles after the mount")
    ap.add_argument("--timeout", type=float, default=120.0, help="planning wall-time limit per plan [s]")
    ap.add_argument("--grid", type=pathlib.Path, default=GRID, help="grid file (its `base` scenario)")
    ap.add_argument("--search-runs", type=int, default=3, help="contact searches (the median is over these)")
    ap.add_argument("--no-search", action="store_true", help="skip the guide path / contact search figures")
    ap.add_argument("--baseline-configs", type=int, default=300,
                    help="configurations of the first ladder's plan re-checked for the baseline")
    args = ap.parse_args(argv)
    if args.runs < 1:
        print("error: runs: must be >= 1", file=sys.stderr)
        return 2

    from climb_core.robot import load_robot
    from planner_node.settings import load_settings

    robot = load_robot(args.robot)
    settings = load_settings()
    summary: dict = {}
    first_plan = None
    grid_cpu = []
    for ladder in [s.strip() for s in args.ladders.split(",") if s.strip()]:
        runs = [plan_once(robot, ladder, args, settings) for _ in range(args.runs)]
        last = runs[-1]
        if first_plan is None and last["result"].plan is not None:
            first_plan = (last["env"], last["result"].plan, ladder)
        wall = statistics.median(r["wall_s"] for r in runs)
        cpu = statistics.median(r["cpu_s"] for r in runs)
        t_chk = sum(r["time_check_s"] for r in runs)
        rate = sum(r["checks"] for r in runs) / t_chk if t_chk > 0 else 0.0
        search = sum(r["search_s"] for r in runs) or 1.0
        split = {k: sum(r[f"time_{k}_s"] for r in runs) / search for k in ("ik", "pcik", "check")}
        print(f"{ladder:>10}: success {last['success']} {last['failure'] or ''} attempts {last['attempts']} "
              f"checks {last['checks']} pcik {last['pcik_calls']} | wall median {wall:.2f} s, CPU median {cpu:.2f} s "
              f"| {rate:.0f} checks/s (wall) | search split: IK {100 * split['ik']:.0f} %, PCIK "
              f"{100 * split['pcik']:.0f} %, checks {100 * split['check']:.0f} % (wall)", flush=True)
        key = ladder.replace("/", "_")
        summary[f"{key}_plan_wall_median_s"] = round(wall, 3)
        summary[f"{key}_plan_cpu_median_s"] = round(cpu, 3)
        summary[f"{key}_checks_per_s"] = round(rate, 1)
        summary[f"{key}_attempts"] = last["attempts"]
        summary[f"{key}_success"] = bool(last["success"])
        if "/" in ladder:
            grid_cpu.append(cpu)
    if grid_cpu:
        summary["grid_plan_cpu_median_s"] = round(statistics.median(grid_cpu), 3)
    if first_plan is not None:
        env, plan, ladder = first_plan
        b = check_baseline(robot, env, plan, settings, args.baseline_configs)
        print(f"baseline ({ladder} plan, {b['configs']} configurations): feasibility check {b['culled']:.3f} ms CPU "
              f"with culling, {b['no_cull']:.3f} ms with every hull pair through coal "
              f"(feasible {b['culled_feasible']} / {b['no_cull_feasible']})")
        summary["check_cpu_ms"] = round(b["culled"], 4)
        summary["check_no_cull_cpu_ms"] = round(b["no_cull"], 4)
    if not args.no_search:
        summary.update(search_figures(robot, max(1, args.search_runs)))
    print(json.dumps(summary))
    return 0


if __name__ == "__main__":
    sys.exit(main())
