"""Physics-constrained inverse kinematics (multicontact_darpa_tasks.txt, III-B).

Extends :mod:`climb_core.ik` (contact pose errors and their Jacobians are the core's) with the
physics of the stance: a sequential QP over the configuration step ``dq`` and the point contact
forces ``f`` of the *regular* contacts,

    min  0.5 |q ⊕ dq ⊖ q_target|²_W + w_float |p_float(q ⊕ dq) - p_preferred|² + eps |f|² + slack penalties
    s.t. contact rows       J_c dq + s_c = -e_c                 (regular, zero-force and floating contacts)
         base equilibrium   J_f,base^T f - K_base dq + s_eq = g_base
         torque limits      |g_a + K_a dq - J_f,a^T f| <= L + s_tau,  s_tau >= 0
         friction / grip    the core feasibility model's pyramid and grip rows on f
         collisions         d_k + ∇d_k dq + s_col >= margin,  s_col >= 0   (pairs closer than the activation distance)
         joint limits and a trust region on dq

with K = ∂(g(q) - J_f(q)^T f)/∂q at the current forces (Pinocchio's static-torque derivatives).
The slacks keep every QP feasible; what is left of them at the end names the constraint that
could not be met (``reach:<limb>``, ``torque_limit:<joint>``, ``equilibrium``, ``collision``). The
final configuration is always re-checked by :func:`climb_core.feasibility.check`.

The three contact types of the paper:

- ``regular``: the limb is on its hold and carries force (friction cone, or grip limit for a
  closed grasp: no cone, bilateral);
- ``zero_force``: the limb is placed on its hold (or at an explicit pose) but exerts no force;
- ``floating``: the limb must touch an environment surface, where on it is free; the cost pulls
  it toward ``preferred_position``. The result turns it into a hold (``PCIKResult.holds``).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np
import pinocchio as pin

from climb_core import collision as collision_mod
from climb_core import feasibility
from climb_core import holds as holds_mod
from climb_core import ik as core_ik
from climb_core.contact import Hold, Stance
from climb_core.errors import SpecError

from .settings import PCIKParams

REGULAR = "regular"
ZERO_FORCE = "zero_force"
FLOATING = "floating"
CONTACT_TYPES = (REGULAR, ZERO_FORCE, FLOATING)


@dataclass(frozen=True)
class ContactSpec:
    """One contact of a physics-constrained IK problem."""

    limb: str
    type: str = REGULAR
    hold: Hold | None = None  # regular / zero_force
    pose: np.ndarray | None = None  # 4x4 T_world_surface target of the limb surface (zero_force without a hold,
    #                                  or a regular contact whose free grasp roll is pinned)
    surface: str | None = None  # floating: environment surface name
    preferred_position: np.ndarray | None = None  # floating: [m] world point the contact is pulled toward
    soft: bool = False  # a design cue: the pose is a strongly weighted cost (``cue_weight``), not a constraint
    robot_surface: str | None = None  # the limb's contact surface; default: the hold's, else for a
    #                                   floating hand holds.hand_surface_for (grasp if bilateral, else palm),
    #                                   else the limb's primary one (``pose`` is that surface's)

    def __post_init__(self) -> None:
        if self.type not in CONTACT_TYPES:
            raise SpecError("contact.type", f"must be one of {', '.join(CONTACT_TYPES)}; got {self.type!r}")
        if self.type == REGULAR and self.hold is None:
            raise SpecError("contact.hold", "a regular contact needs a hold")
        if self.type == ZERO_FORCE and self.hold is None and self.pose is None:
            raise SpecError("contact.hold", "a zero-force contact needs a hold or a pose")
        if self.type == FLOATING and not self.surface:
            raise SpecError("contact.surface", "a floating contact needs an environment surface")
        if self.robot_surface and self.hold is not None and self.hold.robot_surface != self.robot_surface:
            raise SpecError("contact.robot_surface", f"{self.robot_surface!r} but the hold is made with "
                                                     f"{self.hold.robot_surface!r}")

    @property
    def env_surface(self) -> str | None:
        return self.hold.env_surface if self.hold is not None else self.surface


def contact_surface(robot: Any, env: Any, c: ContactSpec) -> Any:
    """The robot ContactSurface contact ``c`` is made with (see ``ContactSpec.robot_surface``)."""
    if c.hold is not None:
        return holds_mod.hold_surface(robot, c.hold)
    if c.robot_surface:
        return holds_mod.limb_surface(robot, c.limb, c.robot_surface)
    if c.type == FLOATING and env is not None:
        rs = holds_mod.robot_surface_for(robot, c.limb, holds_mod.env_surface(env, c.surface), required=False)
        if rs is not None:
            return rs
    return holds_mod.limb_surface(robot, c.limb)


#: [m] a floating polygon's centre is kept this far inside (its circumradius + this) a box's top
#: face edges: the in-plane rows are free inside, so the last steps may overshoot the limit a little
FACE_EDGE_MARGIN = 0.01


def _onto_top_face(sf: Any, rs: Any, p: np.ndarray) -> tuple[np.ndarray, list[np.ndarray]]:
    """``p`` moved into the top face of box ``sf`` so that the robot polygon ``rs`` (a sole or a
    palm, its circumradius + FACE_EDGE_MARGIN) stays on the face, and the face axes (world) along
    which it was moved."""
    T = np.asarray(sf.T_world_surface)
    R, half = T[:3, :3], np.asarray(sf.half_extents, dtype=float)
    up = int(np.argmax(np.abs(R[2, :])))
    v = holds_mod.sole_vertices_in_surface(rs)
    radius = (float(np.max(np.linalg.norm(v[:, :2], axis=1))) if len(v) else 0.0) + FACE_EDGE_MARGIN
    local = R.T @ (np.asarray(p, dtype=float) - T[:3, 3])
    moved = []
    for k in range(3):
        if k == up:
            continue
        lim = max(half[k] - radius, 0.0)
        if abs(local[k]) > lim:
            local[k] = math.copysign(lim, local[k])
            moved.append(R[:, k].copy())
    return T[:3, 3] + R @ local, moved


def contacts_from_stance(stance: Stance) -> list[ContactSpec]:
    return [ContactSpec(h.limb, REGULAR, hold=h) for h in stance.holds]


@dataclass
class PCIKResult:
    q: np.ndarray
    success: bool  # contacts reached and, when checked, feasible
    violated: list[str]  # named constraints still broken (empty on success)
    iterations: int
    position_error: float  # [m] worst contact position error
    angle_error: float  # [rad] worst contact orientation error
    forces: dict[str, np.ndarray] = field(default_factory=dict)  # limb -> (n, 3) [N] world, from the final check
    torques: np.ndarray | None = None  # [N m] actuated joints, from the final check
    check: feasibility.FeasibilityResult | None = None
    holds: dict[str, Hold] = field(default_factory=dict)  # limb -> hold of every contact at q (floating ones made regular)
    slack: dict[str, float] = field(default_factory=dict)  # what remained of each slack group

    @property
    def failure(self) -> str:
        return self.violated[0] if self.violated else ""


# --------------------------------------------------------------------------------------------
# contact rows (pose errors from climb_core.ik)


def _rows_for_free(free_position: np.ndarray | None, free_rotation: np.ndarray | None) -> np.ndarray:
    """Selection (k, 6) of the surface-frame error rows that are constrained."""
    rows = []
    for block, free in ((0, free_position), (3, free_rotation)):
        basis = np.eye(3)
        if free is not None and len(free):
            F = np.atleast_2d(np.asarray(free, dtype=float))
            # orthonormal complement of the free directions
            u, s, vt = np.linalg.svd(F)
            rank = int((s > 1e-9).sum())
            basis = vt[rank:]
        for b in basis:
            r = np.zeros(6)
            r[block:block + 3] = b
            rows.append(r)
    return np.array(rows).reshape(-1, 6)


class _ContactRows:
    """Pose tasks of all contacts; floating targets are re-projected at every iteration."""

    def __init__(self, robot: Any, env: Any, contacts: Sequence[ContactSpec], hold_params: holds_mod.HoldParams,
                 q: np.ndarray):
        self.robot, self.env, self.contacts, self.hold_params = robot, env, list(contacts), hold_params
        self.fixed_targets: dict[str, Any] = {}
        self.surfaces = {c.limb: contact_surface(robot, env, c) for c in self.contacts}
        for c in self.contacts:
            if c.type == FLOATING:
                continue
            # an explicit pose wins (a regular contact may pin the free grasp roll with one)
            if c.pose is None:
                self.fixed_targets[c.limb] = c.hold
            elif c.robot_surface:
                rs = self.surfaces[c.limb]
                T = np.asarray(c.pose, dtype=float)
                self.fixed_targets[c.limb] = holds_mod.HoldTarget(
                    c.limb, rs.frame, T, holds_mod.frame_pose_from_surface(robot, c.limb, T, rs.name), None, "pose",
                    rs.name)
            else:
                self.fixed_targets[c.limb] = np.asarray(c.pose, dtype=float)
        self.tasks = core_ik.contact_tasks(robot, env, q, self.fixed_targets, hold_params) if self.fixed_targets else []
        self.floating = [c for c in self.contacts if c.type == FLOATING]

    def _floating_tasks(self, data: pin.Data) -> tuple[list, list[tuple[ContactSpec, int, np.ndarray]]]:
        tasks, pulls = [], []
        for c in self.floating:
            rs = self.surfaces[c.limb]
            fid = self.robot.frame_id(rs.frame)
            pin.updateFramePlacement(self.robot.model, data, fid)
            T_ws = data.oMf[fid].homogeneous @ np.asarray(rs.T_frame_surface)
            sf = holds_mod.env_surface(self.env, c.surface)
            kwargs: dict[str, Any] = {}
            if holds_mod.held_along_axis(sf, rs):  # along the rung
                a = np.asarray(sf.T_world_surface)[:3, 0]
                s = float(a @ (T_ws[:3, 3] - np.asarray(sf.T_world_surface)[:3, 3]))
                half = 0.5 * float(sf.length) - 0.05
                s = float(np.clip(s, -half, half)) if half > 0 else 0.0
                T_t, kind = holds_mod.surface_target_pose(self.robot, self.env, c.limb, c.surface, s,
                                                          params=self.hold_params, R_world_surface_seed=T_ws[:3, :3],
                                                          robot_surface=rs.name)
                a_s = T_t[:3, :3].T @ a  # rung axis in the target surface frame
                free_pos = a_s[None, :]
                free_rot = holds_mod.grasp_axis_in_surface(rs)[None, :] if kind == "grasp" else None
            else:
                heading = T_ws[:3, 0] - T_ws[:3, 0] @ np.array([0, 0, 1.0]) * np.array([0, 0, 1.0])
                yaw = math.atan2(heading[1], heading[0])
                clamped: list[np.ndarray] = []
                if sf.shape == "box":
                    p_on, clamped = _onto_top_face(sf, rs, T_ws[:3, 3])
                    T_t, kind = holds_mod.surface_target_pose(self.robot, self.env, c.limb, c.surface, 0.0,
                                                              position=p_on, yaw=yaw, params=self.hold_params,
                                                              robot_surface=rs.name)
                else:
                    T_t, kind = holds_mod.surface_target_pose(self.robot, self.env, c.limb, c.surface,
                                                              position=T_ws[:3, 3], yaw=yaw, params=self.hold_params,
                                                              robot_surface=rs.name)
                # in-plane position free, except along the face axes where the polygon would leave the face
                free_pos = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])  # surface frame x, y
                if clamped:
                    u = T_t[:3, :3].T @ np.array(clamped).T  # clamped face axes in the target surface frame
                    free_pos = np.cross(u[:, 0], [0.0, 0.0, 1.0])[None, :] if len(clamped) == 1 else None
                free_rot = np.array([[0.0, 0.0, 1.0]])  # heading about the normal
            task = core_ik.ContactTask(c.limb, fid, pin.SE3(np.asarray(rs.T_frame_surface)), pin.SE3(T_t),
                                 _rows_for_free(free_pos, free_rot))
            tasks.append(task)
            if c.preferred_position is not None:
                pulls.append((c, fid, np.asarray(rs.T_frame_surface)[:3, 3]))
        return tasks, pulls

    def evaluate(self, data: pin.Data, w_ang: float) -> tuple[np.ndarray, np.ndarray, list, list]:
        ftasks, pulls = self._floating_tasks(data) if self.floating else ([], [])
        tasks = self.tasks + ftasks
        e, J, per = core_ik.task_errors(self.robot.model, data, tasks, w_ang, with_jacobian=True)
        if J is None:
            J = np.zeros((0, self.robot.model.nv))
        return e, J, per, pulls

    def soft_rows(self) -> np.ndarray:
        """Boolean mask over the contact rows: True for soft (design cue) contacts."""
        soft = {c.limb for c in self.contacts if c.soft}
        tasks = self.tasks + [None] * len(self.floating)
        out = []
        for t, c in zip(tasks, [None] * len(self.tasks) + self.floating):
            limb = t.limb if t is not None else c.limb
            n = len(t.rows) if t is not None else None
            if n is None:
                n = 0  # floating rows are never soft; counted below
            out += [limb in soft] * n
        return np.array(out, dtype=bool)

    def holds_at(self, q: np.ndarray) -> dict[str, Hold]:
        out = {}
        for c in self.contacts:
            if c.hold is not None:
                out[c.limb] = c.hold
            elif c.type == FLOATING:
                out[c.limb] = holds_mod.hold_from_configuration(self.robot, self.env, q, c.limb, c.surface,
                                                                params=self.hold_params,
                                                                robot_surface=self.surfaces[c.limb].name)
        return out


# --------------------------------------------------------------------------------------------
# collision rows (distances from climb_core.collision)


def soft_mask(rows: "_ContactRows", m_c: int) -> np.ndarray:
    """(m_c,) True for the contact rows of soft (design cue) contacts."""
    soft = rows.soft_rows()
    out = np.zeros(m_c, dtype=bool)
    out[:len(soft)] = soft[:m_c]
    return out


def collision_rows(chk: collision_mod.CollisionChecker, model: pin.Model, data: pin.Data, q: np.ndarray,
                   exclusions: Sequence[tuple[str, str]], activation: float
                   ) -> tuple[np.ndarray, np.ndarray, list[tuple[str, str]]]:
    """Distances d (k,) [m] and gradients (k, nv) of the pairs closer than ``activation``.

    ``data`` must hold computeJointJacobians(q). Gradient of d = n . (p2 - p1) with coal's normal
    n (from geometry 1 to geometry 2) and the witness points attached to their joints.
    """
    rep = chk.distances(q, contacts=exclusions, threshold=activation)
    if not rep.below:
        return np.zeros(0), np.zeros((0, model.nv)), []
    index = chk.pair_index
    pair_joints = chk.pair_joints
    results = chk.geometry_data.distanceResults
    LWA = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED
    joint_cache: dict[int, tuple[np.ndarray, np.ndarray]] = {}  # joint -> (linear, angular rows of its Jacobian)
    origin: dict[int, np.ndarray] = {}  # joint -> its origin [m], world
    dists, grads, names = [], [], []
    for a, b, d in rep.below:
        k = index[(a, b)]
        res = results[k]
        n = np.asarray(res.normal, dtype=float)
        nn = np.linalg.norm(n)
        if nn < 1e-12:
            continue
        n = n / nn
        grad = np.zeros(model.nv)
        ja, jb = pair_joints[k]
        for j, sign, first in ((ja, -1.0, True), (jb, 1.0, False)):
            if j == 0:
                continue
            hit = joint_cache.get(j)
            if hit is None:
                J6 = pin.getJointJacobian(model, data, j, LWA)
                hit = joint_cache[j] = (J6[:3], J6[3:])
                origin[j] = data.oMi[j].translation
            p = np.asarray(res.getNearestPoint1() if first else res.getNearestPoint2())
            r = p - origin[j]
            Jp = hit[0] - _skew(r) @ hit[1]
            grad += sign * (n @ Jp)
        dists.append(float(d))
        grads.append(grad)
        names.append((a, b))
    return np.array(dists), np.array(grads).reshape(-1, model.nv), names


def _skew(r: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -r[2], r[1]], [r[2], 0.0, -r[0]], [-r[1], r[0], 0.0]])


# --------------------------------------------------------------------------------------------
# statics: K = d(g - J^T f)/dq with the point forces held in the joints' local frames


def static_torque_derivative(model: pin.Model, data: pin.Data, q: np.ndarray, frame_ids: Sequence[int],
                             points: Sequence[np.ndarray], forces: np.ndarray) -> np.ndarray:
    """∂τ/∂q (nv, nv) of τ = g(q) - Σ J_p(q)^T f_p with the current point forces (world [N])."""
    fext = pin.StdVec_Force()
    for _ in range(model.njoints):
        fext.append(pin.Force.Zero())
    row = 0
    for fid, P in zip(frame_ids, points):
        j = model.frames[fid].parentJoint
        oMi = data.oMi[j]
        for p in P:
            f = forces[row:row + 3]
            row += 3
            if not np.any(f):
                continue
            # p x f, written out (np.cross costs more than the rest of the loop body)
            fx, fy, fz = f
            px, py, pz = p
            fext[j] += oMi.actInv(pin.Force(f, np.array([py * fz - pz * fy, pz * fx - px * fz, px * fy - py * fx])))
    return pin.computeStaticTorqueDerivatives(model, data, q, fext)


# --------------------------------------------------------------------------------------------
# the solver


def feasibility_config_for(base: feasibility.FeasibilityConfig, params: PCIKParams) -> feasibility.FeasibilityConfig:
    """The core check's force model with the IK's margins (cones, grip and grasp moments, torque
    fraction, margin)."""
    return feasibility.with_check(base, friction_margin=params.friction_margin,
                                  grip_limit_fraction=params.grip_limit_fraction,
                                  torque_limit_fraction=params.torque_limit_fraction,
                                  min_normal_force=params.min_normal_force,
                                  grasp_moment_limit=feasibility.tighter_moment_limit(
                                      base.check.grasp_moment_limit, params.grasp_moment_limit),
                                  sole_cop_margin=max(base.check.sole_cop_margin, params.sole_cop_margin),
                                  collision_margin=params.collision_margin)


def solve(robot: Any, env: Any, q_seed: np.ndarray, contacts: Sequence[ContactSpec] | Stance, *,
          q_target: np.ndarray | None = None, params: PCIKParams | None = None,
          feasibility_cfg: feasibility.FeasibilityConfig | None = None, physics: bool = True,
          collision: bool = True, extra_exclusions: Sequence[tuple[str, str]] = (),
          final_check: bool = True, com_target: np.ndarray | None = None,
          self_margin: float | None = None) -> PCIKResult:
    """Configuration meeting ``contacts`` (+ equilibrium, torque, friction, collision when asked).

    q_target: the configuration the cost pulls toward (default: q_seed). feasibility_cfg: the
    check the result must pass (default config/feasibility.yaml); the IK itself works with its
    own, slightly stricter margins (``params``). extra_exclusions: (limb, surface) pairs allowed to
    touch (a limb landing on or leaving a surface). com_target: (2,) world x, y [m] the centre of
    mass is pulled toward (cost ``com_weight``). self_margin: the final check's margin [m] for the
    robot's self pairs (default: the check config's collision margin).
    """
    if params is None:
        from .settings import load_settings

        params = load_settings().pcik
    base_cfg = feasibility_cfg or feasibility.load_config()
    cfg = feasibility_config_for(base_cfg, params)
    if isinstance(contacts, Stance):
        contacts = contacts_from_stance(contacts)
    contacts = list(contacts)
    limbs = [c.limb for c in contacts]
    if len(set(limbs)) != len(limbs):
        raise SpecError("pcik.contacts", f"a limb appears twice: {limbs}")
    model: pin.Model = robot.model
    nv = model.nv
    na = nv - 6
    q = np.asarray(q_seed, dtype=float).copy()
    if q.shape != (model.nq,) or not np.isfinite(q).all():
        raise SpecError("pcik.q_seed", f"must be {model.nq} finite numbers")
    q[3:7] /= np.linalg.norm(q[3:7])
    q_target = q.copy() if q_target is None else np.asarray(q_target, dtype=float)
    lo = model.lowerPositionLimit[7:] + params.joint_limit_margin
    hi = model.upperPositionLimit[7:] - params.joint_limit_margin
    q[7:] = np.clip(q[7:], lo, hi)
    with core_ik.scratch_data(model) as data:
        return _solve(robot, env, q, contacts, q_target, params, base_cfg, cfg, data, lo, hi, physics, collision,
                      extra_exclusions, final_check, com_target, self_margin)


def _solve(robot: Any, env: Any, q: np.ndarray, contacts: list[ContactSpec], q_target: np.ndarray,
           params: PCIKParams, base_cfg: feasibility.FeasibilityConfig, cfg: feasibility.FeasibilityConfig,
           data: pin.Data, lo: np.ndarray, hi: np.ndarray, physics: bool, collision: bool,
           extra_exclusions: Sequence[tuple[str, str]], final_check: bool, com_target: np.ndarray | None,
           self_margin: float | None) -> PCIKResult:
    """The SQP loop of :func:`solve` (arguments validated; ``data`` a scratch pin.Data)."""
    model: pin.Model = robot.model
    nv = model.nv
    na = nv - 6
    rows = _ContactRows(robot, env, contacts, base_cfg.holds, q)
    exclusions = [(c.limb, c.env_surface) for c in contacts if c.env_surface] + list(extra_exclusions)
    chk = collision_mod.checker(robot, env, base_cfg.collision) if (collision and env is not None) else None

    regular = Stance(tuple(c.hold for c in contacts if c.type == REGULAR), name="pcik")
    use_forces = physics
    if use_forces:
        ws = feasibility.workspace(robot)
        cs = ws.compiled(env, regular, cfg)
        nf = cs.n_forces
        f = np.zeros(nf)
        L = params.torque_limit_fraction * np.asarray(robot.effort_limits(), dtype=float)
    else:
        nf = 0
        f = np.zeros(0)

    W = np.empty(nv)
    W[:3] = params.base_position_weight
    W[3:6] = params.base_orientation_weight
    W[6:] = params.posture_weight
    w_ang = params.orientation_weight
    slack_report: dict[str, float] = {}
    trust = params.step_limit
    prev_merit = None
    it = 0
    per: list = []
    converged = False
    for it in range(1, params.max_iterations + 1):
        pin.computeJointJacobians(model, data, q)
        pin.updateFramePlacements(model, data)
        e_c, J_c, per, pulls = rows.evaluate(data, w_ang)
        m_c = len(e_c)
        if use_forces:
            # the core's force model works on its own workspace data
            g = pin.computeGeneralizedGravity(model, ws.data, q).copy()
            pin.computeJointJacobians(model, ws.data, q)
            Jf = feasibility.contact_jacobians(ws, cs, q)
            K = static_torque_derivative(model, ws.data, q, cs.frame_ids, cs.points, f)
            fp = feasibility.build_force_problem(ws, cs, g, Jf, cfg.check, torque_mode="off", grip_mode="hard")
            static_A = fp.A[6:, :nf]
            static_lo = fp.lower[nf + 1 + 6:]
            static_up = fp.upper[nf + 1 + 6:]
            f_lo, f_hi = fp.lower[:nf], fp.upper[:nf]
        if chk is not None:
            d_col, G_col, col_names = collision_rows(chk, model, data, q, exclusions, params.collision_activation)
        else:
            d_col, G_col, col_names = np.zeros(0), np.zeros((0, nv)), []
        m_col = len(d_col)
        # per pair: the environment margin, or the (smaller) self-collision margin
        col_margin = np.array([params.collision_margin if b.startswith(collision_mod.ENV_PREFIX)
                               else params.self_collision_margin for _, b in col_names]).reshape(-1)

        # ---- variable layout
        n_eq = 6 if use_forces else 0
        n_tau = na if use_forces else 0
        o_f = nv
        o_sc = o_f + nf
        o_seq = o_sc + m_c
        o_st = o_seq + n_eq
        o_scol = o_st + n_tau
        n = o_scol + m_col
        H = np.zeros(n)
        c = np.zeros(n)
        Hq = np.diag(W + params.damping)
        diff = pin.difference(model, q_target, q)  # q ⊖ q_target
        c[:nv] = W * diff
        for spec, fid, p_fs in pulls:
            R = data.oMf[fid].rotation
            p_s = data.oMf[fid].translation + R @ p_fs
            J6 = pin.getFrameJacobian(model, data, fid, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)
            Jp = J6[:3] - _skew(R @ p_fs) @ J6[3:]
            err = p_s - np.asarray(spec.preferred_position, dtype=float)
            Hq += params.floating_weight * Jp.T @ Jp
            c[:nv] += params.floating_weight * Jp.T @ err
        if com_target is not None:
            com = pin.centerOfMass(model, data, q, False)
            Jcom = pin.jacobianCenterOfMass(model, data, q, False)[:2]
            target_xy = np.asarray(com_target, dtype=float)[:2]
            axes = np.isfinite(target_xy)  # NaN: that axis is free
            err = (com[:2] - np.where(axes, target_xy, 0.0))[axes]
            Jc2 = Jcom[axes]
            Hq += params.com_weight * Jc2.T @ Jc2
            c[:nv] += params.com_weight * Jc2.T @ err
        H[o_f:o_sc] = params.force_regularization
        H[o_sc:o_seq] = params.contact_slack_weight
        soft = soft_mask(rows, m_c)
        hard_contacts = ~soft
        if soft.any():
            H[o_sc:o_seq][soft] = params.cue_weight
        H[o_seq:o_st] = params.equilibrium_slack_weight
        H[o_st:o_scol] = params.torque_slack_weight
        c[o_st:o_scol] = params.torque_slack_weight * 1.0  # linear term: prefer exact zeros
        H[o_scol:] = params.collision_slack_weight
        Hfull = np.diag(H)
        Hfull[:nv, :nv] = Hq

        # ---- constraints
        A_rows, lo_rows, up_rows, sense_rows = [], [], [], []

        def add(A, lo_, up_, eq=False):
            A_rows.append(A)
            lo_rows.append(lo_)
            up_rows.append(up_)
            sense_rows.append(np.full(len(lo_), 5 if eq else 0, dtype=np.int32))

        if m_c:
            # contacts first: a hard step toward the contact manifold (as long as the trust region
            # allows it); the slack only opens when that QP is infeasible (joint limits, unreachable)
            A = np.zeros((m_c, n))
            A[:, :nv] = J_c
            A[:, o_sc:o_seq] = np.eye(m_c)
            scale = min(1.0, trust / max(float(np.abs(e_c).max()), 1e-12))
            add(A, -scale * e_c, -scale * e_c, eq=True)
        if use_forces:
            A = np.zeros((6, n))
            A[:, o_f:o_sc] = Jf[:, :6].T
            A[:, :nv] = -K[:6]
            A[:, o_seq:o_st] = np.eye(6)
            add(A, g[:6], g[:6], eq=True)
            # tau = g_a + K_a dq - Jf_a^T f ;  tau - s <= L ; -tau - s <= L
            Ka, JfaT = K[6:], Jf[:, 6:].T
            A = np.zeros((na, n))
            A[:, :nv] = Ka
            A[:, o_f:o_sc] = -JfaT
            A[:, o_st:o_scol] = -np.eye(na)
            add(A, np.full(na, -np.inf), L - g[6:])
            A = np.zeros((na, n))
            A[:, :nv] = -Ka
            A[:, o_f:o_sc] = JfaT
            A[:, o_st:o_scol] = -np.eye(na)
            add(A, np.full(na, -np.inf), L + g[6:])
            if len(static_A):
                A = np.zeros((len(static_A), n))
                A[:, o_f:o_sc] = static_A
                add(A, static_lo, static_up)
        if m_col:
            A = np.zeros((m_col, n))
            A[:, :nv] = G_col
            A[:, o_scol:] = np.eye(m_col)
            add(A, col_margin - d_col, np.full(m_col, np.inf))
        A = np.vstack(A_rows) if A_rows else np.zeros((0, n))
        # simple bounds
        lb = np.full(n, -np.inf)
        ub = np.full(n, np.inf)
        # adaptive trust region: shrink when the merit (posture + contact + collision) went up
        merit = (0.5 * float(W @ diff ** 2) + params.contact_slack_weight * float(e_c @ e_c)
                 + params.collision_slack_weight * float(np.sum(np.minimum(0.0, d_col - col_margin) ** 2))
                 + params.equilibrium_slack_weight * slack_report.get("equilibrium", 0.0) ** 2)
        if prev_merit is not None:
            trust = max(0.5 * trust, 1e-3) if merit > prev_merit else min(1.5 * trust, params.step_limit)
        prev_merit = merit
        step = trust
        lb[:nv], ub[:nv] = -step, step
        ub[6:nv] = np.minimum(step, hi - q[7:])
        lb[6:nv] = np.maximum(-step, lo - q[7:])
        lb[:nv] = np.minimum(lb[:nv], ub[:nv])
        if use_forces:
            lb[o_f:o_sc], ub[o_f:o_sc] = f_lo, f_hi
            lb[o_st:o_scol] = 0.0
        lb[o_scol:] = 0.0
        lower = np.concatenate([lb, np.concatenate(lo_rows) if lo_rows else np.zeros(0)])
        upper = np.concatenate([ub, np.concatenate(up_rows) if up_rows else np.zeros(0)])
        sense = np.concatenate([np.zeros(n, dtype=np.int32)] + sense_rows)
        hard = np.zeros(n, dtype=bool)
        hard[o_sc:o_seq] = hard_contacts
        lb_h, ub_h = lower.copy(), upper.copy()
        lb_h[:n][hard], ub_h[:n][hard] = 0.0, 0.0
        x = _solve_qp(Hfull, c, A, ub_h, lb_h, sense)
        if x is None:  # the contacts cannot be met within this step: let them slack
            x = _solve_qp(Hfull, c, A, upper, lower, sense)
        if x is None:
            break
        dq = x[:nv]
        if use_forces:
            f = x[o_f:o_sc]
            slack_report = {"equilibrium": float(np.abs(x[o_seq:o_st]).max(initial=0.0)),
                            "torque": float(x[o_st:o_scol].max(initial=0.0))}
        slack_report["contact"] = float(np.abs(x[o_sc:o_seq]).max(initial=0.0))
        slack_report["collision"] = float(x[o_scol:].max(initial=0.0))
        q = pin.integrate(model, q, dq)
        pos = max((p for p, _ in per), default=0.0)
        ang = max((a for _, a in per), default=0.0)
        contacts_ok = pos <= params.position_tolerance and ang <= params.angle_tolerance
        if contacts_ok and np.abs(dq).max() < params.step_tolerance:
            converged = True
            break
        if (final_check and contacts_ok and slack_report.get("equilibrium", 0.0) < params.equilibrium_tolerance
                and slack_report.get("torque", 0.0) < 1e-3 and slack_report["collision"] < 1e-4):
            # early exit: the (linearised) constraints hold; confirm with the core check
            early = _final(robot, env, q, contacts, rows, base_cfg, cfg, params, extra_exclusions, collision,
                           w_ang, it, slack_report, margins=False, self_margin=self_margin)
            if early.success:
                return early
    return _final(robot, env, q, contacts, rows, base_cfg, cfg, params, extra_exclusions, collision, w_ang, it,
                  slack_report, margins=False, converged=converged, final_check=final_check, self_margin=self_margin)


def _final(robot: Any, env: Any, q: np.ndarray, contacts: list[ContactSpec], rows: _ContactRows,
           base_cfg: feasibility.FeasibilityConfig, cfg: feasibility.FeasibilityConfig, params: PCIKParams,
           extra_exclusions: Sequence[tuple[str, str]], collision: bool, w_ang: float, it: int,
           slack_report: dict, margins: bool, converged: bool = True, final_check: bool = True,
           self_margin: float | None = None) -> PCIKResult:
    """Evaluate q: contact errors, then the core check (the IK's margins when ``margins``)."""
    model = robot.model
    with core_ik.scratch_data(model) as data:
        pin.computeJointJacobians(model, data, q)
        pin.updateFramePlacements(model, data)
        _, _, per, _ = rows.evaluate(data, w_ang)
    pos = max((p for p, _ in per), default=0.0)
    ang = max((a for _, a in per), default=0.0)
    violated: list[str] = []
    for limb, (pe, ae) in zip([t.limb for t in rows.tasks] + [c.limb for c in rows.floating], per):
        if pe > 10 * params.position_tolerance or ae > 10 * params.angle_tolerance:
            violated.append(f"reach:{limb}")
    holds = rows.holds_at(q) if not violated else {}
    result = PCIKResult(q=q.copy(), success=False, violated=violated, iterations=it, position_error=pos,
                        angle_error=ang, holds=holds, slack=dict(slack_report))
    if violated and final_check and rows.fixed_targets and not rows.floating:
        # the contacts gave way to something else: say what, from the kinematically closest
        # configuration that does make the contacts (when there is one)
        kin = core_ik.solve(robot, env, q, rows.fixed_targets, posture=q,
                            hold_params=base_cfg.holds)
        if kin.success:
            check_stance = Stance(tuple(c.hold for c in contacts if c.type == REGULAR), name="pcik")
            res = check_with_exclusions(robot, env, kin.q, check_stance, base_cfg, collision=collision,
                                        extra_exclusions=list(extra_exclusions), self_margin=self_margin)
            result.violated += [v for v in res.violated if v != "contact"]
            result.check = res
    if violated or not final_check:
        result.success = not violated and converged
        return result
    # the core check on the stance of the regular contacts (+ floating contacts made regular)
    check_stance = Stance(tuple(holds[c.limb] for c in contacts if c.type in (REGULAR, FLOATING)), name="pcik")
    zero_force = [(c.limb, c.env_surface) for c in contacts if c.type == ZERO_FORCE and c.env_surface]
    res = check_with_exclusions(robot, env, q, check_stance, cfg if margins else base_cfg,
                                extra_exclusions=list(extra_exclusions) + zero_force, collision=collision,
                                self_margin=self_margin)
    result.check = res
    result.forces = res.contact_forces
    result.torques = res.joint_torques
    result.violated = list(res.violated)
    result.success = res.feasible
    return result


def check_with_exclusions(robot: Any, env: Any, q: np.ndarray, stance: Stance,
                          cfg: feasibility.FeasibilityConfig, extra_exclusions: Sequence[tuple[str, str]] = (),
                          collision: bool = True, self_margin: float | None = None) -> feasibility.FeasibilityResult:
    """feasibility.check, with extra (limb, surface) pairs allowed to touch (limbs landing on or
    leaving a surface: their collision with it is the contact being made or broken), and
    optionally another margin [m] for the robot's self pairs than the config's (environment) one."""
    if (not extra_exclusions and self_margin is None) or not collision or not cfg.check.check_collision:
        return feasibility.check(robot, env, q, stance, cfg, collision=collision)
    res = feasibility.check(robot, env, q, stance, cfg, collision=False)
    chk = collision_mod.checker(robot, env, cfg.collision)
    contacts = [(h.limb, h.env_surface) for h in stance.holds] + list(extra_exclusions)
    env_margin = cfg.check.collision_margin
    own = env_margin if self_margin is None else self_margin
    rep = chk.distances(q, contacts=contacts, threshold=max(env_margin, own))
    res.min_distance, res.closest_pair = rep.min_distance, rep.pair
    bad = [(a, b, d) for a, b, d in rep.below
           if d < (env_margin if b.startswith(collision_mod.ENV_PREFIX) else own)]
    if bad or rep.min_distance < min(env_margin, own):
        res.violated.append("collision")
        res.details["collisions"] = bad or rep.below
        res.feasible = False
    return res




def _solve_qp(H: np.ndarray, c: np.ndarray, A: np.ndarray, upper: np.ndarray, lower: np.ndarray,
              sense: np.ndarray) -> np.ndarray | None:
    import daqp

    x, _, exitflag, _ = daqp.solve(H, c, A, upper, lower, sense, iter_limit=2000)
    if exitflag < 1:
        return None
    return np.asarray(x)


def describe_failure(result: PCIKResult) -> str:
    if result.success:
        return "ok"
    detail = ", ".join(result.violated) or "not converged"
    return f"{detail} (contact error {result.position_error * 1e3:.1f} mm, {math.degrees(result.angle_error):.1f} deg)"


__all__ = ["ContactSpec", "PCIKResult", "contact_surface", "REGULAR", "ZERO_FORCE", "FLOATING", "solve", "contacts_from_stance",
           "check_with_exclusions", "collision_rows", "static_torque_derivative", "feasibility_config_for"]
