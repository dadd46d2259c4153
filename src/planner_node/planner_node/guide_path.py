"""The free-flyer guide path of the DARPA-tasks paper (section III-A), without ROS.

The robot is a free-flyer: a *state* is (root x, y, z, root yaw, posture blend s). ``s`` runs over
the robot's reference postures in the order of config/guide_postures/<robot>.yaml (G1: crouching,
standing, climbing); a fractional s blends the joint angles and the root pitch of its two
neighbours linearly. A state maps to a full Pinocchio configuration (:meth:`GuidePlanner.configuration`).

A state is *valid* when

- the rough static-equilibrium criterion holds (:meth:`GuidePlanner.support`): at least
  ``min_supporting_limbs`` limbs reach a surface that accepts their limb type, at least
  ``min_supporting_feet`` of them feet on a surface point ``foot_below_com`` below the CoM. A limb
  reaches a surface when the distance from its root joint (hip pitch, shoulder pitch) to the
  surface's closest point (a foot: the surface's upward face) is at most ``reach_fraction`` times
  the limb's length (the sum of its joint-to-joint segments down to the contact surface centre,
  computed from the model once);
- the free-flyer body (the postures file's ``body_links`` in the state's posture) keeps ``body_clearance``
  from every environment surface (coal, on the collision checker's hulls; bounding spheres cull
  the far pairs; the limbs are left to the contact search, which places them).

RRT-Connect (Kuffner and LaValle 2000) grows a tree from the start configuration and one from a
goal configuration (sampled within the goal tolerance). Each random sample is biased toward the
reference postures and toward facing the goal, then *projected*: its root moves down by
``projection_step`` until the criterion holds (at most ``max_drop``), and is rejected when the
body collides there and ``projection_collision_tries - 1`` steps below. Edges are linear
interpolations checked every ``edge_resolution``; the path is shortcut, then cut into milestones
at most ``milestone_spacing`` apart. A ladder climb targets the standing-on-rung-k base positions
in turn (:func:`ladder_goal_position`), one rung apart.

Deterministic for a seed (one numpy Generator, no wall-time dependent branch before the limit);
failures raise InfeasibleError(``guide_path:<reason>``).
"""
from __future__ import annotations

import math
import pathlib
import time
from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np
import pinocchio as pin
import yaml

from climb_core.contact import FEET, GuidePath, limb_type
from climb_core.errors import InfeasibleError, SpecError

from .settings import GuidePathParams, load_settings

#: reference postures the planner needs in every postures file (any order; more are allowed)
REQUIRED_POSTURES = ("standing", "climbing", "crouching")
#: fixture whose feet rung and base give the standing-on-rung offset
LADDER_FIXTURE = "ladder_4_contacts"


# --------------------------------------------------------------------------------------------
# reference postures


@dataclass(frozen=True)
class ReferencePostures:
    """Reference postures of one robot: names in blend order, joint angles (n, nq - 7) [rad],
    root pitch (n,) [rad], sampling weights (n,), and the links of the free-flyer body."""

    names: tuple[str, ...]
    joints: np.ndarray
    root_pitch: np.ndarray
    weights: np.ndarray
    body_links: tuple[str, ...]

    def index(self, name: str) -> int:
        return self.names.index(name)

    def blend(self, s: float) -> tuple[np.ndarray, float]:
        """(joint angles, root pitch) at blend parameter s in [0, n - 1]."""
        i = min(int(math.floor(s)), len(self.names) - 2) if len(self.names) > 1 else 0
        f = s - i if len(self.names) > 1 else 0.0
        if f <= 0.0:
            return self.joints[i].copy(), float(self.root_pitch[i])
        return ((1.0 - f) * self.joints[i] + f * self.joints[i + 1],
                float((1.0 - f) * self.root_pitch[i] + f * self.root_pitch[i + 1]))


def postures_path(robot_name: str, params: GuidePathParams) -> pathlib.Path:
    from climb_core.ros_env import project_root

    d = pathlib.Path(params.postures_dir)
    return (d if d.is_absolute() else project_root() / d) / f"{robot_name}.yaml"


def load_reference_postures(robot: Any, params: GuidePathParams) -> ReferencePostures:
    """The robot's reference postures file; SpecError naming the field for a bad one."""
    path = postures_path(robot.config.name, params)
    where = f"guide_postures/{path.name}"
    try:
        doc = yaml.safe_load(path.read_text())
    except (OSError, yaml.YAMLError) as exc:
        raise SpecError(where, f"cannot read {path}: {exc}") from None
    if not isinstance(doc, dict) or not isinstance(doc.get("postures"), dict):
        raise SpecError(f"{where}.postures", "must be a mapping name -> {root_pitch, weight, joints}")
    order = doc.get("order", list(doc["postures"]))
    missing = [n for n in REQUIRED_POSTURES if n not in order]
    if missing or sorted(order) != sorted(doc["postures"]):
        raise SpecError(f"{where}.order", f"must list every posture once and include {REQUIRED_POSTURES}")
    names = list(robot.joint_names)
    joints, pitch, weights = [], [], []
    for name in order:
        p = doc["postures"][name]
        if not isinstance(p, dict) or not isinstance(p.get("joints"), dict):
            raise SpecError(f"{where}.postures.{name}.joints", "must be a mapping joint -> angle [rad]")
        row = np.zeros(len(names))
        for joint, value in p["joints"].items():
            if joint not in names:
                raise SpecError(f"{where}.postures.{name}.joints.{joint}", f"not a joint of {robot.config.name}")
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
                raise SpecError(f"{where}.postures.{name}.joints.{joint}", "must be a finite number [rad]")
            row[names.index(joint)] = float(value)
        joints.append(row)
        for key, out, low, high, default in (("root_pitch", pitch, -math.pi / 2, math.pi / 2, 0.0),
                                             ("weight", weights, 0.0, math.inf, 1.0)):
            v = p.get(key, default)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not low <= v <= high:
                raise SpecError(f"{where}.postures.{name}.{key}", f"must be a number in [{low}, {high}]")
            out.append(float(v))
    if sum(weights) <= 0.0:
        raise SpecError(f"{where}.postures", "at least one weight must be > 0")
    links = doc.get("body_links")
    if not isinstance(links, list) or not links or not all(isinstance(k, str) for k in links):
        raise SpecError(f"{where}.body_links", "must be a non-empty list of link names")
    return ReferencePostures(tuple(order), np.array(joints), np.array(pitch), np.array(weights) / sum(weights),
                             tuple(links))


def derive_reference_postures(robot: Any, env: Any | None = None) -> dict[str, tuple[dict[str, float], float, str]]:
    """name -> (joint angles, root pitch, how obtained) from the project's configurations: standing =
    ``robot.q_reference()``; climbing = the ``ladder_4_contacts`` fixture on the default ladder (root
    yaw and roll ~0); crouching = the reference posture with the leg pitch joints tripled (hip +
    knee + ankle pitch still sum to 0: soles flat)."""
    from climb_core import fixtures
    from climb_core.environment import build_environment

    names = list(robot.joint_names)
    q_ref = robot.q_reference()
    standing = {n: float(v) for n, v in zip(names, q_ref[7:])}
    _, q_climb = fixtures.get(LADDER_FIXTURE, robot, env or build_environment("default"))
    rpy = pin.rpy.matrixToRpy(pin.Quaternion(q_climb[3:7]).normalized().toRotationMatrix())
    climbing = {n: float(v) for n, v in zip(names, q_climb[7:])}
    legs = ("hip_pitch", "knee", "ankle_pitch")
    crouching = {n: (3.0 * v if any(k in n for k in legs) else v) for n, v in standing.items()}
    return {
        "crouching": (crouching, 0.0, "robot.q_reference() with the hip pitch, knee and ankle pitch angles x3"),
        "standing": (standing, 0.0, "robot.q_reference() (config/robots/<robot>.yaml reference_posture)"),
        "climbing": (climbing, float(rpy[1]), f"fixture {LADDER_FIXTURE} on the default ladder (feet rung 1, "
                                              "hands rung 5): joints and root pitch"),
    }


def write_reference_postures(robot: Any, params: GuidePathParams, body_links: Sequence[str],
                             env: Any | None = None) -> pathlib.Path:
    """Write config/guide_postures/<robot>.yaml from :func:`derive_reference_postures`."""
    derived = derive_reference_postures(robot, env)
    lines = [f"# Reference postures of the guide path's free-flyer (planner_node.guide_path), robot {robot.config.name}.",
             "# Generated by planner_node.guide_path.write_reference_postures; angles [rad], rounded to 1e-4.",
             "# `order` is the blend order (a sample's posture blends two neighbours); `weight` the sampling weight.",
             f"robot: {robot.config.name}",
             "# links of the free-flyer body checked for collision: trunk, head, the first links of each limb",
             "# (hips, shoulders); the rest of the limbs is left to the contact search, which places them",
             "body_links: [" + ", ".join(body_links) + "]",
             "order: [crouching, standing, climbing]", "postures:"]
    weights = {"crouching": 1.0, "standing": 1.0, "climbing": 2.0}
    for name in ("crouching", "standing", "climbing"):
        joints, pitch, how = derived[name]
        lines += [f"  {name}:", f"    obtained: \"{how}\"", f"    root_pitch: {pitch:.4f}",
                  f"    weight: {weights[name]}", "    joints:"]
        lines += [f"      {j}: {round(v, 4)}" for j, v in joints.items() if abs(v) >= 5e-5]
    path = postures_path(robot.config.name, params)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(lines) + "\n")
    return path


# --------------------------------------------------------------------------------------------
# surfaces: closest points


@dataclass(frozen=True)
class _SurfaceSet:
    """Primitives of the surfaces accepting one limb type, stacked for vectorised closest points."""

    names: tuple[str, ...]
    R: np.ndarray  # (m, 3, 3) primitive rotation
    p: np.ndarray  # (m, 3) primitive centre
    half: np.ndarray  # (m, 3) half extents along the primitive axes
    cylinder: np.ndarray  # (m,) bool: axis = primitive z, radius half[0]
    up_axis: np.ndarray  # (m,) primitive axis closest to world z
    up_sign: np.ndarray  # (m,) its sign
    top_only: bool  # clamp boxes onto their upward face (feet)

    def closest(self, x: np.ndarray) -> np.ndarray:
        """(k, m, 3) closest points of the m surfaces to the k points x (k, 3)."""
        if not self.names:
            return np.zeros((len(x), 0, 3))
        local = np.einsum("mji,kmj->kmi", self.R, x[:, None, :] - self.p[None])
        box = np.clip(local, -self.half, self.half)
        if self.top_only:
            m = np.arange(len(self.names))
            box[:, m, self.up_axis] = (self.up_sign * self.half[m, self.up_axis])[None]
        cyl = local.copy()
        cyl[..., 2] = np.clip(local[..., 2], -self.half[:, 2], self.half[:, 2])
        r = np.linalg.norm(local[..., :2], axis=-1)
        scale = np.minimum(1.0, self.half[:, 0] / np.maximum(r, 1e-12))
        cyl[..., :2] = local[..., :2] * scale[..., None]
        out = np.where(self.cylinder[None, :, None], cyl, box)
        return np.einsum("mij,kmj->kmi", self.R, out) + self.p[None]


def _surface_set(surfaces: Sequence[Any], top_only: bool) -> _SurfaceSet:
    R = np.array([s.T_world_primitive()[:3, :3] for s in surfaces]).reshape(-1, 3, 3)
    up = np.abs(R[:, 2, :]).argmax(axis=1) if len(surfaces) else np.zeros(0, dtype=int)
    sign = np.sign(R[np.arange(len(surfaces)), 2, up]) if len(surfaces) else np.zeros(0)
    return _SurfaceSet(tuple(s.name for s in surfaces), R,
                       np.array([s.T_world_primitive()[:3, 3] for s in surfaces]).reshape(-1, 3),
                       np.array([s.primitive_half_extents() for s in surfaces]).reshape(-1, 3),
                       np.array([s.shape == "cylinder" for s in surfaces], dtype=bool), up, sign, top_only)


def contact_surfaces(env: Any, kind: str) -> list[Any]:
    """Surfaces accepting a limb type ("foot" | "hand"): ``env.contact_surfaces``, as Surfaces."""
    return [env.surfaces[s] if isinstance(s, str) else s for s in env.contact_surfaces(kind)]


# --------------------------------------------------------------------------------------------
# the planner


@dataclass
class SupportReport:
    """The equilibrium criterion at one state: which limbs reach which surface."""

    ok: bool
    limbs: dict[str, str]  # limb -> surface it reaches (closest)
    com: np.ndarray


@dataclass
class GuideStats:
    """Counters of one query (samples drawn and rejected, tree nodes, clearance queries, edges)."""

    samples: int = 0
    unsupported: int = 0
    in_collision: int = 0
    nodes: int = 0
    collision_checks: int = 0
    edges_checked: int = 0
    time_s: float = 0.0
    reasons: dict[str, int] = field(default_factory=dict)

    def as_dict(self) -> dict:
        return {k: (round(v, 4) if isinstance(v, float) else v) for k, v in self.__dict__.items()}


class GuidePlanner:
    """The free-flyer of one (robot, environment, parameters): states -> configurations, the
    equilibrium criterion, body clearance, projection and steering (the search is :class:`_Search`)."""

    def __init__(self, robot: Any, env: Any, params: GuidePathParams | None = None):
        from climb_core.collision import ENV_PREFIX, checker

        self.robot, self.env = robot, env
        self.params = params or load_settings().guide_path
        self.postures = load_reference_postures(robot, self.params)
        self.model = robot.model
        self.data = self.model.createData()
        self.n_post = len(self.postures.names)
        self._limb_roots, self._limb_lengths = self._limbs()
        self._surfaces = {k: _surface_set(contact_surfaces(env, k), top_only=(k == "foot")) for k in ("foot", "hand")}
        self.checker = checker(robot, env)
        links = set(self.postures.body_links)
        unknown = links - {self.checker.geom_link[i] for i in range(self.checker.n_robot)}
        if unknown:
            raise SpecError(f"guide_postures/{robot.config.name}.yaml.body_links",
                            f"not collision links of {robot.config.name}: {sorted(unknown)}")
        self.body_geoms = [g for g, link in zip(self.checker.robot_geoms, self.checker.geom_link) if link in links]
        self.body_pairs = [(g, ENV_PREFIX + s) for g in self.body_geoms for s in self.checker.env_names]
        self._build_collision()

    # ---------------------------------------------------------------- model facts
    def _limbs(self) -> tuple[dict[str, int], dict[str, float]]:
        """Root joint id and length [m] per limb: the chain from its first joint that no other limb
        shares (hip pitch; shoulder pitch, after the waist) to the contact surface centre."""
        model, data = self.model, self.data
        q = self.robot.q_reference()
        pin.framesForwardKinematics(model, data, q)
        limbs = self.robot.config.limbs
        roots, lengths = {}, {}
        for name, limb in limbs.items():
            shared = {j for other, ol in limbs.items() if other != name for j in ol.joints}
            chain = [j for j in limb.joints if j not in shared] or list(limb.joints)
            start = limb.joints.index(chain[0])
            ids = [model.getJointId(j) for j in limb.joints[start:]]
            points = [data.oMi[i].translation.copy() for i in ids]
            points.append(data.oMf[self.robot.frame_id(limb.surface.frame)].act(limb.surface.centre))
            roots[name] = ids[0]
            lengths[name] = float(np.linalg.norm(np.diff(np.array(points), axis=0), axis=1).sum())
        return roots, lengths

    @property
    def limb_lengths(self) -> dict[str, float]:
        return dict(self._limb_lengths)

    # ---------------------------------------------------------------- states
    def configuration(self, x: np.ndarray) -> np.ndarray:
        """Full configuration (nq,) of a state (x, y, z, yaw, s)."""
        joints, pitch = self.postures.blend(float(x[4]))
        q = np.empty(self.model.nq)
        q[:3] = x[:3]
        q[3:7] = pin.Quaternion(pin.rpy.rpyToMatrix(0.0, pitch, float(x[3]))).coeffs()
        q[7:] = joints
        return q

    def metric(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """State distance [m] (b may be (n, 5))."""
        d = np.atleast_2d(b) - a
        dyaw = (d[:, 3] + math.pi) % (2.0 * math.pi) - math.pi
        p = self.params
        return np.sqrt((d[:, :3] ** 2).sum(axis=1) + (p.yaw_weight * dyaw) ** 2 + (p.posture_weight * d[:, 4]) ** 2)

    def interpolate(self, a: np.ndarray, b: np.ndarray, t: float) -> np.ndarray:
        dyaw = (b[3] - a[3] + math.pi) % (2.0 * math.pi) - math.pi
        x = a + t * (b - a)
        x[3] = (a[3] + t * dyaw + math.pi) % (2.0 * math.pi) - math.pi
        return x

    # ---------------------------------------------------------------- validity
    def support(self, x: np.ndarray, q: np.ndarray | None = None) -> SupportReport:
        """The rough equilibrium criterion at state x (see the module docstring)."""
        q = self.configuration(x) if q is None else q
        com = pin.centerOfMass(self.model, self.data, q)
        reached: dict[str, str] = {}
        for kind, limbs in (("foot", [l for l in self._limb_roots if limb_type(l) == "foot"]),
                            ("hand", [l for l in self._limb_roots if limb_type(l) == "hand"])):
            surfaces = self._surfaces[kind]
            if not limbs or not surfaces.names:
                continue
            roots = np.array([self.data.oMi[self._limb_roots[l]].translation for l in limbs])
            c = surfaces.closest(roots)
            dist = np.linalg.norm(c - roots[:, None], axis=-1)
            reach = np.array([self.params.reach_fraction * self._limb_lengths[l] for l in limbs])[:, None]
            ok = dist <= reach
            if kind == "foot":
                ok &= c[..., 2] <= com[2] - self.params.foot_below_com
            for i, limb in enumerate(limbs):
                if ok[i].any():
                    reached[limb] = surfaces.names[int(np.argmin(np.where(ok[i], dist[i], np.inf)))]
        feet = sum(1 for l in reached if limb_type(l) == "foot")
        good = len(reached) >= self.params.min_supporting_limbs and feet >= self.params.min_supporting_feet
        return SupportReport(good, reached, com)

    def _build_collision(self) -> None:
        """The body's pairs in a small geometry model, with bounding spheres for culling."""
        query = self.checker.pair_query(self.body_pairs)
        self._gm, self._gd = query.geometry_model, query.geometry_data
        gm = self._gm
        objs = gm.geometryObjects
        pairs = [(p.first, p.second) for p in gm.collisionPairs]
        self._pair_body = np.array([a for a, _ in pairs], dtype=int)
        env_pose = {}
        for name, geometry, transform in self.env.collision_objects():
            env_pose[name] = (np.asarray(transform.getRotation()), np.asarray(transform.getTranslation()))
        body_index = sorted(set(self._pair_body.tolist()))
        self._body_index = body_index
        slot = {g: k for k, g in enumerate(body_index)}
        self._pair_slot = np.array([slot[a] for a in self._pair_body], dtype=int)
        self._sphere_joint, self._sphere_centre, self._sphere_radius = [], [], []
        for g in body_index:
            go = objs[g]
            go.geometry.computeLocalAABB()
            self._sphere_joint.append(go.parentJoint)
            self._sphere_centre.append(go.placement.act(np.asarray(go.geometry.aabb_center)))
            self._sphere_radius.append(float(go.geometry.aabb_radius))
        self._sphere_centre = np.array(self._sphere_centre)
        self._sphere_radius = np.array(self._sphere_radius)
        surf_of = [objs[b].name.removeprefix("env:") for _, b in pairs]
        self._pair_R = np.array([env_pose[s][0] for s in surf_of])
        self._pair_p = np.array([env_pose[s][1] for s in surf_of])
        self._pair_h = np.array([self.env.surfaces[s].primitive_half_extents() for s in surf_of])
        self._pair_names = [(objs[a].name, objs[b].name) for a, b in pairs]

    def clearance(self, q: np.ndarray, threshold: float | None = None) -> tuple[float, tuple[str, str]]:
        """(signed distance [m], pair): below ``threshold`` (default body_clearance) exactly when the
        body's smallest signed distance to the environment is. Pairs are computed (coal) in the
        order of their bounding-sphere lower bound until one falls below the threshold; when none
        does, the smallest distance or lower bound found (a lower bound of the true minimum)."""
        thr = self.params.body_clearance if threshold is None else threshold
        model, data = self.model, self.data
        pin.forwardKinematics(model, data, q)
        T = [data.oMi[j] for j in self._sphere_joint]
        centres = np.array([M.act(c) for M, c in zip(T, self._sphere_centre)])
        c = centres[self._pair_slot]
        local = np.einsum("nji,nj->ni", self._pair_R, c - self._pair_p)
        excess = np.abs(local) - self._pair_h
        outside = np.linalg.norm(np.maximum(excess, 0.0), axis=1) + np.minimum(excess.max(axis=1), 0.0)
        lower = outside - self._sphere_radius[self._pair_slot]
        todo = np.flatnonzero(lower < thr)
        if len(todo) == 0:
            k = int(np.argmin(lower))
            return float(lower[k]), self._pair_names[k]
        pin.updateGeometryPlacements(model, data, self._gm, self._gd)
        best, pair = math.inf, ("", "")
        for k in todo[np.argsort(lower[todo])].tolist():
            d = pin.computeDistance(self._gm, self._gd, k).min_distance
            if d < best:
                best, pair = d, self._pair_names[k]
            if best < thr:
                break
        return best, pair

    def valid(self, x: np.ndarray, stats: GuideStats | None = None) -> str:
        """"" when state x is valid, else "unsupported" or "collision"."""
        q = self.configuration(x)
        if not self.support(x, q).ok:
            return "unsupported"
        if stats is not None:
            stats.collision_checks += 1
        return "" if self.clearance(q)[0] >= self.params.body_clearance else "collision"

    def project(self, x: np.ndarray, floor: float = -math.inf, ceiling: float = math.inf,
                stats: GuideStats | None = None) -> tuple[np.ndarray | None, str]:
        """(x moved down until valid, "") or (None, reason): the root descends by projection_step
        until the criterion holds (at most max_drop, not below ``floor``), then at most
        projection_collision_tries heights are checked for collision. (Rising to the highest
        supported height, limbs at their reach, was tried: states on the reach boundary make
        the interpolated edges between them fail; 10x slower on the scenes.)"""
        p = self.params
        x = np.array(x, dtype=float)
        x[2] = min(x[2], ceiling)
        z0, tries = x[2], 0
        reason = "unsupported"
        while x[2] >= max(z0 - p.max_drop, floor) - 1e-12:
            q = self.configuration(x)
            if self.support(x, q).ok:
                if stats is not None:
                    stats.collision_checks += 1
                if self.clearance(q)[0] >= p.body_clearance:
                    return x, ""
                reason, tries = "collision", tries + 1
                if tries >= p.projection_collision_tries:
                    break
            elif tries:
                break
            x[2] -= p.projection_step
        return None, reason

    def edge_states(self, a: np.ndarray, b: np.ndarray) -> tuple[list[np.ndarray], int]:
        """(states along a -> b checked by the steering, excluding a; every ``stride``-th is a milestone)."""
        length = float(self.metric(a, b)[0])
        n_m = max(1, math.ceil(length / self.params.milestone_spacing - 1e-9))
        stride = max(1, math.ceil(length / n_m / self.params.edge_resolution - 1e-9))
        n = n_m * stride
        return [self.interpolate(a, b, i / n) for i in range(1, n + 1)], stride

    def edge_valid(self, a: np.ndarray, b: np.ndarray, stats: GuideStats | None = None) -> bool:
        """Linear-interpolation steering a -> b: every checked state valid (a assumed valid)."""
        if stats is not None:
            stats.edges_checked += 1
        states, _ = self.edge_states(a, b)
        return all(self.valid(x, stats) == "" for x in states[:-1]) and self.valid(states[-1], stats) == ""


# --------------------------------------------------------------------------------------------
# RRT-Connect


class _Tree:
    def __init__(self, root: np.ndarray, capacity: int = 1024):
        self.x = np.zeros((capacity, 5))
        self.parent = np.full(capacity, -1, dtype=int)
        self.x[0] = root
        self.n = 1

    def add(self, x: np.ndarray, parent: int) -> int:
        if self.n == len(self.x):
            self.x = np.vstack([self.x, np.zeros_like(self.x)])
            self.parent = np.concatenate([self.parent, np.full(len(self.parent), -1, dtype=int)])
        self.x[self.n], self.parent[self.n] = x, parent
        self.n += 1
        return self.n - 1

    def branch(self, i: int) -> list[np.ndarray]:
        """States from the root to node i."""
        out = []
        while i >= 0:
            out.append(self.x[i].copy())
            i = int(self.parent[i])
        return out[::-1]


@dataclass(frozen=True)
class Goal:
    """A goal: base position [m] within tolerance [m]; preferred yaw [rad] and posture (None: any)."""

    position: np.ndarray
    tolerance: float
    yaw: float | None = None
    posture: str | None = None


class _Search:
    """One RRT-Connect query from state ``start`` to ``goal`` (shares the deadline and generator)."""

    def __init__(self, planner: GuidePlanner, start: np.ndarray, goal: Goal, rng: np.random.Generator,
                 deadline: float, stats: GuideStats):
        self.pl, self.start, self.goal, self.rng, self.deadline, self.stats = planner, start, goal, rng, deadline, stats
        p = planner.params
        lo = np.minimum(start[:3], goal.position) - [p.workspace_margin_xy, p.workspace_margin_xy, p.workspace_margin_z]
        hi = np.maximum(start[:3], goal.position) + [p.workspace_margin_xy, p.workspace_margin_xy, p.workspace_margin_z]
        self.lo, self.hi = lo, hi
        d = goal.position[:2] - start[:2]
        self.heading = goal.yaw if goal.yaw is not None else (
            math.atan2(d[1], d[0]) if np.linalg.norm(d) > 1e-3 else float(start[3]))

    def _yaw(self) -> float:
        p = self.pl.params
        if self.rng.random() < p.yaw_bias:
            return float((self.heading + self.rng.normal(0.0, p.yaw_sigma) + math.pi) % (2 * math.pi) - math.pi)
        return float(self.rng.uniform(-math.pi, math.pi))

    def _posture(self) -> float:
        post = self.pl.postures
        if self.rng.random() < self.pl.params.posture_bias:
            return float(self.rng.choice(len(post.names), p=post.weights))
        return float(self.rng.uniform(0.0, len(post.names) - 1))

    def sample(self) -> np.ndarray | None:
        """A biased random state, projected (None when the projection rejects it)."""
        x = np.array([*self.rng.uniform(self.lo, self.hi), self._yaw(), self._posture()])
        self.stats.samples += 1
        y, reason = self.pl.project(x, floor=self.lo[2] - self.pl.params.max_drop, stats=self.stats)
        if y is None:
            self.stats.reasons[reason] = self.stats.reasons.get(reason, 0) + 1
            if reason == "unsupported":
                self.stats.unsupported += 1
            else:
                self.stats.in_collision += 1
        return y

    def goal_state(self) -> np.ndarray:
        """A valid state within the goal tolerance; InfeasibleError naming why none is found."""
        g, post = self.goal, self.pl.postures
        order = ([post.index(g.posture)] if g.posture in post.names else []) + [
            i for i in np.argsort(-post.weights, kind="stable").tolist() if post.names[i] != g.posture]
        reasons: dict[str, int] = {}
        for k in range(self.pl.params.goal_samples):
            if k < len(order):
                x = np.array([*g.position, self.heading, float(order[k])])
            else:
                direction = self.rng.normal(size=3)
                r = g.tolerance * self.rng.random() ** (1 / 3)
                x = np.array([*(g.position + r * direction / np.linalg.norm(direction)), self._yaw(), self._posture()])
            half = math.sqrt(max(g.tolerance ** 2 - float(np.sum((x[:2] - g.position[:2]) ** 2)), 0.0))
            top = g.position[2] if k < len(order) else g.position[2] + half  # the exact goal first
            y, reason = self.pl.project(x, floor=g.position[2] - half, ceiling=top, stats=self.stats)
            if y is not None:
                return y
            reasons[reason] = reasons.get(reason, 0) + 1
            if time.perf_counter() > self.deadline:
                break
        what = "goal_in_collision" if reasons.get("collision") else "goal_unsupported"
        raise InfeasibleError(f"guide_path:{what}", (
            f"no free-flyer state within {g.tolerance} m of the goal {np.round(g.position, 3).tolist()} is "
            f"{'collision-free (body clearance)' if what == 'goal_in_collision' else 'supported (equilibrium criterion)'}"
            f"; tried {sum(reasons.values())}: {reasons}"))

    def _extend(self, tree: _Tree, target: np.ndarray) -> tuple[str, int]:
        """RRT extension toward target: ("reached" | "advanced" | "trapped", new node)."""
        d = self.pl.metric(target, tree.x[: tree.n])
        near = int(np.argmin(d))
        step = self.pl.params.step_size
        if d[near] <= step:
            x, status = target.copy(), "reached"
        else:
            x = self.pl.interpolate(tree.x[near], target, step / float(d[near]))
            x, _ = self.pl.project(x, stats=self.stats)
            if x is None or self.pl.metric(target, x)[0] >= d[near] - 0.25 * step:
                return "trapped", -1  # rejected, or the projection undid the progress
            status = "advanced"
        if not self.pl.edge_valid(tree.x[near], x, self.stats):
            return "trapped", -1
        self.stats.nodes += 1
        return status, tree.add(x, near)

    def _connect(self, tree: _Tree, target: np.ndarray) -> tuple[str, int]:
        while True:
            status, i = self._extend(tree, target)
            if status != "advanced" or time.perf_counter() > self.deadline:
                return status, i

    def run(self) -> list[np.ndarray]:
        """States from start to a goal state; InfeasibleError on timeout."""
        goal = self.goal_state()
        ta, tb = _Tree(self.start), _Tree(goal)
        status, j = self._connect(tb, self.start)  # RRT-Connect's first connect: from the goal toward the start
        if status == "reached":
            return tb.branch(j)[::-1]
        a_is_start = True
        while time.perf_counter() < self.deadline:
            x = self.sample()
            if x is not None:
                status, i = self._extend(ta, x)
                if status != "trapped":
                    s2, j = self._connect(tb, ta.x[i])
                    if s2 == "reached":
                        pa, pb = ta.branch(i), tb.branch(j)
                        path = pa + pb[::-1][1:]
                        return path if a_is_start else path[::-1]
            ta, tb, a_is_start = tb, ta, not a_is_start
        s = self.stats
        if s.samples and s.unsupported == s.samples:
            raise InfeasibleError("guide_path:no_supported_sample", (
                f"none of {s.samples} samples passes the equilibrium criterion within the time limit"))
        raise InfeasibleError("guide_path:goal_unreachable", (
            f"no path to the goal {np.round(self.goal.position, 3).tolist()} within the time limit: "
            f"{s.samples} samples ({s.unsupported} unsupported, {s.in_collision} in collision), "
            f"trees of {ta.n} and {tb.n} nodes"))


# --------------------------------------------------------------------------------------------
# path post-processing and the public API


def _shortcut(pl: GuidePlanner, path: list[np.ndarray], rng: np.random.Generator, stats: GuideStats,
              deadline: float) -> list[np.ndarray]:
    """Greedy pass (from each kept state, the farthest state it connects to), then random pairs."""
    out, i = [path[0]], 0
    while i < len(path) - 1:
        j = len(path) - 1
        while j > i + 1 and (time.perf_counter() > deadline or not pl.edge_valid(path[i], path[j], stats)):
            j -= 1
        out.append(path[j])
        i = j
    path = out
    for _ in range(pl.params.shortcut_iterations):
        if len(path) < 3 or time.perf_counter() > deadline:
            break
        i, j = sorted(rng.choice(len(path), size=2, replace=False).tolist())
        if j - i < 2:
            continue
        if pl.edge_valid(path[i], path[j], stats):
            path = path[: i + 1] + path[j:]
    return path


def _milestones(pl: GuidePlanner, path: list[np.ndarray]) -> list[np.ndarray]:
    """States every milestone_spacing along the path (the steering's own checked states)."""
    out = [path[0]]
    for a, b in zip(path[:-1], path[1:]):
        if pl.metric(a, b)[0] < 1e-6:  # a goal already reached (a start on the first rung goal)
            continue
        states, stride = pl.edge_states(a, b)
        out += states[stride - 1:: stride]
    return out


def state_of(pl: GuidePlanner, q: np.ndarray) -> np.ndarray:
    """The free-flyer state of a configuration: its root position and yaw, the posture blend whose
    joints are closest (least squares over the blend segments)."""
    q = np.asarray(q, dtype=float)
    yaw = float(pin.rpy.matrixToRpy(pin.Quaternion(q[3:7]).normalized().toRotationMatrix())[2])
    best, best_s = math.inf, 0.0
    for s in np.linspace(0.0, pl.n_post - 1, 20 * (pl.n_post - 1) + 1):
        err = float(np.sum((pl.postures.blend(s)[0] - q[7:]) ** 2))
        if err < best:
            best, best_s = err, float(s)
    return np.array([*q[:3], yaw, best_s])


@dataclass
class GuideResult:
    """A guide path and how it was found."""

    path: GuidePath
    states: list[np.ndarray]  # free-flyer state of each milestone
    stats: GuideStats


def plan_guide_path(robot: Any, env: Any, q_start: np.ndarray, goal_position: Sequence[float] | Goal,
                    tolerance: float = 0.15, params: GuidePathParams | None = None, seed: int | None = None,
                    time_limit_s: float | None = None, stats: dict | None = None) -> GuidePath:
    """The guide path from ``q_start`` to a base position within ``tolerance`` [m] of
    ``goal_position`` (or through a list of goals: :func:`plan_guide_path_through`).
    InfeasibleError(``guide_path:<reason>``) when none is found; ``stats`` (a dict) is filled."""
    goal = goal_position if isinstance(goal_position, Goal) else Goal(_vec3(goal_position, "goal_position"), tolerance)
    return plan_guide_path_through(robot, env, q_start, [goal], params, seed, time_limit_s, stats).path


def plan_guide_path_through(robot: Any, env: Any, q_start: np.ndarray, goals: Sequence[Goal],
                            params: GuidePathParams | None = None, seed: int | None = None,
                            time_limit_s: float | None = None, stats: dict | None = None) -> GuideResult:
    """RRT-Connect to each goal in turn (the last reached state starts the next query)."""
    t0 = time.perf_counter()
    params = params or load_settings().guide_path
    seed = params.seed if seed is None else seed
    limit = params.time_limit_s if time_limit_s is None else float(time_limit_s)
    if not limit > 0.0:
        raise SpecError("guide_path.time_limit_s", f"must be > 0, got {time_limit_s!r}")
    for i, g in enumerate(goals):
        if not (isinstance(g.tolerance, (int, float)) and g.tolerance > 0.0):
            raise SpecError(f"guide_path.goals[{i}].tolerance", f"must be > 0, got {g.tolerance!r}")
    pl = _planner(robot, env, params)
    q_start = np.asarray(q_start, dtype=float)
    if q_start.shape != (robot.nq,):
        raise SpecError("guide_path.q_start", f"must have {robot.nq} values, got shape {q_start.shape}")
    rng = np.random.default_rng(seed)
    deadline = t0 + limit
    gs = GuideStats()
    try:
        start = state_of(pl, q_start)
        q0 = q_start.copy()
        if not pl.support(start, q0).ok:
            raise InfeasibleError("guide_path:start_unsupported", "the start configuration fails the equilibrium criterion")
        d, pair = pl.clearance(q0)
        if d < params.body_clearance:
            raise InfeasibleError("guide_path:start_in_collision", f"{pair[0]} - {pair[1]}: {d:.3f} m")
        path = [start]
        for goal in goals:
            seg = _Search(pl, path[-1], goal, rng, deadline, gs).run()
            path += _shortcut(pl, seg, rng, gs, deadline)[1:]
        states = _milestones(pl, path)
    finally:
        gs.time_s = time.perf_counter() - t0
        if stats is not None:
            stats.update(gs.as_dict())
    milestones = [q0] + [pl.configuration(x) for x in states[1:]]
    return GuideResult(GuidePath(robot=robot.config.name, environment=env.name, joint_names=list(robot.joint_names),
                                 milestones=milestones), states, gs)


_PLANNERS: dict[tuple[int, int, GuidePathParams], GuidePlanner] = {}


def _planner(robot: Any, env: Any, params: GuidePathParams) -> GuidePlanner:
    key = (id(robot), id(env), params)
    hit = _PLANNERS.get(key)
    if hit is None or hit.robot is not robot or hit.env is not env:
        if len(_PLANNERS) > 16:
            _PLANNERS.clear()
        hit = _PLANNERS[key] = GuidePlanner(robot, env, params)
    return hit


def _vec3(v: Any, where: str) -> np.ndarray:
    a = np.asarray(v, dtype=float).reshape(-1)
    if a.shape != (3,) or not np.isfinite(a).all():
        raise SpecError(f"guide_path.{where}", f"must be three finite numbers [m], got {v!r}")
    return a


# --------------------------------------------------------------------------------------------
# ladders and scenes


def ladder_base_offset(robot: Any, env: Any) -> tuple[np.ndarray, str]:
    """(base position - feet rung centre [m], feet rung) of the ``ladder_4_contacts`` fixture."""
    from climb_core import fixtures

    stance, q = fixtures.get(LADDER_FIXTURE, robot, env)
    rung = stance.hold("left_foot").env_surface
    return q[:3] - env.surfaces[rung].position, rung


def ladder_goal_position(robot: Any, env: Any, k: int) -> np.ndarray:
    """Base position of standing on rung k [m]: rung k's centre plus the offset of the fixture's base
    from its feet rung (base above the rung by the climbing stance's height, behind it toward the
    robot)."""
    offset, _ = ladder_base_offset(robot, env)
    return env.rung(k).position + offset


def tread_goal_position(robot: Any, env: Any, k: int) -> np.ndarray:
    """Base position of standing upright on tread k [m]: the ``standing`` fixture's base over its
    feet, moved onto the top of the tread's centre."""
    from climb_core import fixtures

    stance, q = fixtures.get("standing", robot, env)
    feet = np.mean([h.centre for h in stance.holds], axis=0)
    tread = env.rung(k)
    return np.array([tread.position[0], tread.position[1], tread.top_z]) + (q[:3] - feet)


def ladder_goals(robot: Any, env: Any, rungs: int, tolerance: float,
                 params: GuidePathParams | None = None) -> list[Goal]:
    """Goals for rungs 1..``rungs`` (one rung apart), facing the ladder: standing on each rung in the
    climbing stance, or, on a ladder no steeper than ``walk_max_incline_deg`` (stairs), standing
    upright on each tread."""
    params = params or load_settings().guide_path
    yaw = float(math.atan2(env.T_world_ladder[1, 0], env.T_world_ladder[0, 0]))
    if float(env.ladder.inclination_deg) <= params.walk_max_incline_deg:
        return [Goal(tread_goal_position(robot, env, k), tolerance, yaw, "standing") for k in range(1, rungs + 1)]
    return [Goal(ladder_goal_position(robot, env, k), tolerance, yaw, "climbing") for k in range(1, rungs + 1)]


def plan_for_environment(robot: Any, env: Any, q_start: np.ndarray, rungs: int | None = None,
                         params: GuidePathParams | None = None, seed: int | None = None,
                         time_limit_s: float | None = None, tolerance: float = 0.1) -> GuideResult:
    """The guide path of a request: the scene's ``env.goal`` when it has one, else ``rungs`` rungs
    of its ladder (one goal per rung)."""
    goal = getattr(env, "goal", None)
    if goal is not None:
        position = getattr(goal, "base_position", None)
        if position is None and isinstance(goal, dict):
            position = goal.get("base_position")
        tol = getattr(goal, "tolerance", None) or (goal.get("tolerance") if isinstance(goal, dict) else None)
        goals = [Goal(_vec3(position, "goal.base_position"), float(tol), posture="standing")]
    elif rungs is not None:
        goals = ladder_goals(robot, env, int(rungs), tolerance, params)
    else:
        raise SpecError("guide_path.goal", "the environment has no goal and no rung count was given")
    return plan_guide_path_through(robot, env, q_start, goals, params, seed, time_limit_s)


def start_configuration(robot: Any, env: Any) -> np.ndarray:
    """The robot's reference configuration standing at the scene's ``start_pose`` (x, y, yaw)."""
    return env.place_at_start(robot.q_reference())


def benchmark(scenario: str = "default", rungs: int = 3, robot_name: str = "g1", seed: int = 0,
              repeats: int = 3) -> dict:
    """Wall time of the guide path (the best of ``repeats``, planner built beforehand) and its
    figures, for scripts/bench_planner.py: start = the ``standing`` fixture on a ladder, the
    scene's start pose (:func:`start_configuration`) when the scene has a goal."""
    from climb_core import fixtures
    from climb_core.environment import build_environment
    from climb_core.robot import load_robot

    robot = load_robot(robot_name)
    env = build_environment(scenario)
    q0 = start_configuration(robot, env) if getattr(env, "goal", None) is not None else \
        fixtures.get("standing", robot, env)[1]
    _planner(robot, env, load_settings().guide_path)
    times, result = [], None
    for _ in range(repeats):
        t = time.perf_counter()
        result = plan_for_environment(robot, env, q0, rungs=rungs, seed=seed)
        times.append(time.perf_counter() - t)
    return {"time_s": min(times), "times_s": times, "milestones": len(result.path.milestones),
            **{k: v for k, v in result.stats.as_dict().items() if k != "time_s"}}


def bench_figures(seed: int = 0) -> dict:
    """The issue's benchmark figures: ``guide_path_default_s`` (default ladder, 3 rungs) and
    ``guide_path_narrow_passage_s`` [s], each the best of 3 runs."""
    return {"guide_path_default_s": round(benchmark("default", 3, seed=seed)["time_s"], 4),
            "guide_path_narrow_passage_s": round(benchmark("narrow_passage", seed=seed)["time_s"], 4)}
