"""The in-process climb (no ROS): plan -> execute in lock-step -> record -> judge.

    result = run_climb(ClimbRequest(ladder="default", robot="g1", rungs=2, mode="qp", out_dir="out/x"))
    print(result.summary)  # the JSON summary of shared/specs/ladder_spec.md ("Results")

1. Plan: ``planner_node.climb_planner.plan_climb`` from the library's start fixture (standing), or,
   with ``strategy="search"``, the DARPA-tasks paper's pipeline (free-flyer guide path, best-first
   contact search, adaptation: :class:`SearchPlanSource`) from ``start_posture``.
2. Post-process: plan joints clipped ``plan.joint_limit_margin`` inside the URDF limits (the
   planner keeps a smaller margin than the controller's joint-limit bounds; a configuration inside
   the controller's margin band can make the QP infeasible next to a collision damper).
3. Execute: ``PyBulletBackend`` + ``Controller`` through ``controller_node.runner.InProcessRunner``
   (one control tick per 5 ms of sim time), until the FSM holds after the last transition, fails
   or needs a replan, or the plan's duration plus ``run.extra_time_s`` has passed; then
   ``run.settle_time_s`` of hold.
4. Record: a decimated rosbag2 (MCAP) of the run's topics, sampled arrays for the plots.
5. Judge from the simulator only: feet on rungs from the contact points (surface carrying the
   foot's normal force), friction ratios of the unilateral contacts, falls.

The decisions (replanning at a hold with ``plan_cycles``, after ``replan_needed`` from the
measured state, how the run ends, the summary) are climb_coordinator.session's, shared with the
`climb_coordinator` node; this module holds the in-process adapters of its three ports:
:class:`LibraryPlanSource` (planner library), :class:`InProcessExecutor` (PyBullet backend +
controller through InProcessRunner, logging, bag, snapshots) and :class:`BackendJudge` (judge.py).

With ``descend=True`` the plan is the climb followed by its reverse
(``planner_node.descend.up_and_down``): the robot climbs ``rungs`` rungs, then climbs back down
until both feet stand on the ground again (hands still on the rung they mounted); the judge then
also requires the feet to have been on rung ``rungs`` when the descent began.
"""
from __future__ import annotations

import pathlib
import time
from dataclasses import dataclass, field, replace
from typing import Any, Callable

import numpy as np

from climb_core.contact import LIMBS, WholeBodyPlan
from climb_core.errors import SpecError

from . import judge
from .record import BagWriter, ClimbLog, sample
from .session import (MODES, STOP_STATES, ClimbRequest, ClimbSession, ExecStatus, PlanOutcome, base_summary,
                      check_request, controller_overrides, plan_duration, scene_goal, validate,
                      with_chosen_strategy)
from .settings import ClimbSettings, apply_planner_overrides, load_climb_settings

__all__ = ["MODES", "ClimbRequest", "ClimbResult", "base_summary", "validate", "check_request", "plan_duration",
           "run_climb", "execute", "clip_plan_to_limits", "snapshot", "LibraryPlanSource", "InProcessExecutor",
           "BackendJudge", "SearchPlanSource", "GivenPlanSource", "StoredPlanSource", "STOP_STATES", "run_stored_plan",
           "stored_plan_fixture"]


@dataclass
class ClimbResult:
    summary: dict
    log: ClimbLog
    plan: WholeBodyPlan | None
    controller: Any = None  # the Controller (history, events) or None when nothing ran
    backend: Any = None  # still open: the caller closes it (ClimbResult.close)
    frames: list = field(default_factory=list)  # (sim time [s], RGB array)
    cone_samples: dict = field(default_factory=dict)  # limb -> list of (normal [N], tangential [N], mu [-])
    wall_time_s: float = 0.0  # [s] execution wall time

    def close(self) -> None:
        if self.backend is not None:
            self.backend.close()
            self.backend = None


def clip_plan_to_limits(plan: WholeBodyPlan, robot, margin: float) -> WholeBodyPlan:
    """The plan with every joint value clipped ``margin`` [rad] inside the URDF position limits
    (free-flyer untouched). Returns a new plan; the input is not modified."""
    model = robot.model
    lo = np.asarray(model.lowerPositionLimit[7:], float) + margin
    hi = np.asarray(model.upperPositionLimit[7:], float) - margin
    bad = lo > hi  # a joint range narrower than 2 margins: its middle
    lo[bad] = hi[bad] = 0.5 * (model.lowerPositionLimit[7:][bad] + model.upperPositionLimit[7:][bad])
    transitions = []
    for t in plan.transitions:
        path = np.array(t.path, float)
        path[:, 7:] = np.clip(path[:, 7:], lo, hi)
        transitions.append(replace(t, path=path))
    return replace(plan, transitions=transitions)


def plan(req: ClimbRequest, robot, env, settings=None, steps: int | None = None):
    """The request's climb planned with the libraries of ``settings.planning.strategy``, nearest
    reference ladder first (``plan_climb`` ranks them: what the sweep and the planning nodes plan)."""
    from planner_node.climb_planner import plan_climb
    from planner_node.descend import up_and_down

    planner = up_and_down if req.descend else plan_climb
    return planner(robot, env, req.rungs if steps is None else steps, settings=settings,
                   seed=req.seed, timeout_s=req.plan_timeout_s)


# ------------------------------------------------------------------------------ the three ports


class LibraryPlanSource:
    """Plan source port: the planner library in this process (first plan from the library's start
    fixture; replans from the measured state projected onto the held stance)."""

    def __init__(self, req: ClimbRequest, robot, env, psettings, cs: ClimbSettings):
        self.req, self.robot, self.env = req, robot, env
        self.psettings, self.cs = psettings, cs

    def plan(self, steps: int, start=None, surface_offsets=None) -> PlanOutcome:
        from climb_core.errors import ClimbError, InfeasibleError
        from planner_node.climb_planner import plan_climb
        from planner_node.replan import measured_start

        req = self.req
        env = self.env.with_surface_offsets(surface_offsets) if surface_offsets else self.env
        projection = None
        if start is None:
            res = plan(req, self.robot, env, self.psettings, steps)
        else:
            q, stance = start
            t0 = time.perf_counter()
            try:
                q0 = measured_start(self.robot, env, q, stance, self.psettings)
            except InfeasibleError as exc:
                return PlanOutcome(False, None, time.perf_counter() - t0, failure=f"start: {exc}")
            projection = float(np.linalg.norm(q0[:3] - np.asarray(q)[:3])) * 1e3
            try:
                res = plan_climb(self.robot, env, steps, start=(q0, stance), settings=self.psettings,
                                 seed=req.seed, timeout_s=req.plan_timeout_s)
            except ClimbError as exc:  # a start the primitives cannot continue from: said, not raised
                return PlanOutcome(False, None, time.perf_counter() - t0, failure=str(exc))
        ok = bool(res.success and res.plan is not None)
        return PlanOutcome(ok, clip_plan_to_limits(res.plan, self.robot, self.cs.plan_joint_limit_margin) if ok
                           else res.plan, res.plan_time_s, res.n_stances,
                           "" if ok else f"{res.failure_constraint}: {res.failure_detail}", dict(res.stats),
                           start_projection_mm=projection)


class SearchPlanSource:
    """Plan source port for ``strategy: search`` (planner_node.pipeline): the free-flyer guide path,
    the best-first contact search and the adaptation, in this process, from the start fixture (or,
    replanning, from the measured state projected onto the held stance)."""

    def __init__(self, req: ClimbRequest, robot, env, psettings, cs: ClimbSettings, start_posture: str):
        self.req, self.robot, self.env, self.psettings, self.cs = req, robot, env, psettings, cs
        self.start_posture = start_posture

    def plan(self, steps: int, start=None, surface_offsets=None) -> PlanOutcome:
        from climb_core import fixtures
        from climb_core.errors import ClimbError
        from planner_node import pipeline
        from planner_node.plan_io import stance_to_dict

        from .session import stance_feet_rung

        t0 = time.perf_counter()
        if start is None and self.env.ladder is None:  # a scene: standing at its start pose
            from planner_node.pipeline import search_start

            q, stance = search_start(pipeline.Problem(pipeline.PlanRequest(id="start", robot=self.robot.config.name,
                                                                           scenario=self.env.name, rungs=0),
                                                      self.robot, self.env.scenario, self.env, None, self.psettings))
            target = 0
        elif start is None:  # the first plan: the feet end on rung ``steps`` (= the request's rungs)
            stance, q = fixtures.get(self.start_posture, self.robot, self.env)
            target = int(steps)
        else:  # a replan: ``steps`` more rungs above the held stance's feet
            q, stance = start
            target = stance_feet_rung(stance) + int(steps)
        request = pipeline.PlanRequest(id="in-process", robot=self.robot.config.name, scenario=self.env.name,
                                       rungs=target, seed=self.req.seed, timeout_s=self.req.plan_timeout_s,
                                       strategy="search",
                                       start={"q": np.asarray(q, float).tolist(), "stance": stance_to_dict(stance)})
        env = self.env.with_surface_offsets(surface_offsets) if surface_offsets else self.env
        problem = pipeline.Problem(request, self.robot, self.env.scenario, env, None, self.psettings,
                                   start=(np.asarray(q, float), stance))
        stages: dict[str, float] = {}
        try:
            t = time.perf_counter()
            path = pipeline.guide_path(problem, strategy="search").product
            stages["guide_path"] = time.perf_counter() - t
            t = time.perf_counter()
            contacts, res, _ = pipeline.search_and_adapt(problem, path)  # repaired where stuck
            contact_plan = contacts.product
            stages["contact_search"] = float(contacts.summary["time_s"])  # the last search
            stages["adaptation"] = time.perf_counter() - t - stages["contact_search"]
        except ClimbError as exc:  # InfeasibleError / SpecError of a stage: the plan failed, said why
            return PlanOutcome(False, None, time.perf_counter() - t0, failure=str(exc), stages_s=stages)
        ok = bool(res.success and res.plan is not None)
        plan = clip_plan_to_limits(res.plan, self.robot, self.cs.plan_joint_limit_margin) if ok else res.plan
        projection = None
        if start is not None and problem.start is not None:
            q0, _ = pipeline.start_state(problem)
            projection = float(np.linalg.norm(q0[:3] - np.asarray(q)[:3])) * 1e3
        return PlanOutcome(ok, plan, time.perf_counter() - t0, len(contact_plan.stances),
                           "" if ok else f"{res.failure_constraint}: {res.failure_detail}", dict(res.stats),
                           stages_s=stages, start_projection_mm=projection)


class GivenPlanSource:
    """Plan source port of a plan made by the caller (a sweep's, a stored one): the first plan as
    given (clipped to the joint limits like a fresh one); replans from ``replans`` (another plan
    source), or none."""

    def __init__(self, plan: WholeBodyPlan, robot, cs: ClimbSettings, replans=None):
        if plan.robot != robot.config.name:
            raise SpecError("plan.robot", f"the given plan is for {plan.robot!r}, not {robot.config.name!r}")
        self.plan_, self.robot, self.cs, self.replans = plan, robot, cs, replans

    def plan(self, steps: int, start=None, surface_offsets=None) -> PlanOutcome:
        if start is not None:
            if self.replans is None:
                return PlanOutcome(False, None, 0.0, failure="replan: a given plan is not replanned")
            return self.replans.plan(steps, start, surface_offsets)
        plan = clip_plan_to_limits(self.plan_, self.robot, self.cs.plan_joint_limit_margin)
        return PlanOutcome(True, plan, 0.0, len(plan.transitions) + 1)


class StoredPlanSource(GivenPlanSource):
    """A :class:`GivenPlanSource` of a plan made before (``planner_node.plan_io`` JSON, e.g.
    scripts/plan.py --out); replans from ``replans`` (None: none)."""

    def __init__(self, path, robot, cs: ClimbSettings, replans=None):
        from planner_node.plan_io import load_plan

        plan, self.metadata = load_plan(path)
        super().__init__(plan, robot, cs, replans)


class BackendJudge:
    """Judge port: the PyBullet backend's contact points (judge.py) and grasps."""

    def __init__(self, backend, cs: ClimbSettings, executor: "InProcessExecutor"):
        self.backend, self.cs, self.executor = backend, cs, executor

    def feet_rungs(self) -> dict:
        return judge.feet_rungs(self.backend, self.cs.foot_force_min)

    def grasps(self) -> dict:
        runner = self.executor.runner
        return dict(runner.sim_state.grasps) if runner is not None else {}

    def base(self) -> tuple[np.ndarray, float]:
        """The simulator's base position [m] and linear speed [m/s] (ground truth)."""
        runner = self.executor.runner
        if runner is None:
            return np.full(3, np.nan), float("nan")
        b = runner.sim_state.base
        return np.asarray(b.T_world_base, float)[:3, 3].copy(), float(np.linalg.norm(b.linear_velocity_in_world))


class InProcessExecutor:
    """Executor port: the controller library ticking the PyBullet backend in lock-step
    (InProcessRunner), with the run's log, bag, friction-cone samples and snapshots."""

    def __init__(self, req: ClimbRequest, cs: ClimbSettings, out: ClimbResult, scenario, initial_fixture: str,
                 params, backend):
        self.req, self.cs, self.out = req, cs, out
        self.scenario, self.initial_fixture = scenario, initial_fixture
        self.params, self.backend = params, backend
        self.session: ClimbSession | None = None
        self.runner = None
        self.controller = None
        self.bag = None
        self.t0 = 0.0

    # -- set-up at the first plan: the runner starts from its initial stance
    def _open(self, plan: WholeBodyPlan) -> None:
        from controller_node.runner import InProcessRunner

        req, cs, out, backend = self.req, self.cs, self.out, self.backend
        runner = InProcessRunner.start(backend, self.params, robot=req.robot, ladder=self.scenario,
                                       posture=self.initial_fixture, stance=plan.initial_stance,
                                       command_delay_ticks=req.command_delay_ticks)
        self.runner, self.controller = runner, runner.controller
        controller = runner.controller
        out.controller = controller
        log = out.log
        log.joint_names = tuple(controller.joint_names)
        log.effort_limits = np.asarray(controller.effort_limits, float).copy()
        dt = self.params.control_period_s
        log_every = max(1, int(round(1.0 / (cs.log_rate_hz * dt))))
        bag_every = max(1, int(round(1.0 / (cs.bag_rate_hz * dt))))
        if req.bag and req.out_dir is not None:
            out_dir = pathlib.Path(req.out_dir)
            out_dir.mkdir(parents=True, exist_ok=True)
            bag_path = out_dir / "bag"
            if bag_path.exists():
                import shutil

                shutil.rmtree(bag_path)
            ft_frames = {s: backend.link_name(j) for s, j in backend.ft_joints.items()}
            self.bag = BagWriter(bag_path, tuple(backend.joint_names), ft_frames, backend.root_link)
            out.summary["bag"] = str(bag_path)
        duration = plan_duration(plan)
        snap_times = list(np.linspace(0.0, duration + cs.settle_time_s, req.snapshots)) if req.snapshots else []
        self.cones = cones = {limb: [] for limb in LIMBS}  # limb -> (normal [N], tangential [N], mu [-])
        self.cone_use = cone_use = judge.ConeUse({name: float(s.friction) for name, s in backend.env.surfaces.items()},
                                                 cs.cone_force_min)
        tick = [0]
        current = [-1]
        bag = self.bag
        session = self.session

        def on_tick(sim_state, output) -> None:
            k = tick[0]
            tick[0] += 1
            index = controller.transition_index
            if index != current[0] and index >= 0:
                current[0] = index
                if session is not None:
                    session.on_transition(index, float(sim_state.time))
            log.tick_ms.append(float(output.status.tick_time_ms))
            log.qp_ms.append(float(output.status.qp_solve_time_ms))
            log.max_current_ratio.append(runner.log.max_current_ratio[-1] if runner.log.max_current_ratio else 0.0)
            if k % log_every == 0:
                sample(log, backend, sim_state, output, controller)
                grasped = {h for h, s in sim_state.grasps.items() if s}
                for limb in LIMBS:
                    load = log.loads[limb][-1]
                    if load is not None and cone_use.add(limb, load[0], load[1], load[2], limb in grasped):
                        cones[limb].append((load[0], load[1], cone_use.surface_mu[load[2]]))
            if bag is not None and k % bag_every == 0:
                bag.write(sim_state, output)
            if snap_times and sim_state.time >= snap_times[0]:
                snap_times.pop(0)
                out.frames.append((float(sim_state.time), snapshot(backend, cs)))

        self._reset_index = lambda: current.__setitem__(0, -1)
        runner.on_tick.append(on_tick)
        self.t0 = time.perf_counter()

    # -- the port
    def start(self, plan: WholeBodyPlan) -> None:
        if self.runner is None:
            self._open(plan)
        else:
            self._reset_index()
        self.controller.set_plan(plan)
        if self.bag is not None:
            self.bag.plans_taken += 1

    def _status(self) -> ExecStatus:
        s, c = self.runner.sim_state, self.controller
        offset = None
        if c.fsm.state == "replan_needed" and c.replan_reason == "contact_offset" and c.placement_offset is not None:
            offset = (c.placement_offset[1], tuple(float(x) for x in c.placement_offset[2]))
        return ExecStatus(sim_time_s=float(s.time), fsm_state=c.fsm.state, transition_index=int(c.transition_index),
                          fell=bool(s.fell), fall_reason=s.fall_reason, qp_failures=int(c.qp_failures),
                          replan_reason=c.replan_reason if c.fsm.state == "replan_needed" else "",
                          surface_offset=offset)

    def run(self, budget_s: float, stop: tuple[str, ...]) -> ExecStatus:
        c = self.controller
        # transition_index is -1 until the FSM has picked the plan's first transition
        self.runner.run(budget_s, until=lambda o: o.status.fsm_state in stop
                        and (c.transition_index >= 0 or o.status.fsm_state == "failure"))
        return self._status()

    def settle(self, duration_s: float) -> ExecStatus:
        self.runner.run(duration_s)
        return self._status()

    def measured_q(self) -> np.ndarray:
        return self.runner.robot_state().q

    def hold(self) -> None:  # in process the caller simply stops ticking
        pass

    def throw(self, drop, at_time: float) -> None:
        from sim_bridge.commands import drop_request

        self.backend.request_perturbation(drop_request(drop, at_time))

    def report(self) -> dict:
        out, log = self.out, self.out.log
        out.wall_time_s = time.perf_counter() - self.t0
        sim_time = float(self.runner.sim_state.time)
        ticks = np.asarray(log.tick_ms)
        out.cone_samples = self.cones
        r = {
            "control_tick_ms": {"p50": round(float(np.percentile(ticks, 50)), 3),
                                "p99": round(float(np.percentile(ticks, 99)), 3),
                                "max": round(float(ticks.max()), 3)} if len(ticks) else None,
            "wall_time_s": round(out.wall_time_s, 2),
            "real_time_factor": round(sim_time / out.wall_time_s, 3) if out.wall_time_s > 0 else 0.0,
            # largest tangential / (mu normal) of each unilateral contact over the run (cone: <= 1)
            "max_cone_use": self.cone_use.summary(),
            "tracking": tracking_summary(self.controller),
        }
        if self.req.mode == "compliance":
            r["motor_trips"] = sorted(self.runner.log.tripped)
            r["max_current_ratio"] = round(max(log.max_current_ratio, default=0.0), 3)
        return r

    def close(self) -> None:
        if self.bag is not None:
            self.bag.close()
            self.bag = None


def tracking_summary(controller) -> dict:
    """Each finished transition's end against its plan (controller event ``transition_finished``):
    ``per_transition`` [index, primitive, base error [m], joint error [rad], joint] and the worst."""
    ends = controller.events_of("transition_finished") if controller is not None else []
    rows = [[int(e.values["index"]), e.values["primitive"], round(float(e.values["base_error"]), 4),
             round(float(e.values["joint_error"]), 4), e.values["joint"]] for e in ends]
    worst = max(rows, key=lambda r: r[3], default=None)
    return {"per_transition": rows,
            "max_joint_error_rad": worst[3] if worst else 0.0,
            "max_joint_error_at": f"transition {worst[0]} ({worst[1]}): {worst[4]}" if worst else "",
            "max_base_error_m": max((r[2] for r in rows), default=0.0)}


# ------------------------------------------------------------------------------ entry points


def run_climb(req: ClimbRequest, settings: ClimbSettings | None = None,
              on_progress: Callable[[str], None] | None = None) -> ClimbResult:
    """Plan, execute and judge one climb. Raises SpecError on a bad request or ladder spec."""
    req = with_chosen_strategy(req)
    validate(req)
    cs = settings or load_climb_settings()
    scenario, plans, posture = _planning(req, cs)
    return execute(req, plans, cs, scenario, posture, on_progress or (lambda m: None))


def run_stored_plan(req: ClimbRequest, path, settings: ClimbSettings | None = None,
                    on_progress: Callable[[str], None] | None = None) -> ClimbResult:
    """Execute and judge a plan made before (``planner_node.plan_io`` JSON: scripts/plan.py --out,
    tests/data/*.json) instead of planning one; replans (``replan_needed``, ``plan_cycles``) go to the
    planner as in :func:`run_climb`. The request's ladder must be the plan's environment and its robot
    the plan's; the robot starts in the fixture whose stance is the plan's initial stance
    (:func:`stored_plan_fixture`) unless ``req.start_posture`` names one. SpecError (naming the field)
    on a plan that does not fit the request."""
    from climb_core.robot import load_robot

    req = with_chosen_strategy(req)
    validate(req)
    cs = settings or load_climb_settings()
    scenario, replans, _ = _planning(req, cs)
    robot = load_robot(req.robot)
    plans = StoredPlanSource(path, robot, cs, replans=replans)
    if plans.plan_.environment != scenario.name:
        raise SpecError("plan.environment", f"{path} was planned on {plans.plan_.environment!r}, "
                                            f"the request's scenario is {scenario.name!r}")
    posture = req.start_posture or stored_plan_fixture(plans.plan_, robot, scenario)
    return execute(req, plans, cs, scenario, posture, on_progress or (lambda m: None))


def stored_plan_fixture(plan: WholeBodyPlan, robot, scenario) -> str:
    """The start fixture (climb_core.fixtures) whose stance holds the plan's initial stance: the same
    limbs on the same surfaces (SpecError when none does: the simulator could not start there)."""
    from climb_core import fixtures
    from climb_core.errors import InfeasibleError

    wanted = sorted((h.limb, h.env_surface) for h in plan.initial_stance.holds)
    for name in fixtures.NAMES:
        try:
            stance, _ = fixtures.get(name, robot, scenario)
        except (SpecError, InfeasibleError):  # a fixture this scenario has no place for
            continue
        if sorted((h.limb, h.env_surface) for h in stance.holds) == wanted:
            return name
    raise SpecError("plan.initial_stance", f"no start fixture holds {wanted} (fixtures: {', '.join(fixtures.NAMES)})")


def _planning(req: ClimbRequest, cs: ClimbSettings):
    """(scenario, plan source, start fixture) of a request: the DARPA-tasks search or the
    primitive planner, with the climb's and the scenario's planner settings."""
    from climb_core.environment import build_environment
    from climb_core.ladder import load_scenario
    from climb_core.robot import load_robot
    from planner_node.primitives import load_library
    from planner_node.settings import load_settings, settings_for_scenario

    scenario = load_scenario(req.ladder)
    env = build_environment(scenario)
    robot = load_robot(req.robot)
    psettings = settings_for_scenario(apply_planner_overrides(load_settings(), cs.planner_overrides), scenario,
                                      scene_overrides=cs.scene_planner_overrides, steep=cs.steep_ladder)
    if req.strategy == "search":
        posture = req.start_posture or "standing"
        return scenario, SearchPlanSource(req, robot, env, psettings, cs, posture), posture
    p = psettings.planning
    library = load_library(robot.config.name, p.strategy, p.primitives_dir, nq=robot.model.nq)
    return scenario, LibraryPlanSource(req, robot, env, psettings, cs), req.start_posture or library.initial_fixture


def execute(req: ClimbRequest, plans, cs: ClimbSettings, scenario, initial_fixture: str,
            say: Callable[[str], None] = lambda m: None) -> ClimbResult:
    """The session with ``plans`` (a plan source), a fresh PyBullet world from
    ``initial_fixture`` and the controller library; the backend stays open in the result."""
    from controller_node.params import load_controller_params
    from sim_bridge.params import load_bridge_params
    from sim_bridge.pybullet_backend import PyBulletBackend

    overrides = controller_overrides(req, cs)
    params = load_controller_params(**overrides)
    if req.command_delay_ticks and "actuation_latency_s" not in overrides:
        params = params.replace(actuation_latency_s=req.command_delay_ticks * params.control_period_s)
    backend = PyBulletBackend(load_bridge_params(**req.bridge_overrides))
    summary = base_summary(req)
    out = ClimbResult(summary, ClimbLog(), None, backend=backend)
    executor = InProcessExecutor(req, cs, out, scenario, initial_fixture, params, backend)
    session = ClimbSession(req, cs, plans, executor, BackendJudge(backend, cs, executor), say)
    session.summary = summary
    goal = scene_goal(scenario)
    if goal is not None:  # a scene without a ladder: judged on its goal (scene_spec.md)
        session.goal = goal
    executor.session = session
    session.transition_drops = [d for d in scenario.perturbation.drops if d.on_transition]
    try:
        session.run()
        out.plan = session.executed_plan()
        executor.close()
        if req.snapshots and executor.runner is not None:
            out.frames.append((float(executor.runner.sim_state.time), snapshot(backend, cs)))
            out.frames = out.frames[-req.snapshots:] if len(out.frames) > req.snapshots else out.frames
    except BaseException:
        executor.close()
        out.close()
        raise
    if not session.executed:  # nothing ran (no plan): nothing to keep open
        out.close()
    return out


def snapshot(backend, cs: ClimbSettings) -> np.ndarray:
    """An RGB image (h, w, 3) of the world from a camera looking at the robot's base (headless:
    PyBullet's TinyRenderer in the backend's DIRECT client)."""
    p = backend.p
    target = backend.link_pose(-1)[:3, 3].copy()
    view = p.computeViewMatrixFromYawPitchRoll(target.tolist(), cs.camera_distance, cs.camera_yaw_deg,
                                               cs.camera_pitch_deg, 0.0, 2, physicsClientId=backend.client)
    proj = p.computeProjectionMatrixFOV(50.0, cs.snapshot_width / cs.snapshot_height, 0.05, 10.0,
                                        physicsClientId=backend.client)
    _, _, rgba, _, _ = p.getCameraImage(cs.snapshot_width, cs.snapshot_height, view, proj,
                                         renderer=p.ER_TINY_RENDERER, physicsClientId=backend.client)
    return np.asarray(rgba, np.uint8).reshape(cs.snapshot_height, cs.snapshot_width, 4)[:, :, :3].copy()
