"""rosbag2 (MCAP) recording and reading for the project's topics.

The recorder writes real rosbag2 bags (metadata.yaml + .mcap, CDR payloads) with `rosbags`, so
`ros2 bag info/play` on a full ROS 2 install and the `mcap` tools read them. Payloads are CDR bytes:
either given raw (a generic recorder subscribing with ``raw=True``) or serialized here from rclpy
message objects with ``rclpy.serialization`` (which needs no ``rclpy.init()``).

Custom ``climb_msgs`` types are registered in the bag from the installed ``.msg`` definitions, so a
reader without this project can still decode them.

Import cost: this module imports rclpy's serialization lazily; ``import msgs_py`` does not import it.
"""
from __future__ import annotations

import importlib
import pathlib
import signal
import sys
import threading
from dataclasses import dataclass
from typing import Any, Iterator

from climb_core.errors import SpecError


def _climb_msgs_definitions() -> dict[str, str]:
    """msgtype ('climb_msgs/msg/Hold') -> .msg text, from the installed interface package."""
    share = pathlib.Path(sys.prefix, "share", "climb_msgs", "msg")
    if not share.is_dir():  # colcon install layout: <prefix>/share next to lib
        import climb_msgs

        share = pathlib.Path(climb_msgs.__file__).resolve().parents[4] / "share" / "climb_msgs" / "msg"
    return {f"climb_msgs/msg/{p.stem}": p.read_text() for p in sorted(share.glob("*.msg"))}


def make_typestore():
    """A rosbags typestore with ROS 2 Jazzy's standard types plus climb_msgs."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.ROS2_JAZZY)
    types: dict[str, Any] = {}
    for name, text in _climb_msgs_definitions().items():
        types.update(get_types_from_msg(text, name))
    store.register(types)
    return store


def msgtype_of(msg: Any) -> str:
    """'sensor_msgs/msg/JointState' for an rclpy message object."""
    module = type(msg).__module__.split(".")  # e.g. sensor_msgs.msg._joint_state
    return f"{module[0]}/{module[1]}/{type(msg).__name__}"


def message_class(msgtype: str):
    """The rclpy message class for 'pkg/msg/Name'."""
    try:
        pkg, kind, name = msgtype.split("/")
        return getattr(importlib.import_module(f"{pkg}.{kind}"), name)
    except (ValueError, ImportError, AttributeError) as exc:
        raise SpecError("msgtype", f"unknown message type {msgtype!r} ({exc})") from None


class BagRecorder:
    """Write topics to a rosbag2 bag (MCAP by default). Thread-safe; closes on SIGINT/SIGTERM.

    ``path`` is the bag directory (it must not exist). Use as a context manager or call close().
    """

    def __init__(self, path: str | pathlib.Path, *, storage: str = "mcap", close_on_signals: bool = True):
        from rosbags.rosbag2 import StoragePlugin, Writer

        self.path = pathlib.Path(path)
        if self.path.exists():
            raise SpecError("bag.path", f"{self.path} already exists; choose a new bag directory")
        plugins = {"mcap": StoragePlugin.MCAP, "sqlite3": StoragePlugin.SQLITE3}
        if storage not in plugins:
            raise SpecError("bag.storage", f"must be one of {sorted(plugins)}, got {storage!r}")
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._typestore = make_typestore()
        self._writer = Writer(self.path, version=9, storage_plugin=plugins[storage])
        self._writer.open()
        self._connections: dict[tuple[str, str], Any] = {}
        self._lock = threading.Lock()
        self.count = 0
        self._closed = False
        self._previous_handlers: dict[int, Any] = {}
        if close_on_signals and threading.current_thread() is threading.main_thread():
            for sig in (signal.SIGINT, signal.SIGTERM):
                self._previous_handlers[sig] = signal.signal(sig, self._on_signal)

    def _on_signal(self, signum, frame) -> None:
        self.close()
        previous = self._previous_handlers.get(signum)
        if callable(previous):
            previous(signum, frame)
        elif signum == signal.SIGINT:
            raise KeyboardInterrupt
        else:
            raise SystemExit(128 + signum)

    def _connection(self, topic: str, msgtype: str):
        key = (topic, msgtype)
        conn = self._connections.get(key)
        if conn is None:
            if msgtype not in self._typestore.types:
                raise SpecError("bag.msgtype", f"type {msgtype!r} of topic {topic!r} is not known to the typestore")
            conn = self._writer.add_connection(topic, msgtype, typestore=self._typestore)
            self._connections[key] = conn
        return conn

    def write_raw(self, topic: str, msgtype: str, data: bytes | memoryview, stamp_ns: int) -> None:
        """Record CDR bytes (as rclpy hands them to a ``raw=True`` subscription)."""
        with self._lock:
            if self._closed:
                raise SpecError("bag", f"{self.path} is closed")
            self._writer.write(self._connection(topic, msgtype), int(stamp_ns), data)
            self.count += 1

    def write(self, topic: str, msg: Any, stamp_ns: int) -> None:
        """Serialize an rclpy message object and record it."""
        from rclpy.serialization import serialize_message

        self.write_raw(topic, msgtype_of(msg), serialize_message(msg), stamp_ns)

    def close(self) -> None:
        with self._lock:
            if self._closed:
                return
            self._closed = True
            self._writer.close()
        for sig, handler in self._previous_handlers.items():
            try:
                signal.signal(sig, handler)
            except (ValueError, TypeError):  # not in the main thread any more / handler was None
                pass

    def __enter__(self) -> "BagRecorder":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


@dataclass(frozen=True)
class BagMessage:
    topic: str
    msgtype: str
    stamp_ns: int
    data: bytes

    def decode(self) -> Any:
        """The rclpy message object (needs the type's Python package installed)."""
        from rclpy.serialization import deserialize_message

        return deserialize_message(self.data, message_class(self.msgtype))


def read_bag(path: str | pathlib.Path, topics: list[str] | None = None) -> Iterator[BagMessage]:
    """Iterate over a rosbag2 bag's messages in time order."""
    from rosbags.rosbag2 import Reader

    with Reader(pathlib.Path(path)) as reader:
        connections = [c for c in reader.connections if topics is None or c.topic in topics]
        for conn, stamp, data in reader.messages(connections=connections):
            yield BagMessage(conn.topic, conn.msgtype, int(stamp), bytes(data))
