"""controller_node.contact_set without a controller: engage and release ramps on real contacts
made from G1's holds on the default ladder (the 4-contact fixture)."""
from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from climb_core import fixtures
from climb_core.contact import LIMBS
from climb_core.environment import build_environment
from climb_core.ladder import load_scenario
from climb_core.robot import load_robot
from controller_node.constraints import contact_from_hold
from controller_node.contact_set import ContactSet, mean_normal


@pytest.fixture(scope="module")
def made():
    robot = load_robot("g1")
    env = build_environment(load_scenario("default"))
    stance, q = fixtures.get("ladder_4_contacts", robot, env)
    data = robot.model.createData()
    pin.framesForwardKinematics(robot.model, data, q)
    out = {}
    for hold in stance.holds:
        limb = robot.config.limbs[hold.limb]
        fid = robot.model.getFrameId(limb.surface.frame)
        out[hold.limb] = (hold, contact_from_hold(hold, fid, data.oMf[fid], np.asarray(limb.surface.T_frame_surface),
                                                  force_limit=1000.0, torque_limit=10.0))
    return out


def fresh(made) -> ContactSet:
    import copy

    s = ContactSet()
    for limb, (hold, contact) in made.items():
        s.put(limb, hold, copy.deepcopy(contact), now=0.0)
    return s


def test_contacts_come_in_the_fixed_limb_order_and_engage_over_their_ramp(made):
    s = fresh(made)
    assert s.limbs() == tuple(limb for limb in LIMBS if limb in made)
    assert [c.limb for c in s.ordered()] == list(s.limbs())
    hold, contact = made["right_hand"]
    s.remove("right_hand")
    assert not s.has("right_hand") and not s.remove("right_hand")
    import copy

    s.put("right_hand", hold, copy.deepcopy(contact), now=1.0, engage_s=0.5)
    s.advance(1.25)
    assert s.active["right_hand"].scale == pytest.approx(0.5) and not s.ready("right_hand", 1.25)
    s.advance(1.5)
    assert s.active["right_hand"].scale == 1.0 and s.ready("right_hand", 1.5) and "right_hand" not in s.ramps


def test_a_release_caps_the_force_from_the_load_it_carried_down_to_zero(made):
    s = fresh(made)
    foot = s.active["left_foot"]
    n = mean_normal(foot)
    assert n[2] > 0.9  # a sole on a rung: up
    s.last_loads["left_foot"] = np.concatenate([120.0 * n, np.zeros(3)])
    assert s.begin_release("left_foot", now=2.0, duration=1.0)
    s.advance(2.5)
    assert foot.ramp_cap == pytest.approx(0.5 * 121.0) and foot.scale == pytest.approx(0.5)
    assert not s.release_done("left_foot", 2.5) and s.release_done("left_foot", 3.0)
    # a grasp keeps its share; its cap is (force norm, largest moment) + margins
    s.last_loads["right_hand"] = np.array([0.0, 30.0, 40.0, 1.0, -3.0, 0.0])
    s.begin_release("right_hand", now=2.0, duration=1.0)
    s.advance(2.5)
    hand = s.active["right_hand"]
    assert hand.scale == 1.0 and np.allclose(hand.ramp_cap, 0.5 * np.array([51.0, 3.5]))
    assert not s.begin_release("nobody", now=2.0, duration=1.0)


def test_a_cancelled_release_gives_the_contact_its_full_share_and_restore_brings_back_what_left(made):
    s = fresh(made)
    snapshot, holds = dict(s.active), dict(s.holds)
    s.last_loads["left_foot"] = np.array([0.0, 0.0, 100.0, 0.0, 0.0, 0.0])
    s.begin_release("left_foot", now=0.0, duration=1.0)
    s.advance(0.5)
    s.remove("right_foot")
    assert s.cancel(("release",)) == ["left_foot"]
    foot = s.active["left_foot"]
    assert foot.scale == 1.0 and foot.ramp_cap is None and not s.ramps
    s.restore(snapshot, holds)
    assert s.limbs() == tuple(limb for limb in LIMBS if limb in made)
    s.clear()
    assert not s.active and not s.holds and not s.ramps and s.last_loads  # loads outlive the set
