"""numpy <-> geometry_msgs: Point, Vector3, Quaternion, Pose (4x4 homogeneous), Wrench.

Conventions: positions [m], forces [N], torques [N m]; quaternions are (x, y, z, w) like
geometry_msgs and Pinocchio's free-flyer configuration; a pose is the 4x4 homogeneous transform
T_parent_child (the message's frame is the parent). Bad input raises SpecError(field, rule).
"""
from __future__ import annotations

import numpy as np
from geometry_msgs.msg import Point, Pose, Quaternion, Vector3, Wrench

from climb_core.errors import SpecError

from ._check import finite_vector

#: Max deviation of R^T R from identity accepted as a rotation matrix (numerical noise only).
ROTATION_TOLERANCE = 1e-6


def point_to_msg(position: np.ndarray, field: str = "point") -> Point:
    """(3,) position [m] -> Point."""
    x, y, z = finite_vector(position, field, 3)
    return Point(x=float(x), y=float(y), z=float(z))


def point_from_msg(msg: Point) -> np.ndarray:
    """Point -> (3,) position [m]."""
    return np.array([msg.x, msg.y, msg.z], dtype=float)


def vector3_to_msg(vector: np.ndarray, field: str = "vector3") -> Vector3:
    x, y, z = finite_vector(vector, field, 3)
    return Vector3(x=float(x), y=float(y), z=float(z))


def vector3_from_msg(msg: Vector3) -> np.ndarray:
    return np.array([msg.x, msg.y, msg.z], dtype=float)


def quaternion_to_msg(quaternion_xyzw: np.ndarray, field: str = "quaternion") -> Quaternion:
    """(4,) unit quaternion (x, y, z, w) -> Quaternion (normalised; the zero quaternion is refused)."""
    q = _unit_quaternion(finite_vector(quaternion_xyzw, field, 4), field)
    return Quaternion(x=float(q[0]), y=float(q[1]), z=float(q[2]), w=float(q[3]))


def quaternion_from_msg(msg: Quaternion, field: str = "quaternion") -> np.ndarray:
    """Quaternion -> (4,) unit quaternion (x, y, z, w)."""
    return _unit_quaternion(finite_vector([msg.x, msg.y, msg.z, msg.w], field, 4), field)


def rotation_to_quaternion(R: np.ndarray, field: str = "rotation") -> np.ndarray:
    """3x3 rotation matrix -> unit quaternion (x, y, z, w) with w >= 0 (Shepperd's method)."""
    R = _rotation(R, field)
    trace = np.trace(R)
    diag = np.diag(R)
    # Pick the largest of 4w^2, 4x^2, 4y^2, 4z^2 to divide by: numerically safe everywhere.
    k = int(np.argmax([trace, *diag]))
    if k == 0:
        s = 2.0 * np.sqrt(1.0 + trace)
        q = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1], 0.25 * s * s]) / s
    else:
        i = k - 1
        j, m = (i + 1) % 3, (i + 2) % 3
        s = 2.0 * np.sqrt(1.0 + R[i, i] - R[j, j] - R[m, m])
        q = np.empty(4)
        q[i] = 0.25 * s
        q[j] = (R[j, i] + R[i, j]) / s
        q[m] = (R[m, i] + R[i, m]) / s
        q[3] = (R[m, j] - R[j, m]) / s
    q /= np.linalg.norm(q)
    return -q if q[3] < 0 else q


def quaternion_to_rotation(quaternion_xyzw: np.ndarray, field: str = "quaternion") -> np.ndarray:
    """Unit quaternion (x, y, z, w) -> 3x3 rotation matrix."""
    x, y, z, w = _unit_quaternion(finite_vector(quaternion_xyzw, field, 4), field)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


def pose_to_msg(T_parent_child: np.ndarray, field: str = "pose") -> Pose:
    """4x4 homogeneous transform -> Pose."""
    T = np.asarray(T_parent_child, dtype=float)
    if T.shape != (4, 4):
        raise SpecError(field, f"must be a 4x4 homogeneous transform, got shape {T.shape}")
    if not np.allclose(T[3], [0.0, 0.0, 0.0, 1.0]):
        raise SpecError(f"{field}[3]", f"last row must be [0, 0, 0, 1], got {T[3].tolist()}")
    return Pose(position=point_to_msg(T[:3, 3], f"{field}.position"),
                orientation=quaternion_to_msg(rotation_to_quaternion(T[:3, :3], f"{field}.rotation")))


def pose_from_msg(msg: Pose, field: str = "pose") -> np.ndarray:
    """Pose -> 4x4 homogeneous transform."""
    T = np.eye(4)
    T[:3, :3] = quaternion_to_rotation(quaternion_from_msg(msg.orientation, f"{field}.orientation"))
    T[:3, 3] = point_from_msg(msg.position)
    return T


def wrench_to_msg(wrench: np.ndarray, field: str = "wrench") -> Wrench:
    """(6,) [fx fy fz [N], tx ty tz [N m]] -> Wrench."""
    w = finite_vector(wrench, field, 6)
    return Wrench(force=vector3_to_msg(w[:3]), torque=vector3_to_msg(w[3:]))


def wrench_from_msg(msg: Wrench) -> np.ndarray:
    """Wrench -> (6,) [force [N], torque [N m]]."""
    return np.concatenate([vector3_from_msg(msg.force), vector3_from_msg(msg.torque)])


def _unit_quaternion(q: np.ndarray, field: str) -> np.ndarray:
    norm = np.linalg.norm(q)
    if norm < 1e-9:
        raise SpecError(field, "must be a non-zero quaternion (x, y, z, w)")
    return q / norm


def _rotation(R: np.ndarray, field: str) -> np.ndarray:
    R = np.asarray(R, dtype=float)
    if R.shape != (3, 3):
        raise SpecError(field, f"must be a 3x3 rotation matrix, got shape {R.shape}")
    if not np.all(np.isfinite(R)):
        raise SpecError(field, "must be finite")
    if np.abs(R.T @ R - np.eye(3)).max() > ROTATION_TOLERANCE or np.linalg.det(R) < 0:
        raise SpecError(field, "must be orthonormal with determinant +1")
    return R
