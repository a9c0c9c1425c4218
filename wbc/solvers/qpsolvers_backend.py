"""Any qpsolvers backend, by name, behind the workspace's interface (cold solves)."""

from __future__ import annotations

import time

import numpy as np
import qpsolvers

from wbc.errors import ConfigurationError, QPSolveError, UnknownSolverError
from wbc.solvers.solution import QPSolution

__all__ = ["QpsolversBackend", "backend_settings"]


def backend_settings(solver: str, eps_abs: float, eps_rel: float = 0.0) -> dict:
    """The keyword settings that give ``solver`` the tolerances ``eps_abs``, ``eps_rel``.

    qpsolvers forwards keywords to the backend unchanged, and the backends name their
    tolerances differently: DAQP (an active-set method, exact up to its pivoting) takes a
    primal feasibility tolerance ``primal_tol`` and rejects ``eps_abs`` with a TypeError;
    OSQP's ADMM solution is then polished (``polishing``: the active set's KKT system solved
    exactly), without which 1e-7 takes thousands of iterations; PIQP and ProxQP take
    ``eps_abs`` and ``eps_rel``. Iteration caps are the backends' own: their iterations are
    not comparable (an active-set change, an ADMM step, an interior-point step).

    Args:
        solver: A qpsolvers backend name.
        eps_abs: Absolute primal (and, where the backend has one, dual) tolerance.
        eps_rel: Relative tolerance (ignored by DAQP).

    Raises:
        ConfigurationError: ``eps_abs <= 0`` or ``eps_rel < 0``.
    """
    if not (eps_abs > 0 and eps_rel >= 0):
        raise ConfigurationError(f"need eps_abs > 0 and eps_rel >= 0, got {eps_abs}, {eps_rel}")
    if solver == "daqp":
        return {"primal_tol": float(eps_abs)}
    settings = {"eps_abs": float(eps_abs), "eps_rel": float(eps_rel)}
    if solver == "osqp":
        settings.update(polishing=True, max_iter=20000)
    return settings


class QpsolversBackend:
    """Solve with ``qpsolvers.solve_problem(problem, solver=name)``.

    Args:
        solver: A name in ``qpsolvers.available_solvers``.
        **settings: Solver-specific keyword settings passed on every solve (set them
            explicitly; `backend_settings` gives the tolerances by their backend's names).
    """

    def __init__(self, solver: str, **settings):
        if solver not in qpsolvers.available_solvers:
            raise UnknownSolverError(solver, tuple(qpsolvers.available_solvers))
        self.solver = solver
        self.tolerances = dict(settings)
        self.n_init = 0

    def reset(self) -> None:
        """Nothing to drop: every solve is cold."""

    def solve(self, problem: qpsolvers.Problem) -> QPSolution:
        """Solve; raise `QPSolveError` if the backend finds no finite solution."""
        t0 = time.perf_counter()
        sol = qpsolvers.solve_problem(problem, solver=self.solver, **self.tolerances)
        elapsed = time.perf_counter() - t0
        if not sol.found or sol.x is None or not np.all(np.isfinite(sol.x)):
            raise QPSolveError(f"{self.solver} found no solution", "not_found")
        return QPSolution(np.asarray(sol.x, float), "solved", -1, elapsed, False)
