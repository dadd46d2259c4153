"""Test session setup: keep DDS on loopback with a private domain, before anything imports rclpy."""
from __future__ import annotations

import os
import pathlib
import sys

ROOT = pathlib.Path(__file__).resolve().parents[1]


def _private_domain() -> int:
    """A private ROS domain in 1..100 per test process: the runner's pid spreads concurrent runs;
    under pytest-xdist the workers of one run (same parent) get distinct domains, so that their
    graphs never see each other."""
    worker = os.environ.get("PYTEST_XDIST_WORKER", "")
    if not worker.startswith("gw"):
        return 1 + os.getpid() % 100
    n = max(1, int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1")))
    return 1 + (os.getppid() % max(1, 100 // n)) * n + int(worker[2:]) % n


if "ROS_DOMAIN_ID" not in os.environ or os.environ.get("CLIMB_TEST_PRIVATE_DOMAIN", "1") == "1":
    os.environ["ROS_DOMAIN_ID"] = str(_private_domain())
# The project's loopback profile applied as is: with it, SYSTEM_DEFAULT binds every socket to
# 127.0.0.1, while LOCALHOST would add senders on 0.0.0.0 and eth0 (measured, climb_core.ros_env).
os.environ["FASTRTPS_DEFAULT_PROFILES_FILE"] = str(ROOT / "config" / "fastdds_localhost.xml")
os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "SYSTEM_DEFAULT"
os.environ.setdefault("RMW_IMPLEMENTATION", "rmw_fastrtps_cpp")
os.environ.setdefault("CLIMB_ROOT", str(ROOT))

if str(ROOT / "tests") not in sys.path:
    sys.path.insert(0, str(ROOT / "tests"))


# -- shared canonical scenario objects (cached models: load once per session) -------------------
import pytest  # noqa: E402


def pytest_collection_modifyitems(config, items):
    """The executed climbs (marker ``heavy``, minutes each) first, in their order: with make
    test's two pytest-xdist workers (--dist load) they start at once on both cores and the short
    tests fill in around them, instead of two of them ending the run on one core."""
    items.sort(key=lambda item: 0 if item.get_closest_marker("heavy") else 1)


@pytest.fixture(scope="session")
def g1():
    """The default robot (Unitree G1 + Dex3 hands), loaded once."""
    from climb_core.robot import load_robot

    return load_robot("g1")


@pytest.fixture(scope="session")
def env():
    """The default ladder's environment (config/ladders/default.yaml)."""
    from climb_core.environment import build_environment
    from climb_core.ladder import load_scenario

    return build_environment(load_scenario("default"))
