"""controller_node.plan_check: a whole-body plan checked against the controller's robot and
ladder before the controller takes it; each failure names the field and the rule."""
from __future__ import annotations

import copy
import dataclasses

import numpy as np
import pytest

from climb_core import fixtures
from climb_core.errors import SpecError
from controller_node.plan_check import check_plan
from controller_node.simple_plans import limb_transfer, plan_of


@pytest.fixture(scope="module")
def plan(g1, env):
    stance, q = fixtures.get("ladder_4_contacts", g1, env)
    return plan_of(g1, env, stance, [limb_transfer(g1, env, stance, q, "right_hand", "rung_6", -0.15)])


def _edit(plan, fn):
    p = copy.deepcopy(plan)
    fn(p)
    return p


def test_a_good_plan_passes(plan, g1, env):
    check_plan(plan, g1, env)


def _set_path(p, path):
    p.transitions[0] = dataclasses.replace(p.transitions[0], path=path)


def _nan(p):
    path = p.transitions[0].path.copy()
    path[1, 12] = np.nan
    _set_path(p, path)


def _short_q(p):
    p.joint_names = p.joint_names[:-1]
    _set_path(p, p.transitions[0].path[:, :-1])


def _zero_quat(p):
    path = p.transitions[0].path.copy()
    path[0, 3:7] = 0.0
    _set_path(p, path)


def _joint_far_out(p):
    path = p.transitions[0].path.copy()
    path[2, 7] = 40.0
    _set_path(p, path)


def _far_base(p):
    path = p.transitions[0].path.copy()
    path[0, :3] = 1e6
    _set_path(p, path)


def _long(p):
    t = p.transitions[0].times.copy()
    t[-1] = 1e5
    p.transitions[0] = dataclasses.replace(p.transitions[0], times=t)


def _unknown_surface(p):
    t = p.transitions[0]
    h = t.target_stance.holds[0]
    p.transitions[0] = dataclasses.replace(t, target_stance=dataclasses.replace(
        t.target_stance, holds=(dataclasses.replace(h, env_surface="rung_99"),) + t.target_stance.holds[1:]))


def _no_target_hold(p):  # the moving limb holds nothing before nor after its transition
    t = p.transitions[0]
    p.initial_stance = p.initial_stance.without(t.moving_limb)
    p.transitions[0] = dataclasses.replace(t, target_stance=t.target_stance.without(t.moving_limb))


def _empty_path(p):
    t = p.transitions[0]
    p.transitions[0] = dataclasses.replace(t, path=np.zeros((0, t.path.shape[1])), times=np.zeros(0))


@pytest.mark.parametrize("edit, field, rule", [
    (lambda p: setattr(p, "robot", "talos"), "whole_body_plan.robot", "talos"),
    (_short_q, "whole_body_plan.joint_names", "misses the robot's joint"),
    (lambda p: p.joint_names.__setitem__(3, "tail_joint"), "whole_body_plan.joint_names", "unknown joint 'tail_joint'"),
    (lambda p: p.joint_names.reverse(), "whole_body_plan.joint_names", "in its order"),
    (_nan, "whole_body_plan.transitions[0].path[1]", "finite"),
    (_zero_quat, "whole_body_plan.transitions[0].path[0]", "unit quaternion"),
    (_joint_far_out, "whole_body_plan.transitions[0].path[2]", "outside its limits"),
    (_far_base, "whole_body_plan.transitions[0].path[0]", "away"),
    (_long, "whole_body_plan.transitions[0].times", "at most"),
    (_unknown_surface, "whole_body_plan.transitions[0].target_stance.holds[0].env_surface", "rung_99"),
    (_no_target_hold, "whole_body_plan.transitions[0].target_stance", "no hold for the moving limb"),
    (_empty_path, "whole_body_plan.transitions[0].path", "at least one way-point"),
    (lambda p: setattr(p.transitions[0], "moving_limb", "tail"), "whole_body_plan.transitions[0].moving_limb",
     "no limb"),
], ids=["robot", "short_q", "unknown_joint", "joint_order", "nan", "zero_quaternion", "joint_limit", "far_base",
        "duration", "unknown_surface", "no_target_hold", "empty_path", "unknown_limb"])
def test_a_bad_plan_is_refused_naming_the_field(plan, g1, env, edit, field, rule):
    with pytest.raises(SpecError) as err:
        check_plan(_edit(plan, edit), g1, env)
    assert err.value.field == field and rule in err.value.rule, str(err.value)


def test_a_limb_freed_for_good_is_accepted(plan, g1, env):
    """A transition whose moving limb held something before and nothing after frees the limb (the
    FSM's ``freed``: a scene's hand leaving its support for good, narrow_passage_step)."""
    def free(p):
        i = next(k for k, t in enumerate(p.transitions) if t.moving_limb)
        t = p.transitions[i]
        p.transitions[i] = dataclasses.replace(t, target_stance=t.target_stance.without(t.moving_limb))
        p.transitions[i + 1:] = []
    freed = _edit(plan, free)
    check_plan(freed, g1, env)
