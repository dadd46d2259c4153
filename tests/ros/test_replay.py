"""scripts/replay.py: byte-for-byte replay on the recorded timing, the refusal to drive a live robot,
and --reexecute of a recorded lock-step run (bridge + controller executing a hand transfer, the
plan and the request recorded by the `recorder` node) within 1 mm of base position, and a changed
controller gain failing that comparison.

Helper processes are this file run as a script: `listen OUT TOPIC...` (raw subscriber recording
arrival times and bytes), `fake NAME` (a node called NAME subscribing to joint_command, counting),
`drive` (publishes the latched climb/request and, once the controller ticks, the plan).
"""
from __future__ import annotations

import json
import os
import pathlib
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

pytestmark = pytest.mark.ros

ROOT = pathlib.Path(__file__).resolve().parents[2]
REPLAY = ROOT / "scripts" / "replay.py"
TICKS = 600  # 3 s of sim time: the plan at ~0.5 s, the hand lets go at ~0.9 s and travels from ~1.1 s
#: the recorded controller's settings (what a coordinator's request carries): the QP without a
#: wall-time bound, so that a loaded machine cannot make the recorded run itself irreproducible
REQUEST = {"id": "replay-test", "robot": "g1", "scenario": "default", "mode": "qp", "seed": 0,
           "initial_posture": "ladder_4_contacts", "controller_overrides": {"qp.time_limit_s": 0.0}}


def _env():
    from climb_core.ros_env import local_dds_env

    return local_dds_env()


def _stop(proc: subprocess.Popen, sig=signal.SIGINT, timeout: float = 15.0) -> str:
    if proc.poll() is None:
        proc.send_signal(sig)
        try:
            proc.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
    return proc.stdout.read() if proc.stdout else ""


# ------------------------------------------------------------------------------------------------
# byte-for-byte replay

def _write_small_bag(path: pathlib.Path) -> None:
    """2 s: joint_states at 100 Hz with irregular gaps, /clock, controller/state (climb_msgs),
    a latched climb/request and a joint_command."""
    from climb_msgs.msg import ControllerState, JointCommand
    from rosgraph_msgs.msg import Clock
    from sensor_msgs.msg import JointState
    from std_msgs.msg import String

    from msgs_py.bag import BagRecorder, qos_profile

    t0 = 1_700_000_000_000_000_000
    with BagRecorder(path, close_on_signals=False) as rec:
        rec.add_topic("/climb/request", "std_msgs/msg/String", [qos_profile(durability="transient_local", depth=1)])
        rec.add_topic("/joint_states", "sensor_msgs/msg/JointState", [qos_profile(depth=10)])
        rec.write("/climb/request", String(data=json.dumps(REQUEST)), t0)
        t = t0
        for k in range(200):
            t += 10_000_000 if k % 10 else 40_000_000  # a 40 ms gap every 10 messages
            clock = Clock()
            clock.clock.sec, clock.clock.nanosec = divmod(k * 5_000_000, 1_000_000_000)
            rec.write("/clock", clock, t)
            rec.write("/joint_states", JointState(name=["a"] * (k % 5), position=[float(k)] * (k % 5)), t + 1000)
            if k % 20 == 0:
                rec.write("/controller/state", ControllerState(fsm_state=f"s{k}", transition_index=k), t + 2000)
        rec.write("/joint_command", JointCommand(names=["a"], modes=b"\x00", values=[1.0]), t + 5000)


def test_replay_is_byte_equal_on_the_recorded_timing(tmp_path):
    from msgs_py.bag import read_bag

    bag = tmp_path / "small"
    _write_small_bag(bag)
    env = _env()
    out = tmp_path / "heard.json"
    topics = ["/ns1/joint_states", "/ns1/clock", "/ns1/controller/state", "/ns1/climb/request"]
    listener = subprocess.Popen([sys.executable, __file__, "listen", str(out), *topics], env=env, cwd=ROOT,
                                stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        time.sleep(1.0)
        proc = subprocess.run([sys.executable, str(REPLAY), str(bag), "--namespace", "ns1", "--topics",
                               "joint_states", "/clock", "controller/state", "climb/request"],
                              env=env, cwd=ROOT, capture_output=True, text=True, timeout=120)
        assert proc.returncode == 0, proc.stderr[-3000:]
        result = json.loads(proc.stdout.strip().splitlines()[-1])
        assert result["topics"]["/joint_states"] == 200 and "/joint_command" not in result["topics"]
    finally:
        text = _stop(listener)
    assert listener.returncode == 0, text[-3000:]
    heard = json.loads(out.read_text())
    recorded = {}
    for m in read_bag(bag):  # DDS carries a payload padded to 4 bytes (what a recorder then stores)
        padded = m.data + b"\x00" * (-len(m.data) % 4)
        recorded.setdefault("/ns1" + m.topic, []).append((m.stamp_ns, padded.hex()))
    for topic in topics:
        got = heard[topic]
        assert [h for _, h in got] == [h for _, h in recorded[topic]], topic  # byte-equal, every one, in order
    # inter-arrival times (DDS receive times) follow the stamps: 10 ms, and 40 ms every 10th
    # message. Medians (a loaded machine delays a message now and then), and the rate over 1 s
    arrivals = np.array([t for t, _ in heard["/ns1/joint_states"]])
    stamps = np.array([s for s, _ in recorded["/ns1/joint_states"]]) * 1e-9
    gap = np.diff(stamps) > 0.02
    assert gap.sum() == 19
    later = np.searchsorted(stamps, stamps + 1.0)
    ok = later < len(stamps)
    rates = (arrivals[later[ok]] - arrivals[ok]) / (stamps[later[ok]] - stamps[ok])
    if result["max_lag_ms"] < 5.0:  # the replayer kept its schedule
        assert np.median(np.diff(arrivals)[gap]) == pytest.approx(0.040, abs=0.008)
        assert np.median(np.diff(arrivals)[~gap]) == pytest.approx(0.010, abs=0.003)
        assert np.median(rates) == pytest.approx(1.0, abs=0.05)
    else:  # a machine loaded enough to stall the replayer: late messages go out at once (bursts);
        # it is still paced, not dumped
        assert 0.5 < np.median(rates) < 2.0, (result, rates)


def test_replay_refuses_to_drive_a_live_robot(tmp_path):
    bag = tmp_path / "small"
    _write_small_bag(bag)
    env = _env()
    fake = subprocess.Popen([sys.executable, __file__, "fake", "sim_bridge"], env=env, cwd=ROOT,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        assert fake.stdout.readline().strip() == "ready"
        time.sleep(0.5)
        refused = subprocess.run([sys.executable, str(REPLAY), str(bag)], env=env, cwd=ROOT,
                                 capture_output=True, text=True, timeout=60)
        # under a namespace, or without the actuation topics, it replays
        spaced = subprocess.run([sys.executable, str(REPLAY), str(bag), "--namespace", "elsewhere", "--rate", "4"],
                                env=env, cwd=ROOT, capture_output=True, text=True, timeout=60)
        harmless = subprocess.run([sys.executable, str(REPLAY), str(bag), "--topics", "controller/state",
                                   "--rate", "4"], env=env, cwd=ROOT, capture_output=True, text=True, timeout=60)
    finally:
        text = _stop(fake)
    assert refused.returncode == 3, refused.stderr
    assert "refusing to replay joint_command" in refused.stderr and "/sim_bridge" in refused.stderr
    assert spaced.returncode == 0, spaced.stderr[-2000:]
    assert harmless.returncode == 0, harmless.stderr[-2000:]
    assert json.loads(spaced.stdout.strip().splitlines()[-1])["topics"]["/joint_command"] == 1
    assert "joint_command received: 0" in text, text  # the live node never got a replayed command


# ------------------------------------------------------------------------------------------------
# re-execution of a recorded lock-step run

def _recorder_cmd(bag: pathlib.Path) -> list[str]:
    exe = pathlib.Path(sys.prefix) / "lib" / "climb_coordinator" / "recorder"
    head = [str(exe)] if exe.exists() else [sys.executable, "-m", "climb_coordinator.recorder_node"]
    return head + ["--ros-args", "-p", f"bag_path:={bag}"]


def _record_run(bag: pathlib.Path, env: dict) -> None:
    """The recorded run: bridge and controller in lock-step, the controller's QP without a
    wall-time bound and the bridge waiting up to 30 s for a command, so that a loaded machine slows
    the run down but cannot change it (a 1 s timeout damps a tick: measured at load 38)."""
    bridge = subprocess.Popen(
        [sys.executable, "-m", "sim_bridge.node", "--ros-args", "--params-file",
         str(ROOT / "config" / "nodes" / "sim_bridge.yaml"), "-p", f"max_ticks:={TICKS}",
         "-p", "initial_posture:=ladder_4_contacts", "-p", "execution:=lockstep",
         "-p", "lockstep.startup_wait_s:=30.0", "-p", "lockstep.command_timeout_s:=30.0"],
        env=env, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    procs = [bridge]
    try:
        recorder = subprocess.Popen(_recorder_cmd(bag), env=env, cwd=ROOT, stdout=subprocess.PIPE,
                                    stderr=subprocess.STDOUT, text=True)
        procs.append(recorder)
        driver = subprocess.Popen([sys.executable, __file__, "drive"], env=env, cwd=ROOT,
                                  stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        procs.append(driver)
        # the recorder subscribes to the plan topic before the controller ticks (a fixed 2 s sleep
        # lost the plan once under make test's load: the recorder's start took longer)
        _wait_for_line(driver, "recorder subscribed", 90.0)
        controller = subprocess.Popen(
            [sys.executable, "-m", "controller_node.node", "--ros-args", "--params-file",
             str(ROOT / "config" / "nodes" / "controller.yaml"), "-p", "initial_stance:=ladder_4_contacts",
             "-p", "qp.time_limit_s:=0.0"],
            env=env, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        procs.append(controller)
        b_out, _ = bridge.communicate(timeout=240)
        assert bridge.returncode == 0, b_out[-3000:]
        d_out = _stop(driver, timeout=20)
        assert driver.returncode == 0, d_out[-3000:]
        c_out = _stop(controller)
        assert controller.returncode == 0, c_out[-3000:]
        time.sleep(1.0)  # the recorder flushes
        r_out = _stop(recorder)
        assert recorder.returncode == 0, r_out[-3000:]
    finally:
        for proc in procs:
            if proc.poll() is None:
                proc.kill()
                proc.wait()


def _wait_for_line(proc: subprocess.Popen, text: str, timeout: float) -> None:
    """Read ``proc``'s stdout until a line contains ``text`` (AssertionError after ``timeout`` s
    or when the process ends first)."""
    import select

    deadline = time.monotonic() + timeout
    fd = proc.stdout.fileno()  # raw reads: nothing left in the text wrapper's buffer unseen
    seen = b""
    while time.monotonic() < deadline:
        ready, _, _ = select.select([fd], [], [], 0.2)
        if ready:
            chunk = os.read(fd, 65536)
            if not chunk:
                break
            seen += chunk
            if text.encode() in seen:
                return
    raise AssertionError(f"no {text!r} from the process within {timeout} s: {seen.decode(errors='replace')[-2000:]}")


@pytest.fixture(scope="module")
def lockstep_bag(tmp_path_factory):
    bag = tmp_path_factory.mktemp("lockstep") / "bag"
    _record_run(bag, _env())
    return bag


def _reexecute(bag: pathlib.Path, *extra: str) -> dict:
    proc = subprocess.run([sys.executable, str(REPLAY), str(bag), "--reexecute", *extra], env=_env(), cwd=ROOT,
                          capture_output=True, text=True, timeout=400)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-4000:]
    return json.loads(proc.stdout.strip().splitlines()[-1])


def test_reexecute_reproduces_the_recorded_run_and_a_changed_gain_does_not(lockstep_bag):
    from climb_coordinator.report import load_run

    run = load_run(lockstep_bag)
    assert run.request["initial_posture"] == "ladder_4_contacts" and len(run.plans_log_ns) == 1
    assert "open_gripper" in run.fsm and run.base_t[-1] >= (TICKS - 5) * 0.005
    # the plan's first tick comes from the controller's acceptance (sim time; its diagnostic, or the
    # periodic diagnostics' copy when the recorder matched the controller too late for the first),
    # not from the order in which the recorder received the plan and the states (a race: 1 in 2
    # loaded runs once)
    assert len(run.plans_after_tick_ns) == 1 and run.plans_after_tick_ns[0] >= 500_000_000 - 5_000_000, run.plans_after_tick_ns
    same = _reexecute(lockstep_bag)
    assert same["plan_start_s"]["reexecuted"] == same["plan_start_s"]["recorded"], same
    assert same["compared"] > 0.8 * TICKS, same
    assert same["max_mm"] <= 1.0 and same["reproduced"], same
    assert same["final_fsm"]["reexecuted"] == same["final_fsm"]["recorded"] == "transfer", same
    # a CoM task 60x softer: the same plan, another trajectory within 2 s of sim time (at 10, 6x
    # softer, it moved the run by 0.98-1.1 mm, too near the 1 mm bound: 1 run in 3 failed)
    changed = _reexecute(lockstep_bag, "--set-param", "controller:tasks.com.stiffness=1.0", "--max-sim-s", "2.0")
    assert changed["compared"] > 0.8 * 400, changed
    assert changed["max_mm"] > 1.0 and not changed["reproduced"], changed


# ------------------------------------------------------------------------------------------------
# helper processes

def _two_args(fn):
    """rclpy passes the MessageInfo to a callback that takes exactly two arguments."""
    return lambda data, info: fn(data, info)


def listen_main(out: str, topics: list[str]) -> int:
    from climb_core.ros_env import apply_local_dds_env

    apply_local_dds_env()
    import rclpy
    from rclpy.qos import DurabilityPolicy, QoSProfile

    from rclpy.signals import SignalHandlerOptions

    from msgs_py.node_kit import install_signal_handlers, running

    types = {"joint_states": "sensor_msgs/msg/JointState", "clock": "rosgraph_msgs/msg/Clock",
             "controller/state": "climb_msgs/msg/ControllerState", "climb/request": "std_msgs/msg/String"}
    from msgs_py.bag import message_class

    install_signal_handlers()
    rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
    node = rclpy.create_node("replay_listener")
    heard: dict[str, list] = {t: [] for t in topics}
    for topic in topics:
        key = next(k for k in types if topic.endswith("/" + k))
        qos = QoSProfile(depth=1000, durability=DurabilityPolicy.TRANSIENT_LOCAL if key == "climb/request"
                         else DurabilityPolicy.VOLATILE)
        def on_message(data, info, t=topic):  # arrival: when DDS received it (not when Python got to it)
            heard[t].append((info["received_timestamp"] * 1e-9, bytes(data).hex()))

        node.create_subscription(message_class(types[key]), topic, _two_args(on_message), qos, raw=True)
    try:
        while running():
            rclpy.spin_once(node, timeout_sec=0.05)
    finally:
        pathlib.Path(out).write_text(json.dumps(heard))
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


def fake_main(name: str) -> int:
    from climb_core.ros_env import apply_local_dds_env

    apply_local_dds_env()
    import rclpy
    from climb_msgs.msg import JointCommand

    from rclpy.signals import SignalHandlerOptions

    from msgs_py.node_kit import install_signal_handlers, running

    install_signal_handlers()
    rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
    node = rclpy.create_node(name)
    count = [0]
    node.create_subscription(JointCommand, "joint_command", lambda m: count.__setitem__(0, count[0] + 1), 10)
    print("ready", flush=True)
    try:
        while running():
            rclpy.spin_once(node, timeout_sec=0.05)
    finally:
        print(f"joint_command received: {count[0]}", flush=True)
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


def drive_main() -> int:
    """Latch the request; once the controller ticks past 0.5 s of sim time, send the plan."""
    from climb_core.ros_env import apply_local_dds_env

    apply_local_dds_env()
    import rclpy
    from climb_msgs.msg import ControllerState, WholeBodyPlan
    from rclpy.qos import DurabilityPolicy, QoSProfile
    from std_msgs.msg import String

    from climb_core import fixtures
    from climb_core.environment import build_environment
    from climb_core.ladder import load_scenario
    from climb_core.robot import load_robot
    from controller_node.simple_plans import limb_transfer, plan_of
    from msgs_py.contact import whole_body_plan_to_msg
    from rclpy.signals import SignalHandlerOptions

    from msgs_py.node_kit import install_signal_handlers, running

    install_signal_handlers()
    robot = load_robot("g1")
    env = build_environment(load_scenario("default"))
    stance, q = fixtures.get("ladder_4_contacts", robot, env)
    plan = plan_of(robot, env, stance, [limb_transfer(robot, env, stance, q, "right_hand", "rung_6", -0.15)])
    rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
    node = rclpy.create_node("replay_test_driver")
    req_pub = node.create_publisher(String, "climb/request", QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL))
    req_pub.publish(String(data=json.dumps(REQUEST)))
    plan_pub = node.create_publisher(WholeBodyPlan, "whole_body_plan", QoSProfile(depth=1))
    sent = [False]

    def on_state(msg: ControllerState) -> None:
        if not sent[0] and msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec >= 500_000_000:
            plan_pub.publish(whole_body_plan_to_msg(plan))
            sent[0] = True
            print("plan sent", flush=True)

    node.create_subscription(ControllerState, "controller/state", on_state, QoSProfile(depth=100))
    announced = False
    try:
        while running():
            rclpy.spin_once(node, timeout_sec=0.05)
            if not announced and plan_pub.get_subscription_count() >= 1:  # the recorder (no controller yet)
                print("recorder subscribed", flush=True)
                announced = True
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    return 0 if sent[0] else 1


if __name__ == "__main__":
    os.environ.setdefault("PYTHONUNBUFFERED", "1")
    mode = sys.argv[1]
    if mode == "listen":
        sys.exit(listen_main(sys.argv[2], sys.argv[3:]))
    if mode == "fake":
        sys.exit(fake_main(sys.argv[2]))
    sys.exit(drive_main())
