"""The scenes' stored whole-body plans (tests/data/<scene>_plan.json, each ``scripts/plan.py
--scenario <scene> --out ...`` with the scene's own settings) re-checked independently of the planner
that made them: every configuration by the frozen feasibility check (planner_node.verify, the
scene's planner settings for the step and speed limits), one hold changed per transition, the last
base at the scene's goal. The sim tests execute them (tests/sim/test_scene_step.py,
test_scene_stairs.py); car_ingress's plan is checked here only (docs/multicontact.md: what stops its
execution)."""
from __future__ import annotations

import pathlib

import numpy as np
import pytest

from climb_core.environment import build_environment
from climb_core.ladder import load_scenario
from planner_node import plan_io
from planner_node.contact_search import transition_changes
from planner_node.settings import load_settings, scenario_settings, scene_settings
from planner_node.verify import verify_plan

DATA = pathlib.Path(__file__).resolve().parents[1] / "data"
HANDS = ("left_hand", "right_hand")

#: scene -> (least transitions, a surface a hand must have held)
STORED = {
    "narrow_passage_step": (15, "palm_block"),
    "stairs_handrail": (10, None),
    "narrow_passage": (50, "palm_block"),
    "car_ingress": (15, None),
}


@pytest.mark.parametrize("scene", sorted(STORED))
def test_a_stored_scene_plan_passes_the_frozen_check_and_ends_at_the_goal(g1, scene):
    least, hand_surface = STORED[scene]
    plan, metadata = plan_io.load_plan(DATA / f"{scene}_plan.json")
    scenario = load_scenario(scene)
    env = build_environment(scenario)
    assert plan.environment == scene and plan.robot == "g1" and len(plan.transitions) >= least
    settings = scenario_settings(scene_settings(load_settings()), scenario)
    report = verify_plan(g1, env, plan, refine=1, settings=settings)
    assert report.ok, (report.summary(), report.failures[:5], report.problems[:5])
    assert report.max_contact_drift < 0.005 and report.min_distance > 0.0
    # the scene's speeds: the plan was timed with them (narrow_passage's are half the planner's)
    assert report.max_joint_speed <= settings.timing.max_joint_speed * (1 + 1e-6)
    stance = plan.initial_stance
    hand_surfaces = set()
    for i, tr in enumerate(plan.transitions):
        assert tr.stance == stance or not transition_changes(stance, tr.stance)[0], f"transition {i} starts elsewhere"
        added, removed = transition_changes(tr.stance, tr.target_stance)
        assert len(added) + len(removed) <= 1, (i, tr.primitive, added, removed)
        hand_surfaces |= {h.env_surface for h in tr.target_stance.holds if h.limb in HANDS}
        stance = tr.target_stance
    assert hand_surfaces, "no hand ever held a surface"
    if hand_surface:
        assert hand_surface in hand_surfaces, hand_surfaces
    goal = env.goal
    q_end = np.asarray(plan.transitions[-1].path[-1])
    assert np.linalg.norm(q_end[:3] - np.asarray(goal.base_position)) <= goal.tolerance
    assert {h.limb for h in stance.holds} >= {"left_foot", "right_foot"}
