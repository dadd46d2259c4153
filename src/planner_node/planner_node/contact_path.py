"""Generic contact-body paths: a stance change of a contact plan without a motion primitive.

The contact search (multicontact_darpa_tasks.txt III-C) gives a stance sequence whose consecutive
stances differ by one hold, each with a transition configuration. Where no library primitive
fits a change, this module builds the whole-body path the way ladder_climbing_drc_hubo.txt builds
its primitives' paths (III-C, Algorithm 1 and the projected interpolation):

- **limb placed** (:func:`transfer_step`): Cartesian cues of the moving limb - lifted off its hold
  along the hold's normal by ``lift_clearance`` (a grasp: toward the body), carried to a point
  ``carry_backoff`` in front of the approach point, then brought onto the new hold along its
  normal from ``approach_distance``. Each cue becomes a whole-body way-point: the
  physics-constrained IK with the kept holds as regular contacts and the cue as a soft pose of the
  moving limb, seeded on the joint-space line between the two transition configurations, then
  retracted from collisions (:func:`planner_node.adapt._retract`). The path between the way-points
  is projected onto the kept stance's contact manifold and fine-checked
  (:func:`planner_node.adapt.build_path`); the end configuration has the limb on its new hold.
- **limb freed** (:func:`free_step`): a limb no later stance holds again is lifted off its hold
  and left free, the robot in equilibrium on the other holds.
- **CoM shift** (:func:`com_step`, also a contact plan's *release*): all holds kept, the end
  configuration in equilibrium without the limb that moves next. The controller's FSM releases
  that limb when it executes the next transition (select -> remove -> unload), as for ladder plans.

With ``contact_path.latch_grasps`` every step starts from its state with each closed grasp latched
at its roll about the bar (:func:`planner_node.adapt.latch_grasps`, as the primitive adaptation
does): the simulator's grasp is rigid, and a plan that rolls a held hand about its rail twists the
wrist against it (measured on the ship ladder: 0.6-0.8 rad of planned roll in a CoM shift, 1.1 rad
of wrist-yaw tracking error). Off by default (the stairs ladder's adaptation ran out of time with
it); the ship ladder's file sets it.

Both return an :class:`~planner_node.msp.Step` (or an AttemptFailure naming the constraint) whose
Transition the FSM executes: ``place_foot`` / ``place_hand`` with the moving limb (the FSM's
remove / add rows by limb kind), ``com_to_foot`` / ``com_to_centre`` without (its move_com row).
"""
from __future__ import annotations

import dataclasses
from typing import Sequence

import numpy as np
import pinocchio as pin

from climb_core import holds as holds_mod
from climb_core.contact import FEET, HANDS, Hold, Stance
from climb_core.errors import SpecError

from . import adapt as A
from . import pcik
from .msp import AttemptFailure, Step
from .primitives import PrimitiveLibrary


def empty_library(robot) -> PrimitiveLibrary:
    """A library without primitives for ``robot``: every contact-plan step takes a generic path."""
    return PrimitiveLibrary(robot=robot.config.name, strategy="none", facing="", reference_ladder={},
                            joint_names=tuple(robot.joint_names), sequences={}, primitives={}, holds={},
                            mount_height=0.0, hands_above_feet_height=0.0)


def transfer_name(limb: str) -> str:
    """The Transition.primitive of a limb placement (the FSM distinguishes hands and feet)."""
    return "place_hand" if limb in HANDS else "place_foot"


def com_name(unload: Sequence[str]) -> str:
    """The Transition.primitive of a CoM shift (toward the feet when a foot moves next)."""
    return "com_to_foot" if unload and unload[0] in FEET else "com_to_centre"


# --------------------------------------------------------------------------------------------
# Cartesian cues of the moving limb


def hold_direction(ctx: A.AdaptContext, hold: Hold, q: np.ndarray) -> np.ndarray:
    """Unit direction [world] a limb leaves / approaches ``hold`` along: the mean normal of a
    unilateral hold (toward the robot); for a grasp (normals all around the bar) the palm normal
    backward, -z of the limb's surface frame at ``q`` (z points out of the palm toward the bar,
    climb_core.holds)."""
    if not hold.bilateral:
        n = hold.normals.mean(axis=0)
        if np.linalg.norm(n) > 0.5:
            return n / np.linalg.norm(n)
    return -np.asarray(ctx.robot.T_world_surface(hold.limb, q))[:3, 2]


def limb_cues(ctx: A.AdaptContext, limb: str, old: Hold | None, new: Hold, q_s: np.ndarray,
              q_e: np.ndarray) -> tuple[list[np.ndarray], np.ndarray]:
    """World poses [4x4] of the moving limb's surface at the way-points and each one's path
    fraction in (0, 1) (arc length of the cue polyline from q_s to q_e): the lift-off (a held
    limb), then - when the front point is farther back than the lift-off - straight back to its
    distance at the lift-off height (a foot clears the rung above before rising; a foot released
    before this step, resting on its surface, is lifted straight up first; on a ladder the back-off
    is along the ladder, the sideways part of the move is made in the carry), - a foot going onto a
    higher flat surface (a step) - straight up to the front point's height, from where its sole's
    front is ``step_edge_clearance`` behind the surface's near edge (:func:`step_rise_distance`: a
    ship ladder's tread overhangs the one below) (down onto a lower one: the front point is over
    the approach point, at the lift-off height), the carry
    toward the front point (``carry_backoff`` behind the approach point, horizontally toward
    where the limb comes from), and the approach point on the new hold's normal. The orientation
    turns from the start's to the end's along the way (the lift-off keeps the start's, the
    approach has the end's)."""
    p = ctx.settings.contact_path
    robot = ctx.robot
    T_s = np.asarray(robot.T_world_surface(limb, q_s))
    T_e = np.asarray(robot.T_world_surface(limb, q_e))
    p_s, p_e = T_s[:3, 3], T_e[:3, 3]
    n_e = hold_direction(ctx, new, q_e)
    approach = p_e + p.approach_distance * n_e
    lift = p_s + p.lift_clearance * hold_direction(ctx, old, q_s) if old is not None else None
    back = p_s - p_e  # horizontal, toward where the limb comes from (across a bar: no sideways swing)
    back[2] = 0.0
    target = ctx.env.surfaces.get(new.env_surface)
    rung = target is not None and (target.shape == "cylinder" or holds_mod.is_bar(target))  # round or rect
    if target is not None and target.role in ("rung", "tread", "platform"):
        # along the ladder only: the sideways part of the move is made in the carry, above the target
        lateral = np.asarray(ctx.env.T_world_ladder, dtype=float)[:3, 1]
        back = back - float(back @ lateral) * lateral
    nb = float(np.linalg.norm(back))
    b = back / nb if nb > 1e-6 else np.zeros(3)
    front = approach + p.carry_backoff * b
    start = lift if lift is not None else p_s
    points = [lift] if lift is not None else []

    def back_off(distance: float) -> None:
        # horizontally, at the lift-off height: a foot released before this step (no old hold,
        # resting where it stood) is lifted straight up first instead of dragged
        nonlocal start, lift
        if lift is None and limb in FEET:
            lift = start = p_s + np.array([0.0, 0.0, p.lift_clearance])
            points.append(lift)
        start = start + distance * b
        points.append(start)

    behind = float((front - start) @ b)
    if behind > 1e-3:  # back off to the front point's distance first
        back_off(behind)
    rise = float(front[2] - start[2])
    flat_foot = target is not None and not rung and limb in FEET
    if flat_foot and rise > p.lift_clearance:
        # onto a higher flat surface (a step, a tread): straight up to the front point's height
        # first, so that the toes clear the edge before the foot moves over it; where the sole
        # is under the surface's edge (a tread overhanging the one below), back off first
        short = step_rise_distance(robot, limb, target, T_e, b) + p.step_edge_clearance - float((start - p_e) @ b)
        if short > 1e-3:
            back_off(short)
            rise = float(front[2] - start[2])
        start = start + np.array([0.0, 0.0, rise])
        points.append(start)
    elif flat_foot and float(approach[2] - start[2]) < -p.lift_clearance:
        # down onto a lower flat surface (off a step): over the approach point at the lift-off
        # height, then straight down onto it (a carry backed off toward the step would cut
        # through its edge)
        front = np.array([approach[0], approach[1], start[2]])
    k = p.carry_waypoints
    points += [start + (i / k) * (front - start) for i in range(1, k + 1)] + [approach]
    poses = []
    d_rot = pin.log3(T_s[:3, :3].T @ T_e[:3, :3])
    poly = [p_s] + points + [p_e]
    length = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(np.array(poly), axis=0), axis=1))])
    s = length[1:-1] / max(float(length[-1]), 1e-9)
    for i, point in enumerate(points):
        if lift is not None and i == 0:
            w = 0.0
        elif i == len(points) - 1:
            w = 1.0
        else:
            w = float(s[i])
        R = T_s[:3, :3] @ pin.exp3(w * d_rot)
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = R, point
        poses.append(T)
    return poses, s


def step_rise_distance(robot, limb: str, target, T_e: np.ndarray, b: np.ndarray) -> float:
    """[m] the least horizontal distance along ``b`` (unit, horizontal: toward where the foot comes
    from) between the foot's end place ``T_e`` and where it may rise beside box ``target``: the
    box's reach toward ``b`` from the end place plus the sole's front (the sole corners' farthest
    reach against ``b``, in the end orientation); -inf for a surface other than a box."""
    if getattr(target, "shape", "") != "box":
        return -np.inf
    p_e = T_e[:3, 3]
    T = np.asarray(target.T_world_surface)
    edge = float((T[:3, 3] - p_e) @ b) + float(np.abs(T[:3, :3].T @ b) @ np.asarray(target.half_extents))
    sole = holds_mod.sole_vertices_in_surface(holds_mod.limb_surface(robot, limb)) @ T_e[:3, :3].T
    return edge + float(np.max(-(sole @ b)))


def lift_height(ctx: A.AdaptContext, path: Sequence[np.ndarray], limb: str, old: Hold, q_s: np.ndarray) -> float:
    """[m] how far the moving limb's surface frame gets from its start along the old hold's
    direction (:func:`hold_direction`), at most, over the path."""
    n = hold_direction(ctx, old, q_s)
    p0 = np.asarray(ctx.robot.T_world_surface(limb, q_s))[:3, 3]
    return max(float((np.asarray(ctx.robot.T_world_surface(limb, q))[:3, 3] - p0) @ n) for q in path)


# --------------------------------------------------------------------------------------------
# steps


def _latched(ctx: A.AdaptContext, state: A.ClimbState) -> A.ClimbState:
    """``state`` with its closed grasps latched (``contact_path.latch_grasps``), else as it is."""
    return A.latch_grasps(ctx, state) if ctx.settings.contact_path.latch_grasps else state


def _seed(ctx: A.AdaptContext, q: np.ndarray, attempt: int, rng: np.random.Generator) -> np.ndarray:
    return q if attempt == 0 else A._perturb(ctx, q, attempt, rng)


def transfer_step(ctx: A.AdaptContext, state: A.ClimbState, limb: str, hold: Hold, q_end: np.ndarray,
                  attempt: int, rng: np.random.Generator, name: str = "") -> Step | AttemptFailure:
    """Move ``limb`` from its hold in ``state`` (or from free) onto ``hold`` (see the module
    docstring); ``q_end``: the contact plan's transition configuration of the new stance (seed of
    the end configuration; attempts > 0 perturb it and the way-point seeds)."""
    if limb not in ctx.robot.config.limbs:
        raise SpecError(f"{name or 'transfer'}.limb", f"the robot has no limb {limb!r}")
    name = name or f"{transfer_name(limb)}_{limb}"
    state = _latched(ctx, state)  # a closed grasp keeps its roll about the bar (the simulator's grasp is rigid)
    old = state.stance.hold(limb)
    sigma_e = Stance(state.stance.with_hold(hold).holds, name=name)
    sigma_t = Stance(tuple(h for h in sigma_e.holds if h.limb != limb), name=f"{name}:transfer")
    # end: the limb on its new hold, the kept holds able to carry the robot without it
    proj = A.project(ctx, _seed(ctx, np.asarray(q_end, dtype=float), attempt, rng), sigma_e, rng, unload=(limb,))
    if proj.q is None:
        return AttemptFailure(proj.failure, f"{name}: end configuration ({dict(proj.failures)})")
    q_s, q_e = np.asarray(state.q, dtype=float), proj.q
    zone = [old, hold]
    cues, fractions = limb_cues(ctx, limb, old, hold, q_s, q_e)
    com_s, com_e = _com_xy(ctx, q_s), _com_xy(ctx, q_e)
    milestones = [q_s]
    for cue, s in zip(cues, fractions):
        q_bar = _seed(ctx, pin.interpolate(ctx.robot.model, q_s, q_e, float(s)), attempt, rng)
        q_w = waypoint(ctx, milestones[-1], q_bar, sigma_t, limb, zone, cue, rng, (1.0 - s) * com_s + s * com_e)
        if q_w is None:
            res = ctx.check(q_bar, sigma_t, A.zone_exclusions(ctx, q_bar, limb, zone))
            return AttemptFailure(A.failure_name(res) or f"reach:{limb}", f"{name}: way-point at s = {s:.2f}")
        milestones.append(q_w)
    milestones.append(q_e)
    path, _, failure = A.build_path(ctx, milestones, sigma_t, limb, zone)
    if path is None:
        return AttemptFailure(failure, f"{name}: path")
    clearance = ctx.settings.contact_path.lift_clearance
    if old is not None and lift_height(ctx, path, limb, old, q_s) < clearance:
        return AttemptFailure(f"lift:{limb}", f"{name}: the limb does not leave its hold by {clearance} m")
    transition = _transition(ctx, transfer_name(limb), limb, sigma_t, sigma_e, path)
    return Step(A.ClimbState(q_e, sigma_e), A.Segment(name, transition, hold, attempt))


def limb_joint_indices(robot, limb: str) -> np.ndarray:
    """Indices in q of the joints that move ``limb`` alone: its chain from the root minus the
    chain of the other limb of its pair (the other hand / foot), e.g. shoulder to wrist."""
    model = robot.model

    def chain(name: str) -> list[int]:
        j = model.frames[robot.frame_id(robot.config.limbs[name].surface.frame)].parentJoint
        out = []
        while j > 0:
            out.append(j)
            j = model.parents[j]
        return out

    pair = HANDS if limb in HANDS else FEET
    other = next((o for o in pair if o != limb and o in robot.config.limbs), None)
    shared = set(chain(other)) if other is not None else set()
    return np.array(sorted(model.idx_qs[j] for j in chain(limb) if j not in shared and model.nqs[j] == 1), int)


def keep_limb_posture(robot, q: np.ndarray, q_from: np.ndarray, limbs) -> np.ndarray:
    """``q`` with the joints of each of ``limbs`` (:func:`limb_joint_indices`) as in ``q_from``:
    a limb freed for good keeps its posture while the others move (the contact search leaves a
    removed hand where it held)."""
    out = np.array(q, dtype=float)
    for limb in limbs:
        idx = limb_joint_indices(robot, limb)
        out[idx] = np.asarray(q_from, dtype=float)[idx]
    return out


def free_lift(ctx: A.AdaptContext, attempt: int, rng: np.random.Generator) -> float:
    """How far a limb freed for good is lifted off its hold before it keeps its posture: the
    transfer's ``lift_clearance`` first, then a random distance up to ``free_lift_max`` on each
    retry. The limb's posture is kept for the moves that follow, so the lift decides its
    clearance from the surface it left while the body moves on (narrow_passage: the freed right
    wrist met the palm block when the CoM went over the foot on the step)."""
    p = ctx.settings.contact_path
    if attempt == 0 or p.free_lift_max <= p.lift_clearance:
        return p.lift_clearance
    return float(rng.uniform(p.lift_clearance, p.free_lift_max))


def freed_posture(ctx: A.AdaptContext, limb: str, q_lift: np.ndarray, attempt: int,
                  rng: np.random.Generator) -> np.ndarray:
    """The posture a limb freed for good keeps for the moves that follow (a configuration; only
    its joints count). A hand: with ``free_rest``, the reference (standing) arm posture on the
    first attempt - the arm folded in front of the body, away from what it held (stairs_handrail:
    a hand left on the rail with its lift-off posture met the rail when the body stepped up onto
    the landing) - the lift-off posture on the second, and blends of the two after. A foot, or
    without ``free_rest``: the lift-off posture."""
    q_lift = np.asarray(q_lift, dtype=float)
    if limb not in HANDS or not ctx.settings.contact_path.free_rest or attempt % 2 == 1:
        return q_lift
    s = 1.0 if attempt == 0 else float(rng.uniform(0.3, 1.0))
    idx = limb_joint_indices(ctx.robot, limb)
    out = q_lift.copy()
    out[idx] = (1.0 - s) * q_lift[idx] + s * ctx.robot.q_reference()[idx]
    return out


def free_step(ctx: A.AdaptContext, state: A.ClimbState, limb: str, q_end: np.ndarray, attempt: int,
              rng: np.random.Generator, name: str = "") -> Step | AttemptFailure:
    """``limb`` leaves its hold in ``state`` for good: lifted off along the hold's direction by
    :func:`free_lift` (a way-point, the other holds kept), then on to a configuration near
    ``q_end`` (the contact plan's) with the limb's joints as :func:`freed_posture` has them (a
    hand: folded to the reference posture first), in equilibrium on the other holds. The Transition has the moving limb and no hold for it in its target stance
    (the FSM: remove, then the path, then the next transition). The later steps keep that limb's
    posture (:func:`keep_limb_posture`)."""
    state = _latched(ctx, state)
    old = state.stance.hold(limb)
    if old is None:
        raise SpecError(f"{name or 'free'}.limb", f"{limb} holds nothing to leave")
    name = name or f"free_{limb}"
    sigma = Stance(tuple(h for h in state.stance.holds if h.limb != limb), name=name)
    q_s = np.asarray(state.q, dtype=float)
    T_s = np.asarray(ctx.robot.T_world_surface(limb, q_s))
    cue = T_s.copy()
    cue[:3, 3] += free_lift(ctx, attempt, rng) * hold_direction(ctx, old, q_s)
    q_w = waypoint(ctx, q_s, _seed(ctx, q_s, attempt, rng), sigma, limb, [old], cue, rng)
    if q_w is None:
        res = ctx.check(q_s, sigma, A.zone_exclusions(ctx, q_s, limb, [old]))
        return AttemptFailure(A.failure_name(res) or f"reach:{limb}", f"{name}: lift-off way-point")
    q_bar = keep_limb_posture(ctx.robot, _seed(ctx, np.asarray(q_end, dtype=float), attempt, rng),
                              freed_posture(ctx, limb, q_w, attempt, rng), [limb])
    proj = A.project(ctx, q_bar, sigma, rng)
    if proj.q is None:
        return AttemptFailure(proj.failure, f"{name}: end configuration ({dict(proj.failures)})")
    q_e = proj.q
    # the lift-off may touch the surface it leaves (the hold's zone); from the lift-off on the
    # freed limb keeps clear of it like any other body (with the zone all along, the hand freed
    # from stairs_handrail's rail went 2.7 cm through it on its way to the reference posture)
    lift, _, failure = A.build_path(ctx, [q_s, q_w], sigma, limb, [old])
    if lift is None:
        return AttemptFailure(failure, f"{name}: lift-off path")
    rest, _, failure = A.build_path(ctx, [q_w, q_e], sigma, limb, [])
    if rest is None:
        return AttemptFailure(failure, f"{name}: path")
    path = list(lift) + list(rest[1:])
    transition = _transition(ctx, f"free_{'hand' if limb in HANDS else 'foot'}", limb, sigma, sigma, path)
    return Step(A.ClimbState(q_e, sigma), A.Segment(name, transition, None, attempt))


def _com_xy(ctx: A.AdaptContext, q: np.ndarray) -> np.ndarray:
    return np.asarray(pin.centerOfMass(ctx.robot.model, ctx.robot.model.createData(), q))[:2].copy()


def waypoint(ctx: A.AdaptContext, q_seed: np.ndarray, q_bar: np.ndarray, stance: Stance, limb: str,
             zone: Sequence[Hold | None], cue: np.ndarray, rng: np.random.Generator,
             com_target: np.ndarray | None = None) -> np.ndarray | None:
    """A whole-body way-point: the physics-constrained IK from ``q_seed`` (the previous way-point:
    the limb travels on from where it is) with ``stance``'s holds regular and ``cue`` (4x4) a soft
    pose of ``limb``, posture pulled toward ``q_bar`` and the CoM toward ``com_target`` (x, y [m]:
    the transfer keeps the CoM between where its end configurations have it, away from the edge of
    the support a bare equilibrium check allows); polished onto the stance and checked. A
    result that fails the check is retracted from there without the cue (the limb stays near it),
    then, failing that, from ``q_bar``. None when nothing passes the check."""
    contacts = pcik.contacts_from_stance(stance) + [pcik.ContactSpec(limb, pcik.ZERO_FORCE, pose=cue, soft=True)]
    ctx.stats.pcik_calls += 1
    params = ctx.settings.pcik
    if com_target is not None:
        params = dataclasses.replace(params, com_weight=ctx.settings.contact_path.com_weight)
    pr = pcik.solve(ctx.robot, ctx.env, q_seed, contacts, q_target=q_bar, params=params,
                    feasibility_cfg=ctx.check_cfg, extra_exclusions=A.zone_exclusions(ctx, q_seed, limb, zone),
                    self_margin=ctx.settings.planning.self_collision_margin, final_check=False,
                    com_target=com_target)
    if not [v for v in pr.violated if v != f"reach:{limb}"]:  # the kept holds are made
        q_c = A.ContactProjector(ctx, stance, pr.q)(pr.q)
        if q_c is not None:
            if ctx.check(q_c, stance, A.zone_exclusions(ctx, q_c, limb, zone)).feasible:
                ctx.stats.cue_retractions += 1
                return q_c
            q_r = A._retract(ctx, q_c, stance, limb, zone, q_target=q_c, rng=rng)
            if q_r is not None:
                return q_r
    return A._retract(ctx, q_bar, stance, limb, zone, q_target=q_bar, rng=rng)


def com_step(ctx: A.AdaptContext, state: A.ClimbState, q_end: np.ndarray, unload: Sequence[str], attempt: int,
             rng: np.random.Generator, name: str = "") -> Step | AttemptFailure:
    """Shift the CoM with every hold of ``state`` kept, to a configuration near ``q_end`` that is
    also in equilibrium without each limb of ``unload`` (the limb released next)."""
    state = _latched(ctx, state)
    stance = state.stance
    unload = tuple(u for u in unload if u and stance.hold(u) is not None)
    name = name or com_name(unload)
    proj = A.project(ctx, _seed(ctx, np.asarray(q_end, dtype=float), attempt, rng), stance, rng, unload=unload)
    if proj.q is None:
        return AttemptFailure(proj.failure, f"{name}: end configuration ({dict(proj.failures)})")
    path, _, failure = A.build_path(ctx, [np.asarray(state.q, dtype=float), proj.q], stance, "", ())
    if path is None:
        return AttemptFailure(failure, f"{name}: path")
    transition = _transition(ctx, com_name(unload), "", stance, stance, path)
    return Step(A.ClimbState(proj.q, stance), A.Segment(name, transition, None, attempt))


def _transition(ctx: A.AdaptContext, primitive: str, limb: str, stance: Stance, target: Stance,
                path: list[np.ndarray]):
    from climb_core.contact import Transition

    from . import interpolation as interp

    times = interp.time_transition(ctx.robot.model, path, stance, ctx.settings.timing)
    return Transition(primitive=primitive, moving_limb=limb, stance=stance, target_stance=target, times=times,
                      path=np.array(path))
