"""The `primitive_adaptation` node: contact plan -> whole-body plan (last stage of the pipeline).

Inputs
  - ``contact_plan`` (climb_msgs/ContactPlan) carrying its plan request (request_id, request_json,
    the pipeline of the graph): Adapt-Primitive under the multi-step search with backtracking for
    the request (:func:`planner_node.pipeline.adapt`: robot, scenario, rungs, seed, timeout_s,
    descend, a measured ``start`` projected onto its stance); it may change the contact plan's
    seed holds (the summary counts them). A searched plan whose adaptation is stuck at a
    transition is repaired here (:func:`planner_node.pipeline.adapt_and_repair`: the contact
    search run again without it; summary ``repairs``). The plan is the one the in-process climb
    makes for the same request. A contact plan without a request (``request_json`` empty) is adapted stance by
    stance on the environment its ``environment`` names (or the ``ladder`` parameter's);
  - ``primitive_adaptation/request`` (std_msgs/String): the older direct request, YAML or JSON:
    ``{ladder: <name | path | spec mapping>, robot: g1, steps: 2, seed: 0, timeout_s: 120,
    start: <fixture name, optional>, id: <free text>}``.
Outputs
  - ``whole_body_plan`` (climb_msgs/WholeBodyPlan, request_id + request_json of the request);
  - ``primitive_adaptation/status`` (climb_msgs/ClimbStatus, id = the request's id): adaptation
    (step k of n sub-tasks, every 0.5 s) -> done (text: the planning summary as JSON: plan_time_s,
    n_stances, n_transitions, attempts, backtracks, ...) | failed (text: the constraint that
    stopped the search, a malformed input's field and rule, or "busy": a request arriving while
    another is planned is refused with ITS OWN id).

Planning runs in a worker thread, one request at a time; the node keeps running whatever
arrives. Parameters (config/nodes/primitive_adaptation.yaml): every planner setting (the climb's:
config/planner.yaml with config/climb.yaml's planner_overrides), ``strategy`` and ``ladder``
(:class:`planner_node.node_params.AdaptationParams`).
"""
from __future__ import annotations

import sys
from typing import Any

import yaml

from climb_core.errors import SpecError

from .settings import NODE_NAME, PlannerSettings

REQUEST_KEYS = ("ladder", "robot", "steps", "seed", "timeout_s", "start", "id")


def parse_request(text: str, default_robot: str = "g1", default_ladder: str = "default") -> dict:
    """A primitive-sequence request from YAML / JSON text; SpecError(field, rule) when malformed."""
    try:
        data = yaml.safe_load(text) if text.strip() else {}
    except yaml.YAMLError as exc:
        raise SpecError("request", f"not YAML / JSON: {exc}") from None
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise SpecError("request", "must be a mapping")
    unknown = sorted(set(data) - set(REQUEST_KEYS))
    if unknown:
        raise SpecError(f"request.{unknown[0]}", f"unknown key (known: {', '.join(REQUEST_KEYS)})")
    out = {"ladder": data.get("ladder", default_ladder), "robot": str(data.get("robot", default_robot)),
           "steps": data.get("steps", 2), "seed": data.get("seed", None), "timeout_s": data.get("timeout_s", None),
           "start": data.get("start", None), "id": str(data.get("id", ""))}
    if isinstance(out["steps"], bool) or not isinstance(out["steps"], int) or out["steps"] < 0:
        raise SpecError("request.steps", f"must be an integer >= 0, got {out['steps']!r}")
    if out["seed"] is not None and (isinstance(out["seed"], bool) or not isinstance(out["seed"], int)
                                    or out["seed"] < 0):
        raise SpecError("request.seed", f"must be an integer >= 0, got {out['seed']!r}")
    if out["timeout_s"] is not None:
        try:
            out["timeout_s"] = float(out["timeout_s"])
        except (TypeError, ValueError):
            raise SpecError("request.timeout_s", f"must be a number [s], got {out['timeout_s']!r}") from None
        if not out["timeout_s"] > 0:
            raise SpecError("request.timeout_s", f"must be > 0 [s], got {out['timeout_s']}")
    if not isinstance(out["ladder"], (str, dict)):
        raise SpecError("request.ladder", "must be a ladder name, a file path or a spec mapping")
    return out


class AdaptationService:
    """ROS-free core of the node: request -> plan (or error). Loads robots and ladders on demand."""

    def __init__(self, settings: PlannerSettings, default_ladder: str = "default"):
        self.settings = settings
        self.default_ladder = default_ladder

    def environment(self, ladder: Any):
        from climb_core.environment import build_environment
        from climb_core.ladder import load_scenario

        return build_environment(load_scenario(ladder))

    def plan_request(self, request: dict, on_progress=None):
        from climb_core import fixtures
        from climb_core.robot import load_robot

        from .climb_planner import plan_climb

        robot = load_robot(request["robot"])
        env = self.environment(request["ladder"])
        start = None
        if request.get("start"):
            stance, q = fixtures.get(request["start"], robot, env)
            start = (q, stance)
        return plan_climb(robot, env, request["steps"], settings=self.settings, start=start, seed=request["seed"],
                          timeout_s=request["timeout_s"], on_progress=on_progress)

    def plan_contact(self, contact_plan, ladder: Any = None, on_progress=None):
        from climb_core.ladder import available_ladders
        from climb_core.robot import available_robots, load_robot

        from .climb_planner import plan_from_contact_plan

        # names only: a message never makes the node read a file
        name = contact_plan.robot or self.settings.planning.robot
        if name not in available_robots():
            raise SpecError("contact_plan.robot", f"unknown robot {name!r} (available: {', '.join(available_robots())})")
        robot = load_robot(name)
        env = None
        if contact_plan.environment in available_ladders():
            env = self.environment(contact_plan.environment)
        env = env or self.environment(ladder or self.default_ladder)
        return plan_from_contact_plan(robot, env, contact_plan, settings=self.settings, on_progress=on_progress)


def make_node():
    from climb_msgs.msg import ContactPlan, WholeBodyPlan
    from std_msgs.msg import String

    from msgs_py.contact import contact_plan_from_msg, whole_body_plan_to_msg
    from msgs_py.node_kit import safe_publish
    from msgs_py.topics import qos_for

    from .node_params import AdaptationParams, node_defaults, planner_settings
    from .pipeline import adapt_and_repair, load_problem, parse_plan_request
    from .stage_node import StageNode, check_request_strategy

    class AdaptationNode(StageNode):
        def __init__(self) -> None:
            super().__init__(NODE_NAME, AdaptationParams, node_defaults(NODE_NAME), "adaptation")
            self.pub_plan = self.create_publisher(WholeBodyPlan, "whole_body_plan", qos_for("whole_body_plan"))
            self.subscribe(String, "primitive_adaptation/request", self._on_request)
            self.subscribe(ContactPlan, "contact_plan", self._on_contact_plan)
            self.get_logger().info("primitive_adaptation ready")
            self.warm_up(planner_settings(self.params), self.params.planning.robot)

        def _on_progress(self, k, n, _attempts) -> None:
            self.set_progress(k, n)

        # ---- the pipeline: a contact plan that answers a plan request
        def _on_contact_plan(self, msg) -> None:
            rid = msg.request_id
            if not msg.request_json:
                self._on_bare_contact_plan(msg)
                return
            try:
                req = parse_plan_request(msg.request_json)
                if req.id != rid:
                    raise SpecError("contact_plan.request_id", f"must be the id of its request_json ({req.id!r}), "
                                                               f"got {rid!r}")
                plan = contact_plan_from_msg(msg)
            except SpecError as exc:
                self.fail(rid, f"malformed input: {exc}")
                return
            if not check_request_strategy(self, rid, req.strategy, "primitive_adaptation"):
                return
            params = self.params
            self.start(rid, lambda: self._adapt(req, plan, params))

        def _adapt(self, req, contact_plan, params) -> None:
            problem = load_problem(req, planner_settings(params))
            res, summary = adapt_and_repair(problem, contact_plan, on_progress=self._on_progress,
                                            strategy=params.strategy)
            self._publish_result(req.id, res, summary, req.text)

        def _publish_result(self, rid: str, res, summary: dict, request_json: str = "") -> None:
            n = len(res.subtasks)
            if res.plan is not None and res.success:
                out = whole_body_plan_to_msg(res.plan, stamp=self.now_s())
                out.request_id = rid
                out.request_json = request_json
                self.done(rid, summary, n)  # first: the summary is there when the plan arrives
                safe_publish(self.pub_plan, out)
            else:
                self.finish(rid, "failed", f"{res.failure_constraint}: {res.failure_detail}",
                            res.report.deepest if res.report else 0, n)

        # ---- legacy inputs: a contact plan without a request, primitive_adaptation/request
        def _on_bare_contact_plan(self, msg) -> None:
            rid = msg.request_id or "contact_plan"
            try:
                plan = contact_plan_from_msg(msg)
            except (SpecError, ValueError) as exc:
                self.fail(rid, f"malformed contact plan: {exc}")
                return
            if not check_request_strategy(self, rid, None, "primitive_adaptation"):
                return
            params = self.params
            service = AdaptationService(planner_settings(params), params.ladder)
            self.start(rid, lambda: self._legacy(rid, lambda: service.plan_contact(plan, on_progress=self._on_progress)))

        def _on_request(self, msg) -> None:
            params = self.params
            try:
                request = parse_request(msg.data, params.planning.robot, params.ladder)
            except SpecError as exc:
                self.fail(_legacy_id(msg.data), f"malformed request: {exc}")
                return
            service = AdaptationService(planner_settings(params), params.ladder)
            rid = request["id"]
            self.start(rid, lambda: self._legacy(rid, lambda: service.plan_request(request, self._on_progress)))

        def _legacy(self, rid: str, job) -> None:
            res = job()
            self._publish_result(rid, res, res.summary())

    return AdaptationNode()


def _legacy_id(text: str) -> str:
    try:
        data = yaml.safe_load(text)
    except Exception:  # noqa: BLE001 - any unreadable text: no id
        return ""
    value = data.get("id") if isinstance(data, dict) else None
    return str(value) if isinstance(value, (str, int)) else ""


def main(args: list[str] | None = None) -> int:
    from climb_core.ros_env import install_signal_handlers

    install_signal_handlers()  # first: a signal during the heavy imports below still exits 0
    from msgs_py.node_kit import run_node

    return run_node(make_node, args, name=NODE_NAME)


if __name__ == "__main__":
    sys.exit(main())
