"""A steep grid ladder that stopped on the open thumb in the 2026-11-23 sweep plans today.

The grid's 82 deg / 21 cm ladder (../shared/bench/ladder_grid.yaml's base) stopped at a hand
transfer on `collision:left_hand_thumb_1_link_0|rung_4` (docs/sweep/g1_forward_full_t120.csv):
the open Dex3 thumb stands 9.7 cm proud of the palm face. It plans with the re-targeted hand
transfers (their release undoes the grasp's roll first) and, from 82 deg, the longer back-off of
every second attempt (`interpolation.hand_backoff_scale`, docs/planner.md). The plan is cached
under .cache/planner/ keyed by the sources and configuration; the checks always run.
"""
from __future__ import annotations

import copy

import pytest

from climb_core import fixtures
from climb_core.environment import build_environment
from climb_core.ladder import parse_scenario
from planner_node import plan_io
from planner_node.climb_planner import plan_climb
from planner_node.settings import load_settings
from planner_node.verify import verify_plan

from test_planner_sweep import grid_doc  # same folder (pytest puts it on sys.path)

STEPS = 2


@pytest.fixture(scope="module")
def steep():
    spec = copy.deepcopy(grid_doc()["base"])
    spec["ladder"].update(inclination_deg=82.0, rung_spacing=0.21)
    return build_environment(parse_scenario(spec, name="grid_82_0.21"))


@pytest.fixture(scope="module")
def planned(g1, steep):
    def compute():
        res = plan_climb(g1, steep, STEPS, seed=0, timeout_s=120.0)
        return (res.plan if res.success else None), res.summary()

    key = plan_io.source_fingerprint("test_steep_grid_ladder", steep.scenario, STEPS, 0)
    plan, meta = plan_io.cached_plan(key, compute)
    assert plan is not None, meta.get("failure_reason")
    return plan


def test_the_steep_ladder_plans_and_passes_the_frozen_check(g1, steep, planned):
    assert load_settings().interpolation.hand_backoff_scale > 1.0
    _, q_start = fixtures.get("standing", g1, steep)
    rep = verify_plan(g1, steep, planned, q_start=q_start, refine=1, goal_feet_rung=STEPS)  # the planner's samples
    assert rep.ok, rep.summary() + f" {rep.failures[:5]} {rep.problems[:5]}"
    assert rep.goal_feet_rungs == (STEPS, STEPS)
    assert rep.min_distance >= 0.0 and rep.max_load_ratio <= 1.0
