"""Issue 20 against the sim_bridge process (real-time mode, one bridge for the module): parameters
(row 3: set_parameters killed the node; row 11: descriptors), raw garbage on the subscriptions
(row 5), sim/reset that fails (row 7) and sim/perturb refusals (row 8). Every bad input is refused
or reported, the bridge keeps publishing, and good input still works afterwards."""
from __future__ import annotations

import array
import math

import pytest

from harness import Client, NodeProcess

pytestmark = pytest.mark.ros

START_TIMEOUT_S = 90.0  # [s] a bridge process up and publishing, on a busy 2-core machine


def stamp_s(msg) -> float:
    return msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec


def damping_controller(client, ns: str) -> tuple[list[float], list]:
    """The test process as a lock-step controller of the bridge in namespace ``ns``: every state is
    answered with a DAMPING command stamped like it. Returns (state stamps [s], diagnostics seen)."""
    import array as _array

    from climb_msgs.msg import JointCommand
    from diagnostic_msgs.msg import DiagnosticArray
    from sensor_msgs.msg import JointState

    diags: list = []
    stamps: list[float] = []
    pub = client.node.create_publisher(JointCommand, f"{ns}/joint_command", client.qos("joint_command"))

    def answer(msg) -> None:
        stamps.append(stamp_s(msg))
        cmd = JointCommand(names=list(msg.name), modes=_array.array("B", [JointCommand.DAMPING] * len(msg.name)),
                           values=_array.array("d", [0.0] * len(msg.name)))
        cmd.header.stamp = msg.header.stamp
        pub.publish(cmd)

    client.node.create_subscription(JointState, f"{ns}/joint_states", answer, client.qos("joint_states"))
    client.node.create_subscription(DiagnosticArray, f"{ns}/diagnostics", lambda m: diags.extend(m.status),
                                    client.qos("diagnostics"))
    return stamps, diags


@pytest.fixture(scope="module")
def bridge():
    from sensor_msgs.msg import JointState

    proc = NodeProcess.module("sim_bridge.node", "-p", "execution:=realtime", name="sim_bridge")
    client = Client("bridge_hardening")
    try:
        client.states = client.subscribe(JointState, "joint_states", depth=50)
        from diagnostic_msgs.msg import DiagnosticArray

        client.diags = []
        client.node.create_subscription(DiagnosticArray, "diagnostics", lambda m: client.diags.extend(m.status),
                                        client.qos("diagnostics"))
        assert client.spin_until(lambda: len(client.states) > 5, START_TIMEOUT_S, [proc]), proc.tail()
        yield proc, client
    finally:
        client.close()
        code = proc.stop()
        out = proc.output()
        proc.close()
        assert code == 0 and "Traceback" not in out, out[-3000:]


def still_publishing(client, proc, n: int = 10) -> bool:
    before = len(client.states)
    return client.spin_until(lambda: len(client.states) >= before + n, 30.0, [proc])


# ------------------------------------------------------------------------------------ row 11
def test_every_parameter_has_a_description_with_unit_and_its_range(bridge):
    from rcl_interfaces.msg import ParameterType

    from climb_core.params import describe
    from sim_bridge.params import BridgeParams

    proc, client = bridge
    descriptors = client.describe_parameters("/sim_bridge")
    infos = describe(BridgeParams)
    assert set(infos) <= set(descriptors)
    for name, info in infos.items():
        d = descriptors[name]
        assert d.description and f"[{info.unit}]" in d.description, (name, d.description)
        if info.type == "float" and info.min is not None:
            assert d.floating_point_range and d.floating_point_range[0].from_value == info.min, name
        if info.type == "int" and info.max is not None:
            assert d.integer_range and d.integer_range[0].to_value == info.max, name
    assert descriptors["cpu_affinity"].description and descriptors["cpu_affinity"].read_only
    assert descriptors["robot"].read_only and descriptors["physics.dt_s"].read_only  # sim/reset / restart
    assert not descriptors["realtime.watchdog_s"].read_only
    assert descriptors["physics.dt_s"].type == ParameterType.PARAMETER_DOUBLE
    # every parameter has a value (an uninitialized cpu_affinity made get_parameters answer none)
    values = client.get_parameters("/sim_bridge", sorted(descriptors))
    assert set(values) == set(descriptors) and values["cpu_affinity"] == []


# ------------------------------------------------------------------------------------- row 3
def test_set_parameters_answers_validates_and_keeps_the_node(bridge):
    proc, client = bridge
    ok = client.set_parameters("/sim_bridge", {"realtime.watchdog_s": 0.08})
    assert ok[0].successful, ok[0].reason
    assert client.get_parameters("/sim_bridge", ["realtime.watchdog_s"]) == {"realtime.watchdog_s": 0.08}
    refused = client.set_parameters("/sim_bridge", {"realtime.watchdog_s": -5.0})
    assert not refused[0].successful and "watchdog_s" in refused[0].reason
    refused = client.set_parameters("/sim_bridge", {"physics.dt_s": 0.002})
    assert not refused[0].successful and "read-only" in refused[0].reason.lower()
    refused = client.set_parameters("/sim_bridge", {"execution": "banana"})
    assert not refused[0].successful
    # ROS's own parameter: the one that met the shadowed Node._clock
    assert client.set_parameters("/sim_bridge", {"use_sim_time": False})[0].successful
    assert proc.alive(), proc.tail()
    assert still_publishing(client, proc)
    assert client.set_parameters("/sim_bridge", {"realtime.watchdog_s": 0.05})[0].successful


# ------------------------------------------------------------------------------------- row 5
@pytest.mark.parametrize("topic", ["joint_command", "gripper_command"])
def test_raw_garbage_is_reported_and_the_bridge_keeps_running(bridge, topic):
    from climb_msgs.msg import GripperCommand, JointCommand

    proc, client = bridge
    msg_type = {"joint_command": JointCommand, "gripper_command": GripperCommand}[topic]
    assert client.wait_matched(msg_type, topic, watch=[proc])
    client.diags.clear()
    # (no empty payload: across processes Fast DDS then drops everything the writer sends next,
    # measured; the reader never sees it)
    for garbage in (bytes(range(17)), b"\x00\x01\x00\x00" + b"\xff" * 40):
        client.publish(msg_type, topic, garbage)
    assert client.spin_until(lambda: sum(f"rejected {topic}: undecodable" in d.message for d in client.diags) >= 2,
                             20.0, [proc]), \
        [d.message for d in client.diags]
    assert still_publishing(client, proc)
    # a good message after the garbage still works
    names = list(client.states[-1].name)
    client.diags.clear()
    good = JointCommand(names=names, modes=array.array("B", [JointCommand.DAMPING] * len(names)),
                        values=array.array("d", [0.0] * len(names)))
    client.publish(JointCommand, "joint_command", good)
    client.publish(JointCommand, "joint_command", JointCommand(names=["nope"], modes=array.array("B", [0]),
                                                               values=array.array("d", [math.nan])))
    assert client.spin_until(lambda: any("unknown joint 'nope'" in d.message for d in client.diags), 10.0, [proc])


# ------------------------------------------------------------------------------------- row 8
def test_perturb_refuses_bad_requests_with_the_reason(bridge):
    from climb_msgs.srv import SimPerturb

    proc, client = bridge
    R = SimPerturb.Request
    cases = [
        (R(kind=R.DROP, mass=2.0, radius=0.08, speed=3.0, target_link="no_such_link"), "no_such_link"),
        (R(kind=R.DROP, mass=2.0, radius=0.08, speed=1e6, target_link="torso"), "speed"),
        (R(kind=R.DROP, mass=1e5, radius=0.08, speed=3.0, target_link="torso"), "mass"),
        (R(kind=R.DROP, mass=math.nan, radius=0.08, speed=3.0, target_link="torso"), "mass"),
        (R(kind=R.DROP, mass=2.0, radius=50.0, speed=3.0, target_link="torso"), "radius"),
        (R(kind=R.RUNG_OFFSET, rung=999, dx=0.01), "999"),
        (R(kind=R.RUNG_OFFSET, rung=1, dz=math.inf), "dz"),
        (R(kind=R.RUNG_OFFSET, rung=1, dx=5.0), "dx"),
        (R(kind=R.RAILS_SHIFT, dy=0.02), "rails"),  # the default ladder has none
        (R(kind=R.DROP, mass=2.0, radius=0.08, speed=3.0, target_link="torso", at_time=-1.0), "at_time"),
        (R(kind=9), "kind"),
    ]
    for request, words in cases:
        response = client.call(SimPerturb, "sim/perturb", request)
        assert response is not None and not response.success, (request, response)
        assert words in response.error, (words, response.error)
    assert proc.alive(), proc.tail()
    client.diags.clear()
    ok = client.call(SimPerturb, "sim/perturb", R(kind=R.RUNG_OFFSET, rung=2, dx=0.01))
    assert ok.success, ok.error
    assert client.spin_until(lambda: any("rung 2 moved" in d.message for d in client.diags), 10.0, [proc])


# ------------------------------------------------------------------------------------- row 7
def test_failed_reset_changes_nothing(bridge):
    from climb_msgs.srv import SimReset

    proc, client = bridge
    assert still_publishing(client, proc, 40)  # sim time well past 0
    t_before = stamp_s(client.states[-1])
    assert t_before > 0.1
    for request, words in [(SimReset.Request(ladder="no_such_ladder"), "no_such_ladder"),
                           (SimReset.Request(robot="banana"), "banana"),
                           (SimReset.Request(q=[0.0, 1.0]), "q"),
                           (SimReset.Request(initial_posture="upside_down"), "upside_down"),
                           (SimReset.Request(ladder="/etc/hostname"), "file path"),  # no file read over ROS
                           (SimReset.Request(robot="/etc/hostname"), "file path"),
                           (SimReset.Request(ladder="ladder: {n_rungs: -3}"), "ladder")]:
        response = client.call(SimReset, "sim/reset", request)
        assert response is not None and not response.success and words in response.error, (request, response)
    n = len(client.states)
    assert still_publishing(client, proc, 20)
    stamps = [stamp_s(m) for m in client.states[n - 1:]]
    assert min(stamps) >= t_before, "a refused reset rewound the sim time"
    assert all(b > a for a, b in zip(stamps, stamps[1:]))
    # the last good ladder is kept: a reset naming no ladder works (it failed forever before). The
    # states are counted from before the call: the restarted ones can all arrive while the call waits
    # for its response (a fresh-clone run on 2026-12-02 saw only states from 2.66 s after it)
    n = len(client.states)
    response = client.call(SimReset, "sim/reset", SimReset.Request(seed=1))
    assert response.success, response.error
    assert still_publishing(client, proc, 5)
    assert min(stamp_s(m) for m in client.states[n:]) < 0.1  # this one restarted the time


# ------------------------------------------------------------------------- sim/contacts (issue 16)
def test_sim_contacts_at_its_sim_time_rate(bridge):
    from climb_msgs.msg import SimContacts

    proc, client = bridge
    received = client.subscribe(SimContacts, "sim/contacts")
    assert client.spin_until(lambda: len(received) >= 6, 30.0, [proc])
    msg = received[-1]
    assert list(msg.limbs) == ["left_foot", "right_foot", "left_hand", "right_hand"]
    assert len(msg.normal_force) == len(msg.tangential_force) == len(msg.surface) == len(msg.rung) == 4
    assert len(msg.grasped) == 4 and msg.header.frame_id == "world"
    gaps = {round(stamp_s(b) - stamp_s(a), 6) for a, b in zip(received[-5:], received[-4:])}
    assert gaps == {0.05}, gaps  # contacts.rate_hz 20 Hz of sim time
    assert client.set_parameters("/sim_bridge", {"contacts.rate_hz": 10.0})[0].successful
    n = len(received)
    assert client.spin_until(lambda: len(received) >= n + 5, 30.0, [proc])
    gaps = {round(stamp_s(b) - stamp_s(a), 6) for a, b in zip(received[-4:], received[-3:])}
    assert gaps == {0.1}, gaps
    assert client.set_parameters("/sim_bridge", {"contacts.rate_hz": 20.0})[0].successful


def test_failed_reset_in_lockstep_keeps_the_tick_going():
    """Row 7 in lock-step: a refused sim/reset neither rewinds the time nor leaves the bridge
    waiting for a command it never asked for ("controller lost"). The test process is the
    controller: it answers every state with a DAMPING command stamped like it."""
    from climb_msgs.srv import SimReset

    proc = NodeProcess.module("sim_bridge.node", "-r", "__ns:=/lockstep_reset", name="sim_bridge_lockstep")
    client = Client("bridge_lockstep_reset")
    try:
        stamps, diags = damping_controller(client, "/lockstep_reset")
        assert client.spin_until(lambda: len(stamps) > 40, START_TIMEOUT_S, [proc]), proc.tail()
        lost = lambda: [d.message for d in diags if "controller lost" in d.message]  # noqa: E731
        assert not lost()
        response = client.call(SimReset, "/lockstep_reset/sim/reset", SimReset.Request(ladder="no_such_ladder"))
        assert response is not None and not response.success and "no_such_ladder" in response.error
        n = len(stamps)
        assert client.spin_until(lambda: len(stamps) > n + 40, 60.0, [proc]), proc.tail()
        after = stamps[n - 1:]
        assert all(round(b - a, 6) == 0.005 for a, b in zip(after, after[1:])), after[:10]
        assert not lost(), lost()
    finally:
        client.close()
        code = proc.stop()
        out = proc.output()
        proc.close()
    assert code == 0 and "Traceback" not in out, out[-3000:]


def test_a_controller_that_joins_after_the_first_state_gets_it_again_and_the_loop_runs():
    """A lock-step bridge that started without a controller (startup wait 0) publishes its t = 0
    state before anyone listens: DDS drops it for the late reader (VOLATILE). Until the first
    command arrives the bridge publishes the awaited state again (lockstep.resend_s, doubling), so
    a controller that joins 2 s late still gets it, answers, and the ticks run with no controller
    reported lost (test_controller_node's CI failure: the observer missed state 0 and waited)."""
    proc = NodeProcess.module("sim_bridge.node", "-r", "__ns:=/late_join", "-p", "lockstep.startup_wait_s:=0.0",
                              "-p", "lockstep.command_timeout_s:=120.0", "-p", "lockstep.resend_s:=0.25",
                              name="sim_bridge_late_join")
    client = Client("bridge_late_join")
    try:
        assert client.spin_until(lambda: "starting the lock-step anyway" in proc.output(), START_TIMEOUT_S, [proc]), \
            proc.tail()
        client.spin(2.0)  # the state stamped 0 went out with nobody listening
        stamps, diags = damping_controller(client, "/late_join")
        assert client.spin_until(lambda: len(stamps) > 40, 60.0, [proc]), (stamps[:5], proc.tail())
        assert stamps[0] == 0.0  # the first state it saw is the one sent before it joined
        ticks = sorted({round(t / 0.005) for t in stamps})
        assert ticks[:40] == list(range(40)), ticks[:10]  # then every tick, no gap
        assert not [d.message for d in diags if "controller lost" in d.message]
        assert not [d.message for d in diags if d.name.endswith("/command")], "an echoed answer was reported"
    finally:
        client.close()
        code = proc.stop()
        out = proc.output()
        proc.close()
    assert code == 0 and "Traceback" not in out, out[-3000:]
