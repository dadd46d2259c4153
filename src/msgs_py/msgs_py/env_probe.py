"""env_probe: a tiny rclpy node that reports the DDS environment it really runs with.

    python -m msgs_py.env_probe [--ros-args --params-file config/nodes/env_probe.yaml -p text:=hi]

It applies the project's loopback settings (climb_core.ros_env.apply_local_dds_env), starts
rclpy, publishes one std_msgs/String on ``topic`` (after waiting up to ``wait_for_subscribers_s``
for a subscriber), and prints one JSON line: the three DDS variables, the RMW implementation,
the domain id rcl actually uses, the local addresses of this process's UDP sockets (read from
/proc, Linux) and its parameters. Used by tests/ros/test_dds_env.py.
"""
from __future__ import annotations

import ipaddress
import json
import os
import sys
import time
from dataclasses import dataclass

from climb_core.params import describe, flatten, param, parse_params
from climb_core.ros_env import apply_local_dds_env

NODE_NAME = "env_probe"
REPORTED_ENV = ("ROS_AUTOMATIC_DISCOVERY_RANGE", "FASTRTPS_DEFAULT_PROFILES_FILE", "ROS_DOMAIN_ID",
                "RMW_IMPLEMENTATION")


@dataclass(frozen=True)
class EnvProbeParams:
    topic: str = param("env_probe", unit="-", description="topic of the one std_msgs/String published")
    text: str = param("env_probe alive", unit="-", description="data of the published message")
    wait_for_subscribers_s: float = param(0.0, unit="s", min=0.0, max=60.0,
                                          description="wait up to this long for a subscriber before "
                                                      "publishing (0 = publish at once)")
    linger_s: float = param(0.3, unit="s", min=0.0, max=10.0,
                            description="keep spinning after publishing so reliable delivery completes")
    qos_depth: int = param(10, unit="-", min=1, max=1000, description="publisher history depth")


def udp_local_addresses(pid: str = "self") -> list[str]:
    """Local ``ip:port`` of every UDP socket the process owns (Linux /proc)."""
    inodes = set()
    fd_dir = f"/proc/{pid}/fd"
    for fd in os.listdir(fd_dir):
        try:
            link = os.readlink(os.path.join(fd_dir, fd))
        except OSError:  # closed meanwhile
            continue
        if link.startswith("socket:["):
            inodes.add(link[len("socket:["):-1])
    out = []
    for table, width in (("udp", 4), ("udp6", 16)):
        try:
            with open(f"/proc/{pid}/net/{table}") as fh:
                rows = fh.read().splitlines()[1:]
        except FileNotFoundError:
            continue
        for row in rows:
            cols = row.split()
            if cols[9] not in inodes:
                continue
            hex_ip, hex_port = cols[1].split(":")
            # /proc prints the address as 32-bit words in host (little-endian) order.
            raw = b"".join(bytes.fromhex(hex_ip[i:i + 8])[::-1] for i in range(0, len(hex_ip), 8))
            ip = ipaddress.IPv4Address(raw) if width == 4 else ipaddress.IPv6Address(raw)
            out.append(f"{ip}:{int(hex_port, 16)}")
    return sorted(out)


def main(args: list[str] | None = None) -> int:
    apply_local_dds_env()
    import rclpy
    from rcl_interfaces.msg import ParameterDescriptor
    from rclpy.executors import ExternalShutdownException
    from std_msgs.msg import String

    rclpy.init(args=args)
    node = None
    try:
        node = rclpy.create_node(NODE_NAME)
        infos = describe(EnvProbeParams)
        for name, value in flatten(EnvProbeParams()).items():
            node.declare_parameter(name, value, ParameterDescriptor(
                description=f"[{infos[name].unit}] {infos[name].description}"))
        params = parse_params({name: node.get_parameter(name).value for name in infos}, EnvProbeParams,
                              node.get_name())
        publisher = node.create_publisher(String, params.topic, params.qos_depth)
        deadline = time.monotonic() + params.wait_for_subscribers_s
        while publisher.get_subscription_count() < 1 and time.monotonic() < deadline:
            rclpy.spin_once(node, timeout_sec=0.02)
        subscribers = publisher.get_subscription_count()
        publisher.publish(String(data=params.text))
        linger_end = time.monotonic() + params.linger_s
        while time.monotonic() < linger_end:
            rclpy.spin_once(node, timeout_sec=0.02)
        report = {
            "node": node.get_fully_qualified_name(),
            "env": {key: os.environ.get(key) for key in REPORTED_ENV},
            "rmw_implementation": rclpy.get_rmw_implementation_identifier(),
            "domain_id": node.context.get_domain_id(),
            "udp_sockets": udp_local_addresses(),
            "subscribers_matched": subscribers,
            "published": params.text,
            "params": flatten(params),
        }
        print(json.dumps(report), flush=True)
        return 0
    except (KeyboardInterrupt, ExternalShutdownException):
        return 130
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()


if __name__ == "__main__":
    sys.exit(main())
