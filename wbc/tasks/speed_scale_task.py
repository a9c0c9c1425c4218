"""Prefer the full base-drive speed."""

from __future__ import annotations

import numpy as np

from wbc.tasks.task import ConstantJacobianTask

__all__ = ["SpeedScaleTask"]


class SpeedScaleTask(ConstantJacobianTask):
    """``r(x) = s - 1``: the wheel-speed scale stays at 1 unless a constraint needs less.

    Works with any layout that has a speed scale (whole-body QP and MPC).
    """

    constant_error = True

    def __init__(self, weight: float = 10.0):
        super().__init__(weight)

    def is_active(self, ctx) -> bool:
        """Active when the layout has a speed scale."""
        return ctx.layout.scale is not None

    def _term_guard(self) -> tuple | None:
        """The layout (activity, structure) and the weight; this class's own."""
        return ("ctx.layout", "task.weight") if type(self) is SpeedScaleTask else None

    def compute_error(self, ctx) -> np.ndarray:
        """-1."""
        return np.array([-1.0])

    def compute_jacobian(self, ctx) -> np.ndarray:
        """Unit row on s."""
        jac = np.zeros((1, ctx.layout.n))
        jac[0, ctx.layout.scale] = 1.0
        return jac
