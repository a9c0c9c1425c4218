"""MPC: position and velocity limits at every node, one implementation."""

from __future__ import annotations

import abc

import numpy as np

from wbc.axes import N_AXES
from wbc.constraints.constraint import Constraint, Inequality, PreparedForm
from wbc.constraints.limits_c import compiled_horizon_bounds

__all__ = ["HorizonLimit", "HorizonPositionLimit", "HorizonVelocityLimit"]


class HorizonLimit(Constraint):
    r"""``lo <= y_k <= hi`` at the nodes k = 1..N, with ``y_k = P x + y_free`` condensed.

    Each node's bounds are relaxed to admit the brake-and-hold trajectory, so that a state
    already past a limit (or too fast to stop before it) is braked, not infeasible. The
    subclasses say which quantity ``y`` is (`_quantity`).

    Args:
        compiled: Write ``h`` in C (`wbc.constraints.limits_c`, the same bits); False, or
            no C compiler: numpy.
    """

    def __init__(self, compiled: bool = True):
        self._key = None
        self._G = None
        self.compiled = compiled  # h in C (`wbc.constraints.limits_c`, the same bits)
        self._c: tuple | None = None  # (N, `CompiledHorizonBounds` or None)

    @abc.abstractmethod
    def _quantity(self, ctx) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray,
                                      np.ndarray]:
        """``(P (N 9, n), lower (9,), upper (9,), brake (N, 9), free (N, 9))`` of ``y``."""

    @abc.abstractmethod
    def _matrix(self, prediction) -> np.ndarray:
        """``P`` (N 9, n): ``y = P x + y_free``."""

    def prepare(self, ctx) -> int:
        """``[P; -P]`` and the compiled ``h`` of ``ctx``'s structure (`Constraint.prepare`)."""
        self._compiled(np.empty((ctx.layout.n_steps, N_AXES)))
        return self._rows(ctx, self._matrix(ctx.prediction)).shape[0]

    def prepared_form(self, ctx) -> PreparedForm:
        """The read-only ``[P; -P]`` of ``ctx``'s structure (`Constraint.prepared_form`)."""
        return PreparedForm(G=self._rows(ctx, self._matrix(ctx.prediction)))

    def _rows(self, ctx, P: np.ndarray) -> np.ndarray:
        """``[P; -P]``, read-only, made once per structure."""
        if self._key != ctx.structure_key:
            self._G = np.vstack([P, -P])
            self._G.setflags(write=False)  # the same rows every tick (`wbc.qp.QP`)
            self._key = ctx.structure_key
        return self._G

    def compute(self, ctx) -> Inequality:
        """``[P; -P] x <= [hi - y_free; y_free - lo]``."""
        P, lower, upper, brake, free = self._quantity(ctx)
        self._rows(ctx, P)
        c = self._compiled(free)
        if c is not None and brake.shape == free.shape and upper.shape == (N_AXES,):
            return Inequality(self._G, c.h(upper, lower, brake, free))
        # [hi - free; free - lo] with hi = max(upper, brake), lo = min(lower, brake), each
        # written into its half of h (no temporaries, the same operations)
        h = np.empty((2, *free.shape))
        hi, lo = h
        np.maximum(upper, brake, out=hi)
        np.subtract(hi, free, out=hi)
        np.minimum(lower, brake, out=lo)
        np.subtract(free, lo, out=lo)
        return Inequality(self._G, h.reshape(-1))


    def _compiled(self, free: np.ndarray):
        """The compiled h of ``free``'s N steps of nine axes (made once for N), or None."""
        if not self.compiled or free.ndim != 2 or free.shape[1] != N_AXES:
            return None
        N = free.shape[0]
        if self._c is None or self._c[0] != N:
            self._c = (N, compiled_horizon_bounds(N))
        return self._c[1]


class HorizonPositionLimit(HorizonLimit):
    """Stroke and joint position limits ``q_lo <= q_k <= q_hi`` (rows of ``Pq``)."""

    def _matrix(self, prediction) -> np.ndarray:
        return prediction.Pq

    def _quantity(self, ctx):
        lim = ctx.limits
        return (ctx.prediction.Pq, lim.position_lower, lim.position_upper,
                ctx.brake_positions, ctx.free_positions)


class HorizonVelocityLimit(HorizonLimit):
    r"""Velocity (flow) limits ``v_lo <= \dot q_k <= v_hi`` (rows of ``Pv``)."""

    def _matrix(self, prediction) -> np.ndarray:
        return prediction.Pv

    def _quantity(self, ctx):
        lim = ctx.limits
        return (ctx.prediction.Pv, lim.velocity_lower, lim.velocity_upper,
                ctx.brake_velocities, ctx.free_velocities)
