"""Quasi-static feasibility of a configuration at a stance (ladder_climbing_drc_hubo.txt, III-A).

A configuration q is feasible at a stance iff

1. contact: every hold's robot surface is on its hold within ``contact_position_tolerance`` /
   ``contact_angle_tolerance_deg``: flat sole corners on the hold points; a sole on a rung with
   the 2 rung points on the sole (on its plane, inside its polygon); a grasp centre on the hold
   centre with the grasp axis along the rung; the sole normals against the hold normals;
2. joint limits: q within the model's position limits;
3. collision-free: signed distances on the convex hulls >= ``collision_margin`` (environment and
   self pairs, :mod:`climb_core.collision`; a limb is not checked against the surface it holds);
4. quasi-static equilibrium: point contact forces f exist with

       g(q) - J_ext^T F_ext = S^T tau + J_c^T f          (pin.computeGeneralizedGravity, point Jacobians)
       the 6 base rows:  J_c,base^T f = g_base           (no actuation on the free flyer)
       tau = g_act - J_c,act^T f,   |tau_j| <= effort_j  ("torque_limit:<joint>")
       unilateral points: f in the friction pyramid of the hold's mu   ("friction")
       grasps (bilateral, no cone): |sum of the hold's forces| <= grip strength  ("grip_limit:<limb>")

The force problem is a small QP over the point forces only (tau is affine in f) plus one load
ratio r: minimise r + eps |f|^2 subject to |tau_j| <= r effort_j, |F_grasp . d| <= r grip,
0 <= r <= 1. Its optimum is the least achievable max(torque ratio, grip ratio); 1 - r is the
load margin. Solved with daqp called directly (a HiGHS LP through scipy is the measured
baseline, ``solver: highs``). When it is infeasible, relaxed problems name the broken
constraints: torque and grip limits relaxed one at a time, then the friction cones replaced by
bare unilateral constraints ("friction" if that helps, "equilibrium" if not).

Grip polytope: the total grasp force is bounded along 13 directions (3 axes, 6 face and 4 body
diagonals of a cube; both signs): exact for forces along those directions, at most 13 % over the grip
strength in between. Each grasp point's force components are also boxed by the grip strength
(this bounds the squeeze forces, hence the moment a grasp can carry); with ``grasp_moment_limit``
each world-axis component of the moment about the grasp centre is capped too (the points' boxes
alone let a grasp carry tens of N m). The grip ratio of a grasp is the largest of these.
"""
from __future__ import annotations

import dataclasses
import math
import pathlib
import time
from collections import OrderedDict
from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np
import pinocchio as pin

from . import collision as collision_mod
from . import holds as holds_mod
from .contact import Stance
from .errors import SpecError
from .params import group, load_params, param

NODE_NAME = "feasibility"


# --------------------------------------------------------------------------------------------
# configuration (config/feasibility.yaml, ROS params layout, node name "feasibility")


@dataclass(frozen=True)
class CheckParams:
    contact_position_tolerance: float = param(0.01, unit="m", min=0.0, description=(
        "max distance between a hold and where the limb's surface actually is"))
    contact_angle_tolerance_deg: float = param(5.0, unit="deg", min=0.0, description=(
        "max angle between the hold's and the limb surface's normal / grasp axis"))
    joint_limit_tolerance: float = param(1.0e-6, unit="rad", min=0.0, description=(
        "slack on the URDF position limits"))
    collision_margin: float = param(0.0, unit="m", description=(
        "min signed distance between hulls (negative = allowed penetration)"))
    check_collision: bool = param(True, unit="-", description="include the collision check")
    friction_pyramid_sides: int = param(4, unit="-", min=3, max=16, description=(
        "sides of the pyramid inscribed in each point's friction cone"))
    friction_margin: float = param(1.0, unit="-", min=0.0, max=1.0, description=(
        "the cones use margin * mu"))
    min_normal_force: float = param(0.0, unit="N", min=0.0, description=(
        "lower bound of each unilateral point's normal force"))
    sole_cop_margin: float = param(0.0, unit="m", min=0.0, max=0.05, description=(
        "the statics of a flat sole count its corners this far inside the sole's edges (along the sole's "
        "length and width): the centre of pressure the stance needs stays that far from the edges, where "
        "tracking errors and the motion's dynamics push it"))
    torque_limit_fraction: float = param(1.0, unit="-", min=0.0, description=(
        "share of the URDF effort limits the stance may use"))
    grip_limit_fraction: float = param(1.0, unit="-", min=0.0, description=(
        "share of each grasp's grip_force_limit the stance may use"))
    grasp_moment_limit: float = param(0.0, unit="N m", min=0.0, description=(
        "cap on each world-axis component of a grasp's moment about its centre, scaled like the grip "
        "(0: none beyond the points' boxes, which let 8 points 4 cm apart carry ~30 N m: a squeeze no "
        "hand gives; the controller caps its grasp wrench per axis, contacts.grasp_torque_limit)"))
    load_ratio_weight: float = param(1.0, unit="-", min=0.0, description=(
        "cost weight of the load ratio r (max of torque and grip ratios)"))
    force_regularization: float = param(1.0e-7, unit="1/N^2", min=1.0e-12, description=(
        "cost weight of 0.5 |f|^2 (makes the QP strictly convex)"))
    ratio_regularization: float = param(1.0e-6, unit="-", min=1.0e-12, description=(
        "cost weight of 0.5 r^2"))
    max_diagnosis_ratio: float = param(1000.0, unit="-", min=1.0, description=(
        "upper bound of the load ratio in the relaxed (diagnosis) problems"))
    ratio_tolerance: float = param(1.0e-6, unit="-", min=0.0, description=(
        "a torque / grip ratio counts as violated above 1 + this"))
    unbounded_force: float = param(1.0e5, unit="N", min=1.0, description=(
        "box on unilateral point forces (numerical bound, never active)"))
    solver: str = param("daqp", unit="-", choices=("daqp", "highs"), description=(
        "daqp (QP, called directly) | highs (scipy linprog, LP without the regularisation)"))
    solver_iter_limit: int = param(1000, unit="-", min=1, description="daqp active-set iterations")


@dataclass(frozen=True)
class FeasibilityConfig:
    check: CheckParams = group(CheckParams, "quasi-static feasibility check")
    holds: holds_mod.HoldParams = group(holds_mod.HoldParams, "hold geometry")
    collision: collision_mod.CollisionParams = group(collision_mod.CollisionParams, "distance queries")


def default_config_path() -> pathlib.Path:
    from .ros_env import project_root

    return project_root() / "config" / "feasibility.yaml"


_CONFIG_CACHE: dict[str, Any] = {}


def load_config(path: str | pathlib.Path | None = None) -> FeasibilityConfig:
    """The ``feasibility`` section of config/feasibility.yaml (or ``path``), cached."""
    p = str(path or default_config_path())
    if p not in _CONFIG_CACHE:
        _CONFIG_CACHE[p] = load_params(p, FeasibilityConfig, NODE_NAME)
    return _CONFIG_CACHE[p]


# --------------------------------------------------------------------------------------------
# result


@dataclass
class FeasibilityResult:
    feasible: bool
    violated: list[str]  # contact, joint_limits, collision, equilibrium, friction, torque_limit:<joint>, grip_limit:<limb>
    contact_forces: dict[str, np.ndarray]  # limb -> (n, 3) force of the environment on the robot at each hold point [N], world
    joint_torques: np.ndarray  # (nv - 6,) actuated joint torques [N m] (NaN when no force solution)
    most_loaded_joint: str
    most_loaded_ratio: float  # |tau| / effort limit of that joint [-]
    grip_ratios: dict[str, float]  # limb -> total grasp force / grip_force_limit [-] (13-direction polytope)
    load_ratio: float  # max(torque ratios, grip ratios) of the force solution [-] (inf when none)
    min_distance: float  # [m] smallest hull distance (inf when not checked)
    closest_pair: tuple[str, str]
    contact_error: float  # [m] worst hold position error
    contact_angle_error: float  # [rad] worst hold orientation error
    joint_limit_violation: float  # [rad] worst excursion beyond a position limit (0 inside)
    solve_time_s: float  # [s] force problem time (all solves)
    n_solves: int
    details: dict[str, Any] = field(default_factory=dict)

    @property
    def torque_margin(self) -> float:
        """1 - max |tau_j| / effort_j [-] (negative when a torque limit is exceeded)."""
        return 1.0 - self.most_loaded_ratio

    @property
    def margins(self) -> dict[str, float]:
        return {"min_distance_m": self.min_distance, "torque_margin": self.torque_margin,
                "load_margin": 1.0 - self.load_ratio, "contact_error_m": self.contact_error,
                "contact_angle_error_rad": self.contact_angle_error}

    def summary(self) -> str:
        state = "feasible" if self.feasible else "infeasible: " + ", ".join(self.violated)
        return (f"{state}; most loaded {self.most_loaded_joint} {self.most_loaded_ratio:.2f}; load ratio "
                f"{self.load_ratio:.2f}; min distance {self.min_distance * 1e3:.1f} mm; contact error "
                f"{self.contact_error * 1e3:.1f} mm")


# --------------------------------------------------------------------------------------------
# compiled stance: everything that depends on the stance only (not on q)


@dataclass
class _CompiledStance:
    stance: Stance
    limbs: list[str]
    frame_ids: list[int]
    points: list[np.ndarray]  # per hold (n_i, 3) world
    offsets: list[int]  # first force variable of each hold
    n_forces: int  # 3 * number of points
    targets: list[holds_mod.HoldTarget]
    kinds: list[str]
    A_static: np.ndarray  # friction + grip rows (without the r column)
    r_static: np.ndarray  # r coefficient of each static row
    upper_static: np.ndarray
    lower_static: np.ndarray
    row_kind: list[str]  # per static row: "friction" | "normal" | "grip:<limb>"
    friction_rows: np.ndarray  # bool mask over the static rows
    normal_rows: np.ndarray
    grip_rows: np.ndarray
    grip_dirs_per_hold: dict[str, tuple[int, float]]  # limb -> (first force index, grip limit [N])
    grip_moments: dict[str, tuple[np.ndarray, float]]  # limb -> (3 x 3k moment rows over its forces, cap [N m])
    force_lower: np.ndarray  # simple bounds of the force variables
    force_upper: np.ndarray
    contacts: list[tuple[str, str]]  # (limb, env surface) pairs for the collision exclusion
    sole_vertices: list[np.ndarray | None]  # per hold: sole corners in the surface frame [m]
    contact_refs: list[tuple]  # per hold: (T_frame_surface, kind, reference data) for contact_errors
    H: np.ndarray  # QP cost Hessian (diagonal regularisation)
    c: np.ndarray  # QP cost vector (load ratio weight)
    layouts: dict = field(default_factory=dict)
    env: Any = None
    cfg: Any = None


def _grip_directions() -> np.ndarray:
    """13 unit directions (3 axes, 6 face and 4 body diagonals of a cube): |d . F| <= G along each
    bounds the grasp force norm by G (at most 13 % above G in between). Shared with the
    controller's QP (controller_node.constraints)."""
    dirs = [np.eye(3)[i] for i in range(3)]
    for i, j in ((0, 1), (0, 2), (1, 2)):
        for s in (1.0, -1.0):
            d = np.zeros(3)
            d[i], d[j] = 1.0, s
            dirs.append(d / math.sqrt(2.0))
    for sy in (1.0, -1.0):
        for sz in (1.0, -1.0):
            dirs.append(np.array([1.0, sy, sz]) / math.sqrt(3.0))
    return np.array(dirs)


GRIP_DIRECTIONS = _grip_directions()  # (13, 3) unit vectors; each row bounds +-d . F


def tangent_basis(normal: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(t1, t2): the tangent axes of a contact normal that orient every friction pyramid, the
    planner's here and the controller's generators (controller_node.constraints), so both use
    the same pyramid."""
    n = np.asarray(normal, dtype=float) / np.linalg.norm(normal)
    helper = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    t1 = np.cross(n, helper)
    t1 /= np.linalg.norm(t1)
    return t1, np.cross(n, t1)


def _inset_sole_points(P: np.ndarray, R_world_sole: np.ndarray, margin: float) -> np.ndarray:
    """A flat sole's corner points moved ``margin`` toward their centre along the sole's length
    and width (R_world_sole: its surface axes): the statics' support polygon, shrunk."""
    c = P.mean(axis=0)
    local = (P - c) @ R_world_sole
    local[:, :2] = np.sign(local[:, :2]) * np.maximum(np.abs(local[:, :2]) - margin, 0.0)
    return c + local @ R_world_sole.T


def _compile(robot: Any, env: Any, stance: Stance, cfg: FeasibilityConfig) -> _CompiledStance:
    if not isinstance(stance, Stance):
        raise SpecError("stance", f"must be a climb_core.contact.Stance, got {type(stance).__name__}")
    p = cfg.check
    limbs, fids, pts, offsets, targets, kinds, contacts = [], [], [], [], [], [], []
    off = 0
    for hold in stance.holds:
        rs = holds_mod.hold_surface(robot, hold)
        if len(hold.points) == 0:
            raise SpecError(f"stance.{hold.limb}.points", "a hold needs at least one contact point")
        if hold.bilateral and rs.kind != "grasp":
            raise SpecError(f"stance.{hold.limb}.bilateral", f"{rs.name} is a {rs.kind}: unilateral, it cannot pull")
        limbs.append(hold.limb)
        fids.append(robot.frame_id(rs.frame))
        offsets.append(off)
        off += 3 * len(hold.points)
        if env is not None:
            targets.append(holds_mod.hold_target(robot, env, hold, params=cfg.holds))
            kinds.append(targets[-1].kind)
            contacts.append((hold.limb, hold.env_surface))
        else:
            targets.append(None)
            kinds.append("grasp" if hold.bilateral else f"{rs.kind}_flat")
        if kinds[-1] == "sole_flat" and p.sole_cop_margin > 0.0 and targets[-1] is not None:
            pts.append(_inset_sole_points(hold.positions, targets[-1].T_world_surface[:3, :3], p.sole_cop_margin))
        else:
            pts.append(hold.positions)
    nf = off
    rows, rcoef, up, lo, kind = [], [], [], [], []
    f_lo = np.full(nf, -p.unbounded_force)
    f_hi = np.full(nf, p.unbounded_force)
    m = p.friction_pyramid_sides
    grip_info, grip_moments = {}, {}
    for hold, o in zip(stance.holds, offsets):
        if hold.bilateral:
            G = p.grip_limit_fraction * float(hold.grip_force_limit)
            if not (math.isfinite(G) and G >= 0.0):
                raise SpecError(f"stance.{hold.limb}.grip_force_limit", f"must be a finite force >= 0 [N], got {G}")
            k = len(hold.points)
            f_lo[o:o + 3 * k] = -G
            f_hi[o:o + 3 * k] = G
            for d in GRIP_DIRECTIONS:
                row = np.zeros(nf)
                row[o:o + 3 * k] = np.tile(d, k)
                # d . F - G r <= 0 and -d . F - G r <= 0, as one two-sided row is impossible with r;
                rows.append(row); rcoef.append(-G); up.append(0.0); lo.append(-np.inf); kind.append(f"grip:{hold.limb}")
                rows.append(-row); rcoef.append(-G); up.append(0.0); lo.append(-np.inf); kind.append(f"grip:{hold.limb}")
            grip_info[hold.limb] = (o, G, k)
            M = p.grip_limit_fraction * p.grasp_moment_limit
            if M > 0.0:  # m . e_a = sum_i f_i . (e_a x (p_i - c)), about the grasp centre
                arms = hold.positions - np.asarray(hold.centre, dtype=float)
                moment = np.zeros((3, 3 * k))
                for a, e in enumerate(np.eye(3)):
                    moment[a] = np.cross(e, arms).reshape(-1)
                for sign in (1.0, -1.0):
                    for a in range(3):
                        row = np.zeros(nf)
                        row[o:o + 3 * k] = sign * moment[a]
                        rows.append(row); rcoef.append(-M); up.append(0.0); lo.append(-np.inf)
                        kind.append(f"grip:{hold.limb}")
                grip_moments[hold.limb] = (moment, M)
            continue
        mu = p.friction_margin * float(hold.friction)
        if not (math.isfinite(mu) and mu >= 0.0):
            raise SpecError(f"stance.{hold.limb}.friction", f"must be a finite coefficient >= 0, got {hold.friction}")
        mu_in = mu * math.cos(math.pi / m)
        for i, cp in enumerate(hold.points):
            n = cp.normal
            if not np.isfinite(n).all() or abs(np.linalg.norm(n) - 1.0) > 1e-6:
                raise SpecError(f"stance.{hold.limb}.points[{i}].normal", "must be a unit vector")
            t1, t2 = tangent_basis(n)
            col = o + 3 * i
            for j in range(m):
                ang = 2.0 * math.pi * j / m
                d = math.cos(ang) * t1 + math.sin(ang) * t2
                row = np.zeros(nf)
                row[col:col + 3] = d - mu_in * n
                rows.append(row); rcoef.append(0.0); up.append(0.0); lo.append(-np.inf); kind.append("friction")
            row = np.zeros(nf)
            row[col:col + 3] = n
            rows.append(row); rcoef.append(0.0); up.append(p.unbounded_force); lo.append(p.min_normal_force)
            kind.append("normal")
    A = np.array(rows).reshape(-1, nf)
    kinds_arr = np.array(kind, dtype=object)
    soles = [holds_mod.sole_vertices_in_surface(holds_mod.hold_surface(robot, h)) if k.endswith("_flat") else None
             for h, k in zip(stance.holds, kinds)]
    refs = []
    for hold, hkind, target, sole in zip(stance.holds, kinds, targets, soles):
        rs = holds_mod.hold_surface(robot, hold)
        sign = holds_mod.polygon_normal_sign(robot, hold.limb, rs) if hkind != "grasp" else 1.0
        T_fs = np.array(rs.T_frame_surface, dtype=float)
        if hkind == "grasp":
            a = np.asarray(env.surfaces[hold.env_surface].T_world_surface, dtype=float)[:3, 0].copy() \
                if env is not None else np.zeros(3)
            refs.append((T_fs, hkind, (holds_mod.grasp_axis_in_surface(rs), a, hold.centre)))
        elif hkind.endswith("_flat"):  # a sole or a palm polygon
            # the polygon's z points out of the robot (sign +1) or into the foot (-1): out = -hold normal
            out_normal = -sign * hold.points[0].normal
            refs.append((T_fs, "polygon_flat", (sole, hold.positions, out_normal)))
        else:  # the rung line must lie under the sole, anywhere along the foot
            poly = holds_mod.sole_vertices_in_surface(rs)[:, :2]
            edges = np.roll(poly, -1, axis=0) - poly
            normals = np.column_stack([edges[:, 1], -edges[:, 0]])
            normals /= np.linalg.norm(normals, axis=1)[:, None]
            edge_offsets = np.einsum("ij,ij->i", normals, poly)
            centroid = poly.mean(axis=0)
            flip = np.where(normals @ centroid - edge_offsets > 0.0, -1.0, 1.0)  # outward normals
            out_normal = -sign * hold.points[0].normal
            refs.append((T_fs, hkind, (hold.positions, normals * flip[:, None], edge_offsets * flip, out_normal)))
    H = np.full(nf + 1, p.force_regularization)
    H[-1] = p.ratio_regularization
    c = np.zeros(nf + 1)
    c[-1] = p.load_ratio_weight
    return _CompiledStance(
        stance=stance, limbs=limbs, frame_ids=fids, points=pts, offsets=offsets, n_forces=nf, targets=targets,
        kinds=kinds, A_static=A, r_static=np.array(rcoef), upper_static=np.array(up), lower_static=np.array(lo),
        row_kind=kind, friction_rows=kinds_arr == "friction", normal_rows=kinds_arr == "normal",
        grip_rows=np.array([k.startswith("grip:") for k in kind], dtype=bool), grip_dirs_per_hold=grip_info,
        grip_moments=grip_moments,
        force_lower=f_lo, force_upper=f_hi, contacts=contacts, sole_vertices=soles, contact_refs=refs, H=np.diag(H),
        c=c)


# --------------------------------------------------------------------------------------------
# workspace per robot (own pin.Data) and the stance cache


class _Workspace:
    def __init__(self, robot: Any):
        self.robot = robot
        self.model: pin.Model = robot.model
        self.data = robot.model.createData()
        self.effort = np.asarray(robot.effort_limits(), dtype=float)
        self.joint_names = list(robot.joint_names)
        self.lower = self.model.lowerPositionLimit.copy()
        self.upper = self.model.upperPositionLimit.copy()
        self.stances: OrderedDict[tuple, _CompiledStance] = OrderedDict()
        self._cfg_by_id: dict[int, tuple[FeasibilityConfig, int]] = {}
        self._cfg_by_value: dict[FeasibilityConfig, int] = {}

    def compiled(self, env: Any, stance: Stance, cfg: FeasibilityConfig) -> _CompiledStance:
        """The compiled form of ``stance`` (cached). The key is the identity of its holds (frozen
        dataclasses, shared between the many Stance objects a planner builds from them) and the
        value of ``cfg`` (callers derive equal configs with ``with_check`` again and again)."""
        if not isinstance(stance, Stance):
            raise SpecError("stance", f"must be a climb_core.contact.Stance, got {type(stance).__name__}")
        cfg_key = self._config_key(cfg)
        holds = stance.holds
        key = (tuple(map(id, holds)), id(env), cfg_key)
        hit = self.stances.get(key)
        if hit is not None and hit.env is env and all(a is b for a, b in zip(hit.stance.holds, holds)):
            self.stances.move_to_end(key)
            return hit
        c = _compile(self.robot, env, stance, cfg)
        c.env, c.cfg = env, cfg  # held (with the stance's holds) so that their ids stay unique while cached
        self.stances[key] = c
        if len(self.stances) > 512:
            self.stances.popitem(last=False)
        return c

    def _config_key(self, cfg: FeasibilityConfig) -> int:
        """A small integer per distinct config value (equal frozen dataclasses share it)."""
        hit = self._cfg_by_id.get(id(cfg))
        if hit is not None and hit[0] is cfg:
            return hit[1]
        k = self._cfg_by_value.setdefault(cfg, len(self._cfg_by_value))
        if len(self._cfg_by_id) > 1024:
            self._cfg_by_id.clear()
        self._cfg_by_id[id(cfg)] = (cfg, k)  # the object is held so that its id is not reused
        return k


_WORKSPACES: dict[int, _Workspace] = {}


def workspace(robot: Any) -> _Workspace:
    """The robot's feasibility workspace (its own pin.Data, compiled-stance cache), one per robot
    model; public for the planner, which builds its force rows on the same compiled stances."""
    ws = _WORKSPACES.get(id(robot))
    if ws is None or ws.robot is not robot:
        ws = _Workspace(robot)
        _WORKSPACES[id(robot)] = ws
    return ws


# --------------------------------------------------------------------------------------------
# the force problem, built as a value and solved separately


@dataclass
class ForceProblem:
    """min 0.5 x'Hx + c'x  s.t.  lower <= x <= upper (first n entries), lower <= A x <= upper.

    x = [f (3 k point forces, world frame [N]), r (load ratio [-])]. ``eq_rows`` are equalities.
    """

    H: np.ndarray
    c: np.ndarray
    A: np.ndarray
    lower: np.ndarray  # simple bounds (n) then rows (m)
    upper: np.ndarray
    sense: np.ndarray  # daqp sense flags (0 inequality, 5 equality), simple bounds first
    n_forces: int
    n_eq: int
    n_torque_rows: int  # torque rows follow the equalities: 2 per actuated joint
    tags: dict[str, Any] = field(default_factory=dict)

    def save(self, path: str | pathlib.Path) -> None:
        np.savez(path, H=self.H, c=self.c, A=self.A, lower=self.lower, upper=self.upper, sense=self.sense,
                 n_forces=self.n_forces, n_eq=self.n_eq, n_torque_rows=self.n_torque_rows)


@dataclass
class ForceSolution:
    ok: bool
    x: np.ndarray | None
    exitflag: int
    solve_time_s: float


def contact_jacobians(ws: _Workspace, cs: _CompiledStance, q: np.ndarray) -> np.ndarray:
    """(3 k, nv) Jacobian of every hold point (attached to its limb frame), world axes.
    Needs computeJointJacobians(q) done."""
    model, data = ws.model, ws.data
    out = np.empty((cs.n_forces, model.nv))
    row = 0
    for fid, P in zip(cs.frame_ids, cs.points):
        pin.updateFramePlacement(model, data, fid)
        J6 = pin.getFrameJacobian(model, data, fid, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)
        r = P - data.oMf[fid].translation
        # v_point = v_origin + w x (p - o)
        wx, wy, wz = J6[3], J6[4], J6[5]
        rx, ry, rz = r[:, 0:1], r[:, 1:2], r[:, 2:3]
        k = len(P)
        block = out[row:row + 3 * k].reshape(k, 3, -1)
        block[:, 0] = J6[0] + wy * rz - wz * ry
        block[:, 1] = J6[1] + wz * rx - wx * rz
        block[:, 2] = J6[2] + wx * ry - wy * rx
        row += 3 * k
    return out


def external_generalized_force(ws: _Workspace, external: Sequence[tuple[str, np.ndarray, np.ndarray]]
                               ) -> np.ndarray:
    """Sum of J_p^T F for external forces (frame name, point in world [m], force in world [N]).
    Needs computeJointJacobians(q) done."""
    out = np.zeros(ws.model.nv)
    for frame, point, force in external:
        fid = ws.robot.frame_id(frame)
        pin.updateFramePlacement(ws.model, ws.data, fid)
        J6 = pin.getFrameJacobian(ws.model, ws.data, fid, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)
        r = np.asarray(point, dtype=float) - ws.data.oMf[fid].translation
        Jp = J6[:3] + np.cross(J6[3:].T, r).T
        out += Jp.T @ np.asarray(force, dtype=float)
    return out


@dataclass
class _Layout:
    """Row layout of one variant of the force problem: static parts filled once per stance."""

    A: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    sense: np.ndarray
    n_torque_rows: int


def _layout(ws: _Workspace, cs: _CompiledStance, p: CheckParams, torque_mode: str, grip_mode: str,
            friction: bool, r_max: float) -> _Layout:
    key = (torque_mode, grip_mode, friction, r_max)
    hit = cs.layouts.get(key)
    if hit is not None:
        return hit
    nf = cs.n_forces
    n = nf + 1
    na = len(ws.effort)
    L = p.torque_limit_fraction * ws.effort
    keep = np.ones(len(cs.row_kind), dtype=bool)
    if not friction:
        keep &= ~cs.friction_rows
    if grip_mode == "off":
        keep &= ~cs.grip_rows
    A_s = cs.A_static[keep]
    r_s = cs.r_static[keep].copy()
    up_s = cs.upper_static[keep].copy()
    if grip_mode == "hard":
        gm = cs.grip_rows[keep]
        up_s[gm] = -r_s[gm]  # d.F <= G
        r_s[gm] = 0.0
    n_torque = {"ratio": 2 * na, "hard": na, "off": 0}[torque_mode]
    m = 6 + n_torque + len(A_s)
    A = np.zeros((m, n))
    lower = np.full(n + m, -np.inf)
    upper = np.full(n + m, np.inf)
    sense = np.zeros(n + m, dtype=np.int32)
    lower[:nf], upper[:nf] = cs.force_lower, cs.force_upper
    if grip_mode != "hard":  # the per-point box of a grasp scales like its total (r G), or goes
        for o, G, k in cs.grip_dirs_per_hold.values():
            box = p.unbounded_force if grip_mode == "off" else r_max * G
            lower[o:o + 3 * k], upper[o:o + 3 * k] = -box, box
    lower[nf], upper[nf] = 0.0, r_max
    sense[n:n + 6] = 5  # base equilibrium rows are equalities
    if torque_mode == "ratio":
        A[6:6 + na, -1] = -L
        A[6 + na:6 + 2 * na, -1] = -L
    s0 = 6 + n_torque
    A[s0:, :nf] = A_s
    A[s0:, -1] = r_s
    lower[n + s0:] = cs.lower_static[keep]
    upper[n + s0:] = up_s
    lay = _Layout(A, lower, upper, sense, n_torque)
    cs.layouts[key] = lay
    return lay


def build_force_problem(ws: _Workspace, cs: _CompiledStance, g: np.ndarray, Jc: np.ndarray, p: CheckParams, *,
                        torque_mode: str = "ratio", grip_mode: str = "ratio", friction: bool = True,
                        r_max: float = 1.0) -> ForceProblem:
    """The QP of the module docstring. torque_mode / grip_mode: "ratio" (bounded by r L) | "hard"
    (bounded by L) | "off"; friction False keeps only the unilateral normal rows."""
    lay = _layout(ws, cs, p, torque_mode, grip_mode, friction, r_max)
    nf = cs.n_forces
    n = nf + 1
    na = len(ws.effort)
    A = lay.A.copy()
    lower = lay.lower.copy()
    upper = lay.upper.copy()
    JcT = Jc.T
    A[:6, :nf] = JcT[:6]
    lower[n:n + 6] = g[:6]
    upper[n:n + 6] = g[:6]
    g_a = g[6:]
    if torque_mode == "ratio":  # tau = g_a - JaT f:  -JaT f - r L <= -g_a,  JaT f - r L <= g_a
        A[6:6 + na, :nf] = -JcT[6:]
        A[6 + na:6 + 2 * na, :nf] = JcT[6:]
        upper[n + 6:n + 6 + na] = -g_a
        upper[n + 6 + na:n + 6 + 2 * na] = g_a
    elif torque_mode == "hard":
        L = p.torque_limit_fraction * ws.effort
        A[6:6 + na, :nf] = JcT[6:]
        lower[n + 6:n + 6 + na] = g_a - L
        upper[n + 6:n + 6 + na] = g_a + L
    return ForceProblem(H=cs.H, c=cs.c, A=A, lower=lower, upper=upper, sense=lay.sense, n_forces=nf, n_eq=6,
                        n_torque_rows=lay.n_torque_rows,
                        tags={"torque_mode": torque_mode, "grip_mode": grip_mode, "friction": friction})


def solve_force_problem(problem: ForceProblem, p: CheckParams, solver: str | None = None) -> ForceSolution:
    solver = solver or p.solver
    t0 = time.perf_counter()
    if solver == "daqp":
        import daqp

        x, _, exitflag, _ = daqp.solve(problem.H, problem.c, problem.A, problem.upper, problem.lower,
                                       problem.sense, iter_limit=p.solver_iter_limit)
        ok = exitflag >= 1
        return ForceSolution(ok, np.asarray(x) if ok else None, int(exitflag), time.perf_counter() - t0)
    if solver == "highs":
        from scipy.optimize import linprog

        n = len(problem.c)
        m_eq = problem.n_eq
        A = problem.A
        lo_r, up_r = problem.lower[n:], problem.upper[n:]
        A_eq, b_eq = A[:m_eq], up_r[:m_eq]
        ub_rows, ub_b = [], []
        for Ai, li, ui in zip(A[m_eq:], lo_r[m_eq:], up_r[m_eq:]):
            if np.isfinite(ui):
                ub_rows.append(Ai); ub_b.append(ui)
            if np.isfinite(li):
                ub_rows.append(-Ai); ub_b.append(-li)
        bounds = list(zip(problem.lower[:n], problem.upper[:n]))
        res = linprog(problem.c, A_ub=np.array(ub_rows), b_ub=np.array(ub_b), A_eq=A_eq, b_eq=b_eq,
                      bounds=bounds, method="highs")
        ok = res.status == 0
        return ForceSolution(ok, np.asarray(res.x) if ok else None, int(res.status), time.perf_counter() - t0)
    raise SpecError("feasibility.check.solver", f"must be daqp or highs, got {solver!r}")


# --------------------------------------------------------------------------------------------
# contact error


def contact_errors(ws: _Workspace, env: Any, cs: _CompiledStance) -> tuple[float, float, list[tuple[str, float, float]]]:
    """(worst position error [m], worst angle error [rad], per limb (limb, pos, angle)); oMf of
    the limb frames already updated."""
    worst_p = worst_a = 0.0
    per = []
    oMf = ws.data.oMf
    for limb, fid, (T_fs, kind, ref) in zip(cs.limbs, cs.frame_ids, cs.contact_refs):
        T_ws = oMf[fid].homogeneous @ T_fs
        R, p = T_ws[:3, :3], T_ws[:3, 3]
        if kind == "grasp":  # ref: (grasp axis in the surface frame, rung axis, hold centre)
            axis_s, a, centre = ref
            d = p - centre
            pos = math.sqrt(float(d @ d))
            ang = math.acos(min(1.0, abs(float((R @ axis_s) @ a))))  # the grasp may hold either way round
        elif kind == "polygon_flat":  # ref: (sole / palm corners in the surface frame, hold points, normal out)
            sole, points, out_normal = ref
            d = sole @ R.T + p - points
            pos = math.sqrt(float(np.max(np.einsum("ij,ij->i", d, d))))
            ang = math.acos(min(1.0, max(-1.0, float(R[:, 2] @ out_normal))))
        else:  # sole on a cylinder; ref: (hold points, sole edge normals / offsets in the surface frame, normal out)
            points, edge_n, edge_c, out_normal = ref
            local = (points - p) @ R  # hold points in the sole surface frame
            outside = np.maximum((local[:, :2] @ edge_n.T - edge_c).max(axis=1), 0.0)
            pos = math.sqrt(float(np.max(local[:, 2] ** 2 + outside ** 2)))  # off the sole plane / polygon
            ang = math.acos(min(1.0, max(-1.0, float(R[:, 2] @ out_normal))))
        per.append((limb, pos, ang))
        worst_p, worst_a = max(worst_p, pos), max(worst_a, ang)
    return worst_p, worst_a, per


# --------------------------------------------------------------------------------------------
# the check


def check(robot: Any, env: Any, q: np.ndarray, stance: Stance, settings: FeasibilityConfig | None = None, *,
          external_forces: Sequence[tuple[str, np.ndarray, np.ndarray]] = (), collision: bool | None = None,
          contact: bool = True) -> FeasibilityResult:
    """Quasi-static feasibility of ``q`` at ``stance`` (see the module docstring).

    external_forces: (robot frame, application point [m] world, force [N] world) pushing the
    robot (a carried load, a push). collision / contact: override the config's collision switch,
    skip the contact-placement check (equilibrium of the holds as given).
    """
    cfg = settings or load_config()
    p = cfg.check
    ws = workspace(robot)
    q = np.asarray(q, dtype=float)
    if q.shape != (ws.model.nq,) or not np.isfinite(q).all():
        raise SpecError("q", f"must be {ws.model.nq} finite numbers, got shape {q.shape}")
    cs = ws.compiled(env, stance, cfg)
    violated: list[str] = []
    details: dict[str, Any] = {}
    model, data = ws.model, ws.data

    # kinematics + dynamics terms
    pin.computeJointJacobians(model, data, q)
    g = pin.computeGeneralizedGravity(model, data, q).copy()
    Jc = contact_jacobians(ws, cs, q)
    if external_forces:
        g -= external_generalized_force(ws, external_forces)

    # 1. contacts
    c_pos = c_ang = 0.0
    if contact and env is not None:
        c_pos, c_ang, per = contact_errors(ws, env, cs)
        details["contact_errors"] = per
        if c_pos > p.contact_position_tolerance or c_ang > math.radians(p.contact_angle_tolerance_deg):
            violated.append("contact")

    # 2. joint limits (actuated joints; the free flyer has none)
    over = np.maximum(ws.lower[7:] - q[7:], q[7:] - ws.upper[7:])
    jl = float(max(0.0, over.max())) if len(over) else 0.0
    if jl > p.joint_limit_tolerance:
        violated.append("joint_limits")
        details["joint_limits"] = [ws.joint_names[i] for i in np.flatnonzero(over > p.joint_limit_tolerance)]

    # 3. collision
    min_d, pair = float("inf"), ("", "")
    do_collision = p.check_collision if collision is None else collision
    if do_collision and env is not None:
        chk = collision_mod.checker(robot, env, cfg.collision)
        rep = chk.distances(q, contacts=cs.contacts, threshold=p.collision_margin)
        min_d, pair = rep.min_distance, rep.pair
        if min_d < p.collision_margin:
            violated.append("collision")
            details["collisions"] = rep.below

    # 4. forces
    force_violations, sol, n_solves, solve_time = _equilibrium(ws, cs, g, Jc, p)
    violated.extend(force_violations)
    return _result(ws, cs, g, Jc, sol, violated, details, p, min_d, pair, c_pos, c_ang, jl, n_solves, solve_time)


def check_equilibrium(robot: Any, q: np.ndarray, stance: Stance, settings: FeasibilityConfig | None = None, *,
                      env: Any = None, external_forces: Sequence[tuple[str, np.ndarray, np.ndarray]] = ()
                      ) -> FeasibilityResult:
    """Only the force problem (item 4): no contact, joint-limit or collision check."""
    return check(robot, env, q, stance, settings, external_forces=external_forces, collision=False, contact=False)


def _equilibrium(ws: _Workspace, cs: _CompiledStance, g: np.ndarray, Jc: np.ndarray, p: CheckParams
                 ) -> tuple[list[str], ForceSolution | None, int, float]:
    prob = build_force_problem(ws, cs, g, Jc, p)
    sol = solve_force_problem(prob, p)
    t = sol.solve_time_s
    if sol.ok:
        return [], sol, 1, t
    # diagnosis: relax the load limits
    R = p.max_diagnosis_ratio
    relaxed = solve_force_problem(build_force_problem(ws, cs, g, Jc, p, r_max=R), p)
    n, t = 2, t + relaxed.solve_time_s
    if relaxed.ok:
        out: list[str] = []
        by_torque = solve_force_problem(build_force_problem(ws, cs, g, Jc, p, grip_mode="hard", r_max=R), p)
        by_grip = solve_force_problem(build_force_problem(ws, cs, g, Jc, p, torque_mode="hard", r_max=R), p)
        n, t = n + 2, t + by_torque.solve_time_s + by_grip.solve_time_s
        if by_torque.ok:
            out += _torque_violations(ws, cs, g, Jc, by_torque.x, p)
        if by_grip.ok:
            out += _grip_violations(cs, by_grip.x, p)
        if not out:  # only the two together: name both from the coupled solution
            out = _torque_violations(ws, cs, g, Jc, relaxed.x, p) + _grip_violations(cs, relaxed.x, p)
        return out or ["equilibrium"], relaxed, n, t
    no_friction = solve_force_problem(build_force_problem(ws, cs, g, Jc, p, friction=False, r_max=R), p)
    n, t = n + 1, t + no_friction.solve_time_s
    if no_friction.ok:
        return ["friction"], no_friction, n, t
    return ["equilibrium"], None, n, t


def _torques(ws: _Workspace, g: np.ndarray, Jc: np.ndarray, x: np.ndarray, nf: int) -> np.ndarray:
    return g[6:] - Jc[:, 6:].T @ x[:nf]


def _torque_violations(ws: _Workspace, cs: _CompiledStance, g: np.ndarray, Jc: np.ndarray, x: np.ndarray,
                       p: CheckParams) -> list[str]:
    ratio = np.abs(_torques(ws, g, Jc, x, cs.n_forces)) / (p.torque_limit_fraction * ws.effort)
    return [f"torque_limit:{ws.joint_names[i]}" for i in np.flatnonzero(ratio > 1.0 + p.ratio_tolerance)]


def _grip_ratios(cs: _CompiledStance, x: np.ndarray, per_point: bool = False) -> dict[str, float]:
    """limb -> total grasp force (13-direction polytope) / grip limit; with ``per_point`` the
    largest point force component counts too (the squeeze that carries moments)."""
    out = {}
    for limb, (o, G, k) in cs.grip_dirs_per_hold.items():
        f = x[o:o + 3 * k]
        F = f.reshape(k, 3).sum(axis=0)
        load = float(np.max(np.abs(GRIP_DIRECTIONS @ F)))
        if per_point:
            load = max(load, float(np.max(np.abs(f))))
        out[limb] = load / G if G > 0 else (0.0 if load < 1e-9 else np.inf)
        if limb in cs.grip_moments:  # the moment about the grasp centre against its cap
            moment, M = cs.grip_moments[limb]
            out[limb] = max(out[limb], float(np.max(np.abs(moment @ f))) / M)
    return out


def _grip_violations(cs: _CompiledStance, x: np.ndarray, p: CheckParams) -> list[str]:
    return [f"grip_limit:{limb}" for limb, r in _grip_ratios(cs, x, per_point=True).items()
            if r > 1.0 + p.ratio_tolerance]


def _result(ws: _Workspace, cs: _CompiledStance, g: np.ndarray, Jc: np.ndarray, sol: ForceSolution | None,
            violated: list[str], details: dict, p: CheckParams, min_d: float, pair: tuple[str, str],
            c_pos: float, c_ang: float, jl: float, n_solves: int, solve_time: float) -> FeasibilityResult:
    na = len(ws.effort)
    if sol is not None and sol.ok:
        x = sol.x
        tau = _torques(ws, g, Jc, x, cs.n_forces)
        ratio = np.abs(tau) / (p.torque_limit_fraction * ws.effort)
        k = int(np.argmax(ratio))
        forces = {limb: x[o:o + 3 * len(P)].reshape(-1, 3).copy()
                  for limb, o, P in zip(cs.limbs, cs.offsets, cs.points)}
        grips = _grip_ratios(cs, x)
        load = max([float(ratio.max())] + list(grips.values()))
        most, most_ratio = ws.joint_names[k], float(ratio[k])
        details["load_ratio_variable"] = float(x[-1])
    else:
        tau = np.full(na, np.nan)
        forces = {limb: np.full((len(P), 3), np.nan) for limb, P in zip(cs.limbs, cs.points)}
        grips = {limb: float("nan") for limb in cs.grip_dirs_per_hold}
        load, most, most_ratio = float("inf"), "", float("inf")
    return FeasibilityResult(
        feasible=not violated, violated=violated, contact_forces=forces, joint_torques=tau,
        most_loaded_joint=most, most_loaded_ratio=most_ratio, grip_ratios=grips, load_ratio=load,
        min_distance=min_d, closest_pair=pair, contact_error=c_pos, contact_angle_error=c_ang,
        joint_limit_violation=jl, solve_time_s=solve_time, n_solves=n_solves, details=details)


def total_contact_force(result: FeasibilityResult) -> np.ndarray:
    """Sum of all contact forces [N], world."""
    return sum((f.sum(axis=0) for f in result.contact_forces.values()), np.zeros(3))


def tighter_moment_limit(a: float, b: float) -> float:
    """The tighter of two grasp_moment_limit values (0 means none)."""
    return min(x for x in (a, b) if x > 0.0) if a > 0.0 or b > 0.0 else 0.0


def with_check(cfg: FeasibilityConfig, **changes: Any) -> FeasibilityConfig:
    """A copy of ``cfg`` with some CheckParams fields changed (tests, tools)."""
    return dataclasses.replace(cfg, check=dataclasses.replace(cfg.check, **changes))
