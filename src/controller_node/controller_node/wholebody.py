"""The whole-body QP of multicontact_darpa_tasks.txt (section III-D), reduced formulation.

Variables ``x = [qdd (nv), contact force variables]`` (generator weights of unilateral point
contacts, 6D wrenches of bilateral grasps); the joint torques are recovered afterwards from the
actuated rows of the dynamics, ``tau = M_a qdd + h_a - (J_c' Phi lambda)_a`` (FIELD_NOTES: dropping
tau from the variables is 1.3-5.5x faster). Rows:

- base rows of the dynamics (eq. 2, 6 equalities);
- torque limits (eq. 4) as inequalities affine in x;
- non-sliding held contacts (eq. 3, 6 equalities per contact, with a damping term on the contact
  velocity);
- friction cones (eq. 5) through generator weights >= 0; grasps get box bounds instead;
- per-point minimum normal force and total normal-force caps (force ramps before a release);
- joint position / velocity limits as bounds on qdd;
- velocity dampers (eq. 6-8) from :class:`controller_node.constraints.CollisionAvoidance`.

Tasks (eq. 1) are weighted least squares on q̈ from :mod:`controller_node.tasks`; small
regularisations keep H positive definite. ``build()`` returns the problem as a value;
``solve()`` raises :class:`controller_node.qp.QpFailure` carrying it.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from .constraints import (_LEVI_CIVITA, GRIP_DIRECTIONS, ActiveContact, CollisionAvoidance, DamperBatch, DamperRow,
                          JointAccelerationBounds, _support_mask, cross, frame_point_kinematics, joint_acceleration_bounds)
from .params import ControllerParams
from .qp import _SENSE_EQUALITY, DAQP_INF, DaqpSolver, QpFailure, QpProblem, QpSolution, make_solver
from .tasks import KinematicsView, Task


#: flat (row-major 6x6) indices in X = [[I, -[p]x], [0, I]] of (x, y, z) and of (-x, -y, -z):
#: X[1,5] = x, X[2,3] = y, X[0,4] = z; X[2,4] = -x, X[0,5] = -y, X[1,3] = -z
_SKEW_POS = np.array([11, 15, 4])
_SKEW_NEG = np.array([16, 5, 9])


_NO_POINTS = np.zeros((0, 3))  # point forces of a grasp
_NO_POINTS.flags.writeable = False


@dataclass
class ContactResult:
    limb: str
    wrench_in_world: np.ndarray  # (6,) [N, N m] at the contact reference point, world axes
    point_forces_in_world: np.ndarray  # (k, 3) [N] unilateral; (0, 3) for a grasp
    normal_force: float  # [N] total along the surface normals (unilateral) / |force| (grasp)


class WholeBodyResult:
    """One solved tick: ``qdd`` (nv,) [m/s^2, rad/s^2], ``tau`` (nv-6,) [N m], per-limb
    :class:`ContactResult`, the :class:`QpSolution`, the damper rows and the QP.

    ``problem`` is materialised on first access (a copy of the reused workspace): read it before
    the next ``build`` / ``solve`` of the same :class:`WholeBodyQP` (the controller's next tick),
    later access raises ``RuntimeError`` instead of returning another tick's matrices.
    """

    __slots__ = ("qdd", "tau", "contacts", "solution", "_problem", "_source", "_batch", "_dampers")

    def __init__(self, qdd: np.ndarray, tau: np.ndarray, contacts: dict[str, ContactResult],
                 solution: QpSolution, problem: QpProblem | None, dampers=None, source=None):
        self.qdd = qdd
        self.tau = tau
        self.contacts = contacts
        self.solution = solution
        self._problem = problem
        self._source = source  # (workspace, generation) when problem is None
        self._batch = dampers if isinstance(dampers, DamperBatch) else None
        self._dampers = None if self._batch is not None else list(dampers or [])

    @property
    def problem(self) -> QpProblem:
        if self._problem is None:
            workspace, generation = self._source
            if workspace.generation != generation:
                raise RuntimeError("the QP of this result was overwritten by a later build; read "
                                   "result.problem before the next tick")
            self._problem = workspace.snapshot()
        return self._problem

    @property
    def dampers(self) -> list[DamperRow]:
        if self._dampers is None:
            self._dampers = self._batch.as_rows()
        return self._dampers


class _Workspace:
    """Preallocated QP arrays for one active-contact set (reused across ticks).

    Layout (same rows, same order as :meth:`WholeBodyQP.build_reference`): dynamics base rows,
    torque-limit rows (together ``[M, -J_c' Phi]``), 6 held-contact rows per contact, the force
    rows of each contact (grip directions / per-point normals + total), then up to ``capacity``
    damper rows. Bounds of variables and rows share ``bu`` / ``bl`` (daqp's layout, +-DAQP_INF
    for free); constant blocks (force rows, their sparsity, equality flags) are filled once.
    """

    def __init__(self, wb: "WholeBodyQP", contacts: list[ActiveContact]):
        p = wb.params.qp
        nv, na = wb.nv, wb.na
        self.contacts = tuple(contacts)
        n = nv + sum(c.n_variables for c in contacts)
        self.n = n
        cap = wb.collision.capacity if (wb.collision is not None and wb.params.collision.enabled) else 0
        variable_blocks = [("qdd", 0, nv)]
        row_blocks = [("dynamics_base", 0, 6), ("torque_limits", 6, nv)]
        layout = []
        r, start = nv, nv
        for c in contacts:
            k = c.n_variables
            layout.append([c, start, start + k, r])
            variable_blocks.append((f"force:{c.limb}", start, start + k))
            row_blocks.append((f"contact:{c.limb}", r, r + 6))
            r += 6
            start += k
        eq_rows = [(0, 6)] + [(entry[3], entry[3] + 6) for entry in layout]
        A_static = []
        for entry in layout:
            c, s0, s1 = entry[0], entry[1], entry[2]
            entry.append(r)  # first force row
            if c.bilateral:
                A_static.append((r, r + len(GRIP_DIRECTIONS), s0, s0 + 3, GRIP_DIRECTIONS))
                row_blocks.append(("contact_force", r, r + len(GRIP_DIRECTIONS)))
                r += len(GRIP_DIRECTIONS)
            else:
                normals = c.normal_rows()
                kp = normals.shape[0]
                A_static.append((r, r + kp, s0, s1, normals))
                A_static.append((r + kp, r + kp + 1, s0, s1, normals.sum(axis=0)[None]))
                row_blocks.append(("contact_force", r, r + kp))
                row_blocks.append(("contact_force", r + kp, r + kp + 1))
                r += kp + 1
        self.layout = [tuple(entry) for entry in layout]  # (contact, var start, var stop, row, force row)
        # batched contact kinematics: each reference point is fixed in its frame's parent joint
        model = wb.model
        k = len(contacts)
        frames = [model.frames[c.frame_id] for c in contacts]
        self.contact_joints = [int(f.parentJoint) for f in frames]
        self.point_in_joint = np.array([f.placement.act(c.reference_in_frame) for f, c in zip(frames, contacts)],
                                       dtype=float).reshape(k, 3)
        self.R_joint_frame = np.array([f.placement.rotation for f in frames], dtype=float).reshape(k, 3, 3)
        self.contact_masks = np.array([_support_mask(model, j) for j in self.contact_joints]).reshape(k, wb.nv)
        self.X = np.zeros((k, 6, 6))  # [[I, -[p]x], [0, I]]: world-origin spatial -> point, world axes
        self.X[:, np.arange(6), np.arange(6)] = 1.0
        self.Jc = np.empty((k, 6, wb.nv))
        self.VA = np.empty((k, 6, 2))  # joint spatial velocity, drift acceleration (world origin)
        self.unilateral = [i for i, c in enumerate(contacts) if not c.bilateral]
        self.m_fixed = r
        m_max = r + cap
        self.variable_blocks = variable_blocks
        self.row_blocks = row_blocks
        self.H = np.zeros((n, n))
        self.H_diag = self.H.reshape(-1)[::n + 1]  # view on the diagonal
        self.g = np.zeros(n)
        self.A = np.zeros((m_max, n))
        for r0, r1, c0, c1, block in A_static:
            self.A[r0:r1, c0:c1] = block
        self.bu = np.full(n + m_max, DAQP_INF)
        self.bl = np.full(n + m_max, -DAQP_INF)
        self.bu[:6], self.bl[:6] = p.base_acceleration_bound, -p.base_acceleration_bound
        for c, s0, s1, _, _ in self.layout:
            if not c.bilateral:
                self.bl[s0:s1] = 0.0  # generator weights >= 0
        self.is_eq = np.zeros(m_max, dtype=bool)
        for r0, r1 in eq_rows:
            self.is_eq[r0:r1] = True
        self.sense = np.zeros(n + m_max, dtype=np.int32)
        self.sense[n:][self.is_eq] = _SENSE_EQUALITY
        self.reg = np.full(n, p.force_regularization)
        self.reg[:nv] = p.acceleration_regularization
        self.torque_scale = (p.torque_regularization / wb.effort ** 2)[:, None] if p.torque_regularization > 0 else None
        self.Dw = np.empty((na, n))
        self.m = self.m_fixed
        self.generation = 0

    def matches(self, contacts: list[ActiveContact]) -> bool:
        mine = self.contacts
        if len(mine) != len(contacts):
            return False
        for a, b in zip(mine, contacts):
            if a is not b:
                return False
        return True

    def snapshot(self) -> QpProblem:
        """The current problem as an independent value (infinite bounds as +-DAQP_INF)."""
        n, m = self.n, self.m
        row_blocks = list(self.row_blocks)
        if m > self.m_fixed:
            row_blocks.append(("collision", self.m_fixed, m))
        return QpProblem(self.H.copy(), self.g.copy(), self.bl[:n].copy(), self.bu[:n].copy(), self.A[:m].copy(),
                         self.bl[n:n + m].copy(), self.bu[n:n + m].copy(), self.is_eq[:m].copy(),
                         list(self.variable_blocks), row_blocks)


class WholeBodyQP:
    """Builds and solves the QP each tick for a Pinocchio free-flyer model."""

    def __init__(self, model: pin.Model, effort_limits: np.ndarray, params: ControllerParams,
                 collision: CollisionAvoidance | None = None):
        self.model = model
        self.data = model.createData()
        self.params = params
        self.nv = model.nv
        self.na = model.nv - 6
        self.effort = np.asarray(effort_limits, float)  # [N m] URDF effort limits
        self.tau_max = self.effort * params.qp.torque_limit_fraction  # [N m] what the QP may use
        self.q_lower = model.lowerPositionLimit[7:].copy()
        self.q_upper = model.upperPositionLimit[7:].copy()
        self.v_limit = model.velocityLimit[6:].copy()
        self.collision = collision
        p = params.qp
        self._joint_bounds = JointAccelerationBounds(self.q_lower, self.q_upper, self.v_limit, p.joint_limit_horizon_s,
                                                     p.joint_acceleration_bound, p.joint_limit_margin)
        self.view = KinematicsView(model, self.data)
        self.solver = make_solver(params.qp.solver, params.qp.time_limit_s, params.qp.iter_limit)
        self._zero_v = np.zeros(model.nv)
        self._dampers: list[DamperRow] = []
        self._batch = DamperBatch.empty(model.nv)
        self._workspace: _Workspace | None = None
        self._contact_layout: list = []
        self.dt = params.control_period_s

    # ------------------------------------------------------------------------------------
    def update(self, q: np.ndarray, v: np.ndarray) -> None:
        """Pinocchio terms for this state: M, h, joint Jacobians and their time variation, CoM
        (+ Jacobian, drift), frame placements, drifts."""
        model, data = self.model, self.data
        # M (full symmetric), nle, J, Jcom, com; its forward pass also leaves data.a = the drift
        # accelerations (qdd = 0), bit for bit what forwardKinematics(q, v, 0) would compute
        pin.computeAllTerms(model, data, q, v)
        # dJ (world): drifts of the contact reference points and damper witness points (~4 us)
        pin.computeJointJacobiansTimeVariation(model, data, q, v)
        pin.centerOfMass(model, data, pin.ACCELERATION, False)  # com, vcom, acom (drift)
        pin.updateFramePlacements(model, data)
        self.view.q = q
        self.view.v = v

    def set_solver(self, name: str) -> None:
        self.solver = make_solver(name, self.params.qp.time_limit_s, self.params.qp.iter_limit)

    # ------------------------------------------------------------------------------------
    def _contact_batch(self, ws: "_Workspace") -> tuple[np.ndarray, np.ndarray]:
        """All contacts of the workspace at once: Jacobians (k, 6, nv) of the reference points
        (linear rows at the point, world axes: LOCAL_WORLD_ALIGNED) and their drifts (k, 6)
        (classical acceleration with qdd = 0). Sets ``self._R_frames`` (k, 3, 3), world <- frame.

        With J_j the world Jacobian masked to the support of the point's joint j, V = (v, w) =
        J_j v and A = (a, alpha) = dJ_j v (spatial, world origin) and X = [[I, -[p]x], [0, I]]:
        J_point = X J_j, velocity X V = (v_p, w), drift X A + (w x v_p, 0)."""
        data = self.data
        oMi = data.oMi
        H = np.array([oMi[j].homogeneous for j in ws.contact_joints])  # (k, 4, 4)
        R_joint = H[:, :3, :3]
        self._R_frames = np.matmul(R_joint, ws.R_joint_frame)
        p = np.matmul(R_joint, ws.point_in_joint[:, :, None])[:, :, 0]
        p += H[:, :3, 3]  # (k, 3) reference points, world
        X = ws.X
        flat = X.reshape(len(p), 36)
        flat[:, _SKEW_POS] = p
        flat[:, _SKEW_NEG] = -p
        masks = ws.contact_masks
        J_world = data.J
        Jc = np.matmul(X, J_world, out=ws.Jc)
        Jc *= masks[:, None, :]
        Mv = masks * self.view.v
        VA = ws.VA
        np.matmul(Mv, J_world.T, out=VA[:, :, 0])
        np.matmul(Mv, data.dJ.T, out=VA[:, :, 1])
        XVA = np.matmul(X, VA)  # (k, 6, 2): (v_p, w), (a + alpha x p, alpha)
        w = XVA[:, 3:, 0]
        v_p = XVA[:, :3, 0]
        drift = XVA[:, :, 1].copy()
        drift[:, :3] += np.einsum("ijk,tj,tk->ti", _LEVI_CIVITA, w, v_p)  # + w x v_p
        return Jc, drift

    def _contact_kinematics(self, contact: ActiveContact):
        """Jacobian (6, nv) of the contact reference point, its drift, and the wrench map."""
        model, data = self.model, self.data
        fid = contact.frame_id
        R = data.oMf[fid].rotation
        r = R @ contact.reference_in_frame
        J, drift, _velocity = frame_point_kinematics(model, data, fid, r)
        return J, drift, contact.wrench_map(R), R

    def build_reference(self, contacts: list[ActiveContact], tasks: list[Task],
                        disabled_pairs: set[tuple[str, str]] | frozenset = frozenset()) -> QpProblem:
        """The straightforward build (fresh arrays, one block at a time, per-pair dampers): the
        reference the workspace path (:meth:`build`) is tested against. Same rows, same order."""
        p = self.params.qp
        nv, na = self.nv, self.na
        data = self.data
        v = self.view.v
        q = self.view.q
        n_f = sum(c.n_variables for c in contacts)
        n = nv + n_f

        # ---- cost: tasks on qdd + regularisation
        H = np.zeros((n, n))
        g = np.zeros(n)
        task_rows = [t.rows(self.view) for t in tasks]
        if task_rows:
            J = np.vstack([r.J for r in task_rows])
            w = np.concatenate([r.weights for r in task_rows])
            e = np.concatenate([r.drift - r.a_des for r in task_rows])
            Jw = J * w[:, None]
            H[:nv, :nv] = J.T @ Jw
            g[:nv] = Jw.T @ e
        H[np.arange(nv), np.arange(nv)] += p.acceleration_regularization
        H[np.arange(nv, n), np.arange(nv, n)] += p.force_regularization

        # ---- bounds: qdd (joint limits), force variables
        lb = np.empty(n)
        ub = np.empty(n)
        lb[:6], ub[:6] = -p.base_acceleration_bound, p.base_acceleration_bound
        lb[6:nv], ub[6:nv] = joint_acceleration_bounds(
            q[7:], v[6:], self.q_lower, self.q_upper, self.v_limit, p.joint_limit_horizon_s,
            p.joint_acceleration_bound, p.joint_limit_margin)

        # ---- dynamics rows [M, -J_c' Phi] x = -h  (base rows equal, actuated rows bounded)
        dyn = np.zeros((nv, n))
        dyn[:, :nv] = data.M
        contact_rows = []
        force_rows: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []  # (row over x, lower, upper)
        variable_blocks = [("qdd", 0, nv)]
        start = nv
        self._contact_layout = []
        for c in contacts:
            Jc, drift, phi, R = self._contact_kinematics(c)
            k = c.n_variables
            sl = slice(start, start + k)
            dyn[:, sl] = -(Jc.T @ phi)
            lo, hi = c.variable_bounds()
            lb[sl], ub[sl] = lo, hi
            row = np.zeros((6, n))
            row[:, :nv] = Jc
            contact_rows.append((row, -drift - p.contact_velocity_gain * (Jc @ v)))
            if c.bilateral:
                force, _torque = c.grip_limits()
                grip = np.zeros((len(GRIP_DIRECTIONS), n))
                grip[:, start:start + 3] = GRIP_DIRECTIONS
                force_rows.append((grip, np.full(len(grip), -force), np.full(len(grip), force)))
            else:
                normals = c.normal_rows()  # (k_points, k)
                per_point = np.zeros((normals.shape[0], n))
                per_point[:, sl] = normals
                f_min = c.min_normal_force * c.scale
                force_rows.append((per_point, np.full(len(normals), f_min), np.full(len(normals), np.inf)))
                total = np.zeros((1, n))
                total[0, sl] = normals.sum(axis=0)
                lo_total, hi_total = c.normal_force_window()
                force_rows.append((total, np.array([lo_total]), np.array([hi_total])))
            variable_blocks.append((f"force:{c.limb}", start, start + k))
            self._contact_layout.append((c, sl, phi, Jc))
            start += k

        h = data.nle
        # joint torques are affine in x: tau = dyn[6:] x + h[6:]; a small cost on (tau / tau_max)^2
        # spreads the load (internal contact forces) away from saturated joints
        if p.torque_regularization > 0:
            Da = dyn[6:]
            scale = p.torque_regularization / self.effort ** 2
            Dw = Da * scale[:, None]
            H += Da.T @ Dw
            g += Dw.T @ h[6:]
        blocks: list[tuple[str, np.ndarray, np.ndarray, np.ndarray, bool]] = []
        blocks.append(("dynamics_base", dyn[:6], -h[:6], -h[:6], True))
        blocks.append(("torque_limits", dyn[6:], -self.tau_max - h[6:], self.tau_max - h[6:], False))
        for c, (row, rhs) in zip(contacts, contact_rows):
            blocks.append((f"contact:{c.limb}", row, rhs, rhs, True))
        for row, lo, hi in force_rows:
            blocks.append(("contact_force", row, lo, hi, False))
        self._dampers = []
        if self.collision is not None and self.params.collision.enabled:
            self._dampers = self.collision.rows_reference(self.model, data, v, self.dt, disabled_pairs)
            if self._dampers:
                rows = np.zeros((len(self._dampers), n))
                rows[:, :nv] = np.array([d.row for d in self._dampers])
                lower = np.array([d.lower for d in self._dampers])
                blocks.append(("collision", rows, lower, np.full(len(lower), np.inf), False))

        A = np.vstack([b[1] for b in blocks])
        lower = np.concatenate([b[2] for b in blocks])
        upper = np.concatenate([b[3] for b in blocks])
        is_eq = np.concatenate([np.full(len(b[2]), b[4]) for b in blocks])
        row_blocks = []
        r0 = 0
        for b in blocks:
            row_blocks.append((b[0], r0, r0 + len(b[2])))
            r0 += len(b[2])
        return QpProblem(H, g, lb, ub, A, lower, upper, is_eq, variable_blocks, row_blocks)

    def solve_relaxed(self, contacts: list[ActiveContact], tasks: list[Task]) -> WholeBodyResult:
        """Fallback when the QP is infeasible: the same problem without the torque-limit and
        collision rows and without the joint-acceleration bounds (contact forces keep their cones
        and grip limits). The caller saturates the torques. Raises QpFailure if still infeasible."""
        problem = self.build(contacts, tasks)
        keep = np.ones(problem.m, dtype=bool)
        for name, a, b in problem.row_blocks:
            if name in ("torque_limits", "collision"):
                keep[a:b] = False
        lb, ub = problem.lb.copy(), problem.ub.copy()
        lb[:self.nv], ub[:self.nv] = -np.inf, np.inf
        blocks, r0 = [], 0
        for name, a, b in problem.row_blocks:
            if keep[a]:
                blocks.append((name, r0, r0 + b - a))
                r0 += b - a
        relaxed = QpProblem(problem.H, problem.g, lb, ub, problem.A[keep], problem.lower[keep], problem.upper[keep],
                            problem.is_eq[keep], problem.variable_blocks, blocks)
        return self._result(self.solver.solve(relaxed), problem=relaxed)

    def solve_equalities(self, contacts: list[ActiveContact], tasks: list[Task]) -> WholeBodyResult:
        """Fallback when the QP is infeasible: the same cost with only the equality rows (base
        dynamics, held contacts), solved as a KKT system; inequalities (torque limits, cones,
        joint limits, dampers) are dropped, so the caller must saturate the torques. Always
        solvable (regularised)."""
        problem = self.build(contacts, tasks)
        eq = problem.is_eq
        A = problem.A[eq]
        b = problem.upper[eq]
        n, m = problem.n, A.shape[0]
        K = np.zeros((n + m, n + m))
        K[:n, :n] = problem.H
        K[:n, n:] = A.T
        K[n:, :n] = A
        K[n:, n:] = -1e-9 * np.eye(m)
        rhs = np.concatenate([-problem.g, b])
        x = np.linalg.solve(K, rhs)[:n]
        solution = QpSolution(x, 0, 0.0, 0, "kkt")
        return self._result(solution, problem=problem)

    def _fill(self, contacts: list[ActiveContact], tasks: list[Task],
              disabled_pairs: set[tuple[str, str]] | frozenset) -> _Workspace:
        """Fill the workspace of this contact set in place for the current Pinocchio terms."""
        ws = self._workspace
        if ws is None or not ws.matches(contacts):
            ws = self._workspace = _Workspace(self, contacts)
        ws.generation += 1
        p = self.params.qp
        nv = self.nv
        n = ws.n
        data = self.data
        v = self.view.v
        q = self.view.q
        A, bu, bl = ws.A, ws.bu, ws.bl
        h = data.nle
        # dynamics rows [M, -J_c' Phi] x = -h (base rows equal, actuated rows bounded: torque limits)
        A[:nv, :nv] = data.M
        bu[n:n + 6] = -h[:6]
        bl[n:n + 6] = -h[:6]
        np.subtract(self.tau_max, h[6:], out=bu[n + 6:n + nv])
        np.subtract(-self.tau_max, h[6:], out=bl[n + 6:n + nv])
        # joint limits as bounds on qdd
        self._joint_bounds.fill(q[7:], v[6:], bl[6:nv], bu[6:nv])
        layout = []
        kv = p.contact_velocity_gain
        k = len(ws.layout)
        if k:
            Jc_all, drift_all = self._contact_batch(ws)
            r0 = ws.layout[0][3]
            A[r0:r0 + 6 * k, :nv] = Jc_all.reshape(6 * k, nv)  # the contacts' rows follow each other
            rhs = bu[n + r0:n + r0 + 6 * k]
            np.matmul(Jc_all, v, out=rhs.reshape(k, 6))
            rhs *= -kv
            rhs -= drift_all.reshape(-1)
            bl[n + r0:n + r0 + 6 * k] = rhs
        for i, (c, s0, s1, r, rf) in enumerate(ws.layout):
            Jc = Jc_all[i]
            if c.bilateral:
                phi = c.wrench_map(None)
                np.negative(Jc.T, out=A[:nv, s0:s1])
                force, torque = c.grip_limits()
                bu[s0:s0 + 3] = force
                bu[s0 + 3:s1] = torque
                bl[s0:s0 + 3] = -force
                bl[s0 + 3:s1] = -torque
                g_rows = len(GRIP_DIRECTIONS)
                bu[n + rf:n + rf + g_rows] = force
                bl[n + rf:n + rf + g_rows] = -force
            else:
                phi = c.wrench_map(self._R_frames[i])
                block = A[:nv, s0:s1]
                np.matmul(Jc.T, phi, out=block)
                np.negative(block, out=block)
                kp = c.points_in_frame.shape[0]
                bl[n + rf:n + rf + kp] = c.min_normal_force * c.scale
                lo_total, hi_total = c.normal_force_window()
                bl[n + rf + kp] = lo_total
                bu[n + rf + kp] = min(hi_total, DAQP_INF)
            layout.append((c, slice(s0, s1), phi, Jc))
        self._contact_layout = layout
        # cost: torque regularisation (tau affine in x: tau = D x + h_a, D = A[6:nv]) + tasks
        H, g = ws.H, ws.g
        if ws.torque_scale is not None:
            Da = A[6:nv]
            np.multiply(Da, ws.torque_scale, out=ws.Dw)
            np.matmul(Da.T, ws.Dw, out=H)
            np.matmul(ws.Dw.T, h[6:], out=g)
        else:
            H.fill(0.0)
            g.fill(0.0)
        dense = []
        for task in tasks:
            rows = task.rows(self.view)
            if rows.columns is not None:  # J selects qdd[columns]: J' W J and J' W e are diagonal
                cols = rows.columns
                ws.H_diag[cols] += rows.weights
                g[cols] += rows.weights * (rows.drift - rows.a_des)
            else:
                dense.append(rows)
        if dense:
            J = np.concatenate([r.J for r in dense]) if len(dense) > 1 else dense[0].J
            w = np.concatenate([r.weights for r in dense]) if len(dense) > 1 else dense[0].weights
            e = (np.concatenate([r.drift - r.a_des for r in dense]) if len(dense) > 1
                 else dense[0].drift - dense[0].a_des)
            Jw = J * w[:, None]
            H[:nv, :nv] += J.T @ Jw
            g[:nv] += Jw.T @ e
        ws.H_diag += ws.reg
        # velocity dampers
        m = ws.m_fixed
        if self.collision is not None and self.params.collision.enabled:
            batch = self.collision.compute(self.model, data, v, self.dt, disabled_pairs)
            k = len(batch)
            if k:
                A[m:m + k, :nv] = batch.rows
                bl[n + m:n + m + k] = batch.lower
                m += k
        else:
            batch = DamperBatch.empty(nv)
        self._batch = batch
        ws.m = m
        return ws

    def build(self, contacts: list[ActiveContact], tasks: list[Task],
              disabled_pairs: set[tuple[str, str]] | frozenset = frozenset()) -> QpProblem:
        """The QP of this tick as an independent value (a copy of the reused workspace)."""
        ws = self._fill(contacts, tasks, disabled_pairs)
        self._dampers = self._batch.as_rows()
        return ws.snapshot()

    def last_dampers(self) -> list[DamperRow]:
        """The damper rows of the last problem built (diagnostics: a failing QP's active pairs)."""
        return self._batch.as_rows() if len(self._batch) else list(self._dampers)

    def solve(self, contacts: list[ActiveContact], tasks: list[Task],
              disabled_pairs: set[tuple[str, str]] | frozenset = frozenset()) -> WholeBodyResult:
        ws = self._fill(contacts, tasks, disabled_pairs)
        solver = self.solver
        if isinstance(solver, DaqpSolver):  # straight from the workspace arrays
            n, m = ws.n, ws.m
            try:
                solution = solver.solve_arrays(ws.H, ws.g, ws.A[:m], ws.bu[:n + m], ws.bl[:n + m], ws.sense[:n + m])
            except QpFailure as failure:
                failure.problem = ws.snapshot()
                raise
            return self._result(solution, batch=self._batch, source=(ws, ws.generation))
        problem = ws.snapshot()
        return self._result(solver.solve(problem), problem=problem, batch=self._batch)

    def _result(self, solution: QpSolution, problem: QpProblem | None = None, batch=None,
                source=None) -> WholeBodyResult:
        x = solution.x
        nv = self.nv
        qdd = x[:nv]
        results: dict[str, ContactResult] = {}
        for c, sl, phi, Jc in self._contact_layout:
            xs = x[sl]
            if c.bilateral:
                wrench = xs.copy()  # Phi = I
                forces = _NO_POINTS
                f = wrench[:3]
                normal = math.sqrt(float(f @ f))
            else:
                wrench = phi @ xs
                kpts, _, ng = c.generators.shape
                forces = np.matmul(c.generators, xs.reshape(kpts, ng, 1))[:, :, 0]
                normal = float(c.total_normal_row() @ xs)  # sum of the points' normal forces
            results[c.limb] = ContactResult(c.limb, wrench, forces, normal)
        data = self.data
        if source is not None:  # the workspace's actuated dynamics rows: tau = [M_a, -(J_c' Phi)_a] x + h_a
            tau = source[0].A[6:nv] @ x + data.nle[6:]
        else:
            generalized = np.zeros(nv)
            for c, sl, phi, Jc in self._contact_layout:
                generalized += Jc.T @ results[c.limb].wrench_in_world
            tau = data.M[6:] @ qdd + data.nle[6:] - generalized[6:]
        return WholeBodyResult(qdd.copy(), tau, results, solution, problem,
                               batch if batch is not None else list(self._dampers), source)
