"""The in-process climb (no ROS): plan -> execute in lock-step -> record -> judge.

    result = run_climb(ClimbRequest(ladder="default", robot="g1", rungs=2, mode="qp", out_dir="out/x"))
    print(result.summary)  # the JSON summary of shared/specs/ladder_spec.md ("Results")

1. Plan: ``planner_node.climb_planner.plan_climb`` from the library's start fixture (standing).
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

from climb_core.contact import FEET, HANDS, LIMBS, Transition, WholeBodyPlan
from climb_core.errors import SpecError

from . import judge
from .record import BagWriter, ClimbLog, sample
from .settings import ClimbSettings, apply_planner_overrides, load_climb_settings

MODES = ("qp", "compliance")


@dataclass
class ClimbRequest:
    ladder: Any = "default"  # name in config/ladders/, a spec file, YAML text or a Scenario
    robot: str = "g1"
    rungs: int = 2  # climbing cycles after the mount (feet end on rung N)
    mode: str = "qp"  # qp | compliance
    out_dir: str | pathlib.Path | None = None  # bag (and plots) go here; None: no files
    seed: int | None = None  # planner seed (default: config/planner.yaml)
    bag: bool = True
    snapshots: int = 0  # film strip frames to capture (0: none)
    plan_timeout_s: float | None = None
    controller_overrides: dict = field(default_factory=dict)
    max_transitions: int | None = None  # execute only the plan's first k transitions (None: all)
    descend: bool = False  # climb `rungs` rungs, then climb back down to the ground
    plan_cycles: int | None = None  # plan this many cycles at a time, the next ones from the reached state
    #: 1: every command acts one control period late (the bridge's lockstep.command_delay_ticks);
    #: the controller then computes each command for the state one period ahead
    #: (actuation_latency_s), unless controller_overrides set it
    command_delay_ticks: int = 0


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


def plan_duration(plan: WholeBodyPlan) -> float:
    return float(sum(t.times[-1] for t in plan.transitions if len(t.times)))


def base_summary(req: ClimbRequest) -> dict:
    return {"success": False, "failure_reason": "", "robot": req.robot,
            "ladder": req.ladder if isinstance(req.ladder, str) else getattr(req.ladder, "name", "custom"),
            "rungs_requested": int(req.rungs), "rungs_reached": 0, "plan_time_s": 0.0, "n_stances": 0,
            "sim_time_s": 0.0, "fell": False, "control_tick_ms": None, "bag": "", "mode": req.mode}


def validate(req: ClimbRequest) -> None:
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


def plan(req: ClimbRequest, robot, env, library, settings=None, steps: int | None = None):
    from planner_node.climb_planner import plan_climb
    from planner_node.descend import up_and_down

    planner = up_and_down if req.descend else plan_climb
    return planner(robot, env, req.rungs if steps is None else steps, library=library, settings=settings,
                   seed=req.seed, timeout_s=req.plan_timeout_s)


def run_climb(req: ClimbRequest, settings: ClimbSettings | None = None,
              on_progress: Callable[[str], None] | None = None) -> ClimbResult:
    """Plan, execute and judge one climb. Raises SpecError on a bad request or ladder spec."""
    from climb_core.environment import build_environment
    from climb_core.ladder import load_scenario
    from climb_core.robot import load_robot
    from planner_node.primitives import load_library
    from planner_node.settings import load_settings

    validate(req)
    cs = settings or load_climb_settings()
    say = on_progress or (lambda msg: None)
    summary = base_summary(req)
    scenario = load_scenario(req.ladder)
    env = build_environment(scenario)
    robot = load_robot(req.robot)
    psettings = apply_planner_overrides(load_settings(), cs.planner_overrides)
    p = psettings.planning
    library = load_library(robot.config.name, p.strategy, p.primitives_dir, nq=robot.model.nq)
    first_steps = req.rungs if req.plan_cycles is None else min(req.plan_cycles, req.rungs)
    say(f"planning {first_steps}-step climb{' and descent' if req.descend else ''} of {summary['ladder']} "
        f"with {req.robot}")
    result = plan(req, robot, env, library, psettings, first_steps)
    summary["plan_time_s"] = round(result.plan_time_s, 3)
    summary["n_stances"] = result.n_stances
    log = ClimbLog()
    if not result.success or result.plan is None:
        summary["failure_reason"] = f"plan: {result.failure_constraint}: {result.failure_detail}"
        return ClimbResult(summary, log, result.plan)
    if req.descend:
        summary["descent_start_transition"] = int(result.stats["descent_start"])
    whole = clip_plan_to_limits(result.plan, robot, cs.plan_joint_limit_margin)
    if req.max_transitions is not None:
        whole = replace(whole, transitions=list(whole.transitions[:req.max_transitions]))
    say(f"plan: {len(whole.transitions)} transitions, {plan_duration(whole):.1f} s of motion "
        f"({result.plan_time_s:.1f} s to plan)")
    replanner = None
    if first_steps < req.rungs:
        def replanner(q, stance, cycles_done: int):
            """The next cycles from the reached state: (plan or None, cycles, record for the summary)."""
            from planner_node.replan import measured_start

            from climb_core.errors import InfeasibleError
            from planner_node.climb_planner import plan_climb

            k = min(req.plan_cycles, req.rungs - cycles_done)
            say(f"replanning {k} more cycle(s) from the reached state")
            try:
                q0 = measured_start(robot, env, q, stance, psettings)
            except InfeasibleError as exc:
                return None, k, {"failure_reason": f"start: {exc}"}
            res = plan_climb(robot, env, k, start=(q0, stance), library=library, settings=psettings, seed=req.seed,
                             timeout_s=req.plan_timeout_s)
            record = {"cycles": k, "plan_time_s": round(res.plan_time_s, 3),
                      "start_projection_mm": round(float(np.linalg.norm(q0[:3] - np.asarray(q)[:3])) * 1e3, 2)}
            if not res.success or res.plan is None:
                record["failure_reason"] = f"plan: {res.failure_constraint}: {res.failure_detail}"
                return None, k, record
            return clip_plan_to_limits(res.plan, robot, cs.plan_joint_limit_margin), k, record
    return execute(req, whole, cs, summary, scenario, library.initial_fixture, say, replanner=replanner,
                   cycles_planned=first_steps)


def execute(req: ClimbRequest, whole: WholeBodyPlan, cs: ClimbSettings, summary: dict, scenario,
            initial_fixture: str, say: Callable[[str], None] = lambda m: None, replanner=None,
            cycles_planned: int | None = None) -> ClimbResult:
    """Run ``whole`` against a fresh PyBullet world from ``initial_fixture`` and judge it.
    ``replanner(q, stance, cycles_done) -> (plan | None, cycles, record)`` gives the next plan
    whenever the controller holds at the end of one and fewer than ``req.rungs`` cycles were
    planned (``cycles_planned`` of them in ``whole``)."""
    from controller_node.params import load_controller_params
    from controller_node.runner import InProcessRunner
    from sim_bridge.pybullet_backend import PyBulletBackend

    overrides = dict(cs.controller_overrides)
    if req.mode == "compliance":
        overrides.update(cs.compliance_overrides)
    overrides.update(req.controller_overrides)
    overrides["mode"] = req.mode
    params = load_controller_params(**overrides)
    if req.command_delay_ticks and "actuation_latency_s" not in overrides:
        params = params.replace(actuation_latency_s=req.command_delay_ticks * params.control_period_s)
    backend = PyBulletBackend()
    out = ClimbResult(summary, ClimbLog(), whole, backend=backend)
    try:
        _execute(req, whole, cs, out, scenario, initial_fixture, params, backend, say, replanner,
                 req.rungs if cycles_planned is None else cycles_planned)
    except BaseException:
        out.close()
        raise
    return out


def _execute(req, whole, cs, out: ClimbResult, scenario, initial_fixture, params, backend, say, replanner=None,
             cycles_planned: int = 0) -> None:
    from controller_node.runner import InProcessRunner

    summary, log = out.summary, out.log
    if req.command_delay_ticks:
        summary["command_delay_ticks"] = req.command_delay_ticks
    runner = InProcessRunner.start(backend, params, robot=req.robot, ladder=scenario, posture=initial_fixture,
                                   stance=whole.initial_stance, command_delay_ticks=req.command_delay_ticks)
    controller = runner.controller
    out.controller = controller
    log.joint_names = tuple(controller.joint_names)
    log.effort_limits = np.asarray(controller.effort_limits, float).copy()
    dt = params.control_period_s
    log_every = max(1, int(round(1.0 / (cs.log_rate_hz * dt))))
    bag_every = max(1, int(round(1.0 / (cs.bag_rate_hz * dt))))
    bag = None
    if req.bag and req.out_dir is not None:
        out_dir = pathlib.Path(req.out_dir)
        out_dir.mkdir(parents=True, exist_ok=True)
        bag_path = out_dir / "bag"
        if bag_path.exists():
            import shutil

            shutil.rmtree(bag_path)
        ft_frames = {s: backend.link_name(j) for s, j in backend.ft_joints.items()}
        bag = BagWriter(bag_path, tuple(backend.joint_names), ft_frames, backend.root_link)
        summary["bag"] = str(bag_path)
    duration = plan_duration(whole)
    snap_times = list(np.linspace(0.0, duration + cs.settle_time_s, req.snapshots)) if req.snapshots else []
    cones = {limb: [] for limb in LIMBS}  # limb -> (normal [N], tangential [N], mu [-]) samples
    surface_mu = {name: float(s.friction) for name, s in backend.env.surfaces.items()}
    tick = [0]
    current = [-1]
    active = [whole]  # the plan being executed (replanning appends the next ones)
    done_before = [0]  # transitions of the plans executed before it
    # descent: the first transition after the climb (the up plan's end) and the feet seen there
    n_up = summary.get("descent_start_transition") if req.descend else None
    top_feet: dict = {}

    def on_tick(sim_state, output) -> None:
        k = tick[0]
        tick[0] += 1
        index = controller.transition_index
        plan_now = active[-1]
        if index != current[0] and 0 <= index < len(plan_now.transitions):
            if index == n_up:
                top_feet.update(judge.feet_rungs(backend, cs.foot_force_min))
            current[0] = index
            t = plan_now.transitions[index]
            say(f"t = {sim_state.time:6.2f} s  transition {done_before[0] + index + 1}/"
                f"{done_before[0] + len(plan_now.transitions)}: {t.primitive} {t.moving_limb}")
        log.tick_ms.append(float(output.status.tick_time_ms))
        log.qp_ms.append(float(output.status.qp_solve_time_ms))
        log.max_current_ratio.append(runner.log.max_current_ratio[-1] if runner.log.max_current_ratio else 0.0)
        if k % log_every == 0:
            sample(log, backend, sim_state, output, controller)
            grasped = {h for h, s in sim_state.grasps.items() if s}
            for limb in LIMBS:
                load = log.loads[limb][-1]
                if load is not None and limb not in grasped and load[0] >= cs.cone_force_min:
                    cones[limb].append((load[0], load[1], surface_mu.get(load[2], float("nan"))))
        if bag is not None and k % bag_every == 0:
            bag.write(sim_state, output)
        if snap_times and sim_state.time >= snap_times[0]:
            snap_times.pop(0)
            out.frames.append((float(sim_state.time), snapshot(backend, cs)))

    runner.on_tick.append(on_tick)
    controller.set_plan(whole)
    say(f"executing in {req.mode} mode ({duration:.1f} s of plan)")
    t0 = time.perf_counter()
    stop = ("hold", "failure", "replan_needed")
    runner.run(duration + cs.extra_time_s, until=lambda o: o.status.fsm_state in stop)
    replans: list[dict] = []
    cycles = cycles_planned
    while (replanner is not None and cycles < req.rungs and controller.fsm.state == "hold"
           and not runner.sim_state.fell):
        stance = active[-1].transitions[-1].target_stance  # the stance the controller holds
        nxt, k, record = replanner(runner.robot_state().q, stance, cycles)
        record["sim_time_s"] = round(float(runner.sim_state.time), 3)
        replans.append(record)
        if nxt is None:
            break
        cycles += k
        done_before[0] += len(active[-1].transitions)
        active.append(nxt)
        current[0] = -1
        controller.set_plan(nxt)
        # transition_index is -1 until the FSM has picked the new plan's first transition
        runner.run(plan_duration(nxt) + cs.extra_time_s,
                   until=lambda o: controller.transition_index >= 0 and o.status.fsm_state in stop)
    if len(active) > 1:
        out.plan = replace(whole, transitions=[t for p in active for t in p.transitions])
        summary["replans"] = replans
    if controller.fsm.state == "hold" and not runner.sim_state.fell:
        runner.run(cs.settle_time_s)
    out.wall_time_s = time.perf_counter() - t0
    if bag is not None:
        bag.close()
    if req.snapshots:
        out.frames.append((float(runner.sim_state.time), snapshot(backend, cs)))
        out.frames = out.frames[-req.snapshots:] if len(out.frames) > req.snapshots else out.frames
    state = runner.sim_state
    loads = judge.limb_loads(backend)
    feet = judge.feet_rungs(backend, cs.foot_force_min, loads)
    reached = judge.rungs_reached(feet)
    ticks = np.asarray(log.tick_ms)
    out.cone_samples = cones
    fsm_state = controller.fsm.state
    summary.update({
        "rungs_reached": reached,
        "sim_time_s": round(float(state.time), 3),
        "fell": bool(state.fell),
        "control_tick_ms": {"p50": round(float(np.percentile(ticks, 50)), 3),
                            "p99": round(float(np.percentile(ticks, 99)), 3),
                            "max": round(float(ticks.max()), 3)} if len(ticks) else None,
        "wall_time_s": round(out.wall_time_s, 2),
        "real_time_factor": round(float(state.time) / out.wall_time_s, 3) if out.wall_time_s > 0 else 0.0,
        "fsm_state": fsm_state,
        "transitions_done": done_before[0] + int(max(controller.transition_index, 0)),
        "n_transitions": done_before[0] + len(active[-1].transitions),
        "qp_failures": int(controller.qp_failures),
        "feet_rungs": {f: feet[f] for f in FEET},
        "grasps": dict(state.grasps),
        # largest tangential / (mu normal) of each unilateral contact over the run (cone: <= 1)
        "max_cone_use": {limb: round(max((t / (mu * n) for n, t, mu in v), default=0.0), 3)
                         for limb, v in cones.items() if v},
    })
    if req.mode == "compliance":
        summary["motor_trips"] = sorted(runner.log.tripped)
        summary["max_current_ratio"] = round(max(log.max_current_ratio, default=0.0), 3)
    reasons = []
    if state.fell:
        reasons.append(f"fell: {state.fall_reason}")
    if fsm_state != "hold":
        reasons.append(f"controller ended in {fsm_state} at transition {done_before[0] + controller.transition_index} "
                       f"of {done_before[0] + len(active[-1].transitions)}")
    if replans and "failure_reason" in replans[-1]:
        reasons.append(f"replanning after {cycles} cycle(s): {replans[-1]['failure_reason']}")
    if req.descend:
        summary["top_feet_rungs"] = {f: top_feet.get(f) for f in FEET}
        top = judge.rungs_reached(top_feet) if top_feet else 0
        if req.max_transitions is None and top < req.rungs:
            reasons.append(f"feet on rungs {top_feet or 'never seen'} when the descent began "
                           f"(need both on rung >= {req.rungs})")
        if req.max_transitions is None and any(feet[f] != 0 for f in FEET):
            reasons.append(f"feet on {feet} at the end of the descent (need both on the ground)")
    elif req.max_transitions is None and reached < req.rungs:
        reasons.append(f"feet on rungs {feet} (need both on rung >= {req.rungs})")
    summary["success"] = not reasons
    summary["failure_reason"] = "; ".join(reasons)
    say(f"done: {summary['failure_reason'] or 'success'}")


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
