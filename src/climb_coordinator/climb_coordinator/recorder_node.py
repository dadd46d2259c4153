"""The ``recorder`` node: every topic of the graph (or a list) into a rosbag2 MCAP bag, generically.

    .venv/lib/climb_coordinator/recorder --ros-args -p bag_path:=out/run/bag [-p topics:="[joint_states, 'ft/*']"]

It looks at the graph every ``discovery_period_s`` (``get_topic_names_and_types``), subscribes with
``raw=True`` to each new topic the selection wants (no per-type code: the message class only gives
rclpy the type support, the bytes go to the bag untouched), with a QoS that matches every
publisher (TRANSIENT_LOCAL when they all are: a latched climb/request or robot_description
published before the recorder joined is received), and stores the publishers' offered QoS in the
bag. A topic is subscribed once it has a publisher (its QoS is then known). The bag is complete on
disk after every flush (``flush_period_s`` <= 1 s, metadata.yaml rewritten atomically): a SIGKILL
loses at most that much; SIGINT / SIGTERM first take what DDS already delivered (``drain_s``), then
close the bag and exit 0. The ROS-free part is
climb_coordinator/recorder.py, the bag format msgs_py/bag.py.
"""
from __future__ import annotations

import sys
import time

NODE_NAME = "recorder"


def _policy_name(value) -> str:
    """rclpy's QoS policy enum member -> 'reliable', 'transient_local', 'keep_last', ..."""
    name = getattr(value, "name", str(value))
    return name.lower()


def publisher_qos(info) -> dict:
    """A TopicEndpointInfo's QoS as the plain dict recorder.py works with."""
    q = info.qos_profile
    return {"reliability": _policy_name(q.reliability), "durability": _policy_name(q.durability),
            "history": _policy_name(q.history), "depth": int(q.depth)}


def make_node(settings=None):
    from rclpy.node import Node
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

    from climb_core.errors import SpecError
    from msgs_py.bag import message_class
    from msgs_py.node_kit import declare_from_schema, diagnose, guarded

    from .recorder import (Recording, RecorderParams, TopicSelector, default_bag_path, normalize_topic,
                           parse_topic_list, subscription_qos)

    class RecorderNode(Node):
        def __init__(self) -> None:
            super().__init__(NODE_NAME)
            p = declare_from_schema(self, RecorderParams, read_only=True)
            self.settings = p
            self.selector = TopicSelector(parse_topic_list(p.topics), parse_topic_list(p.exclude), p.include_hidden)
            path = p.bag_path or str(default_bag_path())
            self.recording = Recording(path, p.flush_period_s,
                                       custom_data={"recorder": "climb_coordinator/recorder"})
            self._subs: dict[str, object] = {}
            self._warned: set[str] = set()
            self.get_logger().info(f"recording to {self.recording.path} "
                                   f"(topics: {', '.join(self.selector.include) or 'all'}; "
                                   f"excluded: {', '.join(self.selector.exclude) or 'none'})")
            self.create_timer(p.discovery_period_s, guarded(self, self.discover, "discover"))
            self.create_timer(p.flush_period_s, guarded(self, self.recording.flush, "flush"))
            self.discover()

        def discover(self) -> None:
            if self.recording.closed:
                return
            for name, types in self.get_topic_names_and_types():
                topic = normalize_topic(name)
                if topic in self._subs or topic in self._warned or not self.selector.wants(topic):
                    continue
                if len(types) != 1:
                    self._skip(topic, f"{len(types)} types on one topic ({', '.join(types)})")
                    continue
                publishers = [publisher_qos(i) for i in self.get_publishers_info_by_topic(topic)]
                if not publishers:
                    continue  # wait for a publisher: its QoS decides the subscription's
                msgtype = types[0]
                try:
                    cls = message_class(msgtype)
                except SpecError as exc:
                    self._skip(topic, str(exc))
                    continue
                if not self.recording.add(topic, msgtype, publishers):
                    self._skip(topic, self.recording.skipped.get(topic, "no definition"))
                    continue
                q = subscription_qos(publishers)
                profile = QoSProfile(
                    history=HistoryPolicy.KEEP_LAST, depth=q["depth"],
                    reliability=(ReliabilityPolicy.BEST_EFFORT if q["reliability"] == "best_effort"
                                 else ReliabilityPolicy.RELIABLE),
                    durability=(DurabilityPolicy.TRANSIENT_LOCAL if q["durability"] == "transient_local"
                                else DurabilityPolicy.VOLATILE))
                self._subs[topic] = self.create_subscription(
                    cls, topic, guarded(self, self._writer(topic), f"record {topic}"), profile, raw=True)
                self.get_logger().info(f"recording {topic} [{msgtype}] ({q['reliability']}, {q['durability']})")

        def _writer(self, topic: str):
            recording = self.recording

            def on_message(data: bytes) -> None:
                if not recording.closed:
                    recording.write(topic, data, time.time_ns())

            return on_message

        def _skip(self, topic: str, why: str) -> None:
            self._warned.add(topic)
            self.get_logger().warning(f"not recording {topic}: {why}")
            diagnose(self, f"{NODE_NAME}/topics", f"not recording {topic}: {why}", level=1)

        def close(self) -> None:
            if not self.recording.closed:
                self.recording.close()
                counts = self.recording.counts
                print(f"recorder: {sum(counts.values())} messages on {len(counts)} topics in "
                      f"{self.recording.path}", file=sys.stderr)

        def destroy_node(self) -> None:
            self.close()
            super().destroy_node()

    return RecorderNode()


def spin_then_drain(nodes, executor, is_running) -> None:
    """run_node's loop: spin until a signal, then take what DDS already holds for the recorder
    (a loaded machine may leave it behind its publishers) until nothing came for DRAIN_IDLE_S or
    the node's drain_s has passed; the bag is closed afterwards (destroy_node)."""
    while is_running():
        executor.spin_once(timeout_sec=0.1)
    node = nodes[0]
    recording = getattr(node, "recording", None)
    if recording is None or recording.closed:
        return
    deadline = time.monotonic() + float(node.settings.drain_s)
    last_count, idle_since = -1, time.monotonic()
    while time.monotonic() < deadline:
        try:
            executor.spin_once(timeout_sec=0.02)
        except Exception:  # noqa: BLE001 - the context went away: nothing more to take
            return
        count = sum(recording.counts.values())
        if count != last_count:
            last_count, idle_since = count, time.monotonic()
        elif time.monotonic() - idle_since > DRAIN_IDLE_S:
            return


DRAIN_IDLE_S = 0.3  # [s] no new message this long: the drain is over


def main(args: list[str] | None = None) -> int:
    from msgs_py.node_kit import run_node

    return run_node(make_node, args, name=NODE_NAME, loop=spin_then_drain)


if __name__ == "__main__":
    sys.exit(main())
