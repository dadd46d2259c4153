"""A spawned node gets the loopback DDS settings, and the graph works on loopback.

The probe (msgs_py.env_probe) is started from an environment with the DDS variables removed and
reports what its rclpy really runs with, including the local addresses of its UDP sockets."""
from __future__ import annotations

import json
import os
import pathlib
import subprocess
import sys
import time
import uuid
import xml.etree.ElementTree as ET

import pytest

from climb_core.params import flatten, load_params, to_yaml
from climb_core.ros_env import DEFAULT_DOMAIN_ID, fastdds_profile_path, local_dds_env
from msgs_py.env_probe import EnvProbeParams

pytestmark = pytest.mark.ros

ROOT = pathlib.Path(__file__).resolve().parents[2]
PROFILE = ROOT / "config" / "fastdds_localhost.xml"
NODE_PARAMS = ROOT / "config" / "nodes" / "env_probe.yaml"
DDS_VARIABLES = ("ROS_AUTOMATIC_DISCOVERY_RANGE", "FASTRTPS_DEFAULT_PROFILES_FILE", "ROS_DOMAIN_ID",
                 "RMW_IMPLEMENTATION")
NS = {"f": "http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles"}
PROCESS_TIMEOUT_S = 60.0  # [s] generous bound on a probe's life on a busy 2-core machine


def stripped_environment() -> dict[str, str]:
    """This process's environment without any DDS setting (what a user's shell may give)."""
    return {k: v for k, v in os.environ.items() if k not in DDS_VARIABLES}


def probe_command(*ros_args: str) -> list[str]:
    return [sys.executable, "-m", "msgs_py.env_probe", "--ros-args", *ros_args]


def parse_report(stdout: str) -> dict:
    lines = [line for line in stdout.splitlines() if line.startswith("{")]
    assert lines, f"probe printed no report: {stdout!r}"
    return json.loads(lines[-1])


def run_probe(env: dict[str, str], *ros_args: str) -> dict:
    child = subprocess.Popen(probe_command(*ros_args), env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                             text=True)
    try:
        out, err = child.communicate(timeout=PROCESS_TIMEOUT_S)
    finally:
        if child.poll() is None:
            child.kill()
            child.wait(timeout=10)
    assert child.returncode == 0, err
    return parse_report(out)


def rtps_listener_sockets(report: dict) -> list[str]:
    """The probe's sockets on the RTPS well-known ports of its domain (7400 + 250 * domain + ...):
    the discovery and user-traffic listeners."""
    base = 7400 + 250 * report["domain_id"]
    return [s for s in report["udp_sockets"] if base <= int(s.rsplit(":", 1)[1]) < base + 250]


def assert_loopback_report(report: dict, domain_id: int) -> None:
    env = report["env"]
    # the profile applied as is: LOCALHOST would add sockets on 0.0.0.0 and eth0 (ros_env)
    assert env["ROS_AUTOMATIC_DISCOVERY_RANGE"] == "SYSTEM_DEFAULT"
    assert pathlib.Path(env["FASTRTPS_DEFAULT_PROFILES_FILE"]).resolve() == PROFILE.resolve()
    assert env["ROS_DOMAIN_ID"] == str(domain_id)
    assert report["domain_id"] == domain_id  # what rcl really uses, not only the variable
    assert report["rmw_implementation"] == "rmw_fastrtps_cpp"
    listeners = rtps_listener_sockets(report)
    # the participant's unicast discovery and user-data ports, and no multicast listener
    assert len(listeners) >= 2, report["udp_sockets"]
    assert all(s.startswith("127.0.0.1:") for s in listeners), listeners
    assert all(s.startswith("127.0.0.1:") for s in report["udp_sockets"]), report["udp_sockets"]


def test_profile_restricts_every_transport_to_loopback():
    assert fastdds_profile_path().resolve() == PROFILE.resolve()
    root = ET.parse(PROFILE).getroot()
    descriptors = {d.findtext("f:transport_id", namespaces=NS): d
                   for d in root.findall("f:transport_descriptors/f:transport_descriptor", NS)}
    participants = root.findall("f:participant", NS)
    assert len(participants) == 1 and participants[0].get("is_default_profile") == "true"
    rtps = participants[0].find("f:rtps", NS)
    assert rtps.findtext("f:useBuiltinTransports", namespaces=NS).strip() == "false"
    used = [t.text.strip() for t in rtps.findall("f:userTransports/f:transport_id", NS)]
    assert used and set(used) <= set(descriptors)
    kinds = {descriptors[t].findtext("f:type", namespaces=NS).strip() for t in used}
    assert "UDPv4" in kinds and kinds <= {"UDPv4", "SHM"}  # shared memory never leaves the host
    for t in used:
        if descriptors[t].findtext("f:type", namespaces=NS).strip() == "UDPv4":
            addresses = [a.text.strip() for a in descriptors[t].findall("f:interfaceWhiteList/f:address", NS)]
            assert addresses == ["127.0.0.1"], (t, addresses)
            # unicast discovery reaches this many participants of one domain (Fast DDS default: 4)
            assert int(descriptors[t].findtext("f:maxInitialPeersRange", namespaces=NS)) >= 32
    # unicast discovery and user data on loopback, no multicast locator at all
    for path in ("f:builtin/f:metatrafficUnicastLocatorList", "f:builtin/f:initialPeersList",
                 "f:defaultUnicastLocatorList"):
        addresses = [a.text.strip() for a in rtps.findall(f"{path}/f:locator/f:udpv4/f:address", NS)]
        assert addresses == ["127.0.0.1"], (path, addresses)
    assert not root.findall(".//f:metatrafficMulticastLocatorList", NS)
    assert not root.findall(".//f:defaultMulticastLocatorList", NS)


def test_ros_env_applies_the_profile_as_is():
    """LOCALHOST (what a shell may export) becomes SYSTEM_DEFAULT while the project's profile is in
    force; another profile keeps the caller's range."""
    profile = str(fastdds_profile_path())
    assert local_dds_env({})["ROS_AUTOMATIC_DISCOVERY_RANGE"] == "SYSTEM_DEFAULT"
    assert local_dds_env({"ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"})["ROS_AUTOMATIC_DISCOVERY_RANGE"] == \
        "SYSTEM_DEFAULT"
    env = local_dds_env({"ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST", "FASTRTPS_DEFAULT_PROFILES_FILE": profile})
    assert env["ROS_AUTOMATIC_DISCOVERY_RANGE"] == "SYSTEM_DEFAULT"
    other = local_dds_env({"ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST", "FASTRTPS_DEFAULT_PROFILES_FILE": "/x.xml"})
    assert other["ROS_AUTOMATIC_DISCOVERY_RANGE"] == "LOCALHOST"
    assert local_dds_env({"FASTRTPS_DEFAULT_PROFILES_FILE": ""})["ROS_AUTOMATIC_DISCOVERY_RANGE"] == "LOCALHOST"


def test_spawned_node_gets_the_loopback_settings():
    domain_id = int(os.environ["ROS_DOMAIN_ID"])  # the session's private domain (conftest)
    base = stripped_environment()
    base["_ROS_WHEELS_BOOTSTRAP_COMPLETE"] = "1"  # as inherited from this venv Python
    env = local_dds_env(base, domain_id=domain_id)
    assert "_ROS_WHEELS_BOOTSTRAP_COMPLETE" not in env  # the child must bootstrap itself (FIELD_NOTES)
    token = f"probe-{uuid.uuid4().hex[:8]}"
    report = run_probe(env, "--params-file", str(NODE_PARAMS), "-p", f"text:={token}",
                       "-p", f"topic:=env_probe_{token.replace('-', '_')}")
    assert_loopback_report(report, domain_id)
    # rcl parsed config/nodes/env_probe.yaml the way climb_core.params does; -p overrides it
    expected = flatten(load_params(NODE_PARAMS, EnvProbeParams, "env_probe"))
    expected.update(text=token, topic=f"env_probe_{token.replace('-', '_')}")
    assert report["params"] == expected and report["published"] == token

    # Started by hand with no DDS setting at all, the node applies the defaults itself.
    bare = stripped_environment()
    bare.pop("_ROS_WHEELS_BOOTSTRAP_COMPLETE", None)
    report = run_probe(bare, "-p", f"topic:=env_probe_bare_{token.replace('-', '_')}")
    assert_loopback_report(report, DEFAULT_DOMAIN_ID)


def test_in_process_subscriber_receives_the_child_message_on_loopback(tmp_path):
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from std_msgs.msg import String

    domain_id = int(os.environ["ROS_DOMAIN_ID"])
    token = f"probe-{uuid.uuid4().hex[:8]}"
    params = EnvProbeParams(topic=f"env_probe_{token.replace('-', '_')}", text=token,
                            wait_for_subscribers_s=20.0, linger_s=0.25, qos_depth=5)
    params_file = tmp_path / "env_probe.yaml"
    params_file.write_text(to_yaml(params, "env_probe"))  # our YAML writer, parsed by rcl in the child

    context = rclpy.Context()
    rclpy.init(context=context)
    node = executor = child = None
    received: list[str] = []
    try:
        assert context.get_domain_id() == domain_id
        node = rclpy.create_node("env_probe_listener", context=context)
        node.create_subscription(String, params.topic, lambda msg: received.append(msg.data), 10)
        executor = SingleThreadedExecutor(context=context)
        executor.add_node(node)
        child = subprocess.Popen(probe_command("--params-file", str(params_file)),
                                 env=local_dds_env(stripped_environment(), domain_id=domain_id),
                                 stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        deadline = time.monotonic() + PROCESS_TIMEOUT_S
        while time.monotonic() < deadline and not (received and child.poll() is not None):
            executor.spin_once(timeout_sec=0.05)
        out, err = child.communicate(timeout=10)
        assert child.returncode == 0, err
    finally:
        if child is not None and child.poll() is None:
            child.kill()
            child.wait(timeout=10)
        if executor is not None:
            executor.shutdown()
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown(context=context)

    report = parse_report(out)
    assert_loopback_report(report, domain_id)
    assert report["params"] == flatten(params)
    assert report["subscribers_matched"] >= 1
    assert received == [token]
