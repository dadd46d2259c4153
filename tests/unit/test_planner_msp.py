"""MSP-Recurse (planner_node.msp): depth-first search with backtracking, on abstract problems."""
from __future__ import annotations

import itertools

import numpy as np
import pytest

from planner_node.msp import TIME_LIMIT, AttemptFailure, Step, branch_rng, multi_step_search


def rung_climb_attempt(dead_end_rung: int, reach: int = 2):
    """A limb climbing rungs: attempt j of a step picks the hold ``current + 1 + (j == 0)`` (the
    first choice is the farther rung), a hold on ``dead_end_rung`` leaves no reachable next hold."""

    def attempt(subtask, state, j, rng):
        if state == dead_end_rung:
            return AttemptFailure("reach", f"nothing reachable from rung {state}")
        target = state + (2 if j == 0 else 1)
        if target - state > reach:
            return AttemptFailure("reach")
        return Step(target, segment=(state, target))

    return attempt


def test_search_succeeds_without_backtracking_when_first_choices_work():
    rep = multi_step_search(0, ["step"] * 3, rung_climb_attempt(dead_end_rung=-1), m=5)
    assert rep.success
    assert rep.final_state == 6  # three times the first choice (+2)
    assert rep.n_backtracks == 0 and rep.n_attempts == 3
    assert [s for s in rep.segments] == [(0, 2), (2, 4), (4, 6)]


def test_search_backtracks_when_the_first_hold_choice_dead_ends():
    # the first choice of step 1 (rung 2) leaves no reachable hold for step 2: the search must
    # come back to step 1 and take its second choice (rung 1), from which the climb finishes
    rep = multi_step_search(0, ["step"] * 2, rung_climb_attempt(dead_end_rung=2), m=3)
    assert rep.success
    assert rep.segments == [(0, 1), (1, 3)]
    assert rep.n_backtracks == 1
    # trace: step 0 attempt 0 ok -> step 1 fails m times -> step 0 attempt 1 ok -> step 1 ok
    assert rep.trace == [(0, 0, True), (1, 0, False), (1, 1, False), (1, 2, False), (0, 1, True), (1, 0, True)]
    assert rep.failures[1]["reach"] == 3


def test_search_reports_the_frontier_constraint_when_everything_fails():
    def attempt(subtask, state, j, rng):
        if state >= 1:
            return AttemptFailure("torque_limit:left_knee_joint" if j % 2 else "collision:knee|rung_2")
        return Step(state + 1, segment=state)

    rep = multi_step_search(0, ["a", "b"], attempt, m=3)
    assert not rep.success
    assert rep.deepest == 1
    # frontier = sub-task 1: 3 x 3 failures, collision twice per visit
    assert rep.failure_constraint == "collision:knee|rung_2"
    assert rep.n_attempts == 3 + 9
    assert rep.segments == [0]  # best partial branch


def test_search_is_deterministic_given_the_seed_and_the_branch():
    draws = []

    def attempt(subtask, state, j, rng):
        x = float(rng.random())
        draws.append(x)
        return Step(state + 1, segment=x) if x > 0.3 else AttemptFailure("sampled")

    a = multi_step_search(0, ["s"] * 4, attempt, m=4, seed=7)
    first = list(draws)
    draws.clear()
    b = multi_step_search(0, ["s"] * 4, attempt, m=4, seed=7)
    assert first == draws and a.trace == b.trace and a.segments == b.segments
    draws.clear()
    multi_step_search(0, ["s"] * 4, attempt, m=4, seed=8)
    assert draws != first
    # a branch's generator depends on the attempt indices along it, not on the call order
    assert branch_rng(3, [0, 1]).random() == branch_rng(3, [0, 1]).random()
    assert branch_rng(3, [0, 1]).random() != branch_rng(3, [1, 0]).random()


def test_search_stops_at_the_time_limit():
    ticks = itertools.count()

    def clock():
        return float(next(ticks))  # one "second" per call

    def attempt(subtask, state, j, rng):
        return AttemptFailure("reach")

    rep = multi_step_search(0, ["s"] * 3, attempt, m=50, time_limit_s=5.0, clock=clock)
    assert not rep.success
    assert rep.failure_constraint == TIME_LIMIT
    assert rep.n_attempts < 10


def test_search_rejects_m_below_one():
    with pytest.raises(ValueError):
        multi_step_search(0, ["s"], lambda *a: Step(0, None), m=0)


def test_progress_callback_sees_every_successful_attempt():
    seen = []
    multi_step_search(0, ["s"] * 3, lambda t, s, j, r: Step(s + 1, s), m=2,
                      on_progress=lambda d, n, k: seen.append((d, n)))
    assert seen == [(1, 3), (2, 3), (3, 3)]
    assert np.all(np.diff([d for d, _ in seen]) == 1)


def test_a_fatal_failure_stops_the_search_at_once():
    calls = []

    def attempt(subtask, state, j, rng):
        calls.append((subtask, j))
        if subtask == "grasp_tread":
            return AttemptFailure("hold:hold.env_surface", "a grasp needs a cylinder", fatal=True)
        return Step(state + 1, segment=subtask)

    rep = multi_step_search(0, ["step", "step", "grasp_tread", "step"], attempt, m=5)
    assert not rep.success
    assert rep.failure_constraint == "hold:hold.env_surface"
    assert calls == [("step", 0), ("step", 0), ("grasp_tread", 0)]  # no backtracking


def test_backtrack_window_stops_a_search_whose_frontier_fails_from_every_predecessor():
    # sub-task 5 fails whatever the state: unbounded, the search backtracks through 3^5 branches;
    # with a window of 1 it tries sub-task 4's other attempts (each followed by sub-task 5's
    # three) and stops there, stuck, naming the frontier's constraint
    def attempt(subtask, state, j, rng):
        if subtask == 5:
            return AttemptFailure("friction")
        return Step(state + 1, segment=state)

    unbounded = multi_step_search(0, list(range(7)), attempt, m=3)
    assert not unbounded.success and not unbounded.stuck
    assert unbounded.n_attempts == sum(3 ** k for k in range(1, 7))  # every branch to sub-task 5
    rep = multi_step_search(0, list(range(7)), attempt, m=3, backtrack_window=1)
    assert not rep.success and rep.stuck
    assert rep.deepest == 5 and rep.failure_constraint == "friction"
    assert rep.n_attempts == 5 + 3 + 2 * (1 + 3)  # down to 5, its 3, then sub-task 4's two others
    assert len(rep.segments) == 5  # the best partial branch
    # a window wide enough for the branch that works finds it
    def attempt_dead_end(subtask, state, j, rng):  # sub-task 3 fails after sub-task 1's first attempt
        if subtask == 1:
            return Step("bad" if j == 0 else "good", segment=j)
        if subtask == 3 and state == "bad":
            return AttemptFailure("reach")
        return Step(state, segment=subtask)

    assert not multi_step_search(0, list(range(5)), attempt_dead_end, m=2, backtrack_window=1).success
    found = multi_step_search(0, list(range(5)), attempt_dead_end, m=2, backtrack_window=2)
    assert found.success and not found.stuck
    with pytest.raises(ValueError, match="backtrack_window"):
        multi_step_search(0, [1], attempt, backtrack_window=-1)


def test_a_prefix_made_before_is_kept_and_not_backtracked_into():
    calls = []

    def attempt(subtask, state, j, rng):
        calls.append((subtask, state))
        if subtask == 3 and state == 12:  # fails from the state the prefix leads to
            return AttemptFailure("collision:knee|step")
        return Step(state + 1, segment=f"s{subtask}")

    prefix = [("p0", 10), ("p1", 11)]
    rep = multi_step_search(0, list(range(4)), attempt, m=2, prefix=prefix)
    assert calls[0] == (2, 11)  # starts after the prefix, from its last state
    assert not rep.success and not rep.stuck and all(i >= 2 for i, _, _ in rep.trace)
    assert rep.deepest == 3 and rep.segments[:2] == ["p0", "p1"] and rep.states[:2] == [10, 11]
    assert multi_step_search(0, list(range(4)), attempt, m=2, prefix=prefix, backtrack_window=4).stuck
    ok = multi_step_search(0, list(range(4)), attempt, m=2, prefix=[("p0", 20), ("p1", 21)])
    assert ok.success and ok.segments == ["p0", "p1", "s2", "s3"] and ok.states == [20, 21, 22, 23]
