"""Commands the bridge accepts, validated once at the door.

The library's command form is :class:`ActuatorCommand`: one mode and one value per actuated joint
in the backend's joint order (the robot model's Pinocchio order). :func:`validate_joint_command`
turns a named command (what arrives on ``joint_command``: names, modes, values) into it and raises
``SpecError(field, rule)`` naming the problem: NaN/inf, lengths that differ, an unknown joint, a
joint named twice, an unknown mode, a PWM duty outside [-1, 1]. Joints the command does not name
are damped (a command describes every actuator; a partial command cannot leave a joint on a
stale torque).

Mode codes equal climb_msgs/JointCommand's constants (a test checks it), without importing ROS.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from climb_core.contact import HANDS
from climb_core.errors import SpecError

TORQUE = 0  # value [N m], saturated at the URDF effort limit
PWM = 1  # value = duty cycle in [-1, 1] through the DC-motor model
POSITION = 2  # value [rad], stiff PD (bring-up only)
DAMPING = 3  # value ignored: tau = -damping_gain * qdot
MODES = {"torque": TORQUE, "pwm": PWM, "position": POSITION, "damping": DAMPING}
MODE_NAMES = {v: k for k, v in MODES.items()}

GRIPPER_OPEN = 0
GRIPPER_CLOSE = 1
GRIPPER_POSITION = 2
GRIPPER_COMMANDS = {"open": GRIPPER_OPEN, "close": GRIPPER_CLOSE, "position": GRIPPER_POSITION}


@dataclass(frozen=True)
class ActuatorCommand:
    """One mode and value per actuated joint, in the backend's joint order."""

    modes: np.ndarray  # (n,) uint8 TORQUE | PWM | POSITION | DAMPING
    values: np.ndarray  # (n,) [N m] | duty [-] | [rad] | ignored
    stamp_ns: int = 0  # [ns] sim time of the state this command answers (lock-step)

    @staticmethod
    def damping(n: int, stamp_ns: int = 0) -> "ActuatorCommand":
        return ActuatorCommand(np.full(n, DAMPING, dtype=np.uint8), np.zeros(n), stamp_ns)

    @staticmethod
    def uniform(mode: int, values: Sequence[float] | np.ndarray, stamp_ns: int = 0) -> "ActuatorCommand":
        """Every joint in ``mode`` (e.g. ActuatorCommand.uniform(TORQUE, tau)); values checked finite."""
        values = np.asarray(values, dtype=float).copy()
        if mode not in MODE_NAMES:
            raise SpecError("joint_command.modes", f"unknown mode {mode!r}; known: {MODES}")
        bad = np.flatnonzero(~np.isfinite(values))
        if bad.size:
            raise SpecError(f"joint_command.values[{int(bad[0])}]", f"must be finite, got {values[bad[0]]}")
        if mode == PWM and np.any(np.abs(values) > 1.0):
            i = int(np.flatnonzero(np.abs(values) > 1.0)[0])
            raise SpecError(f"joint_command.values[{i}]", f"PWM duty must be in [-1, 1], got {values[i]}")
        return ActuatorCommand(np.full(values.shape[0], mode, dtype=np.uint8), values, stamp_ns)


def _mode_code(mode: object, field: str) -> int:
    if isinstance(mode, str):
        if mode.lower() in MODES:
            return MODES[mode.lower()]
    elif isinstance(mode, (int, np.integer)) and not isinstance(mode, bool) and int(mode) in MODE_NAMES:
        return int(mode)
    raise SpecError(field, f"unknown mode {mode!r}; known: "
                    + ", ".join(f"{name}={code}" for name, code in MODES.items()))


def validate_joint_command(names: Sequence[str], modes: Sequence[object], values: Sequence[float],
                           joint_names: Sequence[str], stamp_ns: int = 0,
                           joint_index: dict[str, int] | None = None) -> ActuatorCommand:
    """Named command -> ActuatorCommand in ``joint_names`` order; unnamed joints are DAMPING."""
    fast = _every_joint_in_order(names, modes, values, joint_names, stamp_ns)
    if fast is not None:
        return fast
    f = "joint_command"
    names = list(names)
    modes = list(modes)
    try:
        values = [float(v) for v in values]
    except (TypeError, ValueError):
        raise SpecError(f"{f}.values", "must be numbers") from None
    if len(modes) != len(names):
        raise SpecError(f"{f}.modes", f"must have one mode per name ({len(names)}), got {len(modes)}")
    if len(values) != len(names):
        raise SpecError(f"{f}.values", f"must have one value per name ({len(names)}), got {len(values)}")
    index = joint_index if joint_index is not None else {n: i for i, n in enumerate(joint_names)}
    out_modes = np.full(len(joint_names), DAMPING, dtype=np.uint8)
    out_values = np.zeros(len(joint_names))
    seen: set[int] = set()
    for i, (name, mode, value) in enumerate(zip(names, modes, values)):
        j = index.get(name)
        if j is None:
            raise SpecError(f"{f}.names[{i}]", f"unknown joint {name!r} (not an actuated joint of the robot)")
        if j in seen:
            raise SpecError(f"{f}.names[{i}]", f"joint {name!r} named twice")
        seen.add(j)
        code = _mode_code(mode, f"{f}.modes[{i}]")
        if not math.isfinite(value):
            raise SpecError(f"{f}.values[{i}]", f"{name}: must be finite, got {value}")
        if code == PWM and abs(value) > 1.0:
            raise SpecError(f"{f}.values[{i}]", f"{name}: PWM duty must be in [-1, 1], got {value}")
        out_modes[j] = code
        out_values[j] = value
    return ActuatorCommand(out_modes, out_values, int(stamp_ns))


def _every_joint_in_order(names: Sequence[str], modes: Sequence[object], values: Sequence[float],
                          joint_names: Sequence[str], stamp_ns: int) -> ActuatorCommand | None:
    """The usual command (every joint, in ``joint_names`` order, integer modes) checked with numpy;
    None when it is not of that form or has a problem (the per-joint path then names it)."""
    n = len(joint_names)
    if len(names) != n or len(modes) != n or len(values) != n or list(names) != list(joint_names):
        return None
    try:
        mode_arr = np.asarray(modes)
        value_arr = np.array(values, dtype=float)
    except (TypeError, ValueError):
        return None
    if mode_arr.shape != (n,) or mode_arr.dtype.kind not in "iu" or value_arr.shape != (n,):
        return None
    if n and (mode_arr.min() < 0 or mode_arr.max() > max(MODE_NAMES)):
        return None
    if not np.isfinite(value_arr).all() or np.any((mode_arr == PWM) & (np.abs(value_arr) > 1.0)):
        return None
    return ActuatorCommand(mode_arr.astype(np.uint8), value_arr, int(stamp_ns))


def validate_actuator_command(cmd: ActuatorCommand, n_joints: int) -> ActuatorCommand:
    """Check an in-process ActuatorCommand (length, modes, finite values, PWM range)."""
    f = "joint_command"
    modes = np.asarray(cmd.modes)
    values = np.asarray(cmd.values, dtype=float)
    if modes.shape != (n_joints,):
        raise SpecError(f"{f}.modes", f"must have one mode per actuated joint ({n_joints}), got shape {modes.shape}")
    if values.shape != (n_joints,):
        raise SpecError(f"{f}.values", f"must have one value per actuated joint ({n_joints}), got shape {values.shape}")
    unknown = np.flatnonzero(modes > max(MODE_NAMES)) if modes.dtype.kind == "u" else \
        np.flatnonzero(~np.isin(modes, list(MODE_NAMES)))
    if unknown.size:
        i = int(unknown[0])
        raise SpecError(f"{f}.modes[{i}]", f"unknown mode {int(modes[i])}; known: {MODES}")
    if not np.isfinite(values).all():
        i = int(np.flatnonzero(~np.isfinite(values))[0])
        raise SpecError(f"{f}.values[{i}]", f"must be finite, got {values[i]}")
    over = np.flatnonzero((modes == PWM) & (np.abs(values) > 1.0))
    if over.size:
        i = int(over[0])
        raise SpecError(f"{f}.values[{i}]", f"PWM duty must be in [-1, 1], got {values[i]}")
    return ActuatorCommand(modes.astype(np.uint8), values.copy(), int(cmd.stamp_ns))


@dataclass(frozen=True)
class GripperRequest:
    """Close / open / position a hand, effective at sim time ``stamp_ns`` (0 = next tick)."""

    hand: str  # left_hand | right_hand
    command: int  # GRIPPER_OPEN | GRIPPER_CLOSE | GRIPPER_POSITION
    position: float = 0.0  # [-] 0 open .. 1 closed (POSITION only)
    stamp_ns: int = 0  # [ns]

    def __post_init__(self) -> None:
        f = "gripper_command"
        if self.hand not in HANDS:
            raise SpecError(f"{f}.hand", f"must be one of {', '.join(HANDS)}; got {self.hand!r}")
        command = self.command
        if isinstance(command, str):
            if command not in GRIPPER_COMMANDS:
                raise SpecError(f"{f}.command", f"unknown command {command!r}; known: {GRIPPER_COMMANDS}")
            object.__setattr__(self, "command", GRIPPER_COMMANDS[command])
        elif command not in GRIPPER_COMMANDS.values():
            raise SpecError(f"{f}.command", f"unknown command {command!r}; known: {GRIPPER_COMMANDS}")
        position = float(self.position)
        if not math.isfinite(position) or not 0.0 <= position <= 1.0:
            raise SpecError(f"{f}.position", f"must be in [0, 1], got {self.position}")
        object.__setattr__(self, "position", position)
        if int(self.stamp_ns) < 0:
            raise SpecError(f"{f}.header.stamp", f"must be >= 0, got {self.stamp_ns} ns")


PERTURB_KINDS = {"drop": 0, "rung_offset": 1, "rails_shift": 2}


@dataclass(frozen=True)
class PerturbRequest:
    """A run-time perturbation (service sim/perturb, or the spec's `perturbation` block)."""

    kind: str  # drop | rung_offset | rails_shift
    mass: float = 0.0  # [kg] drop
    radius: float = 0.0  # [m] drop
    speed: float = 0.0  # [m/s] drop: speed when it reaches the target
    target_link: str = ""  # drop: URDF link name (or a limb / frame name)
    rung: int = 0  # rung_offset: 1-based rung index
    dx: float = 0.0  # [m] rung_offset, along the ladder's x (toward the ladder)
    dy: float = 0.0  # [m] rails_shift, along the ladder's y (to the robot's left)
    dz: float = 0.0  # [m] rung_offset, vertical
    at_time: float = 0.0  # [s] sim time at which it takes effect; 0 = next tick
    direction: tuple[float, ...] = ()  # drop: world direction of flight; () = the bridge's drops.direction

    def __post_init__(self) -> None:
        f = "perturbation"
        kind = self.kind
        if isinstance(kind, (int, np.integer)) and not isinstance(kind, bool):
            names = {v: k for k, v in PERTURB_KINDS.items()}
            if int(kind) not in names:
                raise SpecError(f"{f}.kind", f"unknown kind {kind}; known: {PERTURB_KINDS}")
            kind = names[int(kind)]
            object.__setattr__(self, "kind", kind)
        if kind not in PERTURB_KINDS:
            raise SpecError(f"{f}.kind", f"unknown kind {kind!r}; known: {', '.join(PERTURB_KINDS)}")
        for name in ("mass", "radius", "speed", "dx", "dy", "dz", "at_time"):
            value = float(getattr(self, name))
            if not math.isfinite(value):
                raise SpecError(f"{f}.{name}", f"must be finite, got {value}")
            object.__setattr__(self, name, value)
        if self.at_time < 0:
            raise SpecError(f"{f}.at_time", f"must be >= 0 [s], got {self.at_time}")
        if kind == "drop":
            for name in ("mass", "radius", "speed"):
                if getattr(self, name) <= 0:
                    raise SpecError(f"{f}.{name}", f"a drop needs {name} > 0, got {getattr(self, name)}")
            if not self.target_link:
                raise SpecError(f"{f}.target_link", "a drop needs a target link")
            if self.direction:
                d = np.asarray(self.direction, dtype=float)
                if d.shape != (3,) or not np.all(np.isfinite(d)) or float(np.linalg.norm(d)) < 1e-9:
                    raise SpecError(f"{f}.direction", f"must be a finite non-zero 3-vector, got {list(self.direction)}")
                object.__setattr__(self, "direction", tuple(float(x) for x in d / np.linalg.norm(d)))
        if kind == "rung_offset" and int(self.rung) < 1:
            raise SpecError(f"{f}.rung", f"rungs are numbered from 1, got {self.rung}")


def drop_request(drop, at_time: float | None = None) -> PerturbRequest:
    """The PerturbRequest of a scenario's drop (climb_core.ladder.DropSpec), thrown at ``at_time``
    (default: the drop's own)."""
    return PerturbRequest("drop", mass=drop.mass, radius=drop.radius, speed=drop.speed, target_link=drop.target_link,
                          at_time=drop.at_time if at_time is None else at_time, direction=tuple(drop.direction))
