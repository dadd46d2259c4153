"""sim/contacts' computation (sim_bridge.contacts, no ROS) and the backend's refusals before any
change (issue 20 rows 7 and 8) on headless PyBullet."""
from __future__ import annotations

import numpy as np
import pytest

from climb_core.errors import SpecError
from sim_bridge.backend import ResetRequest
from sim_bridge.commands import PerturbRequest
from sim_bridge.contacts import rung_of
from sim_bridge.params import load_bridge_params
from sim_bridge.pybullet_backend import PyBulletBackend

pytestmark = pytest.mark.sim

G = 9.81  # [m/s^2]


@pytest.fixture(scope="module")
def backend():
    b = PyBulletBackend(load_bridge_params())
    b.reset(ResetRequest(robot="g1", ladder="default", initial_posture="standing"))
    yield b
    b.close()


def hold_still(backend, ticks: int = 40) -> None:
    """A few ticks under joint-space PD at the current posture (enough to settle the contacts)."""
    from sim_bridge.commands import POSITION, ActuatorCommand

    q = backend.observe().q.copy()
    n = len(backend.joint_names)
    for _ in range(ticks):
        backend.step(ActuatorCommand(modes=np.full(n, POSITION, dtype=np.uint8), values=q))


def test_rung_of():
    assert [rung_of(s) for s in ("rung_3", "rung_12", "ground", "rail_left", "", "rung_x")] == [3, 12, -1, -1, -1, -1]


def test_standing_on_the_ground(backend):
    backend.reset(ResetRequest(initial_posture="standing"))
    hold_still(backend)
    snap = backend.contacts()
    assert [c.limb for c in snap.limbs] == ["left_foot", "right_foot", "left_hand", "right_hand"]
    feet = [snap.limb("left_foot"), snap.limb("right_foot")]
    assert all(f.surface == "ground" and f.rung == -1 and not f.grasped for f in feet)
    import pinocchio as pin

    weight = pin.computeTotalMass(backend.robot.model) * G
    assert sum(f.normal_force for f in feet) == pytest.approx(weight, rel=0.15)
    assert all(f.tangential_force < 0.2 * f.normal_force for f in feet)
    for hand in ("left_hand", "right_hand"):
        c = snap.limb(hand)
        assert (c.surface, c.rung, c.grasped, c.normal_force) == ("", -1, False, 0.0)
    assert snap.stamp_ns == backend.stamp_ns and not snap.fell


def test_four_contacts_on_the_ladder(backend):
    backend.reset(ResetRequest(initial_posture="ladder_4_contacts"))
    hold_still(backend, 20)
    snap = backend.contacts()
    left, right = snap.limb("left_foot"), snap.limb("right_foot")
    assert left.rung >= 1 and left.rung == right.rung and left.surface == f"rung_{left.rung}"
    assert left.normal_force > 20.0 and right.normal_force > 20.0
    for hand in ("left_hand", "right_hand"):
        c = snap.limb(hand)
        assert c.grasped and c.surface.startswith(("rung_", "rail_")), c
        assert c.rung == rung_of(c.surface)


def test_failed_reset_changes_nothing(backend):
    backend.reset(ResetRequest(initial_posture="standing"))
    hold_still(backend, 10)
    stamp, q, source = backend.stamp_ns, backend.observe().q.copy(), backend.ladder_source
    backend.request_perturbation(PerturbRequest("rung_offset", rung=1, dx=0.01, at_time=10.0))
    for request in (ResetRequest(ladder="no_such_ladder"), ResetRequest(robot="banana"),
                    ResetRequest(q=np.zeros(3)), ResetRequest(initial_posture="upside_down")):
        with pytest.raises(SpecError):
            backend.reset(request)
        assert backend.stamp_ns == stamp and backend.ladder_source == source
        assert np.array_equal(backend.observe().q, q)
        assert len(backend.pending_requests()) == 1
    backend.step()  # the world still runs
    backend.reset(ResetRequest())  # keeps the last good ladder
    assert backend.stamp_ns == 0 and backend.ladder_source == source


def test_perturbations_checked_against_the_world(backend):
    backend.reset(ResetRequest(initial_posture="standing"))
    n = backend.env.n_rungs
    for request, field in [(PerturbRequest("drop", mass=2.0, radius=0.1, speed=3.0, target_link="nope"), "target_link"),
                           (PerturbRequest("drop", mass=2.0, radius=0.1, speed=1e6, target_link="torso"), "speed"),
                           (PerturbRequest("drop", mass=500.0, radius=0.1, speed=3.0, target_link="torso"), "mass"),
                           (PerturbRequest("rung_offset", rung=n + 1, dx=0.01), "rung"),
                           (PerturbRequest("rung_offset", rung=1, dz=-0.6), "dz"),
                           (PerturbRequest("rails_shift", dy=0.01), "kind")]:
        with pytest.raises(SpecError) as info:
            backend.check_perturbation(request)
        assert info.value.field == f"perturbation.{field}"
    backend.check_perturbation(PerturbRequest("rung_offset", rung=n, dx=0.01))
    backend.check_perturbation(PerturbRequest("drop", mass=2.0, radius=0.1, speed=3.0, target_link="left_hand"))


def test_same_numbers_as_the_in_process_judge(backend):
    """sim/contacts' computation agrees with climb_coordinator.judge (the in-process climb's)."""
    from climb_coordinator.judge import limb_loads

    backend.reset(ResetRequest(initial_posture="ladder_4_contacts"))
    hold_still(backend, 20)
    snap, loads = backend.contacts(), limb_loads(backend)
    for c in snap.limbs:
        load = loads.get(c.limb)
        if load is None:
            assert c.normal_force == 0.0 and c.tangential_force == 0.0
            continue
        assert c.normal_force == pytest.approx(max(load.normal_force, 0.0), abs=1e-9)
        assert c.tangential_force == pytest.approx(load.tangential_force, abs=1e-9)
        if not c.grasped:
            assert c.surface == load.surface
