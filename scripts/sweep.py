#!/usr/bin/env python3
"""Run a ladder grid (default ../shared/bench/ladder_grid.yaml, the paper's 336 ladders): plan every
ladder, write a CSV (one row per ladder, with the constraint that stopped each failure) and heat
maps (success like the paper's Fig. 9, and planning time).

    scripts/sweep.py [--grid FILE] [--robot g1] [--workers 2] [--timeout 120] [--steps 2]
                     [--ladders 70/0.20,90/0.35] [--out-dir build/sweep] [--backend local|ray] [--resume]
                     [--execute]

With ``--execute`` every ladder is planned as a climb plans it (config/climb.yaml's planner
overrides) and each plan is executed in the simulator (in process, lock-step, QP, one period of
actuation latency: climb_coordinator.sweep_execute): the CSV gains the execution's columns, the
PNG the executed map beside the planned one, the summary executed success over the grid and
over the planned ladders.

Workers are pluggable: local processes by default; ``--backend ray`` sends the same tasks to an
existing Ray cluster (``--ray-address``, default: the RAY_ADDRESS variable or a local instance).
Every finished ladder is appended to ``<name>.partial.csv`` at once (a killed sweep keeps what it
measured, and its local workers die with it, SIGKILL included); ``--resume`` reuses that journal's rows planned by the same code (src, config and scripts as
committed; a commit of docs or tests keeps the rows), robot, steps, timeout and seed (and, with
``--execute``, executed), and plans only the other ladders.
The last line on standard output is a JSON summary (success rate, median planning time, failures
by category, the CSV and PNG paths).
"""
from __future__ import annotations

import argparse
import json
import pathlib
import sys

from climb_core.ros_env import apply_local_dds_env

apply_local_dds_env()  # DDS stays on this machine (loopback profile, private domain)
import time

ROOT = pathlib.Path(__file__).resolve().parents[1]
DEFAULT_GRID = ROOT.parent / "shared" / "bench" / "ladder_grid.yaml"


def parse_ladders(text: str) -> list[tuple[float, float]]:
    from climb_core.errors import SpecError

    out = []
    for item in filter(None, (x.strip() for x in text.split(","))):
        try:
            inc, sp = item.split("/")
            out.append((float(inc), float(sp)))
        except ValueError:
            raise SpecError("ladders", f"expected inclination/spacing pairs like 75/0.25, got {item!r}") from None
    return out


class Progress:
    """A one-line text progress bar on standard error."""

    def __init__(self, total: int, stream=sys.stderr, width: int = 30):
        self.total, self.stream, self.width = total, stream, width
        self.done = self.ok = 0
        self.t0 = time.monotonic()

    def update(self, row: dict) -> None:
        self.done += 1
        self.ok += bool(row.get("success"))
        frac = self.done / max(self.total, 1)
        elapsed = time.monotonic() - self.t0
        eta = elapsed / self.done * (self.total - self.done) if self.done else 0.0
        bar = "#" * int(frac * self.width) + "-" * (self.width - int(frac * self.width))
        self.stream.write(f"\r[{bar}] {self.done}/{self.total} ok {self.ok} "
                          f"({100 * self.ok / self.done:.0f} %) eta {eta / 60:.1f} min   ")
        if self.done == self.total:
            self.stream.write("\n")
        self.stream.flush()


def task_runner(execute: bool):
    """What a worker runs for one task: plan (planner_node.sweep), or plan and execute."""
    if execute:
        from climb_coordinator.sweep_execute import run_task
    else:
        from planner_node.sweep import run_task
    return run_task


def run_local(tasks, workers: int, progress: Progress, done, execute: bool = False) -> list[dict]:
    """``done(row)`` is called in this process as each row arrives (stamps and journals it).
    The workers die with this process, SIGKILL included (:func:`climb_core.process.die_with_parent`:
    otherwise a killed sweep leaves them planning for an hour with nobody to take their rows)."""
    run_task = task_runner(execute)

    rows = []
    if workers <= 1:
        for t in tasks:
            rows.append(done(run_task(t)))
            progress.update(rows[-1])
        return rows
    import concurrent.futures as cf
    import multiprocessing as mp

    from climb_core.process import die_with_parent

    with cf.ProcessPoolExecutor(max_workers=workers, mp_context=mp.get_context("spawn"),
                                initializer=die_with_parent) as pool:
        futures = [pool.submit(run_task, t) for t in tasks]
        for fut in cf.as_completed(futures):
            rows.append(done(fut.result()))
            progress.update(rows[-1])
    return rows


def run_ray(tasks, address: str | None, progress: Progress, done, execute: bool = False) -> list[dict]:
    import os

    address = address or os.environ.get("RAY_ADDRESS") or None
    if not address:
        # a local instance: every Ray process binds and advertises 127.0.0.1 only (Ray's single-host
        # mode; otherwise its gRPC servers listen on all interfaces and the agent on the host's IP)
        os.environ["RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER"] = "0"
    try:
        import ray
    except ImportError:
        from climb_core.errors import SpecError

        raise SpecError("backend", "ray is not installed: install it (pip install 'ray[default]') to use "
                                   "--backend ray, or use the default local backend") from None
    run_task = task_runner(execute)

    options = dict(ignore_reinit_error=True, log_to_driver=False,
                   runtime_env={"env_vars": {"CLIMB_ROOT": str(ROOT)}})
    if address:  # an existing cluster: its own network settings apply
        ray.init(address=address, **options)
    else:  # a local instance for this run: loopback only, no dashboard, stopped at exit
        ray.init(_node_ip_address="127.0.0.1", include_dashboard=False, **options)
    remote = ray.remote(run_task)
    pending = [remote.remote(t) for t in tasks]
    rows = []
    while pending:
        ready, pending = ray.wait(pending, num_returns=1)
        rows.append(done(ray.get(ready[0])))
        progress.update(rows[-1])
    return rows


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--grid", default=str(DEFAULT_GRID))
    ap.add_argument("--robot", default="g1")
    ap.add_argument("--strategy", default="", help="primitive library (default: config/planner.yaml)")
    ap.add_argument("--steps", type=int, default=None, help="default: the grid file's")
    ap.add_argument("--timeout", type=float, default=None, help="[s] per ladder; default: the grid file's")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--workers", type=int, default=2, help="local worker processes")
    ap.add_argument("--ladders", default="", help="only these grid points: 70/0.20,90/0.35,...")
    ap.add_argument("--out-dir", default=str(ROOT / "build" / "sweep"))
    ap.add_argument("--name", default="", help="file stem (default: <robot>_<strategy or default>)")
    ap.add_argument("--backend", choices=("local", "ray"), default="local")
    ap.add_argument("--ray-address", default=None)
    ap.add_argument("--resume", action="store_true",
                    help="reuse the rows of <name>.partial.csv planned by the same code and settings")
    ap.add_argument("--execute", action="store_true",
                    help="also execute every planned ladder in the simulator (planned as a climb plans it)")
    args = ap.parse_args(argv)

    from climb_core.errors import SpecError
    from planner_node import sweep

    try:
        grid = sweep.load_grid(args.grid)
        select = parse_ladders(args.ladders) if args.ladders else None
        tasks = sweep.make_tasks(grid, args.robot, args.steps, args.timeout, args.seed, args.strategy, select,
                                 execute=args.execute)
        if args.workers < 1:
            raise SpecError("workers", f"must be >= 1, got {args.workers}")
        stem = args.name or f"{args.robot}_{args.strategy or 'default'}"
        out = pathlib.Path(args.out_dir)
        version = sweep.code_version(ROOT)
        journal = sweep.Journal(out / f"{stem}.partial.csv")
        reused, stale = journal.reusable(tasks, version) if args.resume else ([], 0)
        if args.resume:
            print(f"resume: {len(reused)} ladders reused from {journal.path}"
                  + (f" ({stale} rows of other code or settings ignored)" if stale else ""), file=sys.stderr)
        journal.start(reused)
        finished = {sweep.grid_point(r["inclination_deg"], r["rung_spacing"]) for r in reused}
        todo = [t for t in tasks if t.point not in finished]

        def done(row: dict) -> dict:
            row["code_version"] = version
            journal.append(row)
            return row

        progress = Progress(len(todo))
        t0 = time.monotonic()
        rows = reused + (run_ray(todo, args.ray_address, progress, done, args.execute) if args.backend == "ray"
                         else run_local(todo, args.workers, progress, done, args.execute))
    except SpecError as exc:
        print(f"error: {exc}", file=sys.stderr)
        print(json.dumps({"success": False, "failure_reason": f"spec: {exc}"}))
        return 2
    csv_path = sweep.write_csv(rows, out / f"{stem}.csv")
    journal.close()
    png_path = sweep.heat_maps(rows, out / f"{stem}.png",
                               title=f"{args.robot}: {tasks[0].steps}-step climbs, {tasks[0].timeout_s:g} s cutoff"
                                     + (", planned and executed" if args.execute else ""))
    stats = sweep.statistics(rows)
    stats.update(csv=str(csv_path), png=str(png_path), wall_time_s=round(time.monotonic() - t0, 1),
                 robot=args.robot, backend=args.backend, workers=args.workers, reused=len(reused),
                 code_version=version)
    print(json.dumps(stats))
    return 0


if __name__ == "__main__":
    sys.exit(main())
