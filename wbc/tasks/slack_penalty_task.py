"""Exact penalty on the normal-force slacks."""

from __future__ import annotations

import numpy as np

from wbc.errors import ConfigurationError
from wbc.tasks.task import ConstantJacobianTask, Objective

__all__ = ["SlackPenaltyTask"]


class SlackPenaltyTask(ConstantJacobianTask):
    r"""Cost ``rho_1 sum(eps) + rho_2 / 2 ||eps||^2`` on the slacks ``eps >= 0``.

    With ``rho_1`` above the force constraint's Lagrange multipliers the penalty is exact:
    the softened QP has the hard QP's solution whenever that one is feasible, and otherwise
    the least violation. Slacks are in the force constraint's scaled units.

    Args:
        linear: rho_1 (> 0).
        quadratic: rho_2 (> 0; keeps the Hessian definite).
    """

    constant_error = True

    def __init__(self, linear: float = 1e3, quadratic: float = 1e2):
        if not (linear > 0 and quadratic > 0):
            raise ConfigurationError(f"slack penalties must be > 0, got {linear}, {quadratic}")
        super().__init__(quadratic)
        self.linear = float(linear)
        self._with_linear: tuple | None = None  # (the base's c, rho_1, c with rho_1)

    def is_active(self, ctx) -> bool:
        """Active when the layout has slacks."""
        return ctx.layout.slack is not None

    def _term_guard(self) -> tuple | None:
        """The layout (activity, structure), the weight and rho_1; this class's own."""
        return (("ctx.layout", "task.weight", "task.linear") if type(self) is SlackPenaltyTask
                else None)

    def compute_error(self, ctx) -> np.ndarray:
        """Zero: the quadratic part is ``||eps||^2``."""
        return np.zeros(ctx.layout.n_slack)

    def compute_jacobian(self, ctx) -> np.ndarray:
        """Selection of the slacks."""
        jac = np.zeros((ctx.layout.n_slack, ctx.layout.n))
        jac[:, ctx.layout.slack] = np.eye(ctx.layout.n_slack)
        return jac

    def compute_qp_objective(self, ctx) -> Objective:
        """Quadratic part from the base class plus the linear term ``rho_1`` on eps.

        ``c`` is read-only and kept while the base class keeps its own and ``rho_1`` stays.
        """
        H, c = super().compute_qp_objective(ctx)
        kept = self._with_linear
        if kept is None or kept[0] is not c or kept[1] != self.linear:
            full = c.copy()
            full[ctx.layout.slack] += self.linear
            full.setflags(write=False)
            self._with_linear = kept = (c, self.linear, full)
        return H, kept[2]
