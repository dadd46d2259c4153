"""Tasks of the whole-body QP: weighted least squares on task accelerations (paper eq. 1).

Each task tracks a reference with a PD law, ``a_des = a_ref + 2 sqrt(k) (v_ref - v) + k e``
(critically damped), and contributes ``w |J qdd + Jdot v - a_des|^2`` to the cost. A task reads
the Pinocchio data the whole-body QP filled for this tick (:class:`KinematicsView`) and returns
its rows; it keeps its last error for diagnostics.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from .constraints import frame_point_kinematics
from .params import TaskGains


@dataclass
class TaskRows:
    J: np.ndarray  # (k, nv)
    drift: np.ndarray  # (k,) Jdot v
    a_des: np.ndarray  # (k,)
    weights: np.ndarray  # (k,)
    #: set when J is the identity on these qdd columns (zero elsewhere): the QP adds the task
    #: to the diagonal directly
    columns: slice | None = None


class KinematicsView:
    """What tasks may read: model, data after the tick's computations, q and v."""

    def __init__(self, model: pin.Model, data: pin.Data):
        self.model = model
        self.data = data
        self.q = pin.neutral(model)
        self.v = np.zeros(model.nv)

    def frame_jacobian(self, frame_id: int) -> np.ndarray:
        return pin.getFrameJacobian(self.model, self.data, frame_id, pin.LOCAL_WORLD_ALIGNED)

    def frame_drift(self, frame_id: int) -> np.ndarray:
        """Classical acceleration [m/s^2, rad/s^2] of the frame with qdd = 0 (world axes)."""
        return pin.getFrameClassicalAcceleration(self.model, self.data, frame_id, pin.LOCAL_WORLD_ALIGNED).vector

    def frame_velocity(self, frame_id: int) -> np.ndarray:
        return pin.getFrameVelocity(self.model, self.data, frame_id, pin.LOCAL_WORLD_ALIGNED).vector


def _damping(k: float) -> float:
    return 2.0 * math.sqrt(k)


def _norm(e: np.ndarray) -> float:
    return math.sqrt(float(e @ e))


class Task:
    name = "task"

    def __init__(self, gains: TaskGains):
        self.weight = gains.weight  # [-]
        self.stiffness = gains.stiffness  # [1/s^2]
        self.last_error = 0.0  # norm of the last error [m or rad]

    def rows(self, view: KinematicsView) -> TaskRows:
        raise NotImplementedError


class ComTask(Task):
    """Centre of mass position in the world [m]."""

    name = "com"

    def __init__(self, gains: TaskGains, position_com_in_world: np.ndarray | None = None):
        super().__init__(gains)
        self.position = np.zeros(3) if position_com_in_world is None else np.array(position_com_in_world, float)
        self.velocity = np.zeros(3)  # [m/s]
        self.acceleration = np.zeros(3)  # [m/s^2]
        #: per-axis weight multipliers (e.g. lower z weight)
        self.axis_weights = np.ones(3)

    def set_target(self, position, velocity=None, acceleration=None) -> None:
        self.position = np.asarray(position, float)
        self.velocity = np.zeros(3) if velocity is None else np.asarray(velocity, float)
        self.acceleration = np.zeros(3) if acceleration is None else np.asarray(acceleration, float)

    def rows(self, view: KinematicsView) -> TaskRows:
        d = view.data
        error = self.position - d.com[0]
        self.last_error = _norm(error)
        a_des = self.acceleration + _damping(self.stiffness) * (self.velocity - d.vcom[0]) + self.stiffness * error
        return TaskRows(d.Jcom, d.acom[0], a_des, self.weight * self.axis_weights)


class PostureTask(Task):
    """Actuated joint angles [rad]."""

    name = "posture"

    def __init__(self, gains: TaskGains, nv: int):
        super().__init__(gains)
        self.na = nv - 6
        self.q_joints = np.zeros(self.na)
        self.v_joints = np.zeros(self.na)
        self.a_joints = np.zeros(self.na)
        self._J = np.hstack([np.zeros((self.na, 6)), np.eye(self.na)])
        self.joint_weights = np.ones(self.na)
        self._zero = np.zeros(self.na)

    def set_target(self, q_joints, v_joints=None, a_joints=None) -> None:
        self.q_joints = np.asarray(q_joints, float)
        self.v_joints = np.zeros(self.na) if v_joints is None else np.asarray(v_joints, float)
        self.a_joints = np.zeros(self.na) if a_joints is None else np.asarray(a_joints, float)

    def rows(self, view: KinematicsView) -> TaskRows:
        error = self.q_joints - view.q[7:]
        self.last_error = _norm(error)
        a_des = self.a_joints + _damping(self.stiffness) * (self.v_joints - view.v[6:]) + self.stiffness * error
        return TaskRows(self._J, self._zero, a_des, self.weight * self.joint_weights, slice(6, 6 + self.na))


class BaseOrientationTask(Task):
    """Free-flyer orientation; error and angular velocity in the base frame [rad, rad/s]."""

    name = "base_orientation"

    def __init__(self, gains: TaskGains, nv: int):
        super().__init__(gains)
        self.R_world_base = np.eye(3)
        self.omega_in_base = np.zeros(3)
        self._J = np.zeros((3, nv))
        self._J[:, 3:6] = np.eye(3)
        self._zero = np.zeros(3)
        self._zero.flags.writeable = False
        self._weights_of: tuple[float, np.ndarray] | None = None  # (weight, its (3,) row weights)

    def set_target(self, R_world_base: np.ndarray, omega_in_base=None) -> None:
        self.R_world_base = np.asarray(R_world_base, float)
        self.omega_in_base = np.zeros(3) if omega_in_base is None else np.asarray(omega_in_base, float)

    def rows(self, view: KinematicsView) -> TaskRows:
        R = pin.Quaternion(view.q[3:7]).normalized().toRotationMatrix()
        error = pin.log3(R.T @ self.R_world_base)
        self.last_error = _norm(error)
        a_des = _damping(self.stiffness) * (self.omega_in_base - view.v[3:6]) + self.stiffness * error
        if self._weights_of is None or self._weights_of[0] != self.weight:
            weights = np.full(3, self.weight)
            weights.flags.writeable = False
            self._weights_of = (self.weight, weights)
        return TaskRows(self._J, self._zero, a_des, self._weights_of[1], slice(3, 6))


class FrameTask(Task):
    """Pose of a point fixed in a body (the contact body), world axes: position [m] + orientation.

    The point is ``offset_in_frame`` in the frame ``frame_id`` (the robot contact surface centre);
    the target is ``T_world_target`` for that point, with a 6D velocity / acceleration feed-forward
    (linear first, world axes).
    """

    name = "contact_body"

    def __init__(self, gains: TaskGains, frame_id: int, offset_in_frame: np.ndarray | None = None,
                 name: str | None = None):
        super().__init__(gains)
        if name:
            self.name = name
        self.frame_id = frame_id
        self.offset = np.zeros(3) if offset_in_frame is None else np.asarray(offset_in_frame, float)
        self.orientation_weight = gains.orientation_weight
        self.T_world_target = pin.SE3.Identity()
        self.velocity = np.zeros(6)
        self.acceleration = np.zeros(6)
        self.position_error = np.zeros(3)
        self._weights_key: tuple[float, float] | None = None
        self._weights = np.zeros(6)

    def set_target(self, T_world_target: pin.SE3, velocity=None, acceleration=None) -> None:
        self.T_world_target = T_world_target
        self.velocity = np.zeros(6) if velocity is None else np.asarray(velocity, float)
        self.acceleration = np.zeros(6) if acceleration is None else np.asarray(acceleration, float)

    def current(self, view: KinematicsView) -> pin.SE3:
        M = view.data.oMf[self.frame_id]
        return pin.SE3(M.rotation, M.translation + M.rotation @ self.offset)

    def rows(self, view: KinematicsView) -> TaskRows:
        data, fid = view.data, self.frame_id
        M = data.oMf[fid]
        R = M.rotation
        r = R @ self.offset
        J, drift, velocity = frame_point_kinematics(view.model, data, fid, r)
        target = self.T_world_target
        e_pos = target.translation - (M.translation + r)
        e_rot = pin.log3(target.rotation @ R.T)  # world axes
        self.position_error = e_pos
        self.last_error = _norm(e_pos)
        error = np.concatenate((e_pos, e_rot))
        a_des = self.acceleration + _damping(self.stiffness) * (self.velocity - velocity) + self.stiffness * error
        key = (self.weight, self.orientation_weight)
        if key != self._weights_key:
            self._weights_key = key
            self._weights = np.array([self.weight] * 3 + [self.weight * self.orientation_weight] * 3)
        return TaskRows(J, drift, a_des, self._weights)
