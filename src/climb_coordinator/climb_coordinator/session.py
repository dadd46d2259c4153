"""The climb as a session over three ports (no ROS, no simulator here).

    session = ClimbSession(request, settings, plans=<PlanSource>, executor=<Executor>, judge=<Judge>)
    summary = session.run()      # the JSON summary of shared/specs/ladder_spec.md ("Results")

- **PlanSource** ``plan(steps, start=None) -> PlanOutcome``: a plan of ``steps`` climbing cycles
  from the start fixture, or from ``start = (q measured, stance held)`` (a replan).
- **Executor**: ``start(plan)`` hands a plan over, ``run(budget_s, stop)`` executes until the FSM
  is in one of ``stop`` (after picking the plan), a fall, a fault (dead node, controller failure,
  cancel) or ``budget_s`` of sim time; ``settle(duration_s)``, ``measured_q()``, ``hold()`` and
  ``report()`` (timing figures for the summary).
- **Judge** ``feet_rungs()``, ``grasps()``, ``fell()``: the simulator's ground truth (in process:
  PyBullet's contact points; in the graph: the bridge's ``sim/contacts`` topic).

Two adapters implement the ports: in process (climb_coordinator.climb: planner library,
InProcessRunner, judge.py against the backend) and over ROS (climb_coordinator.coordinator_node:
plan/request -> ... -> whole_body_plan, controller/state, sim/contacts). The decisions are here, ONE
code path for both: request checks, when to replan (``plan_cycles`` at a hold, ``replan_needed``
from the measured state, bounded; a controller ``failure`` waited on for
``failure_recovery_s`` in case the controller recovers into ``replan_needed``), the scenario's
drops triggered by a transition (``Executor.throw``), how a run ends and the summary.
"""
from __future__ import annotations

import functools
from dataclasses import dataclass, field
from typing import Any, Callable, Protocol

import numpy as np

from climb_core.contact import FEET, Stance, WholeBodyPlan
from climb_core.errors import SpecError

MODES = ("qp", "compliance")
#: FSM states at which a run stops and the session decides
STOP_STATES = ("hold", "failure", "replan_needed")
#: replan attempts after ``replan_needed`` (a guarded search that found no contact) per climb
MAX_FORCED_REPLANS = 2
#: planning strategies of a climb (planner_node.pipeline.STRATEGIES)
STRATEGIES = ("primitives", "search")
#: stance fixtures a climb may start in (climb_core.fixtures)
START_POSTURES = ("standing", "ladder_4_contacts")
#: [m/s] a scene's goal counts when the base moves slower than this over the settle time
#: (scene_spec.md, Results)
GOAL_SPEED_MAX = 0.02


@dataclass
class ClimbRequest:
    ladder: Any = "default"  # name in config/ladders/, a spec file, YAML text or a Scenario
    robot: str = "g1"
    rungs: int = 2  # climbing cycles after the mount (feet end on rung N)
    mode: str = "qp"  # qp | compliance
    out_dir: Any = None  # bag (and plots) go here; None: no files (in process)
    seed: int | None = None  # planner seed (default: config/planner.yaml)
    bag: bool = True
    snapshots: int = 0  # film strip frames to capture (0: none)
    plan_timeout_s: float | None = None
    controller_overrides: dict = field(default_factory=dict)
    #: dotted sim_bridge params of the in-process simulator (e.g. ``{"sensors.ft_noise_percent": 2.0}``);
    #: through the graph the bridge node's own parameters apply
    bridge_overrides: dict = field(default_factory=dict)
    max_transitions: int | None = None  # execute only the plan's first k transitions (None: all)
    descend: bool = False  # climb `rungs` rungs, then climb back down to the ground
    plan_cycles: int | None = None  # plan this many cycles at a time, the next ones from the reached state
    #: 1: every command acts one control period late (the bridge's lockstep.command_delay_ticks);
    #: the controller then computes each command for the state one period ahead
    #: (actuation_latency_s), unless controller_overrides set it
    command_delay_ticks: int = 0
    max_forced_replans: int = MAX_FORCED_REPLANS
    #: primitives (the ladder paper: the library's primitive sequence adapted) | search (the
    #: DARPA-tasks paper: free-flyer guide path, best-first contact search, then the adaptation)
    #: | "" (chosen for the scenario: :func:`with_chosen_strategy`)
    strategy: str = ""
    strategy_reason: str = ""  # why the strategy was chosen (set by with_chosen_strategy)
    #: the stance fixture the robot starts in (climb_core.fixtures: standing, ladder_4_contacts, ...);
    #: "" = the primitive library's start fixture (strategy primitives) or standing (search)
    start_posture: str = ""


def ladder_name(ladder: Any) -> str:
    if isinstance(ladder, str):
        return ladder if "\n" not in ladder else "custom"
    return getattr(ladder, "name", "") or "custom"


def base_summary(req: ClimbRequest) -> dict:
    out = {"success": False, "failure_reason": "", "robot": req.robot, "ladder": ladder_name(req.ladder),
           "rungs_requested": int(req.rungs), "rungs_reached": 0, "plan_time_s": 0.0, "n_stances": 0,
           "sim_time_s": 0.0, "fell": False, "control_tick_ms": None, "bag": "", "mode": req.mode}
    if req.strategy_reason:
        out.update(strategy=req.strategy, strategy_reason=req.strategy_reason)
    return out


def with_chosen_strategy(req: ClimbRequest) -> ClimbRequest:
    """``req`` with its strategy chosen (:func:`planner_node.settings.choose_strategy`) when it names none, the reason in
    ``strategy_reason`` (the summary's); a scenario that does not load keeps ``primitives`` (the
    request checks then name the spec's broken field)."""
    import dataclasses

    from climb_core.ladder import load_scenario
    from planner_node.settings import choose_strategy

    if req.strategy:
        return req
    try:
        strategy, reason = choose_strategy(load_scenario(req.ladder))
    except SpecError:
        return dataclasses.replace(req, strategy="primitives")
    return dataclasses.replace(req, strategy=strategy, strategy_reason=reason)


def validate(req: ClimbRequest) -> None:
    """The request's own fields (SpecError naming the field and the rule)."""
    if req.mode not in MODES:
        raise SpecError("mode", f"must be one of {', '.join(MODES)}, got {req.mode!r}")
    if isinstance(req.rungs, bool) or not isinstance(req.rungs, int) or req.rungs < 1:
        raise SpecError("rungs", f"must be an integer >= 1, got {req.rungs!r}")
    if req.snapshots < 0:
        raise SpecError("snapshots", f"must be >= 0, got {req.snapshots}")
    if req.max_transitions is not None and req.max_transitions < 1:
        raise SpecError("max_transitions", f"must be >= 1 or None, got {req.max_transitions}")
    if req.plan_cycles is not None:
        if isinstance(req.plan_cycles, bool) or not isinstance(req.plan_cycles, int) or req.plan_cycles < 1:
            raise SpecError("plan_cycles", f"must be an integer >= 1 or None, got {req.plan_cycles!r}")
        if req.descend:
            raise SpecError("plan_cycles", "replanning during a climb and back down is not supported: use one")
    if isinstance(req.command_delay_ticks, bool) or req.command_delay_ticks not in (0, 1):
        raise SpecError("command_delay_ticks", f"must be 0 or 1, got {req.command_delay_ticks!r}")
    if req.strategy and req.strategy not in STRATEGIES:
        raise SpecError("strategy", f"must be empty (chosen for the scenario) or one of {', '.join(STRATEGIES)}, "
                                    f"got {req.strategy!r}")
    if req.start_posture and req.start_posture not in START_POSTURES:
        raise SpecError("start_posture", f"must be empty or one of {', '.join(START_POSTURES)}, "
                                         f"got {req.start_posture!r}")
    if req.strategy == "primitives" and req.start_posture not in ("", "standing"):
        # the primitive libraries start standing (their mount); measured, a library cycle planned
        # from ladder_4_contacts (grasps 0.30 m apart, the library's 0.24 m) met rung 6 early with
        # the left hand, 4.4 cm off its plan
        raise SpecError("start_posture", "the primitives strategy starts standing (its library's mount); "
                                         f"a start on the ladder needs strategy search, got {req.start_posture!r}")
    if req.strategy == "search" and (req.descend or req.plan_cycles is not None):
        raise SpecError("strategy", "a searched climb is planned in one piece and upward: no descend, no plan_cycles")
    if req.bridge_overrides:
        from sim_bridge.params import load_bridge_params

        load_bridge_params(**req.bridge_overrides)  # SpecError naming the parameter and its rule


@functools.lru_cache(maxsize=8)
def _hands_above_feet_height(robot: str, strategy: str, primitives_dir: str) -> float:
    from planner_node.primitives import load_library

    return float(load_library(robot, strategy, primitives_dir or None).hands_above_feet_height)


def check_request(req: ClimbRequest) -> Any:
    """Everything a climb request can be refused for, checked at once (no model loaded):
    the request's fields, an unknown robot, an invalid scenario spec (field and rule), a target
    rung the ladder cannot give that robot (its hands hold a rung ``hands_above_feet_height``
    above the feet); a request naming no strategy is checked with the one chosen for it
    (:func:`with_chosen_strategy`). Returns the Scenario; SpecError(field, rule) on a refusal."""
    from climb_core.environment import build_environment
    from climb_core.ladder import load_scenario
    from climb_core.robot import available_robots

    req = with_chosen_strategy(req)
    validate(req)
    known = available_robots()
    if req.robot not in known:
        raise SpecError("robot", f"unknown robot {req.robot!r} (known: {', '.join(known)})")
    scenario = load_scenario(req.ladder)
    if getattr(scenario, "ladder", None) is None:  # a scene: its goal ends the climb, not rungs
        if req.strategy != "search":
            raise SpecError("strategy", "a scene without a ladder is planned by the contact search: must be "
                                        f"search, got {req.strategy!r}")
        if req.start_posture not in ("", "standing"):
            raise SpecError("start_posture", "a scene starts standing at its start pose, got "
                                             f"{req.start_posture!r}")
        return scenario
    if req.strategy == "search":  # the search chooses the holds (rails, rungs): only the rungs bound the climb
        n = int(scenario.ladder.n_rungs)
        if req.rungs > n:
            raise SpecError("rungs", f"must be <= the ladder's {n} rungs (the feet end on rung `rungs`), got {req.rungs}")
        return scenario
    from planner_node.settings import load_settings

    p = load_settings().planning
    try:
        gap = _hands_above_feet_height(req.robot, p.strategy, str(p.primitives_dir or ""))
    except SpecError as exc:
        raise SpecError("robot", f"robot {req.robot!r} cannot climb: {exc}") from None
    env = build_environment(scenario)
    tops = np.array([env.surfaces[f"rung_{k}"].top_z for k in range(1, env.n_rungs + 1)])
    spacing = float(np.min(np.diff(tops))) if len(tops) > 1 else 0.25
    # the highest rung both feet can stand on: a rung must be left for the hands above it
    top_feet = 0
    for k in range(1, env.n_rungs + 1):
        if tops[k - 1] + gap <= tops[-1] + 0.5 * spacing:
            top_feet = k
    if req.rungs > top_feet:
        raise SpecError("rungs", f"must be <= {top_feet} on this ladder for {req.robot}: its hands hold a rung "
                                 f"{gap:.2f} m above its feet and the ladder has {env.n_rungs} rungs, got {req.rungs}")
    return scenario


# ------------------------------------------------------------------------------------------ ports


@dataclass
class PlanOutcome:
    success: bool
    plan: WholeBodyPlan | None
    plan_time_s: float = 0.0  # [s] wall time
    n_stances: int = 0
    failure: str = ""  # "<constraint>: <detail>" when not success
    stats: dict = field(default_factory=dict)  # the planner's (descent_start, ...)
    stages_s: dict = field(default_factory=dict)  # [s] wall time per planning stage (graph)
    start_projection_mm: float | None = None  # [mm] replans: measured base -> projected start


@dataclass
class ExecStatus:
    sim_time_s: float = 0.0
    fsm_state: str = "idle"
    transition_index: int = -1  # in the plan being executed
    fell: bool = False
    fall_reason: str = ""
    fault: str = ""  # why the run stopped otherwise: "cancelled", "dead node: controller ...", ...
    cancelled: bool = False
    qp_failures: int = 0
    replan_reason: str = ""  # replan_needed: contact_offset | no_contact | contact_lost | qp_failure (controller FSM)
    #: contact_offset: (surface, world translation [m]) of the surface the last placement found
    #: off the plan (where it is minus where the plan had it)
    surface_offset: tuple[str, tuple[float, float, float]] | None = None


class PlanSource(Protocol):
    def plan(self, steps: int, start: tuple[np.ndarray, Stance] | None = None,
             surface_offsets: dict[str, list[float]] | None = None) -> PlanOutcome:
        """``surface_offsets``: surface name -> world translation [m] found during the execution
        (the planner's model moves those surfaces; ``start``'s stance is already moved)."""


class Executor(Protocol):
    def start(self, plan: WholeBodyPlan) -> None: ...
    def run(self, budget_s: float, stop: tuple[str, ...]) -> ExecStatus: ...
    def settle(self, duration_s: float) -> ExecStatus: ...
    def measured_q(self) -> np.ndarray: ...
    def report(self) -> dict: ...
    def throw(self, drop: Any, at_time: float) -> None: ...  # a scenario drop (DropSpec) at sim time at_time [s]


class Judge(Protocol):
    def feet_rungs(self) -> dict[str, int | None]: ...
    def grasps(self) -> dict[str, str]: ...
    def base(self) -> tuple[np.ndarray, float]: ...  # base position [m] (world), speed [m/s]


def plan_duration(plan: WholeBodyPlan) -> float:
    return float(sum(t.times[-1] for t in plan.transitions if len(t.times)))


def rungs_reached(feet: dict[str, int | None]) -> int:
    """Highest rung with both feet on it (0: none / the ground)."""
    values = [feet.get(f) for f in FEET]
    if any(v is None for v in values) or values[0] != values[1]:
        return 0
    return int(values[0])


def replan_stance(plan: WholeBodyPlan, index: int, done: bool = False) -> Stance:
    """The stance to replan from after ``replan_needed`` at transition ``index``. ``done`` (the
    transition completed: its placement loaded a contact found off the plan): its target stance.
    Otherwise (a search that found nothing) the stance the transition started from (the previous
    transition's target; the moving limb on the hold it was lifted from, where the measured state
    is projected back: a limb whose search ended inside the nominal surface it missed cannot
    start a plan there)."""
    if not plan.transitions:
        return plan.initial_stance
    index = min(max(index, 0), len(plan.transitions) - (1 if done else 0))
    if done:
        return plan.transitions[index].target_stance
    return plan.transitions[index - 1].target_stance if index > 0 else plan.initial_stance


def scene_goal(scenario) -> tuple[np.ndarray, float] | None:
    """(goal base position [m], tolerance [m]) of a scene without a ladder (scene_spec.md,
    Results), None for a ladder or a scene without a goal."""
    scene = getattr(scenario, "scene", None)
    if scene is None or getattr(scenario, "ladder", None) is not None or scene.goal is None:
        return None
    return np.asarray(scene.goal.base_position, float), float(scene.goal.tolerance)


def stance_feet_rung(stance: Stance) -> int:
    from .judge import rung_index

    rungs = [rung_index(h.env_surface) for h in stance.holds if h.limb in FEET]
    rungs = [r for r in rungs if r is not None]
    return min(rungs) if rungs else 0


# ---------------------------------------------------------------------------------------- session


class ClimbSession:
    """Plan -> execute -> (replan ...) -> judge, over the three ports; ``run()`` returns the summary."""

    def __init__(self, req: ClimbRequest, settings, plans: PlanSource, executor: Executor, judge: Judge,
                 say: Callable[[str], None] | None = None,
                 on_phase: Callable[[str, str], None] | None = None):
        self.req = req
        self.settings = settings  # ClimbSettings: extra_time_s, settle_time_s, foot_force_min
        self.plans = plans
        self.executor = executor
        self.judge = judge
        self.say = say or (lambda msg: None)
        self.on_phase = on_phase or (lambda phase, text: None)
        self.summary = base_summary(req)
        self.active: list[WholeBodyPlan] = []  # every plan executed, in order
        self.done_before = 0  # transitions of the plans before the current one
        self.replans: list[dict] = []
        #: surface -> world translation [m]: where execution found surfaces against the nominal
        #: model (accumulated over replans; every replan plans in the corrected model)
        self.surface_offsets: dict[str, np.ndarray] = {}
        self._prefix: list = []  # transitions executed of the plans before the current one
        self.top_feet: dict = {}
        self.n_up: int | None = None  # descend: first transition of the descent
        self.executed = False
        self.plan_time_s = 0.0
        #: a scene without a ladder: (goal base position (3,) [m], tolerance [m]), judged instead
        #: of the rungs (set from the scenario by the caller)
        self.goal: tuple[np.ndarray, float] | None = None
        self.settle_speed_max: float | None = None  # [m/s] largest base speed while settling
        self.planned: list[WholeBodyPlan] = []  # every plan as planned (before max_transitions)
        #: the scenario's drops triggered by a transition (DropSpec.at_transition > 0; set by the
        #: caller): thrown through Executor.throw when the climb's transition N starts
        self.transition_drops: list = []
        self.thrown: list[dict] = []

    # ------------------------------------------------------------------ progress (adapters call)
    @property
    def current(self) -> WholeBodyPlan | None:
        return self.active[-1] if self.active else None

    @property
    def n_transitions(self) -> int:
        return self.done_before + (len(self.current.transitions) if self.current is not None else 0)

    def on_transition(self, index: int, sim_time_s: float) -> None:
        """The executor saw the controller pick transition ``index`` of the current plan."""
        plan = self.current
        if plan is None or not 0 <= index < len(plan.transitions):
            return
        if self.n_up is not None and index == self.n_up and not self.top_feet:
            self.top_feet.update(self.judge.feet_rungs())
        t = plan.transitions[index]
        number = self.done_before + index + 1
        self.say(f"t = {sim_time_s:6.2f} s  transition {number}/{self.n_transitions}: "
                 f"{t.primitive} {t.moving_limb}")
        for k, drop in enumerate(self.transition_drops):
            if drop.at_transition == number and not any(d["drop"] == k for d in self.thrown):
                at = sim_time_s + drop.at_time
                self.executor.throw(drop, at)
                self.thrown.append({"drop": k, "transition": number, "at_time_s": round(at, 3), "mass_kg": drop.mass})
                self.say(f"drop {k}: a {drop.mass:g} kg ball thrown at {drop.target_link} at t = {at:.2f} s "
                         f"(transition {number})")

    def progress(self, index: int) -> float:
        """[0, 1] of the transitions planned so far (a replan may add some)."""
        n = self.n_transitions
        return 0.0 if n == 0 else min(1.0, (self.done_before + max(index, 0)) / n)

    # ------------------------------------------------------------------ the run
    def _plan(self, steps: int, start=None) -> PlanOutcome:
        offsets = {k: [round(float(x), 6) for x in v] for k, v in self.surface_offsets.items()}
        out = self.plans.plan(steps, start, offsets or None)
        self.plan_time_s += float(out.plan_time_s)
        return out

    def run(self) -> dict:
        req, cs, s = self.req, self.settings, self.summary
        first = req.rungs if req.plan_cycles is None else min(req.plan_cycles, req.rungs)
        self.on_phase("planning", f"{first}-step climb{' and descent' if req.descend else ''}")
        self.say(f"planning {first}-step climb{' and descent' if req.descend else ''} of {s['ladder']} "
                 f"with {req.robot}")
        out = self._plan(first)
        s["plan_time_s"] = round(out.plan_time_s, 3)
        s["n_stances"] = out.n_stances
        if out.stages_s:
            s["plan_stages_s"] = {k: round(v, 3) for k, v in out.stages_s.items()}
        if not out.success or out.plan is None:
            s["failure_reason"] = f"plan: {out.failure}"
            self.on_phase("failed", s["failure_reason"])
            return s
        plan = out.plan
        self.planned.append(plan)
        if req.descend:
            s["descent_start_transition"] = int(out.stats["descent_start"])
            self.n_up = s["descent_start_transition"]
        if req.max_transitions is not None:
            from dataclasses import replace

            plan = replace(plan, transitions=list(plan.transitions[:req.max_transitions]))
        if req.command_delay_ticks:
            s["command_delay_ticks"] = req.command_delay_ticks
        self.say(f"plan: {len(plan.transitions)} transitions, {plan_duration(plan):.1f} s of motion "
                 f"({out.plan_time_s:.1f} s to plan)")
        self.active.append(plan)
        self.executed = True
        self.on_phase("executing", f"{len(plan.transitions)} transitions")
        self.say(f"executing in {req.mode} mode ({plan_duration(plan):.1f} s of plan)")
        self.executor.start(plan)
        status = self.executor.run(plan_duration(plan) + cs.extra_time_s, STOP_STATES)
        cycles = first
        forced = 0
        while not (status.fault or status.fell):
            if status.fsm_state == "failure" and cs.failure_recovery_s > 0 and forced < req.max_forced_replans:
                # the controller holds on the fallback; it asks for a replan once its QP solves again
                self.say(f"controller failure at transition {self.done_before + max(status.transition_index, 0) + 1}: "
                         f"waiting up to {cs.failure_recovery_s:.1f} s for it to recover")
                status = self.executor.settle(cs.failure_recovery_s)
                if status.fault or status.fell or status.fsm_state != "replan_needed":
                    break
            if status.fsm_state == "hold" and req.plan_cycles is not None and cycles < req.rungs:
                k = min(req.plan_cycles, req.rungs - cycles)
                stance = self.current.transitions[-1].target_stance  # the stance the controller holds
                record = {"cycles": k, "reason": "plan_cycles"}
                self.say(f"replanning {k} more cycle(s) from the reached state")
            elif (status.fsm_state == "replan_needed" and not req.descend and req.max_transitions is None
                  and forced < req.max_forced_replans):
                forced += 1
                done = status.replan_reason == "contact_offset"
                stance = replan_stance(self.current, status.transition_index, done)
                record = {"reason": "replan_needed", "why": status.replan_reason or "no_contact",
                          "transition": self.done_before + max(status.transition_index, 0)}
                if done and status.surface_offset is not None:
                    # the placement loaded its contact where the surface really is: the stance's
                    # holds on it and the planner's model move there
                    surface, offset = status.surface_offset
                    d = np.asarray(offset, dtype=float)
                    stance = stance.with_surface_offsets({surface: d})
                    self.surface_offsets[surface] = self.surface_offsets.get(surface, np.zeros(3)) + d
                    record["surface_offset"] = {surface: [round(float(x), 4) for x in d]}
                # rungs still to climb above the stance's lower foot (0: the planner only finishes the
                # cycle under way, e.g. the hands after both feet reached the top rung)
                k = max(0 if done else 1, req.rungs - stance_feet_rung(stance))
                record["cycles"] = k
                self.say(f"replan_needed ({record['why']}) at transition {record['transition'] + 1}: replanning "
                         f"{k} cycle(s) from the measured state (attempt {forced} of {req.max_forced_replans})")
            else:
                break
            self.on_phase("replanning", f"{record['reason']}: {k} cycle(s)")
            nxt = self._plan(k, (self.executor.measured_q(), stance))
            record["plan_time_s"] = round(nxt.plan_time_s, 3)
            if nxt.start_projection_mm is not None:
                record["start_projection_mm"] = round(nxt.start_projection_mm, 2)
            record["sim_time_s"] = round(status.sim_time_s, 3)
            self.replans.append(record)
            if not nxt.success or nxt.plan is None:
                record["failure_reason"] = f"plan: {nxt.failure}"
                break
            if record["reason"] == "plan_cycles":
                cycles += k
            else:
                cycles = req.rungs
            if record["reason"] == "plan_cycles":
                done = len(self.current.transitions)
            else:  # the transition that loaded an off-plan contact was completed
                done = max(status.transition_index, 0) + (1 if record["why"] == "contact_offset" else 0)
            self.planned.append(nxt.plan)
            self._prefix.extend(self.current.transitions[:done])
            self.done_before += done
            self.active.append(nxt.plan)
            self.on_phase("executing", f"{len(nxt.plan.transitions)} more transitions")
            self.executor.start(nxt.plan)
            status = self.executor.run(plan_duration(nxt.plan) + cs.extra_time_s, STOP_STATES)
        if status.fsm_state == "hold" and not (status.fell or status.fault):
            status = self._settle(cs.settle_time_s)
        return self.finish(status)

    def _settle(self, duration_s: float) -> ExecStatus:
        """Hold for ``duration_s`` of sim time; for a scene, the base's largest speed over it in
        ``settle_speed_max`` [m/s] (sampled every 0.1 s: a scene's goal counts when the robot
        stands still)."""
        if self.goal is None:  # a ladder: judged on the rungs, not on the base's speed
            return self.executor.settle(duration_s)
        chunks = max(1, int(round(duration_s / 0.1)))
        status = None
        self.settle_speed_max = 0.0
        for _ in range(chunks):
            status = self.executor.settle(duration_s / chunks)
            self.settle_speed_max = max(self.settle_speed_max, float(self.judge.base()[1]))
            if status.fell or status.fault:
                break
        return status

    def _judge_goal(self, status: ExecStatus) -> list[str]:
        """A scene without a ladder (scene_spec.md, Results): the base within the goal's
        tolerance, standing still (base speed < GOAL_SPEED_MAX over the settle) and nothing fallen;
        adds the spec's fields to the summary. The reasons it failed ([] when reached)."""
        s = self.summary
        goal, tolerance = self.goal
        position, _ = self.judge.base()
        distance = float(np.linalg.norm(np.asarray(position, float) - goal))
        still = self.settle_speed_max is not None and self.settle_speed_max < GOAL_SPEED_MAX
        stances = [st for plan in self.planned for st in [plan.initial_stance] + [t.target_stance for t in plan.transitions]]
        s.update({"rungs_requested": 0, "rungs_reached": 0, "scene": s["ladder"],
                  "goal_distance_m": round(distance, 4),
                  "goal_reached": bool(distance <= tolerance and still and not status.fell),
                  "contacts_used": sorted({h.env_surface for st in stances for h in st.holds})})
        if self.settle_speed_max is not None:
            s["settle_base_speed_max_m_s"] = round(self.settle_speed_max, 4)
        out = []
        if distance > tolerance and self.req.max_transitions is None:
            out.append(f"base {distance:.3f} m from the goal (tolerance {tolerance} m)")
        if not still and self.req.max_transitions is None:
            speed = "never settled" if self.settle_speed_max is None else f"{self.settle_speed_max:.3f} m/s"
            out.append(f"base not standing still at the goal ({speed}; need < {GOAL_SPEED_MAX} m/s for "
                       f"{self.settings.settle_time_s} s)")
        return out

    def executed_plan(self) -> WholeBodyPlan | None:
        """The plan as executed (the transitions run of every plan, concatenated)."""
        if not self.active:
            return None
        if len(self.active) == 1:
            return self.active[0]
        from dataclasses import replace

        return replace(self.active[0], transitions=self._prefix + list(self.active[-1].transitions))

    def finish(self, status: ExecStatus) -> dict:
        req, s = self.req, self.summary
        feet = self.judge.feet_rungs()
        reached = rungs_reached(feet)
        index = status.transition_index
        s.update({
            "rungs_reached": reached,
            "sim_time_s": round(float(status.sim_time_s), 3),
            "fell": bool(status.fell),
            "fsm_state": status.fsm_state,
            "transitions_done": self.done_before + int(max(index, 0)),
            "n_transitions": self.n_transitions,
            "qp_failures": int(status.qp_failures),
            "feet_rungs": {f: feet.get(f) for f in FEET},
            "grasps": dict(self.judge.grasps()),
        })
        s["plan_time_s"] = round(self.plan_time_s, 3)
        s.update(self.executor.report())
        if self.replans or req.plan_cycles is not None:
            s["replans"] = self.replans
        if self.thrown:
            s["drops_thrown"] = self.thrown
        if status.cancelled:
            s["cancelled"] = True
        reasons = []
        if status.fault:
            reasons.append(status.fault)
        if status.fell:
            reasons.append(f"fell: {status.fall_reason}")
        if status.fsm_state != "hold" and not status.cancelled:
            reasons.append(f"controller ended in {status.fsm_state} at transition {self.done_before + index} "
                           f"of {self.n_transitions}")
        if self.replans and "failure_reason" in self.replans[-1]:
            reasons.append(f"replanning ({self.replans[-1]['reason']}): {self.replans[-1]['failure_reason']}")
        if req.descend:
            s["top_feet_rungs"] = {f: self.top_feet.get(f) for f in FEET}
            top = rungs_reached(self.top_feet) if self.top_feet else 0
            if req.max_transitions is None and top < req.rungs:
                reasons.append(f"feet on rungs {self.top_feet or 'never seen'} when the descent began "
                               f"(need both on rung >= {req.rungs})")
            if req.max_transitions is None and any(feet.get(f) != 0 for f in FEET):
                reasons.append(f"feet on {feet} at the end of the descent (need both on the ground)")
        elif self.goal is not None:
            reasons += self._judge_goal(status)
        elif req.max_transitions is None and reached < req.rungs:
            reasons.append(f"feet on rungs {feet} (need both on rung >= {req.rungs})")
        s["success"] = not reasons
        s["failure_reason"] = "; ".join(reasons)
        self.on_phase("cancelled" if status.cancelled else ("done" if s["success"] else "failed"),
                      s["failure_reason"] or "success")
        self.say(f"done: {s['failure_reason'] or 'success'}")
        return s


def controller_overrides(req: ClimbRequest, settings, control_period_s: float | None = None) -> dict:
    """Dotted controller parameters of a climb on top of config/nodes/controller.yaml (the same
    for the in-process controller and the controller node): config/climb.yaml's overrides,
    compliance ones, the request's, the mode, and (given the control period [s]) the actuation
    latency of a command delay."""
    overrides = dict(settings.controller_overrides)
    if req.mode == "compliance":
        overrides.update(settings.compliance_overrides)
    overrides.update(req.controller_overrides)
    overrides["mode"] = req.mode
    if control_period_s is not None and req.command_delay_ticks and "actuation_latency_s" not in overrides:
        overrides["actuation_latency_s"] = req.command_delay_ticks * control_period_s
    return overrides
