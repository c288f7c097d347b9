"""Model predictive control of the magnetic state S = (D, I) (eq. 13-38), solved as a QP.

Model (eq. 13-15): ``S(k+1) = A S(k) + B(k) U(k)`` with ``A = I_2`` and ``B(k) = G(k) T``.
Over a horizon N (eq. 16-22) the stacked prediction is ``S_bar = M S(k) + C(k) U_bar`` and the
cost (eq. 23-28) is ``|S_bar - S_bar_d|^2_Qbar + |U_bar|^2_Rbar`` with ``Qbar = diag(Q..Q, F)``.
As a QP in U_bar (eq. 36-38):

    H = 2 (C^T Qbar C + Rbar),   h = 2 C^T Qbar (M S - S_bar_d)

Eq. 38 as printed drops the factor 2 that eq. 37 keeps; with that pair the optimum input is
half the true minimiser of eq. 28. We use the consistent pair (the minimiser of eq. 28 is
what the tests check against a brute-force cost).

Constraints (eq. 29-34): ``U_min <= U <= U_max`` and ``S_min <= M S + C U <= S_max``, written
for the solver as ``l <= [I; C] U_bar <= u``, which is eq. 33-34's ``W U_bar <= w``. A state S
beyond the box makes eq. 34 infeasible for every U (the vehicle cannot be back inside at once);
with ``admit_state`` (the default) the box is widened to S on that side for the step,
``min(S_min, S) <= M S + C U <= max(S_max, S)``, so zero input is always feasible and the optimum
may bring the state back, never farther out. Inside the box nothing changes.

This module is unit-agnostic: callers pass B, S, bounds and weights in whatever units they
chose (``companion.nav.mission`` documents its choice). Backends: OSQP (default), set up
once with a fixed sparsity pattern and updated in place each step with warm start; and
daqp, an exact dense active-set solver. Both return the same answer to well under 1e-4.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

__all__ = ["SOLVERS", "MpcController", "MpcSettings", "MpcSolution", "prediction_matrices", "qp_cost"]

SOLVERS = ("osqp", "daqp")


@dataclass(frozen=True)
class MpcSettings:
    """Weights, bounds and backend, all in the caller's units.

    ``q``, ``f``, ``r``: diagonals of Q, F, R. Bounds are per step and repeat over the horizon
    (eq. 31); use +-inf for no bound.
    """

    horizon: int = 2
    q: tuple[float, float] = (1.0, 1.0)
    f: tuple[float, float] = (1.0, 1.0)
    r: tuple[float, float] = (10.0, 10.0)
    u_lower: tuple[float, float] = (-1.0, -1.0)
    u_upper: tuple[float, float] = (1.0, 1.0)
    s_lower: tuple[float, float] = (-math.inf, -math.inf)
    s_upper: tuple[float, float] = (math.inf, math.inf)
    solver: str = "osqp"
    eps: float = 1e-9
    admit_state: bool = True    # widen S's bounds to a current state beyond them (module docstring)


@dataclass(frozen=True)
class MpcSolution:
    """The optimal input sequence; ``u_first`` is u*(k), the move to apply now."""

    u_first: np.ndarray
    u_all: np.ndarray
    ok: bool
    status: str
    solve_time_s: float  # as the solver reports it (not our clock)
    iterations: int


def prediction_matrices(b: np.ndarray, horizon: int, a: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """M (2N x 2) and C (2N x 2N) of eq. 20-22 for a constant B over the horizon."""
    a = np.eye(2) if a is None else np.asarray(a, dtype=float)
    powers = [np.eye(2)]
    for _ in range(horizon):
        powers.append(a @ powers[-1])
    m = np.vstack(powers[1:])
    c = np.zeros((2 * horizon, 2 * horizon))
    for row in range(horizon):
        for col in range(row + 1):
            c[2 * row:2 * row + 2, 2 * col:2 * col + 2] = powers[row - col] @ b
    return m, c


def qp_cost(m: np.ndarray, c: np.ndarray, s: np.ndarray, s_ref: np.ndarray,
            q: np.ndarray, f: np.ndarray, r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """H and h of eq. 37-38 (consistent factor 2) for stacked reference ``s_ref`` (2N)."""
    horizon = c.shape[0] // 2
    q_bar = np.diag(np.concatenate([np.tile(q, horizon - 1), f]))
    r_bar = np.diag(np.tile(r, horizon))
    hess = 2.0 * (c.T @ q_bar @ c + r_bar)
    grad = 2.0 * c.T @ q_bar @ (m @ s - s_ref)
    return 0.5 * (hess + hess.T), grad


class _OsqpBackend:
    """OSQP with a structural sparsity pattern fixed at set-up; values updated in place.

    Building CSC from a dense matrix drops zeros, so a B with a zero entry would change the
    pattern between steps; we build the pattern explicitly (dense upper triangle of P;
    identity plus the block-lower-triangular C in A) and keep explicit zeros.
    """

    def __init__(self, n: int, eps: float) -> None:
        import osqp

        self.n = n
        # P: upper triangle, column-major
        self.p_rows = np.concatenate([np.arange(j + 1) for j in range(n)])
        self.p_cols = np.concatenate([np.full(j + 1, j) for j in range(n)])
        p_ptr = np.concatenate([[0], np.cumsum(np.arange(1, n + 1))])
        # A = [I_n; C], C block-lower-triangular in 2x2 blocks
        rows, cols, ptr = [], [], [0]
        for j in range(n):
            block = j // 2
            col_rows = [j] + [n + i for i in range(2 * block, n)]
            rows += col_rows
            cols += [j] * len(col_rows)
            ptr.append(len(rows))
        self.a_rows, self.a_cols = np.array(rows), np.array(cols)
        # the same entries as flat indices of the dense (n x n) P and (2n x n) A: one take each
        self._p_flat, self._a_flat = self.p_rows * n + self.p_cols, self.a_rows * n + self.a_cols
        p0 = sp.csc_matrix((np.ones(len(self.p_rows)), self.p_rows, p_ptr), shape=(n, n))
        a0 = sp.csc_matrix((np.ones(len(self.a_rows)), self.a_rows, np.array(ptr)), shape=(2 * n, n))
        self.solver = osqp.OSQP()
        self.solver.setup(p0, np.zeros(n), a0, -np.ones(2 * n), np.ones(2 * n), verbose=False,
                          warm_starting=True, polishing=False, eps_abs=eps, eps_rel=eps,
                          max_iter=20000, scaling=10)
        # The compiled solver object behind osqp's Python wrapper (osqp >= 1.0). The wrapper's
        # update() and solve() cost ~5x OSQP's own time for this 4-variable problem (its bound
        # clipping, a derivative cache, an info namespace built per call); nothing of that is
        # needed here (our bounds are within OSQP's infinity, no derivatives), so the same
        # calls go straight to the compiled object when it has them, else through the wrapper.
        ext = getattr(self.solver, "_solver", None)
        needed = ("update_data_vec", "update_data_mat", "solve", "info", "solution")
        self._ext = ext if ext is not None and all(hasattr(ext, name) for name in needed) else None

    def _solve_once(self) -> tuple[np.ndarray, str, float, int]:
        if self._ext is None:
            result = self.solver.solve(raise_error=False)
            return result.x, str(result.info.status), float(result.info.run_time), int(result.info.iter)
        self._ext.solve()
        info = self._ext.info
        return self._ext.solution.x, str(info.status), float(info.run_time), int(info.iter)

    def solve(self, hess, grad, a_full, lower, upper):
        """``lower``, ``upper`` within OSQP's infinity (1e30): the controller clips its bounds to
        +-1e20 (the wrapper's own clipping is not needed)."""
        px, ax = hess.take(self._p_flat), a_full.take(self._a_flat)
        if self._ext is None:
            self.solver.update(Px=px, Ax=ax, q=grad, l=lower, u=upper)
        else:
            self._ext.update_data_vec(q=grad, l=lower, u=upper)
            self._ext.update_data_mat(P_x=px, P_i=None, A_x=ax, A_i=None)
        x, status, run_time, iterations = self._solve_once()
        if status != "solved":
            # a warm start from a very different previous problem can stall ("solved inaccurate"
            # after 0 iterations): retry once from zero before calling it a failure
            self.solver.warm_start(x=np.zeros(self.n), y=np.zeros(2 * self.n))
            x, status, more_time, more_iterations = self._solve_once()
            run_time, iterations = run_time + more_time, iterations + more_iterations
        return x, status == "solved", status, run_time, iterations


class _DaqpBackend:
    """daqp: exact dense active-set QP; warm-started from the previous active set."""

    def __init__(self, n: int, eps: float) -> None:
        import daqp

        self.daqp = daqp
        self.n = n
        self.sense = np.zeros(2 * n, dtype=np.int32)

    def solve(self, hess, grad, a_full, lower, upper):
        # the first n rows of a_full are the identity: daqp takes them as simple bounds
        x, _, exitflag, info = self.daqp.solve(hess, grad, np.ascontiguousarray(a_full[self.n:]),
                                               upper, lower, self.sense)
        ok = exitflag == 1
        return np.asarray(x), ok, f"daqp exitflag {exitflag}", float(info["solve_time"]), int(info["iterations"])


class MpcController:
    """One QP per control step; the problem shape is fixed at construction.

    The decision variables are scaled internally so their magnitude is about one, which keeps
    the solver's absolute tolerance meaningful whatever units the caller uses.
    """

    def __init__(self, settings: MpcSettings) -> None:
        if settings.solver not in SOLVERS:
            raise ValueError(f"unknown QP solver {settings.solver!r}; choose from {SOLVERS}")
        if settings.horizon < 1:
            raise ValueError("horizon must be at least 1")
        self.settings = settings
        n = 2 * settings.horizon
        self.n = n
        self.q = np.asarray(settings.q, dtype=float)
        self.f = np.asarray(settings.f, dtype=float)
        self.r = np.asarray(settings.r, dtype=float)
        self.u_lower = np.tile(settings.u_lower, settings.horizon).astype(float)
        self.u_upper = np.tile(settings.u_upper, settings.horizon).astype(float)
        self.s_lower = np.tile(settings.s_lower, settings.horizon).astype(float)
        self.s_upper = np.tile(settings.s_upper, settings.horizon).astype(float)
        self.backend = (_OsqpBackend if settings.solver == "osqp" else _DaqpBackend)(n, settings.eps)
        # OSQP is first-order: on a badly conditioned B it can stop at "solved inaccurate";
        # the exact active-set solver then answers instead of failing the step
        self._fallback = _DaqpBackend(n, settings.eps) if settings.solver == "osqp" else None
        # A = I (eq. 14): M stacks identities and C(k) repeats B(k) in its lower block triangle;
        # everything but B is fixed, so the arrays are built once and filled in place per step.
        self._block_rows, self._block_cols = np.tril_indices(settings.horizon)
        self._c = np.zeros((n, n))
        # (block row, block column, 2, 2) view of C
        self._c_blocks = self._c.reshape(settings.horizon, 2, settings.horizon, 2).transpose(0, 2, 1, 3)
        self._q_bar = np.concatenate([np.tile(self.q, settings.horizon - 1), self.f])
        self._r_bar2 = 2.0 * np.tile(self.r, settings.horizon)
        self._stack = np.tile(np.arange(2), settings.horizon)   # S(k) repeated over the horizon
        bounds = np.abs(np.concatenate([self.u_lower, self.u_upper]))
        bounds = bounds[np.isfinite(bounds) & (bounds > 0)]
        self._scale = float(bounds.max()) if bounds.size else 1.0  # x = d * y keeps y of order one
        # rows: y (the scaled input, so its box is U's box over d) and C d y (the predicted states)
        self._a_full = np.vstack([np.eye(n), np.zeros((n, n))])
        big = 1e20  # "no bound", well within OSQP's infinity (1e30) whatever the state subtracts
        self._lower = np.clip(np.concatenate([self.u_lower / self._scale, self.s_lower]), -big, big)
        self._upper = np.clip(np.concatenate([self.u_upper / self._scale, self.s_upper]), -big, big)
        self._s_lower = self._lower[n:].copy()
        self._s_upper = self._upper[n:].copy()

    def solve(self, b: np.ndarray, s: np.ndarray, s_target: np.ndarray) -> MpcSolution:
        """Optimal inputs for B (2x2), current state S and target S_d (held over the horizon)."""
        b = np.asarray(b, dtype=float)
        s = np.asarray(s, dtype=float)
        s_target = np.asarray(s_target, dtype=float)
        if not math.isfinite(sum(b.ravel().tolist()) + sum(s.tolist()) + sum(s_target.tolist())):
            return self._failed("non-finite model or state")
        n = self.n
        c = self._c
        self._c_blocks[self._block_rows, self._block_cols] = b   # every lower block, one assignment
        weighted_c = self._q_bar[:, None] * c
        hess = 2.0 * (c.T @ weighted_c)                        # eq. 37
        hess.flat[::n + 1] += self._r_bar2                     # its diagonal
        free_state = s[self._stack]                            # M S(k): S repeated over the horizon
        grad = 2.0 * (weighted_c.T @ (free_state - s_target[self._stack]))   # eq. 38, factor 2
        lower, upper = self._lower, self._upper
        low, high = self._s_lower - free_state, self._s_upper - free_state
        if self.settings.admit_state:   # zero input (C U = 0) stays feasible: 0 within each row's bounds
            low, high = np.minimum(low, 0.0), np.maximum(high, 0.0)
        lower[n:], upper[n:] = low, high
        d = self._scale
        self._a_full[n:] = c * d
        norm = max(float(np.abs(hess).max()) * d * d, 1e-300)
        hess_y, grad_y = hess * (d * d / norm), grad * (d / norm)
        y, ok, status, solve_time, iterations = self.backend.solve(hess_y, grad_y, self._a_full, lower, upper)
        if not ok and self._fallback is not None:
            y, ok, fallback_status, more_time, more_iterations = self._fallback.solve(
                hess_y, grad_y, self._a_full, lower, upper)
            status = f"osqp {status}; daqp fallback: {fallback_status}"
            solve_time, iterations = solve_time + more_time, iterations + more_iterations
        y = np.asarray(y, dtype=float) if ok and y is not None else None
        if y is None or not math.isfinite(sum(y.tolist())):   # no answer, or NaN or infinity in it
            return self._failed(status)
        u = y * d
        return MpcSolution(u[:2].copy(), u, True, status, solve_time, iterations)

    def _failed(self, status: str) -> MpcSolution:
        nan = np.full(self.n, np.nan)
        return MpcSolution(nan[:2].copy(), nan, False, status, 0.0, 0)
