"""The shipped ship ladder (config/ladders/ship.yaml: 60 deg, 17 cm treads every 21.7 cm of rise,
overhanging each other by 4.5 cm, two rails) is planned 3 treads up as a climb plans it: walked
(``guide_path.walk_max_incline_deg`` 60), searched (the DARPA-tasks paper's contact search, the
hands on the rails), the climb's planner settings.

What made it plannable (2026-12-02): the feet stand on the treads with the ladder paper's Fig. 6
hold, the heel 4.5 cm past the nose (``holds.foot_on_tread_offset``), so that the toes are not
under the tread above; centred on its tread the sole's front 4.5 cm was, and the step up from
tread 1 to tread 2 stayed stuck for 15 sessions (sub-task 7, 8,832 attempts in 900 s). The test
checks the plan, not its execution: executed, the robot falls at its first re-grasp of a rail
(docs/multicontact.md)."""
from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from climb_core import feasibility, holds
from climb_core.contact import FEET, HANDS


@pytest.fixture(scope="module")
def planned():
    from climb_coordinator.settings import apply_planner_overrides, load_climb_settings
    from climb_core.environment import build_environment
    from climb_core.ladder import load_scenario
    from climb_core.robot import load_robot
    from planner_node import pipeline
    from planner_node.settings import choose_strategy, load_settings, settings_for_scenario

    cs = load_climb_settings()
    scenario = load_scenario("ship")
    settings = settings_for_scenario(apply_planner_overrides(load_settings(), cs.planner_overrides), scenario,
                                     scene_overrides=cs.scene_planner_overrides, steep=cs.steep_ladder)
    strategy, reason = choose_strategy(scenario, settings)
    assert strategy == "search" and "walked up" in reason, reason
    robot, env = load_robot("g1"), build_environment(scenario)
    request = pipeline.PlanRequest(id="ship", robot="g1", scenario="ship", rungs=3, seed=0, timeout_s=600.0,
                                   strategy="search")
    problem = pipeline.Problem(request, robot, scenario, env, None, settings)
    guide = pipeline.guide_path(problem, strategy="search")
    _, result, _ = pipeline.search_and_adapt(problem, guide.product)
    assert result.plan is not None, result.summary()
    return robot, env, settings, result.plan


def test_the_ship_ladder_is_planned_three_treads_up_holding_the_rails(planned):
    robot, env, _, plan = planned
    last = plan.transitions[-1].target_stance
    assert {h.limb: h.env_surface for h in last.holds if h.limb in FEET} == {"left_foot": "rung_3",
                                                                             "right_foot": "rung_3"}
    hands = {(t.moving_limb, t.target_stance.hold(t.moving_limb).env_surface) for t in plan.transitions
             if t.moving_limb in HANDS and t.target_stance.hold(t.moving_limb) is not None}
    assert hands == {("left_hand", "rail_left"), ("right_hand", "rail_right")}, hands
    level = {"ground": 0, **{f"rung_{k}": k for k in range(1, env.n_rungs + 1)}}
    stances = [plan.initial_stance] + [t.target_stance for t in plan.transitions]
    for st in stances:  # one tread at a time: the feet never more than one tread apart
        feet = [level[h.env_surface] for h in st.holds if h.limb in FEET]
        assert len(feet) < 2 or abs(feet[0] - feet[1]) <= 1, [h.env_surface for h in st.holds]


def test_every_foot_on_a_tread_stands_heel_past_the_nose(planned):
    """Each foot hold on a tread is the Fig. 6 hold (``sole_bar``) with the sole shifted back by
    ``foot_on_tread_offset``; in the plan's configurations the sole is there (the frozen check's
    contact tolerance) and its front does not reach under the tread above."""
    robot, env, _, plan = planned
    cfg = feasibility.load_config()
    forward = holds.ladder_forward(env)
    n = 0
    for t in plan.transitions:
        for h in t.target_stance.holds:
            if h.limb not in FEET or not h.env_surface.startswith("rung_"):
                continue
            target = holds.hold_target(robot, env, h, params=cfg.holds)
            assert target.kind == "sole_bar"
            tread = env.surfaces[h.env_surface]
            back = float((tread.position - target.T_world_surface[:3, 3]) @ forward)
            assert back == pytest.approx(cfg.holds.foot_on_tread_offset, abs=1e-6)
            sole = np.asarray(robot.T_world_surface(h.limb, t.path[-1]))
            assert np.linalg.norm(sole[:3, 3] - target.T_world_surface[:3, 3]) < cfg.check.contact_position_tolerance
            n += 1
    assert n >= 6


def test_a_held_grasp_does_not_roll_about_its_rail(planned):
    """The simulator's grasp is rigid: a hand holding its rail through a transition keeps its pose
    (``planner_node.contact_path`` latches the grasps; unlatched, this plan rolled them 0.6-0.8 rad)."""
    robot, _, _, plan = planned
    worst = 0.0
    for t in plan.transitions:
        for h in t.stance.holds:
            if h.limb not in HANDS or h.limb == t.moving_limb:
                continue
            R0 = np.asarray(robot.T_world_surface(h.limb, t.path[0]))[:3, :3]
            for q in t.path:
                R = np.asarray(robot.T_world_surface(h.limb, q))[:3, :3]
                worst = max(worst, float(np.linalg.norm(pin.log3(R0.T @ R))))
    assert worst < 0.01, worst


def test_the_plan_passes_the_frozen_check(planned):
    from climb_core import fixtures
    from planner_node.verify import verify_plan

    robot, env, settings, plan = planned
    _, q_start = fixtures.get("standing", robot, env)
    rep = verify_plan(robot, env, plan, q_start=q_start, refine=1, settings=settings)
    assert rep.ok, rep.summary()
