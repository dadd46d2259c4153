"""Signed distances robot <-> environment and robot <-> itself, on convex hulls.

:class:`CollisionChecker` is built once per (robot, environment) (:func:`checker` caches it). It
holds one ``pin.GeometryModel``: the robot's collision geometries (qhull convex hulls of the link
meshes, primitives as they are) plus the environment's surfaces attached to the universe joint,
and one collision pair per (robot geometry, environment surface) and per robot self pair kept by
the filter:

- self pairs on the same joint or on a parent/child joint pair are skipped (they touch by
  construction);
- link pairs listed in the robot config's ``collision.ignore_pairs`` are skipped;
- pairs closer than ``reference_contact_distance`` at the robot's reference posture are skipped
  (links that touch at rest, e.g. G1 pelvis_contour vs hip_pitch).

Queries run ``pin.computeDistances`` (coal GJK/EPA on the hulls; negative = penetration depth)
over the active pairs. The pairs between a limb in contact and the surface it holds are
switched off for that query (a hand wraps its rung, a sole rests on its tread): the limb is its
last ``contact_exclusion_joints`` joints (e.g. wrist pitch + yaw with the hand, ankle pitch +
roll with the foot).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Iterable, Sequence

import numpy as np
import pinocchio as pin

from .errors import SpecError
from .params import param

ENV_PREFIX = "env:"


@dataclass(frozen=True)
class CollisionParams:
    reference_contact_distance: float = param(0.002, unit="m", min=0.0, description=(
        "self pairs closer than this at the reference posture are filtered out"))
    contact_exclusion_joints: int = param(2, unit="-", min=1, description=(
        "distal joints of a limb whose geometries may touch the surface that limb holds"))
    self_collision: bool = param(True, unit="-", description="check robot self pairs")
    cull_distance: float = param(0.0, unit="m", min=0.0, description=(
        "pairs whose bounding spheres are farther apart than this (and than the closest exact "
        "distance) are not passed to coal"))


@dataclass
class DistanceReport:
    """Result of one distance query (world frame, metres)."""

    min_distance: float  # [m] smallest signed distance over the active pairs (inf if none)
    pair: tuple[str, str]  # (robot geometry, other geometry) of the closest pair; "env:<surface>" for surfaces
    witness_points: tuple[np.ndarray, np.ndarray]  # nearest points on each geometry [m], world frame
    below: list[tuple[str, str, float]]  # pairs closer than the query's threshold, with distance [m]


def _hull(geometry: Any) -> Any:
    """The convex hull of a coal BVH mesh (built once), or the geometry itself."""
    import coal

    if isinstance(geometry, coal.BVHModelBase):
        if geometry.convex is None:
            geometry.buildConvexHull(True, "Qt")
        return geometry.convex
    return geometry


def _link_of(model: pin.Model, go: Any) -> str:
    return model.frames[go.parentFrame].name


class CollisionChecker:
    """Distances between the robot's hulls and the environment / itself (see module docstring)."""

    def __init__(self, robot: Any, env: Any | None, params: CollisionParams | None = None,
                 hulls: bool = True):
        self.robot = robot
        self.env = env
        self.params = params or CollisionParams()
        model: pin.Model = robot.model
        self.model = model
        self.data = model.createData()
        gm = pin.GeometryModel()
        self.robot_geoms: list[str] = []
        self.geom_link: list[str] = []
        for go in robot.collision_model.geometryObjects:
            geom = _hull(go.geometry) if hulls else go.geometry
            obj = pin.GeometryObject(go.name, go.parentJoint, go.parentFrame, go.placement, geom)
            gm.addGeometryObject(obj)
            self.robot_geoms.append(go.name)
            self.geom_link.append(_link_of(model, go))
        self.n_robot = len(self.robot_geoms)
        self.env_names: list[str] = []
        if env is not None:
            for name, geometry, transform in env.collision_objects():
                placement = pin.SE3(np.asarray(transform.getRotation()), np.asarray(transform.getTranslation()))
                gm.addGeometryObject(pin.GeometryObject(ENV_PREFIX + name, 0, 0, placement, geometry))
                self.env_names.append(name)
        self.geometry_model = gm
        self._ignore = self._ignore_links(robot)
        self._build_pairs(robot)
        self.geometry_data = pin.GeometryData(gm)
        for req in self.geometry_data.distanceRequests:
            req.enable_signed_distance = True
        self._limb_geoms = self._limb_geometry_indices(robot)
        self._excluded_cache: dict[tuple, tuple[int, ...]] = {}
        self._bounding_spheres()

    # ---------------------------------------------------------------- construction helpers
    @staticmethod
    def _ignore_links(robot: Any) -> set[frozenset[str]]:
        cfg = getattr(robot.config, "collision", None)
        pairs = getattr(cfg, "ignore_pairs", ()) if cfg is not None else ()
        out = set()
        for pair in pairs:
            a, b = tuple(pair)
            out.add(frozenset((a, b)))
        return out

    def _env_links(self, robot: Any) -> set[str] | None:
        cfg = getattr(robot.config, "collision", None)
        for attr in ("env_links", "environment_links", "links"):
            links = getattr(cfg, attr, None) if cfg is not None else None
            if links:
                return set(links)
        return None

    def _build_pairs(self, robot: Any) -> None:
        model = self.model
        gm = self.geometry_model
        objs = gm.geometryObjects
        self.pair_names: list[tuple[str, str]] = []
        self.pair_kind: list[str] = []  # "env" | "self"
        env_links = self._env_links(robot)
        for i in range(self.n_robot):
            if env_links is not None and self.geom_link[i] not in env_links:
                continue
            for j in range(len(self.env_names)):
                jj = self.n_robot + j
                gm.addCollisionPair(pin.CollisionPair(i, jj))
                self.pair_names.append((objs[i].name, ENV_PREFIX + self.env_names[j]))
                self.pair_kind.append("env")
        if not self.params.self_collision:
            return
        candidates = []
        for i in range(self.n_robot):
            for j in range(i + 1, self.n_robot):
                ji, jj = objs[i].parentJoint, objs[j].parentJoint
                if ji == jj or model.parents[ji] == jj or model.parents[jj] == ji:
                    continue
                if frozenset((self.geom_link[i], self.geom_link[j])) in self._ignore:
                    continue
                candidates.append((i, j))
        # filter pairs in contact at the reference posture
        probe = pin.GeometryModel()
        for go in objs[: self.n_robot]:
            probe.addGeometryObject(go)
        for i, j in candidates:
            probe.addCollisionPair(pin.CollisionPair(i, j))
        probe_data = pin.GeometryData(probe)
        pin.computeDistances(model, model.createData(), probe, probe_data, self.robot.q_reference())
        self.filtered_at_reference: list[tuple[str, str, float]] = []
        for k, (i, j) in enumerate(candidates):
            d = probe_data.distanceResults[k].min_distance
            if d < self.params.reference_contact_distance:
                self.filtered_at_reference.append((objs[i].name, objs[j].name, float(d)))
                continue
            gm.addCollisionPair(pin.CollisionPair(i, j))
            self.pair_names.append((objs[i].name, objs[j].name))
            self.pair_kind.append("self")

    def _limb_geometry_indices(self, robot: Any) -> dict[str, list[int]]:
        out: dict[str, list[int]] = {}
        n = self.params.contact_exclusion_joints
        for limb_name, limb in robot.config.limbs.items():
            joints = list(limb.joints)[-n:]
            ids = {self.model.getJointId(j) for j in joints}
            frame_joint = self.model.frames[robot.frame_id(limb.surface.frame)].parentJoint
            ids.add(frame_joint)
            out[limb_name] = [i for i in range(self.n_robot)
                              if self.geometry_model.geometryObjects[i].parentJoint in ids]
        return out

    # ---------------------------------------------------------------- queries
    @property
    def n_pairs(self) -> int:
        return len(self.geometry_model.collisionPairs)

    @property
    def pair_index(self) -> dict[tuple[str, str], int]:
        """(robot geometry, other geometry or "env:<surface>") -> pair index (do not modify)."""
        return self._pair_index

    def excluded_pairs(self, contacts: Iterable[tuple[str, str]]) -> list[int]:
        """Pair indices switched off for (limb, env surface) contacts."""
        key = tuple((limb, surface) for limb, surface in contacts)
        hit = self._excluded_cache.get(key)
        if hit is not None:
            return list(hit)
        index = self._pair_index
        out = []
        for limb, surface in key:
            if limb not in self._limb_geoms:
                raise SpecError("collision.limb", f"unknown limb {limb!r}")
            for gi in self._limb_geoms[limb]:
                k = index.get((self.robot_geoms[gi], ENV_PREFIX + surface))
                if k is not None:
                    out.append(k)
        if len(self._excluded_cache) < 4096:  # (limb, surface) combinations of one environment
            self._excluded_cache[key] = tuple(out)
        return out

    def distances(self, q: np.ndarray, contacts: Sequence[tuple[str, str]] = (), threshold: float = 0.0
                  ) -> DistanceReport:
        """Signed distances at ``q`` [m]; pairs of (limb, surface) in ``contacts`` are skipped.

        Exact minimum over the active pairs: a bounding-sphere lower bound culls the pairs
        farther than ``max(threshold, cull_distance)`` and than the smallest exact distance
        found; the rest go through coal. ``below`` lists the pairs with distance < threshold.
        """
        model, data, gm, gd = self.model, self.data, self.geometry_model, self.geometry_data
        pin.forwardKinematics(model, data, np.asarray(q, dtype=float))
        lower = self._lower_bounds()
        excluded = self.excluded_pairs(contacts)
        if excluded:
            lower[excluded] = np.inf
        if not np.isfinite(lower).any():
            return DistanceReport(float("inf"), ("", ""), (np.zeros(3), np.zeros(3)), [])
        pin.updateGeometryPlacements(model, data, gm, gd)
        computed = np.zeros(len(lower), dtype=bool)
        dist = np.full(len(lower), np.inf)
        todo = lower < max(threshold, self.params.cull_distance)
        if not todo.any():
            todo[int(np.argmin(lower))] = True
        while todo.any():
            idx = np.flatnonzero(todo)
            dist[idx] = self._compute(idx)
            computed |= todo
            todo = (lower < dist.min()) & ~computed
        k = int(np.argmin(dist))
        res = gd.distanceResults[k]
        below = [(self.pair_names[i][0], self.pair_names[i][1], float(dist[i]))
                 for i in np.flatnonzero(dist < threshold)]
        return DistanceReport(float(dist[k]), self.pair_names[k],
                              (np.array(res.getNearestPoint1()), np.array(res.getNearestPoint2())), below)

    def all_distances(self, q: np.ndarray) -> np.ndarray:
        """Signed distance of every pair [m] (no culling; for tests and baselines)."""
        gd = self.geometry_data
        gd.setActiveCollisionPairs(self.geometry_model, self._all_active)
        pin.computeDistances(self.model, self.data, self.geometry_model, gd, np.asarray(q, dtype=float))
        return np.array([r.min_distance for r in gd.distanceResults])

    def _compute(self, idx: np.ndarray) -> np.ndarray:
        """Distances of the pairs ``idx`` (placements already updated), one coal query each.

        Each pair keeps its own coal functor (its GJK support-function warm start), so a pair's
        result depends only on the configurations that pair was computed at before: the set of
        pairs computed per query is what the culling decides, nothing else."""
        gm, gd = self.geometry_model, self.geometry_data
        compute = pin.computeDistance
        return np.array([compute(gm, gd, k).min_distance for k in idx.tolist()])

    def _bounding_spheres(self) -> None:
        """Bounds for culling: a sphere per robot geometry (joint index, centre in the joint frame,
        radius) and an oriented box per environment geometry (world pose, half sizes)."""
        gm = self.geometry_model
        n = len(gm.geometryObjects)
        self._sphere_joint = np.zeros(self.n_robot, dtype=int)
        self._sphere_centre = np.zeros((self.n_robot, 3))
        self._sphere_radius = np.zeros(self.n_robot)
        for i in range(self.n_robot):
            go = gm.geometryObjects[i]
            go.geometry.computeLocalAABB()
            self._sphere_joint[i] = go.parentJoint
            self._sphere_centre[i] = go.placement.act(np.asarray(go.geometry.aabb_center))
            self._sphere_radius[i] = float(go.geometry.aabb_radius)
        env_R = np.zeros((len(self.env_names), 3, 3))
        env_p = np.zeros((len(self.env_names), 3))
        env_h = np.zeros((len(self.env_names), 3))
        for j, name in enumerate(self.env_names):
            go = gm.geometryObjects[self.n_robot + j]
            surface = self.env.surfaces.get(name) if hasattr(self.env, "surfaces") else None
            if surface is not None and hasattr(surface, "primitive_half_extents"):
                half = np.asarray(surface.primitive_half_extents(), dtype=float)
            else:  # a box around the geometry's local AABB
                go.geometry.computeLocalAABB()
                half = 0.5 * (np.asarray(go.geometry.aabb_local.max_) - np.asarray(go.geometry.aabb_local.min_))
            env_R[j] = go.placement.rotation
            env_p[j] = go.placement.translation
            env_h[j] = half
        pairs = gm.collisionPairs
        self._pair_a = np.array([p.first for p in pairs], dtype=int)
        self._pair_b = np.array([p.second for p in pairs], dtype=int)
        is_env = self._pair_b >= self.n_robot
        self._env_pairs = np.flatnonzero(is_env)
        self._self_pairs = np.flatnonzero(~is_env)
        env_idx = self._pair_b[is_env] - self.n_robot
        self._env_pair_R = env_R[env_idx]
        self._env_pair_p = env_p[env_idx]
        self._env_pair_h = env_h[env_idx]
        sa, sb = self._pair_a[~is_env], self._pair_b[~is_env]
        self._self_pair_radius = self._sphere_radius[sa] + self._sphere_radius[sb]
        self._pair_index = {pn: k for k, pn in enumerate(self.pair_names)}
        parent = [go.parentJoint for go in gm.geometryObjects]
        #: (n_pairs, 2) parent joint index of each pair's two geometries (0: the universe / environment)
        self.pair_joints: list[tuple[int, int]] = [(int(parent[a]), int(parent[b])) for a, b in
                                                   zip(self._pair_a.tolist(), self._pair_b.tolist())]
        self._all_active = np.zeros((n, n), dtype=bool)
        self._all_active[self._pair_a, self._pair_b] = True
        # the joints carrying spheres (their placements are all the bounds need)
        self._bound_joints = sorted(set(self._sphere_joint.tolist()))
        slot = {j: s for s, j in enumerate(self._bound_joints)}
        self._sphere_slot = np.array([slot[j] for j in self._sphere_joint.tolist()], dtype=int)
        self._self_a, self._self_b = sa, sb
        self._env_a = self._pair_a[is_env]
        self._env_radius = self._sphere_radius[self._env_a]

    def _lower_bounds(self) -> np.ndarray:
        """Lower bound of every pair's signed distance (FK already done): sphere-sphere for self
        pairs, sphere-oriented-box for environment pairs."""
        oMi = self.data.oMi
        T = np.array([oMi[j].homogeneous for j in self._bound_joints])
        S = self._sphere_slot
        centres = np.einsum("nij,nj->ni", T.take(S, axis=0)[:, :3, :3], self._sphere_centre) + T[S, :3, 3]
        lower = np.empty(len(self._pair_a))
        diff = centres.take(self._self_a, axis=0) - centres.take(self._self_b, axis=0)
        lower[self._self_pairs] = np.sqrt(np.einsum("ij,ij->i", diff, diff)) - self._self_pair_radius
        local = np.einsum("nji,nj->ni", self._env_pair_R, centres.take(self._env_a, axis=0) - self._env_pair_p)
        excess = np.abs(local) - self._env_pair_h
        pos = np.maximum(excess, 0.0)
        outside = np.sqrt(np.einsum("ij,ij->i", pos, pos))
        lower[self._env_pairs] = outside + np.minimum(excess.max(axis=1), 0.0) - self._env_radius
        return lower

    def _lower_bounds_reference(self) -> np.ndarray:
        """The per-pair formulation of :meth:`_lower_bounds` (tests: both must agree)."""
        T = np.array([M.homogeneous for M in self.data.oMi])
        J = self._sphere_joint
        centres = np.einsum("nij,nj->ni", T[J, :3, :3], self._sphere_centre) + T[J, :3, 3]
        lower = np.empty(len(self._pair_a))
        sp = self._self_pairs
        diff = centres[self._pair_a[sp]] - centres[self._pair_b[sp]]
        lower[sp] = np.sqrt(np.einsum("ij,ij->i", diff, diff)) - self._self_pair_radius
        ep = self._env_pairs
        ia = self._pair_a[ep]
        local = np.einsum("nji,nj->ni", self._env_pair_R, centres[ia] - self._env_pair_p)
        excess = np.abs(local) - self._env_pair_h
        outside = np.sqrt(np.einsum("ij,ij->i", np.maximum(excess, 0.0), np.maximum(excess, 0.0)))
        lower[ep] = outside + np.minimum(excess.max(axis=1), 0.0) - self._sphere_radius[ia]
        return lower

    def pair_query(self, pairs: Sequence[tuple[str, str]]) -> "PairQuery":
        """A query computing only the named pairs (robot geometry, "env:<surface>" or geometry)."""
        return PairQuery(self, pairs)


class PairQuery:
    """Distances of a fixed subset of the checker's pairs: its own small GeometryModel holding
    only the geometries involved (placements of the others are not updated)."""

    def __init__(self, checker: CollisionChecker, pairs: Sequence[tuple[str, str]]):
        index = checker._pair_index
        missing = [p for p in pairs if tuple(p) not in index]
        if missing:
            raise SpecError("collision.pairs", f"not collision pairs of this checker: {missing[:3]}")
        self.checker = checker
        self.pairs = [tuple(p) for p in pairs]
        src = checker.geometry_model
        gm = pin.GeometryModel()
        local: dict[int, int] = {}
        for name_pair in self.pairs:
            k = index[name_pair]
            for gi in (src.collisionPairs[k].first, src.collisionPairs[k].second):
                if gi not in local:
                    local[gi] = len(local)
                    gm.addGeometryObject(src.geometryObjects[gi])
        for name_pair in self.pairs:
            k = index[name_pair]
            gm.addCollisionPair(pin.CollisionPair(local[src.collisionPairs[k].first],
                                                  local[src.collisionPairs[k].second]))
        self.geometry_model = gm
        self.geometry_data = pin.GeometryData(gm)
        for req in self.geometry_data.distanceRequests:
            req.enable_signed_distance = True
        self.data = checker.model.createData()
        self._results = self.geometry_data.distanceResults  # the C++ vector, filled in place

    def compute(self, q: np.ndarray) -> np.ndarray:
        """Signed distances [m] of the pairs, in the order given."""
        pin.computeDistances(self.checker.model, self.data, self.geometry_model, self.geometry_data,
                             np.asarray(q, dtype=float))
        return np.fromiter((r.min_distance for r in self._results), dtype=float, count=len(self.pairs))


_CACHE: dict[tuple[int, int, CollisionParams, bool], tuple[Any, Any, CollisionChecker]] = {}


def checker(robot: Any, env: Any | None, params: CollisionParams | None = None, hulls: bool = True
            ) -> CollisionChecker:
    """The (cached) checker of this robot and environment."""
    params = params or CollisionParams()
    key = (id(robot), id(env), params, hulls)
    hit = _CACHE.get(key)
    if hit is not None and hit[0] is robot and hit[1] is env:
        return hit[2]
    c = CollisionChecker(robot, env, params, hulls=hulls)
    _CACHE[key] = (robot, env, c)
    return c

