"""Where a sole actually rests on a round rung, read from the ankle's F/T sensor.

A foot on a cylinder touches it along a line (the rung's top line under the sole). The plan puts
that line where the nominal rung is; a rung moved horizontally (the papers' rung errors along x)
still stops the foot's guarded descent at the same height, so the approach cannot see it, but the
line is then elsewhere under the sole. The QP, holding the foot with forces on the planned line,
computes ankle torques for the wrong lever arm and the foot rolls over the rung (measured on G1,
rung 2 moved 2 cm along the sole: the foot pitched 0.5 rad within 0.15 s of loading and the climb
fell).

A line contact exerts no moment about its own axis at any point of the line. With the sensor's
wrench ``(F, M)`` (the distal body's weight removed) and the planned line through ``r0`` with axis
``u`` and the sole's forward direction ``d`` (both in the sensor frame), the line through
``r0 + s d`` satisfies ``(M - (r0 + s d) x F) . u = 0``, so ``s = a / b`` with
``a = (M - r0 x F) . u`` and ``b = (d x F) . u``. :class:`LineContactLocator` fits ``s`` by least
squares over windows of ``samples`` readings whose normal force exceeds ``locate_force`` (from
the contact's engage ramp on), for ``track_s``: a foot that rolled before the first estimate rolls
on the rung, and its line moves under the sole by the rung's radius times the angle. Each
estimate moves the contact's points by ``s d`` and turns its normals with the sole (on a cylinder
the normal at the line is the sole's).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Mapping

import numpy as np
import pinocchio as pin

GRAVITY = np.array([0.0, 0.0, -9.81])  # [m/s^2] world


@dataclass
class _Pending:
    sensor: str
    sensor_fid: int
    limb_fid: int
    r0: np.ndarray  # (3,) planned line centre, sensor frame [m]
    u: np.ndarray  # (3,) line axis, sensor frame
    d: np.ndarray  # (3,) sole forward across the line, sensor frame
    n_sensor: np.ndarray  # (3,) contact normal (toward the robot) at the start, sensor frame
    a: list[float] = field(default_factory=list)
    b: list[float] = field(default_factory=list)
    since: float | None = None  # [s] first counted reading
    total: float = 0.0  # [m] shift applied so far


@dataclass(frozen=True)
class LineEstimate:
    limb: str
    shift: float  # [m] along the sole's forward axis, across the rung
    shift_in_frame: np.ndarray  # (3,) [m] limb frame
    samples: int
    residual: float  # [N m] rms of the moment about the fitted line's axis
    normal_world: np.ndarray  # (3,) the sole's normal now (the contact normal at the line)
    total: float  # [m] shift since the planned line, this one included


class LineContactLocator:
    """Locates line contacts (soles on round rungs) from F/T, one placement at a time per limb.

    ``sensors``: limb -> (sensor name, sensor frame id); ``params``: the controller's
    LineContactParams (locate_force, samples, max_shift)."""

    def __init__(self, model: pin.Model, sensors: Mapping[str, tuple[str, int]], params):
        self.params = params
        self.sensors = dict(sensors)
        self._pending: dict[str, _Pending] = {}
        # the body below each sensor (the foot): its weight is part of the reading
        self._distal: dict[str, tuple[float, np.ndarray]] = {}
        for sensor, fid in {s: f for s, f in self.sensors.values()}.items():
            frame = model.frames[fid]
            inertia = model.inertias[frame.parentJoint]
            self._distal[sensor] = (float(inertia.mass), frame.placement.inverse().act(inertia.lever))

    @property
    def pending(self) -> tuple[str, ...]:
        return tuple(self._pending)

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
        self._pending[limb] = _Pending(sensor, sensor_fid, limb_fid, pts.mean(axis=0), u, d / np.linalg.norm(d),
                                       oMf[sensor_fid].rotation.T @ n)
        return True

    def cancel(self, limb: str) -> None:
        self._pending.pop(limb, None)

    def update(self, now: float, oMf, ft: Mapping[str, np.ndarray]) -> list[LineEstimate]:
        """One tick's readings; the estimates completed on it (moves of at least ``min_shift``)."""
        done = []
        p = self.params
        for limb, job in list(self._pending.items()):
            if job.since is not None and now - job.since > p.track_s:
                del self._pending[limb]
                continue
            wrench = ft.get(job.sensor)
            if wrench is None:
                continue
            R = oMf[job.sensor_fid].rotation
            mass, com = self._distal[job.sensor]
            g = mass * (R.T @ GRAVITY)  # the distal body's weight, sensor frame [N]
            force = np.asarray(wrench[:3], float) - g
            moment = np.asarray(wrench[3:6], float) - np.cross(com, g)
            if float(force @ job.n_sensor) < p.locate_force:
                continue
            if job.since is None:
                job.since = now
            job.a.append(float((moment - np.cross(job.r0, force)) @ job.u))
            job.b.append(float(np.cross(job.d, force) @ job.u))
            if len(job.a) < p.samples:
                continue
            a, b = np.asarray(job.a), np.asarray(job.b)
            job.a, job.b = [], []
            s = float(a @ b / (b @ b))
            s = float(np.clip(job.total + s, -p.max_shift, p.max_shift)) - job.total
            if abs(s) < p.min_shift:
                continue
            residual = float(np.sqrt(np.mean((a - s * b) ** 2)))
            job.r0 = job.r0 + s * job.d
            job.total += s
            T_limb_sensor = oMf[job.limb_fid].inverse() * oMf[job.sensor_fid]
            done.append(LineEstimate(limb, s, T_limb_sensor.rotation @ (s * job.d), len(a), residual,
                                     R @ job.n_sensor, job.total))
        return done
