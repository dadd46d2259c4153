"""The end of each transition against its plan: the controller's event ``transition_finished``
(base position error, the joint farthest from the path's last configuration) and the climb
summary's ``tracking`` built from those events (what ``sweep.py --execute`` reports per ladder)."""
from __future__ import annotations

import numpy as np
import pytest

from climb_core import fixtures
from climb_core.contact import Transition
from controller_node.controller import Controller
from controller_node.estimator import RobotState
from controller_node.params import load_controller_params


@pytest.fixture(scope="module")
def controller(g1, env):
    return Controller(g1, load_controller_params(), env)


def _finish(controller, g1, stance, q_plan, q_measured, index, primitive="com_to_foot"):
    controller.transition = Transition(primitive, "", stance, stance, np.array([0.0, 1.0]),
                                       np.vstack([q_plan, q_plan]))
    controller.transition_index = index
    controller.state = RobotState(float(index), q_measured, np.zeros(g1.model.nv))
    controller.finish_transition()


def test_each_finished_transition_reports_how_far_it_ended_from_the_plan(g1, env, controller):
    from climb_coordinator.climb import tracking_summary

    stance, q = fixtures.get("ladder_4_contacts", g1, env)
    controller.events.clear()
    wrist = g1.joint_names.index("left_wrist_yaw_joint")
    knee = g1.joint_names.index("right_knee_joint")
    off = q.copy()
    off[:3] += [0.03, -0.04, 0.0]  # 5 cm off in the base
    off[7 + wrist] += 0.8  # the wrist the steep ladders leave behind
    off[7 + knee] -= 0.1
    _finish(controller, g1, stance, q, q.copy(), 0)
    _finish(controller, g1, stance, q, off, 1)
    first, second = controller.events_of("transition_finished")
    assert first.values["index"] == 0 and first.values["base_error"] == 0.0 and first.values["joint_error"] == 0.0
    assert second.values["index"] == 1 and second.values["primitive"] == "com_to_foot"
    assert second.values["base_error"] == pytest.approx(0.05)
    assert second.values["joint"] == "left_wrist_yaw_joint" and second.values["joint_error"] == pytest.approx(0.8)

    t = tracking_summary(controller)
    assert [row[0] for row in t["per_transition"]] == [0, 1]
    assert t["max_joint_error_rad"] == pytest.approx(0.8)
    assert t["max_joint_error_at"] == "transition 1 (com_to_foot): left_wrist_yaw_joint"
    assert t["max_base_error_m"] == pytest.approx(0.05)
    assert tracking_summary(None) == {"per_transition": [], "max_joint_error_rad": 0.0, "max_joint_error_at": "",
                                      "max_base_error_m": 0.0}
