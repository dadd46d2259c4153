"""Contacts and constraints of the whole-body QP (multicontact_darpa_tasks.txt, eq. 2-8).

- :class:`ActiveContact`: one held contact (a limb on an environment surface) as the QP sees it:
  unilateral point contacts with linearised friction cones spanned by generators (eq. 5,
  ``f_i = G_i lambda_i, lambda_i >= 0``), or a bilateral grasp as a 6D wrench with box bounds
  (grip strength; no friction cone, as in the paper). Its wrench map ``Phi`` sends the force
  variables to the wrench at the contact reference point, in the world frame.
- :func:`friction_generators`: the cone edges.
- :func:`joint_acceleration_bounds`: joint position / velocity limits turned into bounds on qdd.
- :class:`CollisionAvoidance`: velocity dampers (eq. 6-8) between configured robot links and
  environment surfaces, and between pairs of robot links, with distances and witness points
  from coal on convex hulls. The sign is the corrected one (FIELD_NOTES):
  ``d_dot + t_bar d_ddot >= -xi (d - d_s) / (d_i - d_s)``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import pinocchio as pin

from climb_core.contact import Hold


def skew(v: np.ndarray) -> np.ndarray:
    """Cross-product matrix: skew(a) @ b == a x b."""
    x, y, z = v.tolist()
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a x b for 3-vectors (np.cross costs ~30 us per call on small arrays)."""
    ax, ay, az = a.tolist()
    bx, by, bz = b.tolist()
    return np.array([ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx])


def skew_stack(vectors: np.ndarray) -> np.ndarray:
    """(k, 3, 3) cross-product matrices of (k, 3) vectors."""
    out = np.zeros((len(vectors), 3, 3))
    out[:, 0, 1] = -vectors[:, 2]
    out[:, 0, 2] = vectors[:, 1]
    out[:, 1, 0] = vectors[:, 2]
    out[:, 1, 2] = -vectors[:, 0]
    out[:, 2, 0] = -vectors[:, 1]
    out[:, 2, 1] = vectors[:, 0]
    return out


def tangent_basis(normal: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    n = normal / np.linalg.norm(normal)
    helper = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    t1 = np.cross(n, helper)
    t1 /= np.linalg.norm(t1)
    return t1, np.cross(n, t1)


def friction_generators(normal: np.ndarray, mu: float, count: int = 4) -> np.ndarray:
    """(3, count) unit edges of the pyramid inscribed in the cone |f_t| <= mu f_n around ``normal``.

    Every non-negative combination satisfies the Coulomb law (inner approximation).
    """
    n = normal / np.linalg.norm(normal)
    t1, t2 = tangent_basis(n)
    angles = 2.0 * np.pi * np.arange(count) / count
    edges = n[:, None] + mu * (np.cos(angles)[None, :] * t1[:, None] + np.sin(angles)[None, :] * t2[:, None])
    return edges / np.linalg.norm(edges, axis=0)


@dataclass
class ActiveContact:
    """A contact the controller holds; variables and rows it adds to the QP.

    ``points_in_frame`` are the contact points in the limb frame (fixed once the contact is made);
    ``normals_in_world`` the environment surface normals (toward the robot, fixed in the world).
    The contact reference point (where the wrench is expressed) is ``reference_in_frame``.
    """

    limb: str
    env_surface: str
    frame_id: int
    bilateral: bool
    friction: float  # [-]
    points_in_frame: np.ndarray  # (k, 3) [m]
    normals_in_world: np.ndarray  # (k, 3)
    reference_in_frame: np.ndarray  # (3,) [m]
    force_limit: float  # [N] unilateral: total normal force cap; bilateral: grip force (norm)
    torque_limit: float = 0.0  # [N m] bilateral: per-axis moment cap
    #: force scale in [0, 1] set by the controller's ramps (0: unloaded / released)
    scale: float = 1.0
    #: cap on the normal force (unilateral) or per-component |wrench| (bilateral) during a
    #: release ramp; None outside ramps.
    ramp_cap: np.ndarray | float | None = None
    min_normal_force: float = 0.0  # [N] per point, scaled by ``scale``
    generators: np.ndarray = field(init=False)  # (3, n_gen) per point, stacked as (k, 3, g)

    def __post_init__(self) -> None:
        self.points_in_frame = np.asarray(self.points_in_frame, dtype=float).reshape(-1, 3)
        self.normals_in_world = np.asarray(self.normals_in_world, dtype=float).reshape(-1, 3)
        self.reference_in_frame = np.asarray(self.reference_in_frame, dtype=float).reshape(3)
        self.generators = np.zeros((0, 3, 0))

    def setup_generators(self, friction_margin: float, count: int) -> None:
        if self.bilateral:
            return
        mu = self.friction * friction_margin
        self.generators = np.stack([friction_generators(n, mu, count) for n in self.normals_in_world])
        k, _, g = self.generators.shape
        self._force_block = self.generators.transpose(1, 0, 2).reshape(3, k * g)
        self._normal_rows = np.zeros((k, k * g))
        for i in range(k):
            self._normal_rows[i, i * g:(i + 1) * g] = self.normals_in_world[i] @ self.generators[i]

    @property
    def n_variables(self) -> int:
        if self.bilateral:
            return 6
        return self.generators.shape[0] * self.generators.shape[2]

    def wrench_map(self, R_world_frame: np.ndarray) -> np.ndarray:
        """Phi (6, n_var): wrench [N, N m] at the reference point, world axes, from the variables."""
        if self.bilateral:
            return np.eye(6)
        k, _, g = self.generators.shape
        offsets = (self.points_in_frame - self.reference_in_frame) @ R_world_frame.T  # (k, 3) world
        moments = skew_stack(offsets) @ self.generators  # (k, 3, g)
        phi = np.empty((6, k * g))
        phi[:3] = self._force_block
        phi[3:] = moments.transpose(1, 0, 2).reshape(3, k * g)
        return phi

    def normal_rows(self) -> np.ndarray:
        """(k, n_var): normal force of each point from the generator variables [N]."""
        return self._normal_rows

    def grip_limits(self) -> tuple[float, float]:
        """(force [N], moment [N m]) limits of a grasp now (scale and release ramp applied)."""
        force = self.force_limit * self.scale
        torque = self.torque_limit * self.scale
        if self.ramp_cap is not None:
            cap = np.asarray(self.ramp_cap, dtype=float).reshape(-1)
            force = min(force, float(cap[0]))
            torque = min(torque, float(cap[-1]))
        return force, torque

    def variable_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Unilateral: generator weights >= 0. Grasp: box on the wrench (|f_i| <= F, |m_i| <= M);
        the grip force norm is bounded by :data:`GRIP_DIRECTIONS` rows in the QP."""
        n = self.n_variables
        if not self.bilateral:
            return np.zeros(n), np.full(n, np.inf)
        force, torque = self.grip_limits()
        upper = np.array([force] * 3 + [torque] * 3)
        return -upper, upper

    def normal_force_window(self) -> tuple[float, float]:
        """Bounds [N] on the total normal force (unilateral)."""
        upper = self.force_limit * self.scale
        if self.ramp_cap is not None:
            upper = min(upper, float(self.ramp_cap))
        return 0.0, upper


def _grip_directions() -> np.ndarray:
    """13 unit directions (axes, face diagonals, 4 body diagonals): |d . f| <= F for each bounds
    the grasp force norm by F along them (at most 13 % above F in between), as in
    climb_core.feasibility."""
    dirs = [np.eye(3)[i] for i in range(3)]
    for i, j in ((0, 1), (0, 2), (1, 2)):
        for sign in (1.0, -1.0):
            d = np.zeros(3)
            d[i], d[j] = 1.0, sign
            dirs.append(d / np.sqrt(2.0))
    for sy in (1.0, -1.0):
        for sz in (1.0, -1.0):
            dirs.append(np.array([1.0, sy, sz]) / np.sqrt(3.0))
    return np.array(dirs)


GRIP_DIRECTIONS = _grip_directions()  # (13, 3)


def contact_from_hold(hold: Hold, frame_id: int, T_world_frame: pin.SE3, T_frame_surface: np.ndarray,
                      force_limit: float, torque_limit: float = 0.0, min_normal_force: float = 0.0,
                      friction_margin: float = 0.8, generators_per_point: int = 4) -> ActiveContact:
    """Freeze a hold into an :class:`ActiveContact` at the current limb pose.

    Unilateral: the hold's world points are expressed in the limb frame now and stay attached to
    it; the reference point is their centroid. Bilateral: the reference is the grasp centre
    (robot surface frame origin).
    """
    R = T_world_frame.rotation
    p = T_world_frame.translation
    if hold.bilateral:
        points = np.zeros((0, 3))
        normals = np.zeros((0, 3))
        reference = np.asarray(T_frame_surface, dtype=float)[:3, 3]
        limit = hold.grip_force_limit if hold.grip_force_limit > 0 else force_limit
    else:
        points = (hold.positions - p) @ R  # world -> frame
        normals = hold.normals
        reference = points.mean(axis=0)
        limit = force_limit
    contact = ActiveContact(hold.limb, hold.env_surface, frame_id, hold.bilateral, hold.friction,
                            points, normals, reference, limit, torque_limit,
                            min_normal_force=min_normal_force)
    contact.setup_generators(friction_margin, generators_per_point)
    return contact


def joint_acceleration_bounds(q_joints: np.ndarray, v_joints: np.ndarray, lower: np.ndarray, upper: np.ndarray,
                              velocity_limit: np.ndarray, horizon: float, accel_bound: float,
                              margin: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Bounds on joint qdd [rad/s^2] keeping q inside [lower+margin, upper-margin] over ``horizon``
    (q + v T + qdd T^2 / 2) and |v + qdd T| <= velocity_limit. The interval always contains the
    stopping acceleration -v / T (so lo <= hi, and a joint already past a limit is asked to stop,
    not to jump back)."""
    T = horizon
    lo_pos = 2.0 * (lower + margin - q_joints - v_joints * T) / T ** 2
    hi_pos = 2.0 * (upper - margin - q_joints - v_joints * T) / T ** 2
    lo_vel = (-velocity_limit - v_joints) / T
    hi_vel = (velocity_limit - v_joints) / T
    lo = np.maximum(np.maximum(lo_pos, lo_vel), -accel_bound)
    hi = np.minimum(np.minimum(hi_pos, hi_vel), accel_bound)
    # stopping within the horizon is always allowed: near (or past) a limit the bounds never
    # demand more than that, so they cannot make the QP infeasible against held contacts
    a_stop = np.clip(-v_joints / T, -accel_bound, accel_bound)
    lo = np.minimum(lo, a_stop)
    hi = np.maximum(hi, a_stop)
    return lo, hi


# --------------------------------------------------------------------------------------------
_SUPPORT_MASKS: dict[tuple[int, int], np.ndarray] = {}


def _support_mask(model: pin.Model, joint_id: int) -> np.ndarray:
    """(nv,) 1.0 on the velocity columns of the joints supporting ``joint_id``, else 0."""
    key = (id(model), joint_id)
    mask = _SUPPORT_MASKS.get(key)
    if mask is None:
        mask = np.zeros(model.nv)
        for j in model.supports[joint_id]:
            if j > 0:
                joint = model.joints[j]
                mask[joint.idx_v:joint.idx_v + joint.nv] = 1.0
        _SUPPORT_MASKS[key] = mask
    return mask


def point_jacobian_and_drift(model: pin.Model, data: pin.Data, joint_id: int,
                             point_world: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Linear Jacobian (3, nv) of the point fixed in ``joint_id``'s body that coincides with
    ``point_world`` now, and its drift acceleration Jdot v [m/s^2] (needs computeJointJacobians
    and forwardKinematics(q, v, 0) in ``data``)."""
    Jw = data.J  # (6, nv) spatial Jacobians in the world frame (each column: its joint's motion)
    J = (Jw[:3] - skew(point_world) @ Jw[3:]) * _support_mask(model, joint_id)
    oMi = data.oMi[joint_id]
    r = point_world - oMi.translation
    R = oMi.rotation
    v_local = data.v[joint_id]
    a_local = data.a[joint_id]
    omega = R @ v_local.angular
    v_origin = R @ v_local.linear
    alpha = R @ a_local.angular
    a_origin = R @ a_local.linear + cross(omega, v_origin)  # classical acceleration of the origin
    drift = a_origin + cross(alpha, r) + cross(omega, cross(omega, r))
    return J, drift


@dataclass
class DamperRow:
    """One velocity-damper row, for diagnostics and the QP: row @ qdd >= lower."""

    name: str  # "link|surface" or "link_a|link_b"
    distance: float  # [m]
    distance_rate: float  # [m/s]
    row: np.ndarray  # (nv,) n' J: d_ddot = row @ qdd + drift
    lower: float  # [m/s^2] bound on row @ qdd
    drift: float = 0.0  # [m/s^2] n' Jdot v
    bound: float = 0.0  # [m/s] -xi (d - ds) / (di - ds), the next-step floor of d_dot


class CollisionAvoidance:
    """Velocity dampers for configured pairs, distances from coal on convex hulls.

    ``robot_geometries``: name -> list of (geometry, joint_id, placement_in_joint) for each robot
    link used (one convex hull per mesh). ``environment``: list of (surface_name, geometry,
    coal.Transform3s) from ``Environment.collision_objects()``. A sphere-vs-capsule prefilter
    skips the coal call for pairs far beyond the influence distance.
    """

    def __init__(self, robot_geometries: dict[str, list[tuple[object, int, pin.SE3]]],
                 env_links: tuple[str, ...], environment: list[tuple[str, object, object]],
                 self_pairs: tuple[tuple[str, str], ...], influence_distance: float,
                 security_distance: float, damping: float, broadphase_margin: float,
                 max_braking: float = np.inf):
        import coal

        self._coal = coal
        self.di = influence_distance  # [m]
        self.ds = security_distance  # [m]
        self.xi = damping  # [m/s]
        self.margin = broadphase_margin  # [m]
        self.max_braking = max_braking  # [m/s^2] cap on the deceleration a damper may demand
        self.missing_links = sorted(set(env_links) - set(robot_geometries))
        self.self_pairs = tuple((a, b) for a, b in self_pairs if a in robot_geometries and b in robot_geometries)
        self._env = [(name, geom, tf) for name, geom, tf in environment]
        self._env_capsules = np.array([self._capsule(geom, tf) for _, geom, tf in self._env]).reshape(-1, 7)
        # every robot geometry used: (link, geometry, joint id, placement in joint, bounding-sphere
        # centre in the joint frame, radius)
        used = [name for name in env_links if name in robot_geometries]
        for a, b in self.self_pairs:
            used += [a, b]
        self._items = []
        self._item_index: dict[str, list[int]] = {}
        for link in dict.fromkeys(used):
            for geom, joint_id, placement in robot_geometries[link]:
                centre, radius = self._sphere(geom)
                self._item_index.setdefault(link, []).append(len(self._items))
                self._items.append((link, geom, int(joint_id), placement, placement.act(centre), radius))
        self._env_items = [i for link in dict.fromkeys(n for n in env_links if n in robot_geometries)
                           for i in self._item_index[link]]
        self._radii = np.array([item[5] for item in self._items])
        # radius of each geometry's bounding sphere around its joint origin (rotation bound)
        self._reach = np.array([item[5] for item in self._items])
        self._cache: dict = {}
        self._request = coal.DistanceRequest()
        self._request.enable_signed_distance = True
        self._result = coal.DistanceResult()

    # -- geometry helpers ---------------------------------------------------------------
    def _sphere(self, geom) -> tuple[np.ndarray, float]:
        """Bounding sphere (centre in the geometry frame [m], radius [m]) of a robot geometry."""
        coal = self._coal
        if isinstance(geom, coal.Box):
            return np.zeros(3), float(np.linalg.norm(geom.halfSide))
        if isinstance(geom, coal.Sphere):
            return np.zeros(3), float(geom.radius)
        if isinstance(geom, (coal.Cylinder, coal.Capsule)):
            return np.zeros(3), float(np.hypot(geom.radius, geom.halfLength) + (geom.radius if isinstance(geom, coal.Capsule) else 0.0))
        points = getattr(geom, "points", None)
        vertices = np.asarray(points() if callable(points) else points, dtype=float).reshape(-1, 3) \
            if points is not None else np.zeros((0, 3))
        if len(vertices) == 0:
            geom.computeLocalAABB()
            return np.asarray(geom.aabb_center, dtype=float), float(geom.aabb_radius)
        centre = 0.5 * (vertices.min(axis=0) + vertices.max(axis=0))
        return centre, float(np.max(np.linalg.norm(vertices - centre, axis=1)))

    def _capsule(self, geom, tf) -> np.ndarray:
        """(a(3), b(3), radius) bounding capsule of an environment geometry in the world."""
        R = np.asarray(tf.getRotation())
        p = np.asarray(tf.getTranslation())
        coal = self._coal
        if isinstance(geom, coal.Cylinder) or isinstance(geom, coal.Capsule):
            half = float(geom.halfLength)
            axis = R[:, 2]
            return np.concatenate([p - half * axis, p + half * axis, [float(geom.radius)]])
        if isinstance(geom, coal.Box):
            half = np.asarray(geom.halfSide, dtype=float)
            k = int(np.argmax(half))
            axis = R[:, k] * half[k]
            others = np.delete(half, k)
            return np.concatenate([p - axis, p + axis, [float(np.linalg.norm(others))]])
        if isinstance(geom, coal.Sphere):
            return np.concatenate([p, p, [float(geom.radius)]])
        geom.computeLocalAABB()
        centre = R @ np.asarray(geom.aabb_center) + p
        return np.concatenate([centre, centre, [float(geom.aabb_radius)]])

    # -- per tick -------------------------------------------------------------------------
    def _transform(self, data: pin.Data, joint_id: int, placement: pin.SE3):
        M = data.oMi[joint_id] * placement
        return self._coal.Transform3s(M.rotation, M.translation), M

    def _distance(self, g1, t1, g2, t2) -> tuple[float, np.ndarray, np.ndarray, np.ndarray]:
        result = self._result
        result.clear()
        d = self._coal.distance(g1, t1, g2, t2, self._request, result)
        p1 = np.asarray(result.getNearestPoint1()).copy()
        p2 = np.asarray(result.getNearestPoint2()).copy()
        diff = p1 - p2
        norm = np.linalg.norm(diff)
        if d > 1e-6 and norm > 1e-9:
            n = diff / norm
        else:
            n = -np.asarray(result.normal, dtype=float)  # coal normal points from o1 to o2
        return float(d), p1, p2, n

    def rows(self, model: pin.Model, data: pin.Data, v: np.ndarray, dt: float,
             disabled: set[tuple[str, str]] | frozenset = frozenset()) -> list[DamperRow]:
        """Damper rows for every pair closer than the influence distance.

        ``disabled``: (link, surface) pairs switched off (limb making or holding contact with
        that surface). Needs pin data with joint Jacobians and forwardKinematics(q, v, 0).
        """
        rows: list[DamperRow] = []
        if not self._items:
            return rows
        cutoff = self.di + self.margin
        oMi = data.oMi
        centres = np.array([oMi[item[2]].act(item[4]) for item in self._items])
        env_idx = self._env_items
        caps = self._env_capsules
        if len(caps) and env_idx:
            c = centres[env_idx][:, None, :]  # (L, 1, 3)
            a, ab, r = caps[None, :, :3], (caps[:, 3:6] - caps[:, :3])[None], caps[None, :, 6]
            denom = np.maximum((ab * ab).sum(-1), 1e-12)
            t = np.clip(((c - a) * ab).sum(-1) / denom, 0.0, 1.0)
            gap = np.sqrt((((a + t[..., None] * ab) - c) ** 2).sum(-1)) - r - self._radii[env_idx][:, None]
            for li, k in zip(*np.nonzero(gap < cutoff)):
                item = env_idx[li]
                link, geom, joint_id, placement, _, radius = self._items[item]
                surface, env_geom, env_tf = self._env[k]
                if (link, surface) in disabled:
                    continue
                key = (item, int(k))
                if self._still_far(key, ((item, centres[item], oMi[joint_id].rotation),)):
                    continue
                M = oMi[joint_id] * placement
                d, p_body, _p_obstacle, n = self._distance(
                    geom, self._coal.Transform3s(M.rotation, M.translation), env_geom, env_tf)
                self._remember(key, d, ((item, centres[item], oMi[joint_id].rotation),))
                if d >= self.di:
                    continue
                J, drift = point_jacobian_and_drift(model, data, joint_id, p_body)
                rows.append(self._row(f"{link}|{surface}", d, n, J, drift, v, dt))
        for link_a, link_b in self.self_pairs:
            if (link_a, link_b) in disabled:
                continue
            for ia in self._item_index[link_a]:
                for ib in self._item_index[link_b]:
                    gap = np.linalg.norm(centres[ia] - centres[ib]) - self._radii[ia] - self._radii[ib]
                    if gap >= cutoff:
                        continue
                    _, ga, ja, pa, _, _ = self._items[ia]
                    _, gb, jb, pb, _, _ = self._items[ib]
                    poses = ((ia, centres[ia], oMi[ja].rotation), (ib, centres[ib], oMi[jb].rotation))
                    key = (ia, -1 - ib)
                    if self._still_far(key, poses):
                        continue
                    Ma, Mb = oMi[ja] * pa, oMi[jb] * pb
                    d, p_a, p_b, n = self._distance(ga, self._coal.Transform3s(Ma.rotation, Ma.translation),
                                                    gb, self._coal.Transform3s(Mb.rotation, Mb.translation))
                    self._remember(key, d, poses)
                    if d >= self.di:
                        continue
                    Ja, da = point_jacobian_and_drift(model, data, ja, p_a)
                    Jb, db = point_jacobian_and_drift(model, data, jb, p_b)
                    rows.append(self._row(f"{link_a}|{link_b}", d, n, Ja - Jb, da - db, v, dt))
        return rows

    # -- temporal coherence: a pair measured far enough stays unmeasured until it may have moved
    #    close (its last distance minus a bound on how far its bodies moved since)
    def _remember(self, key, d: float, poses) -> None:
        self._cache[key] = (d, tuple((i, c.copy(), R.copy()) for i, c, R in poses))

    def _still_far(self, key, poses) -> bool:
        cached = self._cache.get(key)
        if cached is None:
            return False
        d, old = cached
        moved = 0.0
        for (i, c, R), (_, c0, R0) in zip(poses, old):
            # every point of a body within `radius` of its sphere centre moved by at most
            # |dc| + ||dR||_F * radius
            dc = c - c0
            dR = (R - R0).ravel()
            moved += math.sqrt(dc @ dc) + math.sqrt(dR @ dR) * self._reach[i]
        return d - moved >= self.di

    def _row(self, name: str, d: float, n: np.ndarray, J: np.ndarray, drift: np.ndarray, v: np.ndarray,
             dt: float) -> DamperRow:
        # eq. 6-8 with the sign restored: d_dot + dt d_ddot >= -xi (d - ds) / (di - ds)
        nJ = n @ J
        d_dot = float(nJ @ v)
        rhs = -self.xi * (d - self.ds) / (self.di - self.ds)
        n_drift = float(n @ drift)
        # d_ddot >= (rhs - d_dot) / dt, capped: a pair entering the zone too fast is braked as hard
        # as max_braking allows instead of making the QP infeasible
        lower = min((rhs - d_dot) / dt, self.max_braking) - n_drift
        return DamperRow(name, d, d_dot, nJ, lower, n_drift, rhs)
