"""Velocity (valve flow) limits as acceleration bounds over one control period."""

from __future__ import annotations

import numpy as np

from wbc.constraints.constraint import Box, Constraint, unbounded

__all__ = ["VelocityLimit"]


class VelocityLimit(Constraint):
    r"""``v_lo <= \dot q + \ddot q\, dt <= v_hi`` for the nine axes (whole-body QP).

    The limits are the cylinders' flow-limited speeds (`HydraulicCylinder.velocity_range`,
    asymmetric) and the drives' ``velocity_limit``. Each bound is relaxed to admit the
    braking acceleration (`AxisLimits.brake_acceleration`): an axis measured above its limit
    is brought back at the acceleration limit instead of making the QP infeasible.
    """

    def compute(self, ctx) -> Box:
        """Box on step 0's accelerations."""
        lim, dt, qd = ctx.limits, ctx.dt, ctx.qd
        brake = ctx.brake
        lb, ub = unbounded(ctx.layout.n)
        s = ctx.layout.step(0)
        # min((v_lo - qd) / dt, brake) and max((v_hi - qd) / dt, brake), in place
        lower = np.subtract(lim.velocity_lower, qd, out=lb[s])
        lower /= dt
        np.minimum(lower, brake, out=lower)
        upper = np.subtract(lim.velocity_upper, qd, out=ub[s])
        upper /= dt
        np.maximum(upper, brake, out=upper)
        return Box(lb, ub)
