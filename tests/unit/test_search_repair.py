"""pipeline.search_and_adapt: a searched plan whose adaptation is stuck at a transition is
searched again without that transition (the loop on fakes of the two stages; the stages
themselves are tested in test_contact_search.py, test_planner_msp.py and the scene tests)."""
from __future__ import annotations

from types import SimpleNamespace

import pytest

from climb_core.errors import InfeasibleError
from planner_node import contact_search, pipeline
from planner_node.settings import load_settings


def _problem(rounds: int):
    import dataclasses

    s = load_settings()
    s = dataclasses.replace(s, contact_search=dataclasses.replace(s.contact_search, repair_rounds=rounds))
    return SimpleNamespace(request=SimpleNamespace(timeout_s=60.0), settings=s)


@pytest.fixture
def stages(monkeypatch):
    """Fake stages: the search returns plan ``k`` (k = number of bans so far); the adaptation is
    stuck at sub-task 3 (stance pair 2) while ``stuck_rounds`` plans remain, then succeeds."""
    calls = SimpleNamespace(banned=[], previous=[], stuck_rounds=2, search_fails_after=None)

    def search(problem, path, banned=(), time_limit_s=None):
        k = len(banned)
        calls.banned.append(list(banned))
        assert time_limit_s is not None and 0 < time_limit_s <= 60.0
        if calls.search_fails_after is not None and k > calls.search_fails_after:
            raise InfeasibleError("contact_search:exhausted", "no sequence without the banned transitions")
        return pipeline.StageResult(SimpleNamespace(name=f"plan{k}"), {"time_s": 1.0})

    def adapt(problem, plan, on_progress=None, timeout_s=None, previous=None):
        calls.previous.append(previous)
        stuck = int(plan.name[4:]) < calls.stuck_rounds
        report = SimpleNamespace(stuck=stuck, deepest=3)
        res = SimpleNamespace(success=not stuck, report=report,
                              contact_steps=[SimpleNamespace(pair=p) for p in (0, 1, 1, 2, 3)],
                              subtasks=["a", "b", "c", "generic_right_hand_2", "e"],
                              failure_constraint="friction" if stuck else "")
        return res, {"plan": plan.name}

    monkeypatch.setattr(pipeline, "contact_search_search", search)
    monkeypatch.setattr(pipeline, "adapt_search", adapt)
    monkeypatch.setattr(contact_search, "banned_transition", lambda plan, i, r: (plan.name, i))
    monkeypatch.setattr(contact_search, "moves_of", lambda plan: [f"m{plan.name[4:]}_{i}" for i in range(6)])
    return calls


def test_a_stuck_transition_is_searched_again_without_it(stages):
    contacts, res, summary = pipeline.search_and_adapt(_problem(rounds=4), path=None)
    assert res.success and summary == {"plan": "plan2"}
    # each search got the transitions the stuck adaptations before it could not make
    assert stages.banned == [[], [("plan0", 2)], [("plan0", 2), ("plan1", 2)]]
    # each adaptation after the first got the stuck one before it (the sub-tasks they share)
    assert stages.previous[0] is None and [p.failure_constraint for p in stages.previous[1:]] == ["friction"] * 2
    repairs = contacts.summary["repairs"]
    assert [(r["transition"], r["move"], r["subtask"], r["constraint"]) for r in repairs] == [
        (2, "m0_2", "generic_right_hand_2", "friction"), (2, "m1_2", "generic_right_hand_2", "friction")]


def test_the_repairs_are_bounded_and_a_failed_repair_search_keeps_the_last_plan(stages):
    stages.stuck_rounds = 99
    contacts, res, _ = pipeline.search_and_adapt(_problem(rounds=1), path=None)
    assert not res.success and res.report.stuck and len(contacts.summary["repairs"]) == 1
    assert len(stages.banned) == 2
    stages.banned.clear()
    stages.search_fails_after = 0  # no sequence without the first ban: the stuck plan is the result
    contacts, res, _ = pipeline.search_and_adapt(_problem(rounds=4), path=None)
    assert contacts.product.name == "plan0" and not res.success
    assert "no sequence" in contacts.summary["repairs"][0]["search"]
    stages.banned.clear()
    stages.search_fails_after = -1  # the first search fails: that is the planning failure
    with pytest.raises(InfeasibleError, match="exhausted"):
        pipeline.search_and_adapt(_problem(rounds=4), path=None)


def test_the_graph_adaptation_stage_repairs_a_stuck_searched_plan(stages, monkeypatch):
    """primitive_adaptation's library call (pipeline.adapt_and_repair): the contact plan received
    from the contact_search node is adapted; stuck, the guide path is planned again and the plan
    repaired as in process; a plan that is not stuck, or of the primitives strategy, is not."""
    problem = _problem(rounds=4)
    first = SimpleNamespace(name="plan0")
    monkeypatch.setattr(pipeline, "strategy_of", lambda problem, strategy: strategy)
    monkeypatch.setattr(pipeline, "adapt", lambda problem, plan, on_progress, strategy:
                        stages_adapt(problem, plan))
    paths = []
    monkeypatch.setattr(pipeline, "guide_path", lambda problem, strategy: paths.append(strategy) or
                        pipeline.StageResult("path", {}))

    def stages_adapt(problem, plan):
        return pipeline.adapt_search(problem, plan)

    res, summary = pipeline.adapt_and_repair(problem, first, strategy="search")
    assert res.success and summary["plan"] == "plan2" and paths == ["search"]
    assert [r["transition"] for r in summary["repairs"]] == [2, 2]
    stages.stuck_rounds = 99
    res, summary = pipeline.adapt_and_repair(problem, first, strategy="primitives")
    assert not res.success and "repairs" not in summary and paths == ["search"]
