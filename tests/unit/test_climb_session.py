"""climb_coordinator.session: the decisions shared by the in-process climb and the coordinator
node, driven through fake ports (no planner, no simulator, no ROS)."""
from __future__ import annotations

import numpy as np
import pytest

from climb_core.contact import Stance, Transition, WholeBodyPlan
from climb_core.errors import SpecError
from climb_coordinator.session import ClimbRequest, ClimbSession, ExecStatus, PlanOutcome, check_request


class Settings:
    extra_time_s = 10.0
    settle_time_s = 1.0
    foot_force_min = 20.0
    failure_recovery_s = 3.0


def _plan(n: int) -> WholeBodyPlan:
    t = [Transition(f"p{i}", "", Stance(()), Stance(()), np.array([0.0, 1.0]), np.zeros((2, 7))) for i in range(n)]
    return WholeBodyPlan("g1", "default", [], Stance(()), t)


class Plans:
    def __init__(self, outcomes):
        self.outcomes = list(outcomes)
        self.calls = []
        self.starts = []

    def plan(self, steps, start=None, surface_offsets=None):
        self.calls.append((steps, start is not None))
        self.starts.append((start, surface_offsets))
        return self.outcomes.pop(0)


class Executor:
    def __init__(self, statuses, settles=()):
        self.statuses = list(statuses)
        self.settles = list(settles)  # what settle returns (else the last status)
        self.started = []

    def start(self, plan):
        self.started.append(plan)

    def run(self, budget_s, stop):
        self.last = self.statuses.pop(0)
        return self.last

    def settle(self, duration_s):
        if self.settles:
            self.last = self.settles.pop(0)
        return self.last

    def measured_q(self):
        return np.zeros(7)

    def report(self):
        return {"wall_time_s": 1.0}


class Judge:
    def __init__(self, rung):
        self.rung = rung

    def feet_rungs(self):
        return {"left_foot": self.rung, "right_foot": self.rung}

    def grasps(self):
        return {}


def test_success_needs_hold_no_fall_and_both_feet_on_the_rung():
    s = ClimbSession(ClimbRequest(rungs=2), Settings(), Plans([PlanOutcome(True, _plan(4), 1.5, 5)]),
                     Executor([ExecStatus(10.0, "hold", 3)]), Judge(2)).run()
    assert s["success"] and s["rungs_reached"] == 2 and s["transitions_done"] == 3 and s["plan_time_s"] == 1.5
    s = ClimbSession(ClimbRequest(rungs=2), Settings(), Plans([PlanOutcome(True, _plan(4), 1.0, 5)]),
                     Executor([ExecStatus(10.0, "hold", 3)]), Judge(1)).run()
    assert not s["success"] and "need both on rung >= 2" in s["failure_reason"]


def test_replan_needed_replans_from_the_measured_state_bounded():
    plans = Plans([PlanOutcome(True, _plan(4), 1.0, 5), PlanOutcome(True, _plan(3), 2.0, 4),
                   PlanOutcome(True, _plan(3), 2.0, 4)])
    ex = Executor([ExecStatus(5.0, "replan_needed", 2), ExecStatus(8.0, "replan_needed", 1)])
    s = ClimbSession(ClimbRequest(rungs=1, max_forced_replans=1), Settings(), plans, ex, Judge(0)).run()
    assert [r["reason"] for r in s["replans"]] == ["replan_needed"]
    assert plans.calls == [(1, False), (1, True)]  # the replan from the measured state
    assert not s["success"] and "replan_needed" in s["failure_reason"]
    assert s["transitions_done"] == 2 + 1 and s["n_transitions"] == 2 + 3
    assert s["plan_time_s"] == 3.0


def _held_plan(n: int) -> WholeBodyPlan:
    """n foot placements on rung_1, rung_2, ...: transition i's target stance has the left foot on rung_{i+1}."""
    from climb_core.contact import ContactPoint, Hold

    def stance(k):
        return Stance((Hold("left_foot", "left_sole", f"rung_{k}", (ContactPoint([0.4, 0.0, 0.25 * k], [0, 0, 1]),),
                            0.5),), name=f"s{k}")
    t = [Transition(f"p{i}", "left_foot", stance(i), stance(i + 1), np.array([0.0, 1.0]), np.zeros((2, 7)))
         for i in range(n)]
    return WholeBodyPlan("g1", "default", [], stance(0), t)


def test_a_contact_found_off_the_plan_replans_from_the_loaded_stance_in_the_corrected_model():
    """replan_needed (contact_offset) after transition 1 loaded rung_2 found 3 cm high: the replan
    starts from that transition's target stance with the hold moved up, the planner's model gets
    rung_2's offset (accumulated over replans), and the completed transition counts as done."""
    plans = Plans([PlanOutcome(True, _held_plan(4), 1.0, 5), PlanOutcome(True, _held_plan(2), 1.0, 3),
                   PlanOutcome(True, _held_plan(2), 1.0, 3)])
    ex = Executor([ExecStatus(5.0, "replan_needed", 1, replan_reason="contact_offset",
                              surface_offset=("rung_2", (0.0, 0.0, 0.03))),
                   ExecStatus(7.0, "replan_needed", 0, replan_reason="contact_offset",
                              surface_offset=("rung_2", (0.0, 0.0, -0.004))),
                   ExecStatus(9.0, "hold", 1)])
    s = ClimbSession(ClimbRequest(rungs=2, max_forced_replans=2), Settings(), plans, ex, Judge(2)).run()
    assert s["success"], s["failure_reason"]
    assert [r["why"] for r in s["replans"]] == ["contact_offset", "contact_offset"]
    assert s["replans"][0]["surface_offset"] == {"rung_2": [0.0, 0.0, 0.03]}
    (start, offsets) = plans.starts[1]
    q, stance = start
    assert stance.name == "s2" and stance.hold("left_foot").env_surface == "rung_2"
    assert stance.hold("left_foot").points[0].position == pytest.approx([0.4, 0.0, 0.53])
    assert offsets == {"rung_2": [0.0, 0.0, 0.03]}
    assert plans.starts[2][1] == {"rung_2": [0.0, 0.0, pytest.approx(0.026)]}  # accumulated
    assert s["transitions_done"] == 2 + 1 + 1  # 2 of plan 1 (1 completed), 1 of plan 2, 1 of plan 3


def test_a_fault_or_a_fall_stops_without_replanning():
    for status, text in ((ExecStatus(5.0, "transfer", 2, fault="dead node: controller"), "dead node: controller"),
                         (ExecStatus(5.0, "transfer", 2, fell=True, fall_reason="base low"), "fell: base low"),
                         (ExecStatus(5.0, "failure", 2), "controller ended in failure")):
        plans = Plans([PlanOutcome(True, _plan(4), 1.0, 5)])
        s = ClimbSession(ClimbRequest(rungs=1), Settings(), plans, Executor([status]), Judge(0)).run()
        assert not s["success"] and text in s["failure_reason"] and len(plans.calls) == 1


def test_a_controller_failure_that_recovers_is_replanned_from_the_measured_state():
    """The controller entered failure at transition 2; the session waits (settle) and the hold QP
    solves again: replan_needed (qp_failure), one replan from the stance before transition 2."""
    plans = Plans([PlanOutcome(True, _plan(4), 1.0, 5), PlanOutcome(True, _plan(2), 1.0, 3)])
    ex = Executor([ExecStatus(5.0, "failure", 1), ExecStatus(12.0, "hold", 1)],
                  settles=[ExecStatus(8.0, "replan_needed", 1, replan_reason="qp_failure")])
    s = ClimbSession(ClimbRequest(rungs=1), Settings(), plans, ex, Judge(1)).run()
    assert s["success"], s["failure_reason"]
    assert [(r["reason"], r["why"]) for r in s["replans"]] == [("replan_needed", "qp_failure")]
    assert len(plans.calls) == 2 and plans.calls[1][1]  # replanned from (measured q, stance)


def test_cancel_is_reported_as_cancelled():
    s = ClimbSession(ClimbRequest(rungs=1), Settings(), Plans([PlanOutcome(True, _plan(4), 1.0, 5)]),
                     Executor([ExecStatus(5.0, "transfer", 2, fault="cancelled", cancelled=True)]), Judge(0)).run()
    assert s["cancelled"] and not s["success"] and s["failure_reason"].startswith("cancelled")


def test_plan_cycles_plans_the_rest_at_each_hold():
    plans = Plans([PlanOutcome(True, _plan(4), 1.0, 5), PlanOutcome(True, _plan(2), 1.0, 3)])
    ex = Executor([ExecStatus(5.0, "hold", 3), ExecStatus(9.0, "hold", 1)])
    s = ClimbSession(ClimbRequest(rungs=2, plan_cycles=1), Settings(), plans, ex, Judge(2)).run()
    assert s["success"] and [r["reason"] for r in s["replans"]] == ["plan_cycles"]
    assert s["transitions_done"] == 4 + 1 and s["n_transitions"] == 6


def test_a_failed_plan_is_the_failure_reason():
    s = ClimbSession(ClimbRequest(rungs=1), Settings(), Plans([PlanOutcome(False, None, 3.0, failure="reach: x")]),
                     Executor([]), Judge(0)).run()
    assert not s["success"] and s["failure_reason"] == "plan: reach: x"


@pytest.mark.parametrize("changes, field", [({"robot": "nobody"}, "robot"), ({"rungs": 5}, "rungs"),
                                            ({"ladder": "no_such_ladder"}, "source"), ({"mode": "x"}, "mode"),
                                            ({"start_posture": "ladder_4_contacts"}, "start_posture"),
                                            ({"start_posture": "ladder_4_contacts", "strategy": "search",
                                              "descend": True}, "strategy"),
                                            ({"ladder": "step_up", "strategy": "primitives"}, "strategy"),
                                            ({"ladder": "step_up", "strategy": "search",
                                              "start_posture": "ladder_4_contacts"}, "start_posture"),
                                            ({"ladder": "stairs", "rungs": 3, "strategy": "primitives"}, "rungs"),
                                            ({"strategy": "forward"}, "strategy"),
                                            ({"ladder": "stairs", "rungs": 9, "strategy": "search"}, "rungs")])
def test_check_request_refuses_with_the_field(changes, field):
    with pytest.raises(SpecError) as err:
        check_request(ClimbRequest(**changes))
    assert err.value.field == field
    check_request(ClimbRequest(rungs=4))  # the default ladder gives G1 rung 4 (hands on rung 8)
    check_request(ClimbRequest(ladder="step_up", strategy="search"))  # a scene: through the graph too
    # the search chooses its holds (on the stairs, the rails): the primitives' hands-on-a-rung bound
    # does not apply, the ladder's rungs do
    check_request(ClimbRequest(ladder="stairs", rungs=3, strategy="search"))
    check_request(ClimbRequest(ladder="stairs", rungs=3))  # chosen: search
    check_request(ClimbRequest(ladder="step_up"))


@pytest.mark.parametrize("ladder, strategy, reason", [
    ("default", "primitives", "regular ladder at 75 deg (> guide_path.walk_max_incline_deg 60)"),
    ("stairs", "search", "stairs ladder at 35 deg (<= guide_path.walk_max_incline_deg 60): walked up"),
    ("ship", "search", "ship ladder at 60 deg (<= guide_path.walk_max_incline_deg 60): walked up"),
    ("step_up", "search", "a scene without a ladder"),
    ("vertical", "primitives", "vertical ladder at 90 deg"),
    ("vertical", "primitives", "steep (>= 84 deg, climb.steep_ladder)")])
def test_a_request_naming_no_strategy_gets_the_scenarios_with_the_reason(ladder, strategy, reason):
    from climb_coordinator.session import base_summary, with_chosen_strategy

    req = with_chosen_strategy(ClimbRequest(ladder=ladder))
    assert req.strategy == strategy and reason in req.strategy_reason, req.strategy_reason
    summary = base_summary(req)
    assert summary["strategy"] == strategy and summary["strategy_reason"] == req.strategy_reason
    # a named strategy is kept as it is (no reason); a spec that does not load keeps the primitives'
    # checks, which then name its broken field
    assert with_chosen_strategy(ClimbRequest(ladder=ladder, strategy="search")).strategy_reason == ""
    assert with_chosen_strategy(ClimbRequest(ladder="no_such_ladder")).strategy == "primitives"


class SceneJudge(Judge):
    """A scene's judge: the base's position [m] and speed [m/s] as the simulator would give them."""

    def __init__(self, position, speeds):
        super().__init__(None)
        self.position = np.asarray(position, float)
        self.speeds = list(speeds)

    def base(self):
        return self.position, self.speeds.pop(0) if len(self.speeds) > 1 else self.speeds[0]


def _scene_session(position, speeds, status=None, **request):
    plan = _held_plan(2)
    session = ClimbSession(ClimbRequest(ladder="narrow_passage_step", strategy="search", **request), Settings(),
                           Plans([PlanOutcome(True, plan, 1.0, 3)]),
                           Executor([status or ExecStatus(10.0, "hold", 1)]), SceneJudge(position, speeds))
    session.goal = (np.array([1.05, 0.0, 1.11]), 0.15)
    return session.run()


def test_a_scene_is_judged_on_its_goal_not_on_rungs():
    """scene_spec.md, Results: success = the base within the goal's tolerance, standing still over
    the settle (< 0.02 m/s at every 0.1 s sample), nothing fallen; rungs 0; contacts_used from the plan."""
    s = _scene_session([1.0, 0.05, 1.12], [0.01])
    assert s["success"] and s["goal_reached"], s["failure_reason"]
    assert s["rungs_requested"] == s["rungs_reached"] == 0 and s["scene"] == "narrow_passage_step"
    assert s["goal_distance_m"] == pytest.approx(np.linalg.norm([0.05, 0.05, 0.01]), abs=1e-4)
    assert s["contacts_used"] == ["rung_0", "rung_1", "rung_2"]  # every surface the plan holds
    far = _scene_session([0.5, 0.0, 1.11], [0.0])
    assert not far["success"] and not far["goal_reached"] and "from the goal" in far["failure_reason"]
    # one sample of the settle above 0.02 m/s: not standing still, not reached
    moving = _scene_session([1.05, 0.0, 1.11], [0.0] * 5 + [0.05] + [0.0] * 10)
    assert not moving["goal_reached"] and "not standing still" in moving["failure_reason"]
    assert moving["settle_base_speed_max_m_s"] == pytest.approx(0.05)
    fell = _scene_session([1.05, 0.0, 1.11], [0.0], ExecStatus(10.0, "hold", 1, fell=True, fall_reason="base low"))
    assert not fell["goal_reached"] and "fell: base low" in fell["failure_reason"]
