"""The `primitive_adaptation` node as a process: requests on its topic, plans and statuses back.

A malformed request gets a `failed` status naming the field and the rule; a valid one is planned
in the node's worker thread (progress on the status topic, a second request meanwhile is refused
as busy) and the whole-body plan that arrives over DDS is still physically valid: the core
feasibility check re-run on it at 4x its discretisation passes, and it ends with both feet on
rung 1. The node is alive at the end and exits cleanly on SIGINT.
"""
from __future__ import annotations

import json
import pathlib
import signal
import subprocess
import sys
import time

import pytest

pytestmark = pytest.mark.ros

ROOT = pathlib.Path(__file__).resolve().parents[2]


def test_adaptation_node_plans_requests_and_survives_bad_ones():
    import rclpy
    from climb_msgs.msg import ClimbStatus, WholeBodyPlan
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
    from std_msgs.msg import String

    from climb_core.environment import build_environment
    from climb_core.ladder import load_scenario
    from climb_core.robot import load_robot
    from climb_core.ros_env import local_dds_env
    from msgs_py.contact import whole_body_plan_from_msg
    from planner_node.verify import verify_plan

    node_proc = subprocess.Popen([sys.executable, "-m", "planner_node.adaptation_node"], env=local_dds_env(),
                                 cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    context = rclpy.Context()
    rclpy.init(context=context)
    statuses: list[ClimbStatus] = []
    plans: list[WholeBodyPlan] = []
    try:
        node = rclpy.create_node("adaptation_test_client", context=context)
        qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.VOLATILE)
        node.create_subscription(ClimbStatus, "primitive_adaptation/status", statuses.append, qos)
        node.create_subscription(WholeBodyPlan, "whole_body_plan", plans.append, qos)
        pub = node.create_publisher(String, "primitive_adaptation/request", qos)
        executor = SingleThreadedExecutor(context=context)
        executor.add_node(node)

        def spin_until(predicate, timeout_s: float) -> bool:
            end = time.monotonic() + timeout_s
            while time.monotonic() < end:
                executor.spin_once(timeout_sec=0.05)
                if predicate():
                    return True
                assert node_proc.poll() is None, node_proc.stdout.read().decode()[-3000:]
            return False

        assert spin_until(lambda: pub.get_subscription_count() > 0 and node.count_publishers(
            "primitive_adaptation/status") > 0, 60.0), "the node never came up"
        time.sleep(0.5)  # let discovery finish in both directions

        # 1. malformed: named field and rule, no plan
        pub.publish(String(data="{steps: -1, id: bad}"))
        assert spin_until(lambda: any(s.phase == "failed" for s in statuses), 20.0)
        (bad,) = [s for s in statuses if s.phase == "failed"]
        assert "request.steps" in bad.text and ">= 0" in bad.text
        assert not plans

        # 2. a valid 1-step request; a second one while it plans is refused as busy
        statuses.clear()
        pub.publish(String(data=json.dumps({"ladder": "default", "robot": "g1", "steps": 1, "seed": 0,
                                            "timeout_s": 120, "id": "one_step"})))
        assert spin_until(lambda: any(s.phase == "adaptation" for s in statuses), 30.0)
        pub.publish(String(data=json.dumps({"steps": 1, "id": "second"})))
        assert spin_until(lambda: any(s.phase == "done" for s in statuses) and plans, 150.0), \
            [(s.phase, s.text[:100]) for s in statuses]
        busy = [s for s in statuses if s.phase == "failed"]
        assert busy and "busy" in busy[0].text and "second" in busy[0].text
        assert busy[0].id == "second"  # the refused request's id, not the running one's (issue 20, row 9)
        progress = [s for s in statuses if s.phase == "adaptation"]
        assert all(s.id == "one_step" and 0 <= s.step <= s.n_steps for s in progress)
        (done,) = [s for s in statuses if s.phase == "done"]
        summary = json.loads(done.text)
        assert summary["success"] is True and done.id == "one_step"

        # 3. the plan that came over DDS is physically valid and ends with both feet on rung 1
        plan = whole_body_plan_from_msg(plans[-1])
        robot = load_robot("g1")
        env = build_environment(load_scenario("default"))
        goal = plan.transitions[-1].target_stance
        assert {h.limb: h.env_surface for h in goal.holds if h.limb.endswith("foot")} == \
            {"left_foot": "rung_1", "right_foot": "rung_1"}
        report = verify_plan(robot, env, plan, refine=4)
        assert report.ok, report
        assert node_proc.poll() is None  # still serving
    finally:
        rclpy.try_shutdown(context=context)
        if node_proc.poll() is None:
            node_proc.send_signal(signal.SIGINT)
            try:
                node_proc.wait(timeout=15)
            except subprocess.TimeoutExpired:
                node_proc.kill()
                node_proc.wait()
    assert node_proc.returncode == 0, node_proc.stdout.read().decode()[-3000:]
