"""The `guide_path` node: plan request -> guide path (first stage of the planning pipeline).

Inputs
  - ``plan/request`` (std_msgs/String): the plan request JSON of the coordinator
    (:func:`planner_node.pipeline.parse_plan_request`: id, robot, scenario, rungs, seed, timeout_s,
    descend, strategy, start).
Outputs
  - ``guide_path`` (climb_msgs/GuidePath, request_id + request_json verbatim): with
    ``strategy: primitives``, the milestones of the primitive sequence moved onto the actual
    ladder; with ``strategy: search``, the free-flyer RRT-Connect path to the scene's goal or up
    the ladder (:func:`planner_node.pipeline.guide_path`);
  - ``guide_path/status`` (climb_msgs/ClimbStatus, id = the request's id): guide_path -> done (text:
    JSON summary) | failed (text: the reason: a malformed request names the field and the rule;
    a scene without a ladder asks for ``strategy: search``).

Parameters (config/nodes/guide_path.yaml): strategy, library, primitives_dir,
projection_iterations (:class:`planner_node.node_params.GuidePathParams`).
"""
from __future__ import annotations

import sys

NODE_NAME = "guide_path"


def make_node():
    from climb_msgs.msg import GuidePath
    from std_msgs.msg import String

    from climb_core.errors import SpecError
    from msgs_py.contact import guide_path_to_msg
    from msgs_py.node_kit import safe_publish
    from msgs_py.topics import qos_for

    from .node_params import GuidePathParams, node_defaults, stage_settings
    from .pipeline import check_request, guide_path, load_problem, parse_plan_request, request_id_of
    from .stage_node import StageNode, check_request_strategy

    class GuidePathNode(StageNode):
        def __init__(self) -> None:
            super().__init__(NODE_NAME, GuidePathParams, node_defaults(NODE_NAME), "guide_path")
            self.pub_path = self.create_publisher(GuidePath, "guide_path", qos_for("guide_path"))
            self.subscribe(String, "plan/request", self._on_request)
            self.get_logger().info("guide_path ready")
            self.warm_up(stage_settings(self.params.library, self.params.primitives_dir))

        def _on_request(self, msg) -> None:
            rid = request_id_of(msg.data)
            try:
                req = parse_plan_request(msg.data)
                check_request(req)
            except SpecError as exc:
                self.fail(rid, f"malformed request: {exc}")
                return
            if not check_request_strategy(self, req.id, req.strategy, "guide_path"):
                return
            params = self.params
            self.start(req.id, lambda: self._plan(req, params))

        def _plan(self, req, params) -> None:
            problem = load_problem(req, stage_settings(params.library, params.primitives_dir))
            res = guide_path(problem, params.projection_iterations, strategy=params.strategy)
            out = guide_path_to_msg(res.product, stamp=self.now_s())
            out.request_id = req.id
            out.request_json = req.text
            self.done(req.id, dict(res.summary, request_id=req.id), len(res.product.milestones))
            safe_publish(self.pub_path, out)

    return GuidePathNode()


def main(args: list[str] | None = None) -> int:
    from climb_core.ros_env import install_signal_handlers

    install_signal_handlers()  # first: a signal during the heavy imports below still exits 0
    from msgs_py.node_kit import run_node

    return run_node(make_node, args, name=NODE_NAME)


if __name__ == "__main__":
    sys.exit(main())
