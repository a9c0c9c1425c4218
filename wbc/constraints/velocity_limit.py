"""Velocity (valve flow) limits as acceleration bounds over one control period."""

from __future__ import annotations

import numpy as np

from wbc.axes import N_AXES
from wbc.constraints.constraint import Box, Constraint, unbounded
from wbc.constraints.limits_c import compiled_bounds

__all__ = ["VelocityLimit"]


class VelocityLimit(Constraint):
    r"""``v_lo <= \dot q + \ddot q\, dt <= v_hi`` for the nine axes (whole-body QP).

    The limits are the cylinders' flow-limited speeds (`HydraulicCylinder.velocity_range`,
    asymmetric) and the drives' ``velocity_limit``. Each bound is relaxed to admit the
    braking acceleration (`AxisLimits.brake_acceleration`): an axis measured above its limit
    is brought back at the acceleration limit instead of making the QP infeasible.

    Attributes:
        compiled: Evaluate in C (`wbc.constraints.limits_c`, the same bits) when a C
            compiler is there; False: numpy.
    """

    def __init__(self):
        self.compiled = True
        self._c = compiled_bounds("velocity_bounds")  # None without a C compiler
        self._c_key: tuple | None = None  # (limits, dt) its input buffer holds

    def compute(self, ctx) -> Box:
        """Box on step 0's accelerations."""
        lim, dt, qd = ctx.limits, ctx.dt, ctx.qd
        brake = ctx.brake
        lb, ub = unbounded(ctx.layout.n)
        s = ctx.layout.step(0)
        c = self._c if self.compiled else None
        if c is not None:
            inp, na = c.inp, N_AXES
            key = self._c_key
            if key is None or key[0] is not lim or key[1] != dt:
                inp[2 * na:3 * na], inp[3 * na:4 * na] = lim.velocity_upper, lim.velocity_lower
                inp[4 * na] = dt
                self._c_key = (lim, dt)
            inp[:na], inp[na:2 * na] = qd, brake
            c.call()
            lb[s], ub[s] = c.out
            return Box(lb, ub)
        # min((v_lo - qd) / dt, brake) and max((v_hi - qd) / dt, brake), in place
        lower = np.subtract(lim.velocity_lower, qd, out=lb[s])
        lower /= dt
        np.minimum(lower, brake, out=lower)
        upper = np.subtract(lim.velocity_upper, qd, out=ub[s])
        upper /= dt
        np.maximum(upper, brake, out=upper)
        return Box(lb, ub)
