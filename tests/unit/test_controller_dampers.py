"""An infeasible QP whose conflict is a collision damper against the held contacts: the
controller releases dampers for that tick instead of failing (``Controller._solve_without_blocked_dampers``):
first the pairs within the security distance, then every pair whose damper demands a separating
acceleration. Measured on the 70-74 deg / 32 cm grid ladders: with one foot on rung 2 the left knee
is 6 mm under rung 3 and its damper asks 4.7 m/s^2 of separation the foot's contact forbids (the
QP feasible without the collision rows, infeasible with them), and the climb fell."""
from __future__ import annotations

import numpy as np
import pytest

from controller_node.constraints import DamperRow
from controller_node.controller import Controller
from controller_node.params import load_controller_params
from controller_node.qp import QpFailure


@pytest.fixture()
def controller(g1, env):
    return Controller(g1, load_controller_params(), env)


def _rows(nv: int, ds: float) -> list[DamperRow]:
    z = np.zeros(nv)
    return [DamperRow("right_knee_link|rung_2", 0.5 * ds, 0.0, z, 0.3),  # within the security distance
            DamperRow("left_knee_link|rung_3", ds + 0.002, -0.041, z, 4.67),  # outside it, pushing
            DamperRow("left_knee_link|rung_2", 0.043, 0.205, z, -98.5)]  # moving away: not binding


def _stub(controller, nv: int, monkeypatch, needs: set) -> list:
    """The controller's last dampers are :func:`_rows`; its QP is feasible only with the pairs
    ``needs`` released. Returns the list of released sets each solve was called with."""
    rows = _rows(nv, controller.params.collision.security_distance)
    monkeypatch.setattr(controller.wb, "last_dampers", lambda: rows)
    calls: list = []

    def solve(contacts, tasks, disabled=frozenset()):
        calls.append(frozenset(disabled))
        if not needs <= set(disabled):
            raise QpFailure(None, -1, "daqp", "infeasible")
        return "solved"

    monkeypatch.setattr(controller.wb, "solve", solve)
    controller.events.clear()
    return calls


def test_a_pushing_damper_is_released_after_the_pairs_within_the_security_distance(g1, controller, monkeypatch):
    calls = _stub(controller, g1.model.nv, monkeypatch, {("left_knee_link", "rung_3")})
    out = controller._solve_without_blocked_dampers([], frozenset({("a", "b")}))
    assert out == "solved"
    within = frozenset({("a", "b"), ("right_knee_link", "rung_2")})
    assert calls == [within, within | {("left_knee_link", "rung_3")}]  # the receding pair is never released
    released, = controller.events_of("dampers_released")
    assert sorted(released.values["pairs"]) == ["left_knee_link|rung_3", "right_knee_link|rung_2"]
    assert controller.dampers_released == 1


def test_the_pairs_within_the_security_distance_alone_when_they_suffice(g1, controller, monkeypatch):
    calls = _stub(controller, g1.model.nv, monkeypatch, {("right_knee_link", "rung_2")})
    assert controller._solve_without_blocked_dampers([], frozenset()) == "solved"
    assert calls == [frozenset({("right_knee_link", "rung_2")})]


def test_a_conflict_the_dampers_do_not_explain_stays_a_failure(g1, controller, monkeypatch):
    calls = _stub(controller, g1.model.nv, monkeypatch, {("left_knee_link", "rung_2")})
    assert controller._solve_without_blocked_dampers([], frozenset()) is None
    assert len(calls) == 2 and not controller.events_of("dampers_released") and controller.dampers_released == 0
    monkeypatch.setattr(controller.wb, "last_dampers", lambda: [])
    assert controller._solve_without_blocked_dampers([], frozenset()) is None and len(calls) == 2
