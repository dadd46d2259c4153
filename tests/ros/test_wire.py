"""The lock-step hot path's raw CDR (msgs_py.cdr) against rclpy's own serialization, the bridge
node's state publication and the controller node's state decoding (in this process, no DDS
traffic), and the nodes' CPU pinning."""
from __future__ import annotations

import array
import os
import subprocess
import sys

import numpy as np
import pytest
from builtin_interfaces.msg import Time
from climb_msgs.msg import ControllerState, JointCommand
from geometry_msgs.msg import WrenchStamped
from nav_msgs.msg import Odometry
from rclpy.serialization import deserialize_message, serialize_message
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import Imu, JointState

from msgs_py import cdr

STAMP = Time(sec=12, nanosec=345_000_000)
STAMP_NS = 12_345_000_000


def joint_state(rng, n=29, frame=""):
    msg = JointState(name=[f"joint_{i}" + "x" * (i % 4) for i in range(n)], position=rng.normal(size=n).tolist(),
                     velocity=rng.normal(size=n).tolist(), effort=rng.normal(size=n).tolist())
    msg.header.stamp, msg.header.frame_id = STAMP, frame
    return msg


def odometry(rng):
    msg = Odometry(child_frame_id="pelvis")
    msg.header.stamp, msg.header.frame_id = STAMP, "world"
    p, o, t = msg.pose.pose.position, msg.pose.pose.orientation, msg.twist.twist
    p.x, p.y, p.z, o.x, o.y, o.z, o.w = rng.normal(size=7)
    t.linear.x, t.linear.y, t.linear.z, t.angular.x, t.angular.y, t.angular.z = rng.normal(size=6)
    msg.pose.covariance = rng.normal(size=36).tolist()  # must be skipped, not read as the twist
    return msg


def test_readers_decode_what_rclpy_serializes():
    rng = np.random.default_rng(3)
    for frame in ("", "a", "base_link_frame"):  # alignment after strings of every length mod 4
        js = joint_state(rng, frame=frame)
        reader = cdr.JointStateReader()
        for _ in range(2):  # second pass: the cached names
            d = reader.read(serialize_message(js))
            assert d.stamp_ns == STAMP_NS and d.names == list(js.name)
            np.testing.assert_array_equal(d.position, js.position)
            np.testing.assert_array_equal(d.velocity, js.velocity)
            np.testing.assert_array_equal(d.effort, js.effort)
        renamed = joint_state(rng, frame=frame)
        renamed.name = ["other"] * 29  # different names: decoded again, not taken from the cache
        assert reader.read(serialize_message(renamed)).names == ["other"] * 29
    od = odometry(rng)
    d = cdr.read_odometry(serialize_message(od))
    p, o, t = od.pose.pose.position, od.pose.pose.orientation, od.twist.twist
    assert d.stamp_ns == STAMP_NS
    np.testing.assert_array_equal(d.pose, [p.x, p.y, p.z, o.x, o.y, o.z, o.w])
    np.testing.assert_array_equal(d.twist, [t.linear.x, t.linear.y, t.linear.z, t.angular.x, t.angular.y, t.angular.z])
    w = WrenchStamped()
    w.header.stamp, w.header.frame_id = STAMP, "left_ankle_roll_link"
    w.wrench.force.x, w.wrench.force.y, w.wrench.force.z = 1.0, -2.0, 300.0
    w.wrench.torque.x, w.wrench.torque.y, w.wrench.torque.z = 4.0, 5.0, -6.0
    assert cdr.read_wrench_stamped(serialize_message(w))[0] == STAMP_NS
    np.testing.assert_array_equal(cdr.read_wrench_stamped(serialize_message(w))[1], [1, -2, 300, 4, 5, -6])
    imu = Imu()
    imu.header.stamp, imu.header.frame_id = STAMP, "pelvis"
    imu.orientation.x, imu.orientation.w = 0.6, 0.8
    imu.angular_velocity.z, imu.linear_acceleration.z = -0.5, 9.81
    imu.orientation_covariance[0] = 7.0
    d = cdr.read_imu(serialize_message(imu))
    np.testing.assert_array_equal(d.orientation_xyzw, [0.6, 0, 0, 0.8])
    np.testing.assert_array_equal(d.angular_velocity, [0, 0, -0.5])
    np.testing.assert_array_equal(d.linear_acceleration, [0, 0, 9.81])
    cmd = JointCommand(names=["a", "bb", "ccc"], modes=bytes([0, 1, 3]), values=[1.5, -0.25, 0.0])
    cmd.header.stamp = STAMP
    d = cdr.JointCommandReader().read(serialize_message(cmd))
    assert d.stamp_ns == STAMP_NS and d.names == ["a", "bb", "ccc"]
    assert d.modes.tolist() == [0, 1, 3] and d.values.tolist() == [1.5, -0.25, 0.0]


def test_templates_write_what_rclpy_deserializes():
    rng = np.random.default_rng(4)
    js = joint_state(rng)
    t = cdr.Template(serialize_message(js), cdr.locate_joint_state)
    q = rng.normal(size=29)
    t.set_stamp(7_005_000_000)
    t.field("position")[:] = q
    t.field("effort")[:] = -q
    back = deserialize_message(t.payload(), JointState)
    assert (back.header.stamp.sec, back.header.stamp.nanosec) == (7, 5_000_000)
    assert back.name == js.name
    np.testing.assert_array_equal(back.position, q)
    np.testing.assert_array_equal(back.velocity, js.velocity)  # untouched
    np.testing.assert_array_equal(back.effort, -q)
    t = cdr.Template(serialize_message(odometry(rng)), cdr.locate_odometry)
    t.field("pose")[:] = np.arange(7.0)
    t.field("twist")[:] = 10 + np.arange(6.0)
    back = deserialize_message(t.payload(), Odometry)
    assert back.child_frame_id == "pelvis"
    assert (back.pose.pose.position.z, back.pose.pose.orientation.w) == (2.0, 6.0)
    assert (back.twist.twist.linear.x, back.twist.twist.angular.z) == (10.0, 15.0)
    t = cdr.Template(serialize_message(Imu()), cdr.locate_imu)
    t.field("angular_velocity")[:] = (1, 2, 3)
    t.field("linear_acceleration")[:] = (4, 5, 6)
    back = deserialize_message(t.payload(), Imu)
    assert (back.angular_velocity.y, back.linear_acceleration.z, back.orientation_covariance[0]) == (2.0, 6.0, 0.0)
    t = cdr.Template(serialize_message(WrenchStamped()), cdr.locate_wrench_stamped)
    t.field("wrench")[:] = (1, 2, 3, 4, 5, 6)
    back = deserialize_message(t.payload(), WrenchStamped)
    assert (back.wrench.force.z, back.wrench.torque.x) == (3.0, 4.0)
    t = cdr.Template(serialize_message(Clock()), cdr.locate_clock)
    t.set_stamp(STAMP_NS)
    assert deserialize_message(t.payload(), Clock).clock == STAMP
    cmd = JointCommand(names=["a", "b"], modes=bytes([1, 1]), values=[0.0, 0.0])
    t = cdr.Template(serialize_message(cmd), cdr.locate_joint_command)
    t.field("values")[:] = (0.5, -0.5)
    back = deserialize_message(t.payload(), JointCommand)
    assert list(back.values) == [0.5, -0.5] and list(back.modes) == [1, 1] and back.names == ["a", "b"]


def test_controller_state_writer_is_byte_exact():
    """Templates per layout (strings), numbers written in place: the same message as rclpy's
    (same length; the padding bytes rclpy leaves uninitialised may differ)."""
    writer = cdr.ControllerStateWriter(ControllerState, serialize_message)
    ticks = [  # an FSM change and a contact-set change between ticks, then the first layout again
        ("transfer", "qp", 3, ("left_foot", "right_foot", "left_hand"), ("com", "posture", "right_hand"),
         (0.012, 0.3, 0.0451), 0, 0.104, 0.71, 0),
        ("search", "qp", 3, ("left_foot", "right_foot", "left_hand"), ("com", "posture", "right_hand"),
         (0.002, 0.1, 0.0051), 0, 0.099, 0.65, 0),
        ("hold", "compliance", 4, ("left_foot", "right_foot", "left_hand", "right_hand"), ("com", "posture"),
         (1e-4, 2e-3), 1, 0.0, 1.2, 3),
        ("transfer", "qp", 7, ("left_foot", "right_foot", "left_hand"), ("com", "posture", "right_hand"),
         (0.5, 0.25, 0.125), 2, 0.2, 0.9, 4),
    ]
    # replan_needed after a placement found rung_2 2.8 cm higher than planned: why, where
    replan = [("contact_offset", "rung_2", (0.0, 0.001, 0.028)), ("contact_offset", "rung_2", (0.0, 0.0, -0.031)),
              ("no_contact", "", (0.0, 0.0, 0.0))]
    ticks += [("replan_needed", "qp", 15, ("left_foot", "right_foot", "left_hand", "right_hand"), ("com", "posture"),
               (1e-3, 2e-3), 0, 0.1, 0.8, 0) + r for r in replan]
    for k, tick_args in enumerate(ticks):
        fsm, mode, index, contacts, names, errors, status, solve, tick, failures = tick_args[:10]
        reason, surface, offset = tick_args[10:] if len(tick_args) > 10 else ("", "", (0.0, 0.0, 0.0))
        stamp = STAMP_NS + k * 5_000_000
        msg = ControllerState(fsm_state=fsm, mode=mode, transition_index=index, active_contacts=list(contacts),
                              task_names=list(names), task_errors=list(errors), qp_status=status,
                              qp_solve_time_ms=solve, tick_time_ms=tick, qp_failures=failures,
                              replan_reason=reason, offset_surface=surface, surface_offset=list(offset),
                              plans_taken=k // 3)
        msg.header.stamp = Time(sec=stamp // 1_000_000_000, nanosec=stamp % 1_000_000_000)
        got = writer.payload(stamp, fsm, mode, index, contacts, names, np.array(errors), status, solve, tick, failures,
                             reason, surface, offset, k // 3)
        assert len(got) == len(serialize_message(msg)), f"tick {k}"
        back = deserialize_message(got, ControllerState)
        assert back == msg, f"tick {k} ({fsm}): {back} != {msg}"
    assert len(writer._layouts) == 5  # the first layout and the contact_offset one were reused


def test_reader_rejects_other_encodings_and_truncated_bytes():
    data = serialize_message(joint_state(np.random.default_rng(5)))
    with pytest.raises(cdr.CdrError, match="little-endian"):
        cdr.JointStateReader().read(b"\x00\x00" + data[2:])  # big-endian CDR
    with pytest.raises(cdr.CdrError):
        cdr.JointStateReader().read(data[:-8])
    with pytest.raises(cdr.CdrError):
        cdr.read_odometry(serialize_message(odometry(np.random.default_rng(6)))[:200])


def test_controller_decoder_falls_back_to_rclpy(monkeypatch):
    from controller_node.node import StateDecoder

    rng = np.random.default_rng(7)
    js, od = serialize_message(joint_state(rng)), serialize_message(odometry(rng))
    w = WrenchStamped()
    w.header.stamp = STAMP
    w.wrench.force.z, w.wrench.torque.y = 50.0, -1.0
    ws = serialize_message(w)
    fast = StateDecoder()
    expected = (fast.joints(js), fast.base(od), fast.wrench(ws))

    def refuse(*args):
        raise cdr.CdrError("refused")

    for name in ("read_odometry", "read_wrench_stamped", "read_imu"):
        monkeypatch.setattr(cdr, name, refuse)
    monkeypatch.setattr(cdr.JointStateReader, "read", lambda self, data: refuse())
    slow = StateDecoder()
    got = (slow.joints(js), slow.base(od), slow.wrench(ws))
    assert got[0].names == expected[0].names and got[0].stamp_ns == expected[0].stamp_ns == STAMP_NS
    np.testing.assert_array_equal(got[0].velocity, expected[0].velocity)
    np.testing.assert_array_equal(got[1].pose, expected[1].pose)
    np.testing.assert_array_equal(got[1].twist, expected[1].twist)
    assert got[2][0] == expected[2][0] and got[2][1].tolist() == expected[2][1].tolist() == [0, 0, 50, 0, -1, 0]


def test_bridge_node_publishes_the_simulated_state_byte_exact():
    """The bridge node's templates carry exactly the backend's state (decoded by rclpy)."""
    import rclpy

    from sim_bridge.node import SimBridgeNode

    class Capture:
        def __init__(self):
            self.sent = []

        def publish(self, data):
            assert isinstance(data, bytes)
            self.sent.append(data)

    rclpy.init(args=["--ros-args", "-p", "initial_posture:=ladder_4_contacts"])
    node = None
    try:
        node = SimBridgeNode()
        node.pub_joints, node.pub_imu, node.pub_truth, node.pub_clock = Capture(), Capture(), Capture(), Capture()
        node.pub_ft = {s: Capture() for s in node.pub_ft}
        # a command as bytes, as the controller node publishes it, goes through the bridge's
        # validation; one step later the F/T sensors carry the stance's load
        state = node.bridge.state
        cmd = JointCommand(names=list(node.backend.joint_names), modes=bytes(len(state.q)),
                           values=np.full(len(state.q), 0.5).tolist())
        cmd.header.stamp.sec, cmd.header.stamp.nanosec = divmod(state.stamp_ns, 1_000_000_000)
        node._on_command(serialize_message(cmd))
        assert node.bridge.command_ready()
        node.bridge.step_lockstep()
        np.testing.assert_array_equal(node.bridge.state.tau, 0.5)  # the decoded command was applied
        state = node.bridge.state
        node.publish_state(state)
        js = deserialize_message(node.pub_joints.sent[-1], JointState)
        assert js.name == list(node.backend.joint_names)
        np.testing.assert_array_equal(js.position, state.q)
        np.testing.assert_array_equal(js.velocity, state.v)
        np.testing.assert_array_equal(js.effort, state.tau)
        od = deserialize_message(node.pub_truth.sent[-1], Odometry)
        p, o, t = od.pose.pose.position, od.pose.pose.orientation, od.twist.twist
        np.testing.assert_array_equal([p.x, p.y, p.z, o.x, o.y, o.z, o.w], state.base.q[:7])
        np.testing.assert_array_equal([t.linear.x, t.linear.y, t.linear.z, t.angular.x, t.angular.y, t.angular.z],
                                      state.base.v[:6])
        assert (od.header.frame_id, od.child_frame_id) == ("world", node.backend.root_link)
        imu = deserialize_message(node.pub_imu.sent[-1], Imu)
        np.testing.assert_array_equal([imu.orientation.x, imu.orientation.y, imu.orientation.z, imu.orientation.w],
                                      state.imu.quaternion_xyzw)
        np.testing.assert_array_equal([imu.linear_acceleration.x, imu.linear_acceleration.y,
                                       imu.linear_acceleration.z], state.imu.linear_acceleration)
        assert sum(w.force[2] for w in state.ft.values()) != 0.0  # the stance loads the F/T sensors
        for sensor, wrench in state.ft.items():
            msg = deserialize_message(node.pub_ft[sensor].sent[-1], WrenchStamped)
            assert msg.header.frame_id == node.backend.link_name(node.backend.ft_joints[sensor])
            assert to_ns(msg.header.stamp) == state.stamp_ns
            np.testing.assert_array_equal([msg.wrench.force.x, msg.wrench.force.y, msg.wrench.force.z,
                                           msg.wrench.torque.x, msg.wrench.torque.y, msg.wrench.torque.z],
                                          np.concatenate([wrench.force, wrench.torque]))
        assert to_ns(deserialize_message(node.pub_clock.sent[-1], Clock).clock) == state.stamp_ns
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()


def to_ns(stamp: Time) -> int:
    return stamp.sec * 1_000_000_000 + stamp.nanosec


PIN_CHECK = """
import os, threading, time, sys
from climb_core.ros_env import pin_to_cpus
stop = threading.Event()
workers = [threading.Thread(target=stop.wait) for _ in range(3)]
for w in workers:
    w.start()
pinned = pin_to_cpus([int(sys.argv[1])])
masks = {tid: sorted(os.sched_getaffinity(int(tid))) for tid in os.listdir("/proc/self/task")}
stop.set()
print(len(masks), sorted(pinned), all(m == [int(sys.argv[1])] for m in masks.values()))
"""


def test_pin_to_cpus_pins_every_thread():
    cpu = max(os.sched_getaffinity(0))
    out = subprocess.run([sys.executable, "-c", PIN_CHECK, str(cpu)],
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr[-2000:]
    words = out.stdout.split()
    n_threads, pinned, all_pinned = int(words[0]), out.stdout.split("[")[1].split("]")[0], words[-1]
    assert n_threads >= 4 and pinned == str(cpu) and all_pinned == "True"
