"""Joint actuators: a command (mode + value per joint) -> joint torques, every physics step.

- TORQUE: tau = value, clipped to the URDF effort limit.
- PWM: duty through the DC-motor model (motor.py): back-EMF, winding resistance, gear.
- POSITION: stiff PD (bring-up; shows why compliance is needed). Explicit tau = kp (value - q) -
  kd qdot here; a backend with an implicit position servo (PyBullet's motor, stable at any
  stiffness on light links) sets ``implicit_position`` and runs it itself, capped at
  :meth:`ActuatorBank.position_force_limits`.
- DAMPING: tau = -damping_gain * qdot (the fallback of the watchdog and of a lost controller).

Every mode ends clipped to the effort limit. TORQUE, POSITION and DAMPING model a
current-regulated driver (the current, tau / (k_t N), is held at the current limit: no trip);
PWM drives the motor's voltage, so its current is only bounded by the over-current protection (a
tripped joint delivers no torque until its hold-off time has passed).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .commands import DAMPING, POSITION, PWM, TORQUE, ActuatorCommand
from .motor import DcMotorBank, MotorParams, TripEvent
from .params import ActuationParams


@dataclass
class ActuatorBank:
    joint_names: tuple[str, ...]
    effort_limits: np.ndarray  # (n,) [N m]
    motor_params: MotorParams
    params: ActuationParams
    implicit_position: bool = False  # POSITION joints are servoed by the backend (tau = 0 here)
    command: ActuatorCommand = field(init=False)
    motors: DcMotorBank = field(init=False)
    tau: np.ndarray = field(init=False)  # (n,) [N m] last applied torque

    def __post_init__(self) -> None:
        self.joint_names = tuple(self.joint_names)
        self.effort_limits = np.asarray(self.effort_limits, dtype=float)
        n = len(self.joint_names)
        if self.effort_limits.shape != (n,) or self.motor_params.n != n:
            raise ValueError("effort limits and motor parameters need one entry per joint")
        self.motors = DcMotorBank(self.motor_params, self.params.overcurrent_trip_delay_s)
        self._regulated_cap = np.minimum(self.effort_limits,
                                         self.motors.torque_from_current(self.motor_params.current_limit))
        self._regulated_floor = -self._regulated_cap
        self._modes_key: tuple[str, bytes] | None = None  # modes of the command the masks below belong to
        self.reset()

    @property
    def n(self) -> int:
        return len(self.joint_names)

    def reset(self) -> None:
        self.set_command(ActuatorCommand.damping(self.n))
        self.motors.reset()
        self.tau = np.zeros(self.n)

    def set_command(self, command: ActuatorCommand) -> None:
        self.command = command
        modes = command.modes
        modes_key = (modes.dtype.str, modes.tobytes())
        if modes_key == self._modes_key:  # a controller sends the same modes tick after tick
            return
        self._modes_key = modes_key
        self._torque = (modes == TORQUE).astype(float)
        self._position = (modes == POSITION).astype(float) * (0.0 if self.implicit_position else 1.0)
        self._damping = (modes == DAMPING).astype(float)
        self._pwm = modes == PWM
        self._any_pwm = bool(self._pwm.any())
        # TORQUE joints (and implicit POSITION ones, tau = 0 here) only: the torques do not depend on
        # the joint state, so they are the same for every physics step of a tick (see torques_constant)
        self._state_independent = not (self._any_pwm or self._damping.any() or self._position.any())

    def torques(self, q: np.ndarray, qdot: np.ndarray, time: float, dt: float) -> tuple[np.ndarray, list[TripEvent]]:
        """Joint torques [N m] for this physics step at sim ``time`` [s]; and over-current trips."""
        p = self.params
        values = self.command.values
        tau = (self._torque * values
               + self._position * (p.position_kp * (values - q) - p.position_kd * qdot)
               - self._damping * (p.damping_gain * qdot))
        # torque modes: current-regulated driver, held at min(effort limit, current limit)
        tau = np.clip(tau, self._regulated_floor, self._regulated_cap)
        current = self.motors.current_from_torque(tau)
        if self._any_pwm:  # PWM: voltage mode through the motor model, protected by the over-current trip
            pwm = self._pwm
            current[pwm] = self.motors.pwm_current(values, qdot)[pwm]
            flowing, trips = self.motors.update(current, time, dt, pwm)
            tau[pwm] = np.clip(self.motors.torque_from_current(flowing), -self.effort_limits, self.effort_limits)[pwm]
        else:
            flowing, trips = self.motors.update(current, time, dt, self._pwm)
        tau[flowing == 0.0] = 0.0  # tripped drivers deliver nothing
        self.tau = tau
        return tau, trips

    def torques_constant(self, time: float) -> bool:
        """True when :meth:`torques` returns the same torques, and leaves the motors in the same
        state, for every physics step from ``time`` [s] on until the command changes: no joint
        depends on the joint state (no PWM, DAMPING or explicit POSITION) and every driver is
        powered (a trip can only happen in PWM, and power never goes away by itself)."""
        return self._state_independent and self.all_powered(time)

    def all_powered(self, time: float) -> bool:
        """Every driver delivers power at ``time`` [s] (= not tripped(time).any(), cheaper)."""
        return bool(time >= self.motors.power_back_at.max())

    def position_force_limits(self) -> np.ndarray:
        """(n,) [N m] torque cap of a position servo: effort limit and current limit."""
        return np.minimum(self.effort_limits, self.motors.torque_from_current(self.motor_params.current_limit))

    def tripped(self, time: float) -> np.ndarray:
        """(n,) bool: joints whose driver is cut at ``time``."""
        return ~self.motors.powered(time)
