"""Impact detection from the robot's own sensors (no simulator truth).

An object hitting the robot shows within a tick or two in two places the controller reads anyway:

- the limbs' F/T sensors: the contact forces jump. :meth:`FtMonitor.jump` (the 10 ms filtered
  force against the 200 ms one) stays small through a contact's force ramp or a guarded
  placement and leaps on a blow; the threshold is ``impact.force_jump`` or ``impact.noise_sigmas``
  standard deviations of the sensor's estimated noise, whichever is larger;
- the joint velocities: a joint's velocity changes by more than the last QP's acceleration
  explains over one control period (``impact.joint_velocity_jump``).

:class:`ImpactMonitor` keeps the peaks of both indicators (``peaks``) so that a climb's log says
how close the nominal motion came to the thresholds. The controller fires the FSM's ``impact``
event on a detection; the ``brace`` state does the rest (fsm.py).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .ft_monitor import FtMonitor


@dataclass
class Impact:
    time: float  # [s]
    source: str  # "ft:<limb>" | "joint:<index>"
    value: float  # [N] force jump | [rad/s] unexplained velocity change
    threshold: float  # [N] | [rad/s]


@dataclass
class ImpactPeaks:
    force_ratio: float = 0.0  # [-] largest force jump / its threshold
    joint_velocity_jump: float = 0.0  # [rad/s] largest unexplained velocity change
    by_limb: dict = field(default_factory=dict)  # limb -> [N] largest force jump


class ImpactMonitor:
    def __init__(self, params, control_period_s: float):
        """``params``: the controller's ImpactParams."""
        self.params = params
        self.period = control_period_s
        self.peaks = ImpactPeaks()
        self._v_prev: np.ndarray | None = None
        self._quiet_until = -np.inf  # [s] no detection before (brace cooldown)

    def mute_until(self, t: float) -> None:
        self._quiet_until = max(self._quiet_until, t)

    def quiet(self, time: float) -> bool:
        """Muted at ``time`` (start-up, a brace's or an unbraced impact's cooldown)."""
        return time < self._quiet_until

    def update(self, time: float, ft: FtMonitor, v_joints: np.ndarray, qdd_joints: np.ndarray | None,
               watch_ft: bool = True) -> Impact | None:
        """One tick; the first indicator over its threshold, or None. ``qdd_joints``: the last
        QP's joint accelerations [rad/s^2] (None: unknown, the joint indicator skips the tick);
        ``watch_ft``: False while contacts are being made or released in a way that may jump."""
        p = self.params
        found: Impact | None = None
        for limb, _sensor, _fid in ft.limbs:
            jump = ft.jump(limb)
            threshold = max(p.force_jump, p.noise_sigmas * ft.noise_std(limb))
            ratio = jump / threshold if threshold > 0 else 0.0
            if jump > self.peaks.by_limb.get(limb, 0.0):
                self.peaks.by_limb[limb] = jump
            if watch_ft:
                self.peaks.force_ratio = max(self.peaks.force_ratio, ratio)
                if found is None and ratio > 1.0:
                    found = Impact(time, f"ft:{limb}", jump, threshold)
        v = np.asarray(v_joints, float)
        if self._v_prev is not None and qdd_joints is not None and p.joint_velocity_jump > 0:
            residual = np.abs(v - self._v_prev - np.asarray(qdd_joints, float) * self.period)
            j = int(np.argmax(residual))
            self.peaks.joint_velocity_jump = max(self.peaks.joint_velocity_jump, float(residual[j]))
            if found is None and residual[j] > p.joint_velocity_jump:
                found = Impact(time, f"joint:{j}", float(residual[j]), p.joint_velocity_jump)
        self._v_prev = v.copy()
        if not p.enabled or time < self._quiet_until:
            return None
        return found


__all__ = ["Impact", "ImpactMonitor", "ImpactPeaks"]
