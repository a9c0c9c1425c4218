"""Regularization: bring every axis to rest."""

from __future__ import annotations

import numpy as np

from wbc.errors import ConfigurationError
from wbc.tasks.task import ConstantJacobianTask

__all__ = ["DampingTask"]


class DampingTask(ConstantJacobianTask):
    r"""``r(x) = \ddot q + \dot q / T``: decelerate every axis with time constant T.

    With no other task, the QP then stops the machine (and keeps it still once at rest):
    "no task gives zero motion". It also makes the Hessian positive definite.

    Args:
        time_constant: T [s].
        weight: Scalar or one per axis; small next to the tracking tasks.
    """

    def __init__(self, time_constant: float = 0.5, weight=1e-3):
        if not time_constant > 0:
            raise ConfigurationError(f"time_constant must be > 0, got {time_constant}")
        super().__init__(weight)
        self.time_constant = float(time_constant)
        self._weights: np.ndarray | None = None  # the weight per axis, read-only

    def compute_weight(self, ctx) -> np.ndarray:
        """The weight for every axis (read-only)."""
        n = ctx.layout.n_axes
        if self._weights is None or self._weights.size != n:
            self._weights = np.broadcast_to(self.weight, (n,)).copy()
            self._weights.setflags(write=False)
        return self._weights

    def compute_error(self, ctx) -> np.ndarray:
        """``qd / T``."""
        return ctx.qd / self.time_constant

    def compute_jacobian(self, ctx) -> np.ndarray:
        """Identity on the accelerations of step 0."""
        jac = np.zeros((ctx.layout.n_axes, ctx.layout.n))
        s = ctx.layout.step(0)
        jac[:, s] = np.eye(ctx.layout.n_axes)
        return jac
