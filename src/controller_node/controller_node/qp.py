"""The QP as a value, its solvers, and what happens when solving fails.

A :class:`QpProblem` is a plain value::

    minimise    1/2 x' H x + g' x
    subject to  lb <= x <= ub                     (simple bounds, one per variable)
                lower <= A x <= upper             (rows flagged ``is_eq`` have lower == upper)

built by :mod:`controller_node.wholebody` once per tick and handed to a solver. Solvers:

- :class:`DaqpSolver`: daqp called directly (dual active set, no workspace kept, a wall-time
  bound through daqp's ``time_limit``). The default.
- :class:`ProxsuiteSolver`: proxsuite dense ProxQP, warm-started from the previous tick when the
  problem keeps its dimensions (re-initialised when the contact set changes them).
- :func:`solve_with_qpsolvers`: the same problem through ``qpsolvers`` (baseline in the bench).

A failure raises :class:`QpFailure` carrying the problem; :func:`save_problem` writes it to
``.npz`` (qpsolvers' field names P q G h A b lb ub plus our own layout) and
:func:`load_problem` reads it back for replay (``scripts/bench_controller.py --replay file``).
"""
from __future__ import annotations

import pathlib
import time
from dataclasses import dataclass, field

import numpy as np

from climb_core.errors import ClimbError

#: daqp's infinity: bounds at or beyond this are free.
DAQP_INF = 1e30

#: daqp ``sense`` flags.
_SENSE_INEQUALITY = 0
_SENSE_EQUALITY = 5


@dataclass
class QpProblem:
    H: np.ndarray  # (n, n) symmetric positive definite cost matrix
    g: np.ndarray  # (n,) cost vector
    lb: np.ndarray  # (n,) variable lower bounds (-inf allowed)
    ub: np.ndarray  # (n,) variable upper bounds (+inf allowed)
    A: np.ndarray  # (m, n) constraint rows
    lower: np.ndarray  # (m,) row lower bounds
    upper: np.ndarray  # (m,) row upper bounds
    is_eq: np.ndarray  # (m,) bool: equality rows (lower == upper)
    #: (name, start, stop) of each block of variables and of constraint rows, for diagnostics.
    variable_blocks: list[tuple[str, int, int]] = field(default_factory=list)
    row_blocks: list[tuple[str, int, int]] = field(default_factory=list)

    @property
    def n(self) -> int:
        return self.H.shape[0]

    @property
    def m(self) -> int:
        return self.A.shape[0]

    def block(self, x: np.ndarray, name: str) -> np.ndarray:
        for block_name, start, stop in self.variable_blocks:
            if block_name == name:
                return x[start:stop]
        raise KeyError(name)

    def residuals(self, x: np.ndarray) -> dict[str, float]:
        """Largest violation [problem units] of the bounds, equality and inequality rows at x."""
        ax = self.A @ x if self.m else np.zeros(0)
        bound = max(0.0, float(np.max(self.lb - x, initial=0.0)), float(np.max(x - self.ub, initial=0.0)))
        eq = float(np.max(np.abs(ax - self.upper)[self.is_eq], initial=0.0))
        ineq_rows = ~self.is_eq
        ineq = max(0.0, float(np.max((self.lower - ax)[ineq_rows], initial=0.0)),
                   float(np.max((ax - self.upper)[ineq_rows], initial=0.0)))
        return {"bounds": bound, "equality": eq, "inequality": ineq}

    def to_qpsolvers(self):
        """The same problem as a ``qpsolvers.Problem`` (P q G h A b lb ub)."""
        import qpsolvers

        eq = self.is_eq
        ineq = ~eq
        A_in = self.A[ineq]
        up = self.upper[ineq]
        lo = self.lower[ineq]
        has_up = up < DAQP_INF
        has_lo = lo > -DAQP_INF
        G = np.vstack([A_in[has_up], -A_in[has_lo]])
        h = np.concatenate([up[has_up], -lo[has_lo]])
        lb = np.where(self.lb <= -DAQP_INF, -np.inf, self.lb)
        ub = np.where(self.ub >= DAQP_INF, np.inf, self.ub)
        return qpsolvers.Problem(self.H, self.g, G if len(h) else None, h if len(h) else None,
                                 self.A[eq] if eq.any() else None, self.upper[eq] if eq.any() else None,
                                 lb, ub)


@dataclass
class QpSolution:
    x: np.ndarray
    status: int  # solver exit flag (daqp: 1 optimal, 2 optimal with soft constraints violated)
    solve_time: float  # [s] wall time inside the solver call
    iterations: int
    solver: str


class QpFailure(ClimbError):
    """The solver found no solution; ``problem`` is the failing QP (save it, replay it)."""

    def __init__(self, problem: QpProblem | None, status: int, solver: str, detail: str = ""):
        self.problem = problem
        self.status = status
        self.solver = solver
        self.saved_path: pathlib.Path | None = None
        super().__init__(f"{solver} failed with status {status}" + (f": {detail}" if detail else ""))


# --------------------------------------------------------------------------------------------
class DaqpSolver:
    """daqp called directly on the stacked problem (bounds first, then rows)."""

    name = "daqp"

    def __init__(self, time_limit_s: float = 0.0, iter_limit: int = 1000):
        import daqp  # noqa: F401  (fail early with a clear ImportError)

        self._daqp = daqp
        self.time_limit_s = float(time_limit_s)  # [s] 0 = unbounded
        self.iter_limit = int(iter_limit)

    def solve(self, problem: QpProblem) -> QpSolution:
        upper = np.concatenate([problem.ub, problem.upper])
        lower = np.concatenate([problem.lb, problem.lower])
        np.clip(upper, -DAQP_INF, DAQP_INF, out=upper)
        np.clip(lower, -DAQP_INF, DAQP_INF, out=lower)
        sense = np.zeros(len(upper), dtype=np.int32)
        sense[problem.n:][problem.is_eq] = _SENSE_EQUALITY
        try:
            return self.solve_arrays(problem.H, problem.g, problem.A, upper, lower, sense)
        except QpFailure as failure:
            failure.problem = problem
            raise

    def solve_arrays(self, H: np.ndarray, g: np.ndarray, A: np.ndarray, upper: np.ndarray, lower: np.ndarray,
                     sense: np.ndarray) -> QpSolution:
        """daqp on arrays already in its layout: ``upper`` / ``lower`` hold the n variable bounds
        then the m row bounds, clipped to +-DAQP_INF; ``sense`` (n + m,) int32. The hot path of
        :class:`controller_node.wholebody.WholeBodyQP` (its workspace arrays, no copies). A failure
        raises :class:`QpFailure` with ``problem`` None (the caller attaches it)."""
        t0 = time.perf_counter()
        x, _fval, exitflag, info = self._daqp.solve(
            H, g, A, upper, lower, sense, time_limit=self.time_limit_s, iter_limit=self.iter_limit)
        elapsed = time.perf_counter() - t0
        exitflag = int(exitflag)
        x = np.asarray(x)
        if exitflag < 1 or not np.isfinite(x).all():
            raise QpFailure(None, exitflag, self.name)
        return QpSolution(x, exitflag, elapsed, int(info.get("iterations", 0)), self.name)


class ProxsuiteSolver:
    """proxsuite dense ProxQP with a workspace kept across ticks and warm start from the last x.

    FIELD_NOTES: proxsuite 0.8.0 segfaults when the warm-start setting changes between
    ``init()`` and the first ``solve()``: the setting is fixed before ``init`` and never touched.
    """

    name = "proxsuite"

    def __init__(self, time_limit_s: float = 0.0, iter_limit: int = 1000, eps_abs: float = 1e-6):
        import proxsuite

        self._proxsuite = proxsuite
        self.time_limit_s = float(time_limit_s)
        self.iter_limit = int(iter_limit)
        self.eps_abs = float(eps_abs)
        self._qp = None
        self._dims: tuple[int, int, int] | None = None

    def _split(self, problem: QpProblem):
        eq = problem.is_eq
        A_eq = problem.A[eq]
        b_eq = problem.upper[eq]
        C = problem.A[~eq]
        u = np.minimum(problem.upper[~eq], 1e20)
        lo = np.maximum(problem.lower[~eq], -1e20)
        lb = np.maximum(problem.lb, -1e20)
        ub = np.minimum(problem.ub, 1e20)
        return A_eq, b_eq, C, lo, u, lb, ub

    def solve(self, problem: QpProblem) -> QpSolution:
        dense = self._proxsuite.proxqp.dense
        A_eq, b_eq, C, lo, u, lb, ub = self._split(problem)
        dims = (problem.n, A_eq.shape[0], C.shape[0])
        t0 = time.perf_counter()
        if self._qp is None or dims != self._dims:
            qp = dense.QP(dims[0], dims[1], dims[2], True)
            qp.settings.eps_abs = self.eps_abs
            qp.settings.max_iter = self.iter_limit
            qp.settings.verbose = False
            qp.settings.initial_guess = self._proxsuite.proxqp.InitialGuess.WARM_START_WITH_PREVIOUS_RESULT
            qp.init(problem.H, problem.g, A_eq, b_eq, C, lo, u, lb, ub)
            self._qp, self._dims = qp, dims
        else:
            self._qp.update(problem.H, problem.g, A_eq, b_eq, C, lo, u, lb, ub)
        self._qp.solve()
        elapsed = time.perf_counter() - t0
        results = self._qp.results
        status = results.info.status
        ok = status == self._proxsuite.proxqp.QPSolverOutput.PROXQP_SOLVED
        solution = QpSolution(np.array(results.x), 1 if ok else -int(status.value) - 1, elapsed,
                              int(results.info.iter), self.name)
        if not ok or not np.all(np.isfinite(solution.x)):
            self._qp = None  # never warm-start from a failed solve
            raise QpFailure(problem, solution.status, self.name, str(status))
        return solution


def make_solver(name: str, time_limit_s: float = 0.0, iter_limit: int = 1000):
    if name == "daqp":
        return DaqpSolver(time_limit_s, iter_limit)
    if name == "proxsuite":
        return ProxsuiteSolver(time_limit_s, iter_limit)
    raise ValueError(f"unknown QP solver {name!r}")


def solve_with_qpsolvers(problem: QpProblem, solver: str = "proxqp") -> QpSolution:
    """Baseline: the same QP through qpsolvers' generic interface (no warm start, no workspace)."""
    import qpsolvers

    t0 = time.perf_counter()
    qps_problem = problem.to_qpsolvers()
    result = qpsolvers.solve_problem(qps_problem, solver=solver)
    elapsed = time.perf_counter() - t0
    if not result.found or result.x is None:
        raise QpFailure(problem, -1, f"qpsolvers/{solver}")
    return QpSolution(np.asarray(result.x), 1, elapsed, 0, f"qpsolvers/{solver}")


# --------------------------------------------------------------------------------------------
def save_problem(problem: QpProblem, path: str | pathlib.Path, **metadata: object) -> pathlib.Path:
    """Write the problem to ``path`` (.npz) with qpsolvers' field names and our row layout."""
    path = pathlib.Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    qps = problem.to_qpsolvers()
    empty = np.zeros((0, problem.n))
    np.savez_compressed(
        path, H=problem.H, g=problem.g, lb_x=problem.lb, ub_x=problem.ub, A_rows=problem.A,
        lower=problem.lower, upper=problem.upper, is_eq=problem.is_eq,
        variable_blocks=np.array([f"{n}:{a}:{b}" for n, a, b in problem.variable_blocks]),
        row_blocks=np.array([f"{n}:{a}:{b}" for n, a, b in problem.row_blocks]),
        P=qps.P, q=qps.q, G=qps.G if qps.G is not None else empty,
        h=qps.h if qps.h is not None else np.zeros(0),
        A=qps.A if qps.A is not None else empty, b=qps.b if qps.b is not None else np.zeros(0),
        lb=qps.lb, ub=qps.ub,
        metadata=np.array([f"{k}={v}" for k, v in metadata.items()]))
    return path


def _blocks(array: np.ndarray) -> list[tuple[str, int, int]]:
    out = []
    for item in array:
        name, start, stop = str(item).rsplit(":", 2)
        out.append((name, int(start), int(stop)))
    return out


def load_problem(path: str | pathlib.Path) -> QpProblem:
    with np.load(path, allow_pickle=False) as data:
        return QpProblem(H=data["H"], g=data["g"], lb=data["lb_x"], ub=data["ub_x"], A=data["A_rows"],
                         lower=data["lower"], upper=data["upper"], is_eq=data["is_eq"].astype(bool),
                         variable_blocks=_blocks(data["variable_blocks"]),
                         row_blocks=_blocks(data["row_blocks"]))


def load_metadata(path: str | pathlib.Path) -> dict[str, str]:
    with np.load(path, allow_pickle=False) as data:
        return dict(str(item).split("=", 1) for item in data["metadata"])
