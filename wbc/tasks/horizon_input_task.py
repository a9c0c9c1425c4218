"""MPC: inputs close to the reference acceleration."""

from __future__ import annotations

import numpy as np

from wbc.tasks.linear_c import INPUT, LinearTerm
from wbc.tasks.task import ConstantJacobianTask, StepWeights

__all__ = ["HorizonInputTask"]


class HorizonInputTask(ConstantJacobianTask):
    r"""``\sum_{k=0}^{N-1} \|u_k - \ddot q^{ref}(t_k)\|^2_W``: regularizes the inputs.

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
        """``-a_ref`` at the step start times."""
        return -ctx.reference.acceleration[:-1].ravel()

    def _linear_term(self, ctx) -> np.ndarray:
        """``W e`` on the accelerations, zeros elsewhere: ``J^T W e`` written directly.

        J selects the accelerations, so each entry of the product ``J^T W e`` has one
        nonzero term, ``w_i e_i``; its other terms are exact zeros, which leave a finite sum
        as it is (at most a zero's sign differs, and adding into the QP's ``q``, which
        starts at +0, does not keep that): the same QP without reading ``J^T W``
        (n x N n_axes), most of it zeros, every tick.
        """
        lay = ctx.layout
        c = np.zeros(lay.n)
        np.multiply(self.compute_weight(ctx), self.compute_error(ctx),
                    out=c[lay.accelerations])
        return c

    def _make_term(self, ctx) -> LinearTerm | None:
        """`INPUT` on the accelerations: `_linear_term` in C (`wbc.tasks.linear_c`).

        This class's own arithmetic: None for a subclass (it says its own).
        """
        if type(self) is not HorizonInputTask:
            return None
        acc = ctx.layout.accelerations
        return LinearTerm(INPUT, self._H, (acc.start, acc.stop - acc.start), (self._weight,),
                          ("ctx.layout", "task.weight"))

    def compute_jacobian(self, ctx) -> np.ndarray:
        """Identity on all accelerations."""
        lay = ctx.layout
        jac = np.zeros((lay.n_axes * lay.n_steps, lay.n))
        jac[:, lay.accelerations] = np.eye(lay.n_axes * lay.n_steps)
        return jac
