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
"""
from __future__ import annotations

import sys
import time

import rclpy
from rclpy.executors import ExternalShutdownException

from climb_core.errors import ClimbError
from climb_core.ros_env import apply_local_dds_env


def main(args: list[str] | None = None) -> int:
    from controller_node.node import ControllerNode, apply_nice
    from climb_core.ros_env import make_executor
    from sim_bridge.node import SimBridgeNode

    apply_local_dds_env()
    rclpy.init(args=args)
    bridge = controller = None
    code = 0
    try:
        bridge = SimBridgeNode()
        controller = ControllerNode()
        apply_nice(controller)
        if controller.get_parameter("autostart").value:
            controller.trigger_configure()
            controller.trigger_activate()
        executor = make_executor()
        executor.add_node(bridge)
        executor.add_node(controller)
        if bridge.params.execution == "lockstep":
            bridge.run_lockstep(executor)
        else:
            bridge.run_realtime(executor)
        # max_ticks reached: the controller still answers the last state (as a separate
        # controller process would) before the graph goes down
        deadline = time.monotonic() + 0.2
        while rclpy.ok() and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.02)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except (ClimbError, ValueError) as err:
        print(f"sim_graph: {err}", file=sys.stderr)
        code = 2
    finally:
        if bridge is not None:
            bridge.destroy_node()
        if controller is not None:
            controller.destroy_node()
        rclpy.try_shutdown()
    return code


if __name__ == "__main__":
    sys.exit(main())
