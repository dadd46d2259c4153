"""DC motor model and actuator modes of the sim bridge (no physics engine)."""
from __future__ import annotations

import numpy as np
import pytest

from sim_bridge.actuation import ActuatorBank
from sim_bridge.commands import DAMPING, POSITION, PWM, TORQUE, ActuatorCommand
from sim_bridge.motor import DcMotorBank, MotorParams, motor_params_from_table
from sim_bridge.params import load_bridge_params
from climb_core.errors import SpecError

V, R, KT, N, I_MAX, HOLD = 48.0, 0.5, 0.1, 20.0, 40.0, 0.5


def motors(n: int = 1) -> MotorParams:
    return MotorParams.uniform(n, supply_voltage=V, resistance=R, torque_constant=KT, gear_ratio=N,
                               current_limit=I_MAX, trip_hold_off_s=HOLD)


def test_stall_and_back_emf_follow_the_dc_motor_equations():
    bank = DcMotorBank(motors(2))
    duty = np.array([0.25, 0.25])
    qdot = np.array([0.0, 3.0])  # [rad/s]
    i = bank.pwm_current(duty, qdot)
    assert i[0] == pytest.approx(0.25 * V / R)  # 24 A at stall
    assert i[1] == pytest.approx((0.25 * V - KT * N * 3.0) / R)  # back-EMF 6 V -> 12 A
    assert bank.torque_from_current(i)[0] == pytest.approx(N * KT * 24.0)  # 48 N m
    # no-load speed: the current vanishes where back-EMF equals the supply
    w0 = 0.25 * V / (KT * N)
    assert bank.pwm_current(np.array([0.25]), np.array([w0]))[0] == pytest.approx(0.0, abs=1e-12)


def test_duty_for_torque_inverts_the_model():
    bank = DcMotorBank(motors(3))
    tau = np.array([10.0, -20.0, 5.0])
    qdot = np.array([0.0, 1.0, -2.0])
    duty = bank.duty_for_torque(tau, qdot)
    assert np.allclose(bank.torque_from_current(bank.pwm_current(duty, qdot)), tau)


def test_overcurrent_trips_after_the_delay_and_powers_back_after_hold_off():
    bank = DcMotorBank(motors(1), trip_delay_s=0.002)
    dt = 0.001
    big = np.array([50.0])  # [A] > 40 A
    flowing, trips = bank.update(big, 0.000, dt)
    assert not trips and flowing[0] == 50.0  # 1 ms above the limit: not yet
    flowing, trips = bank.update(big, 0.001, dt)
    assert len(trips) == 1 and trips[0].until == pytest.approx(0.001 + HOLD)
    assert flowing[0] == 0.0  # power cut at once
    flowing, trips = bank.update(big, 0.3, dt)
    assert flowing[0] == 0.0 and not trips  # still in hold-off: no new trip while unpowered
    flowing, trips = bank.update(np.array([10.0]), 0.6, dt)
    assert flowing[0] == 10.0 and bank.trip_count[0] == 1  # power back


def test_short_spike_does_not_trip():
    bank = DcMotorBank(motors(1), trip_delay_s=0.002)
    bank.update(np.array([60.0]), 0.0, 0.001)
    flowing, trips = bank.update(np.array([10.0]), 0.001, 0.001)
    assert not trips and flowing[0] == 10.0


def test_actuator_modes_compute_the_documented_torques():
    params = load_bridge_params().actuation
    names = ("a", "b", "c", "d")
    bank = ActuatorBank(names, np.array([30.0, 30.0, 30.0, 30.0]), motors(4), params)
    bank.set_command(ActuatorCommand(np.array([TORQUE, PWM, POSITION, DAMPING], dtype=np.uint8),
                                     np.array([50.0, 0.1, 0.001, 123.0])))
    q = np.zeros(4)
    qdot = np.array([0.0, 0.0, 0.0, 2.0])
    tau, trips = bank.torques(q, qdot, 0.0, 0.001)
    assert tau[0] == 30.0  # clipped at the effort limit
    assert tau[1] == pytest.approx(N * KT * 0.1 * V / R)  # 0.1 duty at stall: 9.6 A -> 19.2 N m
    assert tau[2] == pytest.approx(params.position_kp * 0.001)
    assert tau[3] == pytest.approx(-params.damping_gain * 2.0)
    assert not trips


def test_stiff_pwm_against_a_wall_trips_but_torque_modes_are_current_regulated():
    params = load_bridge_params().actuation
    p = MotorParams.uniform(2, supply_voltage=V, resistance=R, torque_constant=KT, gear_ratio=N,
                            current_limit=10.0, trip_hold_off_s=HOLD)  # 10 A = 20 N m
    bank = ActuatorBank(("a", "b"), np.array([30.0, 30.0]), p, params)
    # joint a: 0.5 duty at stall draws 48 A; joint b: a stiff PD asking for 30 N m (15 A)
    bank.set_command(ActuatorCommand(np.array([PWM, POSITION], dtype=np.uint8), np.array([0.5, 0.1])))
    trips = []
    for k in range(5):
        tau, new = bank.torques(np.zeros(2), np.zeros(2), k * 0.001, 0.001)
        trips += new
    assert [t.joint for t in trips] == [0]
    assert tau[0] == 0.0 and bank.tripped(0.004)[0]  # power cut after the 2 ms delay
    assert tau[1] == pytest.approx(20.0) and not bank.tripped(0.004)[1]  # held at the current limit


def test_torques_are_constant_over_a_tick_only_for_state_free_commands():
    """The PyBullet backend computes the torques once per tick when torques_constant() holds; it
    must not hold when a mode reads the joint state or a driver is cut."""
    params = load_bridge_params().actuation
    p = MotorParams.uniform(2, supply_voltage=V, resistance=R, torque_constant=KT, gear_ratio=N,
                            current_limit=10.0, trip_hold_off_s=HOLD)
    bank = ActuatorBank(("a", "b"), np.array([30.0, 30.0]), p, params, implicit_position=True)
    for modes, constant in (([TORQUE, TORQUE], True), ([TORQUE, POSITION], True), ([TORQUE, DAMPING], False),
                            ([PWM, TORQUE], False)):
        bank.set_command(ActuatorCommand(np.array(modes, dtype=np.uint8), np.array([5.0, 0.1])))
        assert bank.torques_constant(0.0) is constant, modes
        if constant:  # same torques whatever the joint state and the time within the tick
            first, _ = bank.torques(np.zeros(2), np.zeros(2), 0.0, 0.001)
            later, _ = bank.torques(np.array([0.3, -0.2]), np.array([4.0, 1.0]), 0.004, 0.001)
            assert np.array_equal(first, later)
    bank.set_command(ActuatorCommand(np.array([PWM, TORQUE], dtype=np.uint8), np.array([0.5, 5.0])))
    for k in range(3):  # 0.5 duty at stall: 48 A > 10 A for 2 ms trips joint a
        bank.torques(np.zeros(2), np.zeros(2), k * 0.001, 0.001)
    bank.set_command(ActuatorCommand(np.array([TORQUE, TORQUE], dtype=np.uint8), np.array([5.0, 5.0])))
    assert not bank.torques_constant(0.003)  # joint a is still cut: its torque changes when power returns
    assert bank.torques(np.zeros(2), np.zeros(2), 0.003, 0.001)[0][0] == 0.0
    assert bank.torques_constant(0.003 + HOLD)


def test_motor_params_validation_and_table():
    with pytest.raises(SpecError, match="resistance"):
        MotorParams.uniform(2, supply_voltage=V, resistance=0.0, torque_constant=KT, gear_ratio=N,
                            current_limit=I_MAX, trip_hold_off_s=HOLD)
    default = dict(supply_voltage=V, resistance=R, torque_constant=KT, gear_ratio=N, current_limit=I_MAX,
                   trip_hold_off_s=HOLD)
    table = motor_params_from_table(("j1", "j2"), default, {"j2": {"gear_ratio": 100.0}})
    assert list(table.gear_ratio) == [N, 100.0]
    with pytest.raises(SpecError, match="unknown joint"):
        motor_params_from_table(("j1",), default, {"jx": {"gear_ratio": 1.0}})
