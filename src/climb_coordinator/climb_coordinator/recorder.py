"""The generic recorder's logic without ROS: which topics to record, with which QoS, into which bag.

The ``recorder`` node (recorder_node.py) discovers the graph's topics, asks :class:`TopicSelector`
whether to record each one, asks :func:`subscription_qos` how to subscribe so that every publisher
matches (a TRANSIENT_LOCAL subscription only when every publisher is TRANSIENT_LOCAL, so that a
latched message reaches it; BEST_EFFORT as soon as one publisher is), and hands every serialized
message to :class:`Recording` (a msgs_py.bag.BagRecorder: rosbag2 MCAP readable at every flush).
Publisher QoS is passed around as plain dicts (``reliability``, ``durability``, ``history``,
``depth``: lower-case names as in rosbag2's metadata), so this module never imports rclpy.
"""
from __future__ import annotations

import fnmatch
import pathlib
import re
import time
from dataclasses import dataclass, field
from typing import Iterable, Sequence

from climb_core.errors import SpecError
from climb_core.params import param

#: topics the recorder leaves out unless listed explicitly (rosbag2's defaults too)
DEFAULT_EXCLUDE = ("/parameter_events",)
#: [-] history depth of the recorder's subscriptions: deep, so that a burst waits in DDS
SUBSCRIPTION_DEPTH = 1000


@dataclass(frozen=True)
class RecorderParams:
    """The recorder node's parameters (config/nodes has no file for it: these are the defaults)."""

    bag_path: str = param("", unit="-", description="bag directory to create (must not exist); empty: "
                          "bags/rosbag2_<UTC date-time> under the working directory")
    topics: tuple[str, ...] = param((), unit="-", description="topics to record: names, globs ('ft/*') or "
                                    "'re:<regex>'; empty: every topic of the graph")
    exclude: tuple[str, ...] = param(DEFAULT_EXCLUDE, unit="-", description="topics never recorded (names, globs, "
                                     "'re:<regex>')")
    include_hidden: bool = param(False, unit="-", description="also record hidden topics (a component starting "
                                 "with '_', e.g. actions' _action/feedback)")
    discovery_period_s: float = param(0.5, unit="s", description="wall time between two looks at the graph's topics",
                                      min=0.05, max=10.0)
    flush_period_s: float = param(0.5, unit="s", description="wall time between two flushes: the most a SIGKILL loses; "
                                  "metadata.yaml is rewritten at each", min=0.05, max=1.0)
    drain_s: float = param(3.0, unit="s", description="on SIGINT / SIGTERM, the longest wall time spent taking the "
                           "messages DDS already delivered before the bag is closed", min=0.0, max=60.0)


def normalize_topic(name: str) -> str:
    """A topic name as the graph reports it: absolute ('/joint_states')."""
    name = name.strip()
    return name if name.startswith("/") else "/" + name


def is_hidden(topic: str) -> bool:
    """A hidden topic has a component starting with '_' (actions' _action/feedback, ...)."""
    return any(part.startswith("_") for part in topic.split("/") if part)


def _pattern(entry: str) -> re.Pattern:
    """A list entry as a regular expression: 're:<regex>' as is, otherwise a topic name or a glob
    ('ft/*', '/sim/**'), relative names matching at the root."""
    if entry.startswith("re:"):
        return re.compile(entry[3:])
    return re.compile(fnmatch.translate(normalize_topic(entry)))


@dataclass
class TopicSelector:
    """Which topics to record: ``include`` (empty: every topic) minus ``exclude``; hidden topics
    only when ``include_hidden`` or listed in ``include`` by name."""

    include: Sequence[str] = ()
    exclude: Sequence[str] = DEFAULT_EXCLUDE
    include_hidden: bool = False
    _inc: list = field(init=False, repr=False)
    _exc: list = field(init=False, repr=False)

    def __post_init__(self) -> None:
        try:
            self._inc = [_pattern(e) for e in self.include if e.strip()]
            self._exc = [_pattern(e) for e in self.exclude if e.strip()]
        except re.error as exc:
            raise SpecError("recorder.topics", f"bad regular expression: {exc}") from None

    def wants(self, topic: str) -> bool:
        topic = normalize_topic(topic)
        if any(p.fullmatch(topic) for p in self._exc):
            return False
        if self._inc:
            explicit = any(p.fullmatch(topic) for p in self._inc)
            if not explicit:
                return False
            if is_hidden(topic) and not self.include_hidden:
                return any(normalize_topic(e) == topic for e in self.include)
            return True
        return self.include_hidden or not is_hidden(topic)


def subscription_qos(publishers: Sequence[dict]) -> dict:
    """The subscription profile that matches every publisher (what ``ros2 bag record`` adapts to):
    RELIABLE unless a publisher is BEST_EFFORT; TRANSIENT_LOCAL only when every publisher is
    (a latched topic: the recorder then gets the message published before it joined); KEEP_LAST
    with a deep history."""
    rel = [p.get("reliability", "reliable") for p in publishers]
    dur = [p.get("durability", "volatile") for p in publishers]
    return {
        "reliability": "best_effort" if any(r == "best_effort" for r in rel) else "reliable",
        "durability": "transient_local" if dur and all(d == "transient_local" for d in dur) else "volatile",
        "history": "keep_last",
        "depth": SUBSCRIPTION_DEPTH,
    }


def bag_qos(publishers: Sequence[dict]) -> list:
    """The publishers' offered profiles as rosbags Qos (metadata.yaml's offered_qos_profiles)."""
    from msgs_py.bag import qos_profile

    out = []
    for p in publishers:
        try:
            out.append(qos_profile(reliability=p.get("reliability", "reliable"),
                                   durability=p.get("durability", "volatile"),
                                   depth=int(p.get("depth", 0) or 0),
                                   history=p.get("history", "keep_last")))
        except KeyError:  # an unknown policy name (system_default, ...): rosbag2 stores it as is
            out.append(qos_profile(depth=int(p.get("depth", 0) or 0)))
    return out


def default_bag_path(root: str | pathlib.Path = "bags") -> pathlib.Path:
    """bags/rosbag2_<UTC date>-<time> (a new directory name)."""
    stamp = time.strftime("%Y_%m_%d-%H_%M_%S", time.gmtime())
    path = pathlib.Path(root) / f"rosbag2_{stamp}"
    k = 1
    while path.exists():
        path = pathlib.Path(root) / f"rosbag2_{stamp}_{k}"
        k += 1
    return path


class Recording:
    """One bag being recorded: topics added with their publishers' QoS, raw CDR messages written
    with their receive time, flushed (complete bag on disk) at least every ``flush_period_s``."""

    def __init__(self, path: str | pathlib.Path, flush_period_s: float = 0.5, custom_data: dict | None = None):
        from msgs_py.bag import BagRecorder

        if not (0.0 < flush_period_s <= 1.0):
            raise SpecError("recorder.flush_period_s", f"must be in (0, 1] [s], got {flush_period_s!r}")
        self.bag = BagRecorder(path, close_on_signals=False, flush_period_s=flush_period_s,
                               custom_data=custom_data)
        self.path = self.bag.path
        self.types: dict[str, str] = {}  # topic -> msgtype
        self.skipped: dict[str, str] = {}  # topic -> why it is not recorded
        self.counts: dict[str, int] = {}

    def add(self, topic: str, msgtype: str, publishers: Sequence[dict]) -> bool:
        """Start recording ``topic``; False (reason in ``skipped``) when its type has no definition."""
        topic = normalize_topic(topic)
        if topic in self.types:
            return True
        try:
            self.bag.add_topic(topic, msgtype, bag_qos(publishers))
        except SpecError as exc:
            self.skipped[topic] = str(exc)
            return False
        self.types[topic] = msgtype
        self.counts[topic] = 0
        return True

    def write(self, topic: str, data: bytes, stamp_ns: int | None = None) -> None:
        topic = normalize_topic(topic)
        self.bag.write_raw(topic, self.types[topic], data, time.time_ns() if stamp_ns is None else stamp_ns)
        self.counts[topic] += 1

    def flush(self) -> None:
        self.bag.flush()

    def close(self) -> None:
        self.bag.close()

    @property
    def closed(self) -> bool:
        return self.bag.closed


def parse_topic_list(values: Iterable[str]) -> list[str]:
    """A ROS string-array parameter: entries may also be comma-separated ('a,b')."""
    out = []
    for v in values:
        out.extend(x.strip() for x in str(v).split(",") if x.strip())
    return out
