"""PWM through the DC-motor model in a closed kinematic chain (G1 on the ladder, both feet on rung
1, both hands latched on rung 5): with a 1 cm hand calibration error, stiff position-like PWM gains
trip the arm drivers' over-current protection, the robot config's compliant arm gains do not
(ladder_climbing_drc_hubo.txt, section IV).

The duty is recomputed every 1 ms here (control period 1 ms): the paper's eq. 1 with these gains
held for 5 ms (200 Hz) is not stable on the G1's light links (see docs/sim_bridge.md).
"""
from __future__ import annotations

import numpy as np
import pytest

from sim_bridge.backend import ResetRequest
from sim_bridge.params import load_bridge_params
from sim_bridge.pybullet_backend import PyBulletBackend
from sim_bridge.simple_control import GravityCompensatedPd, pwm_command

pytestmark = pytest.mark.sim

CALIBRATION_ERROR = 0.01  # [m] each hand's target is off by 1 cm along world x
STIFF_KP = 15.0  # [duty/rad] position-like gain on every joint
LIMBS4 = ("left_foot", "right_foot", "left_hand", "right_hand")


@pytest.fixture(scope="module")
def backend():
    b = PyBulletBackend(load_bridge_params(**{"physics.control_period_s": 0.001}))
    yield b
    b.close()


def miscalibrated_target(robot, q: np.ndarray, error: float) -> np.ndarray:
    """Joint targets that put each hand ``error`` [m] (world x) away from where it really is."""
    import pinocchio as pin

    model, data = robot.model, robot.model.createData()
    pin.computeJointJacobians(model, data, q)
    pin.updateFramePlacements(model, data)
    q_des = q[7:].copy()
    for hand in ("left_hand", "right_hand"):
        limb = robot.config.limbs[hand]
        J = pin.getFrameJacobian(model, data, robot.frame_id(limb.surface.frame), pin.LOCAL_WORLD_ALIGNED)[:3]
        arm = [j for j in limb.joints if not j.startswith("waist")]
        cols = [robot.joint_index_v(j) for j in arm]
        dq = np.linalg.pinv(J[:, cols]) @ np.array([error, 0.0, 0.0])
        for col, delta in zip(cols, dq):
            q_des[col - 6] += delta
    return q_des


def run(backend, kp_arm: float | None, error: float, ticks: int):
    """PWM eq. 1 with the config's gains (legs, waist) and ``kp_arm`` on the arms (None = config)."""
    state = backend.reset(ResetRequest(robot="g1", ladder="default", initial_posture="ladder_4_contacts"))
    assert state.grasps == {"left_hand": "rung_5", "right_hand": "rung_5"}
    robot = backend.robot
    names = robot.joint_names
    kp = np.array([robot.config.pwm.kp[n] for n in names])
    kd = np.array([robot.config.pwm.kd[n] for n in names])
    arm = np.array([any(k in n for k in ("shoulder", "elbow", "wrist")) for n in names])
    if kp_arm is not None:
        kp = np.where(arm, kp_arm, np.maximum(kp, kp_arm))
    q_des = miscalibrated_target(robot, state.base.q, error)
    feedforward = GravityCompensatedPd(robot, state.base.q, contact_limbs=LIMBS4)
    backend.drain_events()
    for _ in range(ticks):
        cmd = pwm_command(robot, backend.actuators.motors, state, q_des, kp, kd,
                          feedforward.gravity_torques(state.base.q))
        state = backend.step(cmd)
    trips = [e for e in backend.drain_events() if e.kind == "overcurrent"]
    arm_trips = {e.values["joint"] for e in trips if any(k in e.values["joint"] for k in ("shoulder", "elbow", "wrist"))}
    return state, trips, arm_trips


def test_stiff_gains_trip_the_arm_drivers_in_the_closed_chain(backend):
    state, trips, arm_trips = run(backend, STIFF_KP, CALIBRATION_ERROR, ticks=100)
    assert arm_trips, "a 1 cm error against stiff gains must trip the arm drivers"
    first = min(trips, key=lambda e: e.time)
    assert first.time < 0.05  # [s]
    limit = {n: l for n, l in zip(backend.joint_names, backend.actuators.motor_params.current_limit)}
    assert abs(float(first.values["current_A"])) > limit[first.values["joint"]]
    assert "power cut" in first.message and first.level == 2
    assert set(state.tripped) & arm_trips or any(float(e.values["until_s"]) > state.time for e in trips)


def test_stiff_gains_without_the_error_do_not_trip(backend):
    """Control experiment: the trips above come from the error in the closed chain."""
    state, trips, arm_trips = run(backend, STIFF_KP, 0.0, ticks=200)
    assert not trips and not state.fell


def test_compliant_arm_gains_absorb_the_error(backend):
    state, trips, arm_trips = run(backend, None, CALIBRATION_ERROR, ticks=500)
    assert not arm_trips
    assert state.grasps == {"left_hand": "rung_5", "right_hand": "rung_5"} and not state.fell
    # the arms comply: the hands stay on the rung instead of going to the miscalibrated targets
    for hand in ("left_hand", "right_hand"):
        assert backend.grasps.slide(hand) < 0.005
    arm = [i for i, n in enumerate(state.joint_names) if "shoulder" in n or "elbow" in n]
    assert np.all(np.abs(state.motor_current[arm]) < backend.actuators.motor_params.current_limit[arm])
