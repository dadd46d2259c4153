"""The generic `recorder` node: raw subscriptions to every topic of a small graph (standard and
climb_msgs types, a TRANSIENT_LOCAL topic published before the recorder joined), a bag readable
by rosbags after a SIGKILL up to its last flush, and a complete bag (rosbags and mcap) after SIGINT.

The graph is this file run as a script: a publisher of joint_states (position = its counter),
controller/state (climb_msgs) and the latched climb/request, printing `<wall time> <counter>`.
"""
from __future__ import annotations

import json
import os
import pathlib
import signal
import subprocess
import sys
import time

import pytest

pytestmark = pytest.mark.ros

ROOT = pathlib.Path(__file__).resolve().parents[2]
REQUEST = {"id": "r1", "robot": "g1", "scenario": "default"}


def recorder_command(*ros_args: str) -> list[str]:
    """The installed `recorder` executable, or the module when make setup has not installed it."""
    exe = pathlib.Path(sys.prefix) / "lib" / "climb_coordinator" / "recorder"
    head = [str(exe)] if exe.exists() else [sys.executable, "-m", "climb_coordinator.recorder_node"]
    return head + ["--ros-args", *ros_args]


def _wait_for(proc: subprocess.Popen, lines: list[str], needle: str, timeout: float) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if any(needle in line for line in lines):
            return
        assert proc.poll() is None, "".join(lines)[-3000:]
        time.sleep(0.05)
    raise AssertionError(f"{needle!r} not seen in {timeout} s:\n" + "".join(lines)[-3000:])


def _reader_thread(proc: subprocess.Popen, lines: list[str]):
    import threading

    def run():
        for line in proc.stdout:
            lines.append(line)

    t = threading.Thread(target=run, daemon=True)
    t.start()
    return t


def test_recorder_survives_sigkill_and_closes_on_sigint(tmp_path):
    from climb_core.ros_env import local_dds_env
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory
    from rclpy.serialization import deserialize_message
    from rosbags.interfaces import QosDurability
    from rosbags.rosbag2 import Reader
    from sensor_msgs.msg import JointState

    env = local_dds_env()
    killed_bag, closed_bag = tmp_path / "killed", tmp_path / "closed"
    graph = subprocess.Popen([sys.executable, __file__], env=env, cwd=ROOT, stdout=subprocess.PIPE, text=True)
    graph_lines: list[str] = []
    _reader_thread(graph, graph_lines)
    procs = [graph]
    try:
        _wait_for(graph, graph_lines, "latched", 30)  # climb/request went out before any recorder
        full = subprocess.Popen(recorder_command("-p", f"bag_path:={killed_bag}", "-p", "flush_period_s:=0.5"),
                                env=env, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        listed = subprocess.Popen(recorder_command("-p", f"bag_path:={closed_bag}",
                                                   "-p", "topics:=[joint_states, controller/state, climb/request]"),
                                  env=env, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        procs += [full, listed]
        full_lines: list[str] = []
        listed_lines: list[str] = []
        _reader_thread(full, full_lines)
        _reader_thread(listed, listed_lines)
        for proc, lines in ((full, full_lines), (listed, listed_lines)):
            for topic in ("/joint_states", "/controller/state", "/climb/request"):
                _wait_for(proc, lines, f"recording {topic} ", 30)
        time.sleep(3.0)  # 3 s of recording
        kill_wall = time.time()
        full.send_signal(signal.SIGKILL)
        full.wait(timeout=10)
        listed.send_signal(signal.SIGINT)
        assert listed.wait(timeout=20) == 0, "".join(listed_lines)[-3000:]
    finally:
        for proc in procs:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
    assert full.returncode == -signal.SIGKILL
    assert "Traceback" not in "".join(listed_lines)

    # the killed bag: rosbags opens it as is; every joint state published up to 1 s before the
    # kill, from the first one recorded, is there, in order, no gap
    published = [(float(t), int(k)) for t, k in (line.split() for line in graph_lines if line[0].isdigit())]
    due = max(k for t, k in published if t <= kill_wall - 1.0)
    with Reader(killed_bag) as reader:
        topics = {c.topic: c for c in reader.connections}
        assert topics["/climb/request"].msgcount == 1  # latched: received though published before
        assert topics["/climb/request"].ext.offered_qos_profiles[0].durability == QosDurability.TRANSIENT_LOCAL
        assert topics["/joint_states"].ext.offered_qos_profiles[0].durability == QosDurability.VOLATILE
        ks = [int(deserialize_message(data, JointState).position[0])
              for conn, _, data in reader.messages(connections=[topics["/joint_states"]])]
        request = [bytes(d) for c, _, d in reader.messages(connections=[topics["/climb/request"]])]
    assert ks == list(range(ks[0], ks[0] + len(ks)))
    assert ks[-1] >= due, (ks[-1], due)
    assert "/parameter_events" not in topics  # excluded by default
    (mcap_file,) = killed_bag.glob("*.mcap")
    with open(mcap_file, "rb") as f:
        assert sum(1 for _ in make_reader(f).iter_messages(topics=["/joint_states"])) == len(ks)
    from std_msgs.msg import String

    assert json.loads(deserialize_message(request[0], String).data) == REQUEST

    # the bag closed on SIGINT: only the listed topics, complete, and mcap decodes the custom
    # type from the definition the bag embeds
    with Reader(closed_bag) as reader:
        assert sorted(c.topic for c in reader.connections) == ["/climb/request", "/controller/state", "/joint_states"]
        counts = {c.topic: c.msgcount for c in reader.connections}
        assert counts["/joint_states"] > 200 and counts["/climb/request"] == 1
    (mcap_file,) = closed_bag.glob("*.mcap")
    with open(mcap_file, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        assert reader.get_summary().statistics.message_count == sum(counts.values())
        states = [m for _, ch, _, m in reader.iter_decoded_messages(topics=["/controller/state"])]
    assert len(states) == counts["/controller/state"] and states[-1].fsm_state == "hold"


# ------------------------------------------------------------------------------------------------
# the graph process


def graph_main() -> int:
    from climb_core.ros_env import apply_local_dds_env

    apply_local_dds_env()
    import rclpy
    from climb_msgs.msg import ControllerState
    from rclpy.qos import DurabilityPolicy, QoSProfile
    from sensor_msgs.msg import JointState
    from std_msgs.msg import String

    from msgs_py.node_kit import install_signal_handlers, running

    install_signal_handlers()
    rclpy.init()
    node = rclpy.create_node("recorder_test_graph")
    latched = node.create_publisher(String, "climb/request", QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL))
    latched.publish(String(data=json.dumps(REQUEST)))
    print("latched", flush=True)
    js = node.create_publisher(JointState, "joint_states", 10)
    cs = node.create_publisher(ControllerState, "controller/state", 10)
    k = 0
    deadline = time.monotonic() + 120.0
    try:
        while running() and time.monotonic() < deadline:
            msg = JointState(name=["a"], position=[float(k)])
            msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(k * 10_000_000, 1_000_000_000)
            js.publish(msg)
            cs.publish(ControllerState(fsm_state="hold", transition_index=k % 7))
            print(f"{time.time():.6f} {k}", flush=True)
            k += 1
            time.sleep(0.01)
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == "__main__":
    os.environ.setdefault("PYTHONUNBUFFERED", "1")
    sys.exit(graph_main())
