"""A closed grasp keeps the roll about its rung it latched with (``projection.latch_grasps``):
``adapt.latch_grasps`` pins each grasp of a state's stance at its pose in the state's configuration,
and the IK then holds all six rows of that grasp instead of leaving the roll free."""
from __future__ import annotations

import dataclasses

import numpy as np
import pinocchio as pin

from climb_core import fixtures
from climb_core import ik as core_ik
from planner_node import adapt, settings as settings_mod
from planner_node.contact_path import empty_library


def _ctx(g1, env, latch: bool):
    s = settings_mod.load_settings()
    s = dataclasses.replace(s, projection=dataclasses.replace(s.projection, latch_grasps=latch),
                            contact_path=dataclasses.replace(s.contact_path, latch_grasps=latch))
    return adapt.AdaptContext(g1, env, empty_library(g1), s)


def _roll(g1, limb, q_a, q_b) -> float:
    """[rad] rotation of the limb's grasp surface between two configurations."""
    Ra = g1.T_world_surface(limb, q_a)[:3, :3]
    Rb = g1.T_world_surface(limb, q_b)[:3, :3]
    return float(np.linalg.norm(pin.log3(Ra.T @ Rb)))


def test_latched_grasps_keep_their_roll_and_feet_are_untouched(g1, env):
    stance, q = fixtures.get("ladder_4_contacts", g1, env)
    state = adapt.ClimbState(q, stance)
    ctx = _ctx(g1, env, latch=True)
    latched = adapt.latch_grasps(ctx, state)
    assert adapt.latch_grasps(ctx, state) is latched  # one latched state per state: stable hold ids
    for h in latched.stance.holds:
        if h.bilateral:
            assert np.allclose(np.asarray(h.pose), g1.T_world_surface(h.limb, q, surface=h.robot_surface))
            assert h == stance.hold(h.limb)  # the pose does not change what the hold is
        else:
            assert h.pose is None and h is stance.hold(h.limb)
    rows = {t.limb: t.rows.shape[0] for t in core_ik.contact_tasks(g1, env, q, latched.stance, ctx.hold_params)}
    free = {t.limb: t.rows.shape[0] for t in core_ik.contact_tasks(g1, env, q, stance, ctx.hold_params)}
    assert rows["left_hand"] == rows["right_hand"] == 6 and free["left_hand"] == free["right_hand"] == 5

    # the torso moved 6 cm toward the ladder: projected back onto the stance, a latched hand keeps
    # its orientation; a free one may turn about the rung
    moved = q.copy()
    moved[0] += 0.06
    moved[7:] += np.random.default_rng(0).normal(0.0, 0.05, len(q) - 7)
    q_latched = adapt.ContactProjector(ctx, latched.stance, moved)(moved)
    assert q_latched is not None
    for hand in ("left_hand", "right_hand"):
        assert _roll(g1, hand, q, q_latched) < 2e-3, hand

    off = _ctx(g1, env, latch=False)
    assert adapt.latch_grasps(off, state) is state
    q_free = adapt.ContactProjector(off, stance, moved)(moved)  # measured: 29 and 7.5 mrad of roll
    assert max(_roll(g1, hand, q, q_free) for hand in ("left_hand", "right_hand")) > 5e-3


def test_the_generic_paths_keep_a_held_grasps_roll(g1, env):
    """With ``contact_path.latch_grasps`` (the ship ladder's file sets it) the search strategy's
    steps (planner_node.contact_path: here a CoM shift with both hands on their rungs) latch the
    grasps of the state they start from, as the primitive adaptation does: the simulator's grasp
    is rigid. Unlatched, the ship ladder's plan rolled the
    held hands 0.6-0.8 rad about the rails in a CoM shift; executed, the wrists were 1.1 rad off
    their plan and the robot fell at the first re-grasp."""
    from planner_node import contact_path
    from planner_node.msp import Step

    stance, q = fixtures.get("ladder_4_contacts", g1, env)
    ctx = _ctx(g1, env, latch=True)
    rng = np.random.default_rng(0)
    # the end seed: the torso 5 cm lower and the arms turned, so that a free grasp would roll
    q_end = q.copy()
    q_end[2] -= 0.05
    q_end[7:] += np.random.default_rng(1).normal(0.0, 0.08, len(q) - 7)
    step = contact_path.com_step(ctx, adapt.ClimbState(q, stance), q_end, ("left_foot",), 0, rng)
    assert isinstance(step, Step), step
    path = step.segment.transition.path
    for hand in ("left_hand", "right_hand"):
        assert max(_roll(g1, hand, q, p) for p in path) < 2e-3, hand
