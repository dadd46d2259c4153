"""rosbag2 (MCAP) recording and reading for the project's topics.

The recorder writes real rosbag2 bags (metadata.yaml + .mcap, CDR payloads) with `rosbags`, so
`ros2 bag info/play` on a full ROS 2 install and the `mcap` tools read them. Payloads are CDR bytes:
either given raw (a generic recorder subscribing with ``raw=True``) or serialized here from rclpy
message objects with ``rclpy.serialization`` (which needs no ``rclpy.init()``).

Custom ``climb_msgs`` types are registered in the bag from the installed ``.msg`` definitions, so a
reader without this project can still decode them.

A bag survives its recorder being killed: the MCAP writer's pending chunk is written out and the
file flushed every ``flush_period_s`` of wall time, so a SIGKILL loses at most that much. A killed
bag has no metadata.yaml and no MCAP summary; :func:`read_bag` reads it anyway (record by record,
up to the last complete chunk) and :func:`recover_bag` rewrites it as a complete rosbag2 bag (what
``ros2 bag reindex`` does for the C++ recorder).

Import cost: this module imports rclpy's serialization lazily; ``import msgs_py`` does not import it.
"""
from __future__ import annotations

import importlib
import pathlib
import shutil
import signal
import sys
import threading
import time
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
    ``flush_period_s`` [s, wall time]: the most a SIGKILL of this process can lose (MCAP storage;
    0 writes every message through at once, which costs a chunk per message).
    """

    def __init__(self, path: str | pathlib.Path, *, storage: str = "mcap", close_on_signals: bool = True,
                 flush_period_s: float = 0.5):
        from rosbags.rosbag2 import StoragePlugin, Writer

        self.path = pathlib.Path(path)
        if self.path.exists():
            raise SpecError("bag.path", f"{self.path} already exists; choose a new bag directory")
        plugins = {"mcap": StoragePlugin.MCAP, "sqlite3": StoragePlugin.SQLITE3}
        if storage not in plugins:
            raise SpecError("bag.storage", f"must be one of {sorted(plugins)}, got {storage!r}")
        if not (flush_period_s >= 0.0):
            raise SpecError("bag.flush_period_s", f"must be a number >= 0 [s], got {flush_period_s!r}")
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.flush_period_s = float(flush_period_s)
        self._last_flush = time.monotonic()
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
            if time.monotonic() - self._last_flush >= self.flush_period_s:
                self._flush_locked()

    def flush(self) -> None:
        """Write everything recorded so far to the file (it then survives a SIGKILL)."""
        with self._lock:
            if not self._closed:
                self._flush_locked()

    def _flush_locked(self) -> None:
        self._last_flush = time.monotonic()
        mcap = self._writer.storage  # rosbags' MCAP storage keeps up to 1 MiB in a pending chunk
        if hasattr(mcap, "close_chunk") and hasattr(mcap, "chunk") and mcap.chunk.bio.tell():
            mcap.close_chunk()
            mcap.bio.flush()

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


def _unclosed_mcap(path: pathlib.Path) -> pathlib.Path | None:
    """The .mcap file of a bag directory whose recorder never closed it (no metadata.yaml)."""
    if not path.is_dir() or (path / "metadata.yaml").exists():
        return None
    files = sorted(path.glob("*.mcap"))
    return files[0] if files else None


def _scan_unclosed(mcap_file: pathlib.Path) -> tuple[list[tuple[str, str, int, bytes]], str]:
    """(topic, msgtype, stamp_ns, data) of every complete message of an unclosed MCAP file, in time
    order, and why the scan stopped ('' at a clean end)."""
    from mcap.records import Channel, Message, Schema
    from mcap.stream_reader import StreamReader

    schemas: dict[int, str] = {}
    channels: dict[int, tuple[str, str]] = {}
    out: list[tuple[str, str, int, bytes]] = []
    stopped = ""
    with open(mcap_file, "rb") as f:
        try:
            for record in StreamReader(f, skip_magic=False).records:
                if isinstance(record, Schema):
                    schemas[record.id] = record.name
                elif isinstance(record, Channel):
                    channels[record.id] = (record.topic, schemas.get(record.schema_id, ""))
                elif isinstance(record, Message) and record.channel_id in channels:
                    topic, msgtype = channels[record.channel_id]
                    out.append((topic, msgtype, int(record.log_time), bytes(record.data)))
        except Exception as exc:  # the tail the kill cut: a truncated record or chunk
            stopped = f"{type(exc).__name__}: {exc}"
    out.sort(key=lambda m: m[2])
    return out, stopped


def recover_bag(path: str | pathlib.Path) -> int:
    """Rewrite a bag whose recorder was killed (no metadata.yaml, no MCAP summary) as a complete
    rosbag2 bag at the same path; returns the number of messages recovered. A closed bag is left
    alone (returns its message count)."""
    path = pathlib.Path(path)
    mcap_file = _unclosed_mcap(path)
    if mcap_file is None:
        if not (path / "metadata.yaml").is_file():
            raise SpecError("bag.path", f"{path} is not a bag directory (no metadata.yaml, no .mcap file)")
        return sum(1 for _ in read_bag(path))
    messages, _ = _scan_unclosed(mcap_file)
    # the new bag is written under its final name in a side directory, then swapped in
    staging_root = path.with_name(f".{path.name}.recovering")
    if staging_root.exists():
        shutil.rmtree(staging_root)
    staging = staging_root / path.name
    with BagRecorder(staging, close_on_signals=False, flush_period_s=3600.0) as rec:
        for topic, msgtype, stamp, data in messages:
            rec.write_raw(topic, msgtype, data, stamp)
    killed = staging_root / f"{path.name}.killed"
    path.rename(killed)
    staging.rename(path)
    shutil.rmtree(staging_root)
    return len(messages)


def read_bag(path: str | pathlib.Path, topics: list[str] | None = None) -> Iterator[BagMessage]:
    """Iterate over a rosbag2 bag's messages in time order. A bag whose recorder was killed is
    read too (every message up to its last complete chunk); :func:`recover_bag` repairs it."""
    from rosbags.rosbag2 import Reader

    path = pathlib.Path(path)
    mcap_file = _unclosed_mcap(path)
    if mcap_file is not None:
        messages, _ = _scan_unclosed(mcap_file)
        for topic, msgtype, stamp, data in messages:
            if topics is None or topic in topics:
                yield BagMessage(topic, msgtype, stamp, data)
        return
    with Reader(path) as reader:
        connections = [c for c in reader.connections if topics is None or c.topic in topics]
        for conn, stamp, data in reader.messages(connections=connections):
            yield BagMessage(conn.topic, conn.msgtype, int(stamp), bytes(data))
