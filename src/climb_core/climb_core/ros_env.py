"""Keep DDS on this machine, and the process-level settings of an executable (signals, CPUs).

Every process the project starts calls :func:`apply_local_dds_env` before ``rclpy.init()`` (or
passes :func:`local_dds_env` to a child process). The user can still override the variables on
purpose; nothing here imports rclpy (the ROS-side helpers are in msgs_py.node_kit).

What keeps every socket on 127.0.0.1 (measured from /proc/<pid>/net/{udp,udp6,tcp,tcp6}, a bare
rclpy node included; docs/interfaces.md): the project's Fast DDS profile
(config/fastdds_localhost.xml: loopback UDP + shared memory, unicast discovery on 127.0.0.1, no
multicast) applied as is, i.e. with ``ROS_AUTOMATIC_DISCOVERY_RANGE=SYSTEM_DEFAULT``. With
``LOCALHOST`` rmw_fastrtps adds a UDP sender on 0.0.0.0 and one on the eth0 address, so while the
project's profile is in force LOCALHOST (or no range) becomes SYSTEM_DEFAULT here, whatever the
caller's shell exported. A user who wants another profile sets FASTRTPS_DEFAULT_PROFILES_FILE (an
empty value: none) and then chooses the range.
"""
from __future__ import annotations

import os
import pathlib
import signal
import threading
from typing import Mapping, MutableMapping

#: Default private domain id; tests add a per-session offset.
DEFAULT_DOMAIN_ID = 42


def project_root() -> pathlib.Path:
    """The repository root (the folder holding config/)."""
    here = pathlib.Path(__file__).resolve()
    for parent in here.parents:
        if (parent / "config" / "fastdds_localhost.xml").is_file():
            return parent
    env_root = os.environ.get("CLIMB_ROOT")
    if env_root:
        return pathlib.Path(env_root)
    raise FileNotFoundError("cannot find the project's config/ folder; set CLIMB_ROOT")


def fastdds_profile_path() -> pathlib.Path:
    return project_root() / "config" / "fastdds_localhost.xml"


#: discovery ranges replaced by SYSTEM_DEFAULT while the project's profile is in force
_RANGES_OVERRIDDEN = ("", "LOCALHOST")


def uses_project_profile(env: Mapping[str, str]) -> bool:
    """The Fast DDS profile in force in ``env`` is config/fastdds_localhost.xml."""
    path = env.get("FASTRTPS_DEFAULT_PROFILES_FILE", "")
    if not path:
        return False
    try:
        return pathlib.Path(path).resolve() == fastdds_profile_path().resolve()
    except (OSError, FileNotFoundError):
        return False


def local_dds_env(base: Mapping[str, str] | None = None, domain_id: int | None = None) -> dict[str, str]:
    """Return a copy of ``base`` (default: os.environ) with the loopback DDS settings filled in.

    Values already present in ``base`` win, except ``domain_id`` when given explicitly and the
    discovery range: LOCALHOST (or none) becomes SYSTEM_DEFAULT while the project's loopback
    profile is in force (LOCALHOST opens sockets on 0.0.0.0 and eth0 next to the profile's).
    """
    env = dict(os.environ if base is None else base)
    env.setdefault("FASTRTPS_DEFAULT_PROFILES_FILE", str(fastdds_profile_path()))
    if uses_project_profile(env) and env.get("ROS_AUTOMATIC_DISCOVERY_RANGE", "").upper() in _RANGES_OVERRIDDEN:
        env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "SYSTEM_DEFAULT"
    env.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")  # another profile: rmw's loopback range
    env.setdefault("RMW_IMPLEMENTATION", "rmw_fastrtps_cpp")
    if domain_id is not None:
        env["ROS_DOMAIN_ID"] = str(domain_id)
    else:
        env.setdefault("ROS_DOMAIN_ID", str(DEFAULT_DOMAIN_ID))
    # A child venv Python must re-run the ROS wheels' bootstrap itself (FIELD_NOTES).
    env.pop("_ROS_WHEELS_BOOTSTRAP_COMPLETE", None)
    return env


def apply_local_dds_env(environ: MutableMapping[str, str] | None = None, domain_id: int | None = None) -> None:
    """Set the loopback DDS variables in this process (call before rclpy.init())."""
    target = os.environ if environ is None else environ
    for key, value in local_dds_env(target, domain_id).items():
        if key == "_ROS_WHEELS_BOOTSTRAP_COMPLETE":
            continue
        if target.get(key) != value:
            target[key] = value


#: Set by SIGINT / SIGTERM once :func:`install_signal_handlers` ran (msgs_py.node_kit reads it).
STOP = threading.Event()


def _on_signal(signum, frame) -> None:  # noqa: ARG001 - signal handler signature
    STOP.set()


def install_signal_handlers() -> bool:
    """SIGINT and SIGTERM only set :data:`STOP` (no KeyboardInterrupt, no default death): the
    node's loop ends at its next turn and the process exits 0 (msgs_py.node_kit.run_node). This
    module is light on purpose: an executable calls it first thing in ``main()``, before its
    heavy imports (rclpy, numpy, pinocchio, pybullet take seconds on a loaded machine), so that
    a signal during the imports is handled too. Main thread only; False elsewhere."""
    if threading.current_thread() is not threading.main_thread():
        return False
    signal.signal(signal.SIGINT, _on_signal)
    signal.signal(signal.SIGTERM, _on_signal)
    return True


def pin_to_cpus(cpus, logger=None) -> set[int] | None:
    """Pin every thread of this process (DDS threads included) to the CPUs ``cpus`` (a node's
    ``cpu_affinity`` parameter; empty: leave the inherited set). Returns the new CPU set, or None
    when nothing was pinned; a CPU this machine lacks is reported on ``logger`` (info / warning),
    not raised."""
    import os

    if not cpus:
        return None
    try:
        wanted = {int(c) for c in cpus}
        for tid in os.listdir("/proc/self/task"):
            try:
                os.sched_setaffinity(int(tid), wanted)
            except ProcessLookupError:  # a thread that just ended
                pass
        now = os.sched_getaffinity(0)
    except (OSError, ValueError) as err:
        if logger is not None:
            logger.warning(f"cpu_affinity {list(cpus)} refused: {err}")
        return None
    if logger is not None:
        logger.info(f"pinned to CPUs {sorted(now)}")
    return now


def apply_cpu_affinity(node) -> set[int] | None:
    """Moved to msgs_py.node_kit.apply_cpu_affinity (it reads a node parameter: ROS side)."""
    from msgs_py import node_kit

    return node_kit.apply_cpu_affinity(node)


def make_executor():
    """Moved to msgs_py.node_kit.make_executor (ROS side; climb_core never imports rclpy)."""
    from msgs_py import node_kit

    return node_kit.make_executor()
