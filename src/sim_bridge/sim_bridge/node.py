"""The `sim_bridge` executable (``ros2 run sim_bridge sim_bridge``; ``python -m sim_bridge.node``).

This module is light on purpose: ``main()`` installs the SIGINT / SIGTERM handlers before the
heavy imports (rclpy, PyBullet, Pinocchio take seconds on a loaded machine), so that a signal at
any moment ends the process with exit code 0 and no traceback (msgs_py.node_kit.run_node). The
node itself is sim_bridge.ros_node.SimBridgeNode (also importable from here, lazily).
"""
from __future__ import annotations

import sys

_LAZY = ("SimBridgeNode", "LIVE_PARAMS", "qos", "to_time", "to_ns")


def main(args: list[str] | None = None) -> int:
    from climb_core.ros_env import install_signal_handlers

    install_signal_handlers()
    from sim_bridge.ros_node import run

    return run(args)


def __getattr__(name: str):
    if name in _LAZY:
        from sim_bridge import ros_node

        return getattr(ros_node, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


if __name__ == "__main__":
    sys.exit(main())
