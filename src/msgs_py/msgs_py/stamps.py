"""float seconds <-> builtin_interfaces Time / Duration, and std_msgs Header.

Time -> seconds -> Time is the identity for |t| < 4e6 s (a float64 then resolves well below
0.5 ns), so a node may echo a state stamp through float seconds (lock-step matching is exact).
"""
from __future__ import annotations

import math

from builtin_interfaces.msg import Duration, Time
from std_msgs.msg import Header

from climb_core.errors import SpecError

from ._check import finite_float

_NS_PER_S = 1_000_000_000
_INT32_MIN, _INT32_MAX = -(2**31), 2**31 - 1

#: Frame of every world-frame message of the project (plans, holds, base truth).
WORLD_FRAME = "world"


def _split(seconds: float, field: str) -> tuple[int, int]:
    t = finite_float(seconds, field)
    sec = math.floor(t)
    nanosec = round((t - sec) * _NS_PER_S)
    if nanosec >= _NS_PER_S:  # rounding carried into the next second
        sec, nanosec = sec + 1, nanosec - _NS_PER_S
    if not _INT32_MIN <= sec <= _INT32_MAX:
        raise SpecError(field, f"must fit builtin_interfaces int32 seconds, got {t} s")
    return sec, nanosec


def seconds_to_time(seconds: float, field: str = "stamp") -> Time:
    """[s] -> Time (sec = floor(t), nanosec in [0, 1e9))."""
    sec, nanosec = _split(seconds, field)
    return Time(sec=sec, nanosec=nanosec)


def time_to_seconds(msg: Time) -> float:
    """Time -> [s]."""
    return msg.sec + msg.nanosec * 1e-9


def quantize_seconds(seconds: float, field: str = "stamp") -> float:
    """``seconds`` rounded to the nanosecond grid of a Time (what survives a message)."""
    return time_to_seconds(seconds_to_time(seconds, field))


def seconds_to_duration(seconds: float, field: str = "duration") -> Duration:
    sec, nanosec = _split(seconds, field)
    return Duration(sec=sec, nanosec=nanosec)


def duration_to_seconds(msg: Duration) -> float:
    return msg.sec + msg.nanosec * 1e-9


def make_header(stamp: float = 0.0, frame_id: str = "") -> Header:
    """Header stamped ``stamp`` [s] in ``frame_id``."""
    return Header(stamp=seconds_to_time(stamp, "header.stamp"), frame_id=frame_id)


def header_stamp(msg: Header) -> float:
    """A header's stamp [s]."""
    return time_to_seconds(msg.stamp)
