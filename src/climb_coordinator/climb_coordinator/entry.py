"""Light entry points of the `climb_coordinator` and `recorder` executables.

Nothing heavy is imported at the top: each ``main`` installs the SIGINT / SIGTERM handlers first
(climb_core.ros_env), then imports its node module (rclpy, numpy, the planner's models: seconds on
a loaded machine), so that a signal at any moment ends the process with exit code 0 and no
traceback (msgs_py.node_kit.run_node; tests/ros/test_signals.py).
"""
from __future__ import annotations

import sys


def coordinator(args: list[str] | None = None) -> int:
    from climb_core.ros_env import install_signal_handlers

    install_signal_handlers()
    from climb_coordinator.coordinator_node import main

    return main(args)


def recorder(args: list[str] | None = None) -> int:
    from climb_core.ros_env import install_signal_handlers

    install_signal_handlers()
    from climb_coordinator.recorder_node import main

    return main(args)


if __name__ == "__main__":  # python -m climb_coordinator.entry coordinator|recorder [--ros-args ...]
    which = sys.argv[1] if len(sys.argv) > 1 else ""
    if which not in ("coordinator", "recorder"):
        sys.exit("usage: python -m climb_coordinator.entry coordinator|recorder [--ros-args ...]")
    sys.exit({"coordinator": coordinator, "recorder": recorder}[which](sys.argv[2:]))
