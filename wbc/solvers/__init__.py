"""QP solvers: DAQP (screened, warm-started), a ProxQP workspace, any qpsolvers backend."""

from __future__ import annotations

import qpsolvers

from wbc.errors import UnknownSolverError
from wbc.solvers.daqp_backend import DaqpBackend
from wbc.solvers.proxqp_workspace import ProxQPWorkspace
from wbc.solvers.qpsolvers_backend import QpsolversBackend, backend_settings
from wbc.solvers.solution import QPSolution

__all__ = ["DaqpBackend", "ProxQPWorkspace", "QPSolution", "QpsolversBackend", "backend_settings",
           "make_solver"]


def make_solver(name: str = "proxqp", eps_abs: float = 1e-7, eps_rel: float = 0.0,
                max_iter: int = 1000, feasible_by_construction: bool = False
                ) -> DaqpBackend | ProxQPWorkspace | QpsolversBackend:
    """A QP solver by name.

    ``daqp``: `DaqpBackend` (DAQP called directly, redundant rows screened out, warm started
    from the previous multipliers; DAQP's own cap of 1000 active-set changes, ``max_iter``
    being ProxQP's outer iterations); ``proxqp``: a warm-started `ProxQPWorkspace`; any
    other qpsolvers name: a cold `QpsolversBackend` with the same absolute/relative
    tolerances under the backend's own setting names (`backend_settings`).
    ``feasible_by_construction`` (soft constraints, limits relaxed to the brake
    trajectory): a ProxQP "primal infeasible" is then retried (`ProxQPWorkspace`).

    Raises:
        UnknownSolverError: The name is not an available qpsolvers backend.
    """
    if name == "proxqp":
        return ProxQPWorkspace(eps_abs=eps_abs, eps_rel=eps_rel, max_iter=max_iter,
                               retry_infeasible=feasible_by_construction)
    if name == "daqp":  # ``max_iter`` counts ProxQP's outer iterations: not DAQP's
        return DaqpBackend(primal_tol=eps_abs)
    if name not in qpsolvers.available_solvers:
        raise UnknownSolverError(name, tuple(qpsolvers.available_solvers))
    return QpsolversBackend(name, **backend_settings(name, eps_abs, eps_rel))
