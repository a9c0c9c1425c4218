"""MPC: velocity (flow) limits at every node."""

from __future__ import annotations

import numpy as np

from wbc.constraints.constraint import Constraint, Inequality

__all__ = ["HorizonVelocityLimit"]


class HorizonVelocityLimit(Constraint):
    r"""``v_lo <= \dot q_k <= v_hi`` at the nodes k = 1..N (rows of ``Pv``).

    Each node's bounds are relaxed to admit the brake-and-hold trajectory (an axis measured
    above its limit is brought back at the acceleration limit): the QP stays feasible.
    """

    def __init__(self):
        self._key = None
        self._G = None

    def compute(self, ctx) -> Inequality:
        """``[Pv; -Pv] x <= [v_hi - v_free; v_free - v_lo]``."""
        if self._key != ctx.structure_key:
            Pv = ctx.prediction.Pv
            self._G = np.vstack([Pv, -Pv])
            self._key = ctx.structure_key
        lim = ctx.limits
        hi = np.maximum(lim.velocity_upper[None, :], ctx.brake_velocities)
        lo = np.minimum(lim.velocity_lower[None, :], ctx.brake_velocities)
        vf = ctx.free_velocities
        return Inequality(self._G, np.concatenate([(hi - vf).ravel(), (vf - lo).ravel()]))
