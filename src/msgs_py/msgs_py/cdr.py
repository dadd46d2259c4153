"""The lock-step hot path's messages as CDR bytes (no rclpy here).

rclpy converts every message between C and Python objects field by field: taking an Odometry
costs ~160 us, a WrenchStamped ~55 us, a JointState(29) ~60 us, and publishing one 20-40 us, while
the same bytes are taken / published raw in 5-12 us. The lock-step exchange moves ~9 such messages
per 5 ms tick, so the bridge and the controller read and write the state and command topics as
serialized bytes (``raw=True`` subscriptions, ``publish(bytes)``): the bytes on the wire are the
same, every other subscriber still gets ordinary messages.

Encoding: plain CDR (XCDR1), little endian (encapsulation ``00 01``), which rmw_fastrtps sends;
primitives are aligned to their size counted from the end of the 4-byte encapsulation header;
a string is a uint32 length (terminating NUL included) then the bytes; a sequence is a uint32
count then its elements; fixed arrays have no count. Anything else (another encapsulation)
raises :class:`CdrError`: the caller then falls back to rclpy's deserialization.

Writers are templates: the node serializes one complete message with rclpy (names, frames,
covariances filled in), :class:`Template` finds the offsets of the fields that change per tick
with the same reader, and each tick only the stamp and those numbers are written.
"""
from __future__ import annotations

import struct
from dataclasses import dataclass

import numpy as np

CDR_LE = b"\x00\x01"  # encapsulation: plain CDR, little endian
_HEADER = 4  # [B] encapsulation header; alignment counts from its end
_NS = 1_000_000_000
_U32 = struct.Struct("<I")
_STAMP = struct.Struct("<iI")  # builtin_interfaces/Time: int32 sec, uint32 nanosec


class CdrError(ValueError):
    """Bytes that are not a plain little-endian CDR message of the expected layout."""


class Reader:
    """Sequential reader: ``pos`` is an absolute offset into ``data``."""

    __slots__ = ("data", "pos")

    def __init__(self, data: bytes, pos: int = _HEADER) -> None:
        if data[:2] != CDR_LE:
            raise CdrError(f"encapsulation {bytes(data[:2]).hex()} is not plain little-endian CDR (0001)")
        self.data = data
        self.pos = pos

    def align(self, size: int) -> None:
        self.pos += -(self.pos - _HEADER) % size

    def u32(self) -> int:
        self.align(4)
        value = _U32.unpack_from(self.data, self.pos)[0]
        self.pos += 4
        return value

    def stamp_ns(self) -> int:
        self.align(4)
        sec, nanosec = _STAMP.unpack_from(self.data, self.pos)
        self.pos += 8
        return sec * _NS + nanosec

    def string(self) -> str:
        n = self.u32()
        end = self.pos + n
        if n == 0 or end > len(self.data):
            raise CdrError(f"string of length {n} at byte {self.pos - 4} overruns {len(self.data)} bytes")
        text = bytes(self.data[self.pos:end - 1]).decode("utf-8")
        self.pos = end
        return text

    def strings(self) -> list[str]:
        return [self.string() for _ in range(self.u32())]

    def octets(self) -> tuple[int, int]:
        """uint8[] / octet sequence: (offset, count)."""
        n = self.u32()
        offset = self.pos
        self.pos += n
        self._check()
        return offset, n

    def scalar(self, size: int) -> int:
        """Offset of a primitive of ``size`` bytes (aligned), skipped."""
        self.align(size)
        offset = self.pos
        self.pos += size
        self._check()
        return offset

    def doubles(self, count: int | None = None) -> tuple[int, int]:
        """float64[count] (fixed array) or float64[] (sequence, count None): (offset, count)."""
        if count is None:
            count = self.u32()
        self.align(8)
        offset = self.pos
        self.pos += 8 * count
        self._check()
        return offset, count

    def _check(self) -> None:
        if self.pos > len(self.data):
            raise CdrError(f"message truncated: needs {self.pos} bytes, has {len(self.data)}")


def _f64(data: bytes, span: tuple[int, int]) -> np.ndarray:
    """A float64 copy of ``span`` = (offset, count) of ``data``."""
    return np.frombuffer(data, dtype="<f8", count=span[1], offset=span[0]).copy()


# ------------------------------------------------------------------------------------- readers
def read_header(r: Reader) -> tuple[int, str]:
    """std_msgs/Header: (stamp [ns], frame_id)."""
    stamp = r.stamp_ns()
    return stamp, r.string()


@dataclass
class JointStateData:
    stamp_ns: int
    names: list[str]
    position: np.ndarray  # [rad]
    velocity: np.ndarray  # [rad/s]
    effort: np.ndarray  # [N m]


class _NamesCache:
    """A message's joint-name sequence (the same every tick) decoded once and reused while the
    bytes that encode it do not change."""

    def __init__(self) -> None:
        self._names_bytes = b""
        self._names: list[str] = []

    def _names_at(self, r: Reader, data: bytes) -> list[str]:
        start = r.pos
        cached = self._names_bytes
        if cached and data[start:start + len(cached)] == cached:
            r.pos = start + len(cached)
            return self._names
        names = r.strings()
        self._names_bytes, self._names = bytes(data[start:r.pos]), names
        return names


class JointStateReader(_NamesCache):
    """sensor_msgs/JointState; names cached (:class:`_NamesCache`)."""

    def read(self, data: bytes) -> JointStateData:
        r = Reader(data)
        stamp, _ = read_header(r)
        names = self._names_at(r, data)
        position, velocity, effort = r.doubles(), r.doubles(), r.doubles()
        return JointStateData(stamp, names, _f64(data, position), _f64(data, velocity), _f64(data, effort))


@dataclass
class OdometryData:
    stamp_ns: int
    pose: np.ndarray  # position [m] then quaternion xyzw
    twist: np.ndarray  # linear [m/s] then angular [rad/s], child frame


def read_odometry(data: bytes) -> OdometryData:
    """nav_msgs/Odometry (covariances skipped)."""
    r = Reader(data)
    stamp, _ = read_header(r)
    r.string()  # child_frame_id
    pose = r.doubles(7)
    r.doubles(36)
    twist = r.doubles(6)
    return OdometryData(stamp, _f64(data, pose), _f64(data, twist))


def read_wrench_stamped(data: bytes) -> tuple[int, np.ndarray]:
    """geometry_msgs/WrenchStamped: (stamp [ns], [fx, fy, fz, tx, ty, tz] [N, N m])."""
    r = Reader(data)
    stamp, _ = read_header(r)
    return stamp, _f64(data, r.doubles(6))


@dataclass
class ImuData:
    stamp_ns: int
    orientation_xyzw: np.ndarray
    angular_velocity: np.ndarray  # [rad/s]
    linear_acceleration: np.ndarray  # [m/s^2]


def read_imu(data: bytes) -> ImuData:
    r = Reader(data)
    stamp, _ = read_header(r)
    orientation = r.doubles(4)
    r.doubles(9)
    angular = r.doubles(3)
    r.doubles(9)
    linear = r.doubles(3)
    return ImuData(stamp, _f64(data, orientation), _f64(data, angular), _f64(data, linear))


@dataclass
class JointCommandData:
    stamp_ns: int
    names: list[str]
    modes: np.ndarray  # uint8 mode codes
    values: np.ndarray


class JointCommandReader(_NamesCache):
    """climb_msgs/JointCommand; names cached (:class:`_NamesCache`)."""

    def read(self, data: bytes) -> JointCommandData:
        r = Reader(data)
        stamp, _ = read_header(r)
        names = self._names_at(r, data)
        modes = r.octets()
        values = r.doubles()
        return JointCommandData(stamp, names,
                                np.frombuffer(data, dtype=np.uint8, count=modes[1], offset=modes[0]).copy(),
                                _f64(data, values))


# ------------------------------------------------------------------------------------- writers
class Template:
    """A serialized message whose stamp and float64 fields are rewritten in place.

    ``fields`` maps a name to the (offset, count) of a float64 run found by ``locate(reader)``;
    :meth:`field` returns a writable numpy view of it, :meth:`payload` the bytes to publish.
    """

    def __init__(self, data: bytes, locate) -> None:
        self.buffer = bytearray(data)
        r = Reader(bytes(data))
        self.fields: dict[str, tuple[int, int]] = locate(r)
        self._views = {name: np.frombuffer(self.buffer, dtype="<f8", count=n, offset=off)
                       for name, (off, n) in self.fields.items()}

    def field(self, name: str) -> np.ndarray:
        return self._views[name]

    def set_stamp(self, stamp_ns: int) -> None:
        """The leading builtin_interfaces/Time (header.stamp, or Clock.clock)."""
        _STAMP.pack_into(self.buffer, _HEADER, stamp_ns // _NS, stamp_ns % _NS)

    def payload(self) -> bytes:
        return bytes(self.buffer)


def locate_joint_state(r: Reader) -> dict[str, tuple[int, int]]:
    read_header(r)
    r.strings()
    return {"position": r.doubles(), "velocity": r.doubles(), "effort": r.doubles()}


def locate_wrench_stamped(r: Reader) -> dict[str, tuple[int, int]]:
    read_header(r)
    return {"wrench": r.doubles(6)}  # force xyz, torque xyz


def locate_imu(r: Reader) -> dict[str, tuple[int, int]]:
    read_header(r)
    orientation = r.doubles(4)
    r.doubles(9)
    angular = r.doubles(3)
    r.doubles(9)
    return {"orientation": orientation, "angular_velocity": angular, "linear_acceleration": r.doubles(3)}


def locate_odometry(r: Reader) -> dict[str, tuple[int, int]]:
    read_header(r)
    r.string()
    pose = r.doubles(7)
    r.doubles(36)
    return {"pose": pose, "twist": r.doubles(6)}


def locate_joint_command(r: Reader) -> dict[str, tuple[int, int]]:
    read_header(r)
    r.strings()
    r.octets()
    return {"values": r.doubles()}


def locate_clock(r: Reader) -> dict[str, tuple[int, int]]:
    r.stamp_ns()
    return {}


_U8 = struct.Struct("<B")


class ControllerStateWriter:
    """climb_msgs/ControllerState from templates, one per layout.

    Its strings (FSM state, mode, active contacts, task names, replan reason, offset surface)
    change only when the FSM or the contact set does, so each distinct set is serialized once by
    ``serialize(msg)`` (rclpy's own serialization) and reused: per tick the stamp, the transition
    index, the task errors, the QP status, the times, the counts and the surface offset are written
    in place."""

    _LIMIT = 256  # layouts kept (a run sees a few dozen)

    def __init__(self, message_type, serialize) -> None:
        self._type = message_type
        self._serialize = serialize
        self._layouts: dict[tuple, tuple[bytearray, dict[str, int], np.ndarray]] = {}

    def payload(self, stamp_ns: int, fsm_state: str, mode: str, transition_index: int,
                active_contacts: tuple[str, ...], task_names: tuple[str, ...], task_errors,
                qp_status: int, qp_solve_time_ms: float, tick_time_ms: float, qp_failures: int,
                replan_reason: str = "", offset_surface: str = "", surface_offset=(0.0, 0.0, 0.0),
                plans_taken: int = 0) -> bytes:
        key = (fsm_state, mode, tuple(active_contacts), tuple(task_names), replan_reason, offset_surface)
        layout = self._layouts.get(key)
        if layout is None:
            layout = self._layouts[key] = self._layout(key)
            if len(self._layouts) > self._LIMIT:
                self._layouts.pop(next(iter(self._layouts)))
        buffer, at, errors = layout
        _STAMP.pack_into(buffer, _HEADER, stamp_ns // _NS, stamp_ns % _NS)
        _U32.pack_into(buffer, at["transition_index"], transition_index)
        errors[:] = task_errors
        _U8.pack_into(buffer, at["qp_status"], qp_status)
        _F64_PAIR.pack_into(buffer, at["qp_solve_time_ms"], qp_solve_time_ms, tick_time_ms)
        _U32.pack_into(buffer, at["qp_failures"], qp_failures)
        _U32.pack_into(buffer, at["plans_taken"], plans_taken)
        _F64_TRIPLE.pack_into(buffer, at["surface_offset"], *surface_offset)
        return bytes(buffer)

    def _layout(self, key: tuple) -> tuple[bytearray, dict[str, int], np.ndarray]:
        fsm_state, mode, contacts, names, reason, surface = key
        msg = self._type(fsm_state=fsm_state, mode=mode, active_contacts=list(contacts), task_names=list(names),
                         replan_reason=reason, offset_surface=surface)
        msg.task_errors = [0.0] * len(names)
        buffer = bytearray(self._serialize(msg))
        r = Reader(bytes(buffer))
        read_header(r)
        r.string()
        r.string()
        at = {"transition_index": r.scalar(4)}
        r.strings()
        r.strings()
        errors_at, n = r.doubles()
        at["qp_status"] = r.scalar(1)
        at["qp_solve_time_ms"] = r.scalar(8)
        if r.scalar(8) != at["qp_solve_time_ms"] + 8:  # tick_time_ms right after: written as a pair
            raise CdrError("ControllerState: qp_solve_time_ms and tick_time_ms are not adjacent")
        at["qp_failures"] = r.scalar(4)
        at["plans_taken"] = r.scalar(4)
        r.string()
        r.string()
        at["surface_offset"] = r.doubles(3)[0]
        return buffer, at, np.frombuffer(buffer, dtype="<f8", count=n, offset=errors_at)


_F64_PAIR = struct.Struct("<dd")
_F64_TRIPLE = struct.Struct("<ddd")
