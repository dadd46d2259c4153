"""What the PyBullet backend collides and how it drives the fingers (the choices that keep a
physics step cheap, docs/sim_bridge.md): self-collision between chains only, fingers out of
self-collision but driven by their servo, a finite ground box."""
from __future__ import annotations

import numpy as np
import pytest

from sim_bridge.backend import ResetRequest
from sim_bridge.commands import GripperRequest
from sim_bridge.pybullet_backend import PyBulletBackend
from sim_bridge.simple_control import GravityCompensatedPd
from sim_bridge.world_bodies import surface_lateral_friction

pytestmark = pytest.mark.sim


@pytest.fixture(scope="module")
def backend():
    b = PyBulletBackend()
    b.reset(ResetRequest(robot="g1", ladder="default", initial_posture="standing"))
    yield b
    b.close()


def chain_of(backend, link_name: str) -> str:
    return backend._collision_chains()[backend.link_index[link_name]]


def test_crossed_legs_collide_but_a_chain_does_not_collide_with_itself(backend):
    """Both hips rolled fully inward (in the air, at rest): PyBullet reports contacts between the
    two legs, none between two links of one leg, none involving a finger."""
    robot = backend.robot
    q = robot.q_reference()
    q[2] += 1.0  # [m] in the air: no ground contact
    joints = list(robot.joint_names)
    for name in ("left_hip_roll_joint", "right_hip_roll_joint"):
        lo, hi = backend.joint_info[name][8], backend.joint_info[name][9]
        q[7 + joints.index(name)] = lo if name.startswith("left") else hi  # adduction limit
    backend.set_state(q)
    backend.step()
    p = backend.p
    pairs = {(chain_of(backend, backend.link_name(c[3])), chain_of(backend, backend.link_name(c[4])))
             for c in p.getContactPoints(bodyA=backend.body, bodyB=backend.body, physicsClientId=backend.client)}
    assert {("left_foot", "right_foot"), ("right_foot", "left_foot")} & pairs, pairs  # the legs meet
    assert all(a != b for a, b in pairs)  # never two links of one chain
    fingers = {backend.link_name(j) for j in backend._fingers}
    assert not any(a in fingers or b in fingers for a, b in backend.checked_pairs)
    assert ("left_knee_link", "right_knee_link") in backend.checked_pairs
    assert ("left_hip_pitch_link", "left_knee_link") not in backend.checked_pairs


def test_finger_servo_closes_and_opens_the_hand(backend):
    """CLOSE away from any rung latches nothing, but the fingers close (explicit PD, capped at the
    finger effort limits) within 0.1 s; OPEN brings them back; the other hand stays open."""
    state = backend.reset(ResetRequest(robot="g1", ladder="default", initial_posture="standing"))
    ctl = GravityCompensatedPd(backend.robot, backend.robot.q_reference())
    p = backend.p

    def finger_q(hand: str) -> np.ndarray:
        idx = backend.hand_fingers[hand]
        return np.array([p.getJointState(backend.body, backend._fingers[k], physicsClientId=backend.client)[0]
                         for k in idx])

    left = backend.hand_fingers["left_hand"]
    closed, open_ = backend.finger_closed[left], backend.finger_open[left]
    travel = np.abs(closed - open_)
    backend.request_gripper(GripperRequest("left_hand", "close"))
    for _ in range(20):  # 0.1 s
        state = backend.step(ctl(state))
    assert state.grasps["left_hand"] == "" and state.finger_positions["left_hand"] == 1.0
    moved = travel > 0
    # within 10 % of the travel (gravity sags the light phalanges a little under the soft servo)
    assert np.all(np.abs(finger_q("left_hand") - closed)[moved] < 0.1 * travel[moved])
    assert np.all(np.abs(finger_q("right_hand") - backend.finger_open[backend.hand_fingers["right_hand"]]) < 0.1)
    backend.request_gripper(GripperRequest("left_hand", "open", stamp_ns=state.stamp_ns))
    for _ in range(20):
        state = backend.step(ctl(state))
    assert np.all(np.abs(finger_q("left_hand") - open_) < 0.1)
    assert not state.fell


def test_the_ground_is_a_finite_box_with_its_top_at_zero(backend):
    """GEOM_PLANE's infinite bounding box would put every link in the narrowphase: the ground is
    the planner's coal box instead, same friction."""
    p, cid = backend.p, backend.client
    shape = p.getCollisionShapeData(backend.ground_body, -1, physicsClientId=cid)[0]
    assert shape[2] == p.GEOM_BOX
    lo, hi = p.getAABB(backend.ground_body, physicsClientId=cid)
    assert hi[2] == pytest.approx(0.0, abs=0.05)  # AABB margin only
    hit = p.rayTest([3.0, 2.0, 1.0], [3.0, 2.0, -1.0], physicsClientId=cid)[0]
    assert hit[0] == backend.ground_body and hit[3][2] == pytest.approx(0.0, abs=1e-6)
    mu = p.getDynamicsInfo(backend.ground_body, -1, physicsClientId=cid)[1]
    assert mu == pytest.approx(surface_lateral_friction(backend.env, backend.env.surfaces["ground"]))
