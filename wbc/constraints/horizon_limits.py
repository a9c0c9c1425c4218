"""MPC: position and velocity limits at every node, one implementation."""

from __future__ import annotations

import abc

import numpy as np

from wbc.constraints.constraint import Constraint, Inequality

__all__ = ["HorizonLimit", "HorizonPositionLimit", "HorizonVelocityLimit"]


class HorizonLimit(Constraint):
    r"""``lo <= y_k <= hi`` at the nodes k = 1..N, with ``y_k = P x + y_free`` condensed.

    Each node's bounds are relaxed to admit the brake-and-hold trajectory, so that a state
    already past a limit (or too fast to stop before it) is braked, not infeasible. The
    subclasses say which quantity ``y`` is (`_quantity`).
    """

    def __init__(self):
        self._key = None
        self._G = None

    @abc.abstractmethod
    def _quantity(self, ctx) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray,
                                      np.ndarray]:
        """``(P (N 9, n), lower (9,), upper (9,), brake (N, 9), free (N, 9))`` of ``y``."""

    def compute(self, ctx) -> Inequality:
        """``[P; -P] x <= [hi - y_free; y_free - lo]``."""
        P, lower, upper, brake, free = self._quantity(ctx)
        if self._key != ctx.structure_key:
            self._G = np.vstack([P, -P])
            self._G.setflags(write=False)  # the same rows every tick (`wbc.qp.QP`)
            self._key = ctx.structure_key
        # [hi - free; free - lo] with hi = max(upper, brake), lo = min(lower, brake), each
        # written into its half of h (no temporaries, the same operations)
        h = np.empty((2, *free.shape))
        hi, lo = h
        np.maximum(upper, brake, out=hi)
        np.subtract(hi, free, out=hi)
        np.minimum(lower, brake, out=lo)
        np.subtract(free, lo, out=lo)
        return Inequality(self._G, h.reshape(-1))


class HorizonPositionLimit(HorizonLimit):
    """Stroke and joint position limits ``q_lo <= q_k <= q_hi`` (rows of ``Pq``)."""

    def _quantity(self, ctx):
        lim = ctx.limits
        return (ctx.prediction.Pq, lim.position_lower, lim.position_upper,
                ctx.brake_positions, ctx.free_positions)


class HorizonVelocityLimit(HorizonLimit):
    r"""Velocity (flow) limits ``v_lo <= \dot q_k <= v_hi`` (rows of ``Pv``)."""

    def _quantity(self, ctx):
        lim = ctx.limits
        return (ctx.prediction.Pv, lim.velocity_lower, lim.velocity_upper,
                ctx.brake_velocities, ctx.free_velocities)
