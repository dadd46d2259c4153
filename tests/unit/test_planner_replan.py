"""Replanning from a measured state: a configuration a few mm off the contact manifold is projected
back onto the held stance and planned from; a state far from the stance is refused by name."""
from __future__ import annotations

import numpy as np
import pytest

from climb_core import fixtures
from climb_core.errors import InfeasibleError


def test_a_measured_state_near_the_stance_is_projected_and_planned_from(g1, env):
    from planner_node.replan import measured_start, plan_from_measured

    stance, q = fixtures.get("ladder_4_contacts", g1, env)
    rng = np.random.default_rng(3)
    q_meas = q.copy()
    q_meas[:3] += rng.normal(0.0, 0.002, 3)  # [m] base estimate error
    q_meas[7:] += rng.normal(0.0, 0.003, g1.model.nq - 7)  # [rad] encoder / compliance error
    q0 = measured_start(g1, env, q_meas, stance)
    assert np.linalg.norm(q0[:3] - q_meas[:3]) < 0.02
    res = plan_from_measured(g1, env, q_meas, stance, 1, seed=0, timeout_s=60)
    assert res.success, res.failure_detail
    assert np.allclose(res.plan.transitions[0].path[0], q0)
    feet = {h.limb: h.env_surface for h in res.plan.transitions[-1].target_stance.holds if h.limb.endswith("foot")}
    assert feet == {"left_foot": "rung_2", "right_foot": "rung_2"}


def test_a_measured_state_off_the_stance_is_refused_with_the_reason(g1, env):
    from planner_node.replan import measured_start

    stance, q = fixtures.get("ladder_4_contacts", g1, env)
    far = q.copy()
    far[2] -= 0.5  # [m] half a metre below: the holds are out of reach
    with pytest.raises(InfeasibleError, match="start_projection"):
        measured_start(g1, env, far, stance)
    with pytest.raises(InfeasibleError, match="q_measured"):
        measured_start(g1, env, q[:10], stance)
