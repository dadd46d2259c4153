"""Where a sole actually rests on a round rung, read from the ankle's F/T sensor.

A foot on a cylinder touches it along a line (the rung's top line under the sole). The plan puts
that line where the nominal rung is; a rung moved horizontally (the papers' rung errors along x)
still stops the foot's guarded descent at the same height, so the approach cannot see it, but the
line is then elsewhere under the sole. The QP, holding the foot with forces on the planned line,
computes ankle torques for the wrong lever arm and the foot rolls over the rung (measured on G1,
rung 2 moved 2 cm along the sole: the foot pitched 0.5 rad within 0.15 s of loading and the climb
fell).

A line contact exerts no moment about its own axis at any point of the line. With the sensor's
wrench ``(F, M)`` (the distal body's weight and the sensor's bias removed) and the planned line
through ``r0`` with axis ``u`` and the sole's forward direction ``d`` (both in the sensor frame),
the line through ``r0 + s d`` satisfies ``(M - (r0 + s d) x F) . u = 0``, so per reading
``a = s b`` with ``a = (M - r0 x F) . u`` and ``b = (d x F) . u``.

:class:`LineContactLocator` fits ``s`` by least squares over the readings whose normal force
exceeds ``locate_force``, from the contact's engage ramp on, while the contact lasts (or ``track_s``), older readings fading
with ``fit_time_constant_s`` (the first ones, taken while the foot loads and rolls, would hold the
fit back: measured 1.5 cm found for a 2 cm error without the fading). An estimate is acted
on when it differs from the line in use by ``min_shift`` and by ``significance`` standard errors
of the fit: noisy sensors move the line only once the readings say so (with 0.5 % F/T noise a
window of three readings scatters by ~5 mm, and acting on each window walked a nominal foot's
line 2 cm off in 0.5 s, measured). The bias is the free limb's reading before the contact (its
weight known): its last readings in the air (:meth:`observe`) averaged when its approach begins
(:meth:`tare`, with the F/T monitor's tare: a creeping foot may press on the rung for a few
hundred milliseconds before the contact is confirmed), taken out of every reading of the fit.
"""
from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from typing import Iterable, Mapping

import numpy as np
import pinocchio as pin

GRAVITY = np.array([0.0, 0.0, -9.81])  # [m/s^2] world
BIAS_READINGS = 60  # the free limb's last readings averaged at the tare (0.3 s at 200 Hz)


def _cross(a, b) -> tuple[float, float, float]:
    """a x b of two 3-sequences (np.cross costs ~10 us on 3-vectors)."""
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


@dataclass
class _Pending:
    """One placement being located. The vectors are tuples of Python floats (sensor frame): the
    per-tick arithmetic on them costs ~5x less than on numpy scalars."""

    sensor: str
    sensor_fid: int
    limb_fid: int
    r0: tuple  # (3,) planned line centre [m]
    u: tuple  # (3,) line axis
    d: tuple  # (3,) sole forward across the line
    n: tuple  # (3,) contact normal (toward the robot) at the start
    bias: tuple  # (6,) the sensor's reading of nothing (free limb, weight removed) [N, N m]
    since: float | None = None  # [s] first counted reading
    count: int = 0  # readings counted
    n_eff: float = 0.0  # their weight in the fit (older readings fade)
    sab: float = 0.0
    sbb: float = 0.0
    saa: float = 0.0
    applied: float = 0.0  # [m] shift in use (moved so far)


@dataclass(frozen=True)
class LineEstimate:
    limb: str
    shift: float  # [m] this move, along the sole's forward axis, across the rung
    shift_in_frame: np.ndarray  # (3,) [m] limb frame
    samples: int
    std: float  # [m] standard error of the fitted line position
    normal_world: np.ndarray  # (3,) the sole's normal now (the contact normal at the line)
    total: float  # [m] the line's distance from the planned one along the sole (this move included)


class LineContactLocator:
    """Locates line contacts (soles on round rungs) from F/T, one placement at a time per limb.

    ``sensors``: limb -> (sensor name, sensor frame id); ``params``: the controller's
    LineContactParams; ``period``: the control period [s] (the step of the fit's fading)."""

    def __init__(self, model: pin.Model, sensors: Mapping[str, tuple[str, int]], params, period: float = 0.005):
        self.params = params
        self.sensors = dict(sensors)
        self._pending: dict[str, _Pending] = {}
        self._free: dict[str, deque] = {limb: deque(maxlen=BIAS_READINGS) for limb in self.sensors}
        self._bias: dict[str, np.ndarray] = {}  # limb -> the free readings' mean at the approach's tare
        # each reading's weight in the fit decays by this per period (fit_time_constant_s)
        self._fade = math.exp(-period / params.fit_time_constant_s) if params.fit_time_constant_s > 0 else 1.0
        # the body below each sensor (the foot): its weight is part of the reading
        self._distal: dict[str, tuple[float, np.ndarray]] = {}
        for sensor, fid in {s: f for s, f in self.sensors.values()}.items():
            frame = model.frames[fid]
            inertia = model.inertias[frame.parentJoint]
            self._distal[sensor] = (float(inertia.mass), frame.placement.inverse().act(inertia.lever))
        self._distal_f = {sensor: (mass, tuple(com.tolist())) for sensor, (mass, com) in self._distal.items()}

    @property
    def pending(self) -> tuple[str, ...]:
        return tuple(self._pending)

    def _unloaded(self, sensor: str, sensor_fid: int, oMf, wrench) -> np.ndarray:
        """The reading with the distal body's weight taken out (6,), sensor frame."""
        mass, com = self._distal[sensor]
        g = mass * (oMf[sensor_fid].rotation.T @ GRAVITY)
        out = np.array(wrench[:6], dtype=float)
        out[:3] -= g
        out[3:] -= np.cross(com, g)
        return out

    def observe(self, ft: Mapping[str, np.ndarray], free: Iterable[str]) -> None:
        """Keep the last readings of the ``free`` limbs (in the air, no contact): the sensor's bias."""
        for limb in free:
            entry = self.sensors.get(limb)
            wrench = ft.get(entry[0]) if entry is not None else None
            if wrench is not None:
                self._free[limb].append(np.array(wrench[:6], dtype=float))

    def tare(self, limb: str, oMf) -> None:
        """The limb's approach begins (it is still in the air): its recent readings' mean, its
        weight at its pose now taken out, is the sensor's bias."""
        readings = self._free.get(limb)
        if readings:
            sensor, fid = self.sensors[limb]
            self._bias[limb] = self._unloaded(sensor, fid, oMf, np.mean(readings, axis=0))
            readings.clear()

    def start(self, limb: str, limb_fid: int, points_in_frame: np.ndarray, normal_world: np.ndarray,
              oMf) -> bool:
        """Begin locating ``limb``'s line (its 2+ contact points in the limb frame, on the line).
        False (nothing to do) without a sensor or a line."""
        if limb not in self.sensors or len(points_in_frame) < 2:
            return False
        sensor, sensor_fid = self.sensors[limb]
        T_sensor_limb = oMf[sensor_fid].inverse() * oMf[limb_fid]
        pts = np.array([T_sensor_limb.act(p) for p in points_in_frame])
        u = pts[-1] - pts[0]
        if np.linalg.norm(u) < 1e-6:
            return False
        u /= np.linalg.norm(u)
        x = T_sensor_limb.rotation[:, 0]  # the limb frame's forward axis (the sole's)
        d = x - u * float(u @ x)
        if np.linalg.norm(d) < 1e-6:
            return False
        n = np.asarray(normal_world, float) / np.linalg.norm(normal_world)
        bias = self._bias.pop(limb, np.zeros(6))
        self._pending[limb] = _Pending(
            sensor, sensor_fid, limb_fid, tuple(pts.mean(axis=0).tolist()), tuple(u.tolist()),
            tuple((d / np.linalg.norm(d)).tolist()), tuple((oMf[sensor_fid].rotation.T @ n).tolist()),
            tuple(np.asarray(bias, float).tolist()))
        return True

    def cancel(self, limb: str) -> None:
        self._pending.pop(limb, None)

    def update(self, now: float, oMf, ft: Mapping[str, np.ndarray]) -> list[LineEstimate]:
        """One tick's readings; the moves they call for (at most one per limb)."""
        done = []
        p = self.params
        for limb, job in list(self._pending.items()):
            if p.track_s > 0.0 and job.since is not None and now - job.since > p.track_s:
                del self._pending[limb]
                continue
            wrench = ft.get(job.sensor)
            if wrench is None:
                continue
            w = wrench.tolist() if isinstance(wrench, np.ndarray) else list(wrench)
            mass, com = self._distal_f[job.sensor]
            R = oMf[job.sensor_fid].rotation
            k = mass * GRAVITY[2]
            r2 = R[2].tolist()
            g = (k * r2[0], k * r2[1], k * r2[2])  # the distal body's weight, sensor frame [N]
            bias = job.bias
            force = (w[0] - g[0] - bias[0], w[1] - g[1] - bias[1], w[2] - g[2] - bias[2])
            c = _cross(com, g)
            mx, my, mz = w[3] - c[0] - bias[3], w[4] - c[1] - bias[4], w[5] - c[2] - bias[5]
            nx, ny, nz = job.n
            if force[0] * nx + force[1] * ny + force[2] * nz < p.locate_force:
                continue
            if job.since is None:
                job.since = now
            rx, ry, rz = _cross(job.r0, force)
            ux, uy, uz = job.u
            a = (mx - rx) * ux + (my - ry) * uy + (mz - rz) * uz
            dx, dy, dz = _cross(job.d, force)
            b = dx * ux + dy * uy + dz * uz
            fade = self._fade
            job.count += 1
            job.n_eff = fade * job.n_eff + 1.0
            job.sab = fade * job.sab + a * b
            job.sbb = fade * job.sbb + b * b
            job.saa = fade * job.saa + a * a
            if job.count < p.samples or job.sbb <= 0.0:
                continue
            s = job.sab / job.sbb
            dof = max(job.n_eff - 1.0, 1.0)
            residual = max(job.saa - 2.0 * s * job.sab + s * s * job.sbb, 0.0) / dof
            std = math.sqrt(residual / job.sbb)
            s = min(max(s, -p.max_shift), p.max_shift)
            move = s - job.applied
            # few readings estimate their own scatter poorly: a wider bound for them (~ Student's t)
            if abs(move) < max(p.min_shift, p.significance * std * (1.0 + 4.0 / dof)):
                continue
            job.applied = s
            T_limb_sensor = oMf[job.limb_fid].inverse() * oMf[job.sensor_fid]
            done.append(LineEstimate(limb, move, T_limb_sensor.rotation @ (move * np.array(job.d)), job.count,
                                     std, R @ np.array(job.n), s))
        return done
