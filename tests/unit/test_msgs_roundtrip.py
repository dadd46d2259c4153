"""msgs_py conversions: dataclass -> message -> CDR bytes -> message -> dataclass is the identity,
and malformed messages raise SpecError naming the field. No rclpy.init() needed."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from builtin_interfaces.msg import Time
from climb_msgs.msg import ClimbStatus, ControllerState, GripperCommand, JointCommand
from rclpy.serialization import deserialize_message, serialize_message
from scipy.spatial.transform import Rotation

import msgs_py as mp
from climb_core.contact import (ContactPlan, ContactPoint, GuidePath, Hold, Stance, Transition,
                                WholeBodyPlan)
from climb_core.errors import SpecError

N_JOINTS = 29  # G1 without fingers
JOINTS = [f"joint_{i}" for i in range(N_JOINTS)]
NQ = 7 + N_JOINTS


def wire(msg):
    """Serialize to CDR and back (proves a real rosidl type); the copy must equal the original."""
    data = serialize_message(msg)
    assert isinstance(data, bytes) and len(data) > 0
    back = deserialize_message(data, type(msg))
    assert back == msg
    return back


def assert_same(a, b, path="obj"):
    if dataclasses.is_dataclass(a):
        assert type(a) is type(b), path
        for f in dataclasses.fields(a):
            assert_same(getattr(a, f.name), getattr(b, f.name), f"{path}.{f.name}")
    elif isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        a, b = np.asarray(a), np.asarray(b)
        assert a.shape == b.shape, f"{path}: {a.shape} != {b.shape}"
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-14, err_msg=path)
    elif isinstance(a, (list, tuple)):
        assert type(a) is type(b) and len(a) == len(b), path
        for i, (x, y) in enumerate(zip(a, b)):
            assert_same(x, y, f"{path}[{i}]")
    elif isinstance(a, dict):
        assert list(a) == list(b), path
        for k in a:
            assert_same(a[k], b[k], f"{path}[{k}]")
    else:
        assert a == b, f"{path}: {a!r} != {b!r}"


@pytest.fixture
def rng():
    return np.random.default_rng(7)


def random_q(rng, n=NQ):
    q = rng.normal(size=n)
    q[3:7] /= np.linalg.norm(q[3:7])
    return q


def grasp_hold(rng, limb="left_hand", rung="rung_3"):
    centre = rng.normal(size=3)
    angles = np.linspace(0.0, 2 * np.pi, 8, endpoint=False)
    normals = np.stack([np.zeros(8), np.cos(angles), np.sin(angles)], axis=1)
    points = tuple(ContactPoint(centre + 0.016 * n, n) for n in normals)  # 32 mm rung
    return Hold(limb, limb.replace("hand", "grasp"), rung, points, friction=0.6, bilateral=True,
                grip_force_limit=180.0)


def foot_hold(rng, limb="left_foot", rung="rung_1"):
    points = tuple(ContactPoint(rng.normal(size=3), rng.normal(size=3)) for _ in range(2))
    return Hold(limb, limb.replace("foot", "sole"), rung, points, friction=0.8)


def four_contact_stance(rng, name="s4"):
    return Stance((foot_hold(rng, "left_foot"), foot_hold(rng, "right_foot", "rung_2"),
                   grasp_hold(rng, "left_hand", "rung_5"), grasp_hold(rng, "right_hand", "rung_5")), name=name)


# --- geometry and time ----------------------------------------------------------------------

def test_geometry_roundtrip_through_the_wire(rng):
    p, v, w = rng.normal(size=3), rng.normal(size=3), rng.normal(size=6)
    assert np.array_equal(mp.point_from_msg(wire(mp.point_to_msg(p))), p)
    assert np.array_equal(mp.vector3_from_msg(wire(mp.vector3_to_msg(v))), v)
    assert np.array_equal(mp.wrench_from_msg(wire(mp.wrench_to_msg(w))), w)
    wrench = mp.wrench_to_msg(w)
    assert (wrench.force.z, wrench.torque.x) == (w[2], w[3])  # force first, then torque
    for R in Rotation.random(20, random_state=3).as_matrix():
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = R, rng.normal(size=3)
        np.testing.assert_allclose(mp.pose_from_msg(wire(mp.pose_to_msg(T))), T, atol=1e-12)


def test_rotation_quaternion_matches_scipy_in_every_branch():
    # random rotations plus half turns, where trace(R) = -1 and the w-branch would divide by ~0
    half_turns = Rotation.from_rotvec(np.pi * np.array([[1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 0]]) /
                                      np.linalg.norm([[1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 0]], axis=1)[:, None])
    for rot in list(Rotation.random(50, random_state=5)) + list(half_turns):
        q = mp.rotation_to_quaternion(rot.as_matrix())
        q_ref = rot.as_quat()  # scipy is (x, y, z, w) too
        assert abs(abs(q @ q_ref) - 1.0) < 1e-12
        np.testing.assert_allclose(mp.quaternion_to_rotation(q), rot.as_matrix(), atol=1e-12)
        assert q[3] >= 0.0


def test_time_conversions_are_exact_on_the_nanosecond_grid(rng):
    for sec, nanosec in zip(rng.integers(0, 4_000_000, 200), rng.integers(0, 10**9, 200)):
        t = mp.time_to_seconds(Time(sec=int(sec), nanosec=int(nanosec)))
        back = wire(mp.seconds_to_time(t))
        assert (back.sec, back.nanosec) == (sec, nanosec)
    assert (mp.seconds_to_time(-1.25).sec, mp.seconds_to_time(-1.25).nanosec) == (-2, 750_000_000)
    carried = mp.seconds_to_time(2.9999999999)  # rounds up into the next second
    assert (carried.sec, carried.nanosec) == (3, 0)
    assert mp.duration_to_seconds(wire(mp.seconds_to_duration(0.005))) == pytest.approx(0.005, abs=1e-12)
    header = wire(mp.make_header(12.5, "world"))
    assert header.frame_id == "world" and mp.header_stamp(header) == 12.5


# --- contact data ---------------------------------------------------------------------------

def test_contact_point_hold_and_stance_roundtrip(rng):
    point = ContactPoint(rng.normal(size=3), rng.normal(size=3))
    assert mp.contact_point_from_msg(wire(mp.contact_point_to_msg(point))) == point
    for hold in (grasp_hold(rng), foot_hold(rng)):
        back = mp.hold_from_msg(wire(mp.hold_to_msg(hold)))
        assert back == hold
        assert_same(back, hold)
    stance = four_contact_stance(rng)
    back = mp.stance_from_msg(wire(mp.stance_to_msg(stance)))
    assert back == stance and back.limbs == stance.limbs
    assert back.hold("right_hand").grip_force_limit == 180.0 and back.hold("right_hand").bilateral


def test_guide_path_and_contact_plan_roundtrip(rng):
    path = GuidePath("g1", "ladder_75deg", list(JOINTS), [random_q(rng) for _ in range(12)])
    msg = wire(mp.guide_path_to_msg(path, stamp=3.25))
    assert msg.header.frame_id == mp.WORLD_FRAME and mp.header_stamp(msg.header) == 3.25
    assert_same(mp.guide_path_from_msg(msg), path)
    stances = [four_contact_stance(rng, f"s{i}") for i in range(5)]
    stances[2] = stances[2].without("left_hand")
    plan = ContactPlan("g1", "ladder_75deg", list(JOINTS), stances, [random_q(rng) for _ in stances])
    back = mp.contact_plan_from_msg(wire(mp.contact_plan_to_msg(plan)))
    assert_same(back, plan)
    assert back.stances[2].limbs == ("left_foot", "right_foot", "right_hand")


def test_transition_and_whole_body_plan_roundtrip(rng):
    s0 = four_contact_stance(rng, "s0")
    transitions = []
    for i, limb in enumerate(["", "left_hand", "right_foot"]):
        n = 40 + i
        transitions.append(Transition(
            primitive="com_to_centre" if not limb else "place_hand", moving_limb=limb,
            stance=s0.without(limb) if limb else s0, target_stance=s0,
            times=np.cumsum(rng.uniform(0.01, 0.05, n)), path=np.stack([random_q(rng) for _ in range(n)])))
    plan = WholeBodyPlan("g1", "ladder_75deg", list(JOINTS), s0, transitions)
    msg = wire(mp.whole_body_plan_to_msg(plan, stamp=1.0))
    assert len(msg.transitions[1].path) == 41 and len(msg.transitions[1].path[0].q) == NQ
    back = mp.whole_body_plan_from_msg(msg)
    assert_same(back, plan)
    assert back.transitions[2].path.shape == (42, NQ)
    single = mp.transition_from_msg(wire(mp.transition_to_msg(transitions[0])))
    assert_same(single, transitions[0])
    # a transition without way-points keeps its width when the joint names are known
    empty = Transition("dismount", "", s0, s0, np.zeros(0), np.zeros((0, NQ)))
    assert mp.transition_from_msg(wire(mp.transition_to_msg(empty, JOINTS)), JOINTS).path.shape == (0, NQ)


# --- commands and status --------------------------------------------------------------------

def test_joint_command_roundtrip_and_mode_names(rng):
    modes = ["pwm"] * 12 + ["torque"] * 17
    cmd = mp.JointCommandData(names=JOINTS, modes=modes, values=rng.uniform(-1, 1, N_JOINTS), stamp=10.005)
    msg = wire(mp.joint_command_to_msg(cmd))
    assert list(msg.modes[:12]) == [JointCommand.PWM] * 12 and msg.modes[12] == JointCommand.TORQUE
    back = mp.joint_command_from_msg(msg, joint_names=JOINTS)
    assert back == cmd and back.mode_names == tuple(modes)
    assert back.stamp == cmd.stamp  # lock-step: the stamp survives exactly
    # one mode for every joint, built from kwargs
    damp = mp.joint_command_to_msg(names=JOINTS[:3], modes="damping", values=[0.0, 0.0, 0.0])
    assert list(damp.modes) == [JointCommand.DAMPING] * 3
    assert mp.validate_joint_command(damp).names == tuple(JOINTS[:3])


def test_gripper_controller_state_and_climb_status_roundtrip():
    grip = mp.GripperCommandData(hand="right_hand", command="position", position=0.4, stamp=2.0)
    msg = wire(mp.gripper_command_to_msg(grip))
    assert msg.command == GripperCommand.POSITION
    assert mp.gripper_command_from_msg(msg) == grip
    assert mp.gripper_command_from_msg(mp.gripper_command_to_msg(hand="left_hand", command="close")).command == "close"

    state = mp.ControllerStateData(
        fsm_state="add_contact", mode="compliance", transition_index=4,
        active_contacts=("left_foot", "right_foot", "right_hand"),
        task_errors={"com": 0.0031, "left_hand_pose": 0.012, "posture": 0.2}, qp_status="ok",
        qp_solve_time_ms=0.31, tick_time_ms=0.9, qp_failures=2, stamp=7.125)
    msg = wire(mp.controller_state_to_msg(state))
    assert list(msg.task_names) == ["com", "left_hand_pose", "posture"] and msg.qp_status == ControllerState.QP_OK
    assert mp.controller_state_from_msg(msg) == state

    status = mp.ClimbStatusData(id="c1", phase="executing", step=3, n_steps=11, progress=3 / 11,
                                text="stance 3/11", stamp=40.0)
    msg = wire(mp.climb_status_to_msg(status))
    assert mp.climb_status_from_msg(msg) == status  # progress is stored at float32 precision
    assert status.progress == pytest.approx(3 / 11, rel=1e-7)
    kw = mp.climb_status_from_msg(mp.climb_status_to_msg(phase="done", step=11, n_steps=11, progress=1.0))
    assert (kw.phase, kw.progress) == ("done", 1.0)


# --- validation -----------------------------------------------------------------------------

def _msg_with(factory, **fields):
    msg = factory()
    for key, value in fields.items():
        setattr(msg, key, value)
    return msg


def _joint_cmd_msg(names, modes, values):
    return _msg_with(JointCommand, names=names, modes=modes, values=values)


CASES = {
    "values length": (lambda: mp.joint_command_from_msg(_joint_cmd_msg(["a", "b"], [0, 0], [1.0])),
                      "joint_command.values"),
    "modes length": (lambda: mp.joint_command_from_msg(_joint_cmd_msg(["a", "b"], [0], [1.0, 2.0])),
                     "joint_command.modes"),
    "non-finite value": (lambda: mp.joint_command_from_msg(_joint_cmd_msg(["a", "b"], [0, 0], [1.0, float("nan")])),
                         "joint_command.values[1]"),
    "unknown mode code": (lambda: mp.joint_command_from_msg(_joint_cmd_msg(["a", "b"], [0, 9], [1.0, 2.0])),
                          "joint_command.modes[1]"),
    "unknown mode name": (lambda: mp.JointCommandData(names=["a"], modes=["turbo"], values=[0.0]),
                          "joint_command.modes[0]"),
    "pwm saturation": (lambda: mp.JointCommandData(names=["a", "b"], modes="pwm", values=[0.5, -1.5]),
                       "joint_command.values[1]"),
    "duplicate joint": (lambda: mp.JointCommandData(names=["a", "a"], modes="torque", values=[0.0, 0.0]),
                        "joint_command.names[1]"),
    "unknown joint": (lambda: mp.joint_command_from_msg(_joint_cmd_msg(["a", "zz"], [0, 0], [1.0, 2.0]), ["a", "b"]),
                      "joint_command.names[1]"),
    "unknown kwarg": (lambda: mp.joint_command_to_msg(names=["a"], modes="torque", values=[0.0], gain=1.0),
                      "joint_command.gain"),
    "gripper hand": (lambda: mp.gripper_command_from_msg(_msg_with(GripperCommand, hand="left_foot")),
                     "gripper_command.hand"),
    "gripper code": (lambda: mp.gripper_command_from_msg(_msg_with(GripperCommand, hand="left_hand", command=7)),
                     "gripper_command.command"),
    "gripper position": (lambda: mp.GripperCommandData("left_hand", "position", position=1.2),
                         "gripper_command.position"),
    "controller mode": (lambda: mp.controller_state_to_msg(mode="pid"), "controller_state.mode"),
    "controller contact": (lambda: mp.ControllerStateData(active_contacts=("left_knee",)),
                           "controller_state.active_contacts[0]"),
    "task error nan": (lambda: mp.ControllerStateData(task_errors={"com": float("inf")}),
                       "controller_state.task_errors[com]"),
    "task lengths": (lambda: mp.controller_state_from_msg(_msg_with(ControllerState, mode="qp", task_names=["com"])),
                     "controller_state.task_errors"),
    "qp status code": (lambda: mp.controller_state_from_msg(_msg_with(ControllerState, mode="qp", qp_status=9)),
                       "controller_state.qp_status"),
    "climb phase": (lambda: mp.climb_status_from_msg(_msg_with(ClimbStatus, phase="flying")), "climb_status.phase"),
    "climb progress": (lambda: mp.ClimbStatusData(progress=1.5), "climb_status.progress"),
    "climb step": (lambda: mp.ClimbStatusData(step=4, n_steps=3), "climb_status.step"),
    "stamp range": (lambda: mp.seconds_to_time(3e9), "stamp"),
    "pose rotation": (lambda: mp.pose_to_msg(np.diag([1.0, 1.0, -1.0, 1.0])), "pose.rotation"),
    "pose shape": (lambda: mp.pose_to_msg(np.eye(3)), "pose"),
    "zero quaternion": (lambda: mp.quaternion_to_msg(np.zeros(4)), "quaternion"),
    "point length": (lambda: mp.point_to_msg([1.0, 2.0]), "point"),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_command_validation_names_the_field(case):
    build, field = CASES[case]
    with pytest.raises(SpecError) as err:
        build()
    assert err.value.field == field, err.value


def test_plan_validation_names_the_field(rng):
    stance = four_contact_stance(rng)
    bad_hold = mp.stance_to_msg(stance)
    bad_hold.holds[1].limb = "tail"
    with pytest.raises(SpecError) as err:
        mp.stance_from_msg(bad_hold)
    assert err.value.field == "stance.holds[1].limb"

    twice = mp.stance_to_msg(stance)
    twice.holds[3].limb = "left_hand"
    with pytest.raises(SpecError) as err:
        mp.stance_from_msg(twice)
    assert err.value.field == "stance.holds[3].limb"

    negative = mp.hold_to_msg(foot_hold(rng))
    negative.friction = -0.2
    with pytest.raises(SpecError, match="friction"):
        mp.hold_from_msg(negative)

    path = mp.guide_path_to_msg(GuidePath("g1", "l", list(JOINTS), [random_q(rng), random_q(rng)]))
    path.milestones[1].q = path.milestones[1].q[:-1]
    with pytest.raises(SpecError) as err:
        mp.guide_path_from_msg(path)
    assert err.value.field == "guide_path.milestones[1]" and str(NQ) in err.value.rule
    path.milestones[1].q = path.milestones[0].q
    path.milestones[0].q[9] = float("nan")
    with pytest.raises(SpecError) as err:
        mp.guide_path_from_msg(path)
    assert err.value.field == "guide_path.milestones[0][9]"

    plan = mp.contact_plan_to_msg(ContactPlan("g1", "l", list(JOINTS), [stance, stance], [random_q(rng)] * 2))
    plan.transition_configurations.pop()
    with pytest.raises(SpecError) as err:
        mp.contact_plan_from_msg(plan)
    assert err.value.field == "contact_plan.transition_configurations"

    transition = Transition("place_hand", "left_hand", stance, stance, np.array([0.0, 0.1, 0.1]),
                            np.stack([random_q(rng) for _ in range(3)]))
    with pytest.raises(SpecError) as err:
        mp.transition_to_msg(transition)
    assert err.value.field == "transition.times[2]"

    good = Transition("place_hand", "left_hand", stance, stance, np.array([0.0, 0.1]),
                      np.stack([random_q(rng) for _ in range(2)]))
    wbp = mp.whole_body_plan_to_msg(WholeBodyPlan("g1", "l", list(JOINTS), stance, [good]))
    wbp.transitions[0].path[1].q = wbp.transitions[0].path[1].q[:20]
    with pytest.raises(SpecError) as err:
        mp.whole_body_plan_from_msg(wbp)
    assert err.value.field == "whole_body_plan.transitions[0].path[1]"
    wbp.transitions[0].path.pop()
    with pytest.raises(SpecError) as err:
        mp.whole_body_plan_from_msg(wbp)
    assert err.value.field == "whole_body_plan.transitions[0].path"

    with pytest.raises(SpecError) as err:
        mp.guide_path_to_msg(GuidePath("g1", "l", JOINTS + [JOINTS[0]], []))
    assert err.value.field == "guide_path.joint_names"


def test_conversions_do_not_import_rclpy():
    import subprocess
    import sys

    code = ("import sys, msgs_py\n"
            "bad = [m for m in sys.modules if m == 'rclpy' or m.startswith('rclpy.')]\n"
            "assert not bad, bad\nprint('clean')\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0 and "clean" in out.stdout, out.stderr
