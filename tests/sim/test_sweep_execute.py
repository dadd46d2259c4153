"""``scripts/sweep.py --execute`` on one ladder of the coarse grid (74 deg, 26 cm; a 1-step climb):
the ladder planned as a climb plans it, that plan executed in the simulator (lock-step, QP, one
period of latency), the CSV row, the summary and the PNG with the executed map beside the planned
one; the execution judged from the simulator (both feet on rung 1, nothing fallen)."""
from __future__ import annotations

import json
import pathlib
import subprocess
import sys

import pytest
import yaml

pytestmark = [pytest.mark.sim, pytest.mark.heavy]

ROOT = pathlib.Path(__file__).resolve().parents[2]
COARSE = ROOT.parent / "shared" / "bench" / "ladder_grid_coarse.yaml"


def test_sweep_execute_plans_and_executes_a_grid_ladder(tmp_path):
    from planner_node import sweep

    grid = yaml.safe_load(COARSE.read_text())  # the grid's base ladder, one point of it
    grid["grid"] = {"inclination_deg": {"start": 74, "stop": 74, "step": 2},
                    "rung_spacing": {"start": 0.26, "stop": 0.26, "step": 0.03}}
    (tmp_path / "grid.yaml").write_text(yaml.safe_dump(grid))
    cmd = [sys.executable, str(ROOT / "scripts" / "sweep.py"), "--grid", str(tmp_path / "grid.yaml"),
           "--steps", "1", "--timeout", "60", "--workers", "1", "--execute", "--out-dir", str(tmp_path),
           "--name", "exec"]
    out = subprocess.run(cmd, capture_output=True, text=True, timeout=900)
    assert out.returncode == 0, out.stderr[-3000:]
    summary = json.loads(out.stdout.strip().splitlines()[-1])
    (row,) = sweep.read_csv(summary["csv"])
    assert row["success"], row["failure_detail"]  # planned
    assert row["executed"] is True, row["exec_failure"]
    assert int(row["exec_rungs_reached"]) == 1  # both feet on rung 1, from the simulator's contacts
    assert row["exec_fell"] == "False" and int(row["exec_replans"]) == 0  # the sweep's own plan, no replan
    assert float(row["exec_sim_time_s"]) > 10.0
    # the execution followed the plan: the joint farthest from it at the worst transition end, named
    assert 0.0 < float(row["exec_max_joint_error_rad"]) < 0.5, row
    assert row["exec_max_joint_error_at"].startswith("transition "), row
    assert summary["n_executed_success"] == 1 and summary["executed_of_planned"] == 1.0
    import matplotlib.image as mpimg

    assert mpimg.imread(summary["png"]).shape[1] > 1800  # planned, executed and time maps side by side
    assert not (tmp_path / "exec.partial.csv").exists()
