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

import numpy as np


def cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """3-vector cross product (np.cross costs ~20x more on 3-vectors)."""
    return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


def quat_to_matrix(q_xyzw: np.ndarray) -> np.ndarray:
    x, y, z, w = (float(v) for v in q_xyzw)
    n = x * x + y * y + z * z + w * w
    s = 2.0 / n if n > 0 else 0.0
    return np.array([
        [1.0 - s * (y * y + z * z), s * (x * y - z * w), s * (x * z + y * w)],
        [s * (x * y + z * w), 1.0 - s * (x * x + z * z), s * (y * z - x * w)],
        [s * (x * z - y * w), s * (y * z + x * w), 1.0 - s * (x * x + y * y)],
    ])


def matrix_to_quat(R: np.ndarray) -> np.ndarray:
    """Unit quaternion (x, y, z, w) with w >= 0."""
    m = np.asarray(R, dtype=float)
    trace = m[0, 0] + m[1, 1] + m[2, 2]
    if trace > 0.0:
        s = 2.0 * np.sqrt(trace + 1.0)
        q = np.array([(m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s, 0.25 * s])
    elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
        s = 2.0 * np.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2])
        q = np.array([0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s, (m[2, 1] - m[1, 2]) / s])
    elif m[1, 1] > m[2, 2]:
        s = 2.0 * np.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2])
        q = np.array([(m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s, (m[0, 2] - m[2, 0]) / s])
    else:
        s = 2.0 * np.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1])
        q = np.array([(m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s, (m[1, 0] - m[0, 1]) / s])
    q /= np.linalg.norm(q)
    return q if q[3] >= 0 else -q


def pose_matrix(position, q_xyzw) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = quat_to_matrix(q_xyzw)
    T[:3, 3] = position
    return T


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


def base_twist_from_com(T_world_base: np.ndarray, position_com_in_world: np.ndarray,
                        linear_velocity_com_in_world: np.ndarray,
                        angular_velocity_in_world: np.ndarray) -> np.ndarray:
    """World-frame linear velocity of the root frame origin from PyBullet's COM velocity."""
    return linear_velocity_com_in_world + cross(angular_velocity_in_world,
                                                   T_world_base[:3, 3] - position_com_in_world)


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
