#!/usr/bin/env python3
"""Plan a ladder climb (or a scene) and execute it in the simulator: through the ROS 2 graph
(default) or in one process.

    scripts/climb.py --scenario default --robot g1 --rungs 2 --mode qp --out out/climb
                     [--graph processes|composed|inprocess] [--seed 0] [--no-bag] [--timeout 1200]
    scripts/climb.py --plan tests/data/vertical_plan.json [--max-transitions 7] --out out/vertical

--plan FILE: execute a plan made before (scripts/plan.py --out FILE; planner_node.plan_io JSON)
instead of planning one, in process; --scenario, --robot and --rungs default to the plan's, the robot starts in
the fixture that holds the plan's first stance, and a replan goes to the planner as usual.

--scenario (alias --ladder): a name in config/ladders/ or config/scenes/, or a scenario file
(shared/specs/ladder_spec.md, scene_spec.md). Without --strategy the strategy is chosen for the
scenario (a scene or a walked ladder such as stairs: search; a steeper ladder: the primitives) and
the summary says why (`strategy_reason`); a scene without a ladder with --strategy primitives exits
with code 2 and says so.
--graph processes (default): every node of config/graph.yaml in its own process (sim_bridge,
controller, guide_path, contact_search, primitive_adaptation, climb_coordinator, recorder);
composed: the bridge and the controller in one `sim_graph` process, the rest separate; inprocess:
no ROS (planner library + controller library + PyBullet in this process).
Graph runs: the climb goes to the coordinator's `climb` action; progress on standard error (a bar on
a terminal, plain lines otherwise); the recorder writes DIR/bag, scripts/report.py renders DIR/report
from it; node logs in DIR/logs. Every child runs in its own process group and dies with this
script, also on Ctrl-C, on a node crash (reported), on --timeout and on SIGKILL of this script.
In-process runs write DIR/bag, DIR/plots.png (and DIR/film_strip.png with --snapshots).
The last line on standard output is the JSON summary (ladder_spec.md "Results"). Exit codes: 0
climbed, 1 did not (or a node crashed, timeout, interrupted), 2 bad spec or option
(`error: <field>: <rule>` on standard error, no traceback).
"""
from __future__ import annotations

import argparse
import json
import pathlib
import signal
import subprocess
import sys
import time

from climb_core.ros_env import apply_local_dds_env

apply_local_dds_env()  # DDS stays on this machine (loopback profile, private domain)

ROOT = pathlib.Path(__file__).resolve().parents[1]
GRAPHS = ("processes", "composed", "inprocess")


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenario", "--ladder", dest="scenario", default=None,
                    help="scenario: name in config/ladders/ or config/scenes/, or a YAML file (--ladder: alias; "
                         "default: default, or the --plan's)")
    ap.add_argument("--robot", default=None,
                    help="robot config name (config/robots/<name>.yaml; default: g1, or the --plan's)")
    ap.add_argument("--rungs", type=int, default=None,
                    help="climbing cycles after the mount (feet end on rung N; default: 2, or the --plan's)")
    ap.add_argument("--mode", default="qp", help="controller mode: qp | compliance")
    ap.add_argument("--out", default="out/climb", help="output directory (bag, report / plots, logs)")
    ap.add_argument("--graph", default=None, choices=GRAPHS,
                    help="processes (default): a process per node; composed: bridge + controller in one "
                         "sim_graph process; inprocess: no ROS (the only one with --plan)")
    ap.add_argument("--plan", default="", metavar="FILE",
                    help="execute this stored plan (scripts/plan.py --out) instead of planning; in process")
    ap.add_argument("--max-transitions", type=int, default=None, metavar="K",
                    help="execute only the plan's first K transitions (e.g. a stored plan's mount)")
    ap.add_argument("--seed", type=int, default=None, help="planner random seed (default: config/planner.yaml)")
    ap.add_argument("--no-bag", action="store_true", help="do not record a bag")
    ap.add_argument("--plan-cycles", type=int, default=None,
                    help="plan this many cycles at a time; the next ones are planned from the reached state")
    ap.add_argument("--descend", action="store_true",
                    help="after the climb, climb back down to the ground (the reverse of the climbing cycles)")
    ap.add_argument("--snapshots", type=int, default=0,
                    help="film strip frames (in process: DIR/film_strip.png; graph: the report's film strip)")
    ap.add_argument("--no-plots", action="store_true", help="no plots (in process) / no report (graph)")
    ap.add_argument("--command-delay", type=int, default=0, choices=(0, 1),
                    help="1: every command acts one control period late (a robot's actuation latency; "
                         "the controller then computes each command for the state one period ahead)")
    ap.add_argument("--strategy", default="", choices=("", "primitives", "search"),
                    help="planning: primitives (the ladder paper; ladders) | search (free-flyer guide path + "
                         "best-first contact search; ladders and scenes); default: chosen for the scenario "
                         "(scenes and walked ladders such as stairs: search; the summary's strategy_reason)")
    ap.add_argument("--start-posture", default="", choices=("", "standing", "ladder_4_contacts"),
                    help="stance the robot starts in (default: the primitive library's start; standing for search)")
    ap.add_argument("--timeout", type=float, default=1200.0, help="[s] wall time for the whole graph run")
    return ap


def _request(args):
    from climb_coordinator.session import ClimbRequest

    return ClimbRequest(ladder=args.scenario, robot=args.robot, rungs=args.rungs, mode=args.mode,
                        out_dir=args.out, seed=args.seed, bag=not args.no_bag, snapshots=args.snapshots,
                        descend=args.descend, plan_cycles=args.plan_cycles, command_delay_ticks=args.command_delay,
                        strategy=args.strategy, start_posture=args.start_posture,
                        max_transitions=args.max_transitions)


def stored_plan_defaults(args) -> None:
    """--plan: the graph is this process, --scenario, --robot and --rungs the plan's unless given
    (SpecError naming the option or the plan's field)."""
    from climb_core.errors import SpecError
    from planner_node.plan_io import load_plan

    if args.graph not in (None, "inprocess"):
        raise SpecError("--plan", f"a stored plan is executed in process (--graph inprocess), not --graph {args.graph}")
    args.graph = "inprocess"
    plan, metadata = load_plan(args.plan)
    args.scenario = args.scenario or plan.environment
    args.robot = args.robot or plan.robot
    if args.rungs is None:
        steps = metadata.get("steps")
        args.rungs = int(steps) if isinstance(steps, int) and steps >= 1 else 2


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    from climb_core.errors import ClimbError, SpecError
    from climb_coordinator.session import base_summary, check_request, with_chosen_strategy

    try:
        if args.plan:
            stored_plan_defaults(args)
    except SpecError as exc:
        print(f"error: {exc}", file=sys.stderr)
        print(json.dumps({"success": False, "failure_reason": f"spec: {exc}", "plan_file": args.plan}))
        return 2
    args.graph = args.graph or "processes"
    args.scenario = args.scenario or "default"
    args.robot = args.robot or "g1"
    args.rungs = 2 if args.rungs is None else args.rungs
    req = with_chosen_strategy(_request(args))
    summary = base_summary(req)
    try:
        check_scene(args.scenario, summary, req.strategy)
        check_request(req) if args.graph != "inprocess" else None
    except SpecError as exc:
        print(f"error: {exc}", file=sys.stderr)
        summary["failure_reason"] = f"spec: {exc}"
        print(json.dumps(summary))
        return 2
    if args.graph == "inprocess":
        return run_inprocess(args, req, summary)
    try:
        return run_graph(args, req, summary)
    except ClimbError as exc:
        print(f"error: {exc}", file=sys.stderr)
        summary["failure_reason"] = str(exc)
        print(json.dumps(summary))
        return 2 if isinstance(exc, SpecError) else 1


def check_scene(source: str, summary: dict, strategy: str) -> None:
    """Add a scene's summary fields (scene_spec.md "Results", nothing reached yet) and refuse a
    scene without a ladder unless the strategy is `search` (SpecError)."""
    from climb_core.ladder import load_scenario
    from climb_core.scene import require_search_strategy

    scenario = load_scenario(source)
    if scenario.scene is None:
        return
    summary.update(scene=scenario.name, contacts_used=[])
    if scenario.scene.goal is not None:
        summary.update(goal_reached=False, goal_distance_m=None)
    if scenario.ladder is None:
        summary.update(rungs_requested=0, rungs_reached=0)
        require_search_strategy(scenario, strategy)


# ------------------------------------------------------------------------------ in process


def run_inprocess(args, req, summary: dict) -> int:
    from climb_core.errors import ClimbError, SpecError
    from climb_coordinator.climb import run_climb, run_stored_plan

    say = lambda m: print(m, file=sys.stderr, flush=True)  # noqa: E731
    try:
        result = run_stored_plan(req, args.plan, on_progress=say) if args.plan else run_climb(req, on_progress=say)
    except SpecError as exc:
        print(f"error: {exc}", file=sys.stderr)
        summary["failure_reason"] = f"spec: {exc}"
        print(json.dumps(summary))
        return 2
    except ClimbError as exc:
        print(f"error: {exc}", file=sys.stderr)
        summary["failure_reason"] = str(exc)
        print(json.dumps(summary))
        return 1
    try:
        if result.backend is not None:
            from climb_coordinator.plots import film_strip, plot_climb

            if not args.no_plots:
                result.summary["plots"] = str(plot_climb(result, pathlib.Path(args.out) / "plots.png"))
            if result.frames:
                result.summary["film_strip"] = str(film_strip(result.frames, pathlib.Path(args.out) / "film_strip.png"))
    finally:
        result.close()
    result.summary["graph"] = "inprocess"
    if args.plan:
        result.summary["plan_file"] = args.plan
    print(json.dumps(result.summary))
    return 0 if result.summary["success"] else 1


# ------------------------------------------------------------------------------ the graph


class Progress:
    """A progress bar on a terminal, plain lines otherwise (standard error)."""

    def __init__(self) -> None:
        self.tty = sys.stderr.isatty()
        self.last = ""
        self.last_t = 0.0

    def show(self, fb) -> None:
        text = (f"{fb.phase:<12} {fb.stage or '':<20} stance {fb.stance_index}/{fb.n_stances} "
                f"{fb.fsm_state or '':<14} {fb.text[:40]}")
        if self.tty:
            width = 30
            filled = int(round(width * max(0.0, min(1.0, fb.progress))))
            sys.stderr.write(f"\r[{'#' * filled}{'.' * (width - filled)}] {100 * fb.progress:5.1f}% {text[:90]:<90}")
            sys.stderr.flush()
        else:
            now = time.monotonic()
            key = f"{fb.phase}{fb.stage}{fb.stance_index}{fb.fsm_state}"
            if key != self.last or now - self.last_t > 10.0:
                print(f"{100 * fb.progress:5.1f}% {text}", file=sys.stderr, flush=True)
                self.last, self.last_t = key, now

    def done(self) -> None:
        if self.tty:
            sys.stderr.write("\n")
            sys.stderr.flush()


class Interrupted(Exception):
    pass


def run_graph(args, req, summary: dict) -> int:
    from climb_coordinator.graph import GraphProcesses, load_graph

    out = pathlib.Path(args.out).resolve()
    out.mkdir(parents=True, exist_ok=True)
    bag = out / "bag"
    if bag.exists():
        import shutil

        shutil.rmtree(bag)
    layout = args.graph
    nodes = load_graph().layout(layout, with_optional=not args.no_bag)
    extra = {"recorder": {"bag_path": str(bag)}, "climb_coordinator": {"bag": str(bag)}}
    bridge_extra = {"lockstep.command_delay_ticks": int(args.command_delay)}
    extra["sim_bridge"] = dict(bridge_extra)
    extra["sim_graph"] = dict(bridge_extra, autostart=False)
    graph = GraphProcesses(nodes, extra, log_dir=out / "logs")
    say = lambda m: print(m, file=sys.stderr, flush=True)  # noqa: E731
    if graph.skipped:
        say(f"not started (executable not installed): {', '.join(graph.skipped)}")
    stop = {"signal": None}

    def on_signal(signum, frame):  # noqa: ARG001
        stop["signal"] = signum
        raise Interrupted()

    old = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    code = 1
    t_start = time.monotonic()
    try:
        say(f"starting the graph ({layout}): {', '.join(graph.commands())}")
        graph.start()
        summary = _drive(args, req, summary, graph, say, t_start)
        code = 0 if summary.get("success") else 1
    except Interrupted:
        summary["failure_reason"] = f"interrupted (signal {stop['signal']})"
        say(summary["failure_reason"])
    finally:
        for s, h in old.items():
            signal.signal(s, h)
        signal.signal(signal.SIGINT, signal.SIG_IGN)  # a second Ctrl-C must not cut the shutdown
        codes = graph.stop()
        signal.signal(signal.SIGINT, old[signal.SIGINT])
    summary["graph"] = layout
    summary["node_exit_codes"] = codes
    if not args.no_bag and "recorder" in codes and bag.exists():
        summary["bag"] = str(bag)
        if not args.no_plots and (ROOT / "scripts" / "report.py").exists():
            summary.update(_report(bag, out, args, say))
    summary["wall_time_total_s"] = round(time.monotonic() - t_start, 2)
    print(json.dumps(summary))
    return code


def _report(bag: pathlib.Path, out: pathlib.Path, args, say) -> dict:
    cmd = [sys.executable, str(ROOT / "scripts" / "report.py"), str(bag), "--out", str(out / "report")]
    if args.snapshots:
        cmd += ["--film", str(args.snapshots)]
    try:
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
    except subprocess.TimeoutExpired:
        return {"report_error": "scripts/report.py timed out"}
    if proc.returncode != 0:
        say(f"report failed: {proc.stderr.strip()[-500:]}")
        return {"report_error": proc.stderr.strip()[-500:]}
    try:
        return {"report": json.loads(proc.stdout.strip().splitlines()[-1])}
    except (ValueError, IndexError):
        return {"report": str(out / "report")}


def _drive(args, req, summary: dict, graph, say, t_start: float) -> dict:
    """The action client: wait for the coordinator, send the goal, follow it, watch the nodes."""
    import rclpy
    from climb_msgs.action import Climb as ClimbAction
    from rclpy.action import ActionClient
    from rclpy.signals import SignalHandlerOptions

    rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
    node = rclpy.create_node("climb_cli")
    progress = Progress()
    deadline = t_start + args.timeout
    try:
        client = ActionClient(node, ClimbAction, "climb")

        def check_nodes() -> None:
            dead = graph.crashed()
            if dead:
                name, rc = dead[0]
                tail = graph.log_tail(name, 800).strip().splitlines()[-3:]
                raise NodeCrashed(f"node {name} crashed (exit code {rc}): {' | '.join(tail)}")

        while not client.wait_for_server(timeout_sec=0.5):
            check_nodes()
            if time.monotonic() > deadline:
                raise NodeCrashed(f"the climb_coordinator's action did not appear within {args.timeout:.0f} s")
        say(f"graph up in {time.monotonic() - t_start:.1f} s; sending the goal")
        goal = ClimbAction.Goal(robot=req.robot, scenario=str(req.ladder), rungs=int(req.rungs),
                                controller_mode=req.mode, seed=int(req.seed or 0), descend=bool(req.descend),
                                plan_cycles=int(req.plan_cycles or 0),
                                command_delay_ticks=int(req.command_delay_ticks), strategy=req.strategy,
                                start_posture=req.start_posture)
        if req.plan_timeout_s:
            goal.planning_timeout_s = float(req.plan_timeout_s)
        if "\n" not in goal.scenario and pathlib.Path(goal.scenario).is_file():
            goal.scenario = pathlib.Path(goal.scenario).read_text()  # the coordinator may run elsewhere
        send = client.send_goal_async(goal, feedback_callback=lambda m: progress.show(m.feedback))
        handle = _spin_until(node, send, deadline, check_nodes)
        if not handle.accepted:
            raise NodeCrashed("the coordinator rejected the goal (a climb is already running)")
        result_future = handle.get_result_async()
        try:
            result = _spin_until(node, result_future, deadline, check_nodes).result
        except (NodeCrashed, Interrupted) as exc:
            progress.done()
            cancel = handle.cancel_goal_async()
            _spin_until(node, cancel, time.monotonic() + 5.0, lambda: None, quiet=True)
            if isinstance(exc, Interrupted):
                raise
            summary["failure_reason"] = str(exc)
            say(str(exc))
            return summary
        progress.done()
        try:
            summary = json.loads(result.summary_json)
        except ValueError:
            summary["failure_reason"] = result.failure_reason or "no summary"
        say(f"done: {summary.get('failure_reason') or 'success'}")
        return summary
    except NodeCrashed as exc:
        progress.done()
        summary["failure_reason"] = str(exc)
        say(str(exc))
        return summary
    finally:
        node.destroy_node()
        rclpy.try_shutdown()


class NodeCrashed(Exception):
    pass


def _spin_until(node, future, deadline: float, check, quiet: bool = False):
    import rclpy

    while not future.done():
        rclpy.spin_once(node, timeout_sec=0.1)
        check()
        if time.monotonic() > deadline:
            if quiet:
                return None
            raise NodeCrashed("timeout: the climb did not end within --timeout")
    return future.result()


if __name__ == "__main__":
    sys.exit(main())
