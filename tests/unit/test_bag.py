"""rosbag2 MCAP recording: standard and climb_msgs types round-trip, other tools read the file."""
import array
import pathlib

import pytest
from climb_msgs.msg import ControllerState, JointCommand
from sensor_msgs.msg import JointState

from climb_core.errors import SpecError
from msgs_py.bag import BagRecorder, read_bag


def _joint_state(k: int) -> JointState:
    msg = JointState(name=["a", "b"], position=[0.1 * k, -0.2 * k], velocity=[1.0, 2.0], effort=[3.0, 4.0])
    msg.header.stamp.sec, msg.header.stamp.nanosec = 0, 5_000_000 * k
    return msg


def test_bag_round_trip_standard_and_custom_types(tmp_path: pathlib.Path):
    bag = tmp_path / "run"
    with BagRecorder(bag) as rec:
        for k in range(200):  # one second at 200 Hz
            rec.write("joint_states", _joint_state(k), 5_000_000 * k)
            cmd = JointCommand(names=["a", "b"], modes=array.array("B", [JointCommand.TORQUE, JointCommand.PWM]),
                               values=array.array("d", [1.5 * k, 0.25]))
            rec.write("joint_command", cmd, 5_000_000 * k + 1)
        rec.write("controller/state", ControllerState(fsm_state="hold", qp_solve_time_ms=0.3), 10**9)
    assert (bag / "metadata.yaml").is_file()
    messages = list(read_bag(bag))
    assert len(messages) == 401
    assert [m.stamp_ns for m in messages] == sorted(m.stamp_ns for m in messages)
    states = [m.decode() for m in messages if m.topic == "joint_states"]
    assert len(states) == 200
    assert states[150].position[0] == pytest.approx(15.0) and list(states[150].name) == ["a", "b"]
    cmds = [m.decode() for m in messages if m.topic == "joint_command"]
    assert list(cmds[10].modes) == [JointCommand.TORQUE, JointCommand.PWM] and cmds[10].values[0] == 15.0
    (last,) = [m.decode() for m in messages if m.topic == "controller/state"]
    assert last.fsm_state == "hold"
    # metadata.yaml holds what the MCAP file embeds (rosbag2's "rosbag2" metadata record)
    import yaml
    from mcap.reader import make_reader

    (mcap_file,) = bag.glob("*.mcap")
    with open(mcap_file, "rb") as f:
        (record,) = [m for m in make_reader(f).iter_metadata() if m.name == "rosbag2"]
    info = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert info == yaml.safe_load(record.metadata["serialized_metadata"])
    assert info["message_count"] == 401 and len(info["topics_with_message_count"]) == 3


def test_mcap_tools_decode_the_custom_types_without_the_project(tmp_path: pathlib.Path):
    """The bag embeds the climb_msgs definitions: mcap-ros2-support decodes them on its own."""
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    bag = tmp_path / "b"
    with BagRecorder(bag) as rec:
        rec.write("controller/state", ControllerState(fsm_state="add_contact", qp_failures=3), 42)
    (mcap_file,) = bag.glob("*.mcap")
    with open(mcap_file, "rb") as f:
        decoded = [(ch.topic, m) for _, ch, _, m in make_reader(f, decoder_factories=[DecoderFactory()])
                   .iter_decoded_messages()]
    assert decoded[0][0] == "controller/state"
    assert decoded[0][1].fsm_state == "add_contact" and decoded[0][1].qp_failures == 3


def test_bad_bag_requests_name_the_problem(tmp_path: pathlib.Path):
    (tmp_path / "exists").mkdir()
    with pytest.raises(SpecError, match="bag.path"):
        BagRecorder(tmp_path / "exists")
    with pytest.raises(SpecError, match="bag.storage"):
        BagRecorder(tmp_path / "x", storage="rosbag1")
    with BagRecorder(tmp_path / "y") as rec:
        with pytest.raises(SpecError, match="bag.msgtype"):
            rec.write_raw("t", "nope_msgs/msg/Nothing", b"\x00\x01\x00\x00", 0)
    with pytest.raises(SpecError, match="is closed"):
        rec.write_raw("t", "std_msgs/msg/String", b"", 0)


_KILLED_RECORDER = r"""
import sys, time
from sensor_msgs.msg import JointState
from msgs_py.bag import BagRecorder
rec = BagRecorder(sys.argv[1], flush_period_s=0.1)
k, last = 0, 0.0
while True:  # until SIGKILL: 2 kHz of joint states, the count reported every 20 ms
    rec.write("joint_states", JointState(name=["a"], position=[float(k)]), k)
    k += 1
    now = time.monotonic()
    if now - last > 0.02:
        print(f"{now:.6f} {k}", flush=True)
        last = now
    time.sleep(0.0005)
"""


def test_a_killed_recorder_leaves_a_bag_standard_readers_open_as_is(tmp_path: pathlib.Path):
    """SIGKILL while recording: metadata.yaml is there and the MCAP file is complete (summary and
    footer rewritten at every flush), so rosbags' Reader and mcap's reader open it as is, with
    every message written more than a few flush periods before the kill, in order and no gap;
    recover_bag has nothing to repair."""
    import os
    import signal
    import subprocess
    import sys
    import time

    from mcap.reader import make_reader
    from rosbags.rosbag2 import Reader

    from msgs_py.bag import recover_bag

    bag = tmp_path / "killed"
    child = subprocess.Popen([sys.executable, "-c", _KILLED_RECORDER, str(bag)], stdout=subprocess.PIPE, text=True)
    reports = []
    try:
        for line in child.stdout:
            t, n = line.split()
            reports.append((float(t), int(n)))
            if len(reports) > 1 and reports[-1][0] - reports[0][0] > 1.0:
                break
    finally:
        kill_time = time.monotonic()
        os.kill(child.pid, signal.SIGKILL)
        child.wait()
    assert child.returncode == -signal.SIGKILL
    assert (bag / "metadata.yaml").is_file()
    # everything reported at least 0.5 s (5 flush periods) before the kill must be there
    safe = max(n for t, n in reports if t <= kill_time - 0.5)
    with Reader(bag) as reader:
        positions = [_decode_position(data) for _, _, data in reader.messages()]
        assert reader.message_count == len(positions)
    assert len(positions) >= safe > 100
    assert positions == [float(k) for k in range(len(positions))]  # no gap, no reordering
    (mcap_file,) = bag.glob("*.mcap")
    with open(mcap_file, "rb") as f:
        reader = make_reader(f)
        assert reader.get_summary().statistics.message_count == len(positions)
        assert sum(1 for _ in reader.iter_messages()) == len(positions)
    assert [m.decode().position[0] for m in read_bag(bag)] == positions
    assert recover_bag(bag) == len(positions)


def _decode_position(data: bytes) -> float:
    from rclpy.serialization import deserialize_message

    return deserialize_message(data, JointState).position[0]


def test_recover_bag_repairs_an_old_style_unclosed_bag(tmp_path: pathlib.Path):
    """A bag cut without summary and metadata.yaml (an older recorder killed): read_bag reads it
    record by record and recover_bag rewrites it complete."""
    from rosbags.rosbag2 import Reader

    from msgs_py.bag import recover_bag

    bag = tmp_path / "old"
    with BagRecorder(bag, close_on_signals=False) as rec:
        for k in range(50):
            rec.write("joint_states", _joint_state(k), 5_000_000 * k)
    (mcap_file,) = bag.glob("*.mcap")
    data = mcap_file.read_bytes()
    # keep the data section only (header + chunks): cut at the DataEnd record
    end = data.rfind(b"\x0f\x04\x00\x00\x00\x00\x00\x00\x00")  # DataEnd opcode + length 4
    mcap_file.write_bytes(data[:end])
    (bag / "metadata.yaml").unlink()
    assert [m.decode().position[0] for m in read_bag(bag)] == [0.1 * k for k in range(50)]
    assert recover_bag(bag) == 50
    with Reader(bag) as r:
        assert r.message_count == 50


def test_types_without_a_msg_file_and_qos_are_recorded(tmp_path: pathlib.Path):
    """An action's feedback message (no .msg file: its definition comes from the Python class) and
    a latched topic's QoS (durability transient_local) land in the bag."""
    from climb_msgs.action import Climb
    from rosbags.interfaces import QosDurability

    from msgs_py.bag import bag_topics, qos_profile

    bag = tmp_path / "types"
    fb = Climb.Impl.FeedbackMessage()
    fb.feedback.phase = "executing"
    with BagRecorder(bag, close_on_signals=False) as rec:
        rec.add_topic("/climb/request", "std_msgs/msg/String", [qos_profile(durability="transient_local", depth=1)])
        rec.write("/climb/_action/feedback", fb, 1)
        from std_msgs.msg import String

        rec.write("/climb/request", String(data="{}"), 2)
    (fb_msg, req) = list(read_bag(bag))
    assert fb_msg.decode().feedback.phase == "executing"
    topics = bag_topics(bag)
    assert topics["/climb/request"].qos[0].durability == QosDurability.TRANSIENT_LOCAL
    assert topics["/climb/request"].count == 1
