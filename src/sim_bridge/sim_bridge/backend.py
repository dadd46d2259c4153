"""The backend interface: what stands in for the robot's hardware.

A controller drives any backend the same way, in-process or behind the ROS node::

    backend = PyBulletBackend(params)                 # or MockBackend(...)
    state = backend.reset(ResetRequest(robot="g1", ladder="default", initial_posture="standing"))
    while ...:
        cmd = controller(state)                       # ActuatorCommand, joint order = state.joint_names
        state = backend.step(cmd)                     # one control period of physics
    backend.close()

``step(cmd)`` is ``apply_command(cmd)`` + one control period + ``observe()``. Gripper and
perturbation requests are queued with their sim time and take effect at the start of the first
tick at or after it, so a run is reproducible tick by tick.

State conventions (SimState): joint arrays in the robot model's actuated-joint order (Pinocchio
order, fingers excluded); F/T wrenches in the sensor link's frame, torque about its origin, the
wrench the distal side (hand / foot) exerts on the proximal side (standing: ankle Fz > 0); IMU in
the robot's root link frame; base ground truth both as the URDF root frame pose/twist in the world
and as Pinocchio free-flyer (q, v) with v in the local frame.
"""
from __future__ import annotations

import abc
import heapq
import itertools
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np

from .commands import ActuatorCommand, GripperRequest, PerturbRequest, validate_actuator_command


@dataclass(frozen=True)
class ResetRequest:
    robot: str = ""  # robot config name or path; "" = keep the current one (or the params' default)
    ladder: Any = None  # ladder spec name / path / YAML text / dict / Scenario; None = keep; "" = ground only
    initial_posture: str = ""  # named stance fixture; "" = the params' default
    q: np.ndarray | None = None  # (nq,) Pinocchio configuration; overrides initial_posture
    seed: int | None = None  # None = the params' seed


@dataclass
class Wrench:
    force: np.ndarray  # (3,) [N]
    torque: np.ndarray  # (3,) [N m]

    def as_array(self) -> np.ndarray:
        return np.concatenate([self.force, self.torque])


@dataclass
class ImuReading:
    frame: str  # link whose frame the readings are in
    quaternion_xyzw: np.ndarray  # (4,) orientation of the IMU frame in the world
    angular_velocity: np.ndarray  # (3,) [rad/s] in the IMU frame
    linear_acceleration: np.ndarray  # (3,) [m/s^2] specific force (a - g) in the IMU frame


@dataclass
class BaseTruth:
    frame: str  # root link
    T_world_base: np.ndarray  # (4, 4) URDF root frame in the world
    linear_velocity_in_world: np.ndarray  # (3,) [m/s] of the root frame origin
    angular_velocity_in_world: np.ndarray  # (3,) [rad/s]
    q: np.ndarray  # (nq,) Pinocchio configuration (free flyer + actuated joints)
    v: np.ndarray  # (nv,) Pinocchio velocity (free-flyer part in the local frame)

    @property
    def position_in_world(self) -> np.ndarray:
        return self.T_world_base[:3, 3]

    @property
    def quaternion_xyzw(self) -> np.ndarray:
        return self.q[3:7]


@dataclass
class BallState:
    body: int  # backend body id
    mass: float  # [kg]
    position: np.ndarray  # (3,) [m]
    velocity: np.ndarray  # (3,) [m/s]
    impulse_on_robot: np.ndarray  # (3,) [N s] accumulated impulse the ball applied to the robot
    touching_robot: bool
    launch_time: float = 0.0  # [s] sim time it was thrown
    launch_velocity: np.ndarray = field(default_factory=lambda: np.zeros(3))  # (3,) [m/s]


@dataclass
class SimState:
    stamp_ns: int  # [ns] sim time
    joint_names: tuple[str, ...]
    q: np.ndarray  # (n,) [rad]
    v: np.ndarray  # (n,) [rad/s]
    tau: np.ndarray  # (n,) [N m] applied this tick (last physics step)
    motor_current: np.ndarray  # (n,) [A]
    tripped: tuple[str, ...]  # joints whose driver has cut the power
    ft: dict[str, Wrench]  # sensor name -> wrench
    imu: ImuReading
    base: BaseTruth
    contact_forces: dict[str, np.ndarray]  # limb -> (3,) [N] total force the environment applies to it (world)
    grasps: dict[str, str]  # hand -> latched surface name ("" = none)
    finger_positions: dict[str, float]  # hand -> [-] 0 open .. 1 closed (commanded)
    fell: bool
    fall_reason: str
    balls: list[BallState] = field(default_factory=list)

    @property
    def time(self) -> float:
        """[s]"""
        return self.stamp_ns * 1e-9


@dataclass(frozen=True)
class Event:
    """Something the bridge reports on diagnostics."""

    kind: str  # overcurrent | grasp | release | grasp_failed | fall | perturbation | drop | warning
    time: float  # [s] sim time
    message: str
    level: int = 1  # 0 OK, 1 WARN, 2 ERROR (diagnostic_msgs levels)
    values: dict[str, str] = field(default_factory=dict)


class Backend(abc.ABC):
    """reset / step / observe / apply_command / close, plus stamped gripper and perturbation queues."""

    joint_names: tuple[str, ...] = ()
    control_period_ns: int = 5_000_000

    def __init__(self) -> None:
        self._queue: list[tuple[int, int, Any]] = []
        self._order = itertools.count()
        self._events: list[Event] = []
        self.stamp_ns = 0

    # -- to implement ---------------------------------------------------------------------------
    @abc.abstractmethod
    def reset(self, request: ResetRequest | None = None) -> SimState:
        """Rebuild / reset the world and return the state at t = 0."""

    @abc.abstractmethod
    def observe(self) -> SimState:
        """State at the current sim time (no physics)."""

    @abc.abstractmethod
    def _apply(self, cmd: ActuatorCommand) -> None:
        """Store a validated command for the next physics steps."""

    @abc.abstractmethod
    def _advance(self) -> None:
        """One control period of physics."""

    @abc.abstractmethod
    def _gripper(self, request: GripperRequest) -> None:
        """Act on a gripper request now."""

    @abc.abstractmethod
    def _perturb(self, request: PerturbRequest) -> None:
        """Act on a perturbation now."""

    def close(self) -> None:
        """Release the simulator."""

    def check_perturbation(self, request: PerturbRequest) -> None:
        """SpecError naming the field when ``request`` cannot be carried out in this world (unknown
        link, no such rung, no rails, out of bounds). The base class accepts what PerturbRequest
        itself accepts."""

    # -- shared ---------------------------------------------------------------------------------
    def apply_command(self, cmd: ActuatorCommand) -> None:
        """Validate (length, modes, finite, PWM range: SpecError otherwise) and store ``cmd``."""
        self._apply(validate_actuator_command(cmd, len(self.joint_names)))

    def step(self, cmd: ActuatorCommand | None = None,
             after_advance: Callable[[int], None] | None = None) -> SimState:
        """Apply ``cmd`` (None: keep the last one), run due requests, one control period, observe.
        ``after_advance(stamp_ns)`` runs once the physics has reached the new time, before the
        sensors are read (the node publishes /clock there)."""
        if cmd is not None:
            self.apply_command(cmd)
        self._run_due_requests()
        self._advance()
        self.stamp_ns += self.control_period_ns
        if after_advance is not None:
            after_advance(self.stamp_ns)
        return self.observe()

    @property
    def time(self) -> float:
        return self.stamp_ns * 1e-9

    def request_gripper(self, request: GripperRequest) -> None:
        """Queue a gripper request for its stamp (0 or past = next tick)."""
        self._push(request.stamp_ns, request)

    def request_perturbation(self, request: PerturbRequest) -> None:
        """Queue a perturbation for its ``at_time`` (0 or past = next tick)."""
        self._push(int(round(request.at_time * 1e9)), request)

    def pending_requests(self) -> list[Any]:
        return [item for _, _, item in sorted(self._queue)]

    def drain_events(self) -> list[Event]:
        events, self._events = self._events, []
        return events

    def _emit(self, kind: str, message: str, level: int = 1, **values: Any) -> None:
        self._events.append(Event(kind, self.time, message, level, {k: str(v) for k, v in values.items()}))

    def _push(self, stamp_ns: int, item: Any) -> None:
        heapq.heappush(self._queue, (int(stamp_ns), next(self._order), item))

    def _clear_requests(self) -> None:
        self._queue.clear()
        self._events.clear()

    def _run_due_requests(self) -> None:
        while self._queue and self._queue[0][0] <= self.stamp_ns:
            _, _, item = heapq.heappop(self._queue)
            if isinstance(item, GripperRequest):
                self._gripper(item)
            else:
                self._perturb(item)
