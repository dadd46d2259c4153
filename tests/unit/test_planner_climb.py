"""G1 climbs the default ladder: the 2-step plan, re-checked at 4x the planner's discretisation.

"2-step climb" = the grid file's definition: mount, then two full climbing cycles, i.e. from
standing on the ground (start fixture) to both feet on rung 2. The plan is cached on disk under
.cache/planner/ keyed by the planner/core sources and the configuration files; the verification
always runs.
"""
from __future__ import annotations

import numpy as np
import pytest

from climb_core import fixtures
from climb_core.contact import FEET, HANDS
from planner_node import plan_io
from planner_node.adapt import limb_rung
from planner_node.climb_planner import plan_climb
from planner_node.settings import load_settings
from planner_node.verify import verify_plan

STEPS = 2


@pytest.fixture(scope="module")
def planned(g1, env):
    def compute():
        res = plan_climb(g1, env, STEPS, seed=0)
        return (res.plan if res.success else None), {**res.summary(), "subtasks": res.subtasks}

    key = plan_io.source_fingerprint("test_planner_climb", env.scenario, STEPS, 0)
    plan, meta = plan_io.cached_plan(key, compute)
    assert plan is not None, meta.get("failure_reason")
    return plan, meta


def test_two_step_climb_is_planned_and_passes_the_core_check_at_4x(g1, env, planned):
    plan, meta = planned
    _, q_start = fixtures.get("standing", g1, env)
    rep = verify_plan(g1, env, plan, q_start=q_start, refine=4, goal_feet_rung=STEPS)
    assert rep.ok, rep.summary() + f" {rep.failures[:5]} {rep.problems[:5]}"
    assert rep.n_checked > 2000  # every plan configuration and 3 in between each pair, per stance
    # joint continuity, contact drift, goal stance
    assert rep.continuity_error < 1e-9
    assert rep.max_step <= load_settings().interpolation.max_step + 1e-9
    assert rep.max_contact_drift < 0.005
    assert rep.goal_feet_rungs == (STEPS, STEPS)
    assert rep.min_distance >= 0.0 and rep.max_load_ratio <= 1.0


def test_plan_structure_is_what_the_controller_expects(g1, env, planned):
    plan, meta = planned
    tp = load_settings().timing
    assert plan.robot == "g1" and plan.joint_names == list(g1.joint_names)
    assert plan.initial_stance.limbs == ("left_foot", "right_foot")
    kinds = [t.primitive for t in plan.transitions]
    assert kinds.count("mount") == 2
    assert kinds.count("place_foot") == 2 * STEPS + 2  # two approach steps + two per cycle
    assert kinds.count("place_hand") == 2 * STEPS
    prev = plan.initial_stance
    for t in plan.transitions:
        assert t.path.shape[1] == g1.model.nq and len(t.times) == len(t.path)
        assert t.times[-1] >= tp.min_transition_duration - 1e-9
        if t.moving_limb:
            # one hold changes: the kept stance is the previous one minus the moving limb
            assert t.moving_limb not in t.stance.limbs
            assert set(t.stance.limbs) | {t.moving_limb} == set(t.target_stance.limbs)
            assert {h.limb for h in prev.holds if h.limb != t.moving_limb} == set(t.stance.limbs)
        else:  # CoM transfer: no stance change
            assert t.stance.limbs == t.target_stance.limbs == prev.limbs
        prev = t.target_stance
    assert all(limb_rung(prev, f) == STEPS for f in FEET)
    assert all(limb_rung(prev, h) > STEPS for h in HANDS)
    # quasi-static and slow: a few seconds per transition, about a minute for the climb
    total = sum(t.times[-1] for t in plan.transitions)
    assert 30.0 < total < 300.0


def test_plan_file_and_message_round_trip(g1, env, planned, tmp_path):
    plan, _ = planned
    path = plan_io.save_plan(tmp_path / "plan.json", plan, {"seed": 0})
    back, meta = plan_io.load_plan(path)
    assert meta == {"seed": 0}
    assert len(back.transitions) == len(plan.transitions)
    for a, b in zip(plan.transitions, back.transitions):
        assert np.allclose(a.path, b.path) and np.allclose(a.times, b.times)
        assert a.target_stance.limbs == b.target_stance.limbs
    from msgs_py.contact import whole_body_plan_from_msg, whole_body_plan_to_msg

    msg_back = whole_body_plan_from_msg(whole_body_plan_to_msg(plan))
    assert np.allclose(msg_back.transitions[-1].path, plan.transitions[-1].path)


def test_replanning_from_the_reached_state_continues_the_climb(g1, env, planned):
    # partially known ladder: plan the first cycles, then one more from where the robot is
    plan, _ = planned
    last = plan.transitions[-1]
    res = plan_climb(g1, env, 1, start=(last.path[-1], last.target_stance), seed=0)
    assert res.success, res.failure_detail
    assert res.subtasks[0] == "com_to_right_foot"  # straight into a climbing cycle
    assert np.allclose(res.plan.transitions[0].path[0], last.path[-1])
    assert all(limb_rung(res.final_state.stance, f) == STEPS + 1 for f in FEET)


def test_the_sequence_from_a_stance_in_the_middle_of_a_cycle_finishes_that_cycle_first(g1, env, planned):
    """A replan right after a placement found its rung off the plan starts mid-cycle: after each
    placement of the planned climb's second cycle, the sequence resumes exactly where the plan went
    on, and the feet end ``steps`` rungs above the stance's lower foot."""
    from planner_node.climb_planner import subtask_sequence
    from planner_node.primitives import load_library

    plan, _ = planned
    settings = load_settings().planning
    library = load_library("g1", settings.strategy, settings.primitives_dir, nq=g1.model.nq)
    cycle = list(library.sequences["cycle"])
    start = len(plan.transitions) - len(cycle)  # the second cycle's first transition
    checked = 0
    for j in range(1, len(cycle)):
        if not library.primitives[cycle[j - 1]].is_limb:
            continue  # a CoM shift leaves the stance as it was
        stance = plan.transitions[start + j - 1].target_stance
        lower = min(limb_rung(stance, f) for f in FEET)
        for steps in (STEPS - lower, STEPS - lower + 1):
            rungs = {limb: limb_rung(stance, limb) for limb in FEET}
            seq = [library.primitives[p] for p in (x.name for x in subtask_sequence(library, stance, steps, env))]
            assert [p.name for p in seq[:len(cycle) - j]] == cycle[j:], (j, [p.name for p in seq])
            for p in seq:  # the feet end `steps` above the lower foot
                if p.is_limb and p.limb in FEET:
                    rungs[p.limb] += 1
            assert rungs == {f: lower + steps for f in FEET}, (j, steps, rungs)
        checked += 1
    assert checked == 3  # after each foot and the first hand (after the second: a boundary)
    boundary = plan.transitions[start - 1].target_stance
    assert [p.name for p in subtask_sequence(library, boundary, 1, env)] == cycle


def test_a_replan_after_the_first_hand_mounted_plans_the_rest_of_the_mount(g1, env, planned):
    """The mount's first hand found its rung off the plan (on a steep ladder: 84/0.20 of the coarse
    grid): the replan starts on the ground with one hand on a rung, mounts the other hand and climbs
    on (a whole-mount sequence is refused from there)."""
    from planner_node.climb_planner import subtask_sequence
    from planner_node.primitives import load_library

    plan, _ = planned
    settings = load_settings().planning
    library = load_library("g1", settings.strategy, settings.primitives_dir, nq=g1.model.nq)
    first = next(t for t in plan.transitions if t.primitive == "mount")
    stance = first.target_stance
    assert [limb_rung(stance, f) for f in FEET] == [0, 0] and limb_rung(stance, first.moving_limb) > 0
    names = [p.name for p in subtask_sequence(library, stance, 1, env)]
    assert names == list(library.sequences["mount"][1:]) + list(library.sequences["first_cycle"]
                                                                  if "first_cycle" in library.sequences
                                                                  else library.sequences["cycle"])
    res = plan_climb(g1, env, 1, start=(first.path[-1], stance), seed=0)
    assert res.success, res.failure_detail
    assert res.subtasks[0] == library.sequences["mount"][1]
    assert np.allclose(res.plan.transitions[0].path[0], first.path[-1])
    assert all(limb_rung(res.final_state.stance, f) == 1 for f in FEET)


def test_a_verify_report_names_the_constraint_of_its_first_infeasible_samples():
    """The frozen check's verdict in a sweep row (failure_detail) names what broke and where: a grid
    ladder rejected by one sample said only "1 infeasible samples, problems: []" before."""
    from planner_node.verify import VerifyReport

    rep = VerifyReport(failures=[(15, 79, "friction"), (16, 3, "torque_limit:left_knee_joint"), (17, 0, "x")],
                       n_checked=1283)
    text = rep.summary()
    assert text.startswith("3 infeasible samples, transition 15 sample 79: friction, "
                           "transition 16 sample 3: torque_limit:left_knee_joint, problems: []"), text
    assert "transition 17" not in text
    assert VerifyReport(n_checked=5).summary().startswith("ok; 5 configurations checked")
