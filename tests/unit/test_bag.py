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
