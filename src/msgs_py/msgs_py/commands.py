"""Commands and status messages: JointCommand, GripperCommand, ControllerState, ClimbStatus.

Each message has a small frozen dataclass that validates itself on construction (SpecError naming
the field), a ``<thing>_to_msg(data=None, /, **kwargs)`` builder (give the dataclass or its fields
as keyword arguments) and a ``<thing>_from_msg(msg)`` that validates what arrived. Stamps are
float seconds rounded to the nanosecond grid of builtin_interfaces/Time on construction, so a
dataclass survives dataclass -> message -> dataclass unchanged.
"""
from __future__ import annotations

import array
import dataclasses
from dataclasses import dataclass, field
from typing import Any, Mapping, Sequence, TypeVar

import numpy as np
from climb_msgs.msg import ClimbStatus, ControllerState, GripperCommand, JointCommand

from climb_core.contact import HANDS, LIMBS
from climb_core.errors import SpecError

from ._check import finite_float, finite_vector, non_negative_int, one_of
from .stamps import header_stamp, make_header, quantize_seconds

#: Joint command modes by name (values are the JointCommand constants).
JOINT_MODES: dict[str, int] = {"torque": JointCommand.TORQUE, "pwm": JointCommand.PWM,
                               "position": JointCommand.POSITION, "damping": JointCommand.DAMPING}
_JOINT_MODE_NAMES = {v: k for k, v in JOINT_MODES.items()}
#: Gripper commands by name.
GRIPPER_COMMANDS: dict[str, int] = {"open": GripperCommand.OPEN, "close": GripperCommand.CLOSE,
                                    "position": GripperCommand.POSITION}
_GRIPPER_COMMAND_NAMES = {v: k for k, v in GRIPPER_COMMANDS.items()}
#: QP status by name (ControllerState constants).
QP_STATUS: dict[str, int] = {"ok": ControllerState.QP_OK, "failed": ControllerState.QP_FAILED,
                             "not_run": ControllerState.QP_NOT_RUN}
_QP_STATUS_NAMES = {v: k for k, v in QP_STATUS.items()}
CONTROLLER_MODES = ("qp", "compliance")
CLIMB_PHASES = ("idle", "guide_path", "contact_search", "adaptation", "executing", "done", "failed",
                "cancelled")

T = TypeVar("T")


def _build(cls: type[T], data: T | None, kwargs: Mapping[str, Any], prefix: str) -> T:
    if data is not None and kwargs:
        raise SpecError(prefix, "give either a dataclass or keyword fields, not both")
    if data is not None:
        if not isinstance(data, cls):
            raise SpecError(prefix, f"expected {cls.__name__}, got {type(data).__name__}")
        return data
    known = {f.name for f in dataclasses.fields(cls)}  # type: ignore[arg-type]
    for key in kwargs:
        if key not in known:
            raise SpecError(f"{prefix}.{key}", f"unknown field; known: {', '.join(sorted(known))}")
    return cls(**kwargs)


def _set(obj: object, name: str, value: object) -> None:
    object.__setattr__(obj, name, value)


# --- JointCommand ---------------------------------------------------------------------------

def _mode_code(mode: object, field: str) -> int:
    if isinstance(mode, str):
        if mode.lower() not in JOINT_MODES:
            raise SpecError(field, f"unknown mode {mode!r}; known: {', '.join(JOINT_MODES)}")
        return JOINT_MODES[mode.lower()]
    if isinstance(mode, (int, np.integer)) and not isinstance(mode, bool) and int(mode) in _JOINT_MODE_NAMES:
        return int(mode)
    raise SpecError(field, f"unknown mode {mode!r}; known: {', '.join(f'{k}={v}' for k, v in JOINT_MODES.items())}")


@dataclass(frozen=True)
class JointCommandData:
    """One actuator command per joint. ``modes`` may be one mode for all joints (name or code)."""

    names: tuple[str, ...]
    modes: np.ndarray  # (n,) uint8 JointCommand.TORQUE | PWM | POSITION | DAMPING
    values: np.ndarray  # (n,) [N m] (TORQUE) | duty [-1, 1] (PWM) | [rad] (POSITION) | ignored (DAMPING)
    stamp: float = 0.0  # [s] stamp of the state this command answers (lock-step)

    def __post_init__(self) -> None:
        f = "joint_command"
        if isinstance(self.names, str):
            raise SpecError(f"{f}.names", "must be a sequence of joint names, got one string")
        names = tuple(self.names)
        for i, name in enumerate(names):
            if not isinstance(name, str) or not name:
                raise SpecError(f"{f}.names[{i}]", f"must be a non-empty string, got {name!r}")
        seen: dict[str, int] = {}
        for i, name in enumerate(names):
            if name in seen:
                raise SpecError(f"{f}.names[{i}]", f"joint {name!r} already commanded at names[{seen[name]}]")
            seen[name] = i
        n = len(names)
        if isinstance(self.modes, (str, int, np.integer)):
            modes = np.full(n, _mode_code(self.modes, f"{f}.modes"), dtype=np.uint8)
        else:
            raw = list(self.modes)
            if len(raw) != n:
                raise SpecError(f"{f}.modes", f"must have one mode per name ({n}), got {len(raw)}")
            modes = np.array([_mode_code(m, f"{f}.modes[{i}]") for i, m in enumerate(raw)], dtype=np.uint8)
        values = np.asarray(self.values, dtype=float)
        if values.ndim != 1 or values.shape[0] != n:
            raise SpecError(f"{f}.values", f"must have one value per name ({n}), got shape {values.shape}")
        values = finite_vector(values, f"{f}.values")
        pwm = modes == JointCommand.PWM
        out = np.flatnonzero(pwm & (np.abs(values) > 1.0))
        if out.size:
            i = int(out[0])
            raise SpecError(f"{f}.values[{i}]", f"PWM duty of {names[i]} must be in [-1, 1], got {values[i]}")
        values.setflags(write=False)
        modes.setflags(write=False)
        _set(self, "names", names)
        _set(self, "modes", modes)
        _set(self, "values", values)
        _set(self, "stamp", quantize_seconds(self.stamp, f"{f}.stamp"))

    @property
    def mode_names(self) -> tuple[str, ...]:
        return tuple(_JOINT_MODE_NAMES[int(m)] for m in self.modes)

    def __eq__(self, other: object) -> bool:
        return (isinstance(other, JointCommandData) and self.names == other.names
                and np.array_equal(self.modes, other.modes) and np.array_equal(self.values, other.values)
                and self.stamp == other.stamp)

    __hash__ = None  # type: ignore[assignment]


def joint_command_to_msg(data: JointCommandData | None = None, /, **kwargs: Any) -> JointCommand:
    """JointCommandData (or its fields as kwargs) -> JointCommand."""
    cmd = _build(JointCommandData, data, kwargs, "joint_command")
    return JointCommand(header=make_header(cmd.stamp), names=list(cmd.names),
                        modes=array.array("B", cmd.modes.tobytes()),
                        values=array.array("d", cmd.values.tobytes()))


def joint_command_from_msg(msg: JointCommand, joint_names: Sequence[str] | None = None) -> JointCommandData:
    """Validate a JointCommand (equal lengths, finite values, known modes, PWM in [-1, 1], and
    names among ``joint_names`` when given) and return it as a JointCommandData."""
    cmd = JointCommandData(names=tuple(msg.names), modes=np.frombuffer(msg.modes, dtype=np.uint8).copy(),
                           values=np.frombuffer(msg.values, dtype=float).copy(), stamp=header_stamp(msg.header))
    if joint_names is not None:
        known = set(joint_names)
        for i, name in enumerate(cmd.names):
            if name not in known:
                raise SpecError(f"joint_command.names[{i}]", f"unknown joint {name!r}")
    return cmd


validate_joint_command = joint_command_from_msg


# --- GripperCommand -------------------------------------------------------------------------

@dataclass(frozen=True)
class GripperCommandData:
    hand: str  # left_hand | right_hand
    command: str  # open | close | position (a GripperCommand code is accepted and named)
    position: float = 0.0  # [-] 0 open .. 1 closed, used by `position` only
    stamp: float = 0.0  # [s] tick at which the request takes effect in lock-step

    def __post_init__(self) -> None:
        f = "gripper_command"
        one_of(self.hand, HANDS, f"{f}.hand")
        command = self.command
        if isinstance(command, (int, np.integer)) and not isinstance(command, bool):
            if int(command) not in _GRIPPER_COMMAND_NAMES:
                raise SpecError(f"{f}.command", f"unknown command code {command}")
            command = _GRIPPER_COMMAND_NAMES[int(command)]
        one_of(command, GRIPPER_COMMANDS, f"{f}.command")
        position = finite_float(self.position, f"{f}.position")
        if not 0.0 <= position <= 1.0:
            raise SpecError(f"{f}.position", f"must be in [0, 1], got {position}")
        _set(self, "command", command)
        _set(self, "position", position)
        _set(self, "stamp", quantize_seconds(self.stamp, f"{f}.stamp"))


def gripper_command_to_msg(data: GripperCommandData | None = None, /, **kwargs: Any) -> GripperCommand:
    cmd = _build(GripperCommandData, data, kwargs, "gripper_command")
    return GripperCommand(header=make_header(cmd.stamp), hand=cmd.hand, command=GRIPPER_COMMANDS[cmd.command],
                          position=cmd.position)


def gripper_command_from_msg(msg: GripperCommand) -> GripperCommandData:
    return GripperCommandData(hand=msg.hand, command=int(msg.command), position=msg.position,
                              stamp=header_stamp(msg.header))


# --- ControllerState ------------------------------------------------------------------------

@dataclass(frozen=True)
class ControllerStateData:
    fsm_state: str = ""  # e.g. hold, remove_contact, add_contact, failure
    mode: str = "qp"  # qp | compliance
    transition_index: int = 0  # plan transition being executed
    active_contacts: tuple[str, ...] = ()  # limbs in contact
    task_errors: Mapping[str, float] = field(default_factory=dict)  # task -> error norm [m or rad]
    qp_status: str = "not_run"  # ok | failed | not_run
    qp_solve_time_ms: float = 0.0  # [ms]
    tick_time_ms: float = 0.0  # [ms] state in -> command out
    qp_failures: int = 0  # since activation
    stamp: float = 0.0  # [s]

    def __post_init__(self) -> None:
        f = "controller_state"
        one_of(self.mode, CONTROLLER_MODES, f"{f}.mode")
        non_negative_int(self.transition_index, f"{f}.transition_index")
        contacts = tuple(self.active_contacts)
        for i, limb in enumerate(contacts):
            one_of(limb, LIMBS, f"{f}.active_contacts[{i}]")
            if limb in contacts[:i]:
                raise SpecError(f"{f}.active_contacts[{i}]", f"{limb} listed twice")
        errors = {}
        for name, err in dict(self.task_errors).items():
            err = finite_float(err, f"{f}.task_errors[{name}]")
            if err < 0.0:
                raise SpecError(f"{f}.task_errors[{name}]", f"an error norm must be >= 0, got {err}")
            errors[str(name)] = err
        one_of(self.qp_status, QP_STATUS, f"{f}.qp_status")
        for name in ("qp_solve_time_ms", "tick_time_ms"):
            value = finite_float(getattr(self, name), f"{f}.{name}")
            if value < 0.0:
                raise SpecError(f"{f}.{name}", f"must be >= 0 [ms], got {value}")
            _set(self, name, value)
        non_negative_int(self.qp_failures, f"{f}.qp_failures")
        _set(self, "transition_index", int(self.transition_index))
        _set(self, "qp_failures", int(self.qp_failures))
        _set(self, "active_contacts", contacts)
        _set(self, "task_errors", errors)
        _set(self, "stamp", quantize_seconds(self.stamp, f"{f}.stamp"))


def controller_state_to_msg(data: ControllerStateData | None = None, /, **kwargs: Any) -> ControllerState:
    s = _build(ControllerStateData, data, kwargs, "controller_state")
    return ControllerState(
        header=make_header(s.stamp), fsm_state=s.fsm_state, mode=s.mode, transition_index=s.transition_index,
        active_contacts=list(s.active_contacts), task_names=list(s.task_errors),
        task_errors=array.array("d", list(s.task_errors.values())), qp_status=QP_STATUS[s.qp_status],
        qp_solve_time_ms=s.qp_solve_time_ms, tick_time_ms=s.tick_time_ms, qp_failures=s.qp_failures)


def controller_state_from_msg(msg: ControllerState) -> ControllerStateData:
    f = "controller_state"
    if len(msg.task_names) != len(msg.task_errors):
        raise SpecError(f"{f}.task_errors", f"must have one error per task name ({len(msg.task_names)}), "
                        f"got {len(msg.task_errors)}")
    if len(set(msg.task_names)) != len(msg.task_names):
        raise SpecError(f"{f}.task_names", "a task name appears twice")
    if msg.qp_status not in _QP_STATUS_NAMES:
        raise SpecError(f"{f}.qp_status", f"unknown code {msg.qp_status}")
    return ControllerStateData(
        fsm_state=msg.fsm_state, mode=msg.mode, transition_index=msg.transition_index,
        active_contacts=tuple(msg.active_contacts), task_errors=dict(zip(msg.task_names, msg.task_errors)),
        qp_status=_QP_STATUS_NAMES[msg.qp_status], qp_solve_time_ms=msg.qp_solve_time_ms,
        tick_time_ms=msg.tick_time_ms, qp_failures=msg.qp_failures, stamp=header_stamp(msg.header))


# --- ClimbStatus ----------------------------------------------------------------------------

@dataclass(frozen=True)
class ClimbStatusData:
    id: str = ""  # climb request id
    phase: str = "idle"  # one of CLIMB_PHASES
    step: int = 0  # stance k ...
    n_steps: int = 0  # ... of n (0 while unknown)
    progress: float = 0.0  # [0, 1]; stored at float32 precision, like the message
    text: str = ""
    stamp: float = 0.0  # [s]

    def __post_init__(self) -> None:
        f = "climb_status"
        one_of(self.phase, CLIMB_PHASES, f"{f}.phase")
        step = non_negative_int(self.step, f"{f}.step")
        n_steps = non_negative_int(self.n_steps, f"{f}.n_steps")
        if step > n_steps:
            raise SpecError(f"{f}.step", f"must be <= n_steps ({n_steps}), got {step}")
        progress = finite_float(self.progress, f"{f}.progress")
        if not 0.0 <= progress <= 1.0:
            raise SpecError(f"{f}.progress", f"must be in [0, 1], got {progress}")
        _set(self, "step", step)
        _set(self, "n_steps", n_steps)
        _set(self, "progress", float(np.float32(progress)))
        _set(self, "stamp", quantize_seconds(self.stamp, f"{f}.stamp"))


def climb_status_to_msg(data: ClimbStatusData | None = None, /, **kwargs: Any) -> ClimbStatus:
    s = _build(ClimbStatusData, data, kwargs, "climb_status")
    return ClimbStatus(header=make_header(s.stamp), id=s.id, phase=s.phase, step=s.step, n_steps=s.n_steps,
                       progress=s.progress, text=s.text)


def climb_status_from_msg(msg: ClimbStatus) -> ClimbStatusData:
    return ClimbStatusData(id=msg.id, phase=msg.phase, step=msg.step, n_steps=msg.n_steps,
                           progress=msg.progress, text=msg.text, stamp=header_stamp(msg.header))
