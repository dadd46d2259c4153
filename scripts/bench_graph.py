#!/usr/bin/env python3
"""The climb through the ROS 2 graph, measured: lock-step real-time factor of the process graph
and of the composed layout (bridge + controller in one sim_graph process), per-stage planning
times, the coordinator's overhead (goal accepted -> first command), and, as the baseline in the
same run, the in-process climb of the same plan (the plan the graph's primitive_adaptation
published, executed by the controller library against PyBullet in this process).

    scripts/bench_graph.py [--rungs 1] [--mode qp] [--layouts processes,composed] [--out out/bench_graph]

Real-time factor: sim time / wall time over the execution (from the controller's first state
after picking the plan to the end of the run), from controller/state as this script receives
it. Progress on standard error; the last line on standard output is one JSON object whose keys
carry their units.
"""
from __future__ import annotations

import argparse
import json
import pathlib
import sys
import threading
import time

from climb_core.ros_env import apply_local_dds_env

apply_local_dds_env()

ROOT = pathlib.Path(__file__).resolve().parents[1]


def say(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


def run_graph(layout: str, args, out: pathlib.Path) -> dict:
    import rclpy
    from climb_msgs.action import Climb as ClimbAction
    from climb_msgs.msg import ControllerState, WholeBodyPlan
    from rclpy.action import ActionClient
    from rclpy.executors import MultiThreadedExecutor

    from climb_coordinator.graph import GraphProcesses, load_graph
    from msgs_py.topics import qos_for

    delay = {"lockstep.command_delay_ticks": args.command_delay}
    extra = {"sim_graph": {"autostart": False, **delay}, "sim_bridge": delay}
    graph = GraphProcesses(load_graph().layout(layout, with_optional=False), extra, log_dir=out / layout / "logs")
    ctx = rclpy.Context()
    rclpy.init(context=ctx)
    node = rclpy.create_node("bench_graph", context=ctx)
    states: list = []  # (wall, sim, fsm)
    plans: list = []
    lock = threading.Lock()

    def on_state(m) -> None:
        with lock:
            states.append((time.monotonic(), m.header.stamp.sec + m.header.stamp.nanosec * 1e-9, m.fsm_state))

    node.create_subscription(ControllerState, "controller/state", on_state, qos_for("controller/state"))
    node.create_subscription(WholeBodyPlan, "whole_body_plan", lambda m: plans.append(m), qos_for("whole_body_plan"))
    client = ActionClient(node, ClimbAction, "climb")
    executor = MultiThreadedExecutor(num_threads=2, context=ctx)
    executor.add_node(node)
    stop = threading.Event()
    spinner = threading.Thread(target=lambda: [executor.spin_once(timeout_sec=0.05) for _ in iter(stop.is_set, True)],
                               daemon=True)
    spinner.start()

    def wait(future, timeout):
        deadline = time.monotonic() + timeout
        while not future.done():
            if time.monotonic() > deadline:
                raise TimeoutError("timeout")
            if graph.crashed():
                raise RuntimeError(f"node crashed: {graph.crashed()}")
            time.sleep(0.01)
        return future.result()

    t_start = time.monotonic()
    try:
        graph.start()
        if not client.wait_for_server(timeout_sec=300.0):
            raise RuntimeError("no climb action server")
        t_up = time.monotonic()
        say(f"[{layout}] graph up in {t_up - t_start:.1f} s; climbing {args.rungs} rung(s) in {args.mode} mode")
        goal = ClimbAction.Goal(robot="g1", scenario=args.scenario, rungs=args.rungs, controller_mode=args.mode,
                                command_delay_ticks=args.command_delay,
                                seed=args.seed)
        handle = wait(client.send_goal_async(goal), 60.0)
        t_accepted = time.monotonic()
        result = wait(handle.get_result_async(), args.timeout).result
        t_end = time.monotonic()
    finally:
        stop.set()
        spinner.join(5)
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown(context=ctx)
        graph.stop()
    summary = json.loads(result.summary_json)
    with lock:
        after = [s for s in states if s[0] >= t_accepted]
    first_state = after[0] if after else None
    moving = [s for s in after if s[2] not in ("idle", "hold", "replan_needed")]
    r = {"success": bool(summary.get("success")), "failure_reason": summary.get("failure_reason", ""),
         "graph_startup_s": round(t_up - t_start, 2), "sim_time_s": summary.get("sim_time_s"),
         "plan_stages_s": summary.get("plan_stages_s", {}), "plan_time_s": summary.get("plan_time_s"),
         "plan": plans[-1] if plans else None}
    if moving:
        w0, s0, _ = moving[0]
        w1, s1, _ = after[-1]
        r["execution_wall_s"] = round(w1 - w0, 2)
        r["execution_sim_s"] = round(s1 - s0, 2)
        r["rtf"] = round((s1 - s0) / (w1 - w0), 3) if w1 > w0 else None
        r["accepted_to_plan_start_s"] = round(w0 - t_accepted, 3)
        r["overhead_excluding_planning_s"] = round(w0 - t_accepted - float(summary.get("plan_time_s") or 0.0), 3)
    if first_state is not None:
        r["accepted_to_first_command_s"] = round(first_state[0] - t_accepted, 3)
    r["total_wall_s"] = round(t_end - t_accepted, 2)
    return r


def run_inprocess(plan_msg, args) -> dict:
    from climb_coordinator.climb import ClimbRequest, execute
    from climb_coordinator.session import PlanOutcome
    from climb_coordinator.settings import load_climb_settings
    from climb_core.ladder import load_scenario
    from msgs_py.contact import whole_body_plan_from_msg
    from planner_node.primitives import load_library
    from planner_node.settings import load_settings

    plan = whole_body_plan_from_msg(plan_msg)

    class FixedPlan:
        def plan(self, steps, start=None):
            return PlanOutcome(True, plan, 0.0, 1 + len(plan.transitions))

    req = ClimbRequest(ladder=args.scenario, robot="g1", rungs=args.rungs, mode=args.mode, bag=False, seed=args.seed,
                       command_delay_ticks=args.command_delay)
    cs = load_climb_settings()
    p = load_settings().planning
    fixture = load_library("g1", p.strategy, p.primitives_dir).initial_fixture
    say(f"[inprocess] executing the graph's plan ({len(plan.transitions)} transitions) in this process")
    res = execute(req, FixedPlan(), cs, load_scenario(args.scenario), fixture)
    try:
        s = res.summary
        return {"success": bool(s["success"]), "failure_reason": s["failure_reason"], "sim_time_s": s["sim_time_s"],
                "execution_wall_s": s["wall_time_s"], "rtf": s["real_time_factor"]}
    finally:
        res.close()


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--rungs", type=int, default=1)
    ap.add_argument("--mode", default="qp")
    ap.add_argument("--scenario", default="default")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--layouts", default="processes,composed")
    ap.add_argument("--command-delay", type=int, default=0, choices=(0, 1),
                    help="1: one-period actuation latency (the bridge's physics runs while the controller computes)")
    ap.add_argument("--timeout", type=float, default=1500.0, help="[s] wall per graph climb")
    ap.add_argument("--out", default=str(ROOT / "out" / "bench_graph"))
    args = ap.parse_args(argv)
    out = pathlib.Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    results: dict = {"rungs": args.rungs, "mode": args.mode, "scenario": args.scenario,
                     "command_delay_ticks": args.command_delay}
    plan_msg = None
    for layout in [x.strip() for x in args.layouts.split(",") if x.strip()]:
        r = run_graph(layout, args, out)
        plan_msg = plan_msg or r.pop("plan", None)
        r.pop("plan", None)
        say(f"[{layout}] {json.dumps(r)}")
        results[f"{layout}_success"] = r["success"]
        results[f"{layout}_failure_reason"] = r["failure_reason"]
        results[f"{layout}_rtf_x"] = r.get("rtf")
        results[f"{layout}_execution_sim_s"] = r.get("execution_sim_s")
        results[f"{layout}_execution_wall_s"] = r.get("execution_wall_s")
        results[f"{layout}_graph_startup_s"] = r["graph_startup_s"]
        results[f"{layout}_plan_time_s"] = r["plan_time_s"]
        for stage, seconds in (r.get("plan_stages_s") or {}).items():
            results[f"{layout}_plan_{stage}_s"] = seconds
        results[f"{layout}_accepted_to_first_command_s"] = r.get("accepted_to_first_command_s")
        results[f"{layout}_accepted_to_plan_start_s"] = r.get("accepted_to_plan_start_s")
        results[f"{layout}_overhead_excluding_planning_s"] = r.get("overhead_excluding_planning_s")
    if plan_msg is not None:
        r = run_inprocess(plan_msg, args)
        say(f"[inprocess] {json.dumps(r)}")
        results["inprocess_success"] = r["success"]
        results["inprocess_rtf_x"] = r["rtf"]
        results["inprocess_execution_sim_s"] = r["sim_time_s"]
        results["inprocess_execution_wall_s"] = r["execution_wall_s"]
    import os

    results["load_avg_1min"] = round(os.getloadavg()[0], 2)
    print(json.dumps(results))
    return 0


if __name__ == "__main__":
    sys.exit(main())
