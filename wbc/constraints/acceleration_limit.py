"""Acceleration limits of every cylinder and joint."""

from __future__ import annotations

import numpy as np

from wbc.constraints.constraint import Box, Constraint, PreparedForm

__all__ = ["AccelerationLimit"]


class AccelerationLimit(Constraint):
    """``-a_max <= qdd_k <= a_max`` for every axis and every step of the layout.

    ``a_max`` is `AxisLimits.acceleration` (cylinder ``max_acceleration``, drive
    ``acceleration_limit``). Works for the whole-body QP and the MPC alike. The box depends
    on the layout and the limits only: it is built once for them (read-only).
    """

    def __init__(self):
        self._key = None
        self._box: Box | None = None

    def prepare(self, ctx) -> int:
        """The box of ``ctx``'s layout and limits, now (`Constraint.prepare`); no rows."""
        self.compute(ctx)
        return 0

    def prepared_form(self, ctx) -> PreparedForm:
        """The box of ``ctx``'s layout and limits (`Constraint.prepared_form`)."""
        return PreparedForm(box=self.compute(ctx))

    def compute(self, ctx) -> Box:
        """Box on all axis accelerations."""
        lay = ctx.layout
        if self._key is None or self._key[0] is not lay or self._key[1] is not ctx.limits:
            lb, ub = np.full(lay.n, -np.inf), np.full(lay.n, np.inf)
            a = np.tile(ctx.limits.acceleration, lay.n_steps)
            lb[lay.accelerations] = -a
            ub[lay.accelerations] = a
            lb.setflags(write=False)
            ub.setflags(write=False)
            self._key, self._box = (lay, ctx.limits), Box(lb, ub)
        return self._box
