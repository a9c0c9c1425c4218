"""MPC: small input steps (a discrete jerk penalty)."""

from __future__ import annotations

import numpy as np

from wbc.tasks.linear_c import SMOOTHNESS, LinearTerm
from wbc.tasks.task import ConstantJacobianTask, StepWeights

__all__ = ["HorizonSmoothnessTask"]


class HorizonSmoothnessTask(ConstantJacobianTask):
    r"""``\|u_0 - u_{prev}\|^2_W + \sum_{k=1}^{N-1} \|u_k - u_{k-1}\|^2_W``.

    ``u_prev`` is the acceleration commanded at the previous tick.

    Args:
        weight: Scalar or per axis (9,).
    """

    def __init__(self, weight=1.0):
        super().__init__(weight)
        self._step_weights = StepWeights()

    def compute_weight(self, ctx) -> np.ndarray:
        """Per-axis weight repeated over the steps."""
        return self._step_weights(self.weight, ctx.layout)

    def compute_error(self, ctx) -> np.ndarray:
        """``[-u_prev, 0, ..., 0]``."""
        e = np.zeros(ctx.layout.n_axes * ctx.layout.n_steps)
        e[:ctx.layout.n_axes] = -ctx.previous_acceleration
        return e

    def _linear_term(self, ctx) -> np.ndarray:
        """``J^T W e`` written directly: ``W e`` on step 0's inputs, zeros elsewhere.

        Only e's first step (``-u_prev``) is nonzero, and there J's first differences have
        one entry per column (1 on step 0's own inputs): each entry of the product has
        one nonzero term, ``w_i e_i`` (see `HorizonInputTask._linear_term`), here
        ``-u_prev`` written in place and then scaled (a product's operands commute).
        """
        lay = ctx.layout
        c = np.zeros(lay.n)
        first = lay.step(0)
        step = c[first]
        np.negative(ctx.previous_acceleration, out=step)
        np.multiply(step, self.compute_weight(ctx)[first], out=step)
        return c

    def _make_term(self, ctx) -> LinearTerm | None:
        """`SMOOTHNESS` on step 0's inputs: `_linear_term` in C (`wbc.tasks.linear_c`).

        This class's own arithmetic: None for a subclass (it says its own).
        """
        if type(self) is not HorizonSmoothnessTask:
            return None
        first = ctx.layout.step(0)
        return LinearTerm(SMOOTHNESS, self._H, (first.start, first.stop - first.start),
                          (self._weight,), ("ctx.layout", "task.weight"))

    def compute_jacobian(self, ctx) -> np.ndarray:
        """First differences of the inputs."""
        lay = ctx.layout
        m = lay.n_axes * lay.n_steps
        d = np.eye(m) - np.eye(m, k=-lay.n_axes)
        jac = np.zeros((m, lay.n))
        jac[:, lay.accelerations] = d
        return jac
