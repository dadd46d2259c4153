"""controller_node.ft_monitor without a controller: the filter, the tare, the online noise
estimate and the contact threshold it raises, on synthetic wrenches."""
from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from controller_node.ft_monitor import FtMonitor, ft_sensor_frames
from controller_node.params import load_controller_params


def monitor(rotation=np.eye(3)):
    params = load_controller_params()
    oMf = [pin.SE3(rotation, np.zeros(3))]
    return FtMonitor({"wrist": 0}, [("hand", "wrist"), ("foot", "no_such_sensor")], params.guarded,
                     params.control_period_s), oMf, params.guarded


def test_the_threshold_rises_with_the_estimated_noise_and_a_step_is_read_against_the_tare():
    ft, oMf, g = monitor()
    assert [limb for limb, _, _ in ft.limbs] == ["hand"]  # a sensor without a frame is left out
    assert ft.threshold("hand") == g.force_threshold  # nothing measured yet
    rng = np.random.default_rng(0)
    sigma = 6.0  # [N] per component
    weight = np.array([0.0, 0.0, -8.0])  # the free hand's own weight and the sensor's bias
    for _ in range(2000):  # 10 s: the estimate's time constant is 1 s
        ft.update(oMf, {"wrist": np.concatenate([weight + rng.normal(0.0, sigma, 3), np.zeros(3)])})
    alpha = min(1.0, 0.005 / g.filter_time_constant_s)
    assert ft.noise_std("hand") == pytest.approx(sigma * np.sqrt(alpha / (2 - alpha)), rel=0.15)
    assert ft.threshold("hand") == pytest.approx(g.noise_sigmas * ft.noise_std("hand"))
    assert ft.threshold("hand") > g.force_threshold
    ft.tare("hand")
    approach = np.array([0.0, 0.0, -1.0])  # moving down onto a surface
    assert abs(ft.change("hand", approach)) < ft.threshold("hand")  # the weight is tared away
    for _ in range(40):  # a contact pushes the hand up by 60 N
        ft.update(oMf, {"wrist": np.concatenate([weight + [0.0, 0.0, 60.0] + rng.normal(0.0, sigma, 3), np.zeros(3)])})
    assert ft.change("hand", approach) == pytest.approx(60.0, abs=4 * ft.noise_std("hand"))
    assert ft.change("hand", approach) > ft.threshold("hand")
    assert ft.change("hand") == pytest.approx(60.0, abs=8 * ft.noise_std("hand"))  # no direction: the norm
    # a contact step is not taken for noise: the estimate barely moved
    assert ft.noise_std("hand") < 1.5 * sigma * np.sqrt(alpha / (2 - alpha))


def test_forces_are_read_in_world_axes():
    R = pin.utils.rpyToMatrix(0.0, 0.0, np.pi / 2)  # the sensor turned 90 deg about z
    ft, oMf, _ = monitor(R)
    ft.update(oMf, {"wrist": [1.0, 0.0, 0.0, 0.0, 0.0, 0.0]})
    assert np.allclose(ft.force("hand"), [0.0, 1.0, 0.0])
    assert np.allclose(ft.force("elsewhere"), 0.0)


def test_sensor_frames_are_the_child_links_of_the_sensor_joints():
    from climb_core.robot import load_robot

    robot = load_robot("g1")
    frames = ft_sensor_frames(robot.model, robot.config.ft_sensors)
    assert set(frames) == set(robot.config.ft_sensors)
    for sensor, fid in frames.items():
        frame = robot.model.frames[fid]
        assert frame.type == pin.FrameType.BODY
        assert robot.model.names[frame.parentJoint] == robot.config.ft_sensors[sensor]


def test_a_sensor_on_a_fixed_joint_reads_in_its_child_link_and_a_missing_one_is_an_error():
    """TALOS's wrist sensors sit on fixed joints (wrist_*_ft_joint), which Pinocchio keeps as
    frames, not joints: they were left out, and TALOS's hands sensed nothing (a gripper pressed on
    its rung with 120 N read 0 N, measured 2026-12-02)."""
    from climb_core.robot import load_robot

    robot = load_robot("talos")
    frames = ft_sensor_frames(robot.model, robot.config.ft_sensors)
    assert set(frames) == set(robot.config.ft_sensors)
    assert robot.model.frames[frames["left_wrist"]].name == "wrist_left_ft_link"
    assert robot.model.frames[frames["right_wrist"]].name == "wrist_right_ft_link"
    with pytest.raises(ValueError, match="ft_sensors.left_wrist"):
        ft_sensor_frames(robot.model, {"left_wrist": "no_such_joint"})


def test_a_push_too_small_for_the_noisy_fast_threshold_confirms_a_stall_on_the_slow_filter():
    """An ankle F/T with 2 % noise (20 N sigma): the fast threshold (5 sigma of the 10 ms filter,
    ~58 N) is more than a creeping foot can push; a 25 N push is confirmed on the 200 ms filter
    (4 sigma of the change from the tare ~13 N), and noise alone does not confirm one."""
    ft, oMf, g = monitor()
    rng = np.random.default_rng(1)
    sigma = 20.0
    for _ in range(2000):
        ft.update(oMf, {"wrist": np.concatenate([rng.normal(0.0, sigma, 3), np.zeros(3)])})
    ft.tare("hand")
    approach = np.array([0.0, 0.0, -1.0])
    quiet = []
    for _ in range(1000):  # 5 s of noise only
        ft.update(oMf, {"wrist": np.concatenate([rng.normal(0.0, sigma, 3), np.zeros(3)])})
        quiet.append(ft.confirms_stall("hand", approach))
    assert not any(quiet)
    assert ft.threshold("hand") > 50.0
    for _ in range(120):  # 0.6 s pushing 25 N
        ft.update(oMf, {"wrist": np.concatenate([[0.0, 0.0, 25.0] + rng.normal(0.0, sigma, 3), np.zeros(3)])})
    assert ft.change("hand", approach) < ft.threshold("hand")
    assert ft.confirms_stall("hand", approach)
    assert ft.change("hand", approach, slow=True) == pytest.approx(25.0, abs=6 * ft.noise_std("hand", slow=True))
