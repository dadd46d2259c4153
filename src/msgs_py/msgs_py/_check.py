"""Small validators shared by the conversions; each raises SpecError(field, rule)."""
from __future__ import annotations

import math
from typing import Iterable

import numpy as np

from climb_core.errors import SpecError


def finite_float(value: object, field: str) -> float:
    """``value`` as a finite Python float."""
    try:
        out = float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        raise SpecError(field, f"must be a number, got {value!r}") from None
    if not math.isfinite(out):
        raise SpecError(field, f"must be finite, got {out}")
    return out


def finite_vector(value: object, field: str, length: int | None = None) -> np.ndarray:
    """``value`` as a 1-D float array, finite, of ``length`` entries when given."""
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise SpecError(field, "must be an array of numbers") from None
    if arr.ndim != 1:
        if length is None or arr.size != length:
            raise SpecError(field, f"must be 1-D, got shape {arr.shape}")
        arr = arr.reshape(length)  # a (3, 1) column is accepted as a (3,) vector
    if length is not None and arr.shape[0] != length:
        raise SpecError(field, f"must have {length} entries, got {arr.shape[0]}")
    bad = np.flatnonzero(~np.isfinite(arr))
    if bad.size:
        raise SpecError(f"{field}[{int(bad[0])}]", f"must be finite, got {arr[bad[0]]}")
    return arr


def one_of(value: str, choices: Iterable[str], field: str) -> str:
    choices = tuple(choices)
    if value not in choices:
        raise SpecError(field, f"must be one of {', '.join(choices)}; got {value!r}")
    return value


def non_negative_int(value: object, field: str) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise SpecError(field, f"must be an integer, got {value!r}")
    if value < 0:
        raise SpecError(field, f"must be >= 0, got {value}")
    return int(value)
