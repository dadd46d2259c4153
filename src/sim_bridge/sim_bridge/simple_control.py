"""A minimal joint-space controller for bring-up, tests and benchmarks (not the project's controller).

:class:`GravityCompensatedPd`: tau = tau_g(q) + Kp (q_des - q) - Kd qdot, with

- tau_g: the joint torques that hold the robot still against gravity when the given limbs carry
  it: with g(q) = rnea(q, 0, 0) and J_c the contact frames' Jacobians (6 rows per sole, 3 per
  grasp), the contact wrenches f solve the floating-base rows J_b^T f = g_b (least weighted norm,
  grasps cost more than soles) and tau_g = g_j - J_j^T f;
- per-joint gains from each joint's apparent inertia m_j = 1 / (M^-1)_jj (every other DoF free),
  kp = m_j w^2, kd = 2 zeta m_j w, so that a light wrist and a heavy hip have the same bandwidth
  w, which must stay well below the control rate (a 200 Hz zero-order-hold PD on a 3e-3 kg m^2
  wrist is unstable at kp = 300 N m/rad).
"""
from __future__ import annotations

from typing import Sequence

import numpy as np

from .backend import SimState
from .commands import PWM, TORQUE, ActuatorCommand


class GravityCompensatedPd:
    def __init__(self, robot, q_des: np.ndarray, contact_limbs: Sequence[str] = ("left_foot", "right_foot"),
                 bandwidth: float = 30.0, damping_ratio: float = 1.0, hand_weight: float = 10.0):
        import pinocchio as pin

        self.pin = pin
        self.robot = robot
        self.model = robot.model
        self.data = robot.model.createData()
        q_des = np.asarray(q_des, dtype=float)
        self.q_des_full = q_des.copy() if q_des.shape == (robot.nq,) else None
        self.q_des = q_des[7:].copy() if q_des.shape == (robot.nq,) else q_des.copy()  # [rad]
        self.contact_frames = [robot.frame_id(robot.config.limbs[limb].surface.frame) for limb in contact_limbs]
        # rows of each contact: 6 (wrench) for soles, 3 (force) for grasps, which cost hand_weight
        # times more than a foot's, so the feet carry the robot when they can
        self.contact_rows = [6 if robot.config.limbs[limb].surface.kind != "grasp" else 3 for limb in contact_limbs]
        self.contact_cost = np.concatenate([np.full(r, 1.0 if r == 6 else hand_weight) for r in self.contact_rows]) \
            if contact_limbs else np.zeros(0)
        q_ref = self.q_des_full if self.q_des_full is not None else robot.q_reference()
        M = pin.crba(self.model, self.data, q_ref)
        m_jj = 1.0 / np.diag(np.linalg.inv(M))[6:]  # apparent inertia: every other DoF free
        self.kp = m_jj * bandwidth ** 2  # [N m/rad]
        self.kd = 2.0 * damping_ratio * m_jj * bandwidth  # [N m s/rad]
        self.effort = robot.effort_limits()

    def gravity_torques(self, q: np.ndarray) -> np.ndarray:
        """(n,) [N m] joint torques balancing gravity with the contact limbs carrying the robot."""
        pin = self.pin
        g = pin.computeGeneralizedGravity(self.model, self.data, q)
        if not self.contact_frames:
            return g[6:]
        pin.computeJointJacobians(self.model, self.data, q)
        pin.updateFramePlacements(self.model, self.data)
        J = np.vstack([pin.getFrameJacobian(self.model, self.data, f, pin.LOCAL_WORLD_ALIGNED)[:rows]
                       for f, rows in zip(self.contact_frames, self.contact_rows)])
        A = J[:, :6].T  # (6, m): the floating-base rows
        w_inv = 1.0 / self.contact_cost
        f = w_inv * (A.T @ np.linalg.lstsq((A * w_inv) @ A.T, g[:6], rcond=None)[0])  # least weighted norm
        return g[6:] - J[:, 6:].T @ f

    def torques(self, state: SimState) -> np.ndarray:
        tau = self.gravity_torques(state.base.q) + self.kp * (self.q_des - state.q) - self.kd * state.v
        return np.clip(tau, -self.effort, self.effort)

    def __call__(self, state: SimState) -> ActuatorCommand:
        return ActuatorCommand(np.full(len(self.q_des), TORQUE, dtype=np.uint8), self.torques(state), state.stamp_ns)


def pwm_command(robot, motors, state: SimState, q_des: np.ndarray, kp: np.ndarray, kd: np.ndarray,
                feedforward_torque: np.ndarray | None = None) -> ActuatorCommand:
    """Paper eq. 1: duty = kp (q_des - q) - kd qdot + f, f = the duty of a feed-forward torque
    through the motor model (``motors``: motor.DcMotorBank), clipped to [-1, 1]."""
    duty = kp * (q_des - state.q) - kd * state.v
    if feedforward_torque is not None:
        duty = duty + motors.duty_for_torque(feedforward_torque, state.v)
    return ActuatorCommand(np.full(len(duty), PWM, dtype=np.uint8), np.clip(duty, -1.0, 1.0), state.stamp_ns)
