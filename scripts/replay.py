#!/usr/bin/env python3
"""Replay a rosbag2 bag into the graph, byte for byte on its original timing, or re-execute its plan.

    scripts/replay.py BAG [--rate R] [--topics T ...] [--namespace NS]
    scripts/replay.py BAG --reexecute [--set-param controller:NAME=VALUE ...]

Replay: every recorded message (``/clock`` included, so nodes on sim time follow the bag) is
published as its recorded CDR bytes (``publish(bytes)``: no decoding, no per-type code) at its
recorded receive time, scaled by ``--rate``, with the QoS its publishers offered when it was
recorded (a latched topic is published TRANSIENT_LOCAL again). ``--namespace NS`` puts every topic
under /NS (``/clock`` too). Safety: a replayed joint_command must never drive a live robot, so
the replay refuses (exit code 3) to publish joint_command, gripper_command or whole_body_plan
into a namespace where a sim_bridge, controller or sim_graph node is live (or subscribes to
them); replay those under a namespace, or leave them out with --topics.

Re-execute (``--reexecute``): the recorded plan(s) (``whole_body_plan``) and request
(``climb/request``: robot, scenario text, mode, seed, command delay, start posture) feed a fresh
``sim_bridge`` + ``controller`` started here, in lock-step, in a private namespace (``/clock``
remapped into it), with no planner running. The controller's ``joint_command`` goes through this
script (``joint_command_gate``, relayed byte for byte), which holds the command of the tick before
the one at which the recorded controller took each plan until the plan has reached the new
controller: the new run takes each plan on the same sim tick as the recorded one. Its gripper
requests are relayed too, while the bridge waits for the next tick's command, so that each acts
from the tick after its stamp (as the recorded one did: it reached the bridge after the joint
command of its tick). The controller runs with the recorded request's ``controller_overrides``
when it has them (else config/climb.yaml's, as the coordinator applies them). A recorded
controller that answered late (the coordinator activates it after the world's first state) left
the recorded bridge damping the ticks before (its "controller lost" diagnostic says so; a bag
whose first commands the recorder missed has none), and after, until its "controller back at t"
diagnostic: those ticks are damped again and the new controller is activated at the state the
recorded one answered first (``--no-damp-unanswered``: autostart instead). The base positions
(``sim/base_truth``) of both runs are then compared at equal sim stamps: max and RMS deviation
[mm]; the first tick whose joint command or joint state differs is reported too (a lock-step run
is bit-identical: 0 mm when nothing changed). ``--set-param controller:NAME=VALUE`` changes a
controller parameter (e.g. a gain, to see the comparison fail). ``REPLAY_DUMP=file`` pickles both
runs' commands and states for a closer look.

The last line on standard output is one JSON object. Exit codes: 0 done, 2 bad arguments or an
unreadable bag, 3 refused (live robot), 4 re-execution failed (a node died, timeout).
"""
from __future__ import annotations

import argparse
import json
import os
import pathlib
import signal
import subprocess
import sys
import tempfile
import time

ROOT = pathlib.Path(__file__).resolve().parents[1]
#: topics that drive a robot: never replayed into a namespace with a live bridge / controller
ACTUATION = ("joint_command", "gripper_command", "whole_body_plan")
#: node names that act on those topics
LIVE_NODES = ("sim_bridge", "controller", "sim_graph")
NS = 1_000_000_000


class Refused(Exception):
    pass


def _abs(topic: str) -> str:
    return topic if topic.startswith("/") else "/" + topic


def target_name(topic: str, namespace: str | None) -> str:
    """The topic a recorded topic is replayed on: /NS/<topic> under a namespace (/clock too)."""
    topic = _abs(topic)
    if not namespace:
        return topic
    return "/" + namespace.strip("/") + topic


def _qos(profiles: list, durable_depth: int = 1, depth: int = 100):
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
    from rosbags.interfaces import QosDurability, QosReliability

    reliable = not any(p.reliability == QosReliability.BEST_EFFORT for p in profiles)
    latched = bool(profiles) and all(p.durability == QosDurability.TRANSIENT_LOCAL for p in profiles)
    if latched:
        depth = max([durable_depth] + [int(p.depth) for p in profiles])
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=depth,
                      reliability=ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL if latched else DurabilityPolicy.VOLATILE)


def _wait_graph(node, seconds: float) -> None:
    """Let discovery fill the graph (a process joining sees its peers after ~0.5 s)."""
    import rclpy

    end = time.monotonic() + seconds
    while time.monotonic() < end:
        rclpy.spin_once(node, timeout_sec=0.05)


def wait_until_active(node, name: str, proc: subprocess.Popen, timeout_s: float) -> None:
    """Poll <name>/get_state until the lifecycle node says active; RuntimeError on timeout or death."""
    import rclpy
    from lifecycle_msgs.msg import State
    from lifecycle_msgs.srv import GetState

    client = node.create_client(GetState, f"{name}/get_state")
    deadline = time.monotonic() + timeout_s
    try:
        while time.monotonic() < deadline and proc.poll() is None:
            if client.wait_for_service(timeout_sec=0.2):
                future = client.call_async(GetState.Request())
                rclpy.spin_until_future_complete(node, future, timeout_sec=2.0)
                result = future.result() if future.done() else None
                if result is not None and result.current_state.id == State.PRIMARY_STATE_ACTIVE:
                    return
            rclpy.spin_once(node, timeout_sec=0.1)
    finally:
        node.destroy_client(client)
    raise RuntimeError(f"the {name} did not become active within {timeout_s:.0f} s")


def live_robot_nodes(node, namespace: str | None) -> list[str]:
    """Full names of the live sim_bridge / controller / sim_graph nodes in the namespace the replay
    publishes into, and of every node of that kind subscribing to an actuation topic there."""
    ns = "/" + namespace.strip("/") if namespace else "/"
    found = set()
    for name, node_ns in node.get_node_names_and_namespaces():
        if any(name == n or name.startswith(n) for n in LIVE_NODES) and node_ns == ns:
            found.add(f"{node_ns.rstrip('/')}/{name}")
    for topic in ACTUATION:
        for info in node.get_subscriptions_info_by_topic(target_name(topic, namespace)):
            if any(info.node_name.startswith(n) for n in LIVE_NODES):
                found.add(f"{info.node_namespace.rstrip('/')}/{info.node_name}")
    return sorted(found)


def check_safe(node, topics: list[str], namespace: str | None) -> None:
    """Raise Refused when actuation topics would reach a live bridge / controller."""
    driving = [t for t in topics if t.strip("/").split("/")[-1] in ACTUATION or t.strip("/") in ACTUATION]
    if not driving:
        return
    live = live_robot_nodes(node, namespace)
    if live:
        raise Refused(f"refusing to replay {', '.join(sorted(t.strip('/') for t in driving))} into a graph with a live "
                      f"{', '.join(live)}: a replayed command must never drive a live robot; replay under "
                      f"--namespace NS or leave these topics out with --topics")


# --------------------------------------------------------------------------------------- replay
def replay(args) -> int:
    from msgs_py.bag import bag_topics, message_class, read_bag

    bag = pathlib.Path(args.bag)
    info = bag_topics(bag)
    wanted = None
    if args.topics:
        wanted = {_abs(t) for t in args.topics}
        missing = sorted(w for w in wanted if w not in {_abs(t) for t in info})
        if missing:
            print(f"error: not in the bag: {', '.join(missing)} (it has {', '.join(sorted(info))})", file=sys.stderr)
            return 2
    topics = [t for t in info if wanted is None or _abs(t) in wanted]
    messages = read_bag(bag, topics=topics)  # streamed: a long bag is never held in memory
    import rclpy

    from climb_core.ros_env import apply_local_dds_env

    apply_local_dds_env()
    rclpy.init()
    node = rclpy.create_node("replay")
    try:
        _wait_graph(node, args.discovery_s)
        check_safe(node, topics, args.namespace)
        pubs = {}
        for t in topics:
            pubs[t] = node.create_publisher(message_class(info[t].msgtype), target_name(t, args.namespace),
                                            _qos(info[t].qos))
        _wait_graph(node, args.match_s)  # subscribers match the new publishers
        check_safe(node, topics, args.namespace)  # a node discovered late is refused too
        counts = {t: 0 for t in topics}
        lag_max = 0.0
        first = None
        t0 = time.perf_counter()
        for m in messages:
            if first is None:  # the schedule starts with the first message read
                first, t0 = m.stamp_ns, time.perf_counter() + 0.01
            due = t0 + (m.stamp_ns - first) / NS / args.rate
            while True:
                left = due - time.perf_counter()
                if left <= 0:
                    break
                time.sleep(left - 0.001 if left > 0.002 else 0)
            lag_max = max(lag_max, time.perf_counter() - due)
            pubs[m.topic].publish(m.data)
            counts[m.topic] += 1
        duration = time.perf_counter() - t0
        _wait_graph(node, args.linger_s)  # reliable delivery of the last messages
    except Refused as exc:
        print(f"error: {exc}", file=sys.stderr)
        print(json.dumps({"bag": str(bag), "refused": str(exc)}))
        return 3
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    print(json.dumps({"bag": str(bag), "published": sum(counts.values()), "topics": counts,
                      "namespace": args.namespace or "", "rate": args.rate,
                      "duration_s": round(duration, 3), "max_lag_ms": round(lag_max * 1e3, 3)}))
    return 0


# ------------------------------------------------------------------------------------ reexecute
def _executable(package: str, name: str, module: str) -> list[str]:
    exe = pathlib.Path(sys.prefix) / "lib" / package / name
    return [str(exe)] if exe.exists() else [sys.executable, "-m", module]


def _nested(flat: dict) -> dict:
    out: dict = {}
    for key, value in flat.items():
        parts = key.split(".")
        d = out
        for p in parts[:-1]:
            d = d.setdefault(p, {})
        d[parts[-1]] = value
    return out


def _merge(base: dict, over: dict) -> dict:
    """``over`` on top of ``base`` (nested); an integer given for a float parameter becomes a float
    (ROS types parameters strictly: 10 is refused where 10.0 is declared)."""
    out = dict(base)
    for key, value in over.items():
        if isinstance(value, dict) and isinstance(out.get(key), dict):
            out[key] = _merge(out[key], value)
        elif isinstance(out.get(key), float) and isinstance(value, int) and not isinstance(value, bool):
            out[key] = float(value)
        else:
            out[key] = value
    return out


def _param_value(text: str):
    import yaml

    try:
        return yaml.safe_load(text)
    except yaml.YAMLError:
        return text


def start_fixture(robot: str) -> str:
    """The planner library's start fixture of ``robot`` (what the coordinator resets the sim to)."""
    from planner_node.primitives import load_library
    from planner_node.settings import load_settings

    p = load_settings().planning
    return load_library(robot, p.strategy, p.primitives_dir).initial_fixture


def reexecution_setup(request: dict, set_params: list[str]) -> tuple[dict, dict, str]:
    """(bridge parameters, controller parameters, posture) for a fresh bridge + controller that
    start as the recorded ones did (config/nodes files + the request + config/climb.yaml's
    controller overrides, as the coordinator sets them)."""
    from controller_node.params import load_controller_params

    from climb_coordinator.settings import load_climb_settings

    robot = str(request.get("robot") or "g1")
    scenario = str(request.get("scenario") or request.get("ladder") or "default")
    mode = str(request.get("mode") or "qp")
    delay = int(request.get("command_delay_ticks") or 0)
    posture = str(request.get("initial_posture") or "") or start_fixture(robot)
    cs = load_climb_settings()
    # the request may carry the overrides its controller ran with (an empty mapping: none)
    controller = dict(request["controller_overrides"] if isinstance(request.get("controller_overrides"), dict)
                      else cs.controller_overrides)
    if mode == "compliance" and "controller_overrides" not in request:
        controller.update(cs.compliance_overrides)
    controller.update({"mode": mode, "robot": robot, "ladder": scenario, "initial_stance": posture,
                       "autostart": True, "execution": "lockstep"})
    if delay and "actuation_latency_s" not in controller:
        controller["actuation_latency_s"] = delay * load_controller_params().control_period_s
    # lockstep.command_timeout_s: the relay never drops a command, so a timeout could only come
    # from a loaded machine (and would damp a tick the recorded run did not damp): 30 s, longer than
    # the relay's wait for a plan's delivery (--plan-delivery-s); a tick the recorded controller did
    # not answer is damped by this script, not by the timeout
    bridge = {"robot": robot, "ladder": scenario, "initial_posture": posture, "execution": "lockstep",
              "seed": int(request.get("seed") or 0), "lockstep.command_delay_ticks": delay,
              "lockstep.command_timeout_s": 30.0, "lockstep.startup_wait_s": 60.0}
    for item in set_params:
        try:
            target, assignment = item.split(":", 1)
            name, value = assignment.split("=", 1)
        except ValueError:
            raise SystemExit(f"error: --set-param {item!r}: expected NODE:NAME=VALUE") from None
        if target not in ("controller", "sim_bridge"):
            raise SystemExit(f"error: --set-param {item!r}: NODE must be controller or sim_bridge")
        (controller if target == "controller" else bridge)[name.strip()] = _param_value(value.strip())
    return bridge, controller, posture


def reexecute(args) -> int:
    import numpy as np
    import yaml

    from climb_coordinator.report import (compare_base, first_tick_after, load_run, plan_acceptances,
                                          plan_start_stamps, plan_taking_stamps, repeated_acceptances)
    from msgs_py.bag import read_bag

    bag = pathlib.Path(args.bag)
    run = load_run(bag)
    plans = [m.data for m in read_bag(bag) if m.topic.strip("/") == "whole_body_plan"]
    if not plans:
        print(f"error: {bag} has no whole_body_plan to re-execute", file=sys.stderr)
        return 2
    if not len(run.base_t):
        print(f"error: {bag} has no sim/base_truth to compare with", file=sys.stderr)
        return 2
    starts = plan_start_stamps(run)
    if len(starts) != len(plans):
        print(f"error: found the start tick of {len(starts)} of {len(plans)} plans in controller/state", file=sys.stderr)
        return 2
    bridge_p, controller_p, posture = reexecution_setup(run.request, args.set_param or [])
    # the recorded controller's first command of the run (after the last sim reset): a controller
    # activated after the world's first state (the coordinator's sequence) let the bridge damp the
    # ticks before it, for as long as the activation took in wall time: a run no re-execution
    # repeats (reported: recorded_first_command_s > 0 and recorded_controller_lost)
    first_cmd, previous, recorded_first = None, None, {}
    for m in read_bag(bag, topics=["/joint_command", "joint_command"]):
        stamp = int.from_bytes(m.data[4:8], "little", signed=True) * NS + int.from_bytes(m.data[8:12], "little")
        if previous is None or stamp < previous:  # the first command, or the first after a reset
            first_cmd = stamp
            recorded_first = {stamp: m.data}
        previous = stamp
    period_ns = 5_000_000
    end_ns = int(round(run.base_t[-1] * NS))
    if args.max_sim_s is not None:
        end_ns = min(end_ns, int(args.max_sim_s * NS))
    bridge_p["max_ticks"] = end_ns // period_ns + 1
    # the recorded bridge may have damped a few more ticks after the controller's first command
    # (stale on arrival while it retried every lost_retry_s): "controller back at t = X" says when
    # it took one again
    accepted = first_cmd
    for m in read_bag(bag, topics=["/diagnostics", "diagnostics"]):
        text = bytes(m.data)
        if b"back at t = " not in text:
            continue
        try:
            for status in m.decode().status:
                if status.name.endswith("/controller") and "back at t = " in status.message:
                    accepted = int(round(float(status.message.split("back at t = ")[1].split()[0]) * NS))
                    break
        except Exception:  # noqa: BLE001 - unreadable: keep the first command
            pass
        break
    # late only when the recorded bridge said it damped ("controller lost"): a first recorded
    # command after t = 0 alone may be the recorder's subscription matching after the controller's
    # first commands (measured in a long test session: 45 commands missed, none damped)
    damped_before = any(b"controller lost" in bytes(m.data) for m in read_bag(bag, topics=["/diagnostics", "diagnostics"]))
    late = bool(args.damp_unanswered and first_cmd is not None and first_cmd > 0 and damped_before)
    if accepted is None or not late or accepted < first_cmd:
        accepted = first_cmd
    if late:  # the controller starts at the same tick as the recorded one; the ticks before are damped
        controller_p["autostart"] = False
    ns = args.reexecute_namespace or f"reexecute_{os.getpid()}"
    tmp = tempfile.TemporaryDirectory(prefix="reexecute_")
    params = pathlib.Path(tmp.name)
    # a params file keyed by the bare node name does not reach a namespaced node: the config file's
    # parameters and the overrides go under /**/<node>
    for node_name, flat, out in (("sim_bridge", bridge_p, "bridge.yaml"), ("controller", controller_p, "controller.yaml")):
        merged = _merge(yaml.safe_load((ROOT / "config" / "nodes" / f"{node_name}.yaml").read_text())
                        [node_name]["ros__parameters"], _nested(flat))
        (params / out).write_text(yaml.safe_dump({f"/**/{node_name}": {"ros__parameters": merged}}))
    remap = ["-r", f"__ns:=/{ns}", "-r", f"/clock:=/{ns}/clock"]
    bridge_cmd = _executable("sim_bridge", "sim_bridge", "sim_bridge.node") + [
        "--ros-args", "--params-file", str(params / "bridge.yaml"), *remap]
    controller_cmd = _executable("controller_node", "controller", "controller_node.node") + [
        "--ros-args", "--params-file", str(params / "controller.yaml"), *remap, "-r", "joint_command:=joint_command_gate",
        "-r", "gripper_command:=gripper_command_gate"]
    print(f"re-executing {len(plans)} plan(s) of {bag} ({controller_p['robot']}, {controller_p['mode']} mode, "
          f"start posture {posture}) to t = {end_ns / NS:.3f} s in /{ns}; plans taken at t = "
          f"{', '.join(f'{s / NS:.3f}' for s in starts)} s", flush=True)

    import rclpy
    from climb_msgs.msg import ControllerState, GripperCommand, JointCommand, WholeBodyPlan
    from sensor_msgs.msg import JointState
    from nav_msgs.msg import Odometry
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

    from rclpy.serialization import deserialize_message

    from climb_core.ros_env import apply_local_dds_env, local_dds_env

    apply_local_dds_env()
    rclpy.init()
    node = rclpy.create_node("reexecute", namespace=f"/{ns}")
    deep = QoSProfile(depth=2000, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.VOLATILE)
    pubs: dict = {}  # "cmd": created once the controller's gated commands reach this node (below)
    plan_pub = node.create_publisher(WholeBodyPlan, "whole_body_plan", QoSProfile(depth=1))
    base_t: list[float] = []
    base_p: list[tuple] = []
    fsm: list[tuple[int, str]] = []
    taken: list[int] = []  # the new controller's plans_taken, per state (as fsm)
    gated: list[int] = []
    grippers: list[tuple[int, bytes]] = []  # the new controller's gripper requests not yet relayed
    commands: dict[int, bytes] = {}  # the new controller's joint_command per stamp
    states: dict[int, bytes] = {}  # the new bridge's joint_states per stamp
    state = {"next_plan": 0, "relayed": 0, "done": False, "last_state": -1, "damped": 0, "matched": False,
             "plans_accepted": 0}
    pending: list[tuple[int, bytes]] = []  # the controller's commands not yet relayed
    gate = {"until": 0.0, "plan": 0}  # [s, monotonic] no command relayed before this; plan awaited
    delay = int(bridge_p.get("lockstep.command_delay_ticks", 0) or 0)

    def _stamp_of(data: bytes) -> int:
        import struct

        sec, nsec = struct.unpack_from("<iI", data, 4)  # header.stamp after the CDR encapsulation
        return sec * NS + nsec

    def on_gripper(data: bytes) -> None:
        grippers.append((_stamp_of(data), bytes(data)))

    def on_command(data: bytes) -> None:
        stamp = _stamp_of(data)
        commands[stamp] = bytes(data)
        pending.append((stamp, bytes(data)))
        relay()

    def relay() -> None:
        """Pass the controller's commands on to the bridge, in order, with two stops.
        - Plans: the command of the tick before the one at which the recorded controller took plan
          i (two ticks before with a one-period command delay: the bridge then publishes a state
          before it needs the previous command) waits until plan i has reached the controller.
        - Grippers: a request stamped t acts from the bridge's next step after it arrives. The
          recorded controller's one, published after its joint command, reached the bridge once
          the step of t had begun (delay 1: once the step of t + T had begun... after the command
          of t, which that step uses), so it acted from t + T. Relayed here while the bridge waits
          for the command of that step (t + T, delay 1: t), which follows a moment later, it acts
          from t + T too, on every run. With a delay the command of t waits for the controller's
          state of t, published after its grippers."""
        now = time.monotonic()
        if gate["plan"] and state["plans_accepted"] >= gate["plan"]:
            gate["until"], gate["plan"] = now, 0  # the controller took the plan: go on at once
        while pending and now >= gate["until"]:
            stamp, data = pending[0]
            if not state["matched"]:  # the first command waits until the new bridge's command
                # subscription and base truth publisher (the comparison's data) are matched here
                if (pubs["cmd"].get_subscription_count() < 1 or pubs["gripper"].get_subscription_count() < 1
                        or subs["base"].get_publisher_count() < 1):
                    return
                state["matched"] = True
                gate["until"] = now + 0.3
                return
            if delay and state["last_state"] < stamp:
                return  # delay 1: the grippers of this tick may still come
            due = [g for g in grippers if g[0] + (1 - delay) * period_ns <= stamp]
            if due:
                for g in due:
                    pubs["gripper"].publish(g[1])
                    grippers.remove(g)
                gate["until"] = now + args.gripper_delay_s
                return
            i = state["next_plan"]
            if i < len(plans) and stamp + (1 + delay) * period_ns >= starts[i]:
                plan_pub.publish(plans[i])
                state["next_plan"] = i + 1
                gated.append(stamp + (1 + delay) * period_ns)  # the tick at which the controller takes it
                # until the controller says it accepted it (its controller/plan diagnostic), at most
                # plan_delivery_s (the bridge waits lockstep.command_timeout_s = 30 s)
                gate["until"], gate["plan"] = now + args.plan_delivery_s, i + 1
                return
            if late and stamp < accepted:  # the recorded bridge ignored it and damped this tick
                pubs["cmd"].publish(damping(stamp))
                state["damped"] += 1
            else:
                pubs["cmd"].publish(data)
            pending.pop(0)
            state["relayed"] += 1

    def on_base(msg: Odometry) -> None:
        p = msg.pose.pose.position
        t = msg.header.stamp.sec * NS + msg.header.stamp.nanosec
        base_t.append(t / NS)
        base_p.append((p.x, p.y, p.z))
        if t >= end_ns:
            state["done"] = True

    def on_state(msg: ControllerState) -> None:
        stamp = msg.header.stamp.sec * NS + msg.header.stamp.nanosec
        fsm.append((stamp, msg.fsm_state))
        taken.append(int(msg.plans_taken))
        state["last_state"] = max(state["last_state"], stamp)
        if delay:
            relay()

    subs = {"gate": node.create_subscription(JointCommand, "joint_command_gate", on_command, deep, raw=True),
            "gripper": node.create_subscription(GripperCommand, "gripper_command_gate", on_gripper, deep, raw=True)}
    damp = {"queue": [], "names": [], "future": None, "active": not late}

    def damping(stamp: int):
        msg = JointCommand(names=damp["names"], modes=bytes([JointCommand.DAMPING] * len(damp["names"])),
                           values=[0.0] * len(damp["names"]))
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp, NS)
        return msg

    def on_joint_states(data: bytes) -> None:
        stamp = _stamp_of(data)
        states[stamp] = bytes(data)
        if late and stamp < first_cmd:
            damp["queue"].append(stamp)  # answered with DAMPING in the main loop (below)

    node.create_subscription(JointState, "joint_states", on_joint_states, deep, raw=True)

    new_lost: list[str] = []
    accepted_after: list = []  # per plan the new controller accepted: its last tick before it [ns]
    periodic_after: list = []  # the same, as the new controller's last periodic diagnostic lists them

    def on_diagnostics(msg) -> None:
        accepted = plan_acceptances(msg)
        state["plans_accepted"] += len(accepted)
        accepted_after.extend(accepted)
        repeated = repeated_acceptances(msg)  # the periodic one repeats every acceptance
        if repeated is not None:
            periodic_after[:] = repeated
        for status in msg.status:
            if status.name.endswith("sim_bridge/controller") or status.name.endswith("sim_bridge/command"):
                new_lost.append(f"{msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9:.3f}: {status.message}")

    from diagnostic_msgs.msg import DiagnosticArray

    subs["diagnostics"] = node.create_subscription(DiagnosticArray, "diagnostics", on_diagnostics, deep)

    subs["base"] = node.create_subscription(Odometry, "sim/base_truth", on_base, deep)
    node.create_subscription(ControllerState, "controller/state", on_state, deep)
    env = local_dds_env()
    procs = {}
    logs = {name: open(params / f"{name}.log", "w+") for name in ("controller", "sim_bridge")}
    failure = ""
    t_start = time.monotonic()
    try:
        procs["controller"] = subprocess.Popen(controller_cmd, env=env, cwd=ROOT, stdout=logs["controller"],
                                               stderr=subprocess.STDOUT, start_new_session=True)
        if late:
            from lifecycle_msgs.msg import Transition
            from lifecycle_msgs.srv import ChangeState

            lifecycle = node.create_client(ChangeState, "controller/change_state")
            if not lifecycle.wait_for_service(timeout_sec=60.0):
                raise RuntimeError("the controller's lifecycle service did not come up")
            future = lifecycle.call_async(ChangeState.Request(transition=Transition(id=Transition.TRANSITION_CONFIGURE)))
            rclpy.spin_until_future_complete(node, future, timeout_sec=60.0)
            if not (future.done() and future.result() is not None and future.result().success):
                raise RuntimeError("the controller refused to configure")
            first = deserialize_message(next(iter(sorted(recorded_first.items())))[1], JointCommand)
            damp["names"] = list(first.names)
        # the bridge starts ticking once it sees a joint_command publisher (this node's): create it
        # only when the controller's gated commands and its plan subscription are matched here,
        # so that no command of the first ticks is lost (the bridge would damp those ticks)
        deadline = time.monotonic() + 60.0
        while (subs["gate"].get_publisher_count() < 1 or subs["gripper"].get_publisher_count() < 1
               or plan_pub.get_subscription_count() < 1):  # matched, not only discovered
            rclpy.spin_once(node, timeout_sec=0.05)
            if procs["controller"].poll() is not None or time.monotonic() > deadline:
                raise RuntimeError("the controller did not come up")
        if not late:  # autostart: the controller must be active before the bridge's first state,
            # or it drops that state (an inactive lifecycle node ignores it) and the bridge damps t = 0
            wait_until_active(node, "controller", procs["controller"], 60.0)
        # the controller's two diagnostics writers (its acceptances; its periodic report) matched
        # here, so that no plan's acceptance is missed (a soft wait: the run goes on without them)
        deadline = time.monotonic() + 10.0
        while subs["diagnostics"].get_publisher_count() < 2 and time.monotonic() < deadline:
            rclpy.spin_once(node, timeout_sec=0.05)
        _wait_graph(node, 0.5)
        if starts and first_cmd is not None and starts[0] <= first_cmd:
            # the recorded controller took its first plan on its first tick (the coordinator
            # activates it once the plan exists): the new one gets it before its first state
            plan_pub.publish(plans[0])
            state["next_plan"] = 1
            gated.append(starts[0])
            deadline = time.monotonic() + 30.0
            while state["plans_accepted"] < 1:
                rclpy.spin_once(node, timeout_sec=0.05)
                if procs["controller"].poll() is not None or time.monotonic() > deadline:
                    raise RuntimeError("the controller did not take the first plan")
        pubs["gripper"] = node.create_publisher(GripperCommand, "gripper_command", QoSProfile(depth=10))
        pubs["cmd"] = node.create_publisher(JointCommand, "joint_command", QoSProfile(depth=10))
        procs["sim_bridge"] = subprocess.Popen(bridge_cmd, env=env, cwd=ROOT, stdout=logs["sim_bridge"],
                                               stderr=subprocess.STDOUT, start_new_session=True)
        deadline = time.monotonic() + args.timeout
        while not state["done"]:
            rclpy.spin_once(node, timeout_sec=0.005)
            if pending:
                relay()
            while damp["queue"] and pubs["cmd"].get_subscription_count() > 0:  # ticks the recorded
                # controller did not answer: damped (once the bridge hears this node)
                pubs["cmd"].publish(damping(damp["queue"].pop(0)))
                state["damped"] += 1
            if late and damp["future"] is None and states and max(states) >= first_cmd:
                # the state the recorded controller answered first is out, the bridge waits for its
                # command: activate the new controller now; it ticks on that state (as the recorded
                # one did, activated while the bridge damped the ticks before)
                damp["future"] = lifecycle.call_async(ChangeState.Request(
                    transition=Transition(id=Transition.TRANSITION_ACTIVATE)))
            dead = [n for n, p in procs.items() if p.poll() is not None]
            if dead and not state["done"]:
                # the bridge ends by itself at max_ticks: drain what it published last
                end = time.monotonic() + 1.0
                while time.monotonic() < end and not state["done"]:
                    rclpy.spin_once(node, timeout_sec=0.01)
                if not state["done"]:
                    failure = f"{', '.join(dead)} exited early (code {procs[dead[0]].returncode})"
                break
            if time.monotonic() > deadline:
                failure = f"timeout after {args.timeout:.0f} s at t = {base_t[-1] if base_t else 0.0:.3f} s"
                break
    except RuntimeError as exc:
        failure = str(exc)
    finally:
        for proc in procs.values():
            if proc.poll() is None:
                proc.send_signal(signal.SIGINT)
        for proc in procs.values():
            try:
                proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait()
        node.destroy_node()
        rclpy.try_shutdown()
    wall = time.monotonic() - t_start
    tails = {}
    for name, f in logs.items():
        f.seek(0)
        text = f.read()
        tails[name] = text[-2000:]
        f.close()
        if args.keep_logs:
            pathlib.Path(args.keep_logs).mkdir(parents=True, exist_ok=True)
            (pathlib.Path(args.keep_logs) / f"{name}.log").write_text(text)
    tmp.cleanup()
    # the tick at which the new controller took each plan: the first after the tick it accepted it
    # after (its acceptance diagnostic, or the periodic diagnostics' copy of it), as the recorded
    # starts are found; when that is not known for every plan, both runs' starts by the FSM's
    # first change (from the gated tick here), so that the two are found by the same rule
    # first the new controller's own count of the plans it took (on every state: not missed)
    new_starts = plan_taking_stamps([s for s, _ in fsm], taken, len(gated))
    afters = [accepted_after[k] if k < len(accepted_after) and accepted_after[k] is not None
              else (periodic_after[k] if k < len(periodic_after) else None) for k in range(len(gated))]
    stamps_fsm = sorted(s for s, _ in fsm)
    if new_starts is None:
        new_starts = [first_tick_after(stamps_fsm, a) for a in afters if a is not None]
    if len(new_starts) != len(gated) or None in new_starts:
        starts = plan_start_stamps(run, from_acceptance=False)
        new_starts = []
        for g in gated:
            change = next((fsm[k][0] for k in range(len(fsm)) if fsm[k][0] >= g and (
                k == 0 or fsm[k][1] != fsm[k - 1][1] or fsm[k][0] < fsm[k - 1][0])), None)
            if change is not None:
                new_starts.append(change)
    import struct

    recorded_cmds, recorded_states, lost = {}, {}, []
    for m in read_bag(bag):
        topic = m.topic.strip("/")
        if topic in ("joint_command", "joint_states") and len(m.data) >= 12:
            sec, nsec = struct.unpack_from("<iI", m.data, 4)
            (recorded_cmds if topic == "joint_command" else recorded_states)[sec * NS + nsec] = m.data
        elif topic == "diagnostics":  # the recorded bridge's damped ticks (controller lost / back)
            try:
                for status in m.decode().status:
                    if status.name.endswith("/controller") and "lost" in status.message:
                        lost.append(status.message)
            except Exception:  # noqa: BLE001 - a diagnostic we cannot read is no evidence
                pass
    common = sorted(set(recorded_cmds) & set(commands))
    from rclpy.serialization import deserialize_message

    def values(data: bytes):
        m = deserialize_message(data, JointCommand)
        return list(m.names), bytes(m.modes), np.asarray(m.values, float)

    if os.environ.get("REPLAY_DUMP"):  # debugging aid: both runs' commands
        import pickle

        with open(os.environ["REPLAY_DUMP"], "wb") as f:
            pickle.dump((recorded_cmds, commands, recorded_states, states), f)
    differ = []  # compared decoded: CDR padding bytes are not part of the message
    for t in common:
        a, b = values(recorded_cmds[t]), values(commands[t])
        if a[0] != b[0] or a[1] != b[1] or not np.array_equal(a[2], b[2]):
            differ.append(t)
    state_differ = []
    for t in sorted(set(recorded_states) & set(states)):
        a = deserialize_message(recorded_states[t], JointState)
        b = deserialize_message(states[t], JointState)
        if not (np.array_equal(np.asarray(a.position), np.asarray(b.position))
                and np.array_equal(np.asarray(a.velocity), np.asarray(b.velocity))):
            state_differ.append(t)
    cmp = compare_base(run.base_t, run.base_pose[:, :3], np.asarray(base_t), np.asarray(base_p).reshape(-1, 3))
    result = {"reexecute": True, "bag": str(bag), "plans": len(plans), "compared": cmp["compared"],
              "max_mm": cmp["max_mm"], "rms_mm": cmp["rms_mm"], "max_at_s": cmp["at_s"],
              "from_s": cmp.get("from_s"), "to_s": cmp.get("to_s"),
              "within_mm": args.tolerance_mm,
              "reproduced": bool(cmp["max_mm"] is not None and cmp["max_mm"] <= args.tolerance_mm and not failure),
              "plan_start_s": {"recorded": [s / NS for s in starts], "reexecuted": [s / NS for s in new_starts]},
              "final_fsm": {"recorded": run.fsm[-1] if run.fsm else "", "reexecuted": fsm[-1][1] if fsm else ""},
              "commands_compared": len(common), "commands_differing": len(differ),
              "first_command_difference_s": differ[0] / NS if differ else None,
              "first_state_difference_s": state_differ[0] / NS if state_differ else None,
              "recorded_controller_lost": lost[:5], "reexecuted_bridge_reports": new_lost[:5],
              "recorded_first_command_s": first_cmd / NS if first_cmd is not None else None,
              "damped_ticks": state["damped"], "recorded_first_accepted_s": accepted / NS if accepted is not None else None,
              "set_param": args.set_param or [], "wall_s": round(wall, 2), "failure": failure}
    if cmp["compared"]:
        print(f"base position deviation over {cmp['compared']} ticks ({cmp['from_s']} .. {cmp['to_s']} s): "
              f"max {cmp['max_mm']:.4f} mm at t = {cmp['at_s']} s, RMS {cmp['rms_mm']:.4f} mm")
    if failure:
        print(f"error: re-execution failed: {failure}", file=sys.stderr)
        for name, tail in tails.items():
            print(f"--- {name} (last lines)\n{tail}", file=sys.stderr)
    print(json.dumps(result))
    return 4 if failure else 0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("bag", help="rosbag2 bag directory")
    ap.add_argument("--rate", type=float, default=1.0, help="playback speed factor (2: twice as fast)")
    ap.add_argument("--topics", nargs="+", default=None, help="replay only these topics")
    ap.add_argument("--namespace", default=None, help="replay every topic under /NS")
    ap.add_argument("--discovery-s", type=float, default=2.0, help="[s] graph discovery before the safety check")
    ap.add_argument("--match-s", type=float, default=1.0, help="[s] wait for subscribers to match before publishing")
    ap.add_argument("--linger-s", type=float, default=0.5, help="[s] keep the publishers after the last message")
    ap.add_argument("--reexecute", action="store_true", help="re-execute the recorded plan on a fresh bridge + controller")
    ap.add_argument("--set-param", action="append", metavar="NODE:NAME=VALUE",
                    help="re-execution: a controller (or sim_bridge) parameter changed from the recorded run")
    ap.add_argument("--tolerance-mm", type=float, default=1.0, help="[mm] re-execution: 'reproduced' when max <= this")
    ap.add_argument("--max-sim-s", type=float, default=None, help="[s] re-execution: stop at this sim time")
    ap.add_argument("--timeout", type=float, default=600.0, help="[s] re-execution: wall-time bound")
    ap.add_argument("--plan-delivery-s", type=float, default=20.0,
                    help="[s] re-execution: the lock-step waits for the controller to accept a plan, at most this long")
    ap.add_argument("--gripper-delay-s", type=float, default=0.02,
                    help="[s] re-execution: a gripper request reaches the bridge this long before the next command")
    ap.add_argument("--damp-unanswered", action=argparse.BooleanOptionalAction, default=True,
                    help="re-execution: damp the ticks before the recorded controller's first command, as the "
                         "recorded bridge did (default: on)")
    ap.add_argument("--keep-logs", default=None, metavar="DIR", help="re-execution: keep the nodes' logs in DIR")
    ap.add_argument("--reexecute-namespace", default=None, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if not args.rate > 0:
        print("error: --rate must be > 0", file=sys.stderr)
        return 2
    bag = pathlib.Path(args.bag)
    if not (bag / "metadata.yaml").is_file() and not list(bag.glob("*.mcap")):
        print(f"error: {bag} is not a rosbag2 bag directory", file=sys.stderr)
        return 2
    from climb_core.errors import ClimbError

    try:
        return reexecute(args) if args.reexecute else replay(args)
    except ClimbError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())
