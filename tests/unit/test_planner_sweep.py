"""A 6-ladder subset of the paper's grid through the sweep machinery (planner_node.sweep).

Rows are cached on disk under .cache/planner/ keyed by the planner / core sources, the
configuration files and the task, so only the first run after a change plans.
"""
from __future__ import annotations

import json
import pathlib
import subprocess
import sys

import pytest

from climb_core.errors import SpecError
from planner_node import plan_io, sweep

ROOT = pathlib.Path(__file__).resolve().parents[2]
GRID = ROOT.parent / "shared" / "bench" / "ladder_grid.yaml"
SUBSET = [(75.0, 0.25), (70.0, 0.29), (72.0, 0.23), (70.0, 0.26), (70.0, 0.32), (90.0, 0.35)]
# planned in the recorded sweeps (docs/planner.md); 90 deg / 35 cm is beyond the library (knees on the rungs)
EXPECTED_SOLVED = {(75.0, 0.25), (70.0, 0.29), (72.0, 0.23), (70.0, 0.26)}
TIMEOUT_S = 20.0  # [s] the solved ones plan in 3-4 s; 90 deg / 35 cm ends at this time limit


def grid_doc() -> dict:
    if GRID.is_file():
        return sweep.load_grid(GRID)
    # the shared folder is outside the repository: the same grid, written out
    return {"base": {"ladder": {"type": "regular", "n_rungs": 8, "first_rung_height": 0.25, "rung_width": 0.5,
                                "rung": {"shape": "circle", "diameter": 0.04},
                                "stringer": {"width": 0.08, "depth": 0.03}, "rails": [], "friction": 0.25,
                                "pose": {"x": 0.45, "y": 0.0, "yaw_deg": 0.0}}},
            "grid": {"inclination_deg": {"start": 70, "stop": 90, "step": 1},
                     "rung_spacing": {"start": 0.20, "stop": 0.35, "step": 0.01}},
            "steps": 2, "timeout_s": 120}


def cached_row(task: sweep.SweepTask) -> dict:
    path = plan_io.cache_dir() / f"sweep-{plan_io.source_fingerprint('sweep', task)}.json"
    if path.is_file():
        return json.loads(path.read_text())
    row = sweep.run_task(task)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(row))
    return row


@pytest.fixture(scope="module")
def rows():
    tasks = sweep.make_tasks(grid_doc(), "g1", timeout_s=TIMEOUT_S, select=SUBSET)
    assert len(tasks) == 6 and all(t.steps == 2 for t in tasks)
    return [cached_row(t) for t in tasks]


def test_grid_expands_to_the_papers_336_ladders():
    tasks = sweep.make_tasks(grid_doc(), "g1")
    assert len(tasks) == 21 * 16
    assert {t.inclination_deg for t in tasks} == set(range(70, 91))
    assert min(t.rung_spacing for t in tasks) == 0.20 and max(t.rung_spacing for t in tasks) == 0.35
    assert all(t.timeout_s == 120.0 for t in tasks)
    with pytest.raises(SpecError):
        sweep.make_tasks(grid_doc(), "g1", select=[(70.5, 0.2)])


def test_subset_plans_and_names_what_stopped_each_failure(rows, tmp_path):
    solved = {(r["inclination_deg"], r["rung_spacing"]) for r in rows if r["success"]}
    assert EXPECTED_SOLVED <= solved, rows
    for r in rows:
        if r["success"]:  # counted only once the frozen check re-verified the plan
            assert r["rungs_reached"] == 2 and r["failure_constraint"] == "" and r["plan_time_s"] > 0
            assert r["verified"] is True and r["verify_s"] > 0 and r["verify_detail"] == ""
        else:
            assert r["failure_constraint"] and r["failure_category"] == r["failure_constraint"].split(":")[0]
    csv_path = sweep.write_csv(rows, tmp_path / "subset.csv")
    back = sweep.read_csv(csv_path)
    assert [(r["inclination_deg"], r["rung_spacing"]) for r in back] == sorted(SUBSET)
    assert list(back[0]) == list(sweep.CSV_FIELDS)
    png = sweep.heat_maps(rows, tmp_path / "subset.png", title="subset")
    assert png.stat().st_size > 10_000
    stats = sweep.statistics(rows)
    assert stats["n"] == 6 and stats["n_success"] == len(solved)


def test_ray_backend_runs_the_tasks_on_a_local_ray_instance(tmp_path):
    """`--backend ray` without an address starts a Ray instance bound to 127.0.0.1 and plans the
    same task there as the local backend would."""
    cmd = [sys.executable, str(ROOT / "scripts" / "sweep.py"), "--backend", "ray", "--ladders", "70/0.20",
           "--timeout", "60", "--out-dir", str(tmp_path)]
    if GRID.is_file():
        cmd += ["--grid", str(GRID)]
    out = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr[-2000:]
    summary = json.loads(out.stdout.strip().splitlines()[-1])
    assert summary["backend"] == "ray" and summary["n"] == 1 and summary["n_success"] == 1
    (row,) = sweep.read_csv(summary["csv"])
    assert float(row["inclination_deg"]) == 70.0 and float(row["rung_spacing"]) == 0.20
    assert row["success"] is True and int(row["rungs_reached"]) == 2


def journal_row(inclination_deg: float, rung_spacing: float, version: str, **extra) -> dict:
    row = {"inclination_deg": inclination_deg, "rung_spacing": rung_spacing, "success": True, "plan_time_s": 3.2,
           "plan_cpu_s": 3.1, "failure_category": "", "failure_constraint": "", "frontier_constraint": "",
           "failure_detail": "", "rungs_reached": 2, "n_stances": 22, "attempts": 21, "backtracks": 0, "robot": "g1",
           "strategy": "forward", "steps": 2, "timeout_s": 60.0, "seed": 0, "code_version": version}
    row.update(extra)
    return row


def test_journal_keeps_rows_of_the_same_code_and_settings_only(tmp_path):
    tasks = sweep.make_tasks(grid_doc(), "g1", timeout_s=60.0, select=[(70.0, 0.20), (71.0, 0.20), (72.0, 0.20)])
    journal = sweep.Journal(tmp_path / "j.partial.csv")
    assert journal.reusable(tasks, "abc") == ([], 0)  # no journal yet
    journal.start([])
    journal.append(journal_row(70.0, 0.20, "abc"))
    journal.append(journal_row(71.0, 0.20, "older"))  # planned by other code
    journal.append(journal_row(72.0, 0.20, "abc", timeout_s=30.0))  # another cutoff
    journal.append(journal_row(73.0, 0.20, "abc"))  # not a point of this run
    kept, ignored = journal.reusable(tasks, "abc")
    assert [(r["inclination_deg"], r["rung_spacing"]) for r in kept] == [(70.0, 0.20)] and ignored == 3
    journal.close()
    assert not journal.path.exists()
    (tmp_path / "bad.partial.csv").write_text("not,a\nsweep,journal\n")
    with pytest.raises(SpecError, match="resume"):
        sweep.Journal(tmp_path / "bad.partial.csv").reusable(tasks, "abc")


def test_resumed_sweep_reuses_the_journal_instead_of_planning(tmp_path):
    """A sweep killed after one ladder: `--resume` takes that ladder's row from the journal (no
    planning: the run finishes in seconds), writes the CSV and removes the journal."""
    version = sweep.code_version(ROOT)
    journal = sweep.Journal(tmp_path / "resumed.partial.csv")
    journal.start([journal_row(70.0, 0.20, version, plan_time_s=4.25)])
    cmd = [sys.executable, str(ROOT / "scripts" / "sweep.py"), "--ladders", "70/0.20", "--timeout", "60",
           "--out-dir", str(tmp_path), "--name", "resumed", "--resume", "--workers", "1"]
    if GRID.is_file():
        cmd += ["--grid", str(GRID)]
    out = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    summary = json.loads(out.stdout.strip().splitlines()[-1])
    assert summary["reused"] == 1 and summary["n"] == 1 and summary["code_version"] == version
    (row,) = sweep.read_csv(summary["csv"])
    assert row["plan_time_s"] == 4.25 and row["code_version"] == version  # the journal's row, not a new plan
    assert not journal.path.exists()


def test_an_executing_sweep_reuses_executed_rows_only(tmp_path):
    """``--execute`` tasks take a journal row only if it was executed (a planning-only row of the
    same code is planned and executed again)."""
    tasks = sweep.make_tasks(grid_doc(), "g1", timeout_s=60.0, select=[(70.0, 0.20), (71.0, 0.20)], execute=True)
    journal = sweep.Journal(tmp_path / "x.partial.csv")
    journal.start([journal_row(70.0, 0.20, "abc", executed=True, exec_rungs_reached=2),
                   journal_row(71.0, 0.20, "abc")])  # planned only
    kept, ignored = journal.reusable(tasks, "abc")
    assert [(r["inclination_deg"], r["executed"]) for r in kept] == [(70.0, True)] and ignored == 1


def test_execution_statistics_and_the_executed_map(tmp_path):
    """Executed success over the grid and over the planned ladders, what stopped the others, and a
    third panel in the PNG; a planning-only sweep has none of it."""
    rows = [journal_row(70.0, 0.20, "v", executed=True),
            journal_row(70.0, 0.23, "v", executed=False, exec_failure="fell: base height 0.2 m < 0.39 m"),
            journal_row(72.0, 0.20, "v", success=False, failure_constraint="time_limit", executed=False,
                        exec_failure="not planned"),
            journal_row(72.0, 0.23, "v", executed=True)]
    path = sweep.write_csv(rows, tmp_path / "e.csv")
    back = sweep.read_csv(path)
    assert [r["executed"] for r in back] == [True, False, False, True]
    st = sweep.statistics(back)
    assert st["n_success"] == 3 and st["n_executed_success"] == 2
    assert st["executed_rate"] == pytest.approx(0.5) and st["executed_of_planned"] == pytest.approx(2 / 3)
    assert st["execution_failures"] == {"fell": 1}
    png = sweep.heat_maps(back, tmp_path / "e.png")
    import matplotlib.image as mpimg

    wide = mpimg.imread(png).shape[1]
    planning_only = [{k: v for k, v in r.items() if not k.startswith("exec")} for r in back]
    assert "executed_rate" not in sweep.statistics(planning_only)
    assert mpimg.imread(sweep.heat_maps(planning_only, tmp_path / "p.png")).shape[1] < 0.75 * wide


def test_code_version_names_the_code_trees_not_the_commit():
    """Rows stay reusable across commits of docs and tests: the version hashes src, config and
    scripts only."""
    version = sweep.code_version(ROOT)
    assert version != "unknown"  # the tests run in a git checkout (a clone in CI)
    trees = subprocess.run(["git", "rev-parse", "HEAD:src", "HEAD:config", "HEAD:scripts"], cwd=ROOT,
                           capture_output=True, text=True, check=True).stdout.split()
    import hashlib

    assert version.split("+")[0] == hashlib.sha1(" ".join(trees).encode()).hexdigest()[:10]


def _children(pid: int) -> dict[int, str]:
    """pid -> command line of the live processes whose parent is ``pid`` (from /proc)."""
    out = {}
    for d in pathlib.Path("/proc").iterdir():
        if not d.name.isdigit():
            continue
        try:
            stat = (d / "stat").read_text()
            fields = stat[stat.rindex(")") + 2:].split()
            if int(fields[1]) == pid and fields[0] not in "ZX":
                out[int(d.name)] = (d / "cmdline").read_bytes().replace(b"\0", b" ").decode()
        except (OSError, ValueError):
            continue
    return out


def _alive(pid: int) -> bool:
    try:
        stat = pathlib.Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return False
    return stat[stat.rindex(")") + 2] not in "ZX"  # a zombie waits for its reaper: it runs no more


def test_a_killed_sweep_takes_its_workers_with_it(tmp_path):
    """SIGKILL of a 2-worker sweep while both workers plan: the workers die with it (they kept
    planning for an hour before, measured 2026-11-30, with nobody to take their rows)."""
    import os
    import signal
    import time

    import yaml

    grid = tmp_path / "grid.yaml"
    grid.write_text(yaml.safe_dump(grid_doc()))
    # two ladders beyond the library: each worker plans until the 60 s limit
    cmd = [sys.executable, str(ROOT / "scripts" / "sweep.py"), "--grid", str(grid), "--ladders", "90/0.35,90/0.32",
           "--timeout", "60", "--workers", "2", "--out-dir", str(tmp_path), "--name", "killed"]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    try:
        workers: list[int] = []
        deadline = time.monotonic() + 90.0
        while time.monotonic() < deadline and len(workers) < 2:
            time.sleep(0.5)
            workers = [pid for pid, cmdline in _children(proc.pid).items() if "spawn_main" in cmdline]
        assert len(workers) == 2, _children(proc.pid)
        time.sleep(3.0)  # past the workers' start-up: planning
        assert all(_alive(pid) for pid in workers)
        proc.kill()
        proc.wait(timeout=10)
        deadline = time.monotonic() + 10.0
        while time.monotonic() < deadline and any(_alive(pid) for pid in workers):
            time.sleep(0.2)
        assert not [pid for pid in workers if _alive(pid)]
    finally:
        try:
            os.killpg(proc.pid, signal.SIGKILL)  # whatever is left of the sweep's session
        except ProcessLookupError:
            pass
