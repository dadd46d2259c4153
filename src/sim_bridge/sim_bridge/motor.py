"""DC motor + driver model of one actuated joint, vectorised over the joints.

Per joint (motor side; SI units):

    u     = duty * V                      # [V]  duty in [-1, 1] (PWM mode)
    e     = k_t * N * qdot                # [V]  back-EMF (k_e = k_t in SI), N = gear ratio
    i     = (u - e) / R                   # [A]  the winding's L/R (~0.1 ms) is far below the 1 ms step
    tau   = N * k_t * i                   # [N m] at the joint, then clipped to the URDF effort limit

Torque-controlled modes (TORQUE, POSITION, DAMPING) model a current-regulated driver: the current
it draws is i = tau / (N k_t), held at the current limit. In PWM (voltage) mode nothing regulates
the current, so the driver protects itself: when |i| stays above the current limit for
``trip_delay_s`` it cuts the joint's power (tau = 0, the motor freewheels) for ``trip_hold_off_s``
and reports an over-current trip; then power comes back by itself, as on the DRC-Hubo drivers of
ladder_climbing_drc_hubo.txt.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from climb_core.errors import SpecError


@dataclass(frozen=True)
class MotorParams:
    """Per-joint motor constants, arrays in the backend's joint order."""

    supply_voltage: np.ndarray  # [V]
    resistance: np.ndarray  # [ohm]
    torque_constant: np.ndarray  # [N m/A] motor side
    gear_ratio: np.ndarray  # [-]
    current_limit: np.ndarray  # [A]
    trip_hold_off_s: np.ndarray  # [s]

    def __post_init__(self) -> None:
        n = None
        for name in ("supply_voltage", "resistance", "torque_constant", "gear_ratio", "current_limit",
                     "trip_hold_off_s"):
            arr = np.atleast_1d(np.asarray(getattr(self, name), dtype=float)).copy()
            if n is None:
                n = arr.shape[0]
            if arr.shape != (n,):
                raise SpecError(f"motor.{name}", f"must have one entry per joint ({n}), got shape {arr.shape}")
            if not np.all(np.isfinite(arr)):
                raise SpecError(f"motor.{name}", "must be finite")
            if name == "trip_hold_off_s":
                if np.any(arr < 0):
                    raise SpecError(f"motor.{name}", "must be >= 0")
            elif np.any(arr <= 0):
                raise SpecError(f"motor.{name}", "must be > 0")
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)

    @property
    def n(self) -> int:
        return int(self.supply_voltage.shape[0])

    @property
    def stall_torque(self) -> np.ndarray:
        """[N m] joint torque at full duty and zero speed (before the effort clip)."""
        return self.gear_ratio * self.torque_constant * self.supply_voltage / self.resistance

    @property
    def torque_at_current_limit(self) -> np.ndarray:
        """[N m] joint torque at the current limit."""
        return self.gear_ratio * self.torque_constant * self.current_limit

    @staticmethod
    def uniform(n: int, **values: float) -> "MotorParams":
        return MotorParams(**{k: np.full(n, float(v)) for k, v in values.items()})


@dataclass(frozen=True)
class TripEvent:
    joint: int  # index in the backend's joint order
    time: float  # [s] sim time of the trip
    current: float  # [A] current that tripped it
    until: float  # [s] sim time at which power returns


@dataclass
class DcMotorBank:
    """Electrical state of every joint's motor and driver."""

    params: MotorParams
    trip_delay_s: float = 0.002  # [s]
    current: np.ndarray = field(init=False)  # [A] last computed current (0 while tripped)
    over_time: np.ndarray = field(init=False)  # [s] time spent above the limit
    power_back_at: np.ndarray = field(init=False)  # [s] sim time power returns (-inf = powered)
    trip_count: np.ndarray = field(init=False)  # [-] trips per joint since reset

    def __post_init__(self) -> None:
        self.reset()

    def reset(self) -> None:
        n = self.params.n
        self.current = np.zeros(n)
        self.over_time = np.zeros(n)
        self.power_back_at = np.full(n, -np.inf)
        self.trip_count = np.zeros(n, dtype=int)

    def powered(self, time: float) -> np.ndarray:
        """(n,) bool: the driver delivers power at ``time`` [s]."""
        return time >= self.power_back_at

    def pwm_current(self, duty: np.ndarray, qdot: np.ndarray) -> np.ndarray:
        """[A] motor current for a duty cycle at joint velocity ``qdot`` [rad/s]."""
        p = self.params
        voltage = np.clip(duty, -1.0, 1.0) * p.supply_voltage
        back_emf = p.torque_constant * p.gear_ratio * qdot
        return (voltage - back_emf) / p.resistance

    def torque_from_current(self, current: np.ndarray) -> np.ndarray:
        return self.params.gear_ratio * self.params.torque_constant * current

    def current_from_torque(self, tau: np.ndarray) -> np.ndarray:
        return tau / (self.params.gear_ratio * self.params.torque_constant)

    def duty_for_torque(self, tau: np.ndarray, qdot: np.ndarray) -> np.ndarray:
        """Duty that produces joint torque ``tau`` [N m] at ``qdot`` [rad/s] (a controller's
        feed-forward f of eq. 1), clipped to [-1, 1]."""
        p = self.params
        voltage = p.resistance * self.current_from_torque(tau) + p.torque_constant * p.gear_ratio * qdot
        return np.clip(voltage / p.supply_voltage, -1.0, 1.0)

    def update(self, current: np.ndarray, time: float, dt: float,
               protected: np.ndarray | None = None) -> tuple[np.ndarray, list[TripEvent]]:
        """Apply the protection to the currents the drivers would draw this step; ``protected``
        (default all) selects the joints whose driver can trip (voltage-mode / PWM joints).

        Returns (current actually flowing [A], trips that happened now).
        """
        powered = self.powered(time)
        over = powered & (np.abs(current) > self.params.current_limit)
        if protected is not None:
            over &= protected
        if not over.any() and not self.over_time.any():
            flowing = np.where(powered, current, 0.0)
            self.current = flowing
            return flowing, []
        self.over_time = np.where(over, self.over_time + dt, 0.0)
        tripping = np.flatnonzero(over & (self.over_time >= self.trip_delay_s - 1e-12))
        events = []
        for j in tripping:
            until = time + float(self.params.trip_hold_off_s[j])
            self.power_back_at[j] = until
            self.trip_count[j] += 1
            self.over_time[j] = 0.0
            events.append(TripEvent(int(j), float(time), float(current[j]), until))
        flowing = np.where(self.powered(time), current, 0.0)
        self.current = flowing
        return flowing, events


def motor_params_from_table(joint_names: Sequence[str], default: dict[str, float],
                            overrides: dict[str, dict[str, float]] | None = None) -> MotorParams:
    """Arrays from a default entry plus per-joint overrides (``{joint: {field: value}}``)."""
    overrides = overrides or {}
    fields = ("supply_voltage", "resistance", "torque_constant", "gear_ratio", "current_limit", "trip_hold_off_s")
    for joint in overrides:
        if joint not in joint_names:
            raise SpecError(f"motor.joints.{joint}", "unknown joint")
    arrays = {}
    for name in fields:
        if name not in default:
            raise SpecError(f"motor.default.{name}", "missing")
        arrays[name] = np.array([float(overrides.get(j, {}).get(name, default[name])) for j in joint_names])
    return MotorParams(**arrays)
