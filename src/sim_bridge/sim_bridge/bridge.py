"""The bridge's protocol logic, without ROS: commands in, ticks, watchdog, diagnostics out.

The node (node.py) only moves messages; everything that decides what the robot does lives here so
that it is tested without processes:

- **Lock-step**: the state stamped t is published; :meth:`SimBridge.offer_command` accepts the
  command stamped t (others are stale and ignored); :meth:`SimBridge.step_lockstep` steps one
  control period with it. With ``lockstep.command_delay_ticks: 1`` the period [t, t + T) runs on
  the command stamped t - T instead (the one computed while the physics produced state t; the
  command stamped 0 also covers [0, T)), so a controller in another process computes the command
  of t while the physics steps: a one-period actuation latency, still deterministic; a command
  stamped t that arrives before the one of t - T waits its turn. If none came in time the caller
  steps anyway: the controller is reported lost and every joint is damped until a command stamped
  for the awaited tick arrives.
  A command for tick t that fails validation is rejected with a diagnostic naming the problem and
  the tick runs on the last valid command (or damping): the bridge never waits for a second try.
- **Real-time**: :meth:`SimBridge.step_realtime` uses the last valid command unless it is older
  than the watchdog (wall time): then every joint is damped and it is reported, until commands
  resume.
"""
from __future__ import annotations

import time as _time
from collections import deque
from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np

from climb_core.errors import SpecError

from .backend import Backend, Event, ResetRequest, SimState
from .commands import (ActuatorCommand, GripperRequest, PerturbRequest, validate_actuator_command,
                       validate_joint_command)
from .params import BridgeParams

OK, WARN, ERROR = 0, 1, 2


@dataclass(frozen=True)
class Diagnostic:
    level: int  # 0 OK, 1 WARN, 2 ERROR
    name: str  # e.g. sim_bridge/command, sim_bridge/overcurrent
    message: str
    values: dict[str, str] = field(default_factory=dict)


@dataclass(frozen=True)
class Verdict:
    accepted: bool
    reason: str = ""  # empty when accepted; else the problem (field: rule) or "stale"


_EVENT_NAMES = {"overcurrent": "overcurrent", "fall": "fall", "grasp": "grasp", "release": "grasp",
                "grasp_failed": "grasp", "slip": "grasp", "perturbation": "perturbation", "drop": "perturbation"}


class SimBridge:
    def __init__(self, backend: Backend, params: BridgeParams):
        self.backend = backend
        self.params = params
        self._delay_ns = params.lockstep.command_delay_ticks * params.physics.control_period_ns
        self.joint_index = {name: i for i, name in enumerate(backend.joint_names)}
        self.state: SimState | None = None
        self._pending: ActuatorCommand | None = None
        self._early: ActuatorCommand | None = None  # delay 1: the answer to the current stamp, come early
        self._last_valid: ActuatorCommand | None = None
        self._last_command_wall = -np.inf
        self._answered_ns = -1  # stamp of the last command taken for its tick (an echo of it is no news)
        self.controller_lost = False
        self.first_command_wait = False  # a world reset by sim/reset waits longer for its first command
        self.watchdog_active = False
        self.rejected = 0
        self.stale = 0
        self.ticks = 0
        self.lost_ticks = 0
        self.watchdog_ticks = 0
        self._diagnostics: list[Diagnostic] = []
        # called with the new stamp [ns] once the physics reached it, before the sensors are read
        self.after_advance: Callable[[int], None] | None = None
        self._step_times: deque[float] = deque(maxlen=1000)
        # lock-step over ROS (the node reports them): state publish calls, wait for the command
        self._publish_times: deque[float] = deque(maxlen=1000)
        self._wait_times: deque[float] = deque(maxlen=1000)
        self._next_summary_ns = 0

    # -- lifecycle ------------------------------------------------------------------------------
    def reset(self, request: ResetRequest | None = None) -> SimState:
        self.state = self.backend.reset(request)
        self.joint_index = {name: i for i, name in enumerate(self.backend.joint_names)}  # the robot may change
        self._pending = None
        self._early = None
        self._last_valid = None
        self._last_command_wall = -np.inf
        self._answered_ns = -1
        self.controller_lost = False
        self.first_command_wait = False
        self.watchdog_active = False
        self.ticks = 0
        self._next_summary_ns = 0
        self._collect_events()
        return self.state

    @property
    def stamp_ns(self) -> int:
        return self.backend.stamp_ns

    @property
    def awaited_stamp_ns(self) -> int:
        """[ns] stamp of the command the next lock-step period runs on: the current stamp, or one
        control period earlier with ``lockstep.command_delay_ticks: 1`` (never before 0)."""
        return max(self.backend.stamp_ns - self._delay_ns, 0)

    # -- inputs ---------------------------------------------------------------------------------
    def offer_command(self, names: Sequence[str], modes: Sequence[object], values: Sequence[float],
                      stamp_ns: int, wall_time: float | None = None) -> Verdict:
        """A joint command as it arrived (names, modes, values, header stamp [ns])."""
        return self._offer(lambda: validate_joint_command(names, modes, values, self.backend.joint_names,
                                                          stamp_ns, self.joint_index), stamp_ns, wall_time)

    def offer_actuator_command(self, cmd: ActuatorCommand, wall_time: float | None = None) -> Verdict:
        """An in-process command already in the backend's joint order."""
        return self._offer(lambda: validate_actuator_command(cmd, len(self.backend.joint_names)),
                           cmd.stamp_ns, wall_time)

    def _offer(self, validate: Callable[[], ActuatorCommand], stamp_ns: int, wall_time: float | None) -> Verdict:
        lockstep = self.params.execution == "lockstep"
        early = False
        if lockstep and stamp_ns != self.awaited_stamp_ns:
            # delay 1: the command of the current stamp may overtake the awaited one's (lost or
            # late); it is kept for the next period instead of being thrown away
            early = stamp_ns == self.stamp_ns
            if stamp_ns == self._answered_ns:
                # the controller's answer sent again for a state published again (lockstep.resend_s)
                # that reached it after its first answer did: that tick ran already
                return Verdict(False, "duplicate")
            if not early:
                self.stale += 1
                self._diag(WARN, "command", f"ignored a command stamped {stamp_ns * 1e-9:.3f} s while waiting "
                           f"for {self.awaited_stamp_ns * 1e-9:.3f} s (stale or early)", stamp_ns=stamp_ns)
                return Verdict(False, "stale")
        try:
            cmd = validate()
        except SpecError as err:
            self.rejected += 1
            fallback = "the last valid command" if self._last_valid is not None else "damping"
            self._diag(ERROR, "command", f"rejected joint_command: {err}; running on {fallback}",
                       field=err.field, rule=err.rule, rejected_total=self.rejected)
            fallback_cmd = self._last_valid or ActuatorCommand.damping(len(self.backend.joint_names))
            if early:
                self._early = fallback_cmd
            elif lockstep:  # this tick's answer was bad: do not wait for another one
                self._pending = fallback_cmd
            return Verdict(False, str(err))
        self._last_valid = cmd
        self._last_command_wall = _time.monotonic() if wall_time is None else wall_time
        if early:
            self._early = cmd
        elif lockstep:
            self._pending = cmd
            self._answered_ns = stamp_ns
        return Verdict(True)

    def offer_gripper(self, request: GripperRequest) -> None:
        self.backend.request_gripper(request)

    def offer_perturbation(self, request: PerturbRequest) -> None:
        """Queue ``request`` for its time; SpecError (nothing queued) when this world cannot carry
        it out (Backend.check_perturbation)."""
        self.backend.check_perturbation(request)
        self.backend.request_perturbation(request)

    # -- lock-step ------------------------------------------------------------------------------
    def command_ready(self) -> bool:
        """The command for the current tick arrived (or was rejected: the tick may go on)."""
        return self._pending is not None

    @property
    def awaiting_first_command(self) -> bool:
        """No valid command reached this world yet (since start or the last sim/reset), and the
        controller is not declared lost: the state it awaits may be published again."""
        return self._last_valid is None and not self.controller_lost

    def step_lockstep(self) -> SimState:
        """Step one control period on the command of this tick, or damp if the controller is lost."""
        n = len(self.backend.joint_names)
        answered = self._pending is not None
        awaited = self.awaited_stamp_ns
        if answered:
            cmd = self._pending
            self.first_command_wait = False
            if self.controller_lost:
                self.controller_lost = False
                self._diag(OK, "controller", f"controller back at t = {self.stamp_ns * 1e-9:.3f} s",
                           lost_ticks=self.lost_ticks)
        else:
            cmd = ActuatorCommand.damping(n, self.stamp_ns)
            self.lost_ticks += 1
            if not self.controller_lost:
                self.controller_lost = True
                self._diag(ERROR, "controller", f"controller lost: no command stamped "
                           f"{awaited * 1e-9:.3f} s within {self.params.lockstep.command_timeout_s} s "
                           "(wall); damping every joint")
        self._pending = None
        state = self._step(cmd)
        if answered and self.awaited_stamp_ns == awaited:
            self._pending = cmd  # delay 1, first period: the command stamped 0 also covers [T, 2T)
        elif self._early is not None:
            self._pending, self._early = self._early, None  # the answer to the stamp now awaited
        return state

    def await_first_command(self) -> None:
        """After a sim/reset: the new world's first tick waits lockstep.reset_wait_s for its command
        when that is longer than command_timeout_s (the climb graph's controller is activated once
        its plan exists), then the usual bounds apply."""
        self.first_command_wait = True

    def wait_budget(self) -> float:
        """[s] wall time to wait for this tick's command."""
        lock = self.params.lockstep
        if self.controller_lost:
            return lock.lost_retry_s
        if self.first_command_wait:
            return max(lock.reset_wait_s, lock.command_timeout_s)
        return lock.command_timeout_s

    # -- real time ------------------------------------------------------------------------------
    def step_realtime(self, wall_time: float | None = None) -> SimState:
        now = _time.monotonic() if wall_time is None else wall_time
        n = len(self.backend.joint_names)
        fresh = self._last_valid is not None and now - self._last_command_wall <= self.params.realtime.watchdog_s
        if fresh:
            cmd = self._last_valid
            if self.watchdog_active:
                self.watchdog_active = False
                self._diag(OK, "watchdog", "commands resumed", watchdog_ticks=self.watchdog_ticks)
        else:
            cmd = ActuatorCommand.damping(n, self.stamp_ns)
            self.watchdog_ticks += 1
            if not self.watchdog_active:
                self.watchdog_active = True
                age = now - self._last_command_wall
                self._diag(ERROR, "watchdog", f"no valid command for {age * 1e3:.0f} ms (> "
                           f"{self.params.realtime.watchdog_s * 1e3:.0f} ms): damping every joint")
        return self._step(cmd)

    # -- common ---------------------------------------------------------------------------------
    def _step(self, cmd: ActuatorCommand) -> SimState:
        start = _time.perf_counter()
        self.backend._apply(cmd)  # validated at the door (offer_*) or built valid (damping)
        self.state = self.backend.step(after_advance=self.after_advance)
        self._step_times.append(_time.perf_counter() - start)
        self.ticks += 1
        self._collect_events()
        if self.stamp_ns >= self._next_summary_ns:
            self._summary()
            self._next_summary_ns = self.stamp_ns + int(round(self.params.diagnostics.period_s * 1e9))
        return self.state

    def note_lockstep_times(self, publish_s: float, wait_s: float) -> None:
        """[s] wall time of one tick's state publish calls and of the wait for its command (the
        node's lock-step loop): with the step time they split the loop's period."""
        self._publish_times.append(publish_s)
        self._wait_times.append(wait_s)

    @staticmethod
    def _time_stats(times: deque[float]) -> dict[str, float]:
        if not times:
            return {"p50_ms": 0.0, "p99_ms": 0.0, "max_ms": 0.0}
        arr = np.array(times) * 1e3
        return {"p50_ms": float(np.median(arr)), "p99_ms": float(np.percentile(arr, 99)), "max_ms": float(arr.max())}

    def step_time_stats(self) -> dict[str, float]:
        """[ms] median / p99 / max wall time of backend.step over the last 1000 ticks."""
        return self._time_stats(self._step_times)

    def _summary(self) -> None:
        stats = self.step_time_stats()
        state = self.state
        tripped = ", ".join(state.tripped) if state is not None and state.tripped else ""
        self._diag(WARN if tripped else OK, "step",
                   f"tick {self.ticks}: step {stats['p50_ms']:.2f} ms (p99 {stats['p99_ms']:.2f})"
                   + (f"; tripped: {tripped}" if tripped else ""),
                   sim_time_s=f"{self.stamp_ns * 1e-9:.3f}", ticks=self.ticks, rejected=self.rejected,
                   stale=self.stale, lost_ticks=self.lost_ticks, watchdog_ticks=self.watchdog_ticks,
                   tripped=tripped, fell=bool(state.fell) if state is not None else False, **self._timing_values())
        # Ongoing faults are repeated with every summary (diagnostic_updater convention), so a
        # subscriber that joins late still sees them, not only the edge that raised them.
        if self.watchdog_active:
            self._diag(ERROR, "watchdog", "no valid command: damping every joint",
                       watchdog_ticks=self.watchdog_ticks)
        if self.controller_lost:
            self._diag(ERROR, "controller", "controller lost: damping every joint", lost_ticks=self.lost_ticks)

    def _timing_values(self) -> dict[str, str]:
        """step_{p50,p99,max}_ms always; publish_* and wait_* once the node reported them."""
        out = {}
        for name, times in (("step", self._step_times), ("publish", self._publish_times), ("wait", self._wait_times)):
            if times or name == "step":
                out.update({f"{name}_{k}": f"{v:.3f}" for k, v in self._time_stats(times).items()})
        return out

    def _collect_events(self) -> None:
        for event in self.backend.drain_events():
            self._diagnostics.append(self._event_diag(event))

    @staticmethod
    def _event_diag(event: Event) -> Diagnostic:
        name = _EVENT_NAMES.get(event.kind, event.kind)
        values = dict(event.values)
        values["sim_time_s"] = f"{event.time:.3f}"
        values["event"] = event.kind
        return Diagnostic(event.level, f"sim_bridge/{name}", event.message, values)

    def _diag(self, level: int, name: str, message: str, **values: object) -> None:
        vals = {k: str(v) for k, v in values.items()}
        vals.setdefault("sim_time_s", f"{self.stamp_ns * 1e-9:.3f}")
        self._diagnostics.append(Diagnostic(level, f"sim_bridge/{name}", message, vals))

    def drain_diagnostics(self) -> list[Diagnostic]:
        out, self._diagnostics = self._diagnostics, []
        return out
