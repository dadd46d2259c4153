"""rosbag2 (MCAP) recording and reading, for any message type.

The recorder writes real rosbag2 bags (metadata.yaml + .mcap, CDR payloads, metadata version 9), so
`ros2 bag info/play` on a full ROS 2 install, ``rosbags`` and the ``mcap`` tools read them. Payloads
are CDR bytes: either given raw (a generic recorder subscribing with ``raw=True``) or serialized here
from rclpy message objects with ``rclpy.serialization`` (which needs no ``rclpy.init()``).

Message definitions: every type is registered in the bag with its ``.msg`` text, taken from the
installed interface packages (``<prefix>/share/<pkg>/msg/<Name>.msg``, the project's climb_msgs
included) or, for generated types without a ``.msg`` file (actions' goal / feedback messages), built
from the Python class's field list. A reader without this project decodes them.

Each topic carries the QoS its publishers offered (``offered_qos_profiles``, durability included) in
metadata.yaml and in the MCAP channel metadata, as ``ros2 bag record`` writes them.

The bag is readable at every moment (a recorder killed with SIGKILL leaves a bag that ``rosbags``
and ``mcap`` read as is, up to its last flush):
- the MCAP file always ends with a complete summary and footer: each flush writes the pending chunk
  followed by a new summary section and footer, in ONE write at the place where the previous
  summary began (the chunk overwrites the old summary); messages between flushes stay in memory;
- ``metadata.yaml`` is written when the bag opens and rewritten atomically (temporary file +
  rename) after every flush, so it never counts a message the MCAP file does not hold.
Flushes happen every ``flush_period_s`` of wall time (on write or from :meth:`BagRecorder.flush`,
which a recorder calls from a timer), and when the pending chunk exceeds 1 MiB.

Bags written by older recorders that were killed (no metadata.yaml, no summary) are still read record
by record (:func:`read_bag`) and repaired by :func:`recover_bag` (what ``ros2 bag reindex`` does).

Import cost: rclpy's serialization is imported lazily; ``import msgs_py`` does not import this module.
"""
from __future__ import annotations

import importlib
import os
import pathlib
import re
import shutil
import signal
import struct
import sys
import threading
import time
from dataclasses import dataclass
from io import BytesIO, StringIO
from typing import Any, Iterator, Sequence

from climb_core.errors import SpecError

MAGIC = b"\x89MCAP0\r\n"
_MESSAGE_HEADER = struct.Struct("<BQHIQQ")
CHUNK_LIMIT_BYTES = 1 << 20  # a pending chunk larger than this is flushed at once


# -- message definitions ---------------------------------------------------------------------------

def _share_dirs() -> list[pathlib.Path]:
    """Where installed interface packages keep their .msg files: this prefix, then AMENT_PREFIX_PATH."""
    dirs = [pathlib.Path(sys.prefix, "share")]
    for prefix in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep):
        if prefix:
            dirs.append(pathlib.Path(prefix, "share"))
    try:  # colcon install layout: <prefix>/lib/python3.x/site-packages/climb_msgs
        import climb_msgs

        dirs.append(pathlib.Path(climb_msgs.__file__).resolve().parents[4] / "share")
    except ImportError:
        pass
    return dirs


def _climb_msgs_definitions() -> dict[str, str]:
    """msgtype ('climb_msgs/msg/Hold') -> .msg text, from the installed interface package."""
    for share in _share_dirs():
        folder = share / "climb_msgs" / "msg"
        if folder.is_dir():
            return {f"climb_msgs/msg/{p.stem}": p.read_text() for p in sorted(folder.glob("*.msg"))}
    return {}


def msg_file_text(msgtype: str) -> str | None:
    """The installed .msg text of 'pkg/msg/Name', or None."""
    try:
        pkg, kind, name = msgtype.split("/")
    except ValueError:
        return None
    for share in _share_dirs():
        path = share / pkg / kind / f"{name}.msg"
        if path.is_file():
            return path.read_text()
    return None


_PRIMITIVES = {"double": "float64", "float": "float32", "boolean": "bool", "octet": "byte", "long double": "float64"}


def _field_type_text(rosidl_type: str) -> str:
    """A field type of ``get_fields_and_field_types()`` ('sequence<double, 3>', 'pkg/Name[2]', ...) in
    .msg syntax ('float64[<=3]', 'pkg/Name[2]')."""
    t = rosidl_type.strip()
    if t.startswith("sequence<") and t.endswith(">"):
        inner = t[len("sequence<"):-1]
        if "," in inner and not inner.rstrip().endswith(">"):
            value, bound = inner.rsplit(",", 1)
            return f"{_field_type_text(value)}[<={bound.strip()}]"
        return f"{_field_type_text(inner)}[]"
    if t.endswith("]") and "[" in t:
        base, dim = t[:-1].split("[", 1)
        return f"{_field_type_text(base)}[{dim}]"
    return _PRIMITIVES.get(t, t)


def introspected_msg_text(cls) -> str:
    """.msg text of an rclpy message class from its field list (no constants: they do not change
    the serialization). Nested types are written 'pkg/Name'."""
    lines = [f"{_field_type_text(ftype)} {fname}" for fname, ftype in cls.get_fields_and_field_types().items()]
    return "\n".join(lines) + "\n"


def _nested_types(cls) -> list[str]:
    """'pkg/kind/Name' of every message type a class's fields contain."""
    out = []
    for slot in getattr(cls, "SLOT_TYPES", ()):
        while hasattr(slot, "value_type"):  # arrays and sequences
            slot = slot.value_type
        namespaces = getattr(slot, "namespaces", None)
        if namespaces:
            out.append("/".join([*namespaces, slot.name]))
    return out


def make_typestore():
    """A rosbags typestore with ROS 2 Jazzy's standard types plus climb_msgs."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.ROS2_JAZZY)
    types: dict[str, Any] = {}
    for name, text in _climb_msgs_definitions().items():
        types.update(get_types_from_msg(text, name))
    store.register(types)
    return store


def ensure_type(store, msgtype: str, _seen: set | None = None) -> None:
    """Register ``msgtype`` (and the types it contains) in a rosbags typestore, from the installed
    .msg file or the Python class's fields. Raises SpecError when neither is available."""
    seen = set() if _seen is None else _seen
    if msgtype in seen:
        return
    seen.add(msgtype)
    if msgtype in store.types:
        return
    cls = None
    try:
        cls = message_class(msgtype)
    except SpecError:
        pass
    if cls is not None:
        for dep in _nested_types(cls):
            ensure_type(store, dep, seen)
            pkg, kind, name = dep.split("/")
            if kind != "msg":  # .msg text names it 'pkg/Name', which resolves to pkg/msg/Name
                _register(store, f"{pkg}/msg/{name}", _definition_text(dep, message_class(dep)))
    _register(store, msgtype, _definition_text(msgtype, cls))


def _definition_text(msgtype: str, cls) -> str:
    text = msg_file_text(msgtype)
    if text is None:
        if cls is None:
            raise SpecError("bag.msgtype", f"type {msgtype!r}: no .msg definition installed and no Python class")
        text = introspected_msg_text(cls)
    return text


def _register(store, msgtype: str, text: str) -> None:
    from rosbags.typesys import get_types_from_msg

    if msgtype in store.types:
        return
    try:
        store.register(get_types_from_msg(text, msgtype))
    except Exception as exc:  # a definition rosbags cannot parse: name it
        raise SpecError("bag.msgtype", f"type {msgtype!r}: cannot register its definition ({exc})") from None


def msgtype_of(msg: Any) -> str:
    """'sensor_msgs/msg/JointState' for an rclpy message object."""
    module = type(msg).__module__.split(".")  # e.g. sensor_msgs.msg._joint_state
    return f"{module[0]}/{module[1]}/{type(msg).__name__}"


def message_class(msgtype: str):
    """The rclpy message class for 'pkg/msg/Name'."""
    try:
        pkg, kind, name = msgtype.split("/")
        module = importlib.import_module(f"{pkg}.{kind}")
        if hasattr(module, name):
            return getattr(module, name)
        # generated sub-types (actions' Climb_FeedbackMessage, services' Trigger_Request) live in
        # the interface's own module: climb_msgs.action._climb
        base = name.split("_", 1)[0]
        snake = re.sub(r"(?<=[a-z0-9])([A-Z])|(?<=[A-Z])([A-Z])(?=[a-z])", r"_\1\2", base).lower()
        return getattr(importlib.import_module(f"{pkg}.{kind}._{snake}"), name)
    except (ValueError, ImportError, AttributeError) as exc:
        raise SpecError("msgtype", f"unknown message type {msgtype!r} ({exc})") from None


# -- QoS ---------------------------------------------------------------------------------------------

def qos_profile(reliability: str = "reliable", durability: str = "volatile", depth: int = 10,
                history: str = "keep_last"):
    """A rosbags Qos (what rosbag2 stores per publisher) from names; deadline, lifespan and
    liveliness lease 'infinite' as ROS 2 reports them."""
    from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime

    infinite = QosTime(0x7FFFFFFF, 0xFFFFFFFF)
    return Qos(QosHistory[history.upper()], int(depth), QosReliability[reliability.upper()],
               QosDurability[durability.upper()], infinite, infinite, QosLiveliness.AUTOMATIC, infinite, False)


# -- the MCAP storage: a complete file after every flush ---------------------------------------------

class _LiveMcap:
    """rosbags' storage-writer protocol for MCAP, whose file is complete (summary + footer) after
    every :meth:`checkpoint`. Schemas and channels are written in the data section before the chunk
    that first uses them, and repeated in the summary."""

    def __init__(self, path: pathlib.Path, compression) -> None:
        from importlib.metadata import version as pkg_version

        from rosbags.rosbag2.storage_mcap import PendingChunk, write_record, write_string

        self.path = path / f"{path.name}.mcap"
        self._fd = os.open(self.path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
        head = BytesIO()
        head.write(MAGIC)
        rec = BytesIO()
        write_string(rec, "ros2")
        write_string(rec, f"rosbags-{pkg_version('rosbags')} (msgs_py.bag live)")
        write_record(head, 0x01, rec)
        self._pwrite(head.getbuffer(), 0)
        self._end = head.tell()  # end of the data on disk: where the next flush writes
        self._new_chunk = lambda: PendingChunk(2**63 - 1, 0, BytesIO(), {})
        self.schemas: list = []
        self.channels: list = []
        self.chunk_indexes: list[BytesIO] = []
        self._defs = BytesIO()  # schema / channel records not yet on disk
        self.chunk = self._new_chunk()
        self.message_start_time = 2**63 - 1
        self.message_end_time = 0
        self.channel_stats: dict[int, int] = {}
        self.pending_messages = 0

    def _pwrite(self, data, offset: int) -> None:
        view = memoryview(data)
        while len(view):
            n = os.pwrite(self._fd, view, offset)
            view, offset = view[n:], offset + n

    def add_msgtype(self, connection) -> None:
        from rosbags.interfaces import MessageDefinitionFormat
        from rosbags.rosbag2.storage_mcap import Schema, write_schema

        fmt = "ros2msg" if connection.msgdef.format == MessageDefinitionFormat.MSG else "ros2idl"
        self.schemas.append(Schema(len(self.schemas) + 1, connection.msgtype, fmt, connection.msgdef.data))
        write_schema(self._defs, self.schemas[-1])

    def add_connection(self, connection, offered_qos_profiles: str) -> None:
        from rosbags.rosbag2.storage_mcap import Channel, write_channel, write_string

        metadata = BytesIO()
        write_string(metadata, "offered_qos_profiles")
        write_string(metadata, offered_qos_profiles)
        self.channels.append(Channel(connection.id, connection.msgtype, connection.topic,
                                     connection.ext.serialization_format, metadata.getvalue()))
        self.channel_stats[connection.id] = 0
        write_channel(self._defs, self.channels[-1], self.schemas)

    def write(self, connection, timestamp: int, data) -> None:
        chunk = self.chunk
        if timestamp < chunk.message_start_time:
            chunk.message_start_time = timestamp
        if timestamp > chunk.message_end_time:
            chunk.message_end_time = timestamp
        bio = chunk.bio
        msgs = chunk.msgs.get(connection.id)
        if msgs is None:
            msgs = chunk.msgs[connection.id] = []
        msgs.append((timestamp, bio.tell()))
        # Message record: opcode 0x05, length, channel id, sequence, log time, publish time, data
        bio.write(_MESSAGE_HEADER.pack(0x05, 22 + len(data), connection.id, 0, timestamp, timestamp))
        bio.write(data)
        self.pending_messages += 1

    @property
    def pending_bytes(self) -> int:
        return self.chunk.bio.tell()

    def _commit_stats(self) -> None:
        for cid, msgs in self.chunk.msgs.items():
            self.channel_stats[cid] += len(msgs)
            for ts, _ in msgs:
                if ts < self.message_start_time:
                    self.message_start_time = ts
                if ts > self.message_end_time:
                    self.message_end_time = ts

    def _close_chunk(self, out: BytesIO, base: int) -> None:
        """The pending chunk and its message indexes into ``out`` (which lands at file offset
        ``base``); its chunk index kept for the summary."""
        from rosbags.rosbag2.storage_mcap import write_record, write_string, write_uint16, write_uint32, write_uint64

        chunk = self.chunk
        payload = chunk.bio.getvalue()
        rec = BytesIO()
        write_uint64(rec, chunk.message_start_time)
        write_uint64(rec, chunk.message_end_time)
        write_uint64(rec, len(payload))
        write_uint32(rec, 0)  # no CRC
        write_string(rec, "")
        write_uint64(rec, len(payload))
        rec.write(payload)
        chunk_start = base + out.tell()
        write_record(out, 0x06, rec)
        chunk_end = base + out.tell()
        offsets = []
        for cid, msgs in chunk.msgs.items():
            offsets.append((cid, base + out.tell()))
            rec = BytesIO()
            write_uint16(rec, cid)
            write_uint32(rec, len(msgs) * 16)
            for ts, offset in msgs:
                write_uint64(rec, ts)
                write_uint64(rec, offset)
            write_record(out, 0x07, rec)
        index = BytesIO()
        write_uint64(index, chunk.message_start_time)
        write_uint64(index, chunk.message_end_time)
        write_uint64(index, chunk_start)
        write_uint64(index, chunk_end - chunk_start)
        write_uint32(index, len(offsets) * 10)
        for cid, offset in offsets:
            write_uint16(index, cid)
            write_uint64(index, offset)
        write_uint64(index, base + out.tell() - chunk_end)
        write_string(index, "")
        write_uint64(index, len(payload))
        write_uint64(index, len(payload))
        self.chunk_indexes.append(index)
        self._commit_stats()
        self.chunk = self._new_chunk()
        self.pending_messages = 0

    def _tail(self, out: BytesIO, base: int, metadata: str) -> None:
        """rosbag2 metadata record, DataEnd, the summary section and the footer."""
        from rosbags.rosbag2.storage_mcap import (write_channel, write_record, write_schema, write_string,
                                                  write_uint16, write_uint32, write_uint64)

        pos = lambda: base + out.tell()  # noqa: E731
        metadata_start = pos()
        rec = BytesIO()
        write_string(rec, "rosbag2")
        sub = BytesIO()
        write_string(sub, "serialized_metadata")
        write_string(sub, metadata)
        write_uint32(rec, sub.tell())
        rec.write(sub.getbuffer())
        write_record(out, 0x0C, rec)
        metadata_end = pos()
        rec = BytesIO()
        write_uint32(rec, 0)
        write_record(out, 0x0F, rec)  # DataEnd
        schema_start = pos()
        for schema in self.schemas:
            write_schema(out, schema)
        channel_start = pos()
        for channel in self.channels:
            write_channel(out, channel, self.schemas)
        chunk_start = pos()
        for index in self.chunk_indexes:
            write_record(out, 0x08, index)
        metadata_index_start = pos()
        rec = BytesIO()
        write_uint64(rec, metadata_start)
        write_uint64(rec, metadata_end - metadata_start)
        write_string(rec, "rosbag2")
        write_record(out, 0x0D, rec)
        statistics_start = pos()
        rec = BytesIO()
        count = sum(self.channel_stats.values())
        write_uint64(rec, count)
        write_uint16(rec, len(self.schemas))
        write_uint32(rec, len(self.channels))
        write_uint32(rec, 0)  # attachments
        write_uint32(rec, 1)  # metadata
        write_uint32(rec, len(self.chunk_indexes))
        write_uint64(rec, self.message_start_time if count else 0)
        write_uint64(rec, self.message_end_time if count else 0)
        write_uint32(rec, len(self.channel_stats) * 10)
        for cid, n in sorted(self.channel_stats.items()):
            write_uint16(rec, cid)
            write_uint64(rec, n)
        write_record(out, 0x0B, rec)
        offsets_start = pos()
        for opcode, start, end in ((0x03, schema_start, channel_start), (0x04, channel_start, chunk_start),
                                   (0x08, chunk_start, metadata_index_start),
                                   (0x0D, metadata_index_start, statistics_start),
                                   (0x0B, statistics_start, offsets_start)):
            if end != start:
                rec = BytesIO()
                rec.write(bytes([opcode]))
                write_uint64(rec, start)
                write_uint64(rec, end - start)
                write_record(out, 0x0E, rec)
        rec = BytesIO()
        write_uint64(rec, schema_start)
        write_uint64(rec, offsets_start)
        write_uint32(rec, 0)
        write_record(out, 0x02, rec)
        out.write(MAGIC)

    def checkpoint(self, metadata) -> None:
        """Write the new schemas / channels, the pending chunk and a fresh summary + footer, in one
        write where the previous summary began; the file is a complete MCAP file afterwards.
        ``metadata()`` gives the rosbag2 metadata text once the chunk is counted."""
        base = self._end
        out = BytesIO()
        out.write(self._defs.getbuffer())
        self._defs = BytesIO()
        if self.chunk.msgs:
            self._close_chunk(out, base)
        data_end = base + out.tell()
        self._tail(out, base, metadata())
        self._pwrite(out.getbuffer(), base)
        os.ftruncate(self._fd, base + out.tell())
        self._end = data_end

    def close(self, version: int, metadata) -> None:
        self.checkpoint(metadata)
        os.close(self._fd)
        self._fd = -1

    def abort(self) -> None:
        if self._fd >= 0:
            os.close(self._fd)
            self._fd = -1


def _mcap_plugin():
    from rosbags.rosbag2 import StoragePlugin

    return StoragePlugin.MCAP


def _make_writer_class():
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.rosbag2.metadata import dump_qos_v9
    from rosbags.interfaces import ConnectionExtRosbag2
    class LiveWriter(Writer):
        """rosbags' rosbag2 writer (MCAP, version 9) whose bag is complete after every checkpoint."""

        STORAGE_PLUGINS = {StoragePlugin.MCAP: _LiveMcap}

        def _qos_text(self, connection) -> str:
            """The connection's offered QoS profiles as rosbag2 writes them (fixed per connection:
            dumped once, not at every checkpoint)."""
            cache = self.__dict__.setdefault("_qos_texts", {})
            if connection.id not in cache:
                cache[connection.id] = dump_qos_v9(connection.ext.offered_qos_profiles)
            return cache[connection.id]

        def _metadata(self) -> dict:
            storage = self.storage
            count = sum(storage.channel_stats.values())  # messages on disk only
            start = storage.message_start_time if count else 0
            duration = max(0, storage.message_end_time - storage.message_start_time) if count else 0
            return {
                "version": self.version,
                "storage_identifier": "mcap",
                "relative_file_paths": [storage.path.name],
                "duration": {"nanoseconds": duration},
                "starting_time": {"nanoseconds_since_epoch": start},
                "message_count": count,
                "topics_with_message_count": [
                    {"topic_metadata": {"name": c.topic, "type": c.msgtype,
                                        "serialization_format": c.ext.serialization_format,
                                        "offered_qos_profiles": self._qos_text(c),
                                        "type_description_hash": c.digest},
                     "message_count": storage.channel_stats.get(c.id, 0)}
                    for c in self.connections if isinstance(c.ext, ConnectionExtRosbag2)],
                "compression_format": "",
                "compression_mode": "",
                "files": [{"path": storage.path.name, "starting_time": {"nanoseconds_since_epoch": start},
                           "duration": {"nanoseconds": duration}, "message_count": count}],
                "custom_data": self.custom_data or None,
                "ros_distro": "jazzy",
            }

        def _dump(self, data) -> str:
            import yaml  # PyYAML with libyaml: ~100x faster than ruamel for this document

            dumper = getattr(yaml, "CSafeDumper", yaml.SafeDumper)
            return yaml.dump(data, Dumper=dumper, default_flow_style=False, sort_keys=True)

        def _write_metadata_yaml(self, text: str) -> None:
            """metadata.yaml, atomically: ``rosbag2_bagfile_information:`` and ``text`` (the
            information's block mapping, as the MCAP file embeds it) indented under it."""
            tmp = self.metapath.with_name(".metadata.yaml.tmp")
            body = "".join(f"  {line}" if line else line for line in text.splitlines(keepends=True))
            with open(tmp, "w", encoding="utf8") as f:
                f.write(f"rosbag2_bagfile_information:\n{body}\n")
            os.replace(tmp, self.metapath)

        def _write(self, storage_call) -> None:
            """Checkpoint or close the storage, then metadata.yaml (atomically) describing exactly
            what the MCAP file now holds (one YAML dump for both: the recorder checkpoints every
            flush_period_s, and the dump was most of its CPU)."""
            text: list[str] = []

            def metadata() -> str:  # called by the storage once the pending chunk is counted
                text.append(self._dump(self._metadata()).strip())
                return text[-1]

            storage_call(metadata)
            self._write_metadata_yaml(text[-1] if text else self._dump(self._metadata()).strip())

        def checkpoint(self) -> None:
            """Pending messages to disk, then metadata.yaml describing exactly them."""
            assert self.storage is not None
            self._write(self.storage.checkpoint)

        def close(self) -> None:
            assert self.storage is not None
            self._write(lambda metadata: self.storage.close(self.version, metadata))
            self.storage = None

    return LiveWriter


# -- the recorder ------------------------------------------------------------------------------------

class BagRecorder:
    """Write topics to a rosbag2 MCAP bag that stays readable at every flush. Thread-safe.

    ``path`` is the bag directory (it must not exist). Use as a context manager or call close().
    ``flush_period_s`` [s, wall time]: the most a SIGKILL of this process can lose (0 writes every
    message through at once, which costs a chunk per message). ``close_on_signals``: install
    SIGINT/SIGTERM handlers that close the bag (for scripts; a ROS node closes it itself).
    """

    def __init__(self, path: str | pathlib.Path, *, storage: str = "mcap", close_on_signals: bool = True,
                 flush_period_s: float = 0.5, custom_data: dict[str, str] | None = None):
        self.path = pathlib.Path(path)
        if self.path.exists():
            raise SpecError("bag.path", f"{self.path} already exists; choose a new bag directory")
        if storage != "mcap":
            raise SpecError("bag.storage", f"must be one of ['mcap'], got {storage!r}")
        if not (flush_period_s >= 0.0):
            raise SpecError("bag.flush_period_s", f"must be a number >= 0 [s], got {flush_period_s!r}")
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.flush_period_s = float(flush_period_s)
        self._last_flush = time.monotonic()
        self._typestore = make_typestore()
        self._writer = _make_writer_class()(self.path, version=9, storage_plugin=_mcap_plugin())
        for key, value in (custom_data or {}).items():
            self._writer.set_custom_data(str(key), str(value))
        self._writer.open()
        self._connections: dict[tuple[str, str], Any] = {}
        self._lock = threading.Lock()
        self.count = 0
        self.flushes = 0
        self._dirty = False
        self._closed = False
        self._writer.checkpoint()  # metadata.yaml and a complete (empty) MCAP file from the start
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

    @property
    def closed(self) -> bool:
        return self._closed

    def topics(self) -> dict[str, str]:
        """topic -> msgtype of every topic added so far."""
        with self._lock:
            return {topic: msgtype for topic, msgtype in self._connections}

    def add_topic(self, topic: str, msgtype: str, qos: Sequence[Any] = ()) -> None:
        """Declare a topic with the QoS profiles its publishers offer (rosbags Qos, see
        :func:`qos_profile`). Its definition is registered at once (SpecError if unknown). A topic
        written without being added gets no QoS."""
        with self._lock:
            self._check_open()
            self._connection(topic, msgtype, qos)
            self._dirty = True

    def _check_open(self) -> None:
        if self._closed:
            raise SpecError("bag", f"{self.path} is closed")

    def _connection(self, topic: str, msgtype: str, qos: Sequence[Any] = ()):
        key = (topic, msgtype)
        conn = self._connections.get(key)
        if conn is None:
            try:
                ensure_type(self._typestore, msgtype)
                conn = self._writer.add_connection(topic, msgtype, typestore=self._typestore,
                                                   offered_qos_profiles=list(qos))
            except SpecError as exc:
                raise SpecError("bag.msgtype", f"topic {topic!r}: {exc}") from None
            except Exception as exc:  # rosbags' TypesysError / WriterError
                raise SpecError("bag.msgtype", f"topic {topic!r}, type {msgtype!r}: {exc}") from None
            self._connections[key] = conn
        return conn

    def write_raw(self, topic: str, msgtype: str, data: bytes | memoryview, stamp_ns: int) -> None:
        """Record CDR bytes (as rclpy hands them to a ``raw=True`` subscription)."""
        with self._lock:
            self._check_open()
            self._writer.write(self._connection(topic, msgtype), int(stamp_ns), data)
            self.count += 1
            self._dirty = True
            if (time.monotonic() - self._last_flush >= self.flush_period_s
                    or self._writer.storage.pending_bytes > CHUNK_LIMIT_BYTES):
                self._flush_locked()

    def flush(self) -> None:
        """Write everything recorded so far to the file (it then survives a SIGKILL); a no-op when
        nothing changed since the last flush."""
        with self._lock:
            if not self._closed and self._dirty:
                self._flush_locked()

    def _flush_locked(self) -> None:
        self._last_flush = time.monotonic()
        self._writer.checkpoint()
        self._dirty = False
        self.flushes += 1

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


# -- reading -----------------------------------------------------------------------------------------

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


@dataclass(frozen=True)
class TopicInfo:
    topic: str
    msgtype: str
    count: int
    qos: list  # rosbags Qos of the publishers when recorded


def bag_topics(path: str | pathlib.Path) -> dict[str, TopicInfo]:
    """topic -> TopicInfo (type, message count, offered QoS) from a bag's metadata."""
    from rosbags.rosbag2 import Reader

    with Reader(pathlib.Path(path)) as reader:
        return {c.topic: TopicInfo(c.topic, c.msgtype, c.msgcount, list(c.ext.offered_qos_profiles))
                for c in reader.connections}


def _mcap_file(path: pathlib.Path) -> pathlib.Path | None:
    files = sorted(path.glob("*.mcap")) if path.is_dir() else []
    return files[0] if files else None


def _readable(path: pathlib.Path) -> bool:
    """rosbags opens the bag as is."""
    from rosbags.rosbag2 import Reader

    if not (path / "metadata.yaml").is_file():
        return False
    try:
        with Reader(path):
            return True
    except Exception:
        return False


def _scan_unclosed(mcap_file: pathlib.Path) -> tuple[list[tuple[str, str, int, bytes]], str]:
    """(topic, msgtype, stamp_ns, data) of every complete message of an MCAP file read record by
    record (a file cut by a kill), in time order, and why the scan stopped ('' at a clean end)."""
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
    """Rewrite a bag that standard readers cannot open (a recorder killed before this module kept
    bags complete: no metadata.yaml, no MCAP summary) as a complete rosbag2 bag at the same path;
    returns the number of messages recovered. A readable bag is left alone (returns its count)."""
    path = pathlib.Path(path)
    if _readable(path):
        return sum(1 for _ in read_bag(path))
    mcap_file = _mcap_file(path)
    if mcap_file is None:
        raise SpecError("bag.path", f"{path} is not a bag directory (no metadata.yaml, no .mcap file)")
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
    """Iterate over a rosbag2 bag's messages in time order. A bag standard readers cannot open (an
    old recorder killed mid-run) is read record by record; :func:`recover_bag` repairs it."""
    from rosbags.rosbag2 import Reader

    path = pathlib.Path(path)
    if not _readable(path):
        mcap_file = _mcap_file(path)
        if mcap_file is None:
            raise SpecError("bag.path", f"{path} is not a bag directory (no metadata.yaml, no .mcap file)")
        messages, _ = _scan_unclosed(mcap_file)
        for topic, msgtype, stamp, data in messages:
            if topics is None or topic in topics:
                yield BagMessage(topic, msgtype, stamp, data)
        return
    with Reader(path) as reader:
        connections = [c for c in reader.connections if topics is None or c.topic in topics]
        if not connections:
            return
        for conn, stamp, data in reader.messages(connections=connections):
            yield BagMessage(conn.topic, conn.msgtype, int(stamp), bytes(data))
