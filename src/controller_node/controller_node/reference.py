"""Time-parameterised references along a transition's way-points.

A transition path is a list of Pinocchio configurations with times. :class:`PathReference`
samples it with a minimum-jerk time scaling over the whole duration (start and end at rest) and a
cubic Hermite (Catmull-Rom) curve through the way-points in the tangent space of each segment's
start (``pin.difference`` / ``pin.integrate``): the reference velocity is continuous across
way-points (a piecewise-geodesic path turns its velocity abruptly at every corner, and a 150 1/s^2
contact-body task turned such a corner into a 30 m/s^2 hand acceleration). It also blends out the
offset between the robot's actual state when the path starts and the path's first way-point,
``(1 - s(t)) * offset``, so tracking starts without a jump and ends on the plan.
"""
from __future__ import annotations

import bisect

import numpy as np
import pinocchio as pin


def min_jerk(u: float) -> tuple[float, float]:
    """s(u) and ds/du of the minimum-jerk profile on u in [0, 1]."""
    u = min(max(u, 0.0), 1.0)
    s = u ** 3 * (10.0 - 15.0 * u + 6.0 * u * u)
    ds = 30.0 * u * u * (1.0 - u) ** 2
    return s, ds


class PathReference:
    """q_ref(t) and v_ref(t) along way-points ``path`` (n, nq) at ``times`` (n,) [s]."""

    def __init__(self, model: pin.Model, times: np.ndarray, path: np.ndarray, min_duration: float = 0.5):
        self.model = model
        path = np.asarray(path, dtype=float).reshape(-1, model.nq)
        times = np.asarray(times, dtype=float).reshape(-1)
        if len(path) == 0:
            raise ValueError("empty path")
        if len(times) != len(path):
            times = np.linspace(0.0, max(min_duration, 0.0), len(path))
        times = times - times[0]
        if np.any(np.diff(times) < 0):
            raise ValueError("way-point times must not decrease")
        self.path = path
        self.times = times
        self.duration = max(float(times[-1]), min_duration)  # [s]
        # path-axis times rescaled onto [0, 1]
        self._u = times / times[-1] if times[-1] > 0 else np.linspace(0.0, 1.0, len(path))
        self._u_list = self._u.tolist()  # bisect on floats: np.searchsorted costs ~3 us a call
        # chords between consecutive way-points (tangent space of the first): sampled every tick
        self._chords = np.array([pin.difference(model, a, b) for a, b in zip(path[:-1], path[1:])]).reshape(-1, model.nv)
        self._tangents = self._catmull_rom_tangents()

    def _catmull_rom_tangents(self) -> np.ndarray:
        """dq/du (n, nv) at every way-point: central differences of the neighbours (zero at the
        ends and across repeated way-points, where the path rests)."""
        n, nv = len(self.path), self.model.nv
        m = np.zeros((n, nv))
        for k in range(1, n - 1):
            du = self._u[k + 1] - self._u[k - 1]
            if du > 0 and self._u[k + 1] > self._u[k] > self._u[k - 1]:
                m[k] = pin.difference(self.model, self.path[k - 1], self.path[k + 1]) / du
        return m

    def _segment(self, s: float) -> tuple[int, float, float]:
        """(way-point index k, position a in [0, 1] on segment k, segment length in u)."""
        u = self._u_list
        k = bisect.bisect_right(u, s) - 1  # == np.searchsorted(u, s, side="right") - 1
        k = min(max(k, 0), len(u) - 2)
        span = u[k + 1] - u[k]
        a = 0.0 if span <= 0 else min(max((s - u[k]) / span, 0.0), 1.0)
        return k, a, span

    def _local(self, k: int, a: float, span: float) -> tuple[np.ndarray, np.ndarray]:
        """Hermite offset from way-point k (tangent space at path[k]) and its derivative along u."""
        a2, a3 = a * a, a * a * a
        h10, h01, h11 = a3 - 2.0 * a2 + a, -2.0 * a3 + 3.0 * a2, a3 - a2
        d10, d01, d11 = 3.0 * a2 - 4.0 * a + 1.0, -6.0 * a2 + 6.0 * a, 3.0 * a2 - 2.0 * a
        chord = self._chords[k]
        m0, m1 = self._tangents[k], self._tangents[k + 1]
        local = h01 * chord + span * (h10 * m0 + h11 * m1)
        d_local_du = (d01 * chord) / span + d10 * m0 + d11 * m1
        return local, d_local_du

    def _at(self, s: float) -> np.ndarray:
        if len(self.path) == 1:
            return self.path[0].copy()
        k, a, span = self._segment(s)
        if span <= 0:
            return self.path[k + 1].copy()
        local, _ = self._local(k, a, span)
        return pin.integrate(self.model, self.path[k], local)

    def progress(self, t: float) -> tuple[float, float]:
        """Min-jerk progress s in [0, 1] and ds/dt [1/s] at time t from the start."""
        s, ds = min_jerk(t / self.duration)
        return s, ds / self.duration

    def sample(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """q_ref (nq,) and v_ref (nv,) at t [s]; v = dq/du * du/dt, the Hermite derivative mapped
        to the tangent space at q_ref (``pin.dIntegrate``, applied by ``dIntegrateTransport``)."""
        s, sdot = self.progress(t)
        if len(self.path) == 1:
            return self.path[0].copy(), np.zeros(self.model.nv)
        k, a, span = self._segment(s)
        if span <= 0:
            return self.path[k + 1].copy(), np.zeros(self.model.nv)
        local, d_local = self._local(k, a, span)
        q = pin.integrate(self.model, self.path[k], local)
        if sdot <= 0.0:
            return q, np.zeros(self.model.nv)
        # dIntegrate(ARG1) @ (dq/du du/dt) without forming the (nv, nv) Jacobian
        return q, pin.dIntegrateTransport(self.model, self.path[k], local, d_local * sdot,
                                          pin.ArgumentPosition.ARG1)

    @property
    def last_segment_start(self) -> float:
        """Progress s at which the last way-point segment (the approach) begins."""
        return self._u_list[-2] if len(self._u_list) >= 2 else 0.0

    @property
    def start(self) -> np.ndarray:
        return self.path[0]

    @property
    def end(self) -> np.ndarray:
        return self.path[-1]
