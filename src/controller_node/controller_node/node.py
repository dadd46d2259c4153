"""The `controller` executable (``ros2 run controller_node controller``; ``python -m controller_node.node``).

Light on purpose: ``main()`` installs the SIGINT / SIGTERM handlers before the heavy imports
(rclpy, numpy, Pinocchio take seconds on a loaded machine), so that a signal at any moment, the
imports included, ends the process with exit code 0 and no traceback (msgs_py.node_kit.run_node).
The node is controller_node.ros_node.ControllerNode (importable from here too, lazily).
"""
from __future__ import annotations

import sys

_LAZY = ("ControllerNode", "StateDecoder", "apply_nice", "build_node", "default_params", "READ_ONLY")


def main(args: list[str] | None = None) -> int:
    from climb_core.ros_env import install_signal_handlers

    install_signal_handlers()
    from controller_node.ros_node import run

    return run(args)


def __getattr__(name: str):
    if name in _LAZY:
        from controller_node import ros_node

        return getattr(ros_node, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


if __name__ == "__main__":
    sys.exit(main())
