"""Lock-step loop of the controller with an in-process sim_bridge backend (no ROS).

    backend = PyBulletBackend()
    runner = InProcessRunner.start(backend, controller_params, robot="g1", ladder="default",
                                   posture="ladder_4_contacts")
    runner.run(10.0)                       # [s] of sim time, one controller tick per control period

Each tick: backend state -> :class:`RobotState` (ground-truth estimator) -> ``Controller.tick``
-> actuator command (TORQUE or PWM, the backend's joint order) and stamped gripper requests ->
``backend.step``. ``on_tick`` callbacks see (sim_state, output) for logging / assertions.
``command_delay_ticks=1`` is the bridge's ``lockstep.command_delay_ticks: 1`` (a one-period
actuation latency): the period [t, t + T) runs on the command computed from the state of t - T
(the first command also covers [0, T)), gripper requests act one period later too.
The sim_bridge package is imported lazily: the controller library itself does not need it.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np

from climb_core.contact import Stance

from .controller import ControlOutput, Controller
from .estimator import GroundTruthEstimator, RobotState
from .params import ControllerParams


@dataclass
class RunLog:
    times: list[float] = field(default_factory=list)  # [s]
    tick_ms: list[float] = field(default_factory=list)  # [ms]
    qp_ms: list[float] = field(default_factory=list)  # [ms]
    fsm_states: list[str] = field(default_factory=list)
    qp_status: list[int] = field(default_factory=list)
    base_height: list[float] = field(default_factory=list)  # [m]
    com: list[np.ndarray] = field(default_factory=list)  # [m]
    max_current_ratio: list[float] = field(default_factory=list)  # [-] |i| / limit, worst joint
    tripped: set[str] = field(default_factory=set)
    fell: bool = False
    fall_reason: str = ""


class InProcessRunner:
    def __init__(self, backend, controller: Controller, sim_state, command_delay_ticks: int = 0):
        from sim_bridge import commands  # lazy: only the runner needs the bridge

        self._commands = commands
        self.backend = backend
        self.controller = controller
        self.sim_state = sim_state
        self.estimator = GroundTruthEstimator(controller.joint_names)
        names = list(sim_state.joint_names)
        self._to_backend = np.array([names.index(n) for n in controller.joint_names])
        self._n_backend = len(names)
        self.log = RunLog()
        self.on_tick: list[Callable[[Any, ControlOutput], None]] = []
        self._current_limit = None
        self.last_output: ControlOutput | None = None
        if command_delay_ticks not in (0, 1):
            raise ValueError(f"command_delay_ticks: must be 0 or 1, got {command_delay_ticks}")
        self.command_delay_ticks = command_delay_ticks
        self._latency_ns = command_delay_ticks * round(controller.params.control_period_s * 1e9)
        self._held = None  # delay 1: the command computed last tick, applied this one

    @classmethod
    def start(cls, backend, params: ControllerParams, robot: str = "g1", ladder: Any = "default",
              posture: str = "standing", q: np.ndarray | None = None, stance: Stance | None = None,
              fsm_table=None, command_delay_ticks: int = 0) -> "InProcessRunner":
        """Reset the backend, build the controller on the backend's robot and environment, and
        activate the posture fixture's holds (or ``stance``)."""
        from sim_bridge.backend import ResetRequest

        from climb_core.environment import build_environment

        sim_state = backend.reset(ResetRequest(robot=robot, ladder=ladder, initial_posture=posture, q=q))
        # the controller knows the nominal ladder (what the planner planned on), never the
        # simulator's perturbed one (rung offsets, moved rails): it finds those through F/T
        nominal = build_environment(backend.scenario) if getattr(backend, "scenario", None) is not None \
            else backend.env
        controller = Controller(backend.robot, params, nominal, fsm_table)
        if stance is None:
            from climb_core import fixtures

            stance = fixtures.get(posture, backend.robot, backend.env)[0]
        runner = cls(backend, controller, sim_state, command_delay_ticks)
        controller.reset(runner.robot_state(), stance)
        return runner

    def robot_state(self) -> RobotState:
        return self.estimator.from_sim_state(self.sim_state)

    def command(self, output: ControlOutput):
        c = self._commands
        values = np.zeros(self._n_backend)
        values[self._to_backend] = output.values
        mode = c.PWM if output.mode == "pwm" else c.TORQUE
        return c.ActuatorCommand.uniform(mode, values, output.stamp_ns)

    def step(self) -> ControlOutput:
        c = self._commands
        output = self.controller.tick(self.robot_state())
        for request in output.grippers:
            self.backend.request_gripper(c.GripperRequest(request.hand, request.command, request.position,
                                                          self.sim_state.stamp_ns + self._latency_ns))
        command = self.command(output)
        if self.command_delay_ticks:
            command, self._held = (self._held if self._held is not None else command), command
        self.sim_state = self.backend.step(command)
        self._record(output)
        for callback in self.on_tick:
            callback(self.sim_state, output)
        self.last_output = output
        return output

    def run(self, duration: float, until: Callable[[ControlOutput], bool] | None = None) -> RunLog:
        """Tick for ``duration`` [s] of sim time (or until ``until(output)`` or a fall)."""
        steps = int(round(duration / self.controller.params.control_period_s))
        for _ in range(steps):
            output = self.step()
            if self.sim_state.fell or (until is not None and until(output)):
                break
        return self.log

    def _record(self, output: ControlOutput) -> None:
        s = self.sim_state
        log = self.log
        log.times.append(s.time)
        log.tick_ms.append(output.status.tick_time_ms)
        log.qp_ms.append(output.status.qp_solve_time_ms)
        log.fsm_states.append(output.status.fsm_state)
        log.qp_status.append(output.status.qp_status)
        log.base_height.append(float(s.base.q[2]))
        log.com.append(self.controller.wb.data.com[0].copy())
        if self._current_limit is None:
            m = self.controller.compliance.motors
            index = {n: i for i, n in enumerate(self.controller.joint_names)}
            self._current_limit = np.array([m.current_limit[index[n]] if n in index else np.inf
                                            for n in s.joint_names])
        log.max_current_ratio.append(float(np.max(np.abs(s.motor_current) / self._current_limit)))
        log.tripped.update(s.tripped)
        if s.fell:
            log.fell, log.fall_reason = True, s.fall_reason
