"""MPC: stroke and joint position limits at every node."""

from __future__ import annotations

import numpy as np

from wbc.constraints.constraint import Constraint, Inequality

__all__ = ["HorizonPositionLimit"]


class HorizonPositionLimit(Constraint):
    r"""``q_lo <= q_k <= q_hi`` at the nodes k = 1..N (rows of ``Pq``).

    Each node's bounds are relaxed to admit the brake-and-hold trajectory, so that a state
    already past a limit (or too fast to stop before it) is braked, not infeasible.
    """

    def __init__(self):
        self._key = None
        self._G = None

    def compute(self, ctx) -> Inequality:
        """``[Pq; -Pq] x <= [q_hi - q_free; q_free - q_lo]``."""
        if self._key != ctx.structure_key:
            Pq = ctx.prediction.Pq
            self._G = np.vstack([Pq, -Pq])
            self._key = ctx.structure_key
        lim = ctx.limits
        hi = np.maximum(lim.position_upper[None, :], ctx.brake_positions)
        lo = np.minimum(lim.position_lower[None, :], ctx.brake_positions)
        qf = ctx.free_positions
        return Inequality(self._G, np.concatenate([(hi - qf).ravel(), (qf - lo).ravel()]))
