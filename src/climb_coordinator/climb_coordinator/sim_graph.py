"""The `sim_graph` executable: the `sim_bridge` and `controller` nodes composed in one process.

The same two nodes as the `sim_bridge` and `controller` executables (same parameters, topics,
services and lifecycle), added to one rclpy EventsExecutor: every message still goes through DDS,
but the lock-step loop never hands over between two processes. The bridge's loop drives the
executor, so the controller's callbacks run on the bridge's thread as soon as the state is in.
This is ROS 2 composition done by hand (rclpy has no component container).

    sim_graph --ros-args --params-file config/nodes/sim_bridge.yaml \\
              --params-file config/nodes/controller.yaml -p initial_posture:=ladder_4_contacts \\
              -p initial_stance:=ladder_4_contacts

Parameters given with ``-p`` reach both nodes (each keeps the ones it declares). Why: each
process of a two-process lock-step idles while the other works, and its next tick starts with
cold caches (the controller's tick costs ~3x, the bridge's physics ~1.5x); on the 2-core
development machine, over 10,000 ticks, two pinned processes run at 0.76-0.89x real time, composed
0.88-1.08x, and the controller's state -> command p99 drops from 2.3-2.9 to 1.8-1.9 ms
(docs/benchmarks.md, ``scripts/bench_controller.py --ros-only --ros-composed --ros-repeat 3``).

Run by msgs_py.node_kit.run_node, the signal handlers installed before the heavy imports: SIGINT /
SIGTERM at any moment (imports and mid-tick included) end the loop at its next turn, then both
nodes are destroyed in the main thread: exit 0, no traceback.
"""
from __future__ import annotations

import sys
import time

#: [s] wall time the controller gets to answer the last state once max_ticks is reached
FINAL_SPIN_S = 0.2


class StopAwareExecutor:
    """The executor, whose ``spin_once`` ends the bridge's own loop once a signal came (raises
    KeyboardInterrupt, which run_node takes as a normal stop): the loop then returns at its next
    turn whatever it checks itself."""

    def __init__(self, executor) -> None:
        self._executor = executor

    def spin_once(self, timeout_sec: float | None = None) -> None:
        from climb_core.ros_env import STOP

        if STOP.is_set():
            raise KeyboardInterrupt
        self._executor.spin_once(timeout_sec=timeout_sec)

    def __getattr__(self, name: str):
        return getattr(self._executor, name)


def build_nodes():
    from controller_node.ros_node import build_node
    from sim_bridge.node import SimBridgeNode

    bridge = SimBridgeNode()
    try:
        controller = build_node()
    except BaseException:
        bridge.destroy_node()
        raise
    return [bridge, controller]


def run_graph(nodes, executor, is_running) -> None:
    bridge, _ = nodes
    ex = StopAwareExecutor(executor)
    if bridge.params.execution == "lockstep":
        bridge.run_lockstep(ex)
    else:
        bridge.run_realtime(ex)
    # max_ticks reached: the controller still answers the last state (as a separate
    # controller process would) before the graph goes down
    deadline = time.monotonic() + FINAL_SPIN_S
    while is_running() and time.monotonic() < deadline:
        executor.spin_once(timeout_sec=0.02)


def main(args: list[str] | None = None) -> int:
    from climb_core.ros_env import install_signal_handlers

    install_signal_handlers()  # first: a signal during the heavy imports below exits 0 too
    from msgs_py.node_kit import run_node

    return run_node(build_nodes, args, name="sim_graph", loop=run_graph)


if __name__ == "__main__":
    sys.exit(main())
