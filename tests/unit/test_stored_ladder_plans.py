"""The vertical ladder's stored whole-body plan (tests/data/vertical_plan.json, ``scripts/plan.py
--scenario vertical --steps 2 --out ...`` with level feet on the rungs, before the pitched feet;
the example of ``scripts/climb.py --plan``) re-checked independently of the planner: every configuration by
the frozen feasibility check, the feet ending on rung 2, and the timing the planner gives it today
(the first hand's mount slowed where the CoM nears the heels: ``timing.edge_slowdown_margin``, set by
config/ladders/vertical.yaml)."""
from __future__ import annotations

import pathlib

import numpy as np

from climb_core.environment import build_environment
from climb_core.ladder import load_scenario
from planner_node import plan_io
from planner_node.interpolation import support_edge_factors, time_transition
from planner_node.settings import load_settings, scenario_settings
from planner_node.verify import verify_plan

STORED = pathlib.Path(__file__).resolve().parents[1] / "data" / "vertical_plan.json"


def test_the_stored_vertical_plan_passes_the_frozen_check_and_ends_on_rung_2(g1):
    plan, _ = plan_io.load_plan(STORED)
    scenario = load_scenario("vertical")
    env = build_environment(scenario)
    assert plan.environment == "vertical" and plan.robot == "g1"
    report = verify_plan(g1, env, plan, refine=1, settings=scenario_settings(load_settings(), scenario),
                         goal_feet_rung=2)
    assert report.ok, (report.summary(), report.failures[:5], report.problems[:5])
    assert report.goal_feet_rungs == (2, 2)
    assert report.max_contact_drift < 0.005 and report.min_distance > 0.0


def test_the_stored_vertical_plan_is_timed_as_the_planner_times_it_with_the_mount_slowed(g1):
    plan, _ = plan_io.load_plan(STORED)
    timing = scenario_settings(load_settings(), load_scenario("vertical")).timing  # the ladder file's slow-down
    assert timing.edge_slowdown_margin > 0.0 and load_settings().timing.edge_slowdown_margin == 0.0
    for t in plan.transitions:
        np.testing.assert_allclose(t.times, time_transition(g1.model, list(t.path), t.stance, timing), atol=1e-6)
    mount = next(t for t in plan.transitions if t.primitive == "mount")  # the first hand's: the soles alone
    factors = support_edge_factors(g1.model, list(mount.path), mount.stance, timing.edge_slowdown_margin,
                                   timing.edge_slowdown_max)
    assert factors is not None and factors.max() > 1.3
