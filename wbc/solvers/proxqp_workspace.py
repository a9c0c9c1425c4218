"""A persistent ProxQP dense workspace: ``init`` once, ``update`` every tick."""

from __future__ import annotations

import time

import numpy as np
import qpsolvers
from proxsuite import proxqp

from wbc.errors import ConfigurationError, QPSolveError
from wbc.solvers.solution import QPSolution

__all__ = ["ProxQPWorkspace"]

_SOLVED = proxqp.QPSolverOutput.PROXQP_SOLVED
_TIGHTER = 1e-3  # eps_primal_inf factor of the last retry


class ProxQPWorkspace:
    """Solves a stream of `qpsolvers.Problem` of fixed dimensions, warm-started.

    The first problem (and any problem whose dimensions differ from the previous one, e.g.
    when a wheel leaves the ground and its force row goes) calls ``init``; the others call
    ``update`` and start from the previous primal-dual solution.

    proxsuite 0.8 (dense) with ``WARM_START_WITH_PREVIOUS_RESULT`` and ``update`` reports
    PRIMAL_INFEASIBLE or MAX_ITER on many feasible problems. Measured on 1500 random
    feasible QPs (12 variables, 30 rows) solved in streams: 972 failures at the default
    ``eps_primal_inf`` (1e-4), 70 at 1e-9 or 1e-12, and 0 at any tolerance once ``mu_eq``
    and ``mu_in`` are reset to their defaults on every ``update``. A very tight
    ``eps_primal_inf`` also makes a truly infeasible MPC take ~10^4 iterations (2 s)
    instead of 6 (1.7 ms) before it is reported, so the workspace resets the proximal
    parameters, keeps ``eps_primal_inf = 1e-9``, and retries a failed warm solve once from a
    cold start. Every tolerance is set explicitly.

    Args:
        eps_abs: Absolute primal/dual residual tolerance.
        eps_rel: Relative tolerance.
        max_iter: Iteration cap. max_iter_in: Inner iteration cap.
        eps_primal_inf, eps_dual_inf: Infeasibility detection tolerances.
        warm_start: Start each update from the previous result.
        retry_infeasible: The problems are feasible by construction (soft constraints): a
            failed cold solve is retried once with ``eps_primal_inf`` 1000x tighter and the
            equality-constrained initial guess.

    Every solve is capped at ``max_iter`` outer times ``max_iter_in`` inner iterations:
    typical MPC solves take 5 (median) to 30 (p99) iterations in all, but proxsuite 0.8
    occasionally wanders for 10^5 iterations (22 s in one closed-loop tick) on a problem it
    solves in 25 from another start; a capped failure falls through to the next try and,
    at worst, to the controller's fallback.
    """

    def __init__(self, eps_abs: float = 1e-7, eps_rel: float = 0.0, max_iter: int = 1000,
                 eps_primal_inf: float = 1e-9, eps_dual_inf: float = 1e-9,
                 warm_start: bool = True, max_iter_in: int = 60,
                 retry_infeasible: bool = False):
        if not (eps_abs > 0 and eps_rel >= 0 and max_iter > 0 and eps_primal_inf > 0
                and eps_dual_inf > 0):
            raise ConfigurationError("ProxQP tolerances must be > 0 (eps_rel >= 0) and "
                                     "max_iter > 0")
        self.eps_abs = float(eps_abs)
        self.eps_rel = float(eps_rel)
        self.max_iter = int(max_iter)
        self.max_iter_in = int(max_iter_in)
        self.eps_primal_inf = float(eps_primal_inf)
        self.eps_dual_inf = float(eps_dual_inf)
        self.warm_start = bool(warm_start)
        self.retry_infeasible = bool(retry_infeasible)
        self._qp = None
        self._dims = None
        self._P = None
        self.n_init = 0  # how many times the workspace was (re)initialized

    def reset(self) -> None:
        """Drop the workspace: the next solve initializes a new one (cold start)."""
        self._qp = None
        self._dims = None
        self._P = None

    @property
    def multipliers(self) -> tuple[np.ndarray, np.ndarray] | None:
        """``(z, z_box)`` of the last successful solve, or None (none yet, or it failed).

        ``z``: the inequality rows' multipliers, shape (n_in,); ``z_box``: the bounds',
        shape (n,) (positive at an upper bound, negative at a lower one), the convention of
        ``qpsolvers.Solution`` (for its dual residual and duality gap).
        """
        if self._qp is None:
            return None
        z = self._qp.results.z
        n_in = self._dims[1]
        return z[:n_in].copy(), z[n_in:].copy()

    def _settings(self, qp) -> None:
        s = qp.settings
        s.eps_abs = self.eps_abs
        s.eps_rel = self.eps_rel
        s.max_iter = self.max_iter
        s.max_iter_in = self.max_iter_in
        s.eps_primal_inf = self.eps_primal_inf
        s.eps_dual_inf = self.eps_dual_inf
        s.verbose = False
        s.initial_guess = proxqp.InitialGuess.NO_INITIAL_GUESS  # `solve` sets it per call

    def _init(self, dims, P, q, C, lo, h, lb, ub, eps_primal_inf: float | None = None) -> None:
        qp = proxqp.dense.QP(dims[0], 0, dims[1], True)
        self._settings(qp)
        if eps_primal_inf is not None:  # the last retry
            qp.settings.eps_primal_inf = eps_primal_inf
            qp.settings.initial_guess = proxqp.InitialGuess.EQUALITY_CONSTRAINED_INITIAL_GUESS
        qp.init(P, q, None, None, C, lo, h, lb, ub)
        self._qp, self._dims, self._P = qp, dims, P.copy()
        self.n_init += 1

    def solve(self, problem: qpsolvers.Problem) -> QPSolution:
        """Solve ``problem``; raise `QPSolveError` unless ProxQP reports it solved.

        A warm-started solve that fails is retried once from a cold start (no initial
        guess), and, with ``retry_infeasible``, once more (see the class docstring).

        Raises:
            QPSolveError: Status other than solved (infeasible, max iterations) or a
                non-finite solution.
        """
        P, q, G, h, A, b, lb, ub = problem.unpack()
        n = q.shape[0]
        if A is not None:
            raise QPSolveError("equality constraints are not used by this workspace",
                               "unsupported")
        n_in = 0 if G is None else G.shape[0]
        if lb is None:
            lb = np.full(n, -np.inf)
        if ub is None:
            ub = np.full(n, np.inf)
        C = G if n_in else None
        lo = np.full(n_in, -np.inf) if n_in else None
        dims = (n, n_in)
        t0 = time.perf_counter()
        warm = self._qp is not None and self._dims == dims and self.warm_start
        if not warm:
            self._init(dims, P, q, C, lo, h, lb, ub)
        else:
            same_P = np.array_equal(P, self._P)
            if not same_P:
                self._P = P.copy()
            # Reset the proximal parameters on every update: keeping the previous solve's
            # (proxsuite 0.8) makes warm starts fail on feasible problems (see above).
            s = self._qp.settings
            s.initial_guess = proxqp.InitialGuess.WARM_START_WITH_PREVIOUS_RESULT
            self._qp.update(None if same_P else P, q, None, None, C, lo, h, lb, ub,
                            mu_eq=s.default_mu_eq, mu_in=s.default_mu_in)
        self._qp.solve()
        if warm and not self._solved():
            self._init(dims, P, q, C, lo, h, lb, ub)  # one cold retry
            self._qp.solve()
            warm = False
        if self.retry_infeasible and not self._solved():
            # proxsuite 0.8 also reports feasible soft-constrained MPC problems primal
            # infeasible, cold, at eps_primal_inf = 1e-9 (active slacks with a large exact
            # penalty; checked feasible by an LP); at 1e-12 and with the equality-
            # constrained initial guess they solve in 40-70 iterations, where the other
            # guesses stall at the iteration cap. On other problems that guess is the slow
            # one (95 000 iterations, 8 s, against 25 cold), hence the order of the tries.
            self._init(dims, P, q, C, lo, h, lb, ub, self.eps_primal_inf * _TIGHTER)
            self._qp.solve()
            warm = False
        elapsed = time.perf_counter() - t0
        info = self._qp.results.info
        x = self._qp.results.x.copy()
        if not self._solved():
            status = info.status.name
            self.reset()  # never warm start from a failed solve
            raise QPSolveError(f"ProxQP did not solve the QP: status {status} after "
                               f"{info.iter} iterations (n={n}, inequalities={n_in})", status)
        return QPSolution(x, info.status.name, int(info.iter), elapsed, warm)

    def _solved(self) -> bool:
        r = self._qp.results
        return r.info.status == _SOLVED and bool(np.all(np.isfinite(r.x)))
