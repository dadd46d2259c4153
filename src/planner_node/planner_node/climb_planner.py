"""Plan an N-step ladder climb: primitive sequence + MSP-Recurse over Adapt-Primitive.

"N-step climb" (the grid file's definition, shared/bench/ladder_grid.yaml): from standing on the
ground, mount (approach steps if needed, then both hands on a rung), then N full climbing cycles
of 7 primitives each; every cycle moves both feet one rung up, so an N-step climb ends with both
feet on rung N (hands on the rung nearest the designed hand height above them). From a state
already on the ladder (partially known ladders: plan k cycles now, replan later from the reached
state), the sequence starts with the cycles.
"""
from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np

from climb_core import feasibility
from climb_core.contact import FEET, HANDS, ContactPlan, Stance, WholeBodyPlan
from climb_core.errors import SpecError

from . import msp
from .adapt import AdaptContext, ClimbState, Segment, adapt_primitive, limb_rung
from .primitives import (Primitive, PrimitiveLibrary, load_library, load_variants, rank_variants,
                         reference_key)
from .settings import PlannerSettings, load_settings


@dataclass
class ClimbPlanResult:
    success: bool
    plan: WholeBodyPlan | None  # the plan (on failure: the best partial plan, or None)
    failure_constraint: str  # "" on success; reach:<limb> | torque_limit:<joint> | collision:<a>|<b> | friction | time_limit ...
    failure_detail: str
    plan_time_s: float  # [s] wall time
    plan_cpu_s: float  # [s] CPU time of this process (the wall time counts the machine's other jobs too)
    subtasks: list[str]  # primitive names of the sequence searched
    report: msp.SearchReport | None
    final_state: ClimbState | None
    stats: dict = field(default_factory=dict)
    segments: list[Segment] = field(default_factory=list)
    #: a contact plan's adaptation: its sub-tasks (ContactStep.pair: the stance pair each makes)
    contact_steps: list = field(default_factory=list)

    @property
    def n_stances(self) -> int:
        """Number of stances of the plan: the initial one plus one per transition."""
        return 0 if self.plan is None else 1 + len(self.plan.transitions)

    def summary(self) -> dict:
        feet_rungs = []
        if self.final_state is not None:
            feet_rungs = [limb_rung(self.final_state.stance, f) or 0 for f in FEET]
        return {
            "success": self.success,
            "failure_reason": "" if self.success else f"{self.failure_constraint}: {self.failure_detail}",
            "failure_constraint": "" if self.success else self.failure_constraint,
            "plan_time_s": round(self.plan_time_s, 3),
            "plan_cpu_s": round(self.plan_cpu_s, 3),
            "n_stances": self.n_stances,
            "n_transitions": 0 if self.plan is None else len(self.plan.transitions),
            "rungs_reached": int(min(feet_rungs)) if feet_rungs else 0,
            "attempts": self.report.n_attempts if self.report else 0,
            "backtracks": self.report.n_backtracks if self.report else 0,
            "duration_s": round(plan_duration(self.plan), 2) if self.plan is not None else 0.0,
        }


def plan_duration(plan: WholeBodyPlan) -> float:
    return float(sum(t.times[-1] for t in plan.transitions if len(t.times)))


def subtask_sequence(library: PrimitiveLibrary, stance: Stance, steps: int, env: Any = None) -> list[Primitive]:
    """Primitives to go from ``stance`` through ``steps`` climbing cycles.

    From a stance in the middle of a cycle (a replan right after a placement that found its rung
    off the plan: one foot a rung above the other, or both feet up and the hands still below
    their rung, or one hand up; ``env`` tells the hands' rung), the rest of that cycle comes
    first and ``steps`` counts the feet's rungs: the feet end ``steps`` rungs above the lower
    foot of ``stance``."""
    if steps < 0:
        raise SpecError("steps", f"must be >= 0, got {steps}")
    feet = [limb_rung(stance, f) for f in FEET]
    hands = [limb_rung(stance, h) for h in HANDS]
    if any(r is None for r in feet):
        raise SpecError("start.stance", "both feet must be in contact to start a climb")
    seq: list[Primitive] = []
    on_ground = all(r == 0 for r in feet)
    hands_on = all(r is not None and r > 0 for r in hands)
    if on_ground and not hands_on:
        held = {h for h, r in zip(HANDS, hands) if r is not None}
        if not held:
            seq += library.sequence("approach") if "approach" in library.sequences else []
            seq += library.sequence("mount")
        else:  # a replan after the mount's first hand found its rung off the plan: the rest of the mount
            seq += _rest_after(library.sequence("mount"), held, "mount", feet, hands)
    elif not hands_on:
        raise SpecError("start.stance", "on the ladder both hands must hold a rung")
    cycles = steps
    if hands_on:
        rest = _rest_of_cycle(library, stance, feet, hands, env)
        seq += rest
        if any(p.is_limb and p.limb in FEET and limb_rung(stance, p.limb) == min(feet) for p in rest):
            cycles -= 1  # the rest of the cycle brings the lower foot up one rung
    for k in range(max(cycles, 0)):
        if on_ground and k == 0 and "first_cycle" in library.sequences:
            seq += library.sequence("first_cycle")
        else:
            seq += library.sequence("cycle")
    return seq


def _rest_of_cycle(library: PrimitiveLibrary, stance: Stance, feet: list, hands: list, env: Any) -> list[Primitive]:
    """The primitives of the library's cycle still to run from ``stance`` ([] at a cycle boundary).

    The limbs already moved in this cycle: the higher foot when the feet differ; both feet when
    they are level on a rung and the hands below the rung of the rule ``above_feet`` (``env``);
    the higher hand (and both feet) when the hands differ. The rest starts right after the
    cycle's prefix that moved exactly those limbs (its CoM shift included)."""
    cycle = library.sequence("cycle")
    moved: set[str] = set()
    if feet[0] != feet[1]:
        moved.add(FEET[int(feet[1] > feet[0])])
    elif hands[0] != hands[1]:
        moved.update(FEET)
    elif env is not None and feet[0] > 0 and hands[0] < _hands_rung(library, stance, env):
        moved.update(FEET)  # (on the ground the hands hold the mount rung: a cycle boundary)
    if hands[0] != hands[1]:
        if feet[0] != feet[1]:
            raise SpecError("start.stance", f"feet on rungs {feet} and hands on rungs {hands}: not a stance "
                                            "of the climbing cycle")
        moved.add(HANDS[int(hands[1] > hands[0])])
    if not moved:
        return []
    return _rest_after(cycle, moved, "cycle", feet, hands)


def _rest_after(sequence: list[Primitive], moved: set[str], name: str, feet: list, hands: list) -> list[Primitive]:
    """The primitives of ``sequence`` after its prefix that moved exactly the limbs ``moved``
    (the prefix's CoM shifts included); SpecError when no prefix did."""
    placed: set[str] = set()
    for j, prim in enumerate(sequence):
        if placed == moved:
            return list(sequence[j:])
        if prim.is_limb:
            placed.add(prim.limb)
    raise SpecError("start.stance", f"feet on rungs {feet} and hands on rungs {hands}: no point of the {name} "
                                    f"{[p.name for p in sequence]} has moved exactly {sorted(moved)}")


def _hands_rung(library: PrimitiveLibrary, stance: Stance, env: Any) -> int:
    """The rung the cycle's hands go to over the stance's feet (the ``above_feet`` rule of
    :func:`planner_node.adapt.target_rung`, attempt 0)."""
    zs = [h.centre[2] for h in stance.holds if h.limb in FEET]
    tops = np.array([env.surfaces[f"rung_{k}"].top_z for k in range(1, env.n_rungs + 1)])
    return int(np.argmin(np.abs(tops - (float(np.mean(zs)) + library.hands_above_feet_height)))) + 1


def plan_climb(robot: Any, env: Any, steps: int, *, library: PrimitiveLibrary | None = None,
               settings: PlannerSettings | None = None, start: tuple[np.ndarray, Stance] | None = None,
               seed: int | None = None, timeout_s: float | None = None,
               feasibility_cfg: feasibility.FeasibilityConfig | None = None,
               on_progress: Callable[[int, int, int], None] | None = None) -> ClimbPlanResult:
    """Plan ``steps`` climbing cycles from ``start`` (default: the library's initial fixture)."""
    t0, c0 = time.perf_counter(), time.process_time()
    settings = settings or load_settings()
    p = settings.planning
    if library is None:
        variants = load_variants(robot.config.name, p.strategy, p.primitives_dir, nq=robot.model.nq)
        main = variants[0]  # library.yaml: the sub-task sequence and the start fixture
        lad = env.scenario.ladder
        variants = rank_variants(variants, float(lad.inclination_deg), float(lad.rung_spacing))
        library = variants[0]
    else:
        variants = [library]
        main = library
    if tuple(library.joint_names) != tuple(robot.joint_names):
        raise SpecError("primitives.joint_names", f"library {library.robot}/{library.strategy} was made for "
                                                  f"other joints than robot {robot.config.name}")
    if start is None:
        from climb_core import fixtures

        stance0, q0 = fixtures.get(main.initial_fixture, robot, env)
    else:
        q0, stance0 = start
    ctx = AdaptContext(robot, env, library, settings, feasibility_cfg)
    # one context per library variant (designed on other reference ladders), sharing the stats
    contexts = [ctx]
    for lib in variants[1:]:
        c = AdaptContext(robot, env, lib, settings, feasibility_cfg)
        c.stats = ctx.stats
        contexts.append(c)
    # the nearest library's own sequences when it has a whole climb (a partial variant may lack its
    # mount): otherwise the main library's
    own = all(library.sequences.get(k) for k in ("mount", "cycle"))
    subtasks = subtask_sequence(library if own else main, stance0, steps, env)
    state0 = ClimbState(np.asarray(q0, dtype=float).copy(), stance0)
    per_variant = max(1, p.attempts_per_variant)

    def attempt(prim: Primitive, state: ClimbState, j: int, rng: np.random.Generator):
        # the nearest reference's primitive first; later attempts the next nearest references'.
        # A partial variant lacks some primitives: only the libraries that have this one count,
        # so attempt 0 of the next library is the seed hold and its later attempts are perturbed.
        having = [c for c in contexts if prim.name in c.library.primitives] or [contexts[-1]]
        k = min(j // per_variant, len(having) - 1)
        c = having[k]
        return adapt_primitive(c, c.library.primitives.get(prim.name, prim), state, j - k * per_variant, rng)

    report = msp.multi_step_search(state0, subtasks, attempt, m=p.attempts_per_subtask,
                                   seed=p.seed if seed is None else seed,
                                   time_limit_s=p.timeout_s if timeout_s is None else timeout_s,
                                   on_progress=on_progress)
    segments: list[Segment] = list(report.segments)
    transitions = [s.transition for s in segments if s.transition is not None]
    plan = WholeBodyPlan(robot=robot.config.name, environment=env.name, joint_names=list(robot.joint_names),
                         initial_stance=stance0, transitions=transitions)
    elapsed = time.perf_counter() - t0
    stats = ctx.stats.as_dict()
    stats["search_s"] = report.elapsed_s
    stats["library_references"] = [list(reference_key(c.library)) for c in contexts]
    return ClimbPlanResult(success=report.success, plan=plan if (report.success or transitions) else None,
                           failure_constraint=report.failure_constraint, failure_detail=report.failure_detail,
                           plan_time_s=elapsed, plan_cpu_s=time.process_time() - c0,
                           subtasks=[s.name for s in subtasks], report=report,
                           final_state=report.final_state, stats=stats, segments=segments)




# --------------------------------------------------------------------------------------------
# a contact plan (stance sequence from the contact search) -> whole-body plan


@dataclass(frozen=True)
class ContactStep:
    """One stance change of a contact plan: adapted from a library primitive, or (``primitive``
    None) a generic contact-body path (:mod:`planner_node.contact_path`)."""

    name: str
    kind: str  # limb | com | release | free
    primitive: Primitive | None
    limb: str
    hold: Any  # the new hold (limb), None otherwise
    q_end: np.ndarray  # the contact plan's transition configuration of the next stance
    unload: tuple[str, ...] = ()  # generic CoM shift / release: limbs that must be removable at its end
    keep: tuple[str, ...] = ()  # limbs freed for good by an earlier step: their joints stay as they are
    pair: int = -1  # i: the step makes the contact plan's change from stance i to stance i + 1


def _same_hold(a, b) -> bool:
    if a is None or b is None:
        return a is b
    return a.env_surface == b.env_surface and np.allclose(a.centre, b.centre, atol=1e-4)


def _surface_kind(surface: str) -> str:
    """The primitives' target surface name of an environment surface ("" when none fits)."""
    if surface == "ground":
        return "ground"
    return "rung" if surface.startswith("rung_") else ""


def contact_plan_steps(library: PrimitiveLibrary, plan: ContactPlan) -> list[ContactStep]:
    """Sub-tasks for a contact plan: one per consecutive stance pair (SpecError when a pair changes
    more than one hold). A pair no library primitive fits (a hold left or made on a surface other
    than the ground or a rung, an empty library) gets a generic step (``primitive`` None). A
    released limb stays held
    (the controller releases it when it moves next): its release is a CoM shift ending with the
    limb removable, and its next placement moves it from that hold."""
    import dataclasses as dc

    from climb_core.contact import LIMBS

    if len(plan.stances) < 2 or len(plan.transition_configurations) != len(plan.stances):
        raise SpecError("contact_plan", "needs >= 2 stances and one transition configuration per stance")
    changes = []
    for i, (a, b) in enumerate(zip(plan.stances[:-1], plan.stances[1:])):
        changed = [limb for limb in LIMBS if not _same_hold(a.hold(limb), b.hold(limb))]
        if len(changed) > 1:
            raise SpecError(f"contact_plan.stances[{i + 1}]", f"one hold may change per transition, got {changed}")
        changes.append(changed[0] if changed else "")
    steps = []
    released: dict[str, Any] = {}  # limb -> hold released by the plan, still held until the limb moves
    first_step: list[int] = []  # per stance pair: index of its first step
    for i, (a, b) in enumerate(zip(plan.stances[:-1], plan.stances[1:])):
        first_step.append(len(steps))
        q_end = np.asarray(plan.transition_configurations[i + 1], dtype=float)
        limb = changes[i]
        nxt = changes[i + 1] if i + 1 < len(changes) else ""
        unload_next = (nxt,) if nxt and (b.hold(nxt) is not None or nxt in released) else ()
        if not limb:
            # the library's CoM shift is a ladder move: only between holds on the ground or rungs
            ladder_stances = all(_surface_kind(h.env_surface) for st in (a, b) for h in st.holds)
            com = [p for p in library.primitives.values() if p.kind == "com"] if ladder_stances else []
            prim = dc.replace(com[0], end_unload=()) if com else None
            steps.append(ContactStep(f"com_{i}", "com", prim, "", None, q_end, () if com else unload_next))
            continue
        new = b.hold(limb)
        if new is None and not any(changes[k] == limb and plan.stances[k + 1].hold(limb) is not None
                                   for k in range(i + 1, len(changes))):
            # released for good (a hand off the block once the feet are up): first the CoM onto
            # the other holds (the limb still held, removable at the end), then the limb leaves its
            # hold and stays free
            steps.append(ContactStep(f"release_{limb}_{i}", "release", None, limb, None, q_end, (limb,)))
            steps.append(ContactStep(f"free_{limb}_{i}", "free", None, limb, None, q_end))
            continue
        if new is None:
            released[limb] = a.hold(limb)
            steps.append(ContactStep(f"release_{limb}_{i}", "release", None, limb, None, q_end, (limb,)))
            continue
        previous = a.hold(limb) or released.pop(limb, None)
        # a primitive moves a limb from the ground or a rung onto the ground or a rung (a ladder
        # library's cycle); from a step, a block or a wall the move is generic
        surface = _surface_kind(new.env_surface) if previous is None or _surface_kind(previous.env_surface) else ""
        want_type = "mount" if previous is None and limb in HANDS else None
        cands = [p for p in library.primitives.values() if p.kind == "limb" and p.limb == limb and surface
                 and p.target.surface == surface and (want_type is None or p.type == want_type)]
        if not cands and surface:
            cands = [p for p in library.primitives.values() if p.kind == "limb" and p.limb == limb
                     and p.target.surface == surface]
        prim = dc.replace(cands[-1], end_unload=(limb,)) if cands else None
        name = prim.name if prim is not None else f"generic_{limb}"
        steps.append(ContactStep(f"{name}_{i}", "limb", prim, limb, new, q_end))
    # every step after a limb's release for good keeps that limb's posture
    out, kept = [], ()
    for k, st in enumerate(steps):
        pair = max(i for i, first in enumerate(first_step) if first <= k)
        out.append(dc.replace(st, keep=kept, pair=pair))
        if st.kind == "free":
            kept = kept + (st.limb,)
    return out


def _same_step(a: ContactStep, b: ContactStep) -> bool:
    """The same sub-task: kind, limb, hold, primitive and end configuration (a repaired contact
    plan shares its first sub-tasks with the plan it repairs)."""
    if (a.kind, a.limb, a.unload, a.keep) != (b.kind, b.limb, b.unload, b.keep):
        return False
    if (a.primitive is None) != (b.primitive is None) or (a.primitive is not None and a.primitive.name != b.primitive.name):
        return False
    if not _same_hold(a.hold, b.hold):
        return False
    return a.q_end.shape == b.q_end.shape and bool(np.allclose(a.q_end, b.q_end, atol=1e-9))


def _adapt_contact_step(ctx: AdaptContext, step: ContactStep, state: ClimbState, attempt: int,
                        rng: np.random.Generator):
    from . import adapt as A
    from . import contact_path

    if step.keep:  # limbs freed for good keep their posture (the search left them where they held)
        step = dataclasses.replace(step, q_end=contact_path.keep_limb_posture(ctx.robot, step.q_end, state.q, step.keep))
    try:
        if step.kind == "free":
            return contact_path.free_step(ctx, state, step.limb, step.q_end, attempt, rng, step.name)
        if step.primitive is None and step.kind == "limb":
            return contact_path.transfer_step(ctx, state, step.limb, step.hold, step.q_end, attempt, rng, step.name)
        if step.primitive is None:  # a generic CoM shift, or a release (the CoM onto the other holds)
            return contact_path.com_step(ctx, state, step.q_end, step.unload, attempt, rng, step.name)
    except SpecError as exc:
        return msp.AttemptFailure(f"hold:{exc.field}", f"{step.name}: {exc}", fatal=True)
    if step.kind == "limb":
        out = A._adapt_limb(ctx, step.primitive, state, attempt, rng, hold=step.hold, q_end_seed=step.q_end)
    else:
        out = A._adapt_com(ctx, step.primitive, state, attempt, rng, q_end_seed=step.q_end)
    if isinstance(out, msp.Step):
        seg = out.segment
        return msp.Step(out.state, Segment(step.name, seg.transition, seg.hold, seg.attempt))
    return out


def plan_from_contact_plan(robot: Any, env: Any, contact_plan: ContactPlan, *,
                           library: PrimitiveLibrary | None = None, settings: PlannerSettings | None = None,
                           seed: int | None = None, timeout_s: float | None = None,
                           feasibility_cfg: feasibility.FeasibilityConfig | None = None,
                           on_progress: Callable[[int, int, int], None] | None = None,
                           previous: ClimbPlanResult | None = None) -> ClimbPlanResult:
    """Whole-body paths for a contact plan's stance sequence: each transition adapted from the
    library primitive of that limb (ending at the plan's hold, seeded by its configuration), or a
    generic contact-body path where none fits (:func:`contact_plan_steps`). Without a library on
    disk every step is generic; ``library=contact_path.empty_library(robot)`` forces that.
    ``previous``: the adaptation of a plan this one repairs (pipeline.search_and_adapt): the
    sub-tasks both share, up to ``contact_path.backtrack_window`` before the first that differs,
    are kept as made there instead of being adapted again."""
    from . import contact_path

    t0, c0 = time.perf_counter(), time.process_time()
    settings = settings or load_settings()
    p = settings.planning
    if library is None:
        try:
            library = load_library(robot.config.name, p.strategy, p.primitives_dir, nq=robot.model.nq)
        except SpecError as exc:
            if exc.field != "primitives":  # a malformed library is an error, a missing one is not
                raise
            library = contact_path.empty_library(robot)
    if list(contact_plan.joint_names) and list(contact_plan.joint_names) != list(robot.joint_names):
        raise SpecError("contact_plan.joint_names", f"must be the joints of robot {robot.config.name}")
    steps = contact_plan_steps(library, contact_plan)
    ctx = AdaptContext(robot, env, library, settings, feasibility_cfg)
    state0 = ClimbState(np.asarray(contact_plan.transition_configurations[0], dtype=float), contact_plan.stances[0])
    window = settings.contact_path.backtrack_window
    prefix: list = []
    if previous is not None and previous.report is not None:
        shared = next((k for k, (a, b) in enumerate(zip(previous.contact_steps, steps)) if not _same_step(a, b)),
                      min(len(previous.contact_steps), len(steps)))
        keep = max(0, min(shared, len(previous.report.states)) - max(window, 0))
        prefix = [(previous.segments[k], previous.report.states[k]) for k in range(keep)]
    report = msp.multi_step_search(state0, steps, lambda st, s, j, rng: _adapt_contact_step(ctx, st, s, j, rng),
                                   m=p.attempts_per_subtask, seed=p.seed if seed is None else seed,
                                   time_limit_s=p.timeout_s if timeout_s is None else timeout_s,
                                   on_progress=on_progress, backtrack_window=window if window >= 0 else None,
                                   prefix=prefix)
    segments = list(report.segments)
    transitions = [s.transition for s in segments if s.transition is not None]
    plan = WholeBodyPlan(robot=robot.config.name, environment=env.name, joint_names=list(robot.joint_names),
                         initial_stance=contact_plan.stances[0], transitions=transitions)
    stats = ctx.stats.as_dict()
    return ClimbPlanResult(success=report.success, plan=plan if (report.success or transitions) else None,
                           failure_constraint=report.failure_constraint, failure_detail=report.failure_detail,
                           plan_time_s=time.perf_counter() - t0, plan_cpu_s=time.process_time() - c0,
                           subtasks=[s.name for s in steps], report=report,
                           final_state=report.final_state, stats=stats, segments=segments,
                           contact_steps=steps)
