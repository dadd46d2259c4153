"""A backend without a physics engine, for unit tests of everything around the simulator.

Each joint is an independent rotor (inertia ``joint_inertia``, viscous friction ``joint_friction``)
driven by the same actuator models as the PyBullet backend (torque clip, DC motor, over-current
trips, PD, damping); the base is fixed in the world. Sensors read what such a robot would feel:
F/T zero, IMU at rest (specific force +g along the world z). A CLOSE gripper request latches on
``mock_surface``, OPEN releases. Perturbations are recorded as events.
"""
from __future__ import annotations

from typing import Sequence

import numpy as np

from .actuation import ActuatorBank
from .backend import Backend, BaseTruth, ImuReading, ResetRequest, SimState, Wrench
from .commands import GRIPPER_CLOSE, GRIPPER_OPEN, ActuatorCommand, GripperRequest, PerturbRequest
from .motor import MotorParams
from .params import BridgeParams, load_bridge_params

FT_SENSORS = ("left_wrist", "right_wrist", "left_ankle", "right_ankle")


class MockBackend(Backend):
    def __init__(self, joint_names: Sequence[str], effort_limits: Sequence[float] | np.ndarray,
                 motor_params: MotorParams | None = None, params: BridgeParams | None = None,
                 joint_inertia: float = 0.05, joint_friction: float = 0.01, base_height: float = 0.8):
        super().__init__()
        self.params = params or load_bridge_params()
        self.joint_names = tuple(joint_names)
        n = len(self.joint_names)
        if motor_params is None:
            motor_params = MotorParams.uniform(n, supply_voltage=48.0, resistance=0.5, torque_constant=0.1,
                                               gear_ratio=20.0, current_limit=40.0, trip_hold_off_s=0.5)
        self.actuators = ActuatorBank(self.joint_names, np.asarray(effort_limits, dtype=float), motor_params,
                                      self.params.actuation)
        self.control_period_ns = self.params.physics.control_period_ns
        self.joint_inertia = float(joint_inertia)  # [kg m^2]
        self.joint_friction = float(joint_friction)  # [N m s/rad]
        self.base_height = float(base_height)  # [m]
        self.q = np.zeros(n)
        self.v = np.zeros(n)
        self.grasps = {"left_hand": "", "right_hand": ""}
        self.fingers = {"left_hand": 0.0, "right_hand": 0.0}
        self.perturbations: list[PerturbRequest] = []
        self.rng = np.random.default_rng(self.params.seed)
        self.steps = 0

    def reset(self, request: ResetRequest | None = None) -> SimState:
        request = request or ResetRequest()
        self._clear_requests()
        self.stamp_ns = 0
        self.steps = 0
        self.actuators.reset()
        n = len(self.joint_names)
        self.q = np.zeros(n) if request.q is None else np.asarray(request.q, dtype=float)[-n:].copy()
        self.v = np.zeros(n)
        self.grasps = {"left_hand": "", "right_hand": ""}
        self.perturbations = []
        self.rng = np.random.default_rng(self.params.seed if request.seed is None else request.seed)
        return self.observe()

    def _apply(self, cmd: ActuatorCommand) -> None:
        self.actuators.set_command(cmd)

    def _advance(self) -> None:
        dt = self.params.physics.dt_s
        for k in range(self.params.physics.substeps):
            t = self.time + k * dt
            tau, trips = self.actuators.torques(self.q, self.v, t, dt)
            for trip in trips:
                self._emit("overcurrent", f"{self.joint_names[trip.joint]}: over-current {trip.current:.1f} A, "
                           f"power cut until t = {trip.until:.3f} s", 2, joint=self.joint_names[trip.joint],
                           current_A=f"{trip.current:.2f}", until_s=f"{trip.until:.3f}")
            acc = (tau - self.joint_friction * self.v) / self.joint_inertia
            self.v = self.v + acc * dt  # semi-implicit Euler, like the physics engine
            self.q = self.q + self.v * dt
            self.steps += 1

    def _gripper(self, request: GripperRequest) -> None:
        if request.command == GRIPPER_CLOSE:
            self.grasps[request.hand] = "mock_surface"
            self.fingers[request.hand] = 1.0
            self._emit("grasp", f"{request.hand} latched on mock_surface", 0, hand=request.hand)
        elif request.command == GRIPPER_OPEN:
            self.grasps[request.hand] = ""
            self.fingers[request.hand] = 0.0
            self._emit("release", f"{request.hand} opened", 0, hand=request.hand)
        else:
            self.fingers[request.hand] = request.position
            if request.position < self.params.grasp.release_position:
                self.grasps[request.hand] = ""

    def _perturb(self, request: PerturbRequest) -> None:
        self.perturbations.append(request)
        self._emit("perturbation", f"{request.kind} applied", 1, perturbation=request.kind)

    def observe(self) -> SimState:
        n = len(self.joint_names)
        s = self.params.sensors
        q = self.q + (self.rng.normal(0.0, s.joint_position_noise_std, n) if s.joint_position_noise_std else 0.0)
        v = self.v + (self.rng.normal(0.0, s.joint_velocity_noise_std, n) if s.joint_velocity_noise_std else 0.0)
        T = np.eye(4)
        T[2, 3] = self.base_height
        q_pin = np.concatenate([[0.0, 0.0, self.base_height, 0.0, 0.0, 0.0, 1.0], self.q])
        v_pin = np.concatenate([np.zeros(6), self.v])
        g = self.params.physics.gravity
        tripped = self.actuators.tripped(self.time)
        return SimState(
            stamp_ns=self.stamp_ns, joint_names=self.joint_names, q=q, v=v, tau=self.actuators.tau.copy(),
            motor_current=self.actuators.motors.current.copy(),
            tripped=tuple(name for name, t in zip(self.joint_names, tripped) if t),
            ft={name: Wrench(np.zeros(3), np.zeros(3)) for name in FT_SENSORS},
            imu=ImuReading("base", np.array([0.0, 0.0, 0.0, 1.0]), np.zeros(3), np.array([0.0, 0.0, g])),
            base=BaseTruth("base", T, np.zeros(3), np.zeros(3), q_pin, v_pin),
            contact_forces={}, grasps=dict(self.grasps), finger_positions=dict(self.fingers),
            fell=False, fall_reason="")
