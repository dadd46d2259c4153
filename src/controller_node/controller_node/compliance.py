"""PWM compliance law of ladder_climbing_drc_hubo.txt, section IV, eq. (1).

    P = kP (x_d - x_c) + kD (xdot_d - xdot_c) + f

per joint, duty P in [-1, 1]. The paper writes the damping term on the current velocity and runs
with kD = 0 and f = 0; here kD multiplies the velocity error (xdot_d = 0 gives the paper's form
with the damping sign that makes it a damper). Gains come from the robot config (legs stiff, arm
gains decreasing shoulder -> elbow -> wrist). ``f`` is either 0 or the QP's feed-forward torque
converted to duty through the joint's DC-motor model, the gravity compensation the paper left as
future work:

    V d = R i + k_e N w,   tau = k_t N i   =>   d = (R tau / (k_t N) + k_t N w) / V

(k_e = k_t in SI units). A last clamp keeps the predicted current |i| = |V d - k_t N w| / R below
``current_margin * current_limit`` so the drivers' over-current protection never trips.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class MotorArrays:
    """Per-joint DC-motor parameters in whole-body joint order."""

    supply_voltage: np.ndarray  # [V]
    resistance: np.ndarray  # [ohm]
    torque_constant: np.ndarray  # [N m/A] motor side (= back-EMF constant [V s/rad])
    gear_ratio: np.ndarray  # [-]
    current_limit: np.ndarray  # [A]

    @property
    def torque_per_amp(self) -> np.ndarray:
        """k_t N [N m/A] at the joint."""
        return self.torque_constant * self.gear_ratio

    @classmethod
    def from_robot_config(cls, config, joint_names) -> "MotorArrays":
        specs = [config.motor.for_joint(name) for name in joint_names]
        return cls(np.array([s.supply_voltage for s in specs]), np.array([s.resistance for s in specs]),
                   np.array([s.torque_constant for s in specs]), np.array([s.gear_ratio for s in specs]),
                   np.array([s.current_limit for s in specs]))


@dataclass(frozen=True)
class PwmGainArrays:
    kp: np.ndarray  # [duty/rad]
    kd: np.ndarray  # [duty s/rad]

    @classmethod
    def from_robot_config(cls, config, joint_names) -> "PwmGainArrays":
        return cls(np.array([config.pwm.kp[name] for name in joint_names], dtype=float),
                   np.array([config.pwm.kd[name] for name in joint_names], dtype=float))


class ComplianceLaw:
    def __init__(self, gains: PwmGainArrays, motors: MotorArrays, current_margin: float = 0.85):
        self.gains = gains
        self.motors = motors
        self.current_margin = current_margin

    def torque_to_duty(self, tau: np.ndarray, velocity: np.ndarray) -> np.ndarray:
        """Duty [-] that produces joint torque ``tau`` [N m] at joint velocity [rad/s] (no clamp)."""
        m = self.motors
        ktn = m.torque_per_amp
        return (m.resistance * tau / ktn + ktn * velocity) / m.supply_voltage

    def duty_to_torque(self, duty: np.ndarray, velocity: np.ndarray) -> np.ndarray:
        """Joint torque [N m] of a duty at a joint velocity (same motor model, no current limit)."""
        m = self.motors
        ktn = m.torque_per_amp
        return ktn * (m.supply_voltage * duty - ktn * velocity) / m.resistance

    def current(self, duty: np.ndarray, velocity: np.ndarray) -> np.ndarray:
        """Predicted motor current [A]."""
        m = self.motors
        return (m.supply_voltage * duty - m.torque_per_amp * velocity) / m.resistance

    def duty_window(self, velocity: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Duty bounds keeping |current| <= margin * limit, intersected with [-1, 1]. A joint
        back-driven so fast that its back-EMF exceeds what full duty can match has no such duty:
        its window shrinks to the full duty of its velocity's sign (the least current there is)."""
        m = self.motors
        emf = m.torque_per_amp * velocity
        i_max = self.current_margin * m.current_limit
        lo = np.clip((emf - i_max * m.resistance) / m.supply_voltage, -1.0, 1.0)
        hi = np.clip((emf + i_max * m.resistance) / m.supply_voltage, -1.0, 1.0)
        return lo, np.maximum(hi, lo)

    def duty(self, q_desired: np.ndarray, q: np.ndarray, v_desired: np.ndarray, v: np.ndarray,
             feedforward_tau: np.ndarray | None = None) -> np.ndarray:
        """Eq. (1): kP (x_d - x_c) + kD (xdot_d - xdot_c) + f, clamped to the current window."""
        duty = self.gains.kp * (q_desired - q) + self.gains.kd * (v_desired - v)
        if feedforward_tau is not None:
            duty = duty + self.torque_to_duty(feedforward_tau, v)
        lo, hi = self.duty_window(v)
        return np.clip(duty, lo, hi)
