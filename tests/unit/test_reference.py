"""controller_node.reference.PathReference on a free-flyer model (Pinocchio's sample humanoid)."""
from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from controller_node.reference import PathReference


@pytest.fixture(scope="module")
def model():
    return pin.buildSampleModelHumanoid(True)  # free-flyer root: SE(3) base + revolute joints


def _path(model, count: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    q = pin.neutral(model)
    out = [q]
    for _ in range(count - 1):
        step = rng.normal(0.0, 0.15, model.nv)  # [m, rad] base translation / rotation and joints
        q = pin.integrate(model, q, step)
        out.append(q)
    return np.array(out)


def test_path_starts_and_ends_on_its_way_points_at_rest(model):
    path = _path(model, 5, 1)
    ref = PathReference(model, np.array([0.0, 0.4, 0.9, 1.3, 2.0]), path)
    q0, v0 = ref.sample(0.0)
    q1, v1 = ref.sample(ref.duration)
    assert np.allclose(pin.difference(model, path[0], q0), 0.0, atol=1e-12)
    assert np.allclose(pin.difference(model, path[-1], q1), 0.0, atol=1e-12)
    assert np.allclose(v0, 0.0) and np.allclose(v1, 0.0)
    assert ref.last_segment_start == pytest.approx(1.3 / 2.0)


def test_reference_velocity_is_the_time_derivative_of_the_configuration(model):
    """v_ref (tangent space at q_ref) against central differences of q_ref inside the segments;
    the joint velocities stay continuous across a way-point (Catmull-Rom tangents)."""
    path = _path(model, 6, 2)
    times = np.array([0.0, 0.3, 0.7, 1.0, 1.6, 2.0])  # [s]
    ref = PathReference(model, times, path)
    eps = 1e-6  # [s]
    for t in np.linspace(0.05, ref.duration - 0.05, 22):  # no sample on a way-point
        q, v = ref.sample(t)
        ahead, _ = ref.sample(t + eps)
        behind, _ = ref.sample(t - eps)
        fd = pin.difference(model, behind, ahead) / (2.0 * eps)  # [m/s, rad/s]
        assert np.allclose(v, fd, rtol=1e-5, atol=1e-6), t
    # way-point 3 (u = 0.5) is passed at t = duration / 2 (min-jerk progress s(1/2) = 1/2)
    q_k, _ = ref.sample(0.5 * ref.duration)
    assert np.allclose(pin.difference(model, path[3], q_k), 0.0, atol=1e-12)
    _, v_before = ref.sample(0.5 * ref.duration - 1e-7)
    _, v_after = ref.sample(0.5 * ref.duration + 1e-7)
    assert np.abs(v_before[6:]).max() > 0.1  # [rad/s] moving through it
    assert np.allclose(v_before[6:], v_after[6:], atol=1e-4)


def test_repeated_way_points_rest_instead_of_dividing_by_zero(model):
    path = _path(model, 3, 3)
    path = np.array([path[0], path[1], path[1], path[2]])
    ref = PathReference(model, np.array([0.0, 0.5, 0.5, 1.0]), path)
    for t in np.linspace(0.0, ref.duration, 41):
        q, v = ref.sample(t)
        assert np.all(np.isfinite(q)) and np.all(np.isfinite(v))
