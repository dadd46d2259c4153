"""Frame conversions between PyBullet's conventions and the project's (URDF frames, Pinocchio).

PyBullet facts (FIELD_NOTES, checked by tests/sim/test_bridge_sensors.py):
- a link's "local inertial frame" is its centre of mass with the axes rotated onto the principal
  axes of inertia (with URDF_USE_INERTIA_FROM_FILE): ``T_link_inertial`` from getDynamicsInfo;
- the base pose PyBullet reports / accepts is the root link's inertial frame, its velocities are
  world-frame at the centre of mass;
- joint reaction forces (F/T sensors) are the wrench the parent exerts on the child, expressed
  in the child's inertial frame, torque about the child's centre of mass.
"""
from __future__ import annotations

import math

import numpy as np


def cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """3-vector cross product (np.cross costs ~20x more on 3-vectors)."""
    return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


def _rotation_entries(q_xyzw) -> list[float]:
    """The 9 entries (row-major) of the rotation matrix of a (not necessarily unit) quaternion, as
    Python floats: building a matrix from floats costs a fraction of numpy's work on a 3 x 3."""
    x, y, z, w = map(float, q_xyzw)
    n = x * x + y * y + z * z + w * w
    s = 2.0 / n if n > 0 else 0.0
    return [1.0 - s * (y * y + z * z), s * (x * y - z * w), s * (x * z + y * w),
            s * (x * y + z * w), 1.0 - s * (x * x + z * z), s * (y * z - x * w),
            s * (x * z - y * w), s * (y * z + x * w), 1.0 - s * (x * x + y * y)]


def quat_to_matrix(q_xyzw: np.ndarray) -> np.ndarray:
    return np.array(_rotation_entries(q_xyzw)).reshape(3, 3)


def matrix_to_quat(R: np.ndarray) -> np.ndarray:
    """Unit quaternion (x, y, z, w) with w >= 0."""
    (m00, m01, m02), (m10, m11, m12), (m20, m21, m22) = np.asarray(R, dtype=float)[:3, :3].tolist()
    trace = m00 + m11 + m22
    if trace > 0.0:
        s = 2.0 * math.sqrt(trace + 1.0)
        q = np.array([(m21 - m12) / s, (m02 - m20) / s, (m10 - m01) / s, 0.25 * s])
    elif m00 > m11 and m00 > m22:
        s = 2.0 * math.sqrt(1.0 + m00 - m11 - m22)
        q = np.array([0.25 * s, (m01 + m10) / s, (m02 + m20) / s, (m21 - m12) / s])
    elif m11 > m22:
        s = 2.0 * math.sqrt(1.0 + m11 - m00 - m22)
        q = np.array([(m01 + m10) / s, 0.25 * s, (m12 + m21) / s, (m02 - m20) / s])
    else:
        s = 2.0 * math.sqrt(1.0 + m22 - m00 - m11)
        q = np.array([(m02 + m20) / s, (m12 + m21) / s, 0.25 * s, (m10 - m01) / s])
    q /= math.sqrt(q.dot(q))  # = np.linalg.norm(q), without its argument checks
    return q if q[3] >= 0 else -q


def pose_matrix(position, q_xyzw) -> np.ndarray:
    r00, r01, r02, r10, r11, r12, r20, r21, r22 = _rotation_entries(q_xyzw)
    x, y, z = map(float, position)
    return np.array([r00, r01, r02, x, r10, r11, r12, y, r20, r21, r22, z, 0.0, 0.0, 0.0, 1.0]).reshape(4, 4)


def inverse(T: np.ndarray) -> np.ndarray:
    out = np.eye(4)
    R = T[:3, :3]
    out[:3, :3] = R.T
    out[:3, 3] = -R.T @ T[:3, 3]
    return out


def wrench_child_inertial_to_link(force_in_inertial: np.ndarray, torque_in_inertial: np.ndarray,
                                  T_link_inertial: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Re-express a wrench given in the child's inertial frame (torque about its COM) in the child
    link's URDF frame, torque about the link frame origin (the joint / sensor origin)."""
    R = T_link_inertial[:3, :3]
    force = R @ force_in_inertial
    torque = R @ torque_in_inertial + cross(T_link_inertial[:3, 3], force)
    return force, torque


def base_pose_from_inertial(T_world_inertial: np.ndarray, T_base_inertial: np.ndarray) -> np.ndarray:
    """URDF root frame in the world from PyBullet's base (inertial) pose."""
    return T_world_inertial @ inverse(T_base_inertial)


def point_velocity(linear_velocity, angular_velocity, offset) -> np.ndarray:
    """v + omega x r: velocity of the point at ``offset`` r from a point of a rigid body moving at v
    (3-sequences; float arithmetic per component, cheaper than numpy's on 3-vectors)."""
    (vx, vy, vz), (wx, wy, wz), (rx, ry, rz) = linear_velocity, angular_velocity, offset
    return np.array([vx + (wy * rz - wz * ry), vy + (wz * rx - wx * rz), vz + (wx * ry - wy * rx)])


def free_flyer_velocity(T_world_base: np.ndarray, linear_velocity_origin_in_world: np.ndarray,
                        angular_velocity_in_world: np.ndarray) -> np.ndarray:
    """Pinocchio free-flyer velocity (local frame): [R^T v_origin, R^T omega]."""
    R = T_world_base[:3, :3]
    return np.concatenate([R.T @ linear_velocity_origin_in_world, R.T @ angular_velocity_in_world])


def world_velocity_from_free_flyer(T_world_base: np.ndarray, v_local: np.ndarray,
                                   position_com_in_world: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """PyBullet base (COM linear, angular) world velocities from a Pinocchio free-flyer velocity."""
    R = T_world_base[:3, :3]
    linear_origin = R @ v_local[:3]
    angular = R @ v_local[3:6]
    linear_com = linear_origin + cross(angular, position_com_in_world - T_world_base[:3, 3])
    return linear_com, angular
