"""The limbs' force/torque sensors as the FSM's guarded moves read them.

One :class:`FtMonitor` per controller. Each tick :meth:`FtMonitor.update` takes the measured
wrenches (sensor axes) and the model's frame placements, and keeps per limb:

- the sensor force in world axes through a first-order filter (``guarded.filter_time_constant_s``);
- the force at the last tare (:meth:`tare`, taken when an approach begins), so that a guarded move
  reads the force change the contact made, not the limb's own weight or the sensor's bias;
- a second, slower filter of the same force (``guarded.confirm_time_constant_s``) that confirms
  a stalled search (a limb blocked short of its creeping target) against a noise floor lower than
  the fast threshold's;
- an online estimate of the sensor's white noise from the raw force's tick-to-tick differences
  (``guarded.noise_time_constant_s``), from which the contact threshold rises above
  ``guarded.force_threshold`` on a noisy sensor (``guarded.noise_sigmas``).

No ROS, no simulator: the controller (controller.py) owns one and answers the FSM's questions
(Context.tare_ft, ft_force_change, contact_threshold) through it.
"""
from __future__ import annotations

import math
from typing import Mapping, Sequence

import numpy as np
import pinocchio as pin

from climb_core.errors import SpecError


def ft_sensor_frames(model: pin.Model, sensor_joints: Mapping[str, str]) -> dict[str, int]:
    """sensor -> frame id of the sensor joint's child link (the frame its wrench is given in).
    A sensor on a fixed joint (TALOS's ``wrist_*_ft_joint``) is no Pinocchio joint but a
    FIXED_JOINT frame: its child link is the BODY frame that follows it. SpecError names a
    sensor whose joint the model has in neither form (its limb would sense nothing)."""
    out = {}
    for sensor, joint in sensor_joints.items():
        if model.existJointName(joint):
            jid = model.getJointId(joint)
            child = [fid for fid, f in enumerate(model.frames) if f.parentJoint == jid and f.type == pin.FrameType.BODY]
        elif model.existFrame(joint, pin.FrameType.FIXED_JOINT):
            fixed = model.getFrameId(joint, pin.FrameType.FIXED_JOINT)
            child = [fid for fid, f in enumerate(model.frames) if f.previousFrame == fixed and f.type == pin.FrameType.BODY]
        else:
            child = []
        if not child:
            raise SpecError(f"ft_sensors.{sensor}", f"joint {joint!r} has no child link in the robot model")
        out[sensor] = child[0]
    return out


class FtMonitor:
    def __init__(self, frames: Mapping[str, int], limb_sensors: Sequence[tuple[str, str]], guarded,
                 control_period_s: float):
        """``frames``: sensor -> frame id (:func:`ft_sensor_frames`); ``limb_sensors``: (limb,
        sensor) pairs, those whose sensor has no frame are left out; ``guarded``: the controller's
        GuardedParams."""
        self.frames = dict(frames)
        self.limbs = [(limb, sensor, self.frames[sensor]) for limb, sensor in limb_sensors if sensor in self.frames]
        self.guarded = guarded
        self.period = control_period_s
        self._filtered: dict[str, np.ndarray] = {}  # limb -> filtered force, world axes [N]
        self._tare: dict[str, np.ndarray] = {}  # limb -> filtered force at the last tare [N]
        self._slow: dict[str, np.ndarray] = {}  # limb -> slow-filtered force, world axes [N]
        self._slow_tare: dict[str, np.ndarray] = {}
        self._raw: dict[str, np.ndarray] = {}  # limb -> last raw force, world axes [N]
        self._noise_var: dict[str, float] = {}  # limb -> raw noise variance per component [N^2]

    def _alpha(self, slow: bool = False) -> float:
        """Gain of the first-order filter (or the slow one) per control period [-]."""
        tau = self.guarded.confirm_time_constant_s if slow else self.guarded.filter_time_constant_s
        return 1.0 if tau <= 0 else min(1.0, self.period / tau)

    def update(self, oMf, ft: Mapping[str, Sequence[float]]) -> None:
        """One tick: ``ft`` sensor -> wrench (force first, sensor axes), ``oMf`` the model data's
        frame placements of this tick."""
        alpha, alpha_slow = self._alpha(), self._alpha(slow=True)
        beta = min(1.0, self.period / self.guarded.noise_time_constant_s)
        filtered, slow = self._filtered, self._slow
        for limb, sensor, fid in self.limbs:
            wrench = ft.get(sensor)
            if wrench is None:
                continue
            force = oMf[fid].rotation @ np.asarray(wrench[:3], float)
            # white noise of variance s^2 per component gives tick-to-tick differences of variance
            # 2 s^2; each sample's share is capped (16 x the estimate + 1 N^2) so that a contact
            # change or an impact does not pass for noise
            previous_raw = self._raw.get(limb)
            self._raw[limb] = force.copy()
            if previous_raw is not None:
                d = force - previous_raw
                var = self._noise_var.get(limb, 0.0)
                sample = min(float(d @ d) / 6.0, 16.0 * var + 1.0)
                self._noise_var[limb] = var + beta * (sample - var)
            previous_slow = slow.get(limb)
            slow[limb] = force.copy() if previous_slow is None else previous_slow + alpha_slow * (force - previous_slow)
            previous = filtered.get(limb)
            if previous is not None:
                force -= previous
                force *= alpha
                force += previous  # previous + alpha (force - previous)
            filtered[limb] = force

    def force(self, limb: str) -> np.ndarray:
        """Filtered force of the limb's sensor in world axes [N] (zeros before any reading)."""
        return self._filtered.get(limb, np.zeros(3)).copy()

    def jump(self, limb: str) -> float:
        """[N] how far the filtered force departs from the slow-filtered one (a sudden change: an
        impact; a contact's force ramp or a guarded placement moves both filters together)."""
        fast, slow = self._filtered.get(limb), self._slow.get(limb)
        if fast is None or slow is None:
            return 0.0
        return float(np.linalg.norm(fast - slow))

    def tare(self, limb: str) -> None:
        """Forces are read against this tick's from now on (:meth:`change`)."""
        self._tare[limb] = self.force(limb)
        self._slow_tare[limb] = self._slow.get(limb, np.zeros(3)).copy()

    def noise_std(self, limb: str, slow: bool = False) -> float:
        """Standard deviation [N] of the filtered (or slow-filtered) force noise along one axis,
        estimated online (white noise through a first-order filter of gain a: s sqrt(a / (2 - a)))."""
        alpha = self._alpha(slow)
        return math.sqrt(self._noise_var.get(limb, 0.0) * alpha / (2.0 - alpha))

    def threshold(self, limb: str) -> float:
        """[N] the force change that means contact: ``guarded.force_threshold``, or
        ``guarded.noise_sigmas`` standard deviations of the filtered noise when larger."""
        g = self.guarded
        return max(g.force_threshold, g.noise_sigmas * self.noise_std(limb))

    def confirms_stall(self, limb: str, approach: np.ndarray | None = None) -> bool:
        """The slow-filtered force change exceeds ``guarded.confirm_sigmas`` standard deviations
        of its noise (the tare's and the present's: sqrt(2) x the filtered noise) and
        ``guarded.force_threshold``: a limb held back short of its target is pressing on something."""
        g = self.guarded
        floor = max(g.force_threshold, g.confirm_sigmas * math.sqrt(2.0) * self.noise_std(limb, slow=True))
        return self.change(limb, approach, slow=True) > floor

    def change(self, limb: str, approach: np.ndarray | None = None, slow: bool = False) -> float:
        """Contact force [N] seen since the tare: the filtered (or slow-filtered) force's change
        against the unit ``approach`` direction (an obstacle pushes the limb back), or its norm
        without one."""
        now = self._slow.get(limb, np.zeros(3)) if slow else self.force(limb)
        change = now - (self._slow_tare if slow else self._tare).get(limb, now)
        if approach is None:
            return float(np.linalg.norm(change))
        return float(-change @ approach)
