"""Multi-step planning: MSP-Recurse of ladder_climbing_drc_hubo.txt (section III-D).

A depth-first search over a fixed sequence of sub-tasks (one motion primitive each). Every
sub-task gets up to ``m`` adaptation attempts from the state its predecessor reached; a success
recurses into the next sub-task, a sub-task whose ``m`` attempts all fail (directly or through
their descendants) sends the search back to its predecessor's next attempt (backtracking). With a
``backtrack_window`` W the search stops instead when the sub-task W below the frontier (the
deepest sub-task reached) has exhausted its attempts, or when every branch is (``SearchReport.stuck``;
0: no backtracking past the frontier): on a long sequence of generic steps
(a searched contact plan of 60 stances) a transition that no predecessor state makes feasible
would otherwise send the search through m^k branches; the caller changes the sequence instead.

The search is problem-agnostic: the caller supplies ``attempt(subtask, state, attempt_index,
rng)`` returning either a :class:`Step` (success: next state + the path segment that leads there)
or a :class:`AttemptFailure` naming the constraint that stopped it. This keeps the search
testable on toy problems and reusable by the node.

Determinism: the random generator of an attempt is seeded from ``seed`` and the attempt indices
of the whole branch leading to it, so a run is reproducible whatever the timing, and a branch
explored after backtracking does not replay the random numbers of a dead branch. The wall-time
limit only decides *whether* the search finishes, never which branch it takes.
"""
from __future__ import annotations

import collections
import time
from dataclasses import dataclass, field
from typing import Any, Callable, Generic, Sequence, TypeVar

import numpy as np

S = TypeVar("S")  # search state (e.g. configuration + stance)
T = TypeVar("T")  # sub-task description (e.g. a motion primitive)

#: Failure constraint reported when the wall-time limit stops the search.
TIME_LIMIT = "time_limit"


@dataclass(frozen=True)
class Step(Generic[S]):
    """A successful attempt: the state reached and the path segment leading to it."""

    state: S
    segment: Any
    info: dict = field(default_factory=dict)


@dataclass(frozen=True)
class AttemptFailure:
    """A failed attempt; ``constraint`` is a short machine-readable name (reach, collision:..)."""

    constraint: str
    detail: str = ""
    #: no other choice upstream can fix it (e.g. the ladder has no surface this primitive can
    #: hold): the whole search stops instead of backtracking
    fatal: bool = False


@dataclass
class SearchReport(Generic[S]):
    success: bool
    segments: list  # one per sub-task on success, the best partial branch otherwise
    final_state: Any
    n_attempts: int  # adaptation calls made
    n_backtracks: int  # times a sub-task exhausted its attempts and returned failure
    deepest: int  # number of sub-tasks of the deepest branch reached
    elapsed_s: float  # [s]
    failure_constraint: str = ""  # empty on success
    failure_detail: str = ""
    #: failures per sub-task index: Counter(constraint -> count)
    failures: dict[int, collections.Counter] = field(default_factory=dict)
    #: (sub-task index, attempt index, success) of the attempts in the order they were made
    trace: list[tuple[int, int, bool]] = field(default_factory=list)
    #: (sub-task index, attempt index, AttemptFailure) of every failed attempt
    failure_log: list[tuple[int, int, "AttemptFailure"]] = field(default_factory=list)
    #: the backtrack window stopped the search (the sub-task ``deepest`` failed from every
    #: predecessor state tried)
    stuck: bool = False
    #: the state after each segment of ``segments``
    states: list = field(default_factory=list)


class _Timeout(Exception):
    pass


class _Fatal(Exception):
    pass


class _Stuck(Exception):
    pass


def branch_rng(seed: int, branch: Sequence[int]) -> np.random.Generator:
    """Random generator of one attempt, keyed by the seed and the branch's attempt indices."""
    return np.random.default_rng(np.random.SeedSequence([int(seed) & 0xFFFFFFFF, len(branch), *branch]))


def multi_step_search(
    initial_state: S,
    subtasks: Sequence[T],
    attempt: Callable[[T, S, int, np.random.Generator], "Step[S] | AttemptFailure"],
    m: int = 5,
    seed: int = 0,
    time_limit_s: float | None = None,
    on_progress: Callable[[int, int, int], None] | None = None,
    clock: Callable[[], float] = time.monotonic,
    backtrack_window: int | None = None,
    prefix: Sequence[tuple[Any, S]] = (),
) -> SearchReport[S]:
    """Depth-first search with backtracking over ``subtasks`` (MSP-Recurse).

    ``prefix``: (segment, state) of the first ``len(prefix)`` sub-tasks, made before (a repaired
    sequence that shares them): the search starts after them and does not backtrack into them.

    ``on_progress(depth, n_subtasks, n_attempts)`` is called after every successful attempt.
    Returns a :class:`SearchReport`; never raises for a failed search.
    """
    if m < 1:
        raise ValueError(f"m must be >= 1 (attempts per sub-task), got {m}")
    if backtrack_window is not None and backtrack_window < 0:
        raise ValueError(f"backtrack_window must be >= 0 or None, got {backtrack_window}")
    n = len(subtasks)
    start = clock()
    deadline = None if time_limit_s is None else start + float(time_limit_s)
    report: SearchReport[S] = SearchReport(False, [], initial_state, 0, 0, 0, 0.0)
    best_partial: list = list(prefix)
    report.deepest = len(prefix)

    def recurse(i: int, state: S, branch: list[int], segments: list) -> list | None:
        # i = number of sub-tasks already done along this branch
        nonlocal best_partial
        if i == n:
            return segments
        for j in range(m):
            if deadline is not None and clock() > deadline:
                raise _Timeout()
            rng = branch_rng(seed, branch + [j])
            report.n_attempts += 1
            outcome = attempt(subtasks[i], state, j, rng)
            ok = isinstance(outcome, Step)
            report.trace.append((i, j, ok))
            if not ok:
                failure = outcome if isinstance(outcome, AttemptFailure) else AttemptFailure("unknown", repr(outcome))
                report.failures.setdefault(i, collections.Counter())[failure.constraint] += 1
                report.failure_log.append((i, j, failure))
                if failure.fatal:
                    report.failure_constraint, report.failure_detail = failure.constraint, failure.detail
                    raise _Fatal()
                continue
            new_segments = segments + [(outcome.segment, outcome.state)]
            if i + 1 > report.deepest:
                report.deepest = i + 1
                best_partial = new_segments
            if on_progress is not None:
                on_progress(i + 1, n, report.n_attempts)
            found = recurse(i + 1, outcome.state, branch + [j], new_segments)
            if found is not None:
                return found
        report.n_backtracks += 1
        if backtrack_window is not None and report.deepest - i >= backtrack_window:
            raise _Stuck()
        return None

    try:
        found = recurse(len(prefix), prefix[-1][1] if prefix else initial_state, [0] * len(prefix), list(prefix))
        # every branch exhausted: within a window, that is being stuck too (the first sub-task, or
        # the first after the prefix, has no attempt left)
        report.stuck = found is None and backtrack_window is not None
    except _Fatal:
        found = None
    except _Stuck:
        found = None
        report.stuck = True
    except _Timeout:
        found = None
        report.failure_constraint = TIME_LIMIT
        frontier = report.failures.get(report.deepest)
        if frontier:
            report.failure_detail = f"while sub-task {report.deepest} failed most on {frontier.most_common(1)[0][0]}"
    report.elapsed_s = clock() - start
    if found is not None:
        report.success = True
        report.failure_constraint = ""
    chosen = found if found is not None else best_partial
    report.segments = [seg for seg, _ in chosen]
    report.states = [st for _, st in chosen]
    report.final_state = chosen[-1][1] if chosen else initial_state
    if found is not None:
        return report
    if not report.failure_constraint:
        report.failure_constraint, report.failure_detail = frontier_failure(report.failures, report.deepest)
    return report


def frontier_failure(failures: dict[int, collections.Counter], deepest: int) -> tuple[str, str]:
    """The constraint that stopped the search: the most frequent failure at the deepest sub-task
    reached (the frontier), falling back to shallower ones."""
    for i in range(deepest, -1, -1):
        counts = failures.get(i)
        if counts:
            name, k = counts.most_common(1)[0]
            total = sum(counts.values())
            return name, f"sub-task {i}: {k}/{total} attempts failed on {name}; all: {dict(counts)}"
    return "unknown", "no attempt recorded"
