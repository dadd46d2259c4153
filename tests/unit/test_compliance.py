"""PWM compliance law (ladder_climbing_drc_hubo.txt eq. 1) with the G1 config's gains and motors."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from climb_core.robot import load_robot
from controller_node.compliance import ComplianceLaw, MotorArrays, PwmGainArrays


@pytest.fixture(scope="module")
def robot():
    return load_robot("g1")


@pytest.fixture(scope="module")
def law(robot):
    names = robot.joint_names
    return ComplianceLaw(PwmGainArrays.from_robot_config(robot.config, names),
                         MotorArrays.from_robot_config(robot.config, names), current_margin=0.85)


def test_gains_are_stiff_in_the_legs_and_decrease_shoulder_to_wrist(robot, law):
    kp = dict(zip(robot.joint_names, law.gains.kp))
    for side in ("left", "right"):
        leg = [kp[f"{side}_{j}_joint"] for j in ("hip_pitch", "knee", "ankle_pitch")]
        arm = [kp[f"{side}_shoulder_pitch_joint"], kp[f"{side}_elbow_joint"], kp[f"{side}_wrist_pitch_joint"]]
        assert min(leg) > max(arm)
        assert arm[0] > arm[1] > arm[2]


def test_paper_law_without_feedforward_is_proportional_to_the_error(law):
    n = len(law.gains.kp)
    q = np.zeros(n)
    error = np.full(n, 0.01)  # [rad]
    duty = law.duty(q + error, q, np.zeros(n), np.zeros(n), None)
    assert duty == pytest.approx(law.gains.kp * error)


def test_feedforward_duty_produces_the_torque_through_the_motor_model(law):
    rng = np.random.default_rng(3)
    n = len(law.gains.kp)
    velocity = rng.uniform(-2.0, 2.0, n)  # [rad/s]
    tau = rng.uniform(-0.3, 0.3, n) * law.motors.torque_per_amp * law.motors.current_limit * 0.5  # [N m]
    duty = law.torque_to_duty(tau, velocity)
    assert law.duty_to_torque(duty, velocity) == pytest.approx(tau, rel=1e-9, abs=1e-9)
    # at zero position error the law outputs exactly that duty (within the current window)
    q = np.zeros(n)
    out = law.duty(q, q, velocity, velocity, tau)
    lo, hi = law.duty_window(velocity)
    assert out == pytest.approx(np.clip(duty, lo, hi))
    assert law.duty_to_torque(out, velocity)[np.abs(duty) < 0.5] == pytest.approx(tau[np.abs(duty) < 0.5])


@settings(max_examples=60, deadline=None)
@given(st.floats(-3.0, 3.0), st.floats(-0.5, 0.5), st.floats(-200.0, 200.0))
def test_duty_never_exceeds_the_current_limit_or_the_unit_range(robot_law_cache, error, speed_fraction, tau):
    """Any error [rad], any joint speed up to half the no-load speed, any feed-forward [N m]:
    |duty| <= 1 and the predicted current stays within margin * limit (no over-current trip)."""
    law = robot_law_cache
    n = len(law.gains.kp)
    v = speed_fraction * law.motors.supply_voltage / law.motors.torque_per_amp  # [rad/s]
    duty = law.duty(np.full(n, error), np.zeros(n), np.zeros(n), v, np.full(n, tau))
    assert np.all(np.abs(duty) <= 1.0)
    assert np.all(np.abs(law.current(duty, v)) <= law.current_margin * law.motors.current_limit + 1e-9)


@pytest.fixture(scope="module")
def robot_law_cache(law):
    return law


@settings(max_examples=60, deadline=None)
@given(st.floats(-3.0, 3.0), st.floats(-3.0, 3.0), st.floats(-200.0, 200.0))
def test_a_joint_back_driven_past_its_no_load_speed_still_gets_a_valid_duty(robot_law_cache, error, speed_fraction,
                                                                             tau):
    """Joint speeds up to 3x the no-load speed (an impact, a slip back-driving the motor): the duty
    stays in [-1, 1] (the bridge rejects anything else), and where no duty can hold the current
    within margin * limit it is the full duty of the velocity's sign, the least current there is."""
    law = robot_law_cache
    m = law.motors
    n = len(law.gains.kp)
    v = np.full(n, speed_fraction) * m.supply_voltage / m.torque_per_amp  # [rad/s]
    duty = law.duty(np.full(n, error), np.zeros(n), np.zeros(n), v, np.full(n, tau))
    assert np.all(np.abs(duty) <= 1.0)
    i_max = law.current_margin * m.current_limit
    reachable = np.abs(m.torque_per_amp * v) <= m.supply_voltage + i_max * m.resistance
    assert np.all(np.abs(law.current(duty, v))[reachable] <= i_max[reachable] + 1e-9)
    assert np.all(duty[~reachable] == np.sign(v[~reachable]))
