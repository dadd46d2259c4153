"""Contact FSM: the transition table (config/fsm/default.yaml) and the state sequence the
controller runs through for a plan, with the controller's QP accelerations integrated as the
robot's motion (the paper's kinematic mode) and the F/T of a moving limb from a stiff spring
where its target rung is (no simulator)."""
from __future__ import annotations

import copy

import numpy as np
import pinocchio as pin
import pytest
import yaml

from climb_core import fixtures
from climb_core.errors import SpecError
from controller_node.controller import Controller
from controller_node.estimator import RobotState
from controller_node.fsm import load_fsm_table, parse_fsm_table
from controller_node.params import load_controller_params
from controller_node.simple_plans import limb_transfer, plan_of


@pytest.fixture(scope="module")
def table_doc():
    from climb_core.ros_env import project_root

    with open(project_root() / "config" / "fsm" / "default.yaml") as stream:
        return yaml.safe_load(stream)


def test_default_table_routes_hands_and_feet_differently(table_doc):
    table = parse_fsm_table(table_doc)
    assert table.initial == "idle"
    assert table.next_state("unload", "unloaded", "right_hand") == "open_gripper"
    assert table.next_state("unload", "unloaded", "left_foot") == "transfer"
    assert table.next_state("transfer", "contact", "left_hand") == "close_gripper"
    assert table.next_state("transfer", "contact", "right_foot") == "load"
    assert table.next_state("search", "exhausted", "right_foot") == "replan_needed"
    # a hand pushing with its palm (unilateral hold) has no gripper states
    assert table.next_state("unload", "unloaded", "right_hand", "palm") == "transfer"
    assert table.next_state("transfer", "contact", "left_hand", "palm") == "load"
    assert table.next_state("search", "contact", "left_hand", "palm") == "load"
    assert table.next_state("search", "exhausted", "left_hand", "palm") == "replan_needed"
    # the wildcard row: a QP failure leads to the failure state from anywhere
    for state in table.states:
        assert table.next_state(state, "qp_failure", "left_hand") == "failure"
    assert table.next_state("idle", "contact", "left_hand") is None


@pytest.mark.parametrize("mutate, field", [
    (lambda d: d.update(initial="nowhere"), "initial"),
    (lambda d: d["transitions"].append({"from": "idle", "event": "plan", "to": "hold"}), "transitions[N]"),
    (lambda d: d["transitions"].append({"from": "idle", "event": "x", "to": "moon"}), "transitions[N].to"),
    (lambda d: d["transitions"].append({"from": "idle", "event": "x", "to": "hold", "limb": "tail"}),
     "transitions[N].limb"),
    (lambda d: d["states"].update(dance="not a state class"), "states.dance"),
    (lambda d: d.update(typo=1), "typo"),
    (lambda d: d.__setitem__("transitions", [r for r in d["transitions"] if r["event"] != "closed"]), "transitions"),
    # a table without the palm rows: a palm push's contact would have nowhere to go
    (lambda d: d.__setitem__("transitions", [r for r in d["transitions"] if r.get("limb") != "palm"]), "transitions"),
])
def test_bad_tables_are_rejected_naming_the_field(table_doc, mutate, field):
    doc = copy.deepcopy(table_doc)
    field = field.replace("N", str(len(doc["transitions"])))  # the appended row's index
    mutate(doc)
    with pytest.raises(SpecError) as info:
        parse_fsm_table(doc, source="fsm")
    assert info.value.field == f"fsm.{field}"


def test_load_fsm_table_by_name_and_missing_file():
    assert "transfer" in load_fsm_table("default").states
    with pytest.raises(SpecError):
        load_fsm_table("no_such_table")


class KinematicLoop:
    """Integrates the QP's qdd (perfect tracking); a moving hand feels a stiff spring when it
    pushes past the target rung's surface along the approach (its wrist F/T)."""

    def __init__(self, controller: Controller, q: np.ndarray, rung_offset: float = 0.0):
        self.c = controller
        self.q = q.copy()
        self.v = np.zeros(controller.model.nv)
        self.t = 0.0
        self.offset = rung_offset  # [m] the real rung is this far along the approach from the plan
        self.k_wall = 2000.0  # [N/m]
        self.contact_plane = None  # (point, approach direction) of the hand's target

    def ft(self) -> dict[str, np.ndarray]:
        c = self.c
        out = {s: np.zeros(6) for s in c.robot.config.ft_sensors}
        near = c.fsm.state in ("close_gripper", "load", "hold") or (c.fsm.state in ("transfer", "search")
                                                                   and c.path.in_approach())
        if self.contact_plane is None or c.moving_limb != "right_hand" or not near:
            return out  # (the plane is infinite: only the approach meets it, not the hand lifting off)
        point, direction = self.contact_plane
        data = c.model.createData()
        pin.framesForwardKinematics(c.model, data, self.q)
        fid = c.limb_frame_ids["right_hand"]
        p = data.oMf[fid].act(c.limb_surface["right_hand"][:3, 3])
        depth = float((p - point) @ direction)
        if depth > 0.0:  # the rung pushes the hand back; the hand pushes the wrist back
            sensor = c.limbs["right_hand"].ft_sensor
            R = data.oMf[c.ft.frames[sensor]].rotation
            out[sensor][:3] = R.T @ (-self.k_wall * depth * direction)
        return out

    def step(self):
        state = RobotState(self.t, self.q.copy(), self.v.copy(), self.ft())
        out = self.c.tick(state)
        dt = self.c.params.control_period_s
        qdd = self.c.last_result.qdd if out.status.qp_status == 0 else np.zeros_like(self.v)
        self.v = self.v + qdd * dt
        self.q = pin.integrate(self.c.model, self.q, self.v * dt)
        self.t += dt
        return out


def _run_until_settled(loop: KinematicLoop, ticks: int):
    """Tick until the FSM rests (hold, failure, replan_needed) or ``ticks`` pass: the states
    visited, in order, and the last output."""
    states, out = [], None
    for _ in range(ticks):
        out = loop.step()
        if not states or states[-1] != out.status.fsm_state:
            states.append(out.status.fsm_state)
        if out.status.fsm_state in ("hold", "failure", "replan_needed"):
            break
    return states, out


@pytest.fixture(scope="module")
def ladder():
    from climb_core.environment import build_environment
    from climb_core.ladder import load_scenario
    from climb_core.robot import load_robot

    robot = load_robot("g1")
    env = build_environment(load_scenario("default"))
    stance, q = fixtures.get("ladder_4_contacts", robot, env)
    transition = limb_transfer(robot, env, stance, q, "right_hand", "rung_6", -0.15)
    return robot, env, stance, q, transition


@pytest.mark.parametrize("offset, expect_early", [(-0.015, True), (0.015, False)])
def test_hand_transfer_runs_remove_then_add_contact_states_and_stops_on_ft_contact(ladder, offset, expect_early):
    robot, env, stance, q, transition = ladder
    params = load_controller_params(**{"collision.enabled": False})
    controller = Controller(robot, params, env)
    loop = KinematicLoop(controller, q)
    controller.reset(RobotState(0.0, q, np.zeros(robot.nv)), stance)
    controller.set_plan(plan_of(robot, env, stance, [transition]))
    T_target = robot.T_world_surface("right_hand", transition.path[-1])
    approach = T_target[:3, 2]
    # the palm face meets the rung when the grasp centre reaches the rung axis (+ offset)
    loop.contact_plane = (T_target[:3, 3] + offset * approach, approach)
    states, out = _run_until_settled(loop, 1400)
    expected = ["unload", "open_gripper", "transfer"] + ([] if expect_early else ["search"]) + \
        ["close_gripper", "load", "hold"]
    assert states[states.index("unload"):] == expected
    # the controller owns the contact set: released during the transfer, back at the end
    assert set(controller.contacts) == {"left_foot", "right_foot", "left_hand", "right_hand"}
    assert controller.holds["right_hand"].env_surface == "rung_6"
    gripper = [(e.values["hand"], e.values["command"]) for e in controller.events_of("gripper")]
    assert gripper == [("right_hand", "open"), ("right_hand", "position"), ("right_hand", "close")]
    frozen = np.asarray(controller.events_of("limb_frozen")[0].values["position"])
    stop = float((frozen - T_target[:3, 3]) @ approach)
    assert stop == pytest.approx(offset, abs=0.006)  # [m] the hand stopped where the spring is


@pytest.mark.parametrize("offset", [-0.03, 0.03])
def test_a_contact_found_off_the_plan_is_loaded_then_held_for_a_replan(ladder, offset):
    """The rung is 3 cm before / past the planned grasp (beyond guarded.replan_offset = 2 cm): the
    hand closes and loads where the F/T found it, the transition counts as done, and the FSM holds
    in replan_needed (reason contact_offset) with the surface's measured offset."""
    robot, env, stance, q, transition = ladder
    params = load_controller_params(**{"collision.enabled": False, "guarded.replan_offset": 0.02})
    controller = Controller(robot, params, env)
    loop = KinematicLoop(controller, q)
    controller.reset(RobotState(0.0, q, np.zeros(robot.nv)), stance)
    # (a second transition follows: at a plan's last one an offset leaves nothing to replan)
    controller.set_plan(plan_of(robot, env, stance, [transition, transition]))
    T_target = robot.T_world_surface("right_hand", transition.path[-1])
    approach = T_target[:3, 2]
    loop.contact_plane = (T_target[:3, 3] + offset * approach, approach)
    states, out = _run_until_settled(loop, 1600)
    assert states[-3:] == ["close_gripper", "load", "replan_needed"], states
    assert out.status.replan_needed and controller.replan_reason == "contact_offset"
    assert "right_hand" in controller.contacts and controller.holds["right_hand"].env_surface == "rung_6"
    limb, surface, moved, distance = controller.placement_offset
    assert (limb, surface) == ("right_hand", "rung_6")
    assert distance == pytest.approx(offset, abs=0.008)  # [m] signed, along the approach
    assert moved == pytest.approx(distance * controller.path.approach["right_hand"], abs=1e-9)
    (event,) = controller.events_of("replan_needed")
    assert event.values["reason"] == "contact_offset"
    # a new plan is taken from there (the session replans from the transition's target stance)
    controller.set_plan(plan_of(robot, env, stance, []))
    assert controller.replan_reason == ""


def test_a_contact_found_within_the_bound_goes_on_with_the_plan(ladder):
    robot, env, stance, q, transition = ladder
    params = load_controller_params(**{"collision.enabled": False, "guarded.replan_offset": 0.02})
    controller = Controller(robot, params, env)
    loop = KinematicLoop(controller, q)
    controller.reset(RobotState(0.0, q, np.zeros(robot.nv)), stance)
    controller.set_plan(plan_of(robot, env, stance, [transition]))
    T_target = robot.T_world_surface("right_hand", transition.path[-1])
    loop.contact_plane = (T_target[:3, 3] - 0.01 * T_target[:3, 2], T_target[:3, 2])
    _, out = _run_until_settled(loop, 1600)
    assert out.status.fsm_state == "hold" and not controller.events_of("replan_needed")
    (event,) = controller.events_of("contact_offset")
    assert event.values["surface"] == "rung_6" and event.values["distance"] == pytest.approx(-0.01, abs=0.006)


def test_search_gives_up_and_asks_for_replanning_without_contact(ladder):
    robot, env, stance, q, transition = ladder
    params = load_controller_params(**{"collision.enabled": False, "guarded.search_distance": 0.02})
    controller = Controller(robot, params, env)
    loop = KinematicLoop(controller, q)  # no spring: the rung is not where planned
    controller.reset(RobotState(0.0, q, np.zeros(robot.nv)), stance)
    controller.set_plan(plan_of(robot, env, stance, [transition]))
    _, out = _run_until_settled(loop, 1400)
    assert out.status.fsm_state == "replan_needed" and out.status.replan_needed
    assert controller.replan_reason == "no_contact"
    assert "right_hand" not in controller.contacts  # never added without a contact


def test_the_search_is_bounded_by_the_limbs_own_travel_then_by_its_targets_lead(ladder, monkeypatch):
    """A limb that lags its creeping target (a foot lags ~1 cm on the robot) searches until it has
    itself travelled search_distance past the plan; a limb that never gets there (held back by
    something it does not feel) gives up once its target ran search_lead_max further."""
    robot, env, stance, q, transition = ladder
    g = {"guarded.search_distance": 0.02, "guarded.search_lead_max": 0.01}
    ended = {}
    for lag in (0.005, 0.05):  # [m] the limb's travel behind its target's
        params = load_controller_params(**{"collision.enabled": False, **g})
        controller = Controller(robot, params, env)
        true_travel = controller.search_travel
        monkeypatch.setattr(controller, "search_travel", lambda limb, f=true_travel, d=lag: f(limb) - d)
        loop = KinematicLoop(controller, q)  # no rung where planned: the search runs out
        controller.reset(RobotState(0.0, q, np.zeros(robot.nv)), stance)
        controller.set_plan(plan_of(robot, env, stance, [transition]))
        _, out = _run_until_settled(loop, 1600)
        assert out.status.fsm_state == "replan_needed" and controller.replan_reason == "no_contact"
        (ended[lag],) = controller.events_of("search_exhausted")
    # the limb 5 mm behind: its target ran 5 mm further, and the limb itself 2 cm
    assert ended[0.005].values["target_travel"] == pytest.approx(0.025, abs=0.001)
    assert ended[0.005].values["limb_travel"] == pytest.approx(0.02, abs=0.001)
    # the limb far behind: the target's lead ends it (2 + 1 cm), the limb short of 2 cm
    assert ended[0.05].values["target_travel"] == pytest.approx(0.03, abs=0.001)
    assert ended[0.05].values["limb_travel"] < 0.0


def test_a_state_that_cannot_start_leaves_the_fsm_holding(ladder, monkeypatch):
    """A transition the controller cannot start (here start_path raising, as a malformed plan's
    did under fuzzing) is reported to the caller once, and the FSM holds the active contacts
    instead of running the half-started state on the next ticks."""
    robot, env, stance, q, transition = ladder
    controller, loop = _started(ladder, [transition])

    def broken(*args, **kwargs):
        raise ValueError("cannot follow this path")

    monkeypatch.setattr(controller.path, "start", broken)
    with pytest.raises(ValueError):
        for _ in range(1400):
            loop.step()
    assert controller.fsm.current.name == "hold"
    assert controller.fsm.history[-1][1:] == ("transfer", "hold", "hold")
    for _ in range(20):  # and it keeps ticking, holding
        out = loop.step()
        assert out.status.fsm_state == "hold"


def test_a_plan_while_a_transition_runs_is_refused_with_the_reason(ladder):
    """A second plan mid-transition (it used to take the running transition away from its state:
    'NoneType' object has no attribute 'times' at the next state's start, found by fuzzing the
    node) is refused; the transition goes on, and a plan is taken again once the FSM holds."""
    from controller_node.controller import PlanRefused

    robot, env, stance, q, transition = ladder
    controller = Controller(robot, load_controller_params(**{"collision.enabled": False}), env)
    loop = KinematicLoop(controller, q)
    controller.reset(RobotState(0.0, q, np.zeros(robot.nv)), stance)
    plan = plan_of(robot, env, stance, [transition])
    controller.set_plan(plan)
    while controller.fsm.state != "unload":
        loop.step()
    with pytest.raises(PlanRefused, match="'unload'"):
        controller.set_plan(plan)
    assert controller.plan is plan and controller.transition is transition
    for _ in range(5):
        loop.step()
    assert controller.hold_plan() in ("unload", "open_gripper")
    controller.set_plan(plan)  # from hold
    assert controller.plan_pending


def test_a_hand_freed_for_good_leaves_its_rung_without_a_guard_or_a_search(ladder):
    """A transition whose target stance has no hold for its moving limb (a hand off the block once
    the feet are up): remove (unload, open gripper), then the path unguarded, then ``freed``; the
    hand stays out of the contact set, and nothing searched for a contact."""
    import dataclasses

    robot, env, stance, q, transfer = ladder
    freed = dataclasses.replace(transfer, target_stance=stance.without("right_hand"))
    params = load_controller_params(**{"collision.enabled": False})
    controller = Controller(robot, params, env)
    loop = KinematicLoop(controller, q)
    controller.reset(RobotState(0.0, q, np.zeros(robot.nv)), stance)
    controller.set_plan(plan_of(robot, env, stance, [freed]))
    states, out = _run_until_settled(loop, 1400)
    assert states[states.index("unload"):] == ["unload", "open_gripper", "transfer", "hold"], states
    assert ("transfer", "freed", "select") in [(a, e, b) for _, a, e, b in controller.fsm.history]
    assert set(controller.contacts) == {"left_foot", "right_foot", "left_hand"}
    assert not controller.events_of("contact_detected") and not controller.events_of("search_started")
    assert controller.transition_index >= 0 and out.status.fsm_state == "hold"


def _started(ladder, transitions, **overrides):
    """A controller (dampers off, ``overrides`` on the params) on the 4-contact ladder stance with a
    plan of ``transitions``, and its kinematic loop."""
    robot, env, stance, q, _ = ladder
    controller = Controller(robot, load_controller_params(**{"collision.enabled": False, **overrides}), env)
    loop = KinematicLoop(controller, q)
    controller.reset(RobotState(0.0, q, np.zeros(robot.nv)), stance)
    controller.set_plan(plan_of(robot, env, stance, transitions))
    return controller, loop


def _run_until_state(loop: KinematicLoop, state: str, ticks: int):
    for _ in range(ticks):
        out = loop.step()
        if out.status.fsm_state == state:
            return out
    raise AssertionError(f"no {state!r} within {ticks} ticks (in {loop.c.fsm.state!r})")


def _com_hold(stance, q, duration=2.0):
    """A CoM "shift" that keeps the CoM where it is: every limb on its hold, a path of one pose."""
    from climb_core.contact import Transition

    return Transition("com_hold", "", stance, stance, np.array([0.0, duration]), np.vstack([q, q]))


def test_an_impact_in_a_com_shift_braces_then_the_plan_resumes_and_completes(ladder):
    """An impact (injected as the monitor reports it) during a CoM shift, four contacts: the brace
    holds them; nothing moved, so the interrupted transition starts again from where the robot is
    and the plan goes on (the right hand onto rung 6)."""
    from controller_node.impact import Impact

    robot, env, stance, q, transition = ladder
    controller, loop = _started(ladder, [_com_hold(stance, q), transition])
    T_target = robot.T_world_surface("right_hand", transition.path[-1])
    loop.contact_plane = (T_target[:3, 3] - 0.015 * T_target[:3, 2], T_target[:3, 2])  # found 1.5 cm early
    _run_until_state(loop, "move_com", 200)
    for _ in range(100):
        loop.step()
    controller.recovery.on_impact(Impact(controller.time, "ft:left_foot", 900.0, 400.0))
    assert controller.fsm.state == "brace"
    states, out = _run_until_settled(loop, 3000)
    assert states[:2] == ["brace", "move_com"] and states[-1] == "hold", states
    (hit,) = controller.events_of("impact_detected")
    assert hit.values["braced"] and hit.values["state"] == "move_com"
    (started,) = controller.events_of("brace_started")
    assert started.values["interrupted"] == "move_com"
    assert started.values["contacts"] == ["left_foot", "left_hand", "right_foot", "right_hand"]
    (ended,) = controller.events_of("brace_ended")
    assert ended.values["duration"] >= controller.params.impact.brace_time_s - 1e-9
    assert max(ended.values["displacement"].values()) < 0.005  # the kinematic robot held still
    assert controller.events_of("brace_resumed") and not controller.events_of("contact_lost")
    assert [e.values["index"] for e in controller.events_of("transition_started")] == [0, 0, 1]
    assert set(controller.contacts) == {"left_foot", "right_foot", "left_hand", "right_hand"}
    assert controller.holds["right_hand"].env_surface == "rung_6"
    assert controller.posture_task.stiffness == controller.params.tasks.posture.stiffness  # restored


def test_an_impact_while_a_limb_travels_is_reported_and_the_transfer_goes_on(ladder):
    """impact.brace_states: a hand in flight is not held mid-air; the impact is reported and the
    transfer completes (measured in the simulator: braced, a 5 kg ball on a moving hand ended in
    a fall; unbraced, the climb completed)."""
    from controller_node.impact import Impact

    robot, env, stance, q, transition = ladder
    controller, loop = _started(ladder, [transition])
    T_target = robot.T_world_surface("right_hand", transition.path[-1])
    loop.contact_plane = (T_target[:3, 3] - 0.015 * T_target[:3, 2], T_target[:3, 2])
    _run_until_state(loop, "transfer", 600)
    controller.recovery.on_impact(Impact(controller.time, "joint:20", 20.0, 12.0))
    assert controller.fsm.state == "transfer"
    (hit,) = controller.events_of("impact_detected")
    assert not hit.values["braced"] and hit.values["state"] == "transfer"
    states, out = _run_until_settled(loop, 2400)
    assert states[-3:] == ["close_gripper", "load", "hold"] and "brace" not in states, states


def test_a_contact_moved_during_the_brace_is_lost_and_the_fsm_asks_for_a_replan(ladder):
    """The brace of a CoM shift, but the left foot's contact point is found 5 cm from where it was
    at the impact (knocked off its rung): it leaves the contact set and the FSM holds in
    replan_needed (reason contact_lost)."""
    from controller_node.impact import Impact

    robot, env, stance, q, transition = ladder
    controller, loop = _started(ladder, [_com_hold(stance, q), transition])
    _run_until_state(loop, "move_com", 200)
    controller.recovery.on_impact(Impact(controller.time, "joint:3", 20.0, 12.0))
    assert controller.fsm.state == "brace"
    controller.recovery.brace.anchors["left_foot"] = controller.recovery.brace.anchors["left_foot"] + np.array([0.0, 0.0, 0.05])
    states, out = _run_until_settled(loop, 1000)
    assert states[-1] == "replan_needed" and controller.replan_reason == "contact_lost"
    (lost,) = controller.events_of("contact_lost")
    assert lost.values["limb"] == "left_foot" and lost.values["moved"] > 0.045
    assert set(controller.contacts) == {"right_foot", "left_hand", "right_hand"}
    (event,) = controller.events_of("replan_needed")
    assert event.values["reason"] == "contact_lost"


def test_a_qp_failure_that_clears_ends_in_replan_needed_not_in_failure(ladder):
    """The QP fails for 0.4 s (longer than qp.failure_grace_s) in the middle of a transfer: the FSM
    goes to failure and holds; once the hold QP has solved for qp.recover_after_s with the joints
    settled, it leaves failure for replan_needed (reason qp_failure), the contacts it held kept."""
    from controller_node.qp import QpFailure

    robot, env, stance, q, transition = ladder
    controller, loop = _started(ladder, [transition], **{"qp.max_saved_failures": 0})
    params = controller.params
    _run_until_state(loop, "transfer", 600)
    real, broken_until = controller.wb.solve, controller.time + 0.4

    def solve(*args, **kwargs):
        if controller.time < broken_until:
            raise QpFailure(None, -1, "test", "made infeasible by the test")
        return real(*args, **kwargs)

    controller.wb.solve = solve
    states, out = _run_until_settled(loop, 200)
    assert states[-1] == "failure"
    held = set(controller.contacts)
    _run_until_state(loop, "replan_needed", 1000)
    assert controller.replan_reason == "qp_failure"
    (recovered,) = controller.events_of("failure_recovered")
    assert recovered.time - broken_until >= params.qp.recover_after_s - 1e-9
    assert set(controller.contacts) == held == {"left_foot", "right_foot", "left_hand"}
    assert not controller.fallback_active
    # and the next plan is taken from there
    controller.set_plan(plan_of(robot, env, stance, []))


def test_a_single_contact_lost_in_a_brace_is_put_back_by_the_transition_that_placed_it(ladder):
    """impact.replace_lost: the right hand, placed on rung 6 by transition 0, is found 5 cm from
    where it was when a blow came during the CoM shift that followed: the FSM runs transition 0's
    placement again (guarded, from where the hand is), then the interrupted CoM shift, and the
    plan ends holding with the hand on rung 6."""
    from controller_node.impact import Impact

    robot, env, stance, q, transition = ladder
    controller = Controller(robot, load_controller_params(**{"collision.enabled": False}), env)
    loop = KinematicLoop(controller, q)
    controller.reset(RobotState(0.0, q, np.zeros(robot.nv)), stance)
    after = _com_hold(transition.target_stance, transition.path[-1])
    controller.set_plan(plan_of(robot, env, stance, [transition, after]))
    T_target = robot.T_world_surface("right_hand", transition.path[-1])
    loop.contact_plane = (T_target[:3, 3] - 0.015 * T_target[:3, 2], T_target[:3, 2])
    _run_until_state(loop, "move_com", 3000)
    controller.recovery.on_impact(Impact(controller.time, "ft:right_hand", 900.0, 400.0))
    controller.recovery.brace.anchors["right_hand"] = controller.recovery.brace.anchors["right_hand"] + np.array([0.0, 0.0, 0.05])
    states, out = _run_until_settled(loop, 4000)
    assert states[0] == "brace" and states[-1] == "hold", states
    assert states[1:] == ["transfer", "close_gripper", "load", "move_com", "hold"], states
    (started,) = controller.events_of("replace_started")
    assert started.values == {"limb": "right_hand", "surface": "rung_6", "transition": 0}
    (done,) = controller.events_of("replace_done")
    assert done.values["transition"] == 1  # the interrupted CoM shift runs next, then the plan ends
    assert [e.values["index"] for e in controller.events_of("transition_started")] == [0, 1, 1]
    assert not controller.events_of("replan_needed")
    assert set(controller.contacts) == {"left_foot", "right_foot", "left_hand", "right_hand"}
    assert controller.holds["right_hand"].env_surface == "rung_6"


@pytest.mark.parametrize("limit, angle_deg, tilted", [(5.0, 6.0, True), (5.0, 4.0, False), (0.0, 30.0, False)])
def test_a_foot_turned_past_the_tilt_limit_on_its_approach_counts_as_touching(ladder, limit, angle_deg, tilted):
    """guarded.tilt_limit_deg: a foot on its guarded approach that pivots on what it touches
    (its orientation off its target's by more than the limit) is a contact; 0 switches it off;
    a hand's wrist is not judged by it."""
    robot, env, stance, q, _ = ladder
    params = load_controller_params(**{"collision.enabled": False, "guarded.tilt_limit_deg": limit})
    controller = Controller(robot, params, env)
    controller.reset(RobotState(0.0, q, np.zeros(robot.nv)), stance)
    for limb, kind in (("left_foot", "foot"), ("right_hand", "hand")):
        controller.moving_limb, controller.moving_kind = limb, kind
        task = controller.contact_body_tasks[limb]
        now = task.current(controller.wb.view)
        task.set_target(pin.SE3(now.rotation @ pin.utils.rotate("y", np.radians(angle_deg)), now.translation))
        assert controller.limb_tilted(limb) is (tilted and kind == "foot")
        task.set_target(now)
        assert controller.limb_tilted(limb) is False
