"""Contact-projection IK: bring the limbs of a stance onto their holds (configuration only).

:func:`solve` runs damped least squares (Gauss-Newton with Levenberg damping) on the contact
constraints, one 6D pose error per limb (``pin.log6`` of target^-1 * current, in the limb's
contact surface frame, with ``pin.Jlog6``); a grasp leaves the rotation about its cylinder axis
free (5 rows). Each step is a small box-constrained QP solved by daqp: the joint position
limits and a step bound are the boxes, a posture regulariser (toward ``posture`` or the seed) and
an optional centre-of-mass target are soft tasks. When the seed does not converge, the solver
restarts from seeds perturbed with a deterministic RNG, each restart perturbed more than the
last (``restarts``, ``restart_step``).

The planner extends this (collision avoidance, physics constraints); keep it a plain function.
"""
from __future__ import annotations

import contextlib
import math
import pathlib
from collections import OrderedDict
from dataclasses import dataclass, field
from typing import Any, Iterator, Mapping

import numpy as np
import pinocchio as pin

from . import holds as holds_mod
from .contact import Hold, Stance
from .errors import SpecError
from .params import load_params, param

NODE_NAME = "ik"


@dataclass(frozen=True)
class IKParams:
    max_iterations: int = param(60, unit="-", min=1, description=(
        "Gauss-Newton iterations per attempt and phase (with the posture / CoM pull, then contacts only)"))
    position_tolerance: float = param(1.0e-4, unit="m", min=0.0, description=(
        "success when every contact position error is below this"))
    angle_tolerance: float = param(1.0e-3, unit="rad", min=0.0, description=(
        "success when every contact orientation error is below this"))
    orientation_weight: float = param(0.3, unit="m/rad", min=0.0, description=(
        "scale of the angular rows against the position rows"))
    damping: float = param(1.0e-4, unit="m^2", min=0.0, description="Levenberg damping of |dq|^2")
    posture_weight: float = param(1.0e-3, unit="m^2/rad^2", min=0.0, description=(
        "weight of the posture regulariser (actuated joints toward the posture)"))
    posture_fade_residual: float = param(0.01, unit="m", min=1.0e-9, description=(
        "the posture weight scales with min(1, contact residual / this), so that the contacts "
        "converge exactly"))
    com_weight: float = param(1.0, unit="-", min=0.0, description="weight of the CoM task against the contacts")
    com_tolerance: float = param(1.0e-3, unit="m", min=0.0, description=(
        "with a CoM target, an attempt continues until the CoM is this close (soft: success "
        "only needs the contacts)"))
    step_limit: float = param(0.3, unit="rad", min=0.0, description=(
        "bound on each joint's change per iteration (base: the same number in m and rad)"))
    joint_limit_margin: float = param(1.0e-3, unit="rad", min=0.0, description=(
        "kept away from the URDF position limits"))
    restarts: int = param(10, unit="-", min=0, description="perturbed restarts after the seed fails")
    restart_step: float = param(0.1, unit="rad", min=0.0, description=(
        "std dev of the joint perturbation grows by this at each restart"))
    restart_base_step: float = param(0.02, unit="m", min=0.0, description=(
        "std dev of the base position perturbation grows by this at each restart"))
    rng_seed: int = param(0, unit="-", min=0, description="seed of the restart perturbations")
    stall_ratio: float = param(0.999, unit="-", min=0.0, max=1.0, description=(
        "an attempt stops when the residual drops by less than this factor over 5 iterations"))


def default_config_path() -> pathlib.Path:
    from .ros_env import project_root

    return project_root() / "config" / "feasibility.yaml"


_CACHE: dict[str, IKParams] = {}


def load_ik_params(path: str | pathlib.Path | None = None) -> IKParams:
    """The ``ik`` section of config/feasibility.yaml (or ``path``), cached."""
    p = str(path or default_config_path())
    if p not in _CACHE:
        _CACHE[p] = load_params(p, IKParams, NODE_NAME)
    return _CACHE[p]


@dataclass
class IKResult:
    q: np.ndarray  # (nq,) configuration
    success: bool
    residual: float  # [m] worst contact position error (angles scaled by orientation_weight)
    position_error: float  # [m] worst contact position error
    angle_error: float  # [rad] worst contact orientation error (free grasp roll excluded)
    iterations: int  # total over attempts
    attempts: int  # 1 + restarts used
    per_limb: dict[str, tuple[float, float]] = field(default_factory=dict)  # limb -> (pos [m], angle [rad])
    com_error: float = 0.0  # [m] distance of the CoM (its targeted coordinates) from com_target

    def __iter__(self) -> Iterator[Any]:
        """Unpacks as (q, success, residual)."""
        return iter((self.q, self.success, self.residual))


@dataclass
class ContactTask:
    """One hold as an IK task: put the limb's contact surface on ``target`` along the selected
    error rows (a grasp leaves its roll about the rung free). Public: the planner's
    physics-constrained IK (planner_node.pcik) builds on these."""

    limb: str
    frame_id: int
    T_frame_surface: pin.SE3
    target: pin.SE3  # T_world_surface target
    rows: np.ndarray  # (k, 6) selection of the 6D error rows (linear, angular), in the surface frame
    # derived once (task_errors): action matrix frame -> surface, and the row weights for a w_ang
    _X_surface_frame: np.ndarray | None = field(default=None, init=False, repr=False, compare=False)
    _weights: tuple[float, np.ndarray] | None = field(default=None, init=False, repr=False, compare=False)


_DATA_POOL: dict[int, tuple[pin.Model, list[pin.Data]]] = {}


@contextlib.contextmanager
def scratch_data(model: pin.Model) -> Iterator[pin.Data]:
    """A pin.Data of ``model`` borrowed from a pool (createData costs ~0.25 ms for G1); every
    algorithm run on it recomputes what it reads, so a borrowed Data gives what a new one does."""
    entry = _DATA_POOL.get(id(model))
    if entry is None or entry[0] is not model:
        entry = (model, [])
        _DATA_POOL[id(model)] = entry
    free = entry[1]
    data = free.pop() if free else model.createData()
    try:
        yield data
    finally:
        free.append(data)


def contact_tasks(robot: Any, env: Any, q_seed: np.ndarray, targets: Stance | Mapping[str, Any],
                  hold_params: holds_mod.HoldParams | None) -> list[ContactTask]:
    """The :class:`ContactTask` of every hold of ``targets`` (a Stance, or limb -> hold / hold spec),
    hold targets resolved from ``q_seed`` (which grasp axis direction, which sole side)."""
    with scratch_data(robot.model) as data:
        pin.framesForwardKinematics(robot.model, data, q_seed)
        return _contact_tasks(robot, env, data, targets, hold_params)


def _contact_tasks(robot: Any, env: Any, data: pin.Data, targets: Stance | Mapping[str, Any],
                   hold_params: holds_mod.HoldParams | None) -> list[ContactTask]:
    items: list[tuple[str, Any]] = (list((h.limb, h) for h in targets.holds) if isinstance(targets, Stance)
                                    else list(targets.items()))
    out = []
    for limb, spec in items:
        # the surface the hold is made with (a hand's grasp or palm); a bare pose: the primary one
        if isinstance(spec, Hold):
            rs = holds_mod.hold_surface(robot, spec)
        else:
            rs = holds_mod.limb_surface(robot, limb, getattr(spec, "robot_surface", None) or None)
        fid = robot.frame_id(rs.frame)
        T_fs = np.asarray(rs.T_frame_surface)
        # a full pose target: a latched grasp (its roll about the rung fixed) or a bare 4x4
        pose = (np.asarray(spec.pose, dtype=float) if isinstance(spec, Hold) and spec.pose is not None
                else spec if isinstance(spec, np.ndarray) and spec.shape == (4, 4) else None)
        if isinstance(spec, holds_mod.HoldTarget):
            ht = spec
        elif pose is not None:
            ht = holds_mod.HoldTarget(limb, rs.frame, pose, holds_mod.frame_pose_from_surface(robot, limb, pose, rs.name),
                                      None, "pose", rs.name)
        else:
            if env is None:
                raise SpecError("ik.targets", "holds need the environment they are on")
            ht = _cached_foot_target(robot, env, spec, hold_params)
            if ht is None:
                seed_R = (data.oMf[fid].homogeneous @ T_fs)[:3, :3]
                ht = holds_mod.hold_target(robot, env, spec, params=hold_params, R_world_surface_seed=seed_R)
        rows = np.eye(6)
        if ht.free_axis_in_surface is not None:
            a = np.asarray(ht.free_axis_in_surface, dtype=float)
            helper = np.array([1.0, 0.0, 0.0]) if abs(a[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
            b1 = np.cross(a, helper)
            b1 /= np.linalg.norm(b1)
            b2 = np.cross(a, b1)
            rows = np.zeros((5, 6))
            rows[:3, :3] = np.eye(3)
            rows[3, 3:] = b1
            rows[4, 3:] = b2
        out.append(ContactTask(limb, fid, pin.SE3(T_fs), pin.SE3(np.asarray(ht.T_world_surface)), rows))
    return out


_FOOT_TARGETS: OrderedDict[tuple, tuple[Any, Any, Any, holds_mod.HoldTarget | None]] = OrderedDict()


def _cached_foot_target(robot: Any, env: Any, hold: Any, hold_params: holds_mod.HoldParams | None
                        ) -> holds_mod.HoldTarget | None:
    """hold_target of a foot hold (sole on a tread, a plane or a rung), cached per hold object:
    it does not depend on the seed configuration. None for a grasp (its axis direction follows the
    seed) and for anything that is not a climb_core Hold."""
    if not isinstance(hold, Hold):
        return None
    key = (id(hold), id(env), id(robot), hold_params)
    hit = _FOOT_TARGETS.get(key)
    if hit is not None and hit[0] is hold and hit[1] is env and hit[2] is robot:
        _FOOT_TARGETS.move_to_end(key)
        return hit[3]
    kind = holds_mod.hold_kind(robot, env, hold)
    ht = None if kind == "grasp" else holds_mod.hold_target(robot, env, hold, params=hold_params)
    _FOOT_TARGETS[key] = (hold, env, robot, ht)  # held so that the ids stay unique while cached
    if len(_FOOT_TARGETS) > 2048:
        _FOOT_TARGETS.popitem(last=False)
    return ht


def task_errors(model: pin.Model, data: pin.Data, tasks: list[ContactTask], w_ang: float, with_jacobian: bool
                ) -> tuple[np.ndarray, np.ndarray | None, list[tuple[float, float]]]:
    """Stacked task errors (angular rows weighted by ``w_ang``), their Jacobian when asked, and per
    task (position error [m], angle error [rad]); ``data`` must hold the configuration's joint
    placements (and Jacobians for ``with_jacobian``)."""
    errs, jacs, per = [], [], []
    norm = np.linalg.norm
    for t in tasks:
        pin.updateFramePlacement(model, data, t.frame_id)
        M = data.oMf[t.frame_id] * t.T_frame_surface
        M_err = t.target.actInv(M)
        e6 = pin.log6(M_err).vector
        sel = t.rows @ e6
        per.append((float(norm(sel[:3])), float(norm(sel[3:]))))
        w = t._weights
        if w is None or w[0] != w_ang:
            W = np.ones(len(t.rows))
            W[3:] = w_ang
            t._weights = w = (w_ang, W)
        W = w[1]
        errs.append(W * sel)
        if with_jacobian:
            X = t._X_surface_frame
            if X is None:
                X = t._X_surface_frame = t.T_frame_surface.inverse().toActionMatrix()
            J_frame = pin.getFrameJacobian(model, data, t.frame_id, pin.ReferenceFrame.LOCAL)
            J_surf = X @ J_frame
            jacs.append(W[:, None] * (t.rows @ (pin.Jlog6(M_err) @ J_surf)))
    e = np.concatenate(errs) if errs else np.zeros(0)
    J = np.vstack(jacs) if with_jacobian and jacs else None
    return e, J, per


def solve(robot: Any, env: Any, q_seed: np.ndarray, targets: Stance | Mapping[str, Any], *,
          posture: np.ndarray | None = None, com_target: np.ndarray | None = None,
          params: IKParams | None = None, hold_params: holds_mod.HoldParams | None = None) -> IKResult:
    """Configuration putting every limb of ``targets`` on its hold.

    targets: a Stance (its holds), or limb -> Hold | holds.HoldTarget | 4x4 T_world_surface (of the
    limb's primary surface; a hold or a HoldTarget names its own robot surface).
    posture: (nq,) configuration whose actuated joints regularise the solution (default q_seed).
    com_target: (2,) world x, y or (3,) x, y, z of the centre of mass [m] (soft task).
    """
    params = params or load_ik_params()
    model: pin.Model = robot.model
    q_seed = np.asarray(q_seed, dtype=float).copy()
    if q_seed.shape != (model.nq,) or not np.isfinite(q_seed).all():
        raise SpecError("ik.q_seed", f"must be {model.nq} finite numbers, got shape {q_seed.shape}")
    q_seed[3:7] /= np.linalg.norm(q_seed[3:7])
    posture = q_seed.copy() if posture is None else np.asarray(posture, dtype=float)
    if posture.shape != (model.nq,):
        raise SpecError("ik.posture", f"must be {model.nq} numbers")
    if com_target is not None:
        com_target = np.asarray(com_target, dtype=float).reshape(-1)
        if com_target.shape not in ((2,), (3,)) or not np.isfinite(com_target).all():
            raise SpecError("ik.com_target", "must be 2 (x, y) or 3 (x, y, z) finite numbers [m]")
    tasks = contact_tasks(robot, env, q_seed, targets, hold_params)
    rng = np.random.default_rng(params.rng_seed)
    lo = model.lowerPositionLimit[7:] + params.joint_limit_margin
    hi = model.upperPositionLimit[7:] - params.joint_limit_margin
    best: IKResult | None = None
    total_iters = 0
    for attempt in range(params.restarts + 1):
        if attempt == 0:
            q0 = q_seed.copy()
        else:
            q0 = q_seed.copy()
            q0[7:] += rng.normal(0.0, attempt * params.restart_step, model.nq - 7)
            q0[:3] += rng.normal(0.0, attempt * params.restart_base_step, 3)
        q0[7:] = np.clip(q0[7:], lo, hi)
        res = _attempt(robot, q0, tasks, posture, com_target, params, lo, hi)
        total_iters += res.iterations
        res.attempts = attempt + 1
        if best is None or (res.success, -res.residual) > (best.success, -best.residual):
            best = res
        if res.success:
            break
    assert best is not None
    best.iterations = total_iters
    best.attempts = attempt + 1
    return best


def _attempt(robot: Any, q: np.ndarray, tasks: list[ContactTask], posture: np.ndarray, com_target: np.ndarray | None,
             params: IKParams, lo: np.ndarray, hi: np.ndarray) -> IKResult:
    with scratch_data(robot.model) as data:
        return _attempt_on(robot, data, q, tasks, posture, com_target, params, lo, hi)


def _attempt_on(robot: Any, data: pin.Data, q: np.ndarray, tasks: list[ContactTask], posture: np.ndarray,
                com_target: np.ndarray | None, params: IKParams, lo: np.ndarray, hi: np.ndarray) -> IKResult:
    import daqp

    model: pin.Model = robot.model
    nv = model.nv
    w_ang = params.orientation_weight
    history: list[float] = []
    it = 0
    polish = False  # after a stall: contacts only (no posture / CoM pull) to converge exactly
    com_err = 0.0
    for it in range(1, 2 * params.max_iterations + 1):
        pin.computeJointJacobians(model, data, q)
        e, J, per = task_errors(model, data, tasks, w_ang, with_jacobian=True)
        pos = max((p for p, _ in per), default=0.0)
        ang = max((a for _, a in per), default=0.0)
        if com_target is not None:
            com = pin.centerOfMass(model, data, q, False)
            Jcom = pin.jacobianCenterOfMass(model, data, q, False)
            k = len(com_target)
            ec = com[:k] - com_target
            com_err = float(np.linalg.norm(ec))
        contacts_ok = pos <= params.position_tolerance and ang <= params.angle_tolerance
        if contacts_ok and com_err <= params.com_tolerance:
            return _result(q, True, per, tasks, w_ang, it - 1, com_err)
        resid = float(np.linalg.norm(e)) + math.sqrt(params.com_weight) * com_err
        history.append(resid)
        stalled = len(history) > 5 and history[-1] > params.stall_ratio * history[-6]
        if stalled or it == params.max_iterations:
            if polish:
                break
            polish, history = True, []
        fade = 0.0 if polish else min(1.0, resid / params.posture_fade_residual)
        P = np.zeros(nv)
        P[6:] = params.posture_weight * fade
        H = J.T @ J + (params.damping + 1e-9) * np.eye(nv) + np.diag(P)
        f = J.T @ e
        diff = pin.difference(model, q, posture)
        f -= P * diff
        if com_target is not None:
            H += params.com_weight * Jcom[:k].T @ Jcom[:k]
            f += params.com_weight * Jcom[:k].T @ ec
        step = params.step_limit
        upper = np.full(nv, step)
        lower = np.full(nv, -step)
        upper[6:] = np.minimum(step, hi - q[7:])
        lower[6:] = np.maximum(-step, lo - q[7:])
        lower = np.minimum(lower, upper)
        dq, _, flag, _ = daqp.solve(H, f, np.zeros((0, nv)), upper, lower, np.zeros(nv, dtype=np.int32))
        if flag < 1:
            dq = np.clip(-np.linalg.solve(H, f), lower, upper)
        q = pin.integrate(model, q, np.asarray(dq))
    pin.computeJointJacobians(model, data, q)
    _, _, per = task_errors(model, data, tasks, w_ang, with_jacobian=False)
    pos = max((p for p, _ in per), default=0.0)
    ang = max((a for _, a in per), default=0.0)
    if com_target is not None:
        com_err = float(np.linalg.norm(pin.centerOfMass(model, data, q, False)[:len(com_target)] - com_target))
    ok = pos <= params.position_tolerance and ang <= params.angle_tolerance
    return _result(q, ok, per, tasks, w_ang, it, com_err)


def _result(q: np.ndarray, ok: bool, per: list[tuple[float, float]], tasks: list[ContactTask], w_ang: float,
            iterations: int, com_error: float = 0.0) -> IKResult:
    pos = max((p for p, _ in per), default=0.0)
    ang = max((a for _, a in per), default=0.0)
    return IKResult(q=q.copy(), success=ok, residual=max(pos, w_ang * ang), position_error=pos, angle_error=ang,
                    iterations=iterations, attempts=1, per_limb={t.limb: pe for t, pe in zip(tasks, per)},
                    com_error=com_error)


def contact_residual(robot: Any, env: Any, q: np.ndarray, targets: Stance | Mapping[str, Any],
                     params: IKParams | None = None) -> tuple[float, float]:
    """(worst position error [m], worst angle error [rad]) of the contact tasks at q."""
    params = params or load_ik_params()
    tasks = contact_tasks(robot, env, q, targets, None)
    with scratch_data(robot.model) as data:
        pin.forwardKinematics(robot.model, data, q)
        _, _, per = task_errors(robot.model, data, tasks, params.orientation_weight, with_jacobian=False)
    return max((p for p, _ in per), default=0.0), max((a for _, a in per), default=0.0)

