"""The planning pipeline of the ROS graph, without ROS: plan request -> guide path -> contact plan
-> whole-body plan, by one of two strategies: ``primitives`` (the ladder paper's method, ladders
only) or ``search`` (the DARPA-tasks paper's free-flyer guide path and best-first contact search,
ladders and scenes; :func:`guide_path_search`, :func:`contact_search_search`, :func:`adapt_search`).

The coordinator publishes a *plan request* (JSON, :func:`parse_plan_request`); three nodes
answer it in turn, each a thin wrapper around one function here:

1. ``guide_path`` -> :func:`guide_path`: the milestones of the primitive sequence moved onto the
   actual ladder. The sub-task sequence is the one the multi-step search will adapt
   (:func:`planner_node.climb_planner.subtask_sequence`: approach, mount, N cycles); each
   primitive's designed key configuration (its end way-point q̄e, a stance or CoM-transfer
   configuration of the reference ladder) is moved so that its hold anchor lands on the seed
   holds of the actual rungs (cycle k: k rung spacings up the actual ladder), then projected onto
   those holds' contact constraints (kinematics only).
2. ``contact_search`` -> :func:`contact_search`: the stance sequence of the library's seed holds
   (attempt 0 of Adapt-Primitive's hold sampling, built with ``climb_core.holds`` on the
   scenario's rungs); each stance's transition configuration is the guide milestone projected
   onto it by Algorithm 1 (IK, then the physics-constrained IK repair) and checked with the frozen
   ``climb_core.feasibility`` check (the end-unloaded limb removed too, as the primitive needs).
3. ``primitive_adaptation`` -> :func:`adapt`: Adapt-Primitive under the multi-step search with
   backtracking (:func:`planner_node.climb_planner.plan_climb`, or
   :func:`planner_node.descend.up_and_down` with ``descend``), from the request's ``start`` when
   it replans from a measured state (:func:`planner_node.replan.measured_start`). It may change
   holds (later attempts sample around the seed holds); the summary counts the seed holds it
   changed. Called with the same request it plans exactly what ``climb_coordinator.climb``
   plans in process (same library, settings, seed and start).

Every error names the field and the rule (:class:`~climb_core.errors.SpecError`), or the
violated constraint (:class:`~climb_core.errors.InfeasibleError`).
"""
from __future__ import annotations

import json
import math
import re
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from climb_core.contact import LIMBS, ContactPlan, GuidePath, Stance, WholeBodyPlan
from climb_core.errors import InfeasibleError, SpecError

from .settings import PlannerSettings

#: planning strategies: ``primitives`` (the ladder paper: motion primitives adapted by a
#: multi-step search, ladders only) and ``search`` (the DARPA-tasks paper: free-flyer guide path,
#: best-first contact search, each transition adapted from a primitive where one fits, else a
#: generic contact-body path)
STRATEGIES = ("primitives", "search")
IMPLEMENTED_STRATEGIES = ("primitives", "search")
REQUEST_FIELDS = ("id", "robot", "scenario", "rungs", "seed", "timeout_s", "descend", "strategy", "start",
                  "surface_offsets")
#: a request is a small JSON document (a spec's YAML text and a start configuration fit easily)
MAX_REQUEST_CHARS = 1_000_000
#: no ladder has more rungs (climb_core.ladder's range of ladder.n_rungs)
MAX_RUNGS = 1000

_NAME_RE = re.compile(r"^[A-Za-z0-9_.\-]+$")


@dataclass(frozen=True)
class PlanRequest:
    """A validated plan request (the JSON fields of the `plan/request` topic)."""

    id: str
    robot: str = "g1"
    scenario: str = "default"  # a ladder name of config/ladders/ or the spec's YAML text
    rungs: int = 2  # climbing cycles (the feet end on rung `rungs`)
    seed: int | None = None  # planner seed (None: the planner's parameter)
    timeout_s: float | None = None  # [s] search time limit (None: the planner's parameter)
    descend: bool = False  # climb `rungs` rungs, then climb back down
    strategy: str | None = None  # primitives | search (None: the node's parameter)
    start: dict | None = None  # {"q": [...], "stance": {...}} (plan_io conventions) or None
    #: surface name -> [x, y, z] world translation [m] of a surface found off the scenario's
    #: model during execution (a replan plans with those surfaces moved)
    surface_offsets: dict | None = None
    text: str = ""  # the request verbatim

    def effective_strategy(self, default: str) -> str:
        return self.strategy or default


def request_id_of(text: str) -> str:
    """The ``id`` of a request text, as well as it can be read ("" when it cannot): a malformed
    request's failure status still carries its id when it has one."""
    try:
        data = json.loads(text)
    except (ValueError, TypeError, RecursionError):
        return ""
    value = data.get("id") if isinstance(data, dict) else None
    return value if isinstance(value, str) else ""


def _int(data: dict, key: str, default: Any, low: int, high: int) -> Any:
    v = data.get(key, default)
    if v is None and default is None:
        return None
    if isinstance(v, bool) or not isinstance(v, int) or not low <= v <= high:
        raise SpecError(f"request.{key}", f"must be an integer in [{low}, {high}], got {v!r}"[:300])
    return v


def parse_plan_request(text: Any) -> PlanRequest:
    """A plan request from its JSON text; SpecError(``request.<field>``, rule) when malformed."""
    if not isinstance(text, str):
        raise SpecError("request", f"must be JSON text, got {type(text).__name__}")
    if len(text) > MAX_REQUEST_CHARS:
        raise SpecError("request", f"longer than {MAX_REQUEST_CHARS} characters ({len(text)})")
    try:
        data = json.loads(text)
    except (ValueError, RecursionError) as exc:
        raise SpecError("request", f"not JSON: {exc}"[:300]) from None
    if not isinstance(data, dict):
        raise SpecError("request", f"must be a JSON object, got {type(data).__name__}")
    unknown = sorted(str(k) for k in data if k not in REQUEST_FIELDS)
    if unknown:
        raise SpecError(f"request.{unknown[0]}", f"unknown field (known: {', '.join(REQUEST_FIELDS)})")
    rid = data.get("id")
    if not isinstance(rid, str) or not rid.strip():
        raise SpecError("request.id", f"must be a non-empty string, got {rid!r}")
    robot = data.get("robot", "g1")
    if not isinstance(robot, str) or not _NAME_RE.match(robot):
        raise SpecError("request.robot", f"must be a robot name of config/robots/, got {robot!r}")
    scenario = data.get("scenario", "default")
    if not isinstance(scenario, str) or not scenario.strip():
        raise SpecError("request.scenario", "must be a ladder name of config/ladders/ or the spec's YAML text")
    if "rungs" not in data:
        raise SpecError("request.rungs", "is required (climbing cycles: the feet end on rung `rungs`)")
    # 0 only from a measured `start` in the middle of a cycle: the rest of that cycle
    rungs = _int(data, "rungs", 2, 0 if data.get("start") is not None else 1, MAX_RUNGS)
    seed = _int(data, "seed", None, 0, 2 ** 63 - 1)
    timeout = data.get("timeout_s")
    if timeout is not None:
        if isinstance(timeout, bool) or not isinstance(timeout, (int, float)) or not math.isfinite(timeout) \
                or timeout <= 0:
            raise SpecError("request.timeout_s", f"must be a number > 0 [s] or null, got {timeout!r}")
        timeout = float(timeout)
    descend = data.get("descend", False)
    if not isinstance(descend, bool):
        raise SpecError("request.descend", f"must be true or false, got {descend!r}")
    strategy = data.get("strategy")
    if strategy is not None and strategy not in STRATEGIES:
        raise SpecError("request.strategy", f"must be one of {', '.join(STRATEGIES)} or null, got {strategy!r}")
    start = data.get("start")
    if start is not None:
        if not isinstance(start, dict) or set(start) != {"q", "stance"}:
            raise SpecError("request.start", "must be null or an object with exactly `q` and `stance`")
        q = start["q"]
        if not isinstance(q, list) or not q or not all(
                isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) for x in q):
            raise SpecError("request.start.q", "must be a non-empty list of finite numbers (Pinocchio q)")
        if not isinstance(start["stance"], dict):
            raise SpecError("request.start.stance", "must be a stance object (plan_io: {name, holds: [...]})")
    if descend and start is not None:
        raise SpecError("request.descend", "a climb and back down is planned from the start fixture, not "
                                           "from a measured `start`")
    offsets = data.get("surface_offsets")
    if offsets is not None:
        if not isinstance(offsets, dict):
            raise SpecError("request.surface_offsets", "must be null or an object: surface name -> [x, y, z] [m]")
        for name, d in offsets.items():
            if not isinstance(d, list) or len(d) != 3 or not all(
                    isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) and abs(x) <= 1.0
                    for x in d):
                raise SpecError(f"request.surface_offsets.{name}"[:200],
                                "must be 3 finite numbers [m] (world x, y, z), each within +-1 m")
    return PlanRequest(id=rid, robot=robot, scenario=scenario, rungs=rungs, seed=seed, timeout_s=timeout,
                       descend=descend, strategy=strategy, start=start, surface_offsets=offsets, text=text)


def check_strategy(strategy: str, stage: str = "") -> None:
    """SpecError (field ``strategy``) for an unknown strategy (every stage runs both)."""
    if strategy not in STRATEGIES:
        raise SpecError("strategy", f"must be one of {', '.join(STRATEGIES)}, got {strategy!r}")


# --------------------------------------------------------------------------------------------
# loading a request's problem


def load_request_scenario(text: str):
    """A scenario from a request's ``scenario``: a shipped ladder or scene name, or spec YAML text.
    A file path is refused (a request on a topic must not make a node read files)."""
    from climb_core.ladder import available_ladders, available_scenes, load_scenario

    s = text.strip()
    is_text = "\n" in text or any(c in s for c in ":{[")
    if not is_text:
        known = available_ladders() + available_scenes()
        if not _NAME_RE.match(s) or s.lower().endswith((".yaml", ".yml")) or s not in known:
            raise SpecError("request.scenario", f"no ladder or scene named {s!r} (known: {', '.join(known)}); "
                                                f"or give the spec's YAML text"[:400])
    try:
        return load_scenario(text if is_text else s)
    except SpecError as exc:
        raise SpecError(f"request.scenario.{exc.field}", exc.rule) from None


def check_request(request: PlanRequest) -> None:
    """The checks of a request that need no model (robot name, scenario spec): fast enough to run
    as it arrives, so that a malformed request is refused with its field even while busy."""
    from climb_core.robot import available_robots

    if request.robot not in available_robots():
        raise SpecError("request.robot", f"unknown robot {request.robot!r} (available: "
                                         f"{', '.join(available_robots())})")
    scenario = load_request_scenario(request.scenario)
    if scenario.ladder is None:  # a scene: its goal, not rungs, ends the climb
        return
    n = int(scenario.ladder.n_rungs)
    if request.rungs > n:
        raise SpecError("request.rungs", f"must be <= the ladder's {n} rungs (the feet end on rung `rungs`), "
                                         f"got {request.rungs}")


@dataclass
class Problem:
    """What every stage needs for one request: models, library and settings."""

    request: PlanRequest
    robot: Any
    scenario: Any
    env: Any
    library: Any
    settings: PlannerSettings
    start: tuple[np.ndarray, Stance] | None = None  # the request's start (measured, not projected)


def load_problem(request: PlanRequest, settings: PlannerSettings) -> Problem:
    """Robot, ladder, primitive library and start of a request (SpecError naming the field)."""
    from climb_core.environment import build_environment
    from climb_core.robot import load_robot

    from .plan_io import stance_from_dict
    from .primitives import load_library

    check_request(request)
    try:
        robot = load_robot(request.robot)
    except SpecError as exc:
        raise SpecError(f"request.robot.{exc.field}", exc.rule) from None
    scenario = load_request_scenario(request.scenario)
    try:
        env = build_environment(scenario)
    except SpecError as exc:
        raise SpecError(f"request.scenario.{exc.field}", exc.rule) from None
    if request.surface_offsets:
        try:
            env = env.with_surface_offsets(request.surface_offsets)
        except SpecError as exc:
            raise SpecError(f"request.{exc.field}", exc.rule) from None
    from .settings import settings_for_scenario

    settings = settings_for_scenario(settings, scenario)  # a scene's / stairs' overrides, the file's own
    p = settings.planning
    library = load_library(robot.config.name, p.strategy, p.primitives_dir, nq=robot.model.nq)
    start = None
    if request.start is not None:
        q = np.asarray(request.start["q"], dtype=float)
        if q.shape != (robot.model.nq,):
            raise SpecError("request.start.q", f"must have nq = {robot.model.nq} entries for robot "
                                               f"{robot.config.name}, got {q.shape[0]}")
        try:
            stance = stance_from_dict(request.start["stance"], "request.start.stance")
        except SpecError:
            raise
        except (TypeError, ValueError, KeyError) as exc:  # Stance refuses a limb held twice, ...
            raise SpecError("request.start.stance", f"malformed stance: {exc}"[:300]) from None
        for i, h in enumerate(stance.holds):
            where = f"request.start.stance.holds[{i}]"
            if h.limb not in LIMBS:
                raise SpecError(f"{where}.limb", f"must be one of {', '.join(LIMBS)}, got {h.limb!r}")
            if not h.points or not (np.isfinite(h.positions).all() and np.isfinite(h.normals).all()):
                raise SpecError(f"{where}.points", "needs at least one point, with finite positions and normals")
            if not (math.isfinite(h.friction) and h.friction > 0) or not (math.isfinite(h.grip_force_limit)
                                                                          and h.grip_force_limit >= 0):
                raise SpecError(where, "friction must be > 0 and grip_force_limit >= 0, both finite")
            if h.env_surface not in env.surfaces:
                raise SpecError(f"request.start.stance.holds[{i}].env_surface",
                                f"no surface {h.env_surface!r} in scenario {env.name!r}")
        start = (q, stance)
    return Problem(request, robot, scenario, env, library, settings, start)


def warm_up(settings: PlannerSettings, robot: str = "g1", scenario: str = "default") -> None:
    """Load what a first request needs (the robot's model, the default ladder, the primitive library,
    the start fixture) so that the first request's stage time is planning, not loading."""
    problem = load_problem(PlanRequest(id="warm-up", robot=robot, scenario=scenario, rungs=1), settings)
    start_state(problem)


def start_state(problem: Problem) -> tuple[np.ndarray, Stance]:
    """(q, stance) the climb starts from: the request's measured start projected onto its stance
    (:func:`planner_node.replan.measured_start`, as the adaptation and the in-process replanner do;
    InfeasibleError ``start:<constraint>`` when it does not project), else the library's start
    fixture."""
    if problem.start is not None:
        from .replan import measured_start

        q_meas, stance = problem.start
        try:
            return measured_start(problem.robot, problem.env, q_meas, stance, problem.settings), stance
        except InfeasibleError as exc:
            raise InfeasibleError(f"start:{exc.constraint}", exc.detail) from None
    from climb_core import fixtures

    stance, q = fixtures.get(problem.library.initial_fixture, problem.robot, problem.env)
    return q, stance


# --------------------------------------------------------------------------------------------
# the seed sequence: the primitive sequence on the actual rungs


@dataclass(frozen=True)
class SeedStep:
    """One stance (or CoM transfer) of the primitive sequence on the actual ladder."""

    primitive: str  # the library primitive whose end this is ("descend:<name>" on the way down)
    type: str  # the primitive's transition name (mount, place_foot, com_to_foot, ...)
    kind: str  # limb | com | descend
    moving_limb: str  # limb primitives: the limb placed ("" otherwise)
    stance: Stance  # the stance at the end of the primitive (seed holds)
    q_key: np.ndarray  # the primitive's key configuration (end way-point) moved onto this ladder
    unload: tuple[str, ...] = ()  # limbs that must be removable at the end (the primitive's end_unload)


def seed_sequence(problem: Problem) -> tuple[np.ndarray, Stance, list[SeedStep]]:
    """(q0, stance0, steps): the sub-task sequence of :func:`plan_climb` with attempt 0's seed holds
    (a primitive whose limb is already on its seed hold adds no step, as in the search).
    InfeasibleError ``no_target`` when a seed hold has no rung (the ladder is too short)."""
    from .adapt import AdaptContext, ClimbState, SKIP, _shift_base, sample_target_hold, stance_anchor
    from .climb_planner import subtask_sequence
    from .primitives import point_to_world, to_world

    q0, stance0 = start_state(problem)
    lib = problem.library
    ctx = AdaptContext(problem.robot, problem.env, lib, problem.settings)
    subtasks = subtask_sequence(lib, stance0, problem.request.rungs, problem.env)
    rng = np.random.default_rng(0)  # attempt 0 draws nothing
    state = ClimbState(q0, stance0)
    steps: list[SeedStep] = []
    for prim in subtasks:
        stance = state.stance
        moving = ""
        if prim.is_limb:
            try:
                hold = sample_target_hold(ctx, prim, state, 0, rng)
            except SpecError as exc:  # as Adapt-Primitive says it: this library cannot hold that surface
                raise InfeasibleError(f"hold:{exc.field}", f"{prim.name}: {exc}") from None
            if hold is None:
                raise InfeasibleError("no_target", f"{prim.name}: no rung for the seed hold of {prim.limb} (the "
                                                   f"ladder has {problem.env.n_rungs} rungs)")
            if isinstance(hold, str) and hold == SKIP:
                continue
            stance = Stance(stance.with_hold(hold).holds, name=prim.name)
            moving = prim.limb
        else:
            stance = Stance(stance.holds, name=prim.name)
        if len(prim.waypoints):
            d = stance_anchor(stance) - point_to_world(problem.env, prim.anchor_end)
            q_key = _shift_base(to_world(problem.env, prim.waypoints[-1]), d)
        else:
            q_key = state.q.copy()
        steps.append(SeedStep(prim.name, prim.type, "limb" if prim.is_limb else "com", moving, stance, q_key,
                              tuple(prim.end_unload)))
        state = ClimbState(q_key, stance)
    if problem.request.descend:
        steps = steps + descent_steps(steps, stance0, q0)
    return q0, stance0, steps


def descent_steps(up: list[SeedStep], stance0: Stance, q0: np.ndarray) -> list[SeedStep]:
    """The way back down (:func:`planner_node.descend.descent_plan`): the stances of the cycles
    after the mount, in reverse order, ending at the stance the mount reached."""
    from .descend import MOUNT_PRIMITIVES

    mounts = [i for i, s in enumerate(up) if s.type in MOUNT_PRIMITIVES]
    first = mounts[-1] + 1 if mounts else 0
    before = [(stance0, q0)] + [(s.stance, s.q_key) for s in up]
    out = []
    for i in range(len(up) - 1, first - 1, -1):
        stance, q = before[i]  # the state before up[i]: where its reverse ends
        out.append(SeedStep(f"descend:{up[i].primitive}", up[i].type, "descend", up[i].moving_limb,
                            Stance(stance.holds, name=f"descend:{up[i].primitive}"), q.copy(), up[i].unload))
    return out


# --------------------------------------------------------------------------------------------
# stage 1: guide path


@dataclass
class StageResult:
    """A stage's product and the summary its `done` status carries (JSON)."""

    product: Any
    summary: dict = field(default_factory=dict)


def strategy_of(problem: Problem, default: str) -> str:
    """The request's strategy (else ``default``, the node's parameter); SpecError when the scenario
    has no ladder and the strategy is not ``search`` (the primitive libraries climb ladders only)."""
    from climb_core.scene import require_search_strategy

    strategy = problem.request.effective_strategy(default)
    check_strategy(strategy, "")
    require_search_strategy(problem.scenario, strategy)
    return strategy


def search_start(problem: Problem) -> tuple[np.ndarray, Stance]:
    """(q, stance) the ``search`` strategy starts from: the request's measured start projected
    onto its stance (as :func:`start_state`), else standing on the ground (both feet) at the
    scenario's start pose."""
    if problem.start is not None:
        return start_state(problem)
    from climb_core import fixtures, holds
    from climb_core.contact import FEET

    robot, env = problem.robot, problem.env
    _, q = fixtures.get("standing", robot, env)
    q = env.place_at_start(q)
    stance = Stance(tuple(holds.hold_from_configuration(robot, env, q, limb, "ground") for limb in FEET),
                    name="standing")
    return q, stance


def _seed(problem: Problem) -> int:
    return problem.settings.planning.seed if problem.request.seed is None else int(problem.request.seed)


def guide_path_search(problem: Problem) -> StageResult:
    """``strategy: search``: the free-flyer guide path (:mod:`planner_node.guide_path`, RRT-Connect)
    from :func:`search_start` to the scene's goal, or up the ladder one milestone per rung."""
    from .guide_path import plan_for_environment

    t0 = time.perf_counter()
    q0, _ = search_start(problem)
    env = problem.env
    rungs = None if getattr(env, "goal", None) is not None else problem.request.rungs
    res = plan_for_environment(problem.robot, env, q0, rungs=rungs, params=problem.settings.guide_path,
                               seed=_seed(problem), time_limit_s=problem.request.timeout_s)
    summary = {"strategy": "search", "n_milestones": len(res.path.milestones),
               "goal": "scene" if rungs is None else f"{rungs} rungs", **res.stats.as_dict(),
               "time_s": round(time.perf_counter() - t0, 3)}
    return StageResult(res.path, summary)


def guide_path(problem: Problem, projection_iterations: int = 30, strategy: str = "primitives") -> StageResult:
    """The guide path of the request's strategy. ``primitives``: the milestones of the primitive
    sequence: the start configuration, then each primitive's key configuration moved onto the
    actual ladder and projected onto its seed holds (a milestone the projection cannot bring onto
    the holds stays where the move put it; counted). ``search``: :func:`guide_path_search`."""
    if strategy_of(problem, strategy) == "search":
        return guide_path_search(problem)
    from .adapt import AdaptContext, ContactProjector

    t0 = time.perf_counter()
    q0, _, steps = seed_sequence(problem)
    ctx = AdaptContext(problem.robot, problem.env, problem.library, problem.settings)
    milestones = [q0]
    projected = 0
    for s in steps:
        q = ContactProjector(ctx, s.stance, s.q_key, max_iterations=projection_iterations)(s.q_key)
        if q is not None:
            projected += 1
        milestones.append(s.q_key.copy() if q is None else q)
    path = GuidePath(robot=problem.robot.config.name, environment=problem.env.name,
                     joint_names=list(problem.robot.joint_names), milestones=milestones)
    summary = {"strategy": "primitives", "n_milestones": len(milestones), "n_projected": projected,
               "primitives": [s.primitive for s in steps], "time_s": round(time.perf_counter() - t0, 3)}
    return StageResult(path, summary)


# --------------------------------------------------------------------------------------------
# stage 2: contact search


def _stance_key(stance: Stance) -> list[tuple[str, str, tuple]]:
    return sorted((h.limb, h.env_surface, tuple(np.round(h.centre, 3))) for h in stance.holds)


def contact_search_search(problem: Problem, path: GuidePath, banned=(), time_limit_s: float | None = None
                          ) -> StageResult:
    """``strategy: search``: the best-first multi-contact search (:mod:`planner_node.contact_search`)
    from :func:`search_start` through the guide path's milestones, without the ``banned``
    transitions. InfeasibleError ``contact_search:<reason>`` when a milestone is not reached."""
    import dataclasses

    from .contact_search import search
    from .settings import walked

    t0 = time.perf_counter()
    q0, stance0 = search_start(problem)
    params = problem.settings.contact_search
    limit = time_limit_s if time_limit_s is not None else problem.request.timeout_s
    if limit is not None:
        params = dataclasses.replace(params, time_limit_s=float(limit))
    res = search(problem.robot, problem.env, q0, stance0, path, params, pcik_params=problem.settings.pcik,
                 banned=banned, walked=walked(problem.scenario, problem.settings))
    summary = {"strategy": "search", "n_stances": len(res.plan.stances), "moves": res.moves,
               **res.stats.as_dict(), "time_s": round(time.perf_counter() - t0, 3)}
    return StageResult(res.plan, summary)


def contact_search(problem: Problem, path: GuidePath, *, restarts: int = 3, require_feasible: bool = False,
                   seed: int = 0, strategy: str = "primitives") -> StageResult:
    """``strategy: search``: :func:`contact_search_search`. ``primitives``: the stance sequence of
    the library's seed holds, each with its transition configuration:
    the guide milestone projected onto the stance (Algorithm 1 with ``restarts`` perturbed
    restarts and the physics-constrained IK repair), checked with the frozen feasibility check.

    A stance whose configuration is not feasible stays in the plan (the adaptation samples other
    holds around it) and is listed in the summary, unless ``require_feasible``: then
    InfeasibleError names the stance and the constraint. SpecError when the guide path does not
    belong to this request (robot, joints, number of milestones)."""
    if strategy_of(problem, strategy) == "search":
        return contact_search_search(problem, path)
    from climb_core import feasibility

    from .adapt import AdaptContext, project
    from .pcik import check_with_exclusions

    t0 = time.perf_counter()
    robot = problem.robot
    if path.robot != robot.config.name:
        raise SpecError("guide_path.robot", f"must be the request's robot {robot.config.name!r}, got {path.robot!r}")
    if list(path.joint_names) != list(robot.joint_names):
        raise SpecError("guide_path.joint_names", f"must be the joints of robot {robot.config.name}")
    q0, stance0, steps = seed_sequence(problem)
    if len(path.milestones) != len(steps) + 1:
        raise SpecError("guide_path.milestones", f"the primitive sequence of this request has {len(steps) + 1} "
                                                 f"milestones, the guide path {len(path.milestones)}")
    ctx = AdaptContext(robot, problem.env, problem.library, problem.settings)
    frozen = ctx.frozen_cfg
    stances = [stance0]
    configurations = [np.asarray(path.milestones[0], dtype=float).copy()]
    report = [{"index": 0, "primitive": "start", **_check_summary(feasibility.check(
        robot, problem.env, configurations[0], stance0, frozen))}]
    for i, s in enumerate(steps, start=1):
        rng = np.random.default_rng(np.random.SeedSequence([int(seed) & 0xFFFFFFFF, i]))
        unload = [u for u in s.unload if u and s.stance.hold(u) is not None]
        proj = project(ctx, np.asarray(path.milestones[i], dtype=float), s.stance, rng, unload=unload,
                       restarts=restarts)
        if proj.q is not None:
            q = proj.q
            entry = _check_summary(feasibility.check(robot, problem.env, q, s.stance, frozen))
            for u in unload:  # the primitive ends with this limb removable
                if entry["feasible"]:  # the limb still touches its surface: that pair is the contact
                    res = check_with_exclusions(robot, problem.env, q, s.stance.without(u), frozen,
                                                [(u, s.stance.hold(u).env_surface)])
                    if not res.feasible:
                        entry = _check_summary(res)
                        entry["constraint"] = f"unload:{u}:{entry['constraint']}"
        else:
            q = np.asarray(path.milestones[i], dtype=float).copy()
            entry = {"feasible": False, "constraint": proj.failure or "projection"}
        report.append({"index": i, "primitive": s.primitive, **entry})
        stances.append(s.stance)
        configurations.append(q)
    infeasible = [r for r in report if not r["feasible"]]
    if require_feasible and infeasible:
        r = infeasible[0]
        raise InfeasibleError(str(r["constraint"]), f"stance {r['index']} ({r['primitive']}) of the seed holds "
                                                    f"is not feasible ({len(infeasible)} of {len(report)})")
    plan = ContactPlan(robot=robot.config.name, environment=problem.env.name, joint_names=list(robot.joint_names),
                       stances=stances, transition_configurations=configurations)
    summary = {"strategy": "primitives", "n_stances": len(stances), "n_feasible": len(report) - len(infeasible),
               "infeasible": [{"index": r["index"], "primitive": r["primitive"], "constraint": r["constraint"]}
                              for r in infeasible],
               "time_s": round(time.perf_counter() - t0, 3)}
    return StageResult(plan, summary)


def _check_summary(res) -> dict:
    from .adapt import failure_name

    return {"feasible": bool(res.feasible), "constraint": "" if res.feasible else failure_name(res),
            "load_ratio": round(float(res.load_ratio), 3) if math.isfinite(res.load_ratio) else None}


# --------------------------------------------------------------------------------------------
# stage 3: adaptation (multi-step search)


def adapt_search(problem: Problem, contact_plan: ContactPlan, on_progress=None, timeout_s: float | None = None,
                 previous=None):
    """``strategy: search``: each transition of the searched contact plan adapted from the library
    primitive that fits it, else a generic contact-body path
    (:func:`planner_node.climb_planner.plan_from_contact_plan`): ``(ClimbPlanResult, summary)``."""
    from .climb_planner import plan_from_contact_plan

    req = problem.request
    res = plan_from_contact_plan(problem.robot, problem.env, contact_plan, library=problem.library,
                                 settings=problem.settings, seed=req.seed,
                                 timeout_s=req.timeout_s if timeout_s is None else timeout_s,
                                 on_progress=on_progress, previous=previous)
    summary = res.summary()
    summary.update(request_id=req.id, strategy="search", rungs_requested=req.rungs if problem.env.ladder else 0)
    return res, summary


def search_and_adapt(problem: Problem, path: GuidePath, on_progress=None):
    """Contact search, adaptation and :func:`repair` (in process, as the graph's two stages do):
    ``(contacts StageResult, ClimbPlanResult, adaptation summary)``, the contact summary with
    ``repairs``. InfeasibleError ``contact_search:<reason>`` when the search finds no sequence."""
    t0 = time.perf_counter()
    contacts = contact_search_search(problem, path, time_limit_s=_time_left(problem, t0))
    res, summary = adapt_search(problem, contacts.product, on_progress, timeout_s=_time_left(problem, t0))
    return repair(problem, path, contacts, res, summary, on_progress, t0)


def _time_left(problem: Problem, t0: float) -> float:
    req = problem.request
    limit = req.timeout_s if req.timeout_s is not None else problem.settings.planning.timeout_s
    return max(1.0, float(limit) - (time.perf_counter() - t0))


def repair(problem: Problem, path: GuidePath, contacts: StageResult, res, summary: dict, on_progress=None,
           t0: float | None = None):
    """Repair of a searched plan whose adaptation is stuck at a transition (its backtrack window,
    ``contact_path.backtrack_window``, exhausted: no state its predecessors reach makes that
    transition's whole-body path): the contact search runs again without that transition (the
    stance pair it changes), and the new plan is adapted, up to ``contact_search.repair_rounds``
    times, within the request's time limit from ``t0`` (``planning.timeout_s`` without one). The
    ladder paper backtracks inside one primitive sequence; a searched sequence has other stances
    to offer, which only the search knows. The adaptation of a repaired plan keeps the sub-tasks
    it shares with the stuck one (``previous`` of
    :func:`planner_node.climb_planner.plan_from_contact_plan`). A repair search that finds no
    sequence leaves the last plan standing (its reason in the repair's ``search``).
    ``(contacts, res, summary)`` of the last round, ``contacts.summary["repairs"]``: per repair,
    the transition given up, its move, the sub-task and the constraint that stopped it."""
    from .contact_search import banned_transition, moves_of

    t0 = time.perf_counter() if t0 is None else t0
    banned: list[tuple] = []
    repairs: list[dict] = []
    resolution = problem.settings.contact_search.key_resolution
    while True:
        contacts.summary["repairs"] = repairs
        report = res.report
        if (res.success or report is None or not report.stuck
                or len(repairs) >= problem.settings.contact_search.repair_rounds):
            return contacts, res, summary
        pair = res.contact_steps[report.deepest].pair
        repairs.append({"transition": pair, "move": moves_of(contacts.product)[pair],
                        "subtask": res.subtasks[report.deepest], "constraint": res.failure_constraint,
                        "time_s": round(time.perf_counter() - t0, 1)})
        banned.append(banned_transition(contacts.product, pair, resolution))
        try:
            again = contact_search_search(problem, path, banned=banned, time_limit_s=_time_left(problem, t0))
        except InfeasibleError as exc:
            repairs[-1]["search"] = str(exc)  # no sequence without it: the last plan stands, stuck
            return contacts, res, summary
        contacts = again
        res, summary = adapt_search(problem, contacts.product, on_progress, timeout_s=_time_left(problem, t0),
                                    previous=res)


def adapt_and_repair(problem: Problem, contact_plan: ContactPlan | None = None, on_progress=None,
                     strategy: str = "primitives"):
    """The adaptation stage of the graph: :func:`adapt`, and a searched plan whose adaptation is
    stuck :func:`repair`-ed here (the guide path planned again for the request - deterministic,
    the guide_path node's - and the contact search re-run without the stuck transitions), so
    that the graph plans what the in-process :func:`search_and_adapt` plans. The summary gains
    ``repairs``. ``(ClimbPlanResult, summary)``."""
    t0 = time.perf_counter()
    res, summary = adapt(problem, contact_plan, on_progress, strategy)
    if strategy_of(problem, strategy) != "search" or res.success or res.report is None or not res.report.stuck:
        return res, summary
    path = guide_path(problem, strategy="search").product
    contacts, res, summary = repair(problem, path, StageResult(contact_plan, {}), res, summary, on_progress, t0)
    summary["repairs"] = contacts.summary["repairs"]
    return res, summary


def adapt(problem: Problem, contact_plan: ContactPlan | None = None, on_progress=None, strategy: str = "primitives"):
    """``strategy: search``: :func:`adapt_search`. ``primitives``: Adapt-Primitive under the
    multi-step search for the request: ``(ClimbPlanResult, summary)``.
    The result is what the in-process climb plans for the same request. ``contact_plan``: the
    contact search's seed stances, compared with the holds the search chose (summary
    ``seed_holds_changed``). InfeasibleError ``start:...`` when a measured start does not project
    onto its stance."""
    if strategy_of(problem, strategy) == "search":
        if contact_plan is None:
            raise SpecError("contact_plan", "strategy 'search' adapts the contact search's plan: none given")
        return adapt_search(problem, contact_plan, on_progress)
    from .climb_planner import plan_climb
    from .descend import up_and_down

    req = problem.request
    start = None
    projection_mm = None
    if problem.start is not None:
        start = start_state(problem)
        projection_mm = round(float(np.linalg.norm(start[0][:3] - problem.start[0][:3])) * 1e3, 2)
    planner = up_and_down if req.descend else plan_climb
    # library None: plan_climb ranks the strategy's libraries by their reference ladders (the sweep's)
    res = planner(problem.robot, problem.env, req.rungs, settings=problem.settings,
                  start=start, seed=req.seed, timeout_s=req.timeout_s, on_progress=on_progress)
    summary = res.summary()
    summary["request_id"] = req.id
    summary["strategy"] = "primitives"
    summary["rungs_requested"] = req.rungs
    if req.descend and "descent_start" in res.stats:
        summary["descent_start_transition"] = int(res.stats["descent_start"])
    if projection_mm is not None:
        summary["start_projection_mm"] = projection_mm
    if contact_plan is not None and res.plan is not None:
        summary["seed_holds_changed"] = holds_changed(contact_plan, res.plan)
    return res, summary


def holds_changed(contact_plan: ContactPlan, plan: WholeBodyPlan, tol: float = 0.01) -> int | None:
    """How many stances of ``plan`` hold differently from the contact plan's seed stances (a hold
    on another surface or moved more than ``tol`` [m]); None when the sequences do not pair up."""
    visited = [plan.initial_stance] + [t.target_stance for t in plan.transitions]
    if len(visited) != len(contact_plan.stances):
        return None
    n = 0
    for a, b in zip(visited, contact_plan.stances):
        ka, kb = _hold_map(a), _hold_map(b)
        if set(ka) != set(kb) or any(ka[k][0] != kb[k][0] or np.linalg.norm(ka[k][1] - kb[k][1]) > tol for k in ka):
            n += 1
    return n


def _hold_map(stance: Stance) -> dict[str, tuple[str, np.ndarray]]:
    return {h.limb: (h.env_surface, h.centre) for h in stance.holds}
