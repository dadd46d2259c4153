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
from climb_core.feasibility import GRIP_DIRECTIONS, tangent_basis  # noqa: F401  (re-exported: the QP's grip rows)


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


def friction_generators(normal: np.ndarray, mu: float, count: int = 4) -> np.ndarray:
    """(3, count) unit edges of the pyramid inscribed in the cone |f_t| <= mu f_n around ``normal``.

    Every non-negative combination satisfies the Coulomb law (inner approximation). The edges
    start 45 deg off ``t1`` and repeat every 360/count deg. With 4 edges the faces are normal to
    ``t1``, ``t2`` (|f.t1|, |f.t2| <= mu cos 45 deg f_n): the planner's pyramid
    (climb_core.feasibility), so a planned stance is inside the controller's cones. With a
    multiple of 4 (8, say) the edges include those and the ones on the tangents: the cone
    contains the planner's pyramid and forces along a single tangent up to mu f_n.
    """
    n = normal / np.linalg.norm(normal)
    t1, t2 = tangent_basis(n)
    angles = 0.25 * np.pi + 2.0 * np.pi * np.arange(count) / count
    edges = n[:, None] + mu * (np.cos(angles)[None, :] * t1[:, None] + np.sin(angles)[None, :] * t2[:, None])
    return edges / np.linalg.norm(edges, axis=0)


_EYE6 = np.eye(6)
_EYE6.flags.writeable = False  # the (shared) wrench map of a grasp


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
        self._offsets_in_frame = self.points_in_frame - self.reference_in_frame
        self._force_block = self.generators.transpose(1, 0, 2).reshape(3, k * g)
        # the moment rows of Phi are linear in the (world) offsets: flat (3 k g,) = map @ offsets.ravel()
        basis = np.eye(3 * k).reshape(3 * k, k, 3)
        self._moment_map = np.einsum("ijk,bpj,pkg->ipgb", _LEVI_CIVITA, basis, self.generators).reshape(3 * k * g, 3 * k)
        self._phi = np.empty((6, k * g))
        self._phi[:3] = self._force_block
        self._normal_rows = np.zeros((k, k * g))
        for i in range(k):
            self._normal_rows[i, i * g:(i + 1) * g] = self.normals_in_world[i] @ self.generators[i]
        self._total_normal_row = self._normal_rows.sum(axis=0)

    @property
    def n_variables(self) -> int:
        if self.bilateral:
            return 6
        return self.generators.shape[0] * self.generators.shape[2]

    def wrench_map(self, R_world_frame: np.ndarray) -> np.ndarray:
        """Phi (6, n_var): wrench [N, N m] at the reference point, world axes, from the variables."""
        if self.bilateral:
            return _EYE6
        offsets = self._offsets_in_frame @ R_world_frame.T  # (k, 3) world
        # moments offset_i x G_i[:, j], laid out like the force block (point-major columns)
        phi = self._phi.copy()
        np.matmul(self._moment_map, offsets.reshape(-1), out=phi[3:].reshape(-1))
        return phi

    def normal_rows(self) -> np.ndarray:
        """(k, n_var): normal force of each point from the generator variables [N]."""
        return self._normal_rows

    def total_normal_row(self) -> np.ndarray:
        """(n_var,): total normal force over the points from the generator variables [N]."""
        return self._total_normal_row

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


class JointAccelerationBounds:
    """:func:`joint_acceleration_bounds` with its constants folded once and the bounds written in
    place (the per-tick path of the whole-body QP); same arithmetic up to rounding."""

    def __init__(self, lower: np.ndarray, upper: np.ndarray, velocity_limit: np.ndarray, horizon: float,
                 accel_bound: float, margin: float = 0.0):
        T = float(horizon)
        self.T = T
        self.scale = 2.0 / T ** 2  # [1/s^2]
        self.lo_q = np.asarray(lower, float) + margin  # [rad]
        self.hi_q = np.asarray(upper, float) - margin
        self.lo_v = -np.asarray(velocity_limit, float) / T  # [rad/s^2]
        self.hi_v = np.asarray(velocity_limit, float) / T
        self.accel = float(accel_bound)
        self._reach = np.empty_like(self.lo_q)
        self._tmp = np.empty_like(self.lo_q)

    def fill(self, q_joints: np.ndarray, v_joints: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> None:
        T, reach, tmp = self.T, self._reach, self._tmp
        np.multiply(v_joints, T, out=reach)
        reach += q_joints  # q + v T
        np.subtract(self.lo_q, reach, out=lo)
        lo *= self.scale
        np.subtract(self.hi_q, reach, out=hi)
        hi *= self.scale
        np.divide(v_joints, -T, out=tmp)  # -v / T: the stopping acceleration
        np.maximum(lo, np.add(self.lo_v, tmp, out=reach), out=lo)
        np.minimum(hi, np.add(self.hi_v, tmp, out=reach), out=hi)
        np.maximum(lo, -self.accel, out=lo)
        np.minimum(hi, self.accel, out=hi)
        np.clip(tmp, -self.accel, self.accel, out=tmp)
        np.minimum(lo, tmp, out=lo)
        np.maximum(hi, tmp, out=hi)


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


def frame_point_kinematics(model: pin.Model, data: pin.Data, frame_id: int, r_world: np.ndarray
                           ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """6D Jacobian (6, nv), drift Jdot v (6,) [m/s^2, rad/s^2] and velocity (6,) [m/s, rad/s] of
    the point ``r_world`` [m] (world axes, from the frame origin) fixed in frame ``frame_id``,
    world-aligned (needs the frame's joint Jacobians, placements, velocities and accelerations in
    ``data``). Drift of the point: a + alpha x r + w x (w x r)."""
    J = pin.getFrameJacobian(model, data, frame_id, pin.LOCAL_WORLD_ALIGNED)  # a new array
    J[:3] -= skew(r_world) @ J[3:]
    vx, vy, vz, wx, wy, wz = pin.getFrameVelocity(model, data, frame_id, pin.LOCAL_WORLD_ALIGNED).vector.tolist()
    ax, ay, az, bx, by, bz = pin.getFrameClassicalAcceleration(
        model, data, frame_id, pin.LOCAL_WORLD_ALIGNED).vector.tolist()
    rx, ry, rz = r_world.tolist()
    cx, cy, cz = wy * rz - wz * ry, wz * rx - wx * rz, wx * ry - wy * rx  # w x r
    drift = np.array([ax + (by * rz - bz * ry) + (wy * cz - wz * cy),
                      ay + (bz * rx - bx * rz) + (wz * cx - wx * cz),
                      az + (bx * ry - by * rx) + (wx * cy - wy * cx), bx, by, bz])
    velocity = np.array([vx + cx, vy + cy, vz + cz, wx, wy, wz])
    return J, drift, velocity


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
                 max_braking: float = np.inf, broadphase_slack: float = 0.03):
        import coal

        self._coal = coal
        self.di = influence_distance  # [m]
        self.ds = security_distance  # [m]
        self.xi = damping  # [m/s]
        self.margin = broadphase_margin  # [m]
        self.max_braking = max_braking  # [m/s^2] cap on the deceleration a damper may demand
        self.slack = broadphase_slack  # [m] sphere-centre motion before the broadphase re-runs
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
        self._tf1 = coal.Transform3s()
        self._setup_batched(env_links, robot_geometries)

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

    def rows_reference(self, model: pin.Model, data: pin.Data, v: np.ndarray, dt: float,
                       disabled: set[tuple[str, str]] | frozenset = frozenset()) -> list[DamperRow]:
        """Reference implementation of :meth:`compute` (one pair at a time, per-pair Python):
        kept to check the batched path against (tests/unit/test_qp.py). Same rows, same order."""
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

    # -- batched per-tick path --------------------------------------------------------------
    def _setup_batched(self, env_links, robot_geometries) -> None:
        """Index tables resolved once: joints, placements, pair names, coal distance functors."""
        items = self._items
        joints = sorted({item[2] for item in items})
        self._joints = [int(j) for j in joints]  # pinocchio containers want Python ints
        joint_slot = {j: i for i, j in enumerate(joints)}
        self._item_slot = np.array([joint_slot[item[2]] for item in items], dtype=int)
        self._item_joint = np.array([item[2] for item in items], dtype=int)
        self._centre_in_joint = np.array([item[4] for item in items], dtype=float).reshape(-1, 3)
        self._placement_R = np.array([item[3].rotation for item in items], dtype=float).reshape(-1, 3, 3)
        self._placement_t = np.array([item[3].translation for item in items], dtype=float).reshape(-1, 3)
        # homogeneous forms: geometry placements in their joints (I, 4, 4), sphere centres (I, 4, 1)
        self._placement_h = np.array([item[3].homogeneous for item in items], dtype=float).reshape(-1, 4, 4)
        self._centre_h = np.concatenate([self._centre_in_joint, np.ones((len(items), 1))], axis=1)[:, :, None]
        self._env_items_arr = np.array(self._env_items, dtype=int)
        caps = self._env_capsules
        self._cap_a = caps[None, :, :3]
        self._cap_ab = (caps[:, 3:6] - caps[:, :3])[None]
        self._cap_denom = np.maximum((self._cap_ab * self._cap_ab).sum(-1), 1e-12)
        self._cap_r = caps[None, :, 6]
        self._cap_a_c = np.ascontiguousarray(caps[:, :3])  # (K, 3)
        self._cap_ab_c = np.ascontiguousarray(caps[:, 3:6] - caps[:, :3])
        self._cap_denom_c = np.maximum((self._cap_ab_c * self._cap_ab_c).sum(-1), 1e-12)  # (K,)
        n_env = len(self._env)
        self._n_env = n_env
        self._env_radii = self._radii[self._env_items_arr][:, None] if len(self._env_items_arr) else np.zeros((0, 1))
        self._env_names = [[f"{items[i][0]}|{surface}" for surface, _, _ in self._env] for i in self._env_items]
        self._env_pair_links = [(items[i][0], [surface for surface, _, _ in self._env]) for i in self._env_items]
        n_pairs = len(self._env_items) * n_env
        self._functors: dict[int, object] = {}
        # self pairs: item pairs, names
        sa, sb, names, links = [], [], [], []
        for link_a, link_b in self.self_pairs:
            for ia in self._item_index[link_a]:
                for ib in self._item_index[link_b]:
                    sa.append(ia)
                    sb.append(ib)
                    names.append(f"{link_a}|{link_b}")
                    links.append((link_a, link_b))
        self._self_a = np.array(sa, dtype=int)
        self._self_b = np.array(sb, dtype=int)
        self._self_names = names
        self._self_links = links
        self._self_radii = self._radii[self._self_a] + self._radii[self._self_b] if sa else np.zeros(0)
        # one table of pairs: environment pairs (pid = li * n_env + k, item, static sentinel),
        # then self pairs (item a, item b)
        self._n_env_pairs = n_pairs
        n_items = len(items)
        self._pair_a = np.concatenate([np.repeat(self._env_items_arr, n_env), self._self_a]).astype(int)
        self._pair_b = np.concatenate([np.full(n_pairs, n_items), self._self_b]).astype(int)
        self._pair_names = [name for row in self._env_names for name in row] + names
        self._pair_disabled = np.zeros(n_pairs + len(sa), dtype=bool)
        self._pair_enabled = np.ones(n_pairs + len(sa), dtype=bool)
        #: coherence budget [m] per pair: last exact distance - d_i - motion since (-inf: unknown)
        self._budget = np.full(n_pairs + len(sa), -np.inf)
        self._motion = np.zeros(n_items + 1)  # [m] per item this tick; the sentinel stays 0
        self._prev_centres: np.ndarray | None = None
        self._prev_R: np.ndarray | None = None
        self._bp_centres: np.ndarray | None = None
        self._candidates = np.zeros(0, dtype=int)
        self._disabled_key: frozenset | None = None
        self._item_masks = np.zeros((len(items), 0))
        self.capacity = n_pairs + len(sa)  # most damper rows one tick can produce

    def _broadphase(self, centres: np.ndarray) -> None:
        """Pairs whose bounding spheres may come within cutoff before a centre moves ``slack``."""
        cutoff = self.di + self.margin
        parts = []
        env_idx = self._env_items_arr
        if self._n_env and len(env_idx):
            # sphere centre c to the capsule axis a + t ab, t in [0, 1]; contiguous operands and
            # einsum reductions (broadcast views and .sum(-1) on a last axis of 3 are slow paths)
            cap_a, cap_ab = self._cap_a_c, self._cap_ab_c
            ca = centres[env_idx][:, None, :] - cap_a  # (L, K, 3)
            t = np.einsum("lkj,kj->lk", ca, cap_ab)
            t /= self._cap_denom_c
            np.clip(t, 0.0, 1.0, out=t)
            diff = ca - t[:, :, None] * cap_ab  # centre -> closest axis point (sign irrelevant)
            gap = np.sqrt(np.einsum("lkj,lkj->lk", diff, diff))
            gap -= self._cap_r
            gap -= self._env_radii
            parts.append(np.flatnonzero(gap < cutoff + self.slack))  # pid = li * n_env + k
        if len(self._self_a):
            dcs = centres[self._self_a] - centres[self._self_b]
            gaps = np.sqrt((dcs * dcs).sum(-1)) - self._self_radii
            parts.append(self._n_env_pairs + np.flatnonzero(gaps < cutoff + 2.0 * self.slack))
        self._candidates = np.concatenate(parts) if parts else np.zeros(0, dtype=int)
        self._bp_centres = centres

    def _set_disabled(self, disabled) -> None:
        if disabled is self._disabled_key:  # the controller passes the same frozenset while nothing changed
            return
        key = disabled if isinstance(disabled, frozenset) else frozenset(disabled)
        if key == self._disabled_key:
            self._disabled_key = key
            return
        self._disabled_key = key
        for li, (link, surfaces) in enumerate(self._env_pair_links):
            for k, surface in enumerate(surfaces):
                self._pair_disabled[li * self._n_env + k] = (link, surface) in key
        for s, pair in enumerate(self._self_links):
            self._pair_disabled[self._n_env_pairs + s] = pair in key
        np.logical_not(self._pair_disabled, out=self._pair_enabled)

    def compute(self, model: pin.Model, data: pin.Data, v: np.ndarray, dt: float,
                disabled: set[tuple[str, str]] | frozenset = frozenset()) -> "DamperBatch":
        """Damper rows for every pair closer than the influence distance, batched.

        ``disabled``: (link, surface) pairs switched off (limb making or holding contact with
        that surface). Needs pin data with the joint Jacobians and their time variation
        (``computeJointJacobiansTimeVariation(q, v)``: ``data.J``, ``data.dJ``) and the joint
        placements of that configuration (:meth:`WholeBodyQP.update` computes them).
        Every step below only skips pairs proven to be at least the influence distance apart,
        so the rows are those of checking every pair exactly (:meth:`rows_reference`):

        1. broadphase, bounding spheres vs environment capsules and vs each other (exact lower
           bounds), all pairs at once, re-run only when a sphere centre moved more than
           ``broadphase_slack`` since the last run (which kept the pairs within cutoff + slack,
           resp. + 2 slack for two moving spheres: the gap is 1-Lipschitz in each centre);
        2. temporal coherence: each pair keeps a budget, its last exact distance minus d_i, from
           which every tick subtracts a bound on how far its bodies moved (|dc| + ||dR||_F reach,
           all items at once); a pair is measured again when the budget is spent;
        3. coal distances (cached functors) for the rest, then all rows and drifts in a few
           matrix products.
        """
        if not self._items:
            return DamperBatch.empty(model.nv)
        if self._item_masks.shape[1] != model.nv:
            self._item_masks = np.array([_support_mask(model, j) for j in self._item_joint.tolist()])
        self._set_disabled(disabled)
        oMi = data.oMi
        H = np.array([oMi[j].homogeneous for j in self._joints])  # (J, 4, 4) joint placements
        H_items = H[self._item_slot]  # (I, 4, 4): each item's joint
        R_items = H_items[:, :3, :3]
        centres = np.matmul(H_items, self._centre_h)[:, :3, 0]  # sphere centres (I, 3), world
        if self._prev_centres is not None:  # spend the coherence budgets
            dc = centres - self._prev_centres
            dR = R_items - self._prev_R
            motion = self._motion
            motion[:-1] = (np.sqrt(np.einsum("ij,ij->i", dc, dc))
                           + np.sqrt(np.einsum("ijk,ijk->i", dR, dR)) * self._reach)
            self._budget -= motion[self._pair_a] + motion[self._pair_b]
        self._prev_centres, self._prev_R = centres, R_items
        if self._bp_centres is not None:
            dc = centres - self._bp_centres
            rerun = float(np.einsum("ij,ij->i", dc, dc).max()) > self.slack * self.slack
        else:
            rerun = True
        if rerun:
            self._broadphase(centres)
        cand = self._candidates
        todo = cand[(self._budget[cand] < 0.0) & self._pair_enabled[cand]]
        names: list[str] = []
        distances: list[float] = []
        normals: list[list[float]] = []
        term_row: list[int] = []
        term_item: list[int] = []
        term_point: list[list[float]] = []
        term_sign: list[float] = []
        if len(todo):
            n_env_pairs = self._n_env_pairs
            it = self._pair_a[todo]
            G = np.matmul(H_items[it], self._placement_h[it])  # (k, 4, 4) geometry poses, world
            R_geom = G[:, :3, :3]
            t_geom = G[:, :3, 3]
            measured = np.empty(len(todo))
            items, env, pair_names, di = self._items, self._env, self._pair_names, self.di
            n_env, functors, request, result, tf1 = self._n_env, self._functors, self._request, self._result, self._tf1
            for n_i, (pid, item) in enumerate(zip(todo.tolist(), it.tolist())):
                if pid < n_env_pairs:
                    # coal distance: a cached functor per pair, one reused transform (constructing
                    # one costs ~3 us); the normal points from the obstacle to the body
                    functor = functors.get(pid)
                    if functor is None:
                        functor = functors[pid] = self._coal.ComputeDistance(items[item][1], env[pid % n_env][1])
                    result.clear()
                    tf1.setRotation(R_geom[n_i])
                    tf1.setTranslation(t_geom[n_i])
                    d = float(functor(tf1, env[pid % n_env][2], request, result))
                    measured[n_i] = d
                    if d < di:
                        p1 = result.getNearestPoint1().tolist()
                        p2 = result.getNearestPoint2().tolist()
                        dx, dy, dz = p1[0] - p2[0], p1[1] - p2[1], p1[2] - p2[2]
                        norm = math.sqrt(dx * dx + dy * dy + dz * dz)
                        if d > 1e-6 and norm > 1e-9:
                            n = [dx / norm, dy / norm, dz / norm]
                        else:
                            n = (-np.asarray(result.normal, dtype=float)).tolist()  # coal: from o1 to o2
                        term_row.append(len(names))
                        term_item.append(item)
                        term_point.append(p1 + n)  # witness point on the body, then the normal
                        term_sign.append(1.0)
                        names.append(pair_names[pid])
                        distances.append(d)
                else:
                    ib = int(self._pair_b[pid])
                    _, gb, jb, pb, _, _ = items[ib]
                    Mb = oMi[jb] * pb
                    d, p_a, p_b, n = self._distance(items[item][1],
                                                    self._coal.Transform3s(R_geom[n_i], t_geom[n_i]),
                                                    gb, self._coal.Transform3s(Mb.rotation, Mb.translation))
                    measured[n_i] = d
                    if d < di:
                        row = len(names)
                        n = n.tolist()
                        term_row += [row, row]
                        term_item += [item, ib]
                        term_point += [p_a.tolist() + n, p_b.tolist() + n]
                        term_sign += [1.0, -1.0]
                        names.append(pair_names[pid])
                        distances.append(d)
            measured -= di
            self._budget[todo] = measured
        k = len(names)
        if k == 0:
            return DamperBatch.empty(model.nv)
        # Each term: a witness point p (world) fixed in the body of joint j, direction n. With the
        # joint's world spatial velocity V = (v, w) = J_j v and drift acceleration A = (a, alpha)
        # = dJ_j v (both at the world origin, J_j = data.J masked to j's support):
        #   row   = [n, p x n]' J_j            (d_dot = row . v, the n' J_p of eq. 7)
        #   drift = n' a_p = [n, p x n]' A + n . (w x v_p),  v_p = v + w x p  (n' Jdot_p v)
        items_t = np.array(term_item)
        PN = np.array(term_point)  # (T, 6): witness points [m] and unit normals, world
        P = PN[:, :3]
        N = PN[:, 3:]
        W = np.empty((len(items_t), 6))
        W[:, :3] = N
        W[:, 3:] = np.einsum("ijk,tj,tk->ti", _LEVI_CIVITA, P, N)  # p x n
        masks = self._item_masks[items_t]  # (T, nv)
        J_world = data.J
        J_terms = W @ J_world
        J_terms *= masks  # (T, nv)
        Mv = masks * v  # (T, nv): v restricted to each term's support
        V = Mv @ J_world.T  # (T, 6)
        A = Mv @ data.dJ.T  # (T, 6)
        w_t = V[:, 3:]
        v_p = V[:, :3] + np.einsum("ijk,tj,tk->ti", _LEVI_CIVITA, w_t, P)
        n_drift_t = np.einsum("ti,ti->t", W, A) + np.einsum("ijk,ti,tj,tk->t", _LEVI_CIVITA, N, w_t, v_p)
        if len(items_t) == k:  # no self pair: one term per row, in row order
            rows = J_terms
            n_drift = n_drift_t
        else:
            rows_t = np.array(term_row)
            sign = np.array(term_sign)
            rows = np.zeros((k, model.nv))
            n_drift = np.zeros(k)
            np.add.at(rows, rows_t, sign[:, None] * J_terms)
            np.add.at(n_drift, rows_t, sign * n_drift_t)
        d_arr = np.array(distances)
        d_dot = rows @ v
        # eq. 6-8 with the sign restored: d_dot + dt d_ddot >= -xi (d - ds) / (di - ds)
        bound = -self.xi * (d_arr - self.ds) / (self.di - self.ds)
        # d_ddot >= (bound - d_dot) / dt, capped: a pair entering the zone too fast is braked as hard
        # as max_braking allows instead of making the QP infeasible
        lower = np.minimum((bound - d_dot) / dt, self.max_braking) - n_drift
        return DamperBatch(names, d_arr, d_dot, rows, lower, n_drift, bound)

    def rows(self, model: pin.Model, data: pin.Data, v: np.ndarray, dt: float,
             disabled: set[tuple[str, str]] | frozenset = frozenset()) -> list[DamperRow]:
        """Damper rows for every pair closer than the influence distance (see :meth:`compute`)."""
        return self.compute(model, data, v, dt, disabled).as_rows()


def _levi_civita() -> np.ndarray:
    eps = np.zeros((3, 3, 3))
    for i, j, k in ((0, 1, 2), (1, 2, 0), (2, 0, 1)):
        eps[i, j, k], eps[i, k, j] = 1.0, -1.0
    return eps


#: (3, 3, 3) permutation tensor: einsum("ijk,tj,tk->ti", eps, a, b) = a x b row-wise
_LEVI_CIVITA = _levi_civita()


@dataclass
class DamperBatch:
    """The damper rows of one tick as arrays: ``rows @ qdd >= lower`` (k rows)."""

    names: list[str]  # "link|surface" or "link_a|link_b"
    distance: np.ndarray  # (k,) [m]
    distance_rate: np.ndarray  # (k,) [m/s]
    rows: np.ndarray  # (k, nv) n' J
    lower: np.ndarray  # (k,) [m/s^2]
    drift: np.ndarray  # (k,) [m/s^2] n' Jdot v
    bound: np.ndarray  # (k,) [m/s] -xi (d - ds) / (di - ds)

    @classmethod
    def empty(cls, nv: int) -> "DamperBatch":
        z = np.zeros(0)
        return cls([], z, z, np.zeros((0, nv)), z, z, z)

    def __len__(self) -> int:
        return len(self.names)

    def as_rows(self) -> list[DamperRow]:
        return [DamperRow(self.names[i], float(self.distance[i]), float(self.distance_rate[i]), self.rows[i],
                          float(self.lower[i]), float(self.drift[i]), float(self.bound[i]))
                for i in range(len(self.names))]
