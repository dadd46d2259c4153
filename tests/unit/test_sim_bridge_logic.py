"""Bridge protocol logic on the mock backend: command validation, lock-step, watchdog, stamped
requests (no physics engine, no ROS)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from climb_core.errors import SpecError
from sim_bridge.bridge import ERROR, SimBridge
from sim_bridge.commands import (DAMPING, MODES, POSITION, PWM, TORQUE, ActuatorCommand, GripperRequest,
                                 PerturbRequest, validate_joint_command)
from sim_bridge.mock_backend import MockBackend
from sim_bridge.params import load_bridge_params

NAMES = ("hip", "knee", "ankle")
LIMITS = np.array([80.0, 80.0, 30.0])
PERIOD_NS = 5_000_000


def make(execution: str = "lockstep", **overrides) -> SimBridge:
    params = load_bridge_params(execution=execution, **overrides)
    backend = MockBackend(NAMES, LIMITS, params=params)
    bridge = SimBridge(backend, params)
    bridge.reset()
    return bridge


def test_mode_codes_match_the_message_constants():
    from climb_msgs.msg import GripperCommand, JointCommand

    assert MODES == {"torque": JointCommand.TORQUE, "pwm": JointCommand.PWM,
                     "position": JointCommand.POSITION, "damping": JointCommand.DAMPING}
    assert (GripperCommand.OPEN, GripperCommand.CLOSE, GripperCommand.POSITION) == (0, 1, 2)


@pytest.mark.parametrize("names, modes, values, field, rule", [
    (["hip"], [TORQUE], [math.nan], "joint_command.values[0]", "finite"),
    (["hip"], [TORQUE], [math.inf], "joint_command.values[0]", "finite"),
    (["hip", "knee"], [TORQUE], [1.0, 2.0], "joint_command.modes", "one mode per name"),
    (["hip"], [TORQUE], [1.0, 2.0], "joint_command.values", "one value per name"),
    (["hip", "elbow"], [TORQUE, TORQUE], [1.0, 2.0], "joint_command.names[1]", "unknown joint 'elbow'"),
    (["hip", "hip"], [TORQUE, TORQUE], [1.0, 2.0], "joint_command.names[1]", "named twice"),
    (["knee"], [7], [1.0], "joint_command.modes[0]", "unknown mode 7"),
    (["knee"], [PWM], [1.5], "joint_command.values[0]", "PWM duty"),
])
def test_bad_commands_name_the_problem(names, modes, values, field, rule):
    with pytest.raises(SpecError) as info:
        validate_joint_command(names, modes, values, NAMES)
    assert info.value.field == field and rule in info.value.rule


@pytest.mark.parametrize("modes, values, field, rule", [
    ([TORQUE, TORQUE, TORQUE], [1.0, math.nan, 3.0], "joint_command.values[1]", "finite"),
    ([TORQUE, 9, TORQUE], [1.0, 2.0, 3.0], "joint_command.modes[1]", "unknown mode 9"),
    ([TORQUE, TORQUE, PWM], [1.0, 2.0, -1.5], "joint_command.values[2]", "PWM duty"),
    ([TORQUE, True, TORQUE], [1.0, 2.0, 3.0], "joint_command.modes[1]", "unknown mode True"),
])
def test_a_full_command_in_joint_order_is_checked_like_any_other(modes, values, field, rule):
    """Every joint in the robot's order (what controllers send) takes a vectorised path: same
    result, same errors as the per-joint path."""
    import array

    good = validate_joint_command(list(NAMES), array.array("B", [PWM, TORQUE, POSITION]),
                                  array.array("d", [0.5, -4.0, 0.2]), NAMES, stamp_ns=15)
    reordered = validate_joint_command(["knee", "ankle", "hip"], [TORQUE, POSITION, PWM], [-4.0, 0.2, 0.5], NAMES,
                                       stamp_ns=15)
    for cmd in (good, reordered):
        assert list(cmd.modes) == [PWM, TORQUE, POSITION] and list(cmd.values) == [0.5, -4.0, 0.2]
        assert cmd.stamp_ns == 15 and cmd.modes.dtype == np.uint8
    with pytest.raises(SpecError) as info:
        validate_joint_command(list(NAMES), modes, values, NAMES)
    assert info.value.field == field and rule in info.value.rule


def test_a_partial_command_damps_the_joints_it_does_not_name():
    cmd = validate_joint_command(["knee"], ["position"], [0.3], NAMES, stamp_ns=10)
    assert list(cmd.modes) == [DAMPING, POSITION, DAMPING] and cmd.values[1] == 0.3 and cmd.stamp_ns == 10


def test_lockstep_accepts_only_the_command_stamped_for_the_current_tick():
    bridge = make()
    assert bridge.stamp_ns == 0 and not bridge.command_ready()
    verdict = bridge.offer_command(NAMES, [TORQUE] * 3, [1.0, 2.0, 3.0], stamp_ns=PERIOD_NS)  # early
    assert not verdict.accepted and verdict.reason == "stale" and not bridge.command_ready()
    assert bridge.offer_command(NAMES, [TORQUE] * 3, [1.0, 2.0, 3.0], stamp_ns=0).accepted
    assert bridge.command_ready()
    state = bridge.step_lockstep()
    assert state.stamp_ns == PERIOD_NS and np.allclose(state.tau, [1.0, 2.0, 3.0])
    assert not bridge.command_ready()  # the next tick needs its own command
    again = bridge.offer_command(NAMES, [TORQUE] * 3, [9.0, 9.0, 9.0], stamp_ns=0)  # tick 0 ran on its answer
    assert not again.accepted and again.reason == "duplicate" and bridge.stale == 1


def test_with_one_tick_of_latency_each_period_runs_on_the_previous_tick_s_command():
    """lockstep.command_delay_ticks = 1: [0, T) and [T, 2T) on the command stamped 0, then
    [t, t + T) on the one stamped t - T; an answer that overtakes the awaited one is kept for its
    period, an invalid one stands for its tick (no wait), and a missing one is damped and reported."""
    bridge = make(**{"lockstep.command_delay_ticks": 1})

    def offer(stamp_ns, value):
        return bridge.offer_command(NAMES, [TORQUE] * 3, [value] * 3, stamp_ns=stamp_ns)

    assert bridge.awaited_stamp_ns == 0 and not bridge.command_ready()
    assert offer(0, 1.0).accepted
    assert np.allclose(bridge.step_lockstep().tau, 1.0)  # [0, T)
    assert bridge.awaited_stamp_ns == 0 and bridge.command_ready()  # start-up: still the command stamped 0
    assert offer(PERIOD_NS, 2.0).accepted  # computed from state T while the physics steps
    assert np.allclose(bridge.step_lockstep().tau, 1.0)  # [T, 2T)
    assert bridge.awaited_stamp_ns == PERIOD_NS and bridge.command_ready()
    assert np.allclose(bridge.step_lockstep().tau, 2.0)  # [2T, 3T) on the command stamped T
    assert bridge.awaited_stamp_ns == 2 * PERIOD_NS and not bridge.command_ready()
    stale = offer(PERIOD_NS, 9.0)
    assert not stale.accepted and stale.reason == "stale"
    too_early = offer(4 * PERIOD_NS, 9.0)
    assert not too_early.accepted and bridge.stale == 2
    # the answer to 3T comes first: kept, not applied to [3T, 4T); the answer to 2T is bad
    assert offer(3 * PERIOD_NS, 4.0).accepted and not bridge.command_ready()
    bad = offer(2 * PERIOD_NS, math.nan)
    assert not bad.accepted and bridge.command_ready()  # the tick runs on the last valid command
    assert np.allclose(bridge.step_lockstep().tau, 4.0)
    assert bridge.command_ready()  # [4T, 5T): the answer to 3T, kept since it came
    assert np.allclose(bridge.step_lockstep().tau, 4.0)
    assert not bridge.command_ready()
    damped = bridge.step_lockstep()  # nobody answered 4T
    assert bridge.controller_lost and bridge.lost_ticks == 1
    assert np.all(np.sign(damped.tau) == -np.sign(damped.v))  # damping, not the last command
    lost = [d for d in bridge.drain_diagnostics() if d.name == "sim_bridge/controller"]
    assert lost and "0.020 s" in lost[-1].message  # the awaited stamp, 4T


def test_the_step_summary_splits_the_lockstep_period_into_publish_wait_and_step():
    bridge = make()
    summaries = [d for d in bridge.drain_diagnostics() if d.name == "sim_bridge/step"]
    for i in range(3):
        bridge.note_lockstep_times(publish_s=0.0002, wait_s=0.001 * (i + 1))
        bridge.offer_command(NAMES, [TORQUE] * 3, [0.0, 0.0, 0.0], stamp_ns=bridge.stamp_ns)
        bridge.step_lockstep()
        summaries += [d for d in bridge.drain_diagnostics() if d.name == "sim_bridge/step"]
    values = summaries[0].values  # the first tick's summary: one publish and one wait so far
    assert float(values["publish_p50_ms"]) == pytest.approx(0.2) and float(values["wait_max_ms"]) == pytest.approx(1.0)
    assert float(values["step_p50_ms"]) >= 0.0
    assert "wait_p99_ms" in values and "publish_max_ms" in values


def test_lost_controller_damps_every_joint_and_is_reported_then_recovers():
    bridge = make()
    bridge.backend.v[:] = [1.0, -2.0, 0.5]  # [rad/s] moving joints
    state = bridge.step_lockstep()  # nothing arrived in time
    gain = bridge.params.actuation.damping_gain
    assert bridge.controller_lost
    assert np.all(np.sign(state.tau) == -np.sign(state.v)) and np.all(np.abs(state.tau) <= gain * 2.0 + 1e-9)
    diags = bridge.drain_diagnostics()
    lost = [d for d in diags if d.name == "sim_bridge/controller"]
    assert lost and lost[0].level == ERROR and "lost" in lost[0].message
    assert bridge.wait_budget() == bridge.params.lockstep.lost_retry_s
    bridge.step_lockstep()
    assert not [d for d in bridge.drain_diagnostics() if d.name == "sim_bridge/controller"]  # reported once
    assert bridge.offer_command(NAMES, [TORQUE] * 3, [5.0, 5.0, 5.0], stamp_ns=bridge.stamp_ns).accepted
    state = bridge.step_lockstep()
    assert not bridge.controller_lost and np.allclose(state.tau, 5.0)
    assert any("back" in d.message for d in bridge.drain_diagnostics())


def test_the_first_state_may_be_sent_again_until_answered_and_an_echoed_answer_is_no_news():
    """lockstep.resend_s: until a world's first command arrives the node may publish the awaited
    state again (a controller that matched after the first send); a controller answers such a
    state with the same command again, and that echo arriving after the tick ran is dropped
    without a stale-command report."""
    bridge = make()
    assert bridge.awaiting_first_command
    assert bridge.offer_command(NAMES, [TORQUE] * 3, [1.0, 2.0, 3.0], stamp_ns=0).accepted
    assert not bridge.awaiting_first_command
    bridge.step_lockstep()
    bridge.drain_diagnostics()
    echo = bridge.offer_command(NAMES, [TORQUE] * 3, [1.0, 2.0, 3.0], stamp_ns=0)
    assert not echo.accepted and echo.reason == "duplicate" and not bridge.command_ready()
    assert bridge.stale == 0 and not bridge.drain_diagnostics()
    older = bridge.offer_command(NAMES, [TORQUE] * 3, [1.0, 2.0, 3.0], stamp_ns=PERIOD_NS * 7)
    assert older.reason == "stale" and bridge.stale == 1  # anything else off-stamp is still reported
    bridge.reset()
    assert bridge.awaiting_first_command  # a new world: its first state may be sent again
    lost = make()
    lost.step_lockstep()  # nothing came: lost, and the states now flow at the lost pace anyway
    assert lost.controller_lost and not lost.awaiting_first_command


def test_a_reset_world_waits_longer_for_its_first_command_then_the_usual_bounds_apply():
    """After sim/reset the climb coordinator activates the controller once the first plan exists:
    the world's first tick waits lockstep.reset_wait_s for it (no damped ticks meanwhile), the
    ticks after it command_timeout_s, a lost controller lost_retry_s."""
    bridge = make(**{"lockstep.reset_wait_s": 120.0, "lockstep.command_timeout_s": 1.0})
    lock = bridge.params.lockstep
    assert bridge.wait_budget() == lock.command_timeout_s  # a world not reset by the service
    bridge.reset()
    bridge.await_first_command()
    assert bridge.wait_budget() == 120.0
    assert bridge.offer_command(NAMES, [TORQUE] * 3, [1.0, 1.0, 1.0], stamp_ns=bridge.stamp_ns).accepted
    bridge.step_lockstep()
    assert bridge.wait_budget() == lock.command_timeout_s
    bridge.reset()
    bridge.await_first_command()
    bridge.step_lockstep()  # the long wait ran out: lost, damped, retried at the lost pace
    assert bridge.controller_lost and bridge.wait_budget() == lock.lost_retry_s
    # the node's default (0): a reset world waits command_timeout_s like any tick
    plain = make(**{"lockstep.command_timeout_s": 1.0})
    plain.await_first_command()
    assert plain.params.lockstep.reset_wait_s == 0.0 and plain.wait_budget() == 1.0


def test_a_bad_command_is_rejected_and_the_tick_runs_on_the_last_valid_one():
    bridge = make()
    bridge.offer_command(NAMES, [TORQUE] * 3, [1.0, 2.0, 3.0], stamp_ns=0)
    bridge.step_lockstep()
    bridge.drain_diagnostics()
    verdict = bridge.offer_command(NAMES, [TORQUE] * 3, [1.0, math.nan, 3.0], stamp_ns=bridge.stamp_ns)
    assert not verdict.accepted and "values[1]" in verdict.reason
    assert bridge.command_ready()  # no second wait for this tick
    state = bridge.step_lockstep()
    assert np.allclose(state.tau, [1.0, 2.0, 3.0]) and not bridge.controller_lost
    errors = [d for d in bridge.drain_diagnostics() if d.name == "sim_bridge/command"]
    assert errors and errors[0].level == ERROR and errors[0].values["field"] == "joint_command.values[1]"
    assert "knee" in errors[0].message and "last valid command" in errors[0].message


def test_a_bad_first_command_falls_back_to_damping():
    bridge = make()
    bridge.backend.v[:] = [1.0, 1.0, 1.0]
    bridge.offer_command(["elbow"], [TORQUE], [1.0], stamp_ns=0)
    state = bridge.step_lockstep()
    assert np.all(state.tau < 0.0)  # damped
    assert "unknown joint 'elbow'" in bridge.drain_diagnostics()[0].message


def test_realtime_watchdog_damps_after_50_ms_without_commands_and_resumes():
    bridge = make("realtime")
    watchdog = bridge.params.realtime.watchdog_s
    assert watchdog == pytest.approx(0.05)
    bridge.offer_command(NAMES, [TORQUE] * 3, [4.0, 4.0, 4.0], stamp_ns=123, wall_time=10.0)  # any stamp
    state = bridge.step_realtime(wall_time=10.0 + 0.8 * watchdog)
    assert np.allclose(state.tau, 4.0) and not bridge.watchdog_active
    bridge.backend.v[:] = [1.0, 1.0, 1.0]
    state = bridge.step_realtime(wall_time=10.0 + 1.2 * watchdog)
    assert bridge.watchdog_active and np.all(state.tau < 0.0)
    diag = [d for d in bridge.drain_diagnostics() if d.name == "sim_bridge/watchdog"]
    assert diag and diag[0].level == ERROR and "damping" in diag[0].message
    bridge.offer_command(NAMES, [TORQUE] * 3, [4.0, 4.0, 4.0], stamp_ns=0, wall_time=10.2)
    state = bridge.step_realtime(wall_time=10.21)
    assert not bridge.watchdog_active and np.allclose(state.tau, 4.0)
    assert any(d.message == "commands resumed" for d in bridge.drain_diagnostics())


def test_gripper_and_perturbation_requests_take_effect_at_their_stamp():
    bridge = make()
    bridge.offer_gripper(GripperRequest("left_hand", "close", stamp_ns=3 * PERIOD_NS))
    bridge.offer_perturbation(PerturbRequest("rung_offset", rung=2, dz=0.02, at_time=0.02))
    for k in range(3):
        bridge.offer_command(NAMES, [DAMPING] * 3, [0.0] * 3, stamp_ns=bridge.stamp_ns)
        state = bridge.step_lockstep()
        assert state.grasps["left_hand"] == ""  # ticks 0, 1, 2
    bridge.offer_command(NAMES, [DAMPING] * 3, [0.0] * 3, stamp_ns=bridge.stamp_ns)
    state = bridge.step_lockstep()  # tick 3 starts at 15 ms: the close request is due
    assert state.grasps["left_hand"] == "mock_surface" and not bridge.backend.perturbations
    bridge.offer_command(NAMES, [DAMPING] * 3, [0.0] * 3, stamp_ns=bridge.stamp_ns)
    bridge.step_lockstep()  # tick 4 starts at 20 ms
    assert [p.kind for p in bridge.backend.perturbations] == ["rung_offset"]


def test_requests_are_validated():
    with pytest.raises(SpecError, match="gripper_command.hand"):
        GripperRequest("left_foot", "close")
    with pytest.raises(SpecError, match="perturbation.mass"):
        PerturbRequest("drop", mass=0.0, radius=0.1, speed=5.5, target_link="torso")
    with pytest.raises(SpecError, match="perturbation.kind"):
        PerturbRequest("earthquake")
    assert PerturbRequest(0, mass=10.0, radius=0.1, speed=5.5, target_link="torso").kind == "drop"


def test_in_process_commands_are_checked_too():
    bridge = make()
    with pytest.raises(SpecError, match="one mode per actuated joint"):
        bridge.backend.apply_command(ActuatorCommand(np.zeros(2, dtype=np.uint8), np.zeros(2)))
    verdict = bridge.offer_actuator_command(ActuatorCommand(np.full(3, PWM, dtype=np.uint8), np.array([0, 2.0, 0])))
    assert not verdict.accepted and "PWM duty" in verdict.reason


def test_same_seed_same_noisy_run():
    def run(seed: int) -> np.ndarray:
        params = load_bridge_params(seed=seed, **{"sensors.joint_position_noise_std": 0.01})
        bridge = SimBridge(MockBackend(NAMES, LIMITS, params=params), params)
        bridge.reset()
        out = []
        for k in range(20):
            bridge.offer_command(NAMES, [TORQUE] * 3, [math.sin(k), 1.0, -1.0], stamp_ns=bridge.stamp_ns)
            out.append(bridge.step_lockstep().q)
        return np.array(out)

    assert np.array_equal(run(3), run(3))
    assert not np.array_equal(run(3), run(4))


def test_joint_names_known_only_after_reset_are_accepted():
    """A backend learns its robot at reset (the PyBullet one does): the bridge must index it then."""

    class LateBackend(MockBackend):
        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            self._names = self.joint_names
            self.joint_names = ()

        def reset(self, request=None):
            self.joint_names = self._names
            return super().reset(request)

    params = load_bridge_params()
    bridge = SimBridge(LateBackend(NAMES, LIMITS, params=params), params)
    bridge.reset()
    assert bridge.offer_command(NAMES, [TORQUE] * 3, [1.0, 1.0, 1.0], stamp_ns=0).accepted
