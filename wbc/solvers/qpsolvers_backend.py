"""Any qpsolvers backend, by name, behind the workspace's interface (cold solves)."""

from __future__ import annotations

import time

import numpy as np
import qpsolvers

from wbc.errors import QPSolveError, UnknownSolverError
from wbc.solvers.solution import QPSolution

__all__ = ["QpsolversBackend"]


class QpsolversBackend:
    """Solve with ``qpsolvers.solve_problem(problem, solver=name)``.

    Args:
        solver: A name in ``qpsolvers.available_solvers``.
        **tolerances: Solver-specific keyword settings passed on every solve (set them
            explicitly, e.g. ``eps_abs=1e-7`` for OSQP/ProxQP).
    """

    def __init__(self, solver: str, **tolerances):
        if solver not in qpsolvers.available_solvers:
            raise UnknownSolverError(solver, tuple(qpsolvers.available_solvers))
        self.solver = solver
        self.tolerances = dict(tolerances)
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
