"""Motion primitive adaptation (ladder_climbing_drc_hubo.txt III-C): Algorithm 1 and Adapt-Primitive.

Adapt-Primitive(Q̄, q_s, σ_s):

1. sample the ending stance σ_e around the primitive's seed hold (:func:`sample_target_hold`;
   attempt 0 takes the seed hold itself, later attempts perturb it, attempts 3 and 4 of a hand
   primitive try the neighbouring rungs);
2. compute q_e ∈ F(σ_e) by projecting the primitive's end configuration (:func:`project`,
   Algorithm 1: Newton-Raphson contact projection from increasingly perturbed seeds, then a
   collision retraction / physics repair with the physics-constrained IK); a landing grasp rolled
   about its rung is projected again at its nominal roll, and a designed end posture that does
   not fit the ladder at all is replaced by the current one (:func:`end_configuration`);
3. linearly transform the primitive's way-points onto (q_s, q_e)
   (:func:`planner_node.interpolation.linear_transform`); a way-point whose moving hand or foot strays from
   its design cue (e.g. the back-off along the palm normal, relative to the actual grasps) is
   moved back onto it (:func:`retarget_poses`): the joint-space offsets alone bend the hand's
   path on ladders far from the reference;
4. project every way-point onto the transition stance σ_t = σ_e minus the moving limb and retract
   the colliding ones (milestones), then interpolate between milestones while keeping the contact
   constraints (recursive projected bisection);
5. fine-discretise and check feasibility (:func:`climb_core.feasibility.check`: contacts, joint
   limits, collisions, quasi-static equilibrium with torque and grip limits).

Any failing step returns an :class:`~planner_node.msp.AttemptFailure` naming the constraint.

Release and approach zones: while the moving limb is within ``contact_exclusion_distance_*`` of
the hold it leaves or the hold it reaches, its collision with that surface is the contact being
broken or made and is not counted (FIELD_NOTES: switch the pair off while a contact is made).
:func:`zone_exclusions` is the one rule, used by the planner and by :mod:`planner_node.verify`.
"""
from __future__ import annotations

import collections
import dataclasses
import math
import time
from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np
import pinocchio as pin

from climb_core import feasibility
from climb_core import holds as holds_mod
from climb_core import ik as core_ik
from climb_core.contact import FEET, HANDS, Hold, Stance, Transition
from climb_core.errors import SpecError

from . import interpolation as interp
from . import pcik
from .msp import AttemptFailure, Step
from .primitives import Primitive, PrimitiveLibrary, point_to_world, to_world
from .settings import PlannerSettings

SKIP = "skip"


# --------------------------------------------------------------------------------------------
# state and context


@dataclass(frozen=True)
class ClimbState:
    """Search state: a configuration and the stance it realises."""

    q: np.ndarray
    stance: Stance


def rung_index(surface: str) -> int:
    """0 for the ground, k for rung_k, -1 otherwise."""
    if surface == "ground":
        return 0
    if surface.startswith("rung_"):
        try:
            return int(surface[5:])
        except ValueError:
            return -1
    return -1


def limb_rung(stance: Stance, limb: str) -> int | None:
    h = stance.hold(limb)
    return None if h is None else rung_index(h.env_surface)


@dataclass
class AdaptStats:
    projections: int = 0
    ik_calls: int = 0
    pcik_calls: int = 0
    pcik_successes: int = 0
    checks: int = 0
    interpolation_projections: int = 0
    retargeted: int = 0  # way-points moved onto their design cue's pose
    cue_retractions: int = 0  # way-points retracted while keeping the moving limb near its cue
    time_ik_s: float = 0.0
    time_pcik_s: float = 0.0
    time_check_s: float = 0.0

    def as_dict(self) -> dict:
        return dataclasses.asdict(self)


class AdaptContext:
    """Everything an adaptation needs: robot, environment, library, parameters, check configs."""

    def __init__(self, robot: Any, env: Any, library: PrimitiveLibrary, settings: PlannerSettings,
                 feasibility_cfg: feasibility.FeasibilityConfig | None = None):
        self.robot = robot
        self.env = env
        self.library = library
        self.settings = settings
        self.frozen_cfg = feasibility_cfg or feasibility.load_config()
        p = settings.planning
        placement = {}
        if p.foot_on_rung_pitch_deg:  # the holds this plan makes (a hold keeps its pitch: the checks read it there)
            placement["foot_on_rung_pitch_deg"] = p.foot_on_rung_pitch_deg
        offset = library.holds.get("foot_on_rung_offset") if library is not None else None
        if offset is not None:  # where the library's design put the soles on the rungs (TALOS: the ball of the
            placement["foot_on_rung_offset"] = float(offset)  # foot; the checks judge the rung line under the sole)
        if placement:
            self.frozen_cfg = dataclasses.replace(self.frozen_cfg, holds=dataclasses.replace(
                self.frozen_cfg.holds, **placement))
        # the planner's own checks: the frozen check with planning margins on top
        self.check_cfg = feasibility.with_check(
            self.frozen_cfg,
            collision_margin=max(self.frozen_cfg.check.collision_margin, p.collision_margin),
            torque_limit_fraction=min(self.frozen_cfg.check.torque_limit_fraction, p.torque_limit_fraction),
            grip_limit_fraction=min(self.frozen_cfg.check.grip_limit_fraction, p.grip_limit_fraction),
            friction_margin=min(self.frozen_cfg.check.friction_margin, p.friction_margin),
            min_normal_force=max(self.frozen_cfg.check.min_normal_force, p.min_normal_force),
            grasp_moment_limit=feasibility.tighter_moment_limit(self.frozen_cfg.check.grasp_moment_limit,
                                                                p.grasp_moment_limit),
            sole_cop_margin=max(self.frozen_cfg.check.sole_cop_margin, p.sole_cop_margin))
        self.hold_params = self.frozen_cfg.holds
        base_ik = core_ik.load_ik_params()
        self.ik_params = dataclasses.replace(base_ik, restarts=0)
        self.stats = AdaptStats()
        # id(state) -> (state, the state with its grasps latched): every attempt from one state sees
        # the same Hold objects (the feasibility check caches compiled stances by their holds' ids)
        self.latched: dict[int, tuple[Any, Any]] = {}
        self._targets: dict[int, tuple[Hold, np.ndarray]] = {}
        self._cues: dict[int, tuple[Primitive, Any]] = {}  # limb_cues per primitive

    # ---------------------------------------------------------------- checks
    def check(self, q: np.ndarray, stance: Stance, exclusions: Sequence[tuple[str, str]] = ()
              ) -> feasibility.FeasibilityResult:
        t0 = time.perf_counter()
        res = pcik.check_with_exclusions(self.robot, self.env, q, stance, self.check_cfg, extra_exclusions=exclusions,
                                         self_margin=self.settings.planning.self_collision_margin)
        self.stats.checks += 1
        self.stats.time_check_s += time.perf_counter() - t0
        return res

    def hold_origin(self, hold: Hold) -> np.ndarray:
        """[m] world position of the robot surface frame when ``hold`` is made (cached per hold)."""
        key = id(hold)
        hit = self._targets.get(key)
        if hit is None or hit[0] is not hold:  # the hold is kept in the entry: its id cannot be reused
            origin = np.asarray(holds_mod.hold_target(self.robot, self.env, hold, params=self.hold_params)
                                .T_world_surface)[:3, 3].copy()
            hit = (hold, origin)
            self._targets[key] = hit
        return hit[1]


def failure_name(res: feasibility.FeasibilityResult) -> str:
    """Short name of the first violated constraint, with the colliding pair for collisions."""
    if not res.violated:
        return ""
    first = res.violated[0]
    if first == "collision":
        pairs = res.details.get("collisions") or []
        if pairs:
            a, b, _ = min(pairs, key=lambda t: t[2])
        else:
            a, b = res.closest_pair
        return f"collision:{a}|{b.removeprefix('env:')}"
    return first


# --------------------------------------------------------------------------------------------
# release / approach zones


def zone_exclusions(ctx: AdaptContext, q: np.ndarray, limb: str, holds: Sequence[Hold]) -> list[tuple[str, str]]:
    """(limb, surface) pairs allowed to touch at q: the moving limb near the hold it leaves / reaches
    (the distance of the hold's own robot surface - a hand's palm or grasp - to where the hold puts it)."""
    if not limb:
        return []
    p = ctx.settings.interpolation
    radius = p.exclusion_distance_hand if limb in HANDS else p.exclusion_distance_foot
    out = []
    for h in holds:
        if h is None or h.limb != limb:
            continue
        T = ctx.robot.T_world_surface(limb, q, surface=h.robot_surface)
        if float(np.linalg.norm(T[:3, 3] - ctx.hold_origin(h))) <= radius:
            out.append((limb, h.env_surface))
    return out


# --------------------------------------------------------------------------------------------
# fast contact projection (interpolation): Gauss-Newton on the core IK's pose errors


class ContactProjector:
    """Projection onto the contact manifold of a stance (minimum-norm Gauss-Newton steps)."""

    def __init__(self, ctx: AdaptContext, stance: Stance, q_seed: np.ndarray, max_iterations: int = 12):
        self.ctx = ctx
        self.model = ctx.robot.model
        self.data = self.model.createData()
        self.tasks = core_ik.contact_tasks(ctx.robot, ctx.env, q_seed, stance, ctx.hold_params) if stance.holds else []
        self.w_ang = ctx.ik_params.orientation_weight
        self.tol_p = ctx.ik_params.position_tolerance
        self.tol_a = ctx.ik_params.angle_tolerance
        self.max_iterations = max_iterations
        self.lo = self.model.lowerPositionLimit[7:]
        self.hi = self.model.upperPositionLimit[7:]

    def errors(self, q: np.ndarray) -> tuple[float, float]:
        pin.computeJointJacobians(self.model, self.data, q)
        _, _, per = core_ik.task_errors(self.model, self.data, self.tasks, self.w_ang, with_jacobian=False)
        return max((a for a, _ in per), default=0.0), max((b for _, b in per), default=0.0)

    def __call__(self, q: np.ndarray, cue: tuple[str, np.ndarray] | None = None) -> np.ndarray | None:
        """q moved onto the stance's contacts; with ``cue`` = (limb, 4x4 T_world_surface) the free
        limb is put at that pose too (a re-targeted way-point), None when that is not reachable."""
        self.ctx.stats.interpolation_projections += 1
        q = np.asarray(q, dtype=float).copy()
        tasks = self.tasks
        if cue is not None:
            tasks = tasks + core_ik.contact_tasks(self.ctx.robot, None, q, {cue[0]: np.asarray(cue[1], dtype=float)},
                                                  None)
        if not tasks:
            return q
        for _ in range(self.max_iterations):
            pin.computeJointJacobians(self.model, self.data, q)
            e, J, per = core_ik.task_errors(self.model, self.data, tasks, self.w_ang, with_jacobian=True)
            pos = max((a for a, _ in per), default=0.0)
            ang = max((b for _, b in per), default=0.0)
            if pos <= self.tol_p and ang <= self.tol_a:
                return q
            JJt = J @ J.T + 1e-8 * np.eye(len(e))
            dq = -J.T @ np.linalg.solve(JJt, e)
            q = pin.integrate(self.model, q, dq)
            q[7:] = np.clip(q[7:], self.lo, self.hi)
        pin.computeJointJacobians(self.model, self.data, q)
        _, _, per = core_ik.task_errors(self.model, self.data, tasks, self.w_ang, with_jacobian=False)
        pos, ang = max((a for a, _ in per), default=0.0), max((b for _, b in per), default=0.0)
        return q if (pos <= self.tol_p and ang <= self.tol_a) else None


# --------------------------------------------------------------------------------------------
# Algorithm 1: project a configuration onto F(stance)


@dataclass
class Projection:
    q: np.ndarray | None
    failure: str = ""
    failures: collections.Counter = field(default_factory=collections.Counter)
    result: feasibility.FeasibilityResult | None = None


def _perturb(ctx: AdaptContext, q: np.ndarray, i: int, rng: np.random.Generator) -> np.ndarray:
    p = ctx.settings.projection
    model = ctx.robot.model
    dv = np.zeros(model.nv)
    dv[:3] = rng.normal(0.0, i * p.perturbation_base, 3)
    dv[6:] = rng.normal(0.0, i * p.perturbation_joint, model.nv - 6)
    out = pin.integrate(model, q, dv)
    out[7:] = np.clip(out[7:], model.lowerPositionLimit[7:], model.upperPositionLimit[7:])
    return out


def project(ctx: AdaptContext, q_bar: np.ndarray, stance: Stance, rng: np.random.Generator, *,
            unload: Sequence[str] = (), com_target: np.ndarray | None = None,
            exclusions: Sequence[tuple[str, str]] = (), restarts: int | None = None,
            pinned: dict[str, np.ndarray] | None = None) -> Projection:
    """Algorithm 1: q ∈ F(stance) near q_bar; with ``unload``, the stance minus each listed limb
    must be feasible too (that limb carries no force: it is about to move, or has just landed).
    The physics-constrained IK repair treats the first listed limb as a zero-force contact.
    ``pinned``: limb -> 4x4 T_world_surface for holds whose free grasp roll is fixed instead."""
    ctx.stats.projections += 1
    robot, env = ctx.robot, ctx.env
    p = ctx.settings.projection
    unload = [u for u in unload if u and stance.hold(u) is not None]
    reduced = [(stance.without(u), [(u, stance.hold(u).env_surface)]) for u in unload]
    failures: collections.Counter = collections.Counter()

    def stable(q: np.ndarray) -> feasibility.FeasibilityResult:
        res = ctx.check(q, stance, exclusions)
        for st, excl in reduced:
            if not res.feasible:
                break
            res = ctx.check(q, st, list(exclusions) + excl)
        return res

    def contacts() -> list[pcik.ContactSpec]:
        out = []
        for h in stance.holds:
            kind = pcik.ZERO_FORCE if (unload and h.limb == unload[0]) else pcik.REGULAR
            out.append(pcik.ContactSpec(h.limb, kind, hold=h, pose=(pinned or {}).get(h.limb)))
        return out

    targets = {h.limb: (pinned or {}).get(h.limb, h) for h in stance.holds} if pinned else stance

    last = None
    repairs_left = p.repair_attempts
    for i in range((p.restarts if restarts is None else restarts) + 1):
        q0 = q_bar if i == 0 else _perturb(ctx, q_bar, i, rng)
        t0 = time.perf_counter()
        r = core_ik.solve(robot, env, q0, targets, posture=q_bar, com_target=com_target, params=ctx.ik_params,
                          hold_params=ctx.hold_params)
        ctx.stats.ik_calls += 1
        ctx.stats.time_ik_s += time.perf_counter() - t0
        if not r.success:
            worst = max(r.per_limb.items(), key=lambda kv: kv[1][0])[0] if r.per_limb else ""
            failures[f"reach:{worst}"] += 1
            continue
        res = stable(r.q)
        last = res
        if res.feasible:
            return Projection(r.q, "", failures, res)
        name = failure_name(res)
        self_collision = name.startswith("collision:") and not name.split("|")[-1] in env.surfaces
        repair = (p.retract and name.startswith("collision") and not self_collision) or \
                 (p.repair_equilibrium and not name.startswith("collision") and name not in ("contact", "joint_limits"))
        repair = repair and repairs_left > 0
        repairs_left -= int(repair)
        if repair:
            t0 = time.perf_counter()
            ctx.stats.pcik_calls += 1
            pr = pcik.solve(robot, env, r.q, contacts(), q_target=q_bar, params=ctx.settings.pcik,
                            feasibility_cfg=ctx.check_cfg, extra_exclusions=list(exclusions),
                            self_margin=ctx.settings.planning.self_collision_margin)
            ctx.stats.time_pcik_s += time.perf_counter() - t0
            if pr.success:
                res2 = stable(pr.q)
                if res2.feasible:
                    ctx.stats.pcik_successes += 1
                    return Projection(pr.q, "", failures, res2)
                name = failure_name(res2)
            elif pr.violated:
                name = pr.violated[0] if not pr.violated[0] == "collision" else name
        failures[name] += 1
    failure = failures.most_common(1)[0][0] if failures else "projection"
    return Projection(None, failure, failures, last)


# --------------------------------------------------------------------------------------------
# hold sampling


def _side(limb: str) -> float:
    return 1.0 if limb.startswith("left") else -1.0


def feet_height(ctx: AdaptContext, stance: Stance) -> float:
    zs = [h.centre[2] for h in stance.holds if h.limb in FEET]
    return float(np.mean(zs)) if zs else 0.0


def rung_heights(ctx: AdaptContext) -> np.ndarray:
    """[m] top height of rung 1..n (index 0 = rung 1)."""
    return np.array([ctx.env.surfaces[f"rung_{k}"].top_z for k in range(1, ctx.env.n_rungs + 1)])


def target_rung(ctx: AdaptContext, prim: Primitive, stance: Stance, attempt: int) -> int | None:
    """Rung index the primitive's seed hold is on (None: no such rung)."""
    lib = ctx.library
    current = limb_rung(stance, prim.limb)
    tops = rung_heights(ctx)
    if prim.target.rule == "next":
        k = (current or 0) + 1
    else:
        if prim.target.rule == "mount":
            z_goal = feet_height(ctx, stance) + lib.mount_height
        else:  # above_feet
            z_goal = feet_height(ctx, stance) + lib.hands_above_feet_height
        k = int(np.argmin(np.abs(tops - z_goal))) + 1
        if ctx.settings.sampling.alternative_rungs and attempt >= 3:
            k += 1 if attempt == 3 else -1
        if current is not None and current > 0:
            k = max(k, current)  # hands never move down while climbing up
    if k < 1 or k > ctx.env.n_rungs:
        return None
    return k


def ground_foot_x(hold_design: dict, inclination_deg: float) -> float:
    """[m] L-frame x of the soles on the ground before mounting: the design's value at 75 deg,
    moved back on steeper ladders by ``ground_foot_x_per_deg`` [m/deg] (rungs above the feet)."""
    return float(hold_design["ground_foot_x"]) + float(hold_design.get("ground_foot_x_per_deg", 0.0)) * (
        inclination_deg - 75.0)


def sample_target_hold(ctx: AdaptContext, prim: Primitive, state: ClimbState, attempt: int,
                       rng: np.random.Generator) -> Hold | str | None:
    """The sampled hold of the moving limb; SKIP when the limb is already there; None if no target."""
    robot, env = ctx.robot, ctx.env
    sp = ctx.settings.sampling
    limb = prim.limb
    old = state.stance.hold(limb)
    if prim.target.surface == "ground":
        lib = ctx.library
        p_l = np.array([ground_foot_x(lib.holds, float(env.scenario.ladder.inclination_deg)),
                        _side(limb) * lib.holds["ground_foot_y"], 0.0])
        if attempt > 0:
            p_l[:2] += np.clip(rng.normal(0.0, sp.ground_sigma, 2), -2 * sp.ground_sigma, 2 * sp.ground_sigma)
        p_w = point_to_world(env, p_l)
        yaw = math.atan2(env.T_world_ladder[1, 0], env.T_world_ladder[0, 0])
        if old is not None and old.env_surface == "ground" and attempt == 0:
            if np.linalg.norm(old.centre[:2] - p_w[:2]) <= ctx.settings.planning.approach_tolerance:
                return SKIP
        return holds_mod.make_hold(robot, env, limb, "ground", position=p_w, yaw=yaw, params=ctx.hold_params)
    k = target_rung(ctx, prim, state.stance, attempt)
    if k is None:
        return None
    surface = f"rung_{k}"
    if old is not None and old.env_surface == surface:
        return SKIP
    s = _side(limb) * prim.seed_s
    if attempt > 0:
        s += float(np.clip(rng.normal(0.0, sp.lateral_sigma), -sp.lateral_max, sp.lateral_max))
    half = 0.5 * float(env.surfaces[surface].length) - 0.05
    s = float(np.clip(s, -half, half))
    return holds_mod.make_hold(robot, env, limb, surface, s, params=ctx.hold_params)


def stance_anchor(stance: Stance) -> np.ndarray:
    return np.mean([h.centre for h in stance.holds], axis=0)


def _shift_base(q: np.ndarray, d: np.ndarray) -> np.ndarray:
    out = np.asarray(q, dtype=float).copy()
    out[:3] += d
    return out


# --------------------------------------------------------------------------------------------
# grasp roll


def grasp_pins(ctx: AdaptContext, q: np.ndarray, stance: Stance, moving_limb: str) -> dict[str, np.ndarray]:
    """Pinned pose [4x4] of the moving hand's new grasp: its hold's nominal pose (the design's
    convention: the palm on the robot's side of the rung, ``grasp_palm_angle_deg`` above the
    horizontal; the IK otherwise leaves the roll about the rung free); {} for a foot / no limb."""
    h = stance.hold(moving_limb) if moving_limb else None
    if h is None or not h.bilateral:
        return {}
    return {h.limb: nominal_grasp_pose(ctx, h, q)}


def nominal_grasp_pose(ctx: AdaptContext, hold: Hold, q: np.ndarray) -> np.ndarray:
    """[4x4] nominal T_world_surface of a grasp (of the two grasp axis directions, the one nearer
    the hand's orientation at q)."""
    seed = ctx.robot.T_world_surface(hold.limb, q)[:3, :3]
    return np.asarray(holds_mod.hold_target(ctx.robot, ctx.env, hold, params=ctx.hold_params,
                                            R_world_surface_seed=seed).T_world_surface)


def _rolled(ctx: AdaptContext, q: np.ndarray, pins: dict[str, np.ndarray]) -> bool:
    tol = ctx.settings.projection.grasp_roll_tolerance
    return any(pose_deviation(ctx.robot.T_world_surface(limb, q), T)[1] > tol for limb, T in pins.items())


def end_configuration(ctx: AdaptContext, q_bar: np.ndarray, q_s: np.ndarray, stance: Stance, moving_limb: str,
                      unload: Sequence[str], rng: np.random.Generator, fallbacks: bool = True) -> Projection:
    """Step 2 of Adapt-Primitive: q_e in F(stance) from the primitive's end configuration q_bar.

    With ``fallbacks`` (not for a contact plan's own end configurations), two more tries, each with
    ``projection.start_seed_restarts`` restarts:

    - a moving hand whose new grasp rolled about the rung by more than
      ``projection.grasp_roll_tolerance`` from the hold's nominal pose is projected again with that
      roll pinned (:func:`grasp_pins`; the free result is kept when this fails);
    - when q_bar cannot be projected at all (the designed posture does not fit this ladder, e.g.
      its pelvis placement on a much steeper one): the current configuration q_s, the moving limb
      brought to its new hold (a CoM primitive: the physics repair unloading the next limb).
    """
    pp = ctx.settings.projection
    proj = project(ctx, q_bar, stance, rng, unload=unload)
    if not fallbacks or pp.start_seed_restarts < 0:
        return proj
    if proj.q is not None:
        pins = grasp_pins(ctx, proj.q, stance, moving_limb)
        if not pins or pp.grasp_roll_tolerance < 0.0 or not _rolled(ctx, proj.q, pins):
            return proj
        alt = project(ctx, proj.q, stance, rng, unload=unload, pinned=pins, restarts=pp.start_seed_restarts)
        return alt if alt.q is not None else proj
    pins = grasp_pins(ctx, q_s, stance, moving_limb) if pp.grasp_roll_tolerance >= 0.0 else {}
    alt = project(ctx, q_s, stance, rng, unload=unload, pinned=pins or None, restarts=pp.start_seed_restarts)
    return alt if alt.q is not None else proj


# --------------------------------------------------------------------------------------------
# re-targeting the moving limb's way-points (Cartesian meaning of the design cues)


@dataclass(frozen=True)
class LimbCues:
    """The designed poses of a limb primitive's moving limb (reference ladder, ladder frame) at
    each way-point, and each one's anchor weight: 0 = placed relative to the start hold (e.g. the
    back-off along the palm normal), 1 = relative to the target hold, in between on the
    transfer between the last start cue and the first target cue."""

    poses: tuple  # 4x4 T_ladder_surface per way-point (q̄s .. q̄e)
    weights: np.ndarray  # (k + 2,) in [0, 1]


def _cue_polyline(prim: Primitive, P_s: np.ndarray, P_e: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Positions [m] (ladder frame) and anchor weights of the design's cue poses, start and end
    included (the same rule as scripts/make_primitives.py: ladder-frame y mirrored for right limbs)."""
    pts, w = [P_s[:3, 3].copy()], [0.0]
    for via in prim.via:
        T = P_s if via.get("from", "start") == "start" else P_e
        off = np.asarray(via.get("offset", [0.0, 0.0, 0.0]), dtype=float).copy()
        if via.get("frame", "ladder") == "surface":
            p = T[:3, 3] + T[:3, :3] @ off
        else:
            off[1] *= _side(prim.limb)
            p = T[:3, 3] + off
        pts.append(p)
        w.append(0.0 if via.get("from", "start") == "start" else 1.0)
    pts.append(P_e[:3, 3].copy())
    w.append(1.0)
    return np.array(pts), np.array(w)


def limb_cues(ctx: AdaptContext, prim: Primitive) -> LimbCues | None:
    """The primitive's :class:`LimbCues` (cached per primitive); None without way-points / cues.
    A way-point's weight is that of its closest point on the cue polyline (searched forward
    along the polyline, so a path that comes back near an earlier cue keeps its order)."""
    if not prim.is_limb or len(prim.waypoints) < 3:
        return None
    cache = ctx._cues
    hit = cache.get(id(prim))
    if hit is not None and hit[0] is prim:
        return hit[1]
    data = ctx.robot.model.createData()
    poses = tuple(np.array(ctx.robot.T_world_surface(prim.limb, q, data)) for q in prim.waypoints)
    pts, w_cue = _cue_polyline(prim, poses[0], poses[-1])
    weights = np.zeros(len(poses))
    seg = 0
    for i, P in enumerate(poses):
        p = P[:3, 3]
        best = (np.inf, seg, 0.0)
        for j in range(seg, len(pts) - 1):
            a, b = pts[j], pts[j + 1]
            ab = b - a
            t = float(np.clip(np.dot(p - a, ab) / max(float(ab @ ab), 1e-12), 0.0, 1.0))
            d = float(np.linalg.norm(a + t * ab - p))
            if d < best[0] - 1e-9:
                best = (d, j, t)
        _, seg, t = best
        weights[i] = (1.0 - t) * w_cue[seg] + t * w_cue[seg + 1]
    weights[0], weights[-1] = 0.0, 1.0
    out = LimbCues(poses, np.maximum.accumulate(weights))
    cache[id(prim)] = (prim, out)
    return out


def retarget_poses(ctx: AdaptContext, prim: Primitive, q_s: np.ndarray, q_e: np.ndarray,
                   start_hold: Hold | None = None, attempt: int = 0) -> list[np.ndarray] | None:
    """World poses [4x4] of the moving limb at each way-point with the design cues' meaning kept
    on this ladder: the designed pose relative to the limb's start pose (weight 0) or actual end
    pose (weight 1), the rigid correction blended on the Lie group in between. A grasp left
    (``start_hold``) counts from its nominal pose, as the design did: a grasp the IK rolled about
    its rung turns back about it within the release zone before backing off along the palm
    normal (the fingers and the thumb then clear the rungs as designed). A hand's back-off is
    lengthened on steep ladders, on odd attempts (:func:`hand_backoff_scale`)."""
    cues = limb_cues(ctx, prim)
    if cues is None:
        return None
    T_WL = pin.SE3(np.asarray(ctx.env.T_world_ladder, dtype=float))
    P_s = T_WL * pin.SE3(cues.poses[0])
    P_e = T_WL * pin.SE3(cues.poses[-1])
    T_s = (nominal_grasp_pose(ctx, start_hold, q_s) if start_hold is not None and start_hold.bilateral
           else ctx.robot.T_world_surface(prim.limb, q_s))
    T_e = ctx.robot.T_world_surface(prim.limb, q_e)
    C_s = pin.SE3(T_s) * P_s.inverse()
    C_e = pin.SE3(T_e) * P_e.inverse()
    d = pin.log6(C_s.inverse() * C_e)
    out = [(C_s * pin.exp6(float(w) * d) * T_WL * pin.SE3(P)).homogeneous for w, P in zip(cues.weights, cues.poses)]
    scale = hand_backoff_scale(ctx, attempt)
    if scale != 1.0 and prim.type == "place_hand":
        # z of a grasp surface points into its rung: a way-point's back-off is its distance behind
        # the start / target grasp along it, blended by the cue weight like the correction above
        n_s, n_e = np.asarray(T_s)[:3, 2], T_e[:3, 2]
        p_s, p_e = np.asarray(T_s)[:3, 3], T_e[:3, 3]
        for i in range(1, len(out) - 1):
            w, p = float(cues.weights[i]), out[i][:3, 3]
            away = -((1.0 - w) * n_s + w * n_e)
            back = (1.0 - w) * float((p_s - p) @ n_s) + w * float((p_e - p) @ n_e)
            if back > 0.0:
                out[i][:3, 3] = p + (scale - 1.0) * back * away / max(float(np.linalg.norm(away)), 1e-9)
    return out


def hand_backoff_scale(ctx: AdaptContext, attempt: int) -> float:
    """The back-off scale of a hand transfer's ``attempt`` (of one library) on this ladder:
    ``interpolation.hand_backoff_scale`` for the odd attempts on ladders at least
    ``hand_backoff_min_incline_deg`` steep, else 1. Each library's seed attempt keeps the design's
    back-off: on the grid's 82-90 deg ladders the longer one planned some that the design's did
    not and lost others that it plans (docs/planner.md), so both are tried."""
    ip = ctx.settings.interpolation
    ladder = getattr(getattr(ctx.env, "scenario", None), "ladder", None)
    if (ladder is None or attempt % 2 == 0
            or float(ladder.inclination_deg) < ip.hand_backoff_min_incline_deg - 1e-9):
        return 1.0
    return ip.hand_backoff_scale


def pose_deviation(T_a: np.ndarray, T_b: np.ndarray) -> tuple[float, float]:
    """([m] position distance, [rad] rotation angle) between two poses."""
    ang = float(np.linalg.norm(pin.log3(np.asarray(T_a)[:3, :3].T @ np.asarray(T_b)[:3, :3])))
    return float(np.linalg.norm(T_a[:3, 3] - T_b[:3, 3])), ang


# --------------------------------------------------------------------------------------------
# paths


def _interpolate_milestones(ctx: AdaptContext, milestones: list[np.ndarray], projector: ContactProjector,
                            cache: dict | None = None) -> list[np.ndarray] | None:
    """Projected interpolation through the milestones; ``cache`` (one per path under repair) keeps
    the sections between unchanged milestone pairs (the projection is deterministic)."""
    ip = ctx.settings.interpolation
    path = [milestones[0]]
    for qa, qb in zip(milestones[:-1], milestones[1:]):
        key = (qa.tobytes(), qb.tobytes())
        seg = cache.get(key) if cache is not None else None
        if seg is None:
            seg = interp.projected_interpolation(ctx.robot.model, qa, qb, projector, ip.max_step, ip.base_scale,
                                                 ip.max_depth)
            if seg is None:
                return None
            if cache is not None:
                cache[key] = seg
        path.extend(seg[1:])
    return path


def _retract(ctx: AdaptContext, q: np.ndarray, stance: Stance, limb: str, zone_holds: Sequence[Hold],
             q_target: np.ndarray, rng: np.random.Generator | None = None, cue: np.ndarray | None = None
             ) -> np.ndarray | None:
    """Retraction: physics-constrained IK from q on the stance (moving limb free), then from
    increasingly perturbed copies of q (``projection.retract_tries``), each result checked. With
    ``cue`` (4x4 pose of the moving limb) a first try pulls the limb toward it (a soft zero-force
    contact: as close as the constraints allow), its result polished onto the stance."""
    rng = rng if rng is not None else np.random.default_rng(0)
    if cue is not None and limb:
        contacts = pcik.contacts_from_stance(stance) + [pcik.ContactSpec(limb, pcik.ZERO_FORCE, pose=cue, soft=True)]
        t0 = time.perf_counter()
        ctx.stats.pcik_calls += 1
        pr = pcik.solve(ctx.robot, ctx.env, q, contacts, q_target=q_target, params=ctx.settings.pcik,
                        feasibility_cfg=ctx.check_cfg, extra_exclusions=zone_exclusions(ctx, q, limb, zone_holds),
                        self_margin=ctx.settings.planning.self_collision_margin, final_check=False)
        ctx.stats.time_pcik_s += time.perf_counter() - t0
        if not [v for v in pr.violated if v != f"reach:{limb}"]:  # the kept holds are made
            q_c = ContactProjector(ctx, stance, pr.q)(pr.q)
            if q_c is not None and ctx.check(q_c, stance, zone_exclusions(ctx, q_c, limb, zone_holds)).feasible:
                ctx.stats.pcik_successes += 1
                ctx.stats.cue_retractions += 1
                return q_c
    for k in range(max(1, ctx.settings.projection.retract_tries)):
        seed = q if k == 0 else _perturb(ctx, q, k, rng)
        t0 = time.perf_counter()
        ctx.stats.pcik_calls += 1
        excl = zone_exclusions(ctx, seed, limb, zone_holds)
        pr = pcik.solve(ctx.robot, ctx.env, seed, stance, q_target=q_target, params=ctx.settings.pcik,
                        feasibility_cfg=ctx.check_cfg, extra_exclusions=excl,
                        self_margin=ctx.settings.planning.self_collision_margin)
        ctx.stats.time_pcik_s += time.perf_counter() - t0
        if not pr.success:
            continue
        excl = zone_exclusions(ctx, pr.q, limb, zone_holds)
        if not ctx.check(pr.q, stance, excl).feasible:
            continue
        ctx.stats.pcik_successes += 1
        return pr.q
    return None


def build_path(ctx: AdaptContext, milestones: list[np.ndarray], stance: Stance, limb: str,
               zone_holds: Sequence[Hold]) -> tuple[list[np.ndarray] | None, list[np.ndarray], str]:
    """Projected interpolation through the milestones, fine-checked. Each infeasible section of the
    path is retracted at its middle configuration (physics-constrained IK), which becomes a new
    milestone; up to ``max_repairs`` rounds. Returns (path or None, final milestones, failure)."""
    projector = ContactProjector(ctx, stance, milestones[0])
    repairs = ctx.settings.interpolation.max_repairs
    milestones = list(milestones)
    res = None
    # a repair round changes the path next to the new milestones only: the rest is not redone
    sections: dict = {}
    checked: dict = {}
    for _ in range(repairs + 1):
        path = _interpolate_milestones(ctx, milestones, projector, sections)
        if path is None:
            return None, milestones, "interpolation"
        bad = _bad_sections(ctx, path, stance, limb, zone_holds, checked)
        if not bad:
            return path, milestones, ""
        res = bad[0][2]
        inserts = []
        for lo, hi, res_k in bad:
            q_fix, at = None, lo
            for at in dict.fromkeys(((lo + hi) // 2, lo, hi)):  # the middle, then the section's ends
                q_fix = _retract(ctx, path[at], stance, limb, zone_holds, q_target=path[at])
                if q_fix is not None:
                    break
            if q_fix is None:
                return None, milestones, failure_name(res_k)
            inserts.append((_segment_index(ctx, milestones, path, at), q_fix))
        for idx, q_fix in sorted(inserts, key=lambda t: -t[0]):
            milestones.insert(idx + 1, q_fix)
    return None, milestones, failure_name(res) if res is not None else "interpolation"


def _bad_sections(ctx: AdaptContext, path: list[np.ndarray], stance: Stance, limb: str,
                  zone_holds: Sequence[Hold], cache: dict | None = None
                  ) -> list[tuple[int, int, feasibility.FeasibilityResult]]:
    """Contiguous runs [lo, hi] of infeasible interior configurations, with the first result of
    each; ``cache`` keeps the results of configurations already checked (same stance and zone)."""
    out: list[tuple[int, int, feasibility.FeasibilityResult]] = []
    run_lo, run_res = -1, None
    for i in range(1, len(path) - 1):
        key = path[i].tobytes()
        res = cache.get(key) if cache is not None else None
        if res is None:
            res = ctx.check(path[i], stance, zone_exclusions(ctx, path[i], limb, zone_holds))
            if cache is not None:
                cache[key] = res
        if not res.feasible:
            if run_lo < 0:
                run_lo, run_res = i, res
        elif run_lo >= 0:
            out.append((run_lo, i - 1, run_res))
            run_lo = -1
    if run_lo >= 0:
        out.append((run_lo, len(path) - 2, run_res))
    return out


def _segment_index(ctx: AdaptContext, milestones: list[np.ndarray], path: list[np.ndarray], i: int) -> int:
    """Index of the milestone that starts the segment holding path[i]."""
    j = 0
    for k in range(1, i + 1):
        if j + 1 < len(milestones) and np.allclose(path[k], milestones[j + 1], atol=1e-12):
            j += 1
    return min(j, len(milestones) - 2)


def make_transition(ctx: AdaptContext, prim: Primitive, stance: Stance, target: Stance, path: list[np.ndarray]
                    ) -> Transition:
    times = interp.time_transition(ctx.robot.model, path, stance, ctx.settings.timing)
    return Transition(primitive=prim.type, moving_limb=prim.limb if prim.is_limb else "", stance=stance,
                      target_stance=target, times=times, path=np.array(path))


# --------------------------------------------------------------------------------------------
# Adapt-Primitive


@dataclass
class Segment:
    """What one successful adaptation adds to the plan (None transition: nothing to do)."""

    primitive: str
    transition: Transition | None
    hold: Hold | None = None
    attempt: int = 0


def latch_grasps(ctx: AdaptContext, state: ClimbState) -> ClimbState:
    """``state`` with every closed grasp of its stance latched at its pose in ``state.q``: from here
    on the hand keeps that roll about the rung (``projection.latch_grasps``; a hold that already has
    a pose keeps it)."""
    if not ctx.settings.projection.latch_grasps:
        return state
    hit = ctx.latched.get(id(state))
    if hit is not None and hit[0] is state:
        return hit[1]
    holds = []
    for h in state.stance.holds:
        if h.bilateral and h.pose is None:
            T = ctx.robot.T_world_surface(h.limb, state.q, surface=h.robot_surface)
            h = dataclasses.replace(h, pose=tuple(tuple(float(x) for x in row) for row in T))
        holds.append(h)
    latched = state if all(a is b for a, b in zip(holds, state.stance.holds)) else \
        ClimbState(state.q, Stance(tuple(holds), name=state.stance.name))
    if len(ctx.latched) > 512:
        ctx.latched.clear()
    ctx.latched[id(state)] = (state, latched)
    return latched


def adapt_primitive(ctx: AdaptContext, prim: Primitive, state: ClimbState, attempt: int,
                    rng: np.random.Generator) -> Step | AttemptFailure:
    """Adapt-Primitive(Q̄, q_s, σ_s) for one attempt (see the module docstring)."""
    try:
        if prim.is_limb:
            return _adapt_limb(ctx, prim, state, attempt, rng)
        return _adapt_com(ctx, prim, state, attempt, rng)
    except SpecError as exc:  # e.g. a grasp asked on a tread: this library cannot hold that surface
        return AttemptFailure(f"hold:{exc.field}", f"{prim.name}: {exc}", fatal=True)


def _world_waypoints(ctx: AdaptContext, prim: Primitive) -> list[np.ndarray]:
    return [to_world(ctx.env, w) for w in prim.waypoints]


def _adapt_limb(ctx: AdaptContext, prim: Primitive, state: ClimbState, attempt: int,
                rng: np.random.Generator, hold: Hold | None = None,
                q_end_seed: np.ndarray | None = None) -> Step | AttemptFailure:
    """Adapt-Primitive for a limb transfer; ``hold`` / ``q_end_seed`` fix the ending hold and
    seed the end configuration (a contact plan's next stance and transition configuration)
    instead of sampling around the seed hold."""
    state = latch_grasps(ctx, state)
    limb = prim.limb
    old = state.stance.hold(limb)
    if hold is None:
        hold = sample_target_hold(ctx, prim, state, attempt, rng)
    if hold is None:
        return AttemptFailure("no_target", f"{prim.name}: no rung for the seed hold (the ladder is too short)",
                              fatal=attempt == 0)
    if isinstance(hold, str) and hold == SKIP:
        return Step(state, Segment(prim.name, None, old, attempt))
    sigma_e = state.stance.with_hold(hold)
    sigma_e = Stance(sigma_e.holds, name=f"{prim.name}")
    sigma_t = Stance(tuple(h for h in sigma_e.holds if h.limb != limb), name=f"{prim.name}:transfer")
    wps = _world_waypoints(ctx, prim)
    d_end = stance_anchor(sigma_e) - point_to_world(ctx.env, prim.anchor_end)
    q_bar_e = _shift_base(wps[-1], d_end) if q_end_seed is None else np.asarray(q_end_seed, dtype=float)
    if attempt > 0 and q_end_seed is not None:
        q_bar_e = _perturb(ctx, q_bar_e, attempt, rng)
    proj = end_configuration(ctx, q_bar_e, state.q, sigma_e, limb, prim.end_unload, rng,
                             fallbacks=q_end_seed is None)
    if proj.q is None:
        return AttemptFailure(proj.failure, f"{prim.name}: end configuration ({dict(proj.failures)})")
    q_e = proj.q
    q_s = state.q
    moved = interp.linear_transform(ctx.robot.model, wps, q_s, q_e, ctx.settings.interpolation.base_scale)
    zone = [old, hold]
    projector = ContactProjector(ctx, sigma_t, q_s)
    ip = ctx.settings.interpolation
    # the design cues' Cartesian meaning on this ladder (the joint-space transform bends it)
    wanted = ip.retarget_mount if prim.type == "mount" else ip.retarget_hands if limb in HANDS else ip.retarget_feet
    cue_poses = retarget_poses(ctx, prim, q_s, q_e, old, attempt) if wanted else None
    milestones = [q_s]
    for i, q_i in enumerate(moved[1:-1], start=1):
        if attempt > 0:  # later attempts also explore around the primitive's way-points
            q_i = _perturb(ctx, q_i, attempt, rng)
        q_p, cue = None, None
        if cue_poses is not None:
            dp, da = pose_deviation(ctx.robot.T_world_surface(limb, q_i), cue_poses[i])
            if dp > ip.retarget_position_tolerance or da > ip.retarget_angle_tolerance:
                cue = cue_poses[i]
                q_p = projector(q_i, cue=(limb, cue))
                if q_p is not None:
                    q_i = q_p
                    ctx.stats.retargeted += 1
        if q_p is None:
            q_p = projector(q_i)
        if q_p is None and attempt > 0:
            q_i = moved[i]  # the perturbation took it off the manifold's reach: the way-point itself
            q_p = projector(q_i)
        if q_p is None:
            return AttemptFailure(f"reach:{limb}", f"{prim.name}: way-point projection")
        res = ctx.check(q_p, sigma_t, zone_exclusions(ctx, q_p, limb, zone))
        if not res.feasible:
            q_r = _retract(ctx, q_p, sigma_t, limb, zone, q_target=q_i, cue=cue)
            if q_r is None:
                return AttemptFailure(failure_name(res), f"{prim.name}: way-point")
            q_p = q_r
        milestones.append(q_p)
    milestones.append(q_e)
    path, _, failure = build_path(ctx, milestones, sigma_t, limb, zone)
    if path is None:
        return AttemptFailure(failure, f"{prim.name}: path")
    transition = make_transition(ctx, prim, sigma_t, sigma_e, path)
    return Step(ClimbState(q_e, sigma_e), Segment(prim.name, transition, hold, attempt))


def _adapt_com(ctx: AdaptContext, prim: Primitive, state: ClimbState, attempt: int,
               rng: np.random.Generator, q_end_seed: np.ndarray | None = None) -> Step | AttemptFailure:
    state = latch_grasps(ctx, state)
    stance = state.stance
    wps = _world_waypoints(ctx, prim)
    d_end = stance_anchor(stance) - point_to_world(ctx.env, prim.anchor_end)
    q_bar_e = _shift_base(wps[-1], d_end) if q_end_seed is None else np.asarray(q_end_seed, dtype=float)
    if attempt > 0:
        q_bar_e = _perturb(ctx, q_bar_e, attempt, rng)
    # the way-points carry the designed CoM placement (make_primitives used com_over); the
    # projection keeps it and the stability check (with the unloaded limb) enforces equilibrium
    proj = end_configuration(ctx, q_bar_e, state.q, stance, "", prim.end_unload, rng,
                             fallbacks=q_end_seed is None and bool(prim.end_unload))
    if proj.q is None:
        return AttemptFailure(proj.failure, f"{prim.name}: end configuration ({dict(proj.failures)})")
    q_e = proj.q
    q_s = state.q
    moved = interp.linear_transform(ctx.robot.model, wps, q_s, q_e, ctx.settings.interpolation.base_scale)
    projector = ContactProjector(ctx, stance, q_s)
    milestones = [q_s]
    for q_i in moved[1:-1]:
        q_p = projector(q_i)
        if q_p is not None and ctx.check(q_p, stance).feasible:
            milestones.append(q_p)
    milestones.append(q_e)
    path, _, failure = build_path(ctx, milestones, stance, "", ())
    if path is None:
        return AttemptFailure(failure, f"{prim.name}: path")
    transition = make_transition(ctx, prim, stance, stance, path)
    return Step(ClimbState(q_e, stance), Segment(prim.name, transition, None, attempt))
