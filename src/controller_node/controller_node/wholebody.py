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

from dataclasses import dataclass, field

import numpy as np
import pinocchio as pin

from .constraints import (GRIP_DIRECTIONS, ActiveContact, CollisionAvoidance, DamperRow, cross,
                          joint_acceleration_bounds, skew)
from .params import ControllerParams
from .qp import QpProblem, QpSolution, make_solver
from .tasks import KinematicsView, Task


@dataclass
class ContactResult:
    limb: str
    wrench_in_world: np.ndarray  # (6,) [N, N m] at the contact reference point, world axes
    point_forces_in_world: np.ndarray  # (k, 3) [N] unilateral; (0, 3) for a grasp
    normal_force: float  # [N] total along the surface normals (unilateral) / |force| (grasp)


@dataclass
class WholeBodyResult:
    qdd: np.ndarray  # (nv,) [m/s^2, rad/s^2]
    tau: np.ndarray  # (nv-6,) [N m]
    contacts: dict[str, ContactResult]
    solution: QpSolution
    problem: QpProblem
    dampers: list[DamperRow] = field(default_factory=list)


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
        self.view = KinematicsView(model, self.data)
        self.solver = make_solver(params.qp.solver, params.qp.time_limit_s, params.qp.iter_limit)
        self._zero_v = np.zeros(model.nv)
        self._dampers: list[DamperRow] = []
        self.dt = params.control_period_s

    # ------------------------------------------------------------------------------------
    def update(self, q: np.ndarray, v: np.ndarray) -> None:
        """Pinocchio terms for this state: M, h, joint Jacobians, CoM (+ Jacobian, drift), drifts."""
        model, data = self.model, self.data
        pin.computeAllTerms(model, data, q, v)  # M (full symmetric), nle, J, Jcom, com
        pin.forwardKinematics(model, data, q, v, self._zero_v)  # data.a = drift accelerations
        pin.centerOfMass(model, data, pin.ACCELERATION, False)  # com, vcom, acom (drift)
        pin.updateFramePlacements(model, data)
        self.view.q = q
        self.view.v = v

    def set_solver(self, name: str) -> None:
        self.solver = make_solver(name, self.params.qp.time_limit_s, self.params.qp.iter_limit)

    # ------------------------------------------------------------------------------------
    def _contact_kinematics(self, contact: ActiveContact):
        """Jacobian (6, nv) of the contact reference point, its drift, and the wrench map."""
        model, data = self.model, self.data
        oMf = data.oMf[contact.frame_id]
        R = oMf.rotation
        r = R @ contact.reference_in_frame
        J = pin.getFrameJacobian(model, data, contact.frame_id, pin.LOCAL_WORLD_ALIGNED).copy()
        J[:3] -= skew(r) @ J[3:]
        vel = pin.getFrameVelocity(model, data, contact.frame_id, pin.LOCAL_WORLD_ALIGNED).vector
        acc = pin.getFrameClassicalAcceleration(model, data, contact.frame_id, pin.LOCAL_WORLD_ALIGNED).vector
        omega = vel[3:]
        drift = acc.copy()
        drift[:3] += cross(acc[3:], r) + cross(omega, cross(omega, r))
        return J, drift, contact.wrench_map(R), R

    def build(self, contacts: list[ActiveContact], tasks: list[Task],
              disabled_pairs: set[tuple[str, str]] | frozenset = frozenset()) -> QpProblem:
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
            self._dampers = self.collision.rows(self.model, data, v, self.dt, disabled_pairs)
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
        return self._result(relaxed, self.solver.solve(relaxed))

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
        return self._result(problem, solution)

    def solve(self, contacts: list[ActiveContact], tasks: list[Task],
              disabled_pairs: set[tuple[str, str]] | frozenset = frozenset()) -> WholeBodyResult:
        problem = self.build(contacts, tasks, disabled_pairs)
        solution = self.solver.solve(problem)  # raises QpFailure
        return self._result(problem, solution)

    def _result(self, problem: QpProblem, solution: QpSolution) -> WholeBodyResult:
        x = solution.x
        qdd = x[:self.nv]
        generalized = np.zeros(self.nv)
        results: dict[str, ContactResult] = {}
        for c, sl, phi, Jc in self._contact_layout:
            wrench = phi @ x[sl]
            generalized += Jc.T @ wrench
            if c.bilateral:
                forces = np.zeros((0, 3))
                normal = float(np.linalg.norm(wrench[:3]))
            else:
                kpts, _, ng = c.generators.shape
                lam = x[sl].reshape(kpts, ng)
                forces = np.einsum("kij,kj->ki", c.generators, lam)
                normal = float(np.sum(forces * c.normals_in_world))
            results[c.limb] = ContactResult(c.limb, wrench, forces, normal)
        tau = self.data.M[6:] @ qdd + self.data.nle[6:] - generalized[6:]
        return WholeBodyResult(qdd.copy(), tau, results, solution, problem, list(self._dampers))
