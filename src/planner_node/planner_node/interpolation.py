"""Configuration-space paths: linear primitive transform, projected interpolation, timing.

Configurations are Pinocchio free-flyer configurations (base position [m], base quaternion
x y z w, joint angles [rad]); differences and interpolations go through the Lie group
(``pin.difference`` / ``pin.integrate`` / ``pin.interpolate``), never through raw vector
arithmetic on quaternions.
"""
from __future__ import annotations

from typing import Callable, Sequence

import numpy as np
import pinocchio as pin


def step_norm(dv: np.ndarray, base_scale: float = 1.0) -> float:
    """Size of a tangent step: max(|joint step| [rad], |base step| / base_scale).

    ``base_scale`` [m/rad] converts the base linear part to an angle-like quantity; the base
    angular part is an angle already.
    """
    lin = np.abs(dv[:3]).max() / base_scale if dv.shape[0] > 6 else 0.0
    ang = np.abs(dv[3:]).max() if dv.shape[0] > 3 else 0.0
    return float(max(lin, ang))


def path_parameter(model: pin.Model, path: Sequence[np.ndarray], base_scale: float = 1.0) -> np.ndarray:
    """Normalised cumulative length (0 .. 1) of a polyline in configuration space."""
    lengths = [0.0]
    for qa, qb in zip(path[:-1], path[1:]):
        dv = pin.difference(model, qa, qb)
        dv = dv.copy()
        dv[:3] /= base_scale
        lengths.append(lengths[-1] + float(np.linalg.norm(dv)))
    lengths = np.asarray(lengths)
    if lengths[-1] <= 1e-12:
        return np.linspace(0.0, 1.0, len(path))
    return lengths / lengths[-1]


def linear_transform(model: pin.Model, waypoints: Sequence[np.ndarray], q_start: np.ndarray,
                     q_end: np.ndarray, base_scale: float = 1.0) -> list[np.ndarray]:
    """Map a primitive's way-points (q̄s, q̄1..q̄k, q̄e) onto new end points (qs, qe).

    Each way-point keeps its offset from the primitive's straight line, i.e.
    q_i = q̄_i ⊕ [(1 - s_i) (qs ⊖ q̄s) + s_i (qe ⊖ q̄e)] with s_i the way-point's normalised
    path parameter; the result starts exactly at qs and ends exactly at qe.
    """
    if len(waypoints) < 2:
        raise ValueError("a primitive needs at least its start and end configurations")
    s = path_parameter(model, waypoints, base_scale)
    d_start = pin.difference(model, waypoints[0], q_start)
    d_end = pin.difference(model, waypoints[-1], q_end)
    out = []
    for si, qi in zip(s, waypoints):
        out.append(pin.integrate(model, qi, (1.0 - si) * d_start + si * d_end))
    out[0] = np.array(q_start, dtype=float)
    out[-1] = np.array(q_end, dtype=float)
    return out


def subdivide(model: pin.Model, path: Sequence[np.ndarray], max_step: float,
              base_scale: float = 1.0) -> list[np.ndarray]:
    """Insert linearly interpolated configurations so that no step exceeds ``max_step``
    (see :func:`step_norm`). Keeps the original way-points."""
    if len(path) == 0:
        return []
    out = [np.array(path[0], dtype=float)]
    for qa, qb in zip(path[:-1], path[1:]):
        k = n_substeps(model, qa, qb, max_step, base_scale)
        for t in np.linspace(0.0, 1.0, k + 1)[1:]:
            out.append(pin.interpolate(model, qa, qb, float(t)))
    return out


def n_substeps(model: pin.Model, qa: np.ndarray, qb: np.ndarray, max_step: float,
               base_scale: float = 1.0) -> int:
    dv = pin.difference(model, qa, qb)
    return max(1, int(np.ceil(step_norm(dv, base_scale) / max_step - 1e-9)))


def projected_interpolation(
    model: pin.Model,
    q_a: np.ndarray,
    q_b: np.ndarray,
    project: Callable[[np.ndarray], np.ndarray | None],
    max_step: float,
    base_scale: float = 1.0,
    max_depth: int = 12,
) -> list[np.ndarray] | None:
    """Recursive projected bisection between two configurations of one contact manifold.

    The midpoint of every segment longer than ``max_step`` is projected back onto the contact
    constraints (``project`` returns None when it cannot); the recursion stops when consecutive
    configurations are closer than ``max_step``. A projected midpoint that lands farther from its
    neighbours than the segment itself (the manifold folds) is a failure. Returns the list of
    configurations from q_a to q_b inclusive, or None.
    """

    def dist(qx, qy):
        return step_norm(pin.difference(model, qx, qy), base_scale)

    def rec(qa, qb, depth):
        d = dist(qa, qb)
        if d <= max_step:
            return [qb]
        if depth >= max_depth:
            return None
        q_mid = project(pin.interpolate(model, qa, qb, 0.5))
        if q_mid is None:
            return None
        # projection must make progress: both halves shorter than the whole segment
        if dist(qa, q_mid) >= d or dist(q_mid, qb) >= d:
            return None
        left = rec(qa, q_mid, depth + 1)
        if left is None:
            return None
        right = rec(q_mid, qb, depth + 1)
        if right is None:
            return None
        return left + right

    rest = rec(np.asarray(q_a, dtype=float), np.asarray(q_b, dtype=float), 0)
    if rest is None:
        return None
    return [np.asarray(q_a, dtype=float)] + rest


def time_parameterize(model: pin.Model, path: Sequence[np.ndarray], max_joint_speed: float,
                      max_base_speed: float, max_base_angular_speed: float,
                      min_duration: float = 0.0, ramp_fraction: float = 0.0,
                      max_com_acceleration: float = 0.0, segment_scale: np.ndarray | None = None) -> np.ndarray:
    """Times [s] of the way-points so that no joint exceeds ``max_joint_speed`` [rad/s], the
    base ``max_base_speed`` [m/s] / ``max_base_angular_speed`` [rad/s] on any segment.

    ``ramp_fraction`` slows the first and last segments (a slow start and stop, still piecewise
    linear): segment durations are scaled by up to 2x at the ends. ``min_duration`` [s] is the
    least total duration of the path. ``max_com_acceleration`` [m/s^2] (0: no bound) bounds the
    horizontal acceleration of the centre of mass at every way-point, the path starting and ending
    at rest (:func:`bound_com_acceleration`): a quasi-static plan's ZMP then stays within
    z_com / g * that bound of the CoM's ground projection. ``segment_scale`` (one factor >= 1 per
    segment, e.g. :func:`support_edge_factors`) lengthens segments after the ramps.
    """
    n = len(path)
    if n == 0:
        return np.zeros(0)
    durations = np.zeros(n - 1)
    for i, (qa, qb) in enumerate(zip(path[:-1], path[1:])):
        dv = pin.difference(model, qa, qb)
        dt = max(np.abs(dv[6:]).max(initial=0.0) / max_joint_speed,
                 np.linalg.norm(dv[:3]) / max_base_speed,
                 np.linalg.norm(dv[3:6]) / max_base_angular_speed)
        durations[i] = dt
    if ramp_fraction > 0.0 and n > 2:
        s = np.linspace(0.0, 1.0, n - 1)
        edge = np.minimum(s, 1.0 - s) / max(ramp_fraction, 1e-9)
        durations *= 1.0 + np.clip(1.0 - edge, 0.0, 1.0)
    if segment_scale is not None and n > 1:
        durations *= np.asarray(segment_scale, dtype=float)
    total = durations.sum()
    if total < min_duration:
        durations = (durations + (min_duration - total) / max(n - 1, 1)) if total <= 0 else durations * (min_duration / total)
    if max_com_acceleration > 0.0 and n > 1:
        durations = bound_com_acceleration(model, path, durations, max_com_acceleration)
    return np.concatenate([[0.0], np.cumsum(durations)])


def support_edge_factors(model: pin.Model, path: Sequence[np.ndarray], stance, margin: float,
                         max_factor: float) -> np.ndarray | None:
    """Per-segment slow-down factors (>= 1) of a path whose stance the flat soles carry alone (no
    grasp, every hold a foot's sole with an area): where the centre of mass comes closer than ``margin``
    [m] to a heel or toe edge of the soles' convex hull (the hull edges facing along the soles'
    length), the two segments around that way-point take ``margin / distance`` times longer, at
    most ``max_factor``. The controller's CoM lags its reference and overshoots by a share of the
    CoM's speed: near the heels that is enough for G1 to tip over them (the vertical ladder's mount,
    the CoM planned 2.6 cm from the heels, fell at full speed and was executed slowed there).
    None: nothing to slow (a grasp, a contact without an area, or no way-point that near)."""
    if margin <= 0.0 or len(path) < 2 or not on_soles_alone(stance):
        return None
    from scipy.spatial import ConvexHull, QhullError  # (here: ~0.5 s to import, only when on)

    points, axis = [], np.zeros(2)
    for h in stance.holds:
        xy = h.positions[:, :2]
        _, s, vt = np.linalg.svd(xy - xy.mean(axis=0))
        if s[-1] < 1e-3:  # a line contact (a sole on a round rung): no heel edge to keep off
            return None
        axis += vt[0] if vt[0] @ axis >= 0.0 else -vt[0]  # the sole's length: its long axis
        points.append(xy)
    axis /= max(float(np.linalg.norm(axis)), 1e-12)
    try:
        hull = ConvexHull(np.vstack(points))
    except QhullError:
        return None
    eq = hull.equations[np.abs(hull.equations[:, :2] @ axis) > np.cos(np.pi / 4)]  # heel and toe edges
    if len(eq) == 0:
        return None
    data = model.createData()
    com = np.array([pin.centerOfMass(model, data, np.asarray(q, dtype=float))[:2] for q in path])
    distance = -np.max(com @ eq[:, :2].T + eq[:, 2], axis=1)
    factor = np.clip(margin / np.maximum(distance, 1e-3), 1.0, max_factor)
    if factor.max() <= 1.0:
        return None
    return np.maximum(factor[:-1], factor[1:])


def on_soles_alone(stance) -> bool:
    """Whether the flat soles carry ``stance`` alone: no grasp, and every hold a foot's with at
    least three points (a sole's area, not a point foot)."""
    from climb_core.contact import limb_type

    return bool(stance.holds) and all(not h.bilateral and limb_type(h.limb) == "foot" and len(h.positions) >= 3
                                      for h in stance.holds)


def com_acceleration_bound(stance, timing) -> float:
    """The CoM acceleration bound [m/s^2] of a transition held in ``stance`` (0: none):
    ``timing.max_com_acceleration``, and on the soles alone (:func:`on_soles_alone`) the smaller
    ``timing.soles_max_com_acceleration`` too (each 0: off)."""
    bounds = [b for b in (timing.max_com_acceleration,
                          timing.soles_max_com_acceleration if on_soles_alone(stance) else 0.0) if b > 0.0]
    return min(bounds, default=0.0)


def time_transition(model: pin.Model, path: Sequence[np.ndarray], stance, timing) -> np.ndarray:
    """Way-point times [s] of one transition's path held in ``stance`` under ``timing``
    (:class:`planner_node.settings.TimingParams`): the speed limits, ramps and least duration of
    :func:`time_parameterize`, the CoM's acceleration bounded (:func:`com_acceleration_bound`), slowed
    near the soles' heel and toe edges (:func:`support_edge_factors`)."""
    scale = support_edge_factors(model, path, stance, timing.edge_slowdown_margin, timing.edge_slowdown_max)
    return time_parameterize(model, path, timing.max_joint_speed, timing.max_base_speed,
                             timing.max_base_angular_speed, timing.min_transition_duration, timing.ramp_fraction,
                             com_acceleration_bound(stance, timing), scale)


def bound_com_acceleration(model: pin.Model, path: Sequence[np.ndarray], durations: np.ndarray,
                           max_acceleration: float, iterations: int = 200) -> np.ndarray:
    """Segment durations, lengthened where needed, under which the centre of mass's horizontal
    acceleration at every way-point is at most ``max_acceleration`` [m/s^2]: the CoM moves at a
    constant velocity along each segment, from rest at the first way-point to rest at the last, and
    changes velocity at a way-point over the half-durations of its two segments. A way-point over
    the bound stretches its two segments by sqrt(excess) (acceleration scales with 1 / time^2);
    repeated until none is over (to 1 %) or ``iterations``."""
    data = model.createData()
    com = np.array([pin.centerOfMass(model, data, np.asarray(q, dtype=float))[:2] for q in path])
    step = np.diff(com, axis=0)
    d = np.maximum(np.asarray(durations, dtype=float), 1e-6).copy()
    for _ in range(iterations):
        v = np.vstack([np.zeros(2), step / d[:, None], np.zeros(2)])  # rest before and after
        half = 0.5 * (np.concatenate([[0.0], d]) + np.concatenate([d, [0.0]]))  # time around each way-point
        acc = np.linalg.norm(np.diff(v, axis=0), axis=1) / half  # at way-points 0..n-1
        excess = acc / max_acceleration
        if excess.max() <= 1.01:
            break
        stretch = np.ones(len(d))
        for i in np.nonzero(excess > 1.0)[0]:
            f = float(np.sqrt(excess[i]))
            for k in (i - 1, i):
                if 0 <= k < len(d):
                    stretch[k] = max(stretch[k], f)
        d *= stretch
    return d


def max_joint_jump(model: pin.Model, path: Sequence[np.ndarray]) -> float:
    """Largest joint change [rad] (or base change, base_scale 1) between consecutive configurations."""
    if len(path) < 2:
        return 0.0
    return max(step_norm(pin.difference(model, qa, qb)) for qa, qb in zip(path[:-1], path[1:]))
