"""Does the controller's contact model admit what the planner planned? (diagnostics, ROS-free)

The planner certifies every configuration with :func:`climb_core.feasibility.check` (point forces,
friction pyramids, grip polytopes). The controller holds the same stance with its own contact
model (generator cones, 6D grasp wrenches with force and moment caps, ramps). If the controller's
set of static contact forces is smaller, a planned stance can be impossible to hold under the QP
even at rest: the QP saturates torques and the posture drifts (what a 45 deg rotated friction
pyramid once did to the first climb).

:func:`static_torque_ratio` answers it for the controller's current state: the least achievable
max_j |tau_j| / effort_j over every contact force distribution the QP's contact rows allow, at
zero acceleration. A value <= ``qp.torque_limit_fraction`` means the QP can hold the stance.
"""
from __future__ import annotations

import numpy as np
from scipy.optimize import linprog

from .qp import QpProblem

#: row blocks of the whole-body problem that do not constrain a static force distribution
_SKIPPED = ("torque_limits", "collision")


def static_torque_ratio(problem: QpProblem, nv: int, effort: np.ndarray) -> float:
    """min r s.t. qdd = 0, the problem's equality / contact-force rows, |tau_j| <= r effort_j,
    where tau = (actuated dynamics rows) x + h is read off the ``torque_limits`` block (its bounds
    are -+tau_max - h). Returns inf when no static distribution exists."""
    blocks = {}
    for name, a, b in problem.row_blocks:
        blocks.setdefault(name, []).append((a, b))
    if "torque_limits" not in blocks:
        raise ValueError("the problem has no torque_limits block")
    (ta, tb), = blocks["torque_limits"]
    n = problem.n
    A_tau = problem.A[ta:tb]
    bias = 0.5 * (problem.lower[ta:tb] + problem.upper[ta:tb])  # -h (actuated)
    effort = np.asarray(effort, float)
    # variables [x, r]: (A_tau x - bias) / effort in [-r, r]
    ub_rows = [np.hstack([A_tau, -effort[:, None]]), np.hstack([-A_tau, -effort[:, None]])]
    ub_rhs = [bias, -bias]
    eq_rows, eq_rhs = [], []
    for name, segments in blocks.items():
        if name in _SKIPPED:
            continue
        for a, b in segments:
            for i in range(a, b):
                row = np.append(problem.A[i], 0.0)
                if problem.is_eq[i]:
                    eq_rows.append(row)
                    eq_rhs.append(problem.lower[i])
                    continue
                if np.isfinite(problem.upper[i]):
                    ub_rows.append(row[None])
                    ub_rhs.append([problem.upper[i]])
                if np.isfinite(problem.lower[i]):
                    ub_rows.append(-row[None])
                    ub_rhs.append([-problem.lower[i]])
    lb = np.where(np.isfinite(problem.lb), problem.lb, -np.inf)
    ub = np.where(np.isfinite(problem.ub), problem.ub, np.inf)
    bounds = [(0.0, 0.0)] * nv + [(None if not np.isfinite(lo) else lo, None if not np.isfinite(hi) else hi)
                                  for lo, hi in zip(lb[nv:n], ub[nv:n])] + [(0.0, None)]
    cost = np.zeros(n + 1)
    cost[-1] = 1.0
    res = linprog(cost, A_ub=np.vstack(ub_rows), b_ub=np.concatenate(ub_rhs),
                  A_eq=np.array(eq_rows) if eq_rows else None, b_eq=np.array(eq_rhs) if eq_rows else None,
                  bounds=bounds, method="highs")
    return float(res.x[-1]) if res.status == 0 else float("inf")


def controller_static_ratio(controller) -> float:
    """:func:`static_torque_ratio` of the problem the controller would solve now (its active
    contacts and tasks, its state)."""
    contacts = [controller.contacts[limb] for limb in controller.contacts]
    problem = controller.wb.build(contacts, controller.active_tasks)
    return static_torque_ratio(problem, controller.model.nv, controller.effort_limits)
