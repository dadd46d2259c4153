"""The controller's input state and the pluggable base-state estimator.

:class:`RobotState` is what one tick consumes: time, Pinocchio ``q`` / ``v`` (free-flyer velocity
in the base frame) and the F/T wrenches (sensor link frame, the wrench the hand / foot exerts on
the proximal side: standing, the ankle reads Fz > 0).

Estimators turn raw measurements into a RobotState. In simulation the base comes from ground
truth (``sim/base_truth``): :class:`GroundTruthEstimator`. A real robot would plug an IMU +
leg-kinematics estimator behind the same ``estimate`` signature.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Mapping, Sequence

import numpy as np


@dataclass
class RobotState:
    time: float  # [s]
    q: np.ndarray  # (nq,) base position [m], quaternion xyzw, joints [rad]
    v: np.ndarray  # (nv,) base linear [m/s] / angular [rad/s] velocity in the base frame, joints [rad/s]
    ft: dict[str, np.ndarray] = field(default_factory=dict)  # sensor -> (6,) [N, N m] in the sensor link frame
    stamp_ns: int = 0  # [ns] stamp of the measurements this state answers (lock-step)


def quaternion_xyzw_to_matrix(quat: np.ndarray) -> np.ndarray:
    x, y, z, w = np.asarray(quat, float) / np.linalg.norm(quat)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


class GroundTruthEstimator:
    """Base pose / twist from the simulator's ground truth; joints from joint_states.

    ``joint_names`` is the whole-body joint order (Pinocchio order); measurements given by name
    are reordered once per call through a cached index.
    """

    def __init__(self, joint_names: Sequence[str]):
        self.joint_names = tuple(joint_names)
        self._index_cache: dict[tuple[str, ...], np.ndarray] = {}

    def _index(self, names: Sequence[str]) -> np.ndarray:
        key = tuple(names)
        index = self._index_cache.get(key)
        if index is None:
            position = {n: i for i, n in enumerate(key)}
            missing = [n for n in self.joint_names if n not in position]
            if missing:
                raise KeyError(f"joint state lacks {missing[:3]}")
            index = np.array([position[n] for n in self.joint_names])
            self._index_cache[key] = index
        return index

    def estimate(self, time: float, joint_names: Sequence[str], joint_positions: np.ndarray,
                 joint_velocities: np.ndarray, position_base_in_world: np.ndarray,
                 quaternion_base_xyzw: np.ndarray, linear_velocity_base_in_world: np.ndarray,
                 angular_velocity_base_in_world: np.ndarray,
                 ft: Mapping[str, np.ndarray] | None = None, stamp_ns: int = 0) -> RobotState:
        """World-frame base twist (of the base frame origin) -> Pinocchio local free-flyer velocity."""
        index = self._index(joint_names)
        quat = np.asarray(quaternion_base_xyzw, float)
        quat = quat / np.linalg.norm(quat)
        R = quaternion_xyzw_to_matrix(quat)
        q = np.concatenate([position_base_in_world, quat, np.asarray(joint_positions, float)[index]])
        v = np.concatenate([R.T @ np.asarray(linear_velocity_base_in_world, float),
                            R.T @ np.asarray(angular_velocity_base_in_world, float),
                            np.asarray(joint_velocities, float)[index]])
        return RobotState(time, q, v, dict(ft or {}), stamp_ns)

    def estimate_local(self, time: float, joint_names: Sequence[str], joint_positions: np.ndarray,
                       joint_velocities: np.ndarray, position_base_in_world: np.ndarray,
                       quaternion_base_xyzw: np.ndarray, twist_base_in_base: np.ndarray,
                       ft: Mapping[str, np.ndarray] | None = None, stamp_ns: int = 0) -> RobotState:
        """Base twist already in the base frame (sim/base_truth's Odometry: the Pinocchio free-flyer
        velocity, linear then angular)."""
        index = self._index(joint_names)
        quat = np.asarray(quaternion_base_xyzw, float)
        q = np.concatenate([position_base_in_world, quat / np.linalg.norm(quat),
                            np.asarray(joint_positions, float)[index]])
        v = np.concatenate([np.asarray(twist_base_in_base, float), np.asarray(joint_velocities, float)[index]])
        return RobotState(time, q, v, dict(ft or {}), stamp_ns)

    def from_sim_state(self, sim_state) -> RobotState:
        """sim_bridge.backend.SimState (in-process backend) -> RobotState."""
        base = sim_state.base
        index = self._index(sim_state.joint_names)
        q = np.array(base.q, dtype=float)
        v = np.array(base.v, dtype=float)
        q[7:] = np.asarray(sim_state.q, float)[index]
        v[6:] = np.asarray(sim_state.v, float)[index]
        ft = {name: w.as_array() for name, w in sim_state.ft.items()}
        return RobotState(sim_state.time, q, v, ft, int(sim_state.stamp_ns))
