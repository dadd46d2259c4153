"""The `contact_search` node: guide path -> contact plan (second stage of the planning pipeline).

Inputs
  - ``guide_path`` (climb_msgs/GuidePath) with its plan request (request_id, request_json).
Outputs
  - ``contact_plan`` (climb_msgs/ContactPlan, request_id + request_json passed on): with
    ``strategy: primitives``, the stance sequence of the primitive library's seed holds on the
    scenario's rungs, each with its transition configuration (the guide milestone projected onto
    the stance by Algorithm 1) checked with the frozen feasibility check; with ``strategy: search``,
    the best-first multi-contact search through the guide path's milestones
    (:func:`planner_node.pipeline.contact_search`);
  - ``contact_search/status`` (climb_msgs/ClimbStatus, id = the request's id): contact_search ->
    done (text: JSON summary: n_stances, n_feasible, the infeasible stances with their constraint)
    | failed (the reason).

Parameters (config/nodes/contact_search.yaml): strategy, library, primitives_dir, restarts,
require_feasible (:class:`planner_node.node_params.ContactSearchParams`).
"""
from __future__ import annotations

import sys

NODE_NAME = "contact_search"


def make_node():
    from climb_msgs.msg import ContactPlan, GuidePath

    from climb_core.errors import SpecError
    from msgs_py.contact import contact_plan_to_msg, guide_path_from_msg
    from msgs_py.node_kit import safe_publish
    from msgs_py.topics import qos_for

    from .node_params import ContactSearchParams, node_defaults, stage_settings
    from .pipeline import contact_search, load_problem, parse_plan_request
    from .stage_node import StageNode, check_request_strategy

    class ContactSearchNode(StageNode):
        def __init__(self) -> None:
            super().__init__(NODE_NAME, ContactSearchParams, node_defaults(NODE_NAME), "contact_search")
            self.pub_plan = self.create_publisher(ContactPlan, "contact_plan", qos_for("contact_plan"))
            self.subscribe(GuidePath, "guide_path", self._on_guide_path)
            self.get_logger().info("contact_search ready")
            self.warm_up(stage_settings(self.params.library, self.params.primitives_dir))

        def _on_guide_path(self, msg) -> None:
            rid = msg.request_id
            if not msg.request_json:
                self.fail(rid, "malformed input: guide_path.request_json: empty; the contact search needs the plan "
                               "request the guide path answers")
                return
            try:
                req = parse_plan_request(msg.request_json)
                if req.id != rid:
                    raise SpecError("guide_path.request_id", f"must be the id of its request_json ({req.id!r}), "
                                                             f"got {rid!r}")
                path = guide_path_from_msg(msg)
            except SpecError as exc:
                self.fail(rid, f"malformed input: {exc}")
                return
            if not check_request_strategy(self, rid, req.strategy, "contact_search"):
                return
            params = self.params
            self.start(rid, lambda: self._search(req, path, params))

        def _search(self, req, path, params) -> None:
            settings = stage_settings(params.library, params.primitives_dir)
            problem = load_problem(req, settings)
            res = contact_search(problem, path, restarts=params.restarts, require_feasible=params.require_feasible,
                                 seed=settings.planning.seed if req.seed is None else req.seed,
                                 strategy=params.strategy)
            out = contact_plan_to_msg(res.product, stamp=self.now_s())
            out.request_id = req.id
            out.request_json = req.text
            self.done(req.id, dict(res.summary, request_id=req.id), len(res.product.stances))
            safe_publish(self.pub_plan, out)

    return ContactSearchNode()


def main(args: list[str] | None = None) -> int:
    from climb_core.ros_env import install_signal_handlers

    install_signal_handlers()  # first: a signal during the heavy imports below still exits 0
    from msgs_py.node_kit import run_node

    return run_node(make_node, args, name=NODE_NAME)


if __name__ == "__main__":
    sys.exit(main())
