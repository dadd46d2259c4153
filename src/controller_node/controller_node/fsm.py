"""The contact finite-state machine (multicontact_darpa_tasks.txt, section III-D).

The transition table lives in config/fsm/<name>.yaml (:func:`load_fsm_table`); the states are
the classes below. A state has a documented lifecycle:

- ``start(ctx)``: set the tasks / targets it needs, request contact or gripper changes;
- ``run(ctx) -> event | None``: once per tick, after the new state arrived, before the QP;
- ``teardown(ctx)``: remove the tasks it added.

States act through the *context* (the controller, :class:`controller_node.controller.Controller`):
they never hold contacts themselves. The controller owns the active contact set; states ask it
to ramp, release or add a contact. Events raised by ``run`` are looked up in the table; several
instantaneous states (``select``) may chain within one tick.
"""
from __future__ import annotations

import pathlib
from dataclasses import dataclass
from typing import Any, Protocol

import yaml

from climb_core.contact import HANDS, LIMBS, Hold, Transition
from climb_core.errors import SpecError
from climb_core.ros_env import project_root

ANY_STATE = "*"
#: what a table row's ``limb`` may restrict it to: a hand that grasps (bilateral hold: gripper
#: states), a hand that pushes with its palm (unilateral hold: no gripper), a foot
LIMB_KINDS = ("hand", "palm", "foot")


def limb_kind(limb: str, hold: Hold | None = None) -> str:
    """``foot``; for a hand, ``palm`` when the hold it makes or breaks is unilateral (a palm push),
    else ``hand`` (a grasp, or no hold known)."""
    if limb not in HANDS:
        return "foot"
    return "palm" if hold is not None and not hold.bilateral else "hand"


@dataclass(frozen=True)
class TableRow:
    source: str
    event: str
    target: str
    limb: str = ""  # "" | hand | palm | foot


@dataclass(frozen=True)
class FsmTable:
    initial: str
    states: dict[str, str]  # name -> description
    rows: tuple[TableRow, ...]

    def next_state(self, state: str, event: str, moving_limb: str = "", kind: str = "") -> str | None:
        """The row's target for ``event`` in ``state`` (rows of ``state`` first, then ``*``).
        ``kind`` (:data:`LIMB_KINDS`) is the moving limb's; default: :func:`limb_kind` of the limb
        alone (a hand grasps)."""
        kind = kind or (limb_kind(moving_limb) if moving_limb else "")
        for rows in (r for r in self.rows if r.source == state), (r for r in self.rows if r.source == ANY_STATE):
            for row in rows:
                if row.event == event and (not row.limb or row.limb == kind):
                    return row.target
        return None

    def events_from(self, state: str) -> set[str]:
        return {r.event for r in self.rows if r.source in (state, ANY_STATE)}


def parse_fsm_table(data: Any, source: str = "fsm") -> FsmTable:
    """Validate a transition table (SpecError naming the field and the rule)."""
    if not isinstance(data, dict):
        raise SpecError(source, "must be a mapping with initial, states, transitions")
    unknown = set(data) - {"initial", "states", "transitions"}
    if unknown:
        raise SpecError(f"{source}.{sorted(unknown)[0]}", "unknown key")
    states = data.get("states")
    if not isinstance(states, dict) or not states:
        raise SpecError(f"{source}.states", "must be a non-empty mapping of state name -> description")
    missing = sorted(set(states) - set(STATE_CLASSES))
    if missing:
        raise SpecError(f"{source}.states.{missing[0]}", f"no such state class; known: {sorted(STATE_CLASSES)}")
    initial = data.get("initial")
    if initial not in states:
        raise SpecError(f"{source}.initial", f"must be one of the states, got {initial!r}")
    raw_rows = data.get("transitions")
    if not isinstance(raw_rows, list) or not raw_rows:
        raise SpecError(f"{source}.transitions", "must be a non-empty list")
    rows = []
    seen = set()
    for i, raw in enumerate(raw_rows):
        where = f"{source}.transitions[{i}]"
        if not isinstance(raw, dict) or not {"from", "event", "to"} <= set(raw) or set(raw) - {"from", "event", "to", "limb"}:
            raise SpecError(where, "must have keys from, event, to (and optionally limb)")
        row = TableRow(str(raw["from"]), str(raw["event"]), str(raw["to"]), str(raw.get("limb", "")))
        if row.source != ANY_STATE and row.source not in states:
            raise SpecError(f"{where}.from", f"unknown state {row.source!r}")
        if row.target not in states:
            raise SpecError(f"{where}.to", f"unknown state {row.target!r}")
        if row.limb and row.limb not in LIMB_KINDS:
            raise SpecError(f"{where}.limb", f"must be one of {LIMB_KINDS}")
        key = (row.source, row.event, row.limb)
        if key in seen:
            raise SpecError(where, f"duplicate row for state {row.source!r}, event {row.event!r}")
        seen.add(key)
        rows.append(row)
    # every event a state can raise must lead somewhere (for every limb kind it can occur with)
    for name in states:
        for event in STATE_CLASSES[name].events:
            for kind in LIMB_KINDS:
                limb = "left_foot" if kind == "foot" else "left_hand"
                table = FsmTable(initial, dict(states), tuple(rows))
                if table.next_state(name, event, limb, kind) is None:
                    raise SpecError(f"{source}.transitions", f"state {name!r} raises {event!r} ({kind}) "
                                                             "but no row handles it")
    return FsmTable(str(initial), {str(k): str(v) for k, v in states.items()}, tuple(rows))


def load_fsm_table(name_or_path: str | pathlib.Path = "default") -> FsmTable:
    path = pathlib.Path(name_or_path)
    if not path.suffix:
        path = project_root() / "config" / "fsm" / f"{name_or_path}.yaml"
    if not path.is_file():
        raise SpecError("fsm_table", f"{path} not found")
    with open(path, encoding="utf-8") as stream:
        return parse_fsm_table(yaml.safe_load(stream), source=path.stem)


# --------------------------------------------------------------------------------------------
class Context(Protocol):
    """What states may use (implemented by :class:`controller_node.controller.Controller`)."""

    time: float  # [s]
    params: Any  # ControllerParams
    transition: Transition | None  # the plan transition being executed
    moving_limb: str  # its moving limb ("" for a CoM shift)
    moving_kind: str  # limb_kind of the moving limb and the hold it makes or breaks ("" for a CoM shift)
    target_surface: str  # the environment surface the moving limb goes to
    plan_pending: bool  # a new plan arrived
    replan_needed: bool
    replan_reason: str  # set by the state that raises the event leading to replan_needed
    contact_body_tasks: dict  # limb -> FrameTask
    recovery: "RecoveryContext"  # the brace and failure states' part (controller_node.recovery.Recovery)
    path: "PathContext"  # the transition's path and the guarded search (controller_node.tracking.PathTracker)

    def next_transition(self) -> Transition | None: ...
    def finish_transition(self) -> None: ...
    def has_contact(self, limb: str) -> bool: ...
    def hold_here(self) -> None: ...
    def begin_release(self, limb: str) -> None: ...
    def release_done(self, limb: str) -> bool: ...
    def remove_contact(self, limb: str) -> None: ...
    def add_contact(self, limb: str) -> None: ...
    def contact_ready(self, limb: str) -> bool: ...
    def contact_off_plan(self, limb: str) -> bool: ...
    def gripper(self, hand: str, command: str, position: float = 0.0) -> None: ...
    def tare_ft(self, limb: str) -> None: ...
    def ft_force_change(self, limb: str) -> float: ...
    def contact_threshold(self, limb: str) -> float: ...
    def search_stalled(self, limb: str) -> bool: ...
    def limb_tilted(self, limb: str) -> bool: ...
    def search_travel(self, limb: str) -> float: ...
    def set_guard(self, limb: str, surface: str, on: bool) -> None: ...
    def emit(self, kind: str, **values: Any) -> None: ...


class PathContext(Protocol):
    """What states use to follow a transition's path (implemented by
    :class:`controller_node.tracking.PathTracker`)."""

    def start(self, transition: Transition, moving_limb: str = "") -> None: ...
    def track(self) -> bool: ...
    def in_approach(self, fraction: float = 0.0) -> bool: ...
    def freeze_limb(self) -> None: ...
    def creep(self, distance: float) -> None: ...


class RecoveryContext(Protocol):
    """What the brace and failure states use (implemented by :class:`controller_node.recovery.Recovery`)."""

    def enter_fallback(self) -> None: ...
    def begin_brace(self) -> None: ...
    def end_brace(self) -> None: ...
    def brace_settled(self) -> bool: ...
    def lost_contacts(self) -> list[str]: ...
    def resume_after_brace(self) -> None: ...
    def replace_lost(self, lost: list[str]) -> bool: ...
    def failure_recovered(self) -> bool: ...
    def leave_failure(self) -> None: ...


class State:
    name = "state"
    events: tuple[str, ...] = ()

    def __init__(self) -> None:
        self.started_at = 0.0

    def elapsed(self, ctx: Context) -> float:
        return ctx.time - self.started_at

    def start(self, ctx: Context) -> None:
        pass

    def run(self, ctx: Context) -> str | None:
        return None

    def teardown(self, ctx: Context) -> None:
        pass


class IdleState(State):
    name = "idle"
    events = ("plan",)

    def start(self, ctx: Context) -> None:
        ctx.hold_here()

    def run(self, ctx: Context) -> str | None:
        return "plan" if ctx.plan_pending else None


class HoldState(IdleState):
    name = "hold"

    def start(self, ctx: Context) -> None:
        ctx.hold_here()
        ctx.emit("plan_done")


class ReplanNeededState(IdleState):
    name = "replan_needed"

    def start(self, ctx: Context) -> None:
        ctx.hold_here()
        ctx.replan_needed = True
        ctx.emit("replan_needed", limb=ctx.moving_limb, reason=ctx.replan_reason)


class SelectState(State):
    name = "select"
    events = ("com_shift", "remove", "add", "plan_done")

    def run(self, ctx: Context) -> str | None:
        transition = ctx.next_transition()
        if transition is None:
            return "plan_done"
        limb = transition.moving_limb
        if not limb:
            return "com_shift"
        return "remove" if ctx.has_contact(limb) else "add"


class MoveComState(State):
    name = "move_com"
    events = ("path_done",)

    def start(self, ctx: Context) -> None:
        ctx.path.start(ctx.transition, "")

    def run(self, ctx: Context) -> str | None:
        if ctx.path.track():
            ctx.finish_transition()
            return "path_done"
        return None


class UnloadState(State):
    """Remove contact, part 1: hold the path start and ramp the moving limb's force to zero."""

    name = "unload"
    events = ("unloaded",)

    def start(self, ctx: Context) -> None:
        ctx.hold_here()
        ctx.begin_release(ctx.moving_limb)

    def run(self, ctx: Context) -> str | None:
        return "unloaded" if ctx.release_done(ctx.moving_limb) else None

    def teardown(self, ctx: Context) -> None:
        if ctx.moving_kind != "hand":  # a grasp leaves the set when its gripper has opened
            ctx.remove_contact(ctx.moving_limb)


class OpenGripperState(State):
    name = "open_gripper"
    events = ("opened",)

    def start(self, ctx: Context) -> None:
        ctx.gripper(ctx.moving_limb, "open")

    def run(self, ctx: Context) -> str | None:
        return "opened" if self.elapsed(ctx) >= ctx.params.gripper.open_time_s else None

    def teardown(self, ctx: Context) -> None:
        ctx.remove_contact(ctx.moving_limb)


class TransferState(State):
    """Add contact: the contact-body task follows the way-points; the F/T guards the approach.
    A transition whose target stance has no hold for the moving limb frees it: the path is
    followed without a guard, then ``freed``.

    The limb's F/T is tared when the last path segment (the approach) begins, and watched from
    ``guarded.settle_time_s`` later: a force against the approach direction above
    ``guarded.force_threshold`` (or ``guarded.noise_sigmas`` standard deviations of the sensor's
    noise when larger: Context.contact_threshold) is the contact (early when the path is not
    finished)."""

    name = "transfer"
    events = ("contact", "path_end", "freed")

    def start(self, ctx: Context) -> None:
        limb = ctx.moving_limb
        if ctx.has_contact(limb):  # plan starting with the limb free is fine; otherwise release now
            ctx.remove_contact(limb)
        ctx.path.start(ctx.transition, limb)  # the damper of (limb, target surface) goes off on
        # the last path segment (the approach), see PathTracker.track
        if ctx.moving_kind == "palm":  # a push: fingers straight, out of the push surface's way
            ctx.gripper(limb, "open")
        elif limb in HANDS:
            ctx.gripper(limb, "position", ctx.params.gripper.pregrasp_position)
        self.tared_at = None

    def run(self, ctx: Context) -> str | None:
        done = ctx.path.track()
        if moving_hold(ctx.transition) is None:  # the limb leaves its hold for good: no contact to find
            if done:
                ctx.finish_transition()
                return "freed"
            return None
        g = ctx.params.guarded
        if self.tared_at is None and ctx.path.in_approach(g.approach_arm_fraction):
            ctx.tare_ft(ctx.moving_limb)
            self.tared_at = ctx.time
        if self.tared_at is not None:  # stiffen the approach smoothly: a blocked limb pushes harder
            task = ctx.contact_body_tasks[ctx.moving_limb]
            k0 = ctx.params.tasks.contact_body.stiffness
            ramp = min(1.0, (ctx.time - self.tared_at) / max(g.stiffen_time_s, 1e-9))
            task.stiffness = k0 + ramp * (g.search_stiffness - k0)
        armed = self.tared_at is not None and ctx.time - self.tared_at >= g.settle_time_s
        if armed:
            by_force = ctx.ft_force_change(ctx.moving_limb) > ctx.contact_threshold(ctx.moving_limb)
            if by_force or ctx.limb_tilted(ctx.moving_limb):
                ctx.path.freeze_limb()
                ctx.emit("contact_detected", limb=ctx.moving_limb, early=not done, state=self.name,
                         by="force" if by_force else "tilt")
                return "contact"
        return "path_end" if done else None

    def teardown(self, ctx: Context) -> None:  # (search sets its own stiffness in start)
        ctx.contact_body_tasks[ctx.moving_limb].stiffness = ctx.params.tasks.contact_body.stiffness


class SearchState(State):
    """Past the planned pose without contact: creep along the approach direction, bounded by the
    limb's own travel (``guarded.search_distance``), not its target's: a limb lagging its creeping
    target (a foot lags ~1 cm) is given up to ``guarded.search_lead_max`` more target travel, so
    that a foothold missed by 4 cm is still found (measured before: rung 2 4 cm low, the foot's
    target 5 cm past the plan, the foot 3.8 cm, 2 mm above the rung: ``no_contact``)."""

    name = "search"
    events = ("contact", "exhausted")

    def start(self, ctx: Context) -> None:
        self.travelled = 0.0
        ctx.contact_body_tasks[ctx.moving_limb].stiffness = ctx.params.guarded.search_stiffness
        ctx.emit("search_started", limb=ctx.moving_limb)

    def teardown(self, ctx: Context) -> None:
        ctx.contact_body_tasks[ctx.moving_limb].stiffness = ctx.params.tasks.contact_body.stiffness

    def run(self, ctx: Context) -> str | None:
        g = ctx.params.guarded
        limb = ctx.moving_limb
        by_force = ctx.ft_force_change(limb) > ctx.contact_threshold(limb)
        by = "force" if by_force else "stall" if ctx.search_stalled(limb) else "tilt" if ctx.limb_tilted(limb) else ""
        if by:
            ctx.path.freeze_limb()
            ctx.emit("contact_detected", limb=limb, early=False, state=self.name, extra_travel=self.travelled, by=by)
            return "contact"
        if self.travelled >= g.search_distance and (ctx.search_travel(limb) >= g.search_distance
                                                    or self.travelled >= g.search_distance + g.search_lead_max):
            ctx.emit("search_exhausted", limb=limb, target_travel=round(self.travelled, 4),
                     limb_travel=round(ctx.search_travel(limb), 4))
            ctx.path.freeze_limb()
            ctx.replan_reason = "no_contact"
            return "exhausted"
        step = g.approach_speed * ctx.params.control_period_s
        self.travelled += step
        ctx.path.creep(self.travelled)
        return None


class CloseGripperState(State):
    name = "close_gripper"
    events = ("closed",)

    def start(self, ctx: Context) -> None:
        ctx.gripper(ctx.moving_limb, "close")

    def run(self, ctx: Context) -> str | None:
        return "closed" if self.elapsed(ctx) >= ctx.params.gripper.close_time_s else None


class LoadState(State):
    """The new contact joins with a force ramp. A placement that found its surface off the plan
    beyond ``guarded.replan_offset`` ends in ``off_plan`` once loaded (the transition is done; the
    plan's next poses assume the planned surface, so the robot holds and a replan follows)."""

    name = "load"
    events = ("loaded", "off_plan")

    def start(self, ctx: Context) -> None:
        ctx.add_contact(ctx.moving_limb)

    def run(self, ctx: Context) -> str | None:
        if ctx.contact_ready(ctx.moving_limb):
            ctx.finish_transition()
            if ctx.contact_off_plan(ctx.moving_limb):
                ctx.replan_reason = "contact_offset"
                return "off_plan"
            return "loaded"
        return None


class BraceState(State):
    """After an impact (the controller fires ``impact``, impact.py): every active contact held at
    full load (a release under way is cancelled, grasps allowed the whole grip strength), the
    posture task stiffened toward the configuration at the impact, a QP that the blow makes
    infeasible answered with the relaxed solve instead of a failure. Once ``impact.brace_time_s``
    has passed and the joints have settled (or ``impact.brace_max_s``): a contact that moved more
    than ``impact.contact_lost_distance`` is lost (``contact_lost``: hold and ask for a replan);
    otherwise the interrupted transition resumes from where the robot is (``resume``). A single
    lost contact is put back first (``replace``: the plan's transition that placed it runs again,
    guarded, then the interrupted one; ``impact.replace_lost``)."""

    name = "brace"
    events = ("resume", "replace", "contact_lost")

    def start(self, ctx: Context) -> None:
        ctx.recovery.begin_brace()

    def run(self, ctx: Context) -> str | None:
        p = ctx.params.impact
        t = self.elapsed(ctx)
        if t < p.brace_time_s or (t < p.brace_max_s and not ctx.recovery.brace_settled()):
            return None
        lost = ctx.recovery.lost_contacts()
        if lost:
            if ctx.recovery.replace_lost(lost):  # put it back first (the transition that placed it, again)
                return "replace"
            ctx.replan_reason = "contact_lost"
            return "contact_lost"
        ctx.recovery.resume_after_brace()
        return "resume"

    def teardown(self, ctx: Context) -> None:
        ctx.recovery.end_brace()


class FailureState(State):
    """The QP kept failing: hold tasks at the configuration at failure (the PD fallback while the
    QP cannot be solved). Once the hold QP has solved for ``qp.recover_after_s`` and the joints
    have settled, ``recovered``: the plan is abandoned and a replan asked for (reason
    ``qp_failure``)."""

    name = "failure"
    events = ("recovered",)

    def start(self, ctx: Context) -> None:
        ctx.recovery.enter_fallback()

    def run(self, ctx: Context) -> str | None:
        if ctx.recovery.failure_recovered():
            ctx.replan_reason = "qp_failure"
            return "recovered"
        return None

    def teardown(self, ctx: Context) -> None:
        ctx.recovery.leave_failure()


STATE_CLASSES: dict[str, type[State]] = {cls.name: cls for cls in (
    IdleState, HoldState, ReplanNeededState, SelectState, MoveComState, UnloadState, OpenGripperState,
    TransferState, SearchState, CloseGripperState, LoadState, BraceState, FailureState)}


class Fsm:
    """Runs the states of a table; ``step`` once per tick, ``fire`` for external events."""

    MAX_CHAIN = 8  # instantaneous transitions allowed within one tick

    def __init__(self, table: FsmTable):
        self.table = table
        self.states = {name: STATE_CLASSES[name]() for name in table.states}
        self.current = self.states[table.initial]
        self.history: list[tuple[float, str, str, str]] = []  # (time, from, event, to)
        self._started = False

    @property
    def state(self) -> str:
        return self.current.name

    def begin(self, ctx: Context) -> None:
        self.current.started_at = ctx.time
        self.current.start(ctx)
        self._started = True

    def fire(self, ctx: Context, event: str) -> bool:
        """Apply ``event`` now; False when the table has no row for it in the current state."""
        target = self.table.next_state(self.current.name, event, ctx.moving_limb, ctx.moving_kind)
        if target is None:
            return False
        self.history.append((ctx.time, self.current.name, event, target))
        self.current.teardown(ctx)
        self.current = self.states[target]
        self.current.started_at = ctx.time
        try:
            self.current.start(ctx)
        except Exception:
            # a state that cannot start (a transition of the plan it cannot execute) is not left
            # half set up for the next tick: the FSM holds the active contacts, then the error
            # goes on to the caller (reported there)
            failed = self.current.name
            hold = self.table.next_state(failed, "hold", ctx.moving_limb, ctx.moving_kind)
            if hold is not None and hold != failed:
                self.history.append((ctx.time, failed, "hold", hold))
                self.current = self.states[hold]
                self.current.started_at = ctx.time
                self.current.start(ctx)
            raise
        return True

    def step(self, ctx: Context) -> None:
        if not self._started:
            self.begin(ctx)
        for _ in range(self.MAX_CHAIN):
            event = self.current.run(ctx)
            if event is None:
                return
            if not self.fire(ctx, event):
                raise SpecError("fsm", f"state {self.current.name!r} raised {event!r}, which the table "
                                       "does not handle")


def moving_hold(transition: Transition) -> Hold | None:
    """The hold the moving limb makes at the end of ``transition`` (None for a CoM shift)."""
    if not transition.moving_limb:
        return None
    return transition.target_stance.hold(transition.moving_limb)


__all__ = ["FsmTable", "TableRow", "Fsm", "State", "STATE_CLASSES", "load_fsm_table", "parse_fsm_table",
           "limb_kind", "moving_hold", "LIMBS"]
