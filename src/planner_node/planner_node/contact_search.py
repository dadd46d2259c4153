"""Best-first multi-contact search (multicontact_darpa_tasks.txt, III-C).

The search walks a tree of *contact sets* (:class:`~climb_core.contact.Stance`), each stored with
its transition configuration, toward the milestones of a guide path, one milestone after the
other:

- a priority queue (``heapq``) holds the nodes ordered by their cost to the targeted milestone;
  the best is popped and expanded (once: a contact set already expanded is not expanded again);
- *add*: for every free limb and every environment surface that accepts it (within reach of the
  limb's root), a zero-force floating contact on that surface is added and the
  physics-constrained IK (:func:`planner_node.pcik.solve`) is called with the existing contacts
  regular, the cost pulling toward the milestone and the floating limb toward its position at the
  milestone; on success the floating contact becomes a hold (``PCIKResult.holds``) and the new set
  is pushed;
- *remove*: for every contact, the IK is called with that contact zero-force (the limb stays on its
  hold carrying nothing: the robot is in equilibrium on the others); on success the set without it
  is pushed; sets keep more than ``min_contacts`` contacts on a ladder (the three-support gait),
  ``min_contacts_scene`` elsewhere (1: single support, walking); a hand is removed only from a set
  that keeps ``hand_release_min_contacts`` (1 by default; 2: never onto one foot alone), and a set
  left on one contact is solved with ``single_support_cop_margin`` (off by default);
- on a walked ladder (stairs: the caller's ``walked``) the IK pulls the CoM over the held feet and a
  free foot is offered the treads at most ``foot_max_treads_up`` above the other foot's
  (:func:`tread_levels`: one tread at a time);
- a free foot is offered a surface whose top is more than ``step_up_hand_support`` above its sole
  only while a hand holds a surface (off by default: a high step with a hand's support);
- branching: the surfaces of a free limb beyond its reach from its root (hip; an arm: the waist, whose chain holds the shoulder) are
  pruned before any IK call; of the others, the ``max_surfaces_per_limb`` closest to the limb's
  place at the milestone are tried, closest first (0: all of them, the paper's exhaustive
  expansion), until one puts the limb within ``key_resolution`` of that place;
- a node reaches an intermediate milestone when its base (position and rotation) is within
  ``milestone_tolerance`` of the milestone's, or is as close to the next milestone's base as this
  milestone's is (the guide path plans the free-flyer, where the limbs go is the search's), the
  last one when its base and every limb the milestone puts on a surface are within
  ``goal_tolerance``; a popped node whose limbs are in place but whose base is not is *settled*
  first (the IK stops at its first feasible iterate, near its seed: the settling call runs it to
  convergence toward the milestone, then the frozen check decides); the next milestone is
  searched from the node that reached this one; an intermediate milestone that
  ``milestone_max_nodes`` expansions do not reach (or whose queue runs dry) is given up and the
  next one is targeted from the same node (``milestones_skipped``: the guide path's free-flyer may
  hover where no contact set holds it - car_ingress's base 0.3 m above the ground in front of the
  sill); after the last one the
  stance sequence and the transition configurations are read back up the tree
  (:class:`~climb_core.contact.ContactPlan`: consecutive stances differ by exactly one hold).

Configuration distance (:func:`configuration_distance`), in metres:

    d(q, q_m) = |p_base - p_base,m| + w_rot angle(R_base,m^T R_base)
                + w_limb sum_limbs |p_limb - p_limb,m| + w_joint rms(q_joints - q_joints,m)

Base position and the four contact surfaces' positions are what a contact transition changes and
what the guide path prescribes (the robot's place and where its limbs are); they are in metres
and comparable across robots. The joints enter with a small weight (per radian, RMS so that the
number of joints does not matter): they separate postures that put the limbs at the same places
without dominating the task-space terms. With ``lookahead``, a node's priority is the smaller of
its costs to the targeted milestone and to the next one. A node's cost is d to the milestone, plus
``floating_cost_weight`` times the floating limb's distance to its milestone position (the paper's
cost of an added contact), where a limb without a contact counts, instead of its distance, the
least it can be once placed again (its milestone place's distance to the closest surface that
accepts it) plus ``free_limb_cost``: removing the contact of a limb far from where it can go
ranks high, removing one already there ranks low, and a milestone whose limbs are in the air (a
guide path's in-between posture) does not make every removal look promising.

Deterministic: ties in the queue are broken by insertion order, candidates are enumerated in a
fixed order, and the IK is deterministic (up to coal's warm-started distance queries: the same
moves, configurations equal to ~1e-4). Bounded by ``time_limit_s`` and ``max_nodes``; a
failure raises :class:`~climb_core.errors.InfeasibleError` ``contact_search:<reason>`` with the
nodes expanded and IK calls in the detail.
"""
from __future__ import annotations

import dataclasses
import heapq
import math
import time
from dataclasses import dataclass, field
from typing import Any, Collection

import numpy as np
import pinocchio as pin

from climb_core import feasibility
from climb_core import holds as holds_mod
from climb_core.contact import LIMBS, ContactPlan, GuidePath, Hold, Stance, limb_type
from climb_core.errors import InfeasibleError, SpecError

from . import pcik
from .settings import ContactSearchParams, PCIKParams

def accepting_surfaces(robot: Any, env: Any, limb: str) -> list[Any]:
    """The environment surfaces ``limb`` may be placed on (``Environment.contact_surfaces``), in
    the environment's order, that it has a robot surface for (:func:`climb_core.holds.robot_surface_for`:
    a foot its sole; a hand closes its grasp around a bilateral surface - a bilateral contact, a
    grip limit instead of a friction cone - and pushes with its palm on any other). A grasp needs a
    cylinder or a rect bar that fits the hand (:func:`climb_core.holds.grasp_fits`)."""
    out = []
    for sf in env.contact_surfaces(limb_type(limb)):
        rs = holds_mod.robot_surface_for(robot, limb, sf, required=False)
        if rs is None or (rs.kind == "grasp" and not holds_mod.grasp_fits(robot, limb, sf)):
            continue
        out.append(sf)
    return out


# --------------------------------------------------------------------------------------------
# geometry: distances, reach


@dataclass(frozen=True)
class _LimbReach:
    root_joint: int  # Pinocchio joint id of the limb's first joint (hip pitch; an arm: the waist yaw)
    length: float  # [m] upper bound of the root-to-contact-surface distance


def limb_reach(robot: Any, limb: str) -> _LimbReach:
    """The limb's root joint and its length: the sum of the joint-origin-to-joint-origin distances
    along the chain plus the last joint to the contact surface origin (an upper bound of the
    distance the surface can be from the root, whatever the joint angles)."""
    cfg = robot.config.limbs[limb]
    model = robot.model
    data = model.createData()
    q = robot.q_reference()
    pin.framesForwardKinematics(model, data, q)
    ids = [int(model.getJointId(j)) for j in cfg.joints]
    pts = [data.oMi[j].translation.copy() for j in ids]
    fid = robot.frame_id(cfg.surface.frame)
    pts.append((data.oMf[fid].homogeneous @ np.asarray(cfg.surface.T_frame_surface))[:3, 3])
    length = float(sum(np.linalg.norm(b - a) for a, b in zip(pts[:-1], pts[1:])))
    return _LimbReach(ids[0], length)


def tread_levels(env: Any) -> dict[str, int]:
    """Surface name -> its level on the ladder: the ground 0, rung / tread k k
    (:func:`planner_node.adapt.rung_index`), the platform n + 1."""
    from .adapt import rung_index

    levels = {name: rung_index(name) for name in env.surfaces if rung_index(name) >= 0}
    if "platform" in env.surfaces:
        levels["platform"] = int(env.n_rungs) + 1
    return levels


def surface_distance(surface: Any, point: np.ndarray) -> float:
    """[m] distance from ``point`` to the surface's solid (0 inside)."""
    T = np.asarray(surface.T_world_surface)
    local = T[:3, :3].T @ (np.asarray(point, dtype=float) - T[:3, 3])
    if surface.shape == "cylinder":
        half = 0.5 * float(surface.length)
        x = float(np.clip(local[0], -half, half))
        radial = math.hypot(local[1], local[2])
        return float(math.hypot(local[0] - x, max(radial - float(surface.radius), 0.0)))
    if surface.shape == "plane":
        return max(float(local[2]), 0.0)
    h = np.asarray(surface.half_extents, dtype=float)
    return float(np.linalg.norm(np.maximum(np.abs(local) - h, 0.0)))


class _Kinematics:
    """Forward kinematics the search needs (limb surface positions, limb roots), one pin.Data."""

    def __init__(self, robot: Any):
        self.robot = robot
        self.data = robot.model.createData()
        self.frames = {limb: (robot.frame_id(robot.config.limbs[limb].surface.frame),
                              np.asarray(robot.config.limbs[limb].surface.T_frame_surface))
                       for limb in LIMBS if limb in robot.config.limbs}
        self.reach = {limb: limb_reach(robot, limb) for limb in self.frames}

    def limb_positions(self, q: np.ndarray) -> dict[str, np.ndarray]:
        """limb -> [m] world position of its contact surface origin at q."""
        pin.framesForwardKinematics(self.robot.model, self.data, q)
        return {limb: (self.data.oMf[fid].homogeneous @ T)[:3, 3].copy() for limb, (fid, T) in self.frames.items()}

    def roots(self, q: np.ndarray) -> dict[str, np.ndarray]:
        """limb -> [m] world position of its root joint at q (call after :meth:`limb_positions`
        with the same q, or alone)."""
        pin.forwardKinematics(self.robot.model, self.data, q)
        return {limb: self.data.oMi[r.root_joint].translation.copy() for limb, r in self.reach.items()}


@dataclass(frozen=True)
class _Target:
    """A milestone: its configuration, its limb positions and, per limb, the distance from that
    position to the closest surface the limb may be placed on (the least a hold can be away)."""

    q: np.ndarray
    limbs: dict[str, np.ndarray]
    floor: dict[str, float] = field(default_factory=dict)


def distance_terms(q: np.ndarray, limbs: dict[str, np.ndarray], target: _Target,
                   params: ContactSearchParams) -> tuple[float, float, dict[str, float]]:
    """(free-flyer term: base position and rotation [m], joint term [m], limb -> its contact
    surface's distance to the milestone's [m])."""
    dp = float(np.linalg.norm(q[:3] - target.q[:3]))
    R = pin.Quaternion(np.asarray(q[3:7])).toRotationMatrix()
    Rm = pin.Quaternion(np.asarray(target.q[3:7])).toRotationMatrix()
    angle = float(np.linalg.norm(pin.log3(Rm.T @ R)))
    dj = float(np.sqrt(np.mean((q[7:] - target.q[7:]) ** 2)))
    per_limb = {k: float(np.linalg.norm(limbs[k] - target.limbs[k])) for k in target.limbs}
    return dp + params.base_rotation_weight * angle, params.joint_weight * dj, per_limb


def configuration_distance(q: np.ndarray, limbs: dict[str, np.ndarray], target: _Target,
                           params: ContactSearchParams) -> float:
    """d(q, q_m) [m] of the module docstring (``limbs``: the limb positions at q)."""
    base, joints, per_limb = distance_terms(q, limbs, target, params)
    return base + joints + params.limb_weight * sum(per_limb.values())


# --------------------------------------------------------------------------------------------
# the tree


@dataclass
class Node:
    """A contact set with its transition configuration; ``parent`` None at the root."""

    stance: Stance
    q: np.ndarray
    parent: "Node | None" = None
    move: str = ""  # "add:<limb>@<surface>" | "remove:<limb>@<surface>" | "" (root)
    depth: int = 0
    distance: float = math.inf  # [m] configuration distance to the milestone it was pushed for
    base_distance: float = math.inf  # [m] its free-flyer term (base position and rotation)
    limb_distances: dict[str, float] = field(default_factory=dict)  # [m] limb -> distance to its milestone place
    kept_as: "Node | None" = field(default=None, repr=False)  # the node that stands for it after without_detours


@dataclass
class SearchStats:
    nodes_expanded: int = 0
    nodes_pushed: int = 0
    ik_calls: int = 0
    ik_failures: int = 0
    ik_time_s: float = 0.0
    pruned_by_reach: int = 0
    pruned_by_rank: int = 0
    pruned_by_step: int = 0
    pruned_by_support: int = 0
    skipped_visited: int = 0
    skipped_banned: int = 0
    time_s: float = 0.0
    milestones_reached: int = 0
    milestones_skipped: list[int] = field(default_factory=list)  # intermediate milestones given up (their budget)

    @property
    def ik_calls_per_s(self) -> float:
        return self.ik_calls / self.time_s if self.time_s > 0 else 0.0

    def as_dict(self) -> dict:
        return {"nodes_expanded": self.nodes_expanded, "nodes_pushed": self.nodes_pushed,
                "ik_calls": self.ik_calls, "ik_failures": self.ik_failures,
                "ik_calls_per_s": round(self.ik_calls_per_s, 2), "ik_time_s": round(self.ik_time_s, 3),
                "pruned_by_reach": self.pruned_by_reach, "pruned_by_rank": self.pruned_by_rank,
                "pruned_by_step": self.pruned_by_step, "pruned_by_support": self.pruned_by_support,
                "skipped_visited": self.skipped_visited, "skipped_banned": self.skipped_banned,
                "milestones_reached": self.milestones_reached, "milestones_skipped": list(self.milestones_skipped),
                "time_s": round(self.time_s, 3)}


@dataclass
class SearchResult:
    plan: ContactPlan
    moves: list[str]  # per stance after the first: "add:<limb>@<surface>" / "remove:<limb>@<surface>"
    stats: SearchStats
    milestone_nodes: list[int] = field(default_factory=list)  # index in plan.stances where each milestone was reached


def banned_transition(plan: ContactPlan, i: int, resolution: float) -> tuple[frozenset, frozenset]:
    """The change from ``plan.stances[i]`` to ``plan.stances[i + 1]`` as ``search(banned=...)`` takes it."""
    return stance_key(plan.stances[i], resolution), stance_key(plan.stances[i + 1], resolution)


def stance_key(stance: Stance, resolution: float) -> frozenset:
    """Canonical key of a contact set: limb -> surface and hold centre on a ``resolution`` grid."""
    return frozenset((h.limb, h.env_surface, tuple(int(v) for v in np.round(h.centre / resolution)))
                     for h in stance.holds)


# --------------------------------------------------------------------------------------------
# the search


class _Search:
    def __init__(self, robot: Any, env: Any, params: ContactSearchParams, pcik_params: PCIKParams | None,
                 feasibility_cfg: feasibility.FeasibilityConfig | None, banned: Collection[tuple] = (),
                 walked: bool = False):
        self.robot, self.env, self.params = robot, env, params
        self.banned = frozenset(banned)
        if params.ik_floating_weight > 0.0:  # the added contact lands at its milestone place
            pcik_params = dataclasses.replace(pcik_params, floating_weight=params.ik_floating_weight)
        if params.ik_max_iterations > 0:
            pcik_params = dataclasses.replace(pcik_params, max_iterations=params.ik_max_iterations)
        self.pcik_params = pcik_params
        self.cfg = feasibility_cfg or feasibility.load_config()
        self.kin = _Kinematics(robot)
        self.surfaces = {limb: accepting_surfaces(robot, env, limb) for limb in self.kin.frames}
        # a ladder is climbed on three supports; elsewhere the robot also walks (single support)
        on_ladder = getattr(env, "ladder", None) is not None
        self.min_contacts = params.min_contacts if on_ladder else params.min_contacts_scene
        walked_ladder = on_ladder and walked  # stairs, a ship ladder: walked up, the CoM over the feet
        self.com_over_feet = walked_ladder and params.com_over_feet_weight > 0.0
        self.tread_of = tread_levels(env) if walked_ladder and params.foot_max_treads_up > 0 else {}
        if self.com_over_feet:
            self.pcik_com = dataclasses.replace(self.pcik_params, com_weight=params.com_over_feet_weight)
        self.stats = SearchStats()
        self.t0 = time.perf_counter()
        self.best: tuple[float, float] = (math.inf, math.inf)  # closest (configuration, base) distance [m]
        self.milestone_nodes0 = 0  # nodes expanded when the targeted milestone's search began (its own budget)
        self.last = False

    def target(self, q: np.ndarray) -> _Target:
        limbs = self.kin.limb_positions(q)
        floor = {limb: min((surface_distance(sf, p) for sf in self.surfaces[limb]), default=math.inf)
                 for limb, p in limbs.items()}
        return _Target(q, limbs, floor)

    # ---- budget
    def _out_of_budget(self) -> str:
        if time.perf_counter() - self.t0 > self.params.time_limit_s:
            return "time_limit"
        if self.stats.nodes_expanded >= self.params.max_nodes:
            return "node_budget"
        cap = self.params.milestone_max_nodes
        if cap and not self.last and self.stats.nodes_expanded - self.milestone_nodes0 >= cap:
            return "milestone_budget"
        return ""

    # ---- IK
    def _ik(self, q_seed: np.ndarray, contacts: list[pcik.ContactSpec], q_target: np.ndarray) -> pcik.PCIKResult | None:
        """The physics-constrained IK; None when the holds module cannot model a contact of the pair
        (SpecError: e.g. a sole on a surface shape it cannot stand on). A set left on one contact
        (single support) is solved with the soles' ``single_support_cop_margin``."""
        t = time.perf_counter()
        self.stats.ik_calls += 1
        com = self._feet_centroid(contacts)
        params = self.pcik_params if com is None else self.pcik_com
        if self.params.single_support_cop_margin > 0.0 and sum(1 for c in contacts if c.type == pcik.REGULAR) == 1:
            params = dataclasses.replace(params, sole_cop_margin=max(params.sole_cop_margin,
                                                                     self.params.single_support_cop_margin))
        try:
            res = pcik.solve(self.robot, self.env, q_seed, contacts, q_target=q_target, params=params,
                             feasibility_cfg=self.cfg, com_target=com)
        except SpecError:
            res = None
        self.stats.ik_time_s += time.perf_counter() - t
        if res is None or not res.success:
            self.stats.ik_failures += 1
            return None
        return res

    def _feet_centroid(self, contacts: list[pcik.ContactSpec]) -> np.ndarray | None:
        """The CoM target of ``com_over_feet`` (x, y of the held feet's hold centres), else None."""
        if not self.com_over_feet:
            return None
        feet = [c.hold.centre[:2] for c in contacts
                if c.hold is not None and c.type == pcik.REGULAR and limb_type(c.limb) == "foot"]
        return np.mean(feet, axis=0) if feet else None

    def _priority(self, node: Node, target: _Target, after: _Target | None = None,
                  floating: tuple[str, np.ndarray] | None = None) -> float:
        """Node cost: the distance of the limbs in contact counted at their places, each free
        limb at the least it can be once placed again (its milestone place's distance to the
        closest surface accepting it) plus ``free_limb_cost``, plus the added contact's distance
        to its preferred place;
        with ``lookahead``, the smaller of that cost to the targeted milestone and to the next."""
        limbs = self.kin.limb_positions(node.q)
        held = set(node.stance.limbs)
        costs = []
        for k, t in enumerate((target, after) if (after is not None and self.params.lookahead) else (target,)):
            base, joints, per_limb = distance_terms(node.q, limbs, t, self.params)
            if k == 0:
                node.distance = base + joints + self.params.limb_weight * sum(per_limb.values())
                node.base_distance = base
                node.limb_distances = per_limb
            cost = base + joints + self.params.limb_weight * sum(
                d if j in held else t.floor.get(j, 0.0) for j, d in per_limb.items())
            cost += self.params.free_limb_cost * sum(1 for j in per_limb if j not in held)
            if floating is not None:
                limb, _ = floating
                cost += self.params.floating_cost_weight * float(np.linalg.norm(limbs[limb] - t.limbs[limb]))
            costs.append(cost)
        return min(costs)

    # ---- expansion
    def _children(self, node: Node, target: _Target, seen: set) -> list[tuple[Node, tuple | None]]:
        stance, q = node.stance, node.q
        regular = [pcik.ContactSpec(h.limb, pcik.REGULAR, hold=h) for h in stance.holds]
        out: list[tuple[Node, tuple | None]] = []
        roots = self.kin.roots(q)
        for limb in self.kin.frames:  # add a floating contact for each free limb and accepting surface
            if stance.hold(limb) is not None:
                continue
            preferred = target.limbs[limb]
            reach = self.kin.reach[limb].length + self.params.reach_margin
            candidates = []
            for sf in self.surfaces[limb]:
                if surface_distance(sf, roots[limb]) > reach:
                    self.stats.pruned_by_reach += 1
                else:
                    candidates.append(sf)
            candidates = self._within_a_step(stance, limb, candidates)
            candidates = self._supported_step(stance, limb, q, candidates)
            # closest to the limb's milestone place first, at most max_surfaces_per_limb of them
            candidates.sort(key=lambda sf: surface_distance(sf, preferred))  # stable: ties in env order
            cap = self.params.max_surfaces_per_limb
            if cap and len(candidates) > cap:
                self.stats.pruned_by_rank += len(candidates) - cap
                candidates = candidates[:cap]
            for k, sf in enumerate(candidates):
                if self._out_of_budget():
                    return out
                spec = pcik.ContactSpec(limb, pcik.FLOATING, surface=sf.name, preferred_position=preferred)
                res = self._ik(q, regular + [spec], target.q)
                if res is None or limb not in res.holds:
                    continue
                child = Stance(stance.holds + (res.holds[limb],), name=f"add:{limb}@{sf.name}")
                if self._banned(stance, child):
                    continue
                out.append((Node(child, res.q, node, f"add:{limb}@{sf.name}", node.depth + 1), (limb, preferred)))
                if np.linalg.norm(res.holds[limb].centre - preferred) <= self.params.key_resolution:
                    # the limb landed at its milestone place: a farther surface would not rank better
                    self.stats.pruned_by_rank += len(candidates) - k - 1
                    break
        if len(stance.holds) > self.min_contacts:  # remove each contact (zero force)
            for h in stance.holds:
                if limb_type(h.limb) == "hand" and len(stance.holds) - 1 < self.params.hand_release_min_contacts:
                    continue
                child = stance.without(h.limb)
                if stance_key(child, self.params.key_resolution) in seen:
                    self.stats.skipped_visited += 1
                    continue
                if self._banned(stance, child):
                    continue
                if self._out_of_budget():
                    return out
                contacts = [c if c.limb != h.limb else pcik.ContactSpec(h.limb, pcik.ZERO_FORCE, hold=h)
                            for c in regular]
                res = self._ik(q, contacts, target.q)
                if res is None:
                    continue
                child = Stance(child.holds, name=f"remove:{h.limb}@{h.env_surface}")
                out.append((Node(child, res.q, node, f"remove:{h.limb}@{h.env_surface}", node.depth + 1), None))
        return out

    def _within_a_step(self, stance: Stance, limb: str, candidates: list[Any]) -> list[Any]:
        """On a walked ladder, a foot's surfaces at most ``foot_max_treads_up`` treads above the
        other foot's hold (:func:`tread_levels`); every surface when the other foot holds nothing or
        holds no tread."""
        if not self.tread_of or limb_type(limb) != "foot":
            return candidates
        other = next((h for h in stance.holds if h.limb != limb and limb_type(h.limb) == "foot"), None)
        level = None if other is None else self.tread_of.get(other.env_surface)
        if level is None:
            return candidates
        bound = level + self.params.foot_max_treads_up
        kept = [sf for sf in candidates if self.tread_of.get(sf.name, -1) <= bound]
        self.stats.pruned_by_step += len(candidates) - len(kept)
        return kept

    def _supported_step(self, stance: Stance, limb: str, q: np.ndarray, candidates: list[Any]) -> list[Any]:
        """A foot's surfaces whose top is more than ``step_up_hand_support`` above its sole at ``q``
        are kept only when a hand holds a surface (every surface when the rule is off)."""
        rise = self.params.step_up_hand_support
        if rise <= 0.0 or limb_type(limb) != "foot" or any(limb_type(h.limb) == "hand" for h in stance.holds):
            return candidates
        sole_z = float(self.robot.T_world_surface(limb, q)[2, 3])
        kept = [sf for sf in candidates if sf.top_z - sole_z <= rise]
        self.stats.pruned_by_support += len(candidates) - len(kept)
        return kept

    def _banned(self, stance: Stance, child: Stance) -> bool:
        if not self.banned:
            return False
        r = self.params.key_resolution
        if (stance_key(stance, r), stance_key(child, r)) in self.banned:
            self.stats.skipped_banned += 1
            return True
        return False

    def _reached(self, node: Node, target: _Target, after: _Target | None) -> bool:
        """A guide-path milestone places the free-flyer (base), the search places the limbs: the
        last milestone is reached by the base and by every limb the milestone puts on a surface
        (its place within ``goal_tolerance`` of one; a limb in the air there is free); an
        intermediate one by the base, or passed: the base is as close to the next milestone's as
        this milestone's is (a guide path's in-between milestone need not be a configuration any
        contact set can hold)."""
        if after is None:
            tol = self.params.goal_tolerance
            return node.base_distance <= tol and all(
                node.limb_distances[j] <= tol for j, floor in target.floor.items() if floor <= tol)
        if node.base_distance <= self.params.milestone_tolerance:
            return True
        base_next, _, _ = distance_terms(node.q, {}, _Target(after.q, {}), self.params)
        span, _, _ = distance_terms(target.q, {}, _Target(after.q, {}), self.params)
        return base_next <= span

    def _limbs_in_place(self, node: Node, target: _Target) -> bool:
        """Every limb the milestone puts on a surface is in contact within ``goal_tolerance`` of it."""
        tol = self.params.goal_tolerance
        return all(node.stance.hold(j) is not None and node.limb_distances[j] <= tol
                   for j, floor in target.floor.items() if floor <= tol)

    def _settle(self, node: Node, target: _Target) -> Node | None:
        """The node's stance with its configuration pulled to the milestone: the IK (every contact
        regular, a limb the node removed zero-force on its hold) run to convergence instead of
        stopping at its first feasible iterate (near its seed: with the limbs in place, the body
        may still be away from the milestone's), then the frozen check."""
        t = time.perf_counter()
        self.stats.ik_calls += 1
        contacts = pcik.contacts_from_stance(node.stance)
        left = [] if node.parent is None else [h for h in node.parent.stance.holds if node.stance.hold(h.limb) is None]
        contacts += [pcik.ContactSpec(h.limb, pcik.ZERO_FORCE, hold=h) for h in left]  # a removal keeps its limb there
        res = pcik.solve(self.robot, self.env, node.q, contacts, q_target=target.q, params=self.pcik_params,
                         feasibility_cfg=self.cfg, final_check=False)
        out = None
        if not res.violated and pcik.check_with_exclusions(self.robot, self.env, res.q, node.stance, self.cfg, [
                (h.limb, h.env_surface) for h in left]).feasible:
            out = Node(node.stance, res.q, node.parent, node.move, node.depth)
            self._priority(out, target)
        self.stats.ik_time_s += time.perf_counter() - t
        if out is None:
            self.stats.ik_failures += 1
        return out

    def to_milestone(self, root: Node, target: _Target, index: int, after: _Target | None) -> Node:
        """Best-first search from ``root`` until a node reaches ``target`` (``after``: the next
        milestone, None for the last)."""
        counter = 0
        self.milestone_nodes0 = self.stats.nodes_expanded
        queue: list[tuple[float, int, Node]] = []
        heapq.heappush(queue, (self._priority(root, target, after), counter, root))
        seen = {stance_key(root.stance, self.params.key_resolution)}
        expanded: set = set()
        self.best = (root.distance, root.base_distance)
        self.last = after is None
        while queue:
            reason = self._out_of_budget()
            if reason == "milestone_budget":
                raise _GiveUpMilestone(reason)
            if reason:
                self._fail(reason, index)
            _, _, node = heapq.heappop(queue)
            if self._reached(node, target, after):
                return node
            if node.base_distance > self.params.milestone_tolerance and self._limbs_in_place(node, target):
                settled = self._settle(node, target)
                if settled is not None and self._reached(settled, target, after):
                    return settled
            key = stance_key(node.stance, self.params.key_resolution)
            if key in expanded:
                self.stats.skipped_visited += 1
                continue
            expanded.add(key)
            self.stats.nodes_expanded += 1
            for child, floating in self._children(node, target, seen):
                ckey = stance_key(child.stance, self.params.key_resolution)
                if ckey in seen:
                    self.stats.skipped_visited += 1
                    continue
                seen.add(ckey)
                counter += 1
                prio = self._priority(child, target, after, floating)
                self.best = min(self.best, (child.distance, child.base_distance))
                heapq.heappush(queue, (prio, counter, child))
                self.stats.nodes_pushed += 1
        if not self.last:
            raise _GiveUpMilestone("exhausted")
        self._fail("exhausted", index)
        raise AssertionError  # unreachable

    def _fail(self, reason: str, index: int) -> None:
        s = self.stats
        s.time_s = time.perf_counter() - self.t0
        tol = (f"{self.params.goal_tolerance} m on the base and the limbs it puts on surfaces" if self.last
               else f"{self.params.milestone_tolerance} m on the base")
        raise InfeasibleError(f"contact_search:{reason}", (
            f"milestone {index} not reached: closest node at configuration distance {self.best[0]:.3f} m, its base "
            f"{self.best[1]:.3f} m from the milestone's (tolerance {tol}) after {s.nodes_expanded} nodes expanded, {s.ik_calls} IK calls "
            f"({s.ik_failures} failed), {s.time_s:.1f} s (time limit {self.params.time_limit_s} s, node budget "
            f"{self.params.max_nodes})"))


def search(robot: Any, env: Any, q_start: np.ndarray, stance_start: Stance, path: GuidePath,
           params: ContactSearchParams | None = None, *, pcik_params: PCIKParams | None = None,
           feasibility_cfg: feasibility.FeasibilityConfig | None = None,
           banned: Collection[tuple] = (), walked: bool | None = None) -> SearchResult:
    """The stance sequence from (``q_start``, ``stance_start``) through the milestones of ``path``.

    The first milestone is skipped when the start is already within tolerance of it (a guide path
    starts at the start configuration). ``params`` default to config/planner.yaml's
    ``contact_search``; ``pcik_params`` to its ``pcik``; ``feasibility_cfg`` to the frozen
    config/feasibility.yaml. InfeasibleError ``contact_search:<reason>`` (time_limit,
    node_budget, exhausted) when a milestone is not reached; SpecError for a guide path of another
    robot or an empty one. ``banned``: transitions not to make, pairs of :func:`stance_key` (from,
    to) (:func:`banned_transition`: a transition whose whole-body path the adaptation could not
    build). ``walked``: the robot walks up this ladder (:func:`planner_node.settings.walked`; None:
    judged with config/planner.yaml's ``guide_path.walk_max_incline_deg``): the search's IK keeps
    the CoM over the held feet and a foot goes up one tread at a time."""
    from .settings import load_settings
    from .settings import walked as walked_scenario

    settings = None
    if params is None or pcik_params is None or walked is None:
        settings = load_settings()
    if walked is None:
        walked = walked_scenario(env, settings)
    params = params or settings.contact_search
    pcik_params = pcik_params or settings.pcik
    if path.robot != robot.config.name:
        raise SpecError("guide_path.robot",
                        f"must be the robot searched for ({robot.config.name!r}), got {path.robot!r}")
    if not path.milestones:
        raise SpecError("guide_path.milestones", "needs at least one milestone")
    nq = robot.model.nq
    for i, m in enumerate(path.milestones):
        if np.asarray(m).shape != (nq,) or not np.isfinite(m).all():
            raise SpecError(f"guide_path.milestones[{i}]", f"must be {nq} finite numbers")
    s = _Search(robot, env, params, pcik_params, feasibility_cfg, banned, walked)
    node = Node(stance_start, np.asarray(q_start, dtype=float).copy())
    reached: list[Node] = []
    targets = [s.target(np.asarray(m, dtype=float)) for m in path.milestones]
    for i, target in enumerate(targets):
        try:
            node = s.to_milestone(node, target, i, targets[i + 1] if i + 1 < len(targets) else None)
        except _GiveUpMilestone:  # an intermediate milestone no contact set gets to: on to the next one
            s.stats.milestones_skipped.append(i)
            continue
        reached.append(node)
        s.stats.milestones_reached = i + 1
    s.stats.time_s = time.perf_counter() - s.t0
    chain: list[Node] = []
    n: Node | None = node
    while n is not None:
        chain.append(n)
        n = n.parent
    chain.reverse()
    chain = without_detours(chain)
    index = {id(n): k for k, n in enumerate(chain)}
    index.update({id(n): index[id(n.kept_as)] for n in reached if id(n) not in index})
    plan = ContactPlan(robot=robot.config.name, environment=env.name, joint_names=list(robot.joint_names),
                       stances=[n.stance for n in chain], transition_configurations=[n.q.copy() for n in chain])
    return SearchResult(plan, [n.move for n in chain[1:]], s.stats, [index[id(n)] for n in reached])


class _GiveUpMilestone(Exception):
    """An intermediate milestone's own node budget spent (or its queue empty) without reaching it."""


def without_detours(chain: list[Node]) -> list[Node]:
    """``chain`` without the detours that come back to a contact set already in it: from each
    node whose stance equals an earlier one's (the same holds), back to that earlier node, which
    stays with its configuration. The search expands each set once per milestone only, so the
    extracted sequence can add a contact at one milestone and take it off again at the next: on
    narrow_passage a hand went onto the wall and off while a foot was in the air, two moves for
    nothing that the adaptation then had to make whole-body. Consecutive stances still differ by
    exactly one hold. A dropped node's ``kept_as`` is the node that stands for it."""
    kept: list[Node] = []
    for n in chain:
        for k, m in enumerate(kept):
            added, removed = transition_changes(m.stance, n.stance)
            if not added and not removed:
                for d in kept[k + 1:] + [n]:
                    d.kept_as = m
                kept = kept[:k + 1]
                break
        else:
            kept.append(n)
    for n in chain:  # a node dropped with the detour of a node dropped later
        while n.kept_as is not None and n.kept_as.kept_as is not None:
            n.kept_as = n.kept_as.kept_as
    return kept


def transition_changes(before: Stance, after: Stance) -> tuple[list[Hold], list[Hold]]:
    """(holds added, holds removed) from ``before`` to ``after`` (a hold is the same when its limb,
    surface and points are)."""
    def same(a: Hold, b: Hold) -> bool:
        return a.limb == b.limb and a.env_surface == b.env_surface and np.allclose(a.positions, b.positions)

    added = [h for h in after.holds if not any(same(h, g) for g in before.holds)]
    removed = [h for h in before.holds if not any(same(h, g) for g in after.holds)]
    return added, removed


def moves_of(plan: ContactPlan) -> list[str]:
    """The moves of a contact plan, "add:<limb>@<surface>" / "remove:<limb>@<surface>" per stance
    pair (as the search names them)."""
    out = []
    for a, b in zip(plan.stances[:-1], plan.stances[1:]):
        added, removed = transition_changes(a, b)
        h, kind = (added[0], "add") if added else (removed[0], "remove") if removed else (None, "")
        out.append(f"{kind}:{h.limb}@{h.env_surface}" if h is not None else "")
    return out


__all__ = ["search", "moves_of", "SearchResult", "SearchStats", "Node", "configuration_distance", "accepting_surfaces",
           "limb_reach", "surface_distance", "tread_levels", "stance_key", "transition_changes", "without_detours", "limb_type"]
