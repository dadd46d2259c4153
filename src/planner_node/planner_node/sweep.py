"""The ladder sweep (ladder_climbing_drc_hubo.txt Fig. 9): grid file -> tasks -> CSV + heat maps.

A grid file (shared/bench/ladder_grid.yaml) has a ``base`` ladder spec, ``grid`` ranges for
``inclination_deg`` and ``rung_spacing`` (start, stop, step; inclusive), ``steps`` and
``timeout_s``. Every grid point is one task: plan a ``steps``-cycle climb of that ladder.
:func:`run_task` is what a worker runs (a local process or a Ray task): it returns one CSV row,
with the constraint that stopped a failed plan (``failure_constraint``: reach:<limb>,
torque_limit:<joint>, collision:<a>|<b>, friction, equilibrium, grip_limit:<limb>, time_limit ...)
and its category (the part before the colon).
"""
from __future__ import annotations

import copy
import csv
import math
import pathlib
import time
from dataclasses import dataclass
from typing import Any, Iterable

import numpy as np
import yaml

from climb_core.errors import SpecError

CSV_FIELDS = ("inclination_deg", "rung_spacing", "success", "plan_time_s", "plan_cpu_s", "failure_category",
              "failure_constraint", "frontier_constraint", "failure_detail", "rungs_reached", "n_stances", "attempts",
              "backtracks", "robot", "strategy", "steps", "timeout_s", "seed", "code_version",
              # a planned climb re-checked by the frozen feasibility check (planner_node.verify):
              # counted as success only if it passes
              "verified", "verify_s", "verify_detail",
              # --execute (climb_coordinator.sweep_execute): the planned climb executed in the simulator;
              # empty in a planning-only sweep
              "executed", "exec_failure", "exec_rungs_reached", "exec_fell", "exec_replans", "exec_qp_failures",
              "exec_sim_time_s", "exec_wall_time_s",
              # the worst transition end of the execution against the plan (controller event
              # transition_finished): the joint farthest from the plan's configuration [rad], where
              "exec_max_joint_error_rad", "exec_max_joint_error_at")


@dataclass(frozen=True)
class SweepTask:
    inclination_deg: float
    rung_spacing: float
    spec: dict  # full scenario dict
    robot: str
    steps: int
    timeout_s: float
    seed: int
    strategy: str = ""
    execute: bool = False  # also execute the plan in the simulator (climb_coordinator.sweep_execute)

    @property
    def point(self) -> tuple[float, float]:
        """The grid point (inclination [deg], spacing [m]) rounded for matching rows and selections."""
        return grid_point(self.inclination_deg, self.rung_spacing)

    @property
    def name(self) -> str:
        return f"incl{self.inclination_deg:g}_sp{self.rung_spacing:.2f}"


def grid_point(inclination_deg: float, rung_spacing: float) -> tuple[float, float]:
    return round(float(inclination_deg), 6), round(float(rung_spacing), 6)


def _range(field: str, r: Any) -> list[float]:
    try:
        start, stop, step = float(r["start"]), float(r["stop"]), float(r["step"])
    except (KeyError, TypeError, ValueError):
        raise SpecError(f"grid.{field}", "needs numeric start, stop and step") from None
    if not (step > 0 and stop >= start and all(math.isfinite(x) for x in (start, stop, step))):
        raise SpecError(f"grid.{field}", "needs step > 0 and stop >= start")
    n = int(round((stop - start) / step)) + 1
    return [round(start + k * step, 10) for k in range(n)]


def load_grid(path: str | pathlib.Path) -> dict:
    path = pathlib.Path(path)
    if not path.is_file():
        raise SpecError("grid", f"file {path} not found")
    try:
        data = yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        raise SpecError("grid", f"{path}: invalid YAML: {exc}") from None
    if not isinstance(data, dict) or "base" not in data or "grid" not in data:
        raise SpecError("grid", f"{path} needs `base` and `grid`")
    unknown = set(data["grid"]) - {"inclination_deg", "rung_spacing"}
    if unknown:
        raise SpecError("grid.grid", f"unknown axes {sorted(unknown)} (inclination_deg, rung_spacing)")
    return data


def make_tasks(grid: dict, robot: str, steps: int | None = None, timeout_s: float | None = None, seed: int = 0,
               strategy: str = "", select: Iterable[tuple[float, float]] | None = None,
               execute: bool = False) -> list[SweepTask]:
    incls = _range("inclination_deg", grid["grid"]["inclination_deg"])
    spacings = _range("rung_spacing", grid["grid"]["rung_spacing"])
    steps = int(grid.get("steps", 2) if steps is None else steps)
    timeout_s = float(grid.get("timeout_s", 120.0) if timeout_s is None else timeout_s)
    wanted = None if select is None else {grid_point(a, b) for a, b in select}
    tasks = []
    for inc in incls:
        for sp in spacings:
            if wanted is not None and grid_point(inc, sp) not in wanted:
                continue
            spec = copy.deepcopy(grid["base"])
            spec.setdefault("ladder", {})
            spec["ladder"]["inclination_deg"] = float(inc)
            spec["ladder"]["rung_spacing"] = float(sp)
            tasks.append(SweepTask(inc, sp, spec, robot, steps, timeout_s, seed, strategy, execute))
    if wanted is not None and len(tasks) != len(wanted):
        raise SpecError("ladders", "some selected (inclination, spacing) pairs are not grid points")
    return tasks


def code_version(root: str | pathlib.Path | None = None) -> str:
    """The version of the code a row was made with: a short hash of the git trees of src, config
    and scripts at HEAD (a commit of docs or tests keeps it: a long sweep resumes across such
    commits), ``+dirty`` when any of them differs from HEAD; a resumed sweep only reuses rows of
    the same version. ``unknown`` outside a git checkout."""
    import hashlib
    import subprocess

    from climb_core.ros_env import project_root

    root = pathlib.Path(root) if root is not None else project_root()
    dirs = ("src", "config", "scripts")
    try:
        trees = subprocess.run(["git", "rev-parse", *(f"HEAD:{d}" for d in dirs)], cwd=root, capture_output=True,
                               text=True, timeout=10, check=True).stdout.split()
        dirty = subprocess.run(["git", "status", "--porcelain", "--", *dirs], cwd=root,
                               capture_output=True, text=True, timeout=10, check=True).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return "unknown"
    return hashlib.sha1(" ".join(trees).encode()).hexdigest()[:10] + ("+dirty" if dirty else "")


def _same_run(row: dict, task: SweepTask, version: str) -> bool:
    try:
        return (row.get("robot") == task.robot and int(row.get("steps") or -1) == task.steps
                and float(row.get("timeout_s") or -1.0) == float(task.timeout_s) and int(row.get("seed") or -1) == task.seed
                and row.get("code_version") == version and (not task.strategy or row.get("strategy") == task.strategy)
                and (not task.execute or row.get("executed") not in ("", None)))
    except ValueError:
        return False


class Journal:
    """Rows appended to ``<stem>.partial.csv`` as they complete (flushed to disk each time), so a
    sweep that is killed or times out keeps what it measured; :meth:`reusable` hands them to a
    resumed run (``scripts/sweep.py --resume``)."""

    def __init__(self, path: str | pathlib.Path):
        self.path = pathlib.Path(path)

    def reusable(self, tasks: list[SweepTask], version: str) -> tuple[list[dict], int]:
        """Rows of the journal that match a task of this run (same grid point, robot, strategy,
        steps, timeout, seed and code version), and how many rows did not match."""
        if not self.path.is_file():
            return [], 0
        try:
            old = read_csv(self.path)
        except (OSError, KeyError, ValueError, csv.Error) as exc:
            raise SpecError("resume", f"{self.path} is not a sweep journal: {exc}") from None
        by_point = {t.point: t for t in tasks}
        keep, seen = [], set()
        for r in old:
            key = grid_point(r["inclination_deg"], r["rung_spacing"])
            t = by_point.get(key)
            if t is None or key in seen or not _same_run(r, t, version):
                continue
            seen.add(key)
            keep.append(r)
        return keep, len(old) - len(keep)

    def start(self, rows: list[dict]) -> None:
        """Begin a journal holding ``rows`` (those reused from the last one)."""
        self.path.parent.mkdir(parents=True, exist_ok=True)
        with self.path.open("w", newline="") as f:
            w = csv.DictWriter(f, fieldnames=list(CSV_FIELDS), extrasaction="ignore")
            w.writeheader()
            w.writerows(rows)

    def append(self, row: dict) -> None:
        import os

        with self.path.open("a", newline="") as f:
            csv.DictWriter(f, fieldnames=list(CSV_FIELDS), extrasaction="ignore").writerow(row)
            f.flush()
            os.fsync(f.fileno())

    def close(self) -> None:
        """The sweep completed (its CSV is written): the journal goes."""
        self.path.unlink(missing_ok=True)


def failure_category(constraint: str) -> str:
    return constraint.split(":", 1)[0] if constraint else ""


def frontier(res) -> str:
    """The constraint that failed most at the deepest sub-task reached (also for a time-limited
    search: what the robot was stuck on when the clock ran out)."""
    from .msp import frontier_failure

    if res.report is None:
        return res.failure_constraint
    return frontier_failure(res.report.failures, res.report.deepest)[0]


@dataclass
class Planned:
    """What :func:`plan_task` made beside its row (None fields after a spec error)."""

    robot: Any = None
    env: Any = None
    settings: Any = None
    result: Any = None  # ClimbPlanResult


def run_task(task: SweepTask) -> dict:
    """Plan one grid ladder; never raises (errors become a failed row)."""
    return plan_task(task)[0]


def plan_task(task: SweepTask, settings=None) -> tuple[dict, Planned]:
    """:func:`run_task`'s row and the models and plan behind it (an executing sweep runs the plan);
    ``settings``: the planner settings (default: config/planner.yaml), the task's strategy on top."""
    import dataclasses

    from climb_core.environment import build_environment
    from climb_core.ladder import parse_scenario
    from climb_core.robot import load_robot

    from .climb_planner import plan_climb
    from .settings import load_settings

    row = {"inclination_deg": task.inclination_deg, "rung_spacing": task.rung_spacing, "robot": task.robot,
           "steps": task.steps, "timeout_s": task.timeout_s, "seed": task.seed}
    t0 = time.perf_counter()
    planned = Planned()
    try:
        settings = settings or load_settings()
        if task.strategy:
            settings = dataclasses.replace(settings, planning=dataclasses.replace(settings.planning,
                                                                                  strategy=task.strategy))
        robot = load_robot(task.robot)
        env = build_environment(parse_scenario(task.spec, name=task.name))
        res = plan_climb(robot, env, task.steps, settings=settings, seed=task.seed, timeout_s=task.timeout_s)
        planned = Planned(robot, env, settings, res)
        s = res.summary()
        ok, failure, detail = bool(res.success), res.failure_constraint, res.failure_detail
        if res.success:
            ok, detail = verified(row, robot, env, res.plan, settings, task.steps)
            failure = "" if ok else "verify"
        row.update(success=ok, plan_time_s=round(res.plan_time_s, 3),
                   plan_cpu_s=round(res.plan_cpu_s, 3),
                   failure_constraint="" if ok else failure,
                   frontier_constraint="" if ok else ("verify" if res.success else frontier(res)),
                   failure_detail="" if ok else detail[:300],
                   rungs_reached=s["rungs_reached"], n_stances=s["n_stances"], attempts=s["attempts"],
                   backtracks=s["backtracks"], strategy=settings.planning.strategy)
    except SpecError as exc:
        row.update(success=False, plan_time_s=round(time.perf_counter() - t0, 3), plan_cpu_s=0.0,
                   failure_constraint="spec", frontier_constraint="spec",
                   failure_detail=str(exc), rungs_reached=0, n_stances=0, attempts=0, backtracks=0,
                   strategy=task.strategy)
    row["failure_category"] = failure_category(row.get("failure_constraint", ""))
    return row, planned


def verified(row: dict, robot, env, plan, settings, steps: int) -> tuple[bool, str]:
    """Re-check a planned climb with the frozen feasibility check at the planner's discretisation,
    its feet ending on rung ``steps`` (``row``'s verify columns filled); (ok, the failures)."""
    from .verify import verify_plan

    t0 = time.perf_counter()
    rep = verify_plan(robot, env, plan, refine=1, settings=settings, goal_feet_rung=steps)
    row.update(verified=bool(rep.ok), verify_s=round(time.perf_counter() - t0, 3),
               verify_detail="" if rep.ok else rep.summary()[:300])
    return bool(rep.ok), "" if rep.ok else f"frozen check: {rep.summary()}"


def write_csv(rows: list[dict], path: str | pathlib.Path) -> pathlib.Path:
    path = pathlib.Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(CSV_FIELDS), extrasaction="ignore")
        w.writeheader()
        for r in sorted(rows, key=lambda r: (r["inclination_deg"], r["rung_spacing"])):
            w.writerow(r)
    return path


def read_csv(path: str | pathlib.Path) -> list[dict]:
    with pathlib.Path(path).open() as f:
        rows = list(csv.DictReader(f))
    for r in rows:
        r["inclination_deg"] = float(r["inclination_deg"])
        r["rung_spacing"] = float(r["rung_spacing"])
        r["success"] = r["success"] in ("True", "true", "1")
        r["plan_time_s"] = float(r["plan_time_s"])
        ex = r.get("executed")  # "" or absent: not executed (a planning-only sweep or journal)
        r["executed"] = None if ex in ("", None) else ex in ("True", "true", "1")
    return rows


def executed_rows(rows: list[dict]) -> list[dict]:
    """The rows of an executing sweep (``executed`` True or False; None: the ladder was not run)."""
    return [r for r in rows if r.get("executed") is not None]


def statistics(rows: list[dict]) -> dict:
    n = len(rows)
    ok = [r for r in rows if r["success"]]
    times = [float(r["plan_time_s"]) for r in ok]
    cats: dict[str, int] = {}
    for r in rows:
        if not r["success"]:
            cats[r["failure_category"] or "unknown"] = cats.get(r["failure_category"] or "unknown", 0) + 1
    return {"n": n, "n_success": len(ok), "success_rate": (len(ok) / n) if n else 0.0,
            "median_plan_time_s": float(np.median(times)) if times else float("nan"),
            "median_plan_cpu_s": float(np.median([float(r.get("plan_cpu_s") or 0.0) for r in ok])) if ok
            else float("nan"),
            "p90_plan_time_s": float(np.percentile(times, 90)) if times else float("nan"),
            "failures_by_category": dict(sorted(cats.items(), key=lambda kv: -kv[1])),
            **execution_statistics(rows)}


def execution_statistics(rows: list[dict]) -> dict:
    """An executing sweep's figures: executed successes over the grid and over the planned
    ladders, and what stopped the executions of planned ladders (the failure reason's first word);
    {} for a planning-only sweep."""
    ran = executed_rows(rows)
    if not ran:
        return {}
    planned = [r for r in ran if r["success"]]
    ok = [r for r in planned if r["executed"]]
    why: dict[str, int] = {}
    for r in planned:
        if not r["executed"]:
            key = (str(r.get("exec_failure") or "unknown").split(":", 1)[0].split(" ", 1)[0]) or "unknown"
            why[key] = why.get(key, 0) + 1
    return {"n_executed_success": len(ok), "executed_rate": len(ok) / len(ran),
            "executed_of_planned": (len(ok) / len(planned)) if planned else 0.0,
            "execution_failures": dict(sorted(why.items(), key=lambda kv: -kv[1]))}


def heat_maps(rows: list[dict], path: str | pathlib.Path, title: str = "") -> pathlib.Path:
    """Success map (black = planned, like the paper's Fig. 9, failures coloured by category) and a
    planning-time map, side by side, as one PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.colors import ListedColormap

    incls = sorted({r["inclination_deg"] for r in rows})
    sps = sorted({r["rung_spacing"] for r in rows})
    def cat(r):  # what stopped it: the frontier constraint's category (time limits included)
        return failure_category(r.get("frontier_constraint") or r.get("failure_constraint") or "") or "unknown"

    cats = sorted({cat(r) for r in rows if not r["success"]})
    codes = {c: i + 1 for i, c in enumerate(cats)}
    S = np.full((len(sps), len(incls)), np.nan)
    T = np.full((len(sps), len(incls)), np.nan)
    for r in rows:
        i, j = sps.index(r["rung_spacing"]), incls.index(r["inclination_deg"])
        S[i, j] = 0 if r["success"] else codes[cat(r)]
        T[i, j] = float(r["plan_time_s"])
    palette = ["black", "tab:red", "tab:orange", "tab:blue", "tab:green", "tab:purple", "tab:brown", "tab:pink",
               "tab:gray", "tab:olive", "tab:cyan"]
    cmap = ListedColormap(palette[:len(cats) + 1])
    ran = executed_rows(rows)
    fig, axes = plt.subplots(1, 3 if ran else 2, figsize=(19.5 if ran else 13, 5.2))
    extent = (incls[0] - 0.5, incls[-1] + 0.5, 100 * sps[0] - 0.5, 100 * sps[-1] + 0.5)
    ax = axes[0]
    ax.imshow(S, origin="lower", aspect="auto", cmap=cmap, vmin=-0.5, vmax=len(cats) + 0.5, extent=extent,
              interpolation="nearest")
    st = statistics(rows)
    ax.set_title(f"planned (black): {st['n_success']}/{st['n']} = {100 * st['success_rate']:.0f} %")
    ax.set_xlabel("inclination [deg]")
    ax.set_ylabel("rung spacing [cm]")
    handles = [plt.Rectangle((0, 0), 1, 1, color=palette[0])] + \
              [plt.Rectangle((0, 0), 1, 1, color=palette[codes[c]]) for c in cats]
    ax.legend(handles, ["planned"] + [f"stopped by: {c}" for c in cats], loc="upper left", fontsize=7,
              bbox_to_anchor=(1.0, 1.0))
    if ran:  # executed beside planned: black = planned and executed, grey = planned, fell or stopped
        E = np.full((len(sps), len(incls)), np.nan)
        for r in ran:
            E[sps.index(r["rung_spacing"]), incls.index(r["inclination_deg"])] = (
                0 if r["executed"] else 1 if r["success"] else 2)
        ax = axes[1]
        ax.imshow(E, origin="lower", aspect="auto", cmap=ListedColormap(["black", "tab:gray", "white"]),
                  vmin=-0.5, vmax=2.5, extent=extent, interpolation="nearest")
        ax.set_title(f"executed (black): {st['n_executed_success']}/{len(ran)} = {100 * st['executed_rate']:.0f} %, "
                     f"{100 * st['executed_of_planned']:.0f} % of planned")
        ax.set_xlabel("inclination [deg]")
        ax.set_ylabel("rung spacing [cm]")
        ax.legend([plt.Rectangle((0, 0), 1, 1, color=c, ec="k") for c in ("black", "tab:gray", "white")],
                  ["executed", "planned, not executed", "not planned"], loc="upper left", fontsize=7,
                  bbox_to_anchor=(1.0, 1.0))
    ax = axes[-1]
    im = ax.imshow(T, origin="lower", aspect="auto", cmap="viridis", extent=extent, interpolation="nearest")
    ax.set_title(f"planning time [s] (median of successes {st['median_plan_time_s']:.2f} s)")
    ax.set_xlabel("inclination [deg]")
    ax.set_ylabel("rung spacing [cm]")
    fig.colorbar(im, ax=ax)
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    path = pathlib.Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
