"""The `primitive_adaptation` node: a thin rclpy wrapper around the planner library.

Inputs
  - ``primitive_adaptation/request`` (std_msgs/String): a primitive-sequence request, YAML or JSON
    mapping: ``{ladder: <name | path | spec mapping>, robot: g1, steps: 2, seed: 0, timeout_s: 120,
    start: <fixture name, optional>, id: <free text>}``;
  - ``contact_plan`` (climb_msgs/ContactPlan): a stance sequence from the contact search, adapted
    transition by transition on the environment of the ``ladder`` parameter (or the plan's
    ``environment`` when it names a ladder).
Outputs
  - ``whole_body_plan`` (climb_msgs/WholeBodyPlan, reliable, volatile: the controller's QoS);
  - ``primitive_adaptation/status`` (climb_msgs/ClimbStatus): phase adaptation -> done | failed,
    step k of n, progress, text (the failure's constraint, or the error of a malformed request).

Planning runs in a worker thread, one request at a time; a malformed request or a request while
busy gets a ``failed`` status with the reason, the node keeps running. Parameters: the planner's
(config/planner.yaml, node name ``primitive_adaptation``) plus ``ladder`` and ``robot`` defaults.
"""
from __future__ import annotations

import json
import sys
import threading
from typing import Any

import yaml

from climb_core.errors import ClimbError, SpecError
from climb_core.params import describe, flatten, parse_params

from .settings import NODE_NAME, PlannerSettings, load_settings

#: [s] status publication period while planning
STATUS_PERIOD_S = 0.5
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
        from climb_core.robot import load_robot

        from .climb_planner import plan_from_contact_plan

        robot = load_robot(contact_plan.robot or self.settings.planning.robot)
        env = None
        if contact_plan.environment:
            try:
                env = self.environment(contact_plan.environment)
            except SpecError:
                env = None
        env = env or self.environment(ladder or self.default_ladder)
        return plan_from_contact_plan(robot, env, contact_plan, settings=self.settings, on_progress=on_progress)


def main(args: list[str] | None = None) -> int:
    from climb_core.ros_env import apply_local_dds_env

    apply_local_dds_env()
    import rclpy
    from climb_msgs.msg import ClimbStatus, ContactPlan, WholeBodyPlan
    from rclpy.executors import ExternalShutdownException, MultiThreadedExecutor
    from rclpy.node import Node
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
    from std_msgs.msg import String

    from msgs_py.contact import contact_plan_from_msg, whole_body_plan_to_msg
    from msgs_py.stamps import make_header

    def qos(depth: int) -> QoSProfile:
        return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=depth, reliability=ReliabilityPolicy.RELIABLE,
                          durability=DurabilityPolicy.VOLATILE)

    class AdaptationNode(Node):
        def __init__(self) -> None:
            super().__init__(NODE_NAME)
            defaults = flatten(load_settings())
            for name, info in describe(PlannerSettings).items():
                self.declare_parameter(name, defaults[name])  # scalars only (types: bool, int, float, str)
            self.declare_parameter("ladder", "default")
            flat = {name: self.get_parameter(name).value for name in describe(PlannerSettings)}
            self.settings = parse_params(flat, PlannerSettings, NODE_NAME)
            self.service = AdaptationService(self.settings, self.get_parameter("ladder").value)
            self.pub_plan = self.create_publisher(WholeBodyPlan, "whole_body_plan", qos(1))
            self.pub_status = self.create_publisher(ClimbStatus, "primitive_adaptation/status", qos(10))
            self.create_subscription(String, "primitive_adaptation/request", self._on_request, qos(10))
            self.create_subscription(ContactPlan, "contact_plan", self._on_contact_plan, qos(1))
            self._busy = threading.Lock()
            self._progress = (0, 0)
            self._id = ""
            self.create_timer(STATUS_PERIOD_S, self._tick)
            self.get_logger().info("primitive_adaptation ready")

        def status(self, phase: str, text: str = "", step: int = 0, n: int = 0) -> None:
            msg = ClimbStatus(header=make_header(self.get_clock().now().nanoseconds * 1e-9), id=self._id, phase=phase,
                              step=int(step), n_steps=int(n), progress=float(step / n) if n else 0.0, text=text)
            self.pub_status.publish(msg)

        def _tick(self) -> None:
            if self._busy.locked():
                k, n = self._progress
                self.status("adaptation", "planning", k, n)

        def _on_request(self, msg) -> None:
            try:
                request = parse_request(msg.data, self.settings.planning.robot, self.service.default_ladder)
            except SpecError as exc:
                self.status("failed", f"malformed request: {exc}")
                return
            self._start(lambda cb: self.service.plan_request(request, cb), request["id"])

        def _on_contact_plan(self, msg) -> None:
            try:
                plan = contact_plan_from_msg(msg)
            except (SpecError, ValueError) as exc:
                self.status("failed", f"malformed contact plan: {exc}")
                return
            self._start(lambda cb: self.service.plan_contact(plan, on_progress=cb), "contact_plan")

        def _start(self, job, request_id: str) -> None:
            if not self._busy.acquire(blocking=False):
                self.status("failed", f"busy: request {request_id!r} ignored")
                return
            self._id = request_id
            self._progress = (0, 0)
            threading.Thread(target=self._run, args=(job,), daemon=True).start()

        def _run(self, job) -> None:
            try:
                def progress(k, n, _):
                    self._progress = (k, n)

                res = job(progress)
                if res.plan is not None and res.success:
                    self.pub_plan.publish(whole_body_plan_to_msg(res.plan,
                                                                 stamp=self.get_clock().now().nanoseconds * 1e-9))
                    self.status("done", json.dumps(res.summary()), len(res.subtasks), len(res.subtasks))
                else:
                    self.status("failed", f"{res.failure_constraint}: {res.failure_detail}",
                                res.report.deepest if res.report else 0, len(res.subtasks))
            except ClimbError as exc:
                self.status("failed", f"{exc}")
            except Exception as exc:  # keep the node alive whatever the planner raised
                self.get_logger().error(f"planning crashed: {exc!r}")
                self.status("failed", f"internal error: {exc!r}")
            finally:
                self._busy.release()

    rclpy.init(args=args)
    node = None
    try:
        node = AdaptationNode()
        executor = MultiThreadedExecutor(num_threads=2)
        executor.add_node(node)
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
