"""The three planning nodes (guide_path, contact_search, primitive_adaptation) as separate
processes, driven over topics as the coordinator drives them.

One module-scoped graph: the nodes started with their config/nodes/*.yaml, a client node in this
process publishing plan/request and recording guide_path, contact_plan, whole_body_plan and the
three status topics.

- a plan request for the default ladder, 2 rungs, G1 passes through every stage in order, each
  product carrying the request's id and JSON; the whole-body plan is the in-process climb's plan
  for the same request (climb_coordinator.climb.plan); the adaptation's `done` text is the
  planning summary;
- a replan from a measured state (`start`: q and stance) plans what the in-process replanner plans;
- `strategy: search` (guide path, best-first contact search, adaptation) from the 4-contact stance
  to rung 3: a whole-body plan the controller accepts;
- bad requests: a malformed one fails at guide_path naming the field, a scene with the
  `primitives` strategy is refused with the reason, a contact plan arriving while the adaptation
  is busy is refused with ITS id;
- the strategy parameter: validated on set, it decides for a request that names none;
- garbage bytes on every input: reported on diagnostics, the nodes keep serving;
- SIGTERM / SIGINT mid-planning: every node exits 0 without a traceback.
Plus the YAML files say what the code's defaults are.
"""
from __future__ import annotations

import json
import pathlib
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

pytestmark = pytest.mark.ros

ROOT = pathlib.Path(__file__).resolve().parents[2]
NODES = {"guide_path": "planner_node.guide_path_node", "contact_search": "planner_node.contact_search_node",
         "primitive_adaptation": "planner_node.adaptation_node"}
STATUS = [f"{n}/status" for n in NODES]
REQUEST = {"id": "climb-1", "robot": "g1", "scenario": "default", "rungs": 2, "seed": 0, "timeout_s": 120,
           "descend": False}


def test_node_yaml_files_hold_the_code_defaults():
    from climb_core.params import load_params

    from planner_node.node_params import (AdaptationParams, ContactSearchParams, GuidePathParams,
                                          node_defaults)

    for name, schema in (("guide_path", GuidePathParams), ("contact_search", ContactSearchParams),
                         ("primitive_adaptation", AdaptationParams)):
        assert load_params(ROOT / "config" / "nodes" / f"{name}.yaml", schema, name) == node_defaults(name), name


@pytest.mark.parametrize("change, field", [
    ({"rungs": 0}, "request.rungs"), ({"rungs": 1.5}, "request.rungs"), ({"id": ""}, "request.id"),
    ({"seed": -1}, "request.seed"), ({"timeout_s": 0}, "request.timeout_s"), ({"descend": "yes"}, "request.descend"),
    ({"strategy": "dfs"}, "request.strategy"), ({"robot": "../g1"}, "request.robot"),
    ({"start": {"q": [0.0]}}, "request.start"), ({"start": {"q": [float("nan")], "stance": {}}}, "request.start.q"),
    ({"mode": "qp"}, "request.mode"), ({"rungs": 10 ** 9}, "request.rungs"), ({"seed": 2 ** 64}, "request.seed"),
    ({"surface_offsets": [0.0, 0.0, 0.03]}, "request.surface_offsets"),
    ({"surface_offsets": {"rung_2": [0.0, 0.03]}}, "request.surface_offsets.rung_2"),
    ({"surface_offsets": {"rung_2": [0.0, 0.0, float("inf")]}}, "request.surface_offsets.rung_2"),
    ({"surface_offsets": {"rung_2": [0.0, 0.0, 5.0]}}, "request.surface_offsets.rung_2")])
def test_plan_requests_are_checked_field_by_field(change, field):
    from climb_core.errors import SpecError
    from planner_node.pipeline import parse_plan_request

    with pytest.raises(SpecError) as err:
        parse_plan_request(json.dumps(dict(REQUEST, **change)))
    assert err.value.field == field
    assert parse_plan_request(json.dumps(REQUEST)).rungs == 2


def test_a_request_never_makes_a_node_read_a_file_and_more_rungs_than_the_ladder_has_are_refused():
    from climb_core.errors import SpecError
    from planner_node.node_params import stage_settings
    from planner_node.pipeline import check_request, load_problem, parse_plan_request, seed_sequence

    for scenario in ("config/ladders/default.yaml", "/etc/passwd", "no_such_ladder"):
        with pytest.raises(SpecError) as err:
            check_request(parse_plan_request(json.dumps(dict(REQUEST, scenario=scenario))))
        assert err.value.field == "request.scenario"
    with pytest.raises(SpecError) as err:  # more rungs than the ladder has: refused as it arrives
        check_request(parse_plan_request(json.dumps(dict(REQUEST, rungs=9))))
    assert err.value.field == "request.rungs" and "8 rungs" in err.value.rule
    # up to the top rung: the hands stay on the highest rung they reach
    problem = load_problem(parse_plan_request(json.dumps(dict(REQUEST, rungs=8))), stage_settings())
    _, _, steps = seed_sequence(problem)
    assert {h.limb: h.env_surface for h in steps[-1].stance.holds}["left_foot"] == "rung_8"


def test_surface_offsets_move_the_planners_model_of_a_request():
    """A replan's request carries where execution found surfaces: every stage's problem has them
    moved; an unknown surface is refused by name."""
    from climb_core.errors import SpecError
    from planner_node.node_params import stage_settings
    from planner_node.pipeline import load_problem, parse_plan_request

    nominal = load_problem(parse_plan_request(json.dumps(REQUEST)), stage_settings()).env
    moved = load_problem(parse_plan_request(json.dumps(dict(REQUEST, surface_offsets={"rung_2": [0.0, 0.0, 0.03]}))),
                         stage_settings()).env
    assert moved.surfaces["rung_2"].position - nominal.surfaces["rung_2"].position == pytest.approx([0, 0, 0.03])
    assert moved.surfaces["rung_3"].position == pytest.approx(nominal.surfaces["rung_3"].position)
    with pytest.raises(SpecError) as err:
        load_problem(parse_plan_request(json.dumps(dict(REQUEST, surface_offsets={"rung_99": [0, 0, 0.01]}))),
                     stage_settings())
    assert err.value.field == "request.surface_offsets.rung_99"


def test_a_ladder_the_library_cannot_hold_fails_the_guide_path_with_the_constraint():
    from climb_core.errors import InfeasibleError
    from planner_node.node_params import stage_settings
    from planner_node.pipeline import guide_path, load_problem, parse_plan_request

    problem = load_problem(parse_plan_request(json.dumps(dict(REQUEST, scenario="a_frame"))), stage_settings())
    with pytest.raises(InfeasibleError) as err:  # its treads are 0.08 m deep boxes: past the Dex3 hand's
        guide_path(problem)  # max_bar (0.047 m deep), the field and the limit named
    assert err.value.constraint == "hold:ladder.rung.depth" and "mount_left_hand" in err.value.detail
    assert "0.047" in err.value.detail


def test_the_seed_sequence_of_a_climb_and_back_down_retraces_the_cycles():
    from planner_node.node_params import stage_settings
    from planner_node.pipeline import load_problem, parse_plan_request, seed_sequence

    problem = load_problem(parse_plan_request(json.dumps(dict(REQUEST, rungs=1, descend=True))), stage_settings())
    q0, stance0, steps = seed_sequence(problem)
    up = [s for s in steps if s.kind != "descend"]
    down = [s for s in steps if s.kind == "descend"]
    assert len(up) == 14 and len(down) == 7  # approach 5 + mount 2 + one cycle of 7, then that cycle back
    feet = {h.limb: h.env_surface for h in up[-1].stance.holds if h.limb.endswith("foot")}
    assert feet == {"left_foot": "rung_1", "right_foot": "rung_1"}
    assert [h.env_surface for h in down[-1].stance.holds] == [h.env_surface for h in up[6].stance.holds]
    assert down[0].primitive == "descend:" + up[-1].primitive


class Client:
    """A client node in this process: publishes requests, records what the stages publish."""

    def __init__(self, procs):
        import rclpy
        from climb_msgs.msg import ClimbStatus, ContactPlan, GuidePath, WholeBodyPlan
        from rclpy.executors import SingleThreadedExecutor
        from std_msgs.msg import String

        from msgs_py.topics import qos_for

        self.procs = procs
        self.context = rclpy.Context()
        rclpy.init(context=self.context)
        self.node = rclpy.create_node("planning_test_client", context=self.context)
        self.log: list[tuple[str, object]] = []  # (topic, message) in arrival order
        for topic, cls in (("guide_path", GuidePath), ("contact_plan", ContactPlan),
                           ("whole_body_plan", WholeBodyPlan)):
            self.node.create_subscription(cls, topic, lambda m, t=topic: self.log.append((t, m)), qos_for(topic))
        for topic in STATUS:
            self.node.create_subscription(ClimbStatus, topic, lambda m, t=topic: self.log.append((t, m)),
                                          qos_for(topic))
        from diagnostic_msgs.msg import DiagnosticArray

        self.node.create_subscription(DiagnosticArray, "diagnostics", lambda m: self.log.append(("diagnostics", m)),
                                      qos_for("diagnostics"))
        self.pub_request = self.node.create_publisher(String, "plan/request", qos_for("plan/request"))
        self.pub_guide = self.node.create_publisher(GuidePath, "guide_path", qos_for("guide_path"))
        self.pub_contact = self.node.create_publisher(ContactPlan, "contact_plan", qos_for("contact_plan"))
        self.String = String
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)

    def spin_until(self, predicate, timeout_s: float, what: str = "") -> None:
        end = time.monotonic() + timeout_s
        while time.monotonic() < end:
            self.executor.spin_once(timeout_sec=0.05)
            if predicate():
                return
            for name, p in self.procs.items():
                assert p.poll() is None, f"{name} died: {p.stdout.read().decode()[-3000:]}"
        raise AssertionError(f"timeout waiting for {what}: " + "; ".join(
            f"{t} {getattr(m, 'id', getattr(m, 'request_id', ''))} {getattr(m, 'phase', '')} "
            f"{getattr(m, 'text', '')[:200]}" for t, m in self.log[-12:]))

    def spin_for(self, seconds: float) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self.executor.spin_once(timeout_sec=0.05)

    def request(self, data) -> None:
        self.pub_request.publish(self.String(data=data if isinstance(data, str) else json.dumps(data)))

    def of(self, topic: str, rid: str) -> list:
        return [m for t, m in self.log if t == topic and (getattr(m, "request_id", None) == rid
                                                          or getattr(m, "id", None) == rid)]

    def status(self, rid: str, phase: str | None = None) -> list:
        return [(t, m) for t, m in self.log if t in STATUS and m.id == rid and (phase is None or m.phase == phase)]

    def close(self) -> None:
        import rclpy

        rclpy.try_shutdown(context=self.context)


@pytest.fixture(scope="module")
def graph():
    from climb_core.ros_env import local_dds_env

    env = local_dds_env()
    procs = {name: subprocess.Popen([sys.executable, "-m", module, "--ros-args", "--params-file",
                                     str(ROOT / "config" / "nodes" / f"{name}.yaml")],
                                    env=env, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
             for name, module in NODES.items()}
    client = Client(procs)
    try:
        client.spin_until(lambda: client.pub_request.get_subscription_count() > 0
                          and client.pub_contact.get_subscription_count() > 0
                          and all(client.node.count_publishers(t) > 0 for t in STATUS)
                          and client.node.count_publishers("whole_body_plan") > 0, 90.0, "the nodes")
        time.sleep(1.0)  # discovery in both directions
        yield client
    finally:
        client.close()
        for p in procs.values():
            if p.poll() is None:
                p.kill()
                p.wait()


def in_process_plan(rungs: int, seed: int, timeout_s: float, start=None):
    """What climb_coordinator.climb plans for the request (its first plan, or a replan from a
    measured state as its replanner does)."""
    from climb_core.environment import build_environment
    from climb_core.ladder import load_scenario
    from climb_core.robot import load_robot
    from climb_coordinator.climb import ClimbRequest, plan
    from climb_coordinator.settings import apply_planner_overrides, load_climb_settings
    from planner_node.climb_planner import plan_climb
    from planner_node.replan import measured_start
    from planner_node.settings import load_settings

    robot = load_robot("g1")
    env = build_environment(load_scenario("default"))
    psettings = apply_planner_overrides(load_settings(), load_climb_settings().planner_overrides)
    if start is None:
        req = ClimbRequest(ladder="default", robot="g1", rungs=rungs, seed=seed, plan_timeout_s=timeout_s)
        return plan(req, robot, env, psettings, rungs)
    q, stance = start
    q0 = measured_start(robot, env, q, stance, psettings)
    return plan_climb(robot, env, rungs, start=(q0, stance), settings=psettings, seed=seed, timeout_s=timeout_s)


def assert_same_plan(msg, expected) -> None:
    from msgs_py.contact import whole_body_plan_from_msg

    got = whole_body_plan_from_msg(msg)
    assert len(got.transitions) == len(expected.transitions)
    assert [t.primitive for t in got.transitions] == [t.primitive for t in expected.transitions]
    for a, b in zip(got.transitions, expected.transitions):
        assert a.path.shape == b.path.shape
        assert np.allclose(a.path, b.path, atol=1e-9) and np.allclose(a.times, b.times, atol=1e-9)
        assert [h.env_surface for h in a.target_stance.holds] == [h.env_surface for h in b.target_stance.holds]
    assert np.allclose(got.transitions[0].path[0], expected.transitions[0].path[0], atol=1e-9)
    assert np.allclose(got.transitions[-1].path[-1], expected.transitions[-1].path[-1], atol=1e-9)


def test_a_request_passes_every_stage_in_order_and_plans_the_in_process_climb(graph):
    client = graph
    client.request(REQUEST)
    rid = REQUEST["id"]
    client.spin_until(lambda: client.of("whole_body_plan", rid) or client.status(rid, "failed"), 240.0,
                      "the whole-body plan")
    assert not client.status(rid, "failed"), client.status(rid, "failed")[0][1].text
    order = [t for t, m in client.log if t in ("guide_path", "contact_plan", "whole_body_plan")]
    assert order == ["guide_path", "contact_plan", "whole_body_plan"]
    products = [m for t, m in client.log if t in ("guide_path", "contact_plan", "whole_body_plan")]
    for m in products:
        assert m.request_id == rid and json.loads(m.request_json) == REQUEST
    client.spin_until(lambda: len(client.status(rid, "done")) == 3, 10.0, "three done statuses")
    client.spin_for(1.5)  # > 2 progress periods: no progress status may follow a done
    # each stage: its phase, then done (last), all with the request's id
    for topic, phase in zip(STATUS, ("guide_path", "contact_search", "adaptation")):
        phases = [m.phase for t, m in client.status(rid) if t == topic]
        assert phases[0] == phase and phases[-1] == "done", (topic, phases)
    texts = {t: json.loads(m.text) for t, m in client.status(rid, "done")}
    guide, contact, summary = (texts[s] for s in STATUS)
    gp, cp, wb = products
    assert guide["n_milestones"] == len(gp.milestones) == 22  # start + approach 5 + mount 2 + 2 cycles of 7
    assert guide["n_projected"] == 21  # every key configuration brought onto its seed holds
    assert contact["n_stances"] == len(cp.stances) == 22 and contact["n_feasible"] >= 1
    assert summary["success"] is True and summary["request_id"] == rid
    assert summary["n_stances"] == len(wb.transitions) + 1 and summary["plan_time_s"] > 0
    assert summary["rungs_reached"] == 2
    # the seed stances climb the actual rungs: the last one has both feet on rung 2
    last = {h.limb: h.env_surface for h in cp.stances[-1].holds}
    assert last["left_foot"] == last["right_foot"] == "rung_2"
    # the graph's plan is the in-process climb's plan
    expected = in_process_plan(2, REQUEST["seed"], REQUEST["timeout_s"])
    assert expected.success
    assert_same_plan(wb, expected.plan)


def test_a_replan_from_a_measured_state_plans_what_the_in_process_replanner_plans(graph):
    from msgs_py.contact import whole_body_plan_from_msg
    from planner_node.plan_io import stance_to_dict

    client = graph
    first = whole_body_plan_from_msg(client.of("whole_body_plan", REQUEST["id"])[-1])
    # the state after the first cycle (mount = 7 transitions, then 7 per cycle), a few mm off
    t = first.transitions[13]
    q = np.asarray(t.path[-1], dtype=float).copy()
    q[:3] += [0.002, -0.001, 0.001]
    request = dict(REQUEST, id="climb-1-replan-1", rungs=1, start={"q": q.tolist(), "stance": stance_to_dict(
        t.target_stance)})
    client.request(request)
    rid = request["id"]
    client.spin_until(lambda: client.of("whole_body_plan", rid) or client.status(rid, "failed"), 240.0,
                      "the replanned whole-body plan")
    assert not client.status(rid, "failed"), client.status(rid, "failed")[0][1].text
    client.spin_until(lambda: client.status(rid, "done") and any(
        t == "primitive_adaptation/status" for t, _ in client.status(rid, "done")), 10.0, "done")
    summary = json.loads([m for t, m in client.status(rid, "done") if t == "primitive_adaptation/status"][0].text)
    assert summary["success"] and 0 < summary["start_projection_mm"] < 50
    contact = json.loads([m for t, m in client.status(rid, "done") if t == "contact_search/status"][0].text)
    assert all(i["index"] != 0 for i in contact["infeasible"])  # the start, projected, is feasible
    # a measured state 20 cm off its stance: the first stage says so
    far = q.copy()
    far[:3] += [0.0, 0.0, 0.2]
    client.request(dict(request, id="climb-1-replan-far", start={"q": far.tolist(), "stance": request["start"]["stance"]}))
    client.spin_until(lambda: client.status("climb-1-replan-far", "failed"), 60.0, "the refusal of a far start")
    (topic, msg), = client.status("climb-1-replan-far", "failed")
    assert topic == "guide_path/status" and msg.text.startswith("start:"), msg.text
    expected = in_process_plan(1, REQUEST["seed"], REQUEST["timeout_s"], start=(q, t.target_stance))
    assert expected.success
    assert_same_plan(client.of("whole_body_plan", rid)[-1], expected.plan)


def test_malformed_requests_fail_at_the_guide_path_naming_the_field(graph):
    client = graph
    client.request(dict(REQUEST, id="bad-rungs", rungs=-1))
    client.request(dict(REQUEST, id="bad-key", rung=2))
    client.request("{not json")
    client.request(dict(REQUEST, id="bad-ladder", scenario="no_such_ladder"))
    client.request(dict(REQUEST, id="bad-spec", scenario="ladder:\n  rung_spacing: -1.0\n"))
    client.spin_until(lambda: all(client.status(r, "failed") for r in ("bad-rungs", "bad-key", "", "bad-ladder",
                                                                        "bad-spec")), 60.0, "five failures")
    text = {r: client.status(r, "failed")[0][1].text for r in ("bad-rungs", "bad-key", "", "bad-ladder", "bad-spec")}
    assert "request.rungs" in text["bad-rungs"] and "[1, 1000]" in text["bad-rungs"]
    assert "request.rung" in text["bad-key"] and "unknown field" in text["bad-key"]
    assert "request" in text[""] and "JSON" in text[""]
    assert "request.scenario" in text["bad-ladder"] and "no_such_ladder" in text["bad-ladder"]
    assert "request.scenario.ladder" in text["bad-spec"]
    for r in text:
        assert all(t == "guide_path/status" for t, _ in client.status(r, "failed"))
        assert not client.of("guide_path", r) if r else True


def test_a_search_request_passes_every_stage_to_a_whole_body_plan(graph):
    """strategy: search over DDS: the free-flyer guide path, the best-first contact search (no seed
    holds) and the adaptation (primitives where they fit, generic paths elsewhere), from the
    4-contact stance on rung 1 to the feet on rung 3; the plan is one the controller accepts."""
    from climb_core import fixtures
    from climb_core.environment import build_environment
    from climb_core.robot import load_robot
    from controller_node.plan_check import check_plan
    from msgs_py.contact import whole_body_plan_from_msg
    from planner_node.plan_io import stance_to_dict

    client = graph
    robot, env = load_robot("g1"), build_environment("default")
    stance, q = fixtures.get("ladder_4_contacts", robot, env)
    rid = "search-1"
    client.request(dict(REQUEST, id=rid, rungs=3, strategy="search", timeout_s=300,
                        start={"q": q.tolist(), "stance": stance_to_dict(stance)}))
    client.spin_until(lambda: client.of("whole_body_plan", rid) or client.status(rid, "failed"), 400.0,
                      "the searched whole-body plan")
    assert not client.status(rid, "failed"), client.status(rid, "failed")[0][1].text
    client.spin_until(lambda: len(client.status(rid, "done")) == 3, 10.0, "three done statuses")
    done = {t: json.loads(m.text) for t, m in client.status(rid, "done")}
    assert [done[s]["strategy"] for s in STATUS] == ["search"] * 3
    assert done["guide_path/status"]["n_milestones"] >= 3  # one per rung (the start's own rung included)
    moves = done["contact_search/status"]["moves"]
    assert all(m.split(":")[0] in ("add", "remove") for m in moves) and done["contact_search/status"]["ik_calls"] > 0
    plan = whole_body_plan_from_msg(client.of("whole_body_plan", rid)[-1])
    check_plan(plan, robot, env)
    assert len(plan.transitions) == len(moves)
    last = plan.transitions[-1].target_stance
    assert {last.hold(f).env_surface for f in ("left_foot", "right_foot")} == {"rung_3"}


def test_a_scene_planned_with_the_primitives_strategy_is_refused_with_the_reason(graph):
    client = graph
    client.request(dict(REQUEST, id="scene-1", scenario="narrow_passage", rungs=1))
    client.spin_until(lambda: client.status("scene-1", "failed"), 30.0, "the refusal")
    (topic, msg), = client.status("scene-1", "failed")
    assert topic == "guide_path/status"
    assert "strategy 'search' needed for a scene without a ladder" in msg.text
    assert not client.of("guide_path", "scene-1")


def test_a_contact_plan_while_the_adaptation_is_busy_is_refused_with_its_own_id(graph):
    client = graph
    request = dict(REQUEST, id="busy-a", rungs=1)
    client.request(request)
    client.spin_until(lambda: client.of("contact_plan", "busy-a"), 60.0, "busy-a's contact plan")
    client.spin_until(lambda: any(t == "primitive_adaptation/status" for t, _ in
                                  client.status("busy-a", "adaptation")), 30.0, "busy-a planning")
    second = client.of("contact_plan", "busy-a")[-1]
    second.request_id = "busy-b"
    second.request_json = json.dumps(dict(request, id="busy-b"))
    client.pub_contact.publish(second)
    client.spin_until(lambda: client.status("busy-b", "failed"), 30.0, "the refusal")
    (topic, refusal), = client.status("busy-b", "failed")
    assert topic == "primitive_adaptation/status"
    assert "busy" in refusal.text and "busy-a" in refusal.text and "busy-b" in refusal.text
    client.spin_until(lambda: client.of("whole_body_plan", "busy-a"), 240.0, "busy-a's plan")
    assert not client.of("whole_body_plan", "busy-b")
    # the refusal did not disturb the running request's statuses
    assert all(m.id == "busy-a" for t, m in client.log if t == "primitive_adaptation/status" and m.phase != "failed"
               and m.id.startswith("busy"))


def set_parameter(client, node_name: str, name: str, value: str):
    from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue
    from rcl_interfaces.srv import SetParameters

    cli = client.node.create_client(SetParameters, f"/{node_name}/set_parameters")
    try:
        client.spin_until(lambda: cli.service_is_ready(), 20.0, f"{node_name}/set_parameters")
        future = cli.call_async(SetParameters.Request(parameters=[Parameter(name=name, value=ParameterValue(
            type=ParameterType.PARAMETER_STRING, string_value=value))]))
        client.spin_until(future.done, 20.0, "the set_parameters answer")
        return future.result().results[0]
    finally:
        client.node.destroy_client(cli)


def test_the_strategy_parameter_is_validated_and_decides_a_request_without_one(graph):
    client = graph
    bad = set_parameter(client, "contact_search", "strategy", "banana")
    assert not bad.successful and "strategy" in bad.reason and "primitives" in bad.reason
    assert set_parameter(client, "guide_path", "strategy", "search").successful
    try:
        request = dict(REQUEST, id="scene-2", scenario="narrow_passage", rungs=1)
        del request["descend"]
        client.request(request)  # no strategy in the request: each node's parameter decides
        client.spin_until(lambda: client.status("scene-2", "failed"), 60.0, "the contact search's refusal")
        (topic, msg), = client.status("scene-2", "done")  # the guide path searched the scene
        assert topic == "guide_path/status" and json.loads(msg.text)["strategy"] == "search"
        path = client.of("guide_path", "scene-2")[-1]
        assert len(path.milestones) >= 2
        (topic, msg), = client.status("scene-2", "failed")  # contact_search still runs primitives
        assert topic == "contact_search/status" and "strategy 'search' needed" in msg.text
    finally:
        assert set_parameter(client, "guide_path", "strategy", "primitives").successful


def test_garbage_bytes_on_every_input_are_reported_and_the_nodes_keep_serving(graph):
    client = graph
    client.spin_until(lambda: client.pub_guide.get_subscription_count() > 0, 20.0, "contact_search")
    time.sleep(0.5)
    for pub in (client.pub_request, client.pub_guide, client.pub_contact):
        pub.publish(b"\x00\x01\x00\x00" + bytes(range(13)))  # 17 bytes, not the topic's type

    def reported():
        names = {s.name for t, m in client.log if t == "diagnostics" for s in m.status}
        return {"guide_path/plan/request", "contact_search/guide_path", "primitive_adaptation/contact_plan"} <= names

    client.spin_until(reported, 20.0, "three diagnostics")
    # each node still answers its input (here a malformed one, answered at once)
    from climb_msgs.msg import ContactPlan, GuidePath

    client.request(dict(REQUEST, id="after-garbage-1", rungs=0))
    client.pub_guide.publish(GuidePath(request_id="after-garbage-2", request_json='{"id": "after-garbage-2"}'))
    client.pub_contact.publish(ContactPlan(request_id="after-garbage-3", request_json='{"id": "after-garbage-3"}'))
    client.spin_until(lambda: all(client.status(f"after-garbage-{k}", "failed") for k in (1, 2, 3)), 20.0, "answers")
    for k, topic in enumerate(STATUS, start=1):
        (t, msg), = client.status(f"after-garbage-{k}", "failed")
        assert t == topic and "request.rungs" in msg.text


def test_signals_mid_planning_exit_every_node_cleanly(graph):
    client = graph
    client.request(dict(REQUEST, id="interrupted"))
    client.spin_until(lambda: any(t == "primitive_adaptation/status" for t, _ in
                                  client.status("interrupted", "adaptation")), 60.0, "the adaptation planning")
    for name, p in client.procs.items():  # SIGTERM to the planning one, SIGINT to the others
        p.send_signal(signal.SIGTERM if name == "primitive_adaptation" else signal.SIGINT)
    for name, p in client.procs.items():
        out, _ = p.communicate(timeout=30)
        text = out.decode()
        assert p.returncode == 0, f"{name}: {text[-3000:]}"
        assert "Traceback" not in text, f"{name}: {text[-3000:]}"
