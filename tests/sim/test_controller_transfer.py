"""Limb transfers on the default ladder under the QP + contact FSM (in-process, lock-step):
right hand rung 5 -> rung 6, then right foot rung 1 -> rung 2 (also with one tick of actuation
latency); guarded motion with rung 6 moved 2 cm (detection from the wrist F/T); the same hand
transfer in PWM compliance mode (also with the latency, compensated by the law's prediction)."""
from __future__ import annotations

import numpy as np
import pytest

from climb_core import fixtures
from climb_core.contact import HANDS
from controller_node.params import load_controller_params
from controller_node.runner import InProcessRunner
from controller_node.simple_plans import limb_transfer, plan_of

pytestmark = pytest.mark.sim

HAND_S = -0.15  # [m] right hand along rung 6 (fixture spacing)
FOOT_S = -0.12  # [m] right foot along rung 2


@pytest.fixture
def backend():
    from sim_bridge.pybullet_backend import PyBulletBackend

    b = PyBulletBackend()
    yield b
    b.close()


def _start(backend, command_delay_ticks=0, **overrides):
    params = load_controller_params(**overrides)
    runner = InProcessRunner.start(backend, params, posture="ladder_4_contacts",
                                   command_delay_ticks=command_delay_ticks)
    stance, q = fixtures.get("ladder_4_contacts", backend.robot, backend.env)
    return runner, stance, q


def _hand_touches_other_rungs(runner, limb):
    """A callback recording ticks where the moving hand touches something other than its target
    rung (sim contact list: used only to judge the test, never by the controller)."""
    hits = []

    def check(sim_state, output):
        if output.status.fsm_state in ("transfer",) and not runner.controller.path.in_approach():
            if np.linalg.norm(sim_state.contact_forces[limb]) > 1.0:
                hits.append(sim_state.time)

    return hits, check


@pytest.mark.parametrize("delay", [0, 1], ids=["same_tick", "one_tick_latency"])
def test_right_hand_then_right_foot_transfer_regrasp_and_no_fall(backend, delay):
    """delay 1: every command acts one period late (the bridge's lockstep.command_delay_ticks: 1,
    the pipelined lock-step) and the controller computing each command for the state one period
    ahead (``actuation_latency_s``): the QP controller does the same transfers."""
    runner, stance, q = _start(backend, command_delay_ticks=delay, actuation_latency_s=delay * 0.005)
    robot, env = backend.robot, backend.env
    hand = limb_transfer(robot, env, stance, q, "right_hand", "rung_6", HAND_S)
    foot = limb_transfer(robot, env, hand.target_stance, hand.path[-1], "right_foot", "rung_2", FOOT_S)
    runner.controller.set_plan(plan_of(robot, env, stance, [hand, foot]))
    hits, check = _hand_touches_other_rungs(runner, "right_hand")
    runner.on_tick.append(check)
    grasp_at = []
    runner.on_tick.append(lambda s, o: grasp_at.append(s.time) if s.grasps["right_hand"] == "rung_6" else None)
    log = runner.run(14.0, until=lambda o: o.status.fsm_state in ("hold", "failure", "replan_needed"))
    state = runner.sim_state
    c = runner.controller
    assert not log.fell, log.fall_reason
    assert c.fsm.state == "hold", [h[1:] for h in c.fsm.history]
    assert c.qp_failures == 0
    assert not hits  # the hand travelled without touching the rungs
    # the FSM went through both meta-states for each limb, in order
    visited = [h[3] for h in c.fsm.history]
    for expected in (["unload", "open_gripper", "transfer"], ["close_gripper", "load"], ["unload", "transfer"]):
        for s in expected:
            assert s in visited
    assert visited.index("close_gripper") < len(visited) - visited[::-1].index("unload") - 1
    # re-grasped rung 6 and kept it; the right foot stands on rung 2 and carries load
    assert state.grasps == {"left_hand": "rung_5", "right_hand": "rung_6"}
    assert grasp_at and grasp_at[0] > 1.0
    assert state.contact_forces["right_foot"][2] > 40.0
    rung2 = backend.surface_frame("rung_2")[:3, 3]
    sole = backend.surface_pose("right_foot")[:3, 3]
    assert abs(sole[0] - rung2[0]) < 0.05 and 0.0 < sole[2] - rung2[2] < 0.04
    assert set(c.contacts) == {"left_foot", "right_foot", "left_hand", "right_hand"}
    detections = c.events_of("contact_detected")
    assert [e.values["limb"] for e in detections] == ["right_hand", "right_foot"]


def _hand_onto_moved_rung_6(backend, offset):
    """The right hand's transfer to rung 6, planned on the nominal ladder while the simulator's
    rung 6 is ``offset`` [m] off along the hand's approach (its palm normal at the planned grasp):
    closer (< 0, early contact) or farther (late). Runs to hold / failure / replan_needed;
    (runner, the transfer, the planned grasp pose, the log)."""
    from sim_bridge.commands import PerturbRequest

    runner, stance, q = _start(backend)
    robot, env = backend.robot, backend.env
    hand = limb_transfer(robot, env, stance, q, "right_hand", "rung_6", HAND_S)
    T_planned = robot.T_world_surface("right_hand", hand.path[-1])
    normal = T_planned[:3, 2]  # palm normal = approach direction at the grasp
    along = np.array([normal[0], normal[2]]) / np.hypot(normal[0], normal[2])
    dx, dz = offset * along  # ladder base frame = world axes here (yaw 0)
    backend.request_perturbation(PerturbRequest("rung_offset", rung=6, dx=float(dx), dz=float(dz)))
    runner.controller.set_plan(plan_of(robot, env, stance, [hand]))
    log = runner.run(8.0, until=lambda o: o.status.fsm_state in ("hold", "failure", "replan_needed"))
    return runner, hand, T_planned, log


@pytest.mark.parametrize("offset, early", [(-0.02, True), (0.02, False)])
def test_guarded_motion_detects_a_rung_moved_2cm_from_the_wrist_ft(backend, offset, early):
    """Rung 6 is 2 cm off its planned place along the hand's approach (its palm normal at the
    planned grasp): closer (early contact) or farther (late). The plan is made on the nominal
    ladder; the contact is detected from the wrist F/T only; the hand stops on the real rung,
    grasps it and the transfer completes."""
    runner, hand, T_planned, log = _hand_onto_moved_rung_6(backend, offset)
    c = runner.controller
    assert not log.fell, log.fall_reason
    assert c.fsm.state == "hold", [h[1:] for h in c.fsm.history]
    assert c.qp_failures == 0
    detections = c.events_of("contact_detected")
    assert len(detections) == 1 and detections[0].values["limb"] == "right_hand"
    detected_at = np.asarray(c.events_of("limb_frozen")[0].values["position"])  # grasp centre [m]
    rung_axis = backend.surface_frame("rung_6")[:3, 3]
    # stopped on the real rung: grasp centre on its axis (x-z plane), 2 cm from the planned pose
    assert np.hypot(*(detected_at - rung_axis)[[0, 2]]) < 0.005
    assert np.linalg.norm(detected_at - T_planned[:3, 3]) == pytest.approx(0.02, abs=0.005)
    transfer_start = c.events_of("contact_removed")[0].time
    planned_arrival = transfer_start + hand.times[-1]  # [s] end of the planned approach
    if early:
        assert detections[0].values["state"] == "transfer"
        assert detections[0].time < planned_arrival - 0.2
    else:
        assert detections[0].values["state"] == "search"
        assert detections[0].time > planned_arrival
        assert 0.015 < detections[0].values["extra_travel"] < 0.035  # [m] crept on ~2 cm
    assert runner.sim_state.grasps["right_hand"] == "rung_6"


@pytest.mark.parametrize("delay", [0, 1], ids=["same_tick", "one_tick_latency_compensated"])
def test_compliance_mode_hand_transfer_through_the_pwm_motor_model_without_trips(backend, delay):
    """delay 1: the duty acts one period late and the law runs on the state predicted one period
    ahead (``actuation_latency_s``); without that prediction 16 drivers trip (measured)."""
    runner, stance, q = _start(backend, command_delay_ticks=delay, mode="compliance", actuation_latency_s=delay * 0.005)
    robot, env = backend.robot, backend.env
    hand = limb_transfer(robot, env, stance, q, "right_hand", "rung_6", HAND_S)
    runner.controller.set_plan(plan_of(robot, env, stance, [hand]))
    log = runner.run(8.0, until=lambda o: o.status.fsm_state in ("hold", "failure", "replan_needed"))
    assert runner.last_output.mode == "pwm"
    assert not log.fell, log.fall_reason
    assert runner.controller.fsm.state == "hold"
    assert not log.tripped  # no driver cut its motor
    assert max(log.max_current_ratio) < 1.0  # every motor below its over-current threshold
    assert runner.sim_state.grasps == {"left_hand": "rung_5", "right_hand": "rung_6"}
    assert all(h in HANDS for h in runner.sim_state.grasps)


def _noisy_backend(noise_percent: float, bias_percent: float):
    import dataclasses

    from sim_bridge.params import load_bridge_params
    from sim_bridge.pybullet_backend import PyBulletBackend

    params = load_bridge_params()
    return PyBulletBackend(dataclasses.replace(params, sensors=dataclasses.replace(
        params.sensors, ft_noise_percent=noise_percent, ft_bias_percent=bias_percent)))


@pytest.mark.parametrize("offset", [-0.02, 0.02])
def test_guarded_motion_under_ft_noise_of_2_percent_of_range(offset):
    """Issue 19, sensor realism: every F/T component carries white noise of sigma 2 % of the
    sensor's range (G1 wrist, 300 N: 6 N, as much as the nominal contact threshold) and a
    constant bias of sigma 1 %. The controller estimates each sensor's noise online and
    raises its contact threshold to guarded.noise_sigmas standard deviations of the filtered
    force; the bias is tared away at the approach. The hand still finds rung 6, 2 cm off the plan,
    on the real rung, and nothing fires before it."""
    backend = _noisy_backend(2.0, 1.0)
    try:
        runner, _, _, log = _hand_onto_moved_rung_6(backend, offset)
        c = runner.controller
        assert not log.fell, log.fall_reason
        assert c.fsm.state == "hold", [h[1:] for h in c.fsm.history]
        assert c.qp_failures == 0
        # the threshold rose with the noise: 5 sigma of 6 N through the filter (a = 1/2: x 0.58)
        assert c.contact_threshold("right_hand") == pytest.approx(5 * 6.0 * np.sqrt(0.5 / 1.5), rel=0.25)
        detections = c.events_of("contact_detected")
        assert len(detections) == 1 and detections[0].values["limb"] == "right_hand"
        detected_at = np.asarray(c.events_of("limb_frozen")[0].values["position"])
        rung_axis = backend.surface_frame("rung_6")[:3, 3]
        assert np.hypot(*(detected_at - rung_axis)[[0, 2]]) < 0.01  # [m] on the real rung
        assert runner.sim_state.grasps["right_hand"] == "rung_6"
    finally:
        backend.close()
