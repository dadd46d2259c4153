"""G1 standing on the ground in PyBullet under a gravity-compensated joint PD: forces, F/T, IMU,
base ground truth (headless)."""
from __future__ import annotations

import numpy as np
import pytest

from sim_bridge.backend import ResetRequest
from sim_bridge.pybullet_backend import PyBulletBackend
from sim_bridge.simple_control import GravityCompensatedPd

pytestmark = pytest.mark.sim


@pytest.fixture(scope="module")
def standing():
    """Stand 1.5 s; return (backend, final state, ground force history [N])."""
    backend = PyBulletBackend()
    state = backend.reset(ResetRequest(robot="g1", ladder="default", initial_posture="standing"))
    ctl = GravityCompensatedPd(backend.robot, backend.robot.q_reference())
    ground = []
    for _ in range(300):
        state = backend.step(ctl(state))
        ground.append(backend.ground_reaction())
    yield backend, state, np.array(ground)
    backend.close()


def subtree_mass(robot, joint: str) -> float:
    import pinocchio as pin

    data = robot.model.createData()
    pin.computeSubtreeMasses(robot.model, data)
    return float(data.mass[robot.model.getJointId(joint)])


def test_ground_forces_sum_to_the_weight(standing):
    backend, state, ground = standing
    weight = backend.robot.mass * backend.params.physics.gravity
    assert not state.fell
    assert ground[-1][2] == pytest.approx(weight, rel=0.01)
    assert np.linalg.norm(ground[-1][:2]) < 0.01 * weight
    feet = state.contact_forces["left_foot"] + state.contact_forces["right_foot"]
    assert feet[2] == pytest.approx(weight, rel=0.01)  # the feet carry it all, nothing else touches
    assert np.linalg.norm(state.contact_forces["left_hand"]) == 0.0


def test_ankle_ft_sum_is_the_weight_minus_the_feet(standing):
    backend, state, _ = standing
    robot = backend.robot
    g = backend.params.physics.gravity
    below = sum(subtree_mass(robot, robot.config.ft_sensors[s]) for s in ("left_ankle", "right_ankle"))
    expected = (robot.mass - below) * g  # [N]
    total = np.zeros(3)
    for sensor, limb in (("left_ankle", "left_foot"), ("right_ankle", "right_foot")):
        T_world_sensor = backend.link_pose(backend.ft_joints[sensor])
        force_world = T_world_sensor[:3, :3] @ state.ft[sensor].force
        assert force_world[2] > 0.3 * expected  # each foot carries a share, pushing up on the leg
        total += force_world
    assert total[2] == pytest.approx(expected, rel=0.03)
    assert np.linalg.norm(total[:2]) < 0.03 * expected


def test_wrist_sensors_read_the_hands_weight(standing):
    backend, state, _ = standing
    robot = backend.robot
    g = backend.params.physics.gravity
    for sensor in ("left_wrist", "right_wrist"):
        hand_weight = subtree_mass(robot, robot.config.ft_sensors[sensor]) * g
        assert 2.0 < hand_weight < 20.0  # a hand, not a body
        R_world_sensor = backend.link_pose(backend.ft_joints[sensor])[:3, :3]
        force_world = R_world_sensor @ state.ft[sensor].force
        # the hanging hand pulls the forearm down by its weight
        assert np.allclose(force_world, [0.0, 0.0, -hand_weight], atol=0.03 * hand_weight)
        # its weight acts at the hand's centre of mass: torque = r_com x (-m g z) about the sensor
        T_world_sensor = backend.link_pose(backend.ft_joints[sensor])
        import pinocchio as pin

        data = robot.model.createData()
        pin.centerOfMass(robot.model, data, state.base.q)  # fills data.com[i] per subtree
        jid = robot.model.getJointId(robot.config.ft_sensors[sensor])
        pin.forwardKinematics(robot.model, data, state.base.q)
        com_world = data.oMi[jid].act(data.com[jid])
        lever = com_world - T_world_sensor[:3, 3]
        expected_torque = np.cross(lever, [0.0, 0.0, -hand_weight])
        torque_world = R_world_sensor @ state.ft[sensor].torque
        assert np.allclose(torque_world, expected_torque, atol=0.03 * hand_weight * 0.1 + 0.01)


def test_imu_and_base_truth_at_rest(standing):
    backend, state, _ = standing
    g = backend.params.physics.gravity
    assert np.allclose(state.imu.linear_acceleration, [0.0, 0.0, g], atol=0.05)  # specific force, upright
    assert np.allclose(state.imu.angular_velocity, 0.0, atol=1e-3)
    q_ref = backend.robot.q_reference()
    assert np.allclose(state.base.q[:3], q_ref[:3], atol=3e-3)  # URDF root frame, not the COM
    assert np.allclose(state.base.T_world_base[:3, 3], state.base.q[:3])
    assert np.linalg.norm(state.base.v) < 1e-2
    assert state.base.frame == "pelvis" and state.imu.frame == "pelvis"


def test_base_truth_velocity_is_pinocchio_free_flyer_convention():
    """Throw the robot in the air spinning: the reported Pinocchio (q, v) integrate into each other."""
    import pinocchio as pin

    backend = PyBulletBackend()
    try:
        backend.reset(ResetRequest(robot="g1", ladder="default"))
        robot = backend.robot
        q0 = robot.q_reference()
        q0[2] += 2.0  # [m] in the air
        q0[3:7] = pin.Quaternion(pin.utils.rpyToMatrix(0.3, -0.2, 0.5)).coeffs()
        v0 = np.zeros(robot.nv)
        v0[:6] = [1.0, -0.5, 2.0, 0.8, -1.5, 2.0]  # local frame [m/s, rad/s]
        backend.set_state(q0, v0)
        s0 = backend.observe()
        assert np.allclose(s0.base.q, q0, atol=1e-6) and np.allclose(s0.base.v[:6], v0[:6], atol=1e-6)
        s1 = backend.step()
        s2 = backend.step()
        dt = backend.params.physics.control_period_s
        # central difference of the configuration = velocity at the middle sample
        v_mid = pin.difference(robot.model, s0.base.q, s2.base.q) / (2 * dt)
        assert np.allclose(v_mid[:6], s1.base.v[:6], atol=0.05)
        assert not np.allclose(s1.base.v[:3], s1.base.linear_velocity_in_world, atol=0.1)  # local != world
        R = s1.base.T_world_base[:3, :3]
        assert np.allclose(R @ s1.base.v[:3], s1.base.linear_velocity_in_world, atol=1e-9)
        # free fall: the accelerometer reads (almost) nothing
        assert np.linalg.norm(s1.imu.linear_acceleration) < 2.0  # vs 9.81 standing (centripetal terms remain)
    finally:
        backend.close()


def test_ft_noise_and_bias_in_percent_of_each_sensors_range():
    """Issue 19, sensor realism: ``sensors.ft_noise_percent`` is the white-noise sigma of every
    F/T component in % of that sensor's range (robot config ``ft_ranges``: G1 ankles 1000 N /
    50 N m, wrists 300 N / 10 N m); ``ft_bias_percent`` the sigma of a constant offset drawn at
    every reset. Measured against the same standing run without them (same seed, same physics:
    the noise does not feed back, the PD reads no F/T)."""
    import dataclasses

    from sim_bridge.params import load_bridge_params

    def stand(noise: float, bias: float, seed: int = 3) -> dict[str, np.ndarray]:
        params = load_bridge_params()
        params = dataclasses.replace(params, sensors=dataclasses.replace(
            params.sensors, ft_noise_percent=noise, ft_bias_percent=bias))
        backend = PyBulletBackend(params)
        try:
            state = backend.reset(ResetRequest(robot="g1", ladder="default", initial_posture="standing", seed=seed))
            ctl = GravityCompensatedPd(backend.robot, backend.robot.q_reference())
            out = {s: [] for s in state.ft}
            for _ in range(400):
                state = backend.step(ctl(state))
                for s, w in state.ft.items():
                    out[s].append(w.as_array())
            return {s: np.array(v) for s, v in out.items()}
        finally:
            backend.close()

    clean, noisy, biased = stand(0.0, 0.0), stand(2.0, 0.0), stand(0.0, 1.0)
    for sensor, (force_range, torque_range) in (("left_ankle", (1000.0, 50.0)), ("right_wrist", (300.0, 10.0))):
        error = noisy[sensor] - clean[sensor]
        std = error.std(axis=0)
        np.testing.assert_allclose(std[:3], 0.02 * force_range, rtol=0.15)
        np.testing.assert_allclose(std[3:], 0.02 * torque_range, rtol=0.15)
        assert np.abs(error.mean(axis=0)[:3]).max() < 0.3 * 0.02 * force_range  # zero-mean
        offset = biased[sensor] - clean[sensor]
        assert np.abs(offset - offset[0]).max() < 1e-9  # constant over the run
        assert 0.0 < np.abs(offset[0, :3]).max() < 4 * 0.01 * force_range
    # another reset draws another bias
    assert not np.allclose(stand(0.0, 1.0, seed=4)["left_ankle"][0] - clean["left_ankle"][0],
                           biased["left_ankle"][0] - clean["left_ankle"][0])
