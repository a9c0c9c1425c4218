"""Bounds and rate limit of the base-drive wheel-speed scale."""

from __future__ import annotations

import math

from wbc.constraints.constraint import Box, Constraint, unbounded
from wbc.errors import ConfigurationError

__all__ = ["SpeedScaleLimit"]


class SpeedScaleLimit(Constraint):
    """``max(s_min, s_prev - r dt) <= s <= min(1, c, s_prev + r dt)``.

    ``c`` is a cap the controller may set each tick (`cap`, e.g. the MPC's speed governor);
    the scale still moves towards it at the rate limit, and never below ``s_min``.

    Args:
        minimum: s_min in [0, 1).
        rate: r [1/s]: the largest change of the scale per second (the operator sees no
            jumps in speed).
    """

    def __init__(self, minimum: float = 0.0, rate: float = 0.5):
        if not (0.0 <= minimum < 1.0 and rate > 0):
            raise ConfigurationError(f"need 0 <= minimum < 1 and rate > 0, got {minimum}, "
                                     f"{rate}")
        self.minimum = float(minimum)
        self.rate = float(rate)
        self.cap = 1.0
        self._box: tuple | None = None  # (n, scale index, lo, hi, the read-only Box)

    def prepare(self, ctx) -> int:
        """No rows: a box, which the speed scale now sets (`Constraint.prepare`)."""
        return 0

    def bounds(self, previous: float, dt: float) -> tuple[float, float]:
        """(lower, upper) for a previous scale and a period [s]."""
        lo = max(self.minimum, min(previous, 1.0) - self.rate * dt)
        hi = min(1.0, max(previous, self.minimum) + self.rate * dt)
        hi = max(lo, min(hi, self.cap))
        return lo, hi

    def compute(self, ctx) -> Box | None:
        """Box on s; None when the layout has no speed scale.

        Read-only, and the last tick's Box again while ``n``, the scale's index and its
        bounds are the same (the scale mostly sits at 1: `wbc.qp.QPBuilder` then reuses its
        bounds).
        """
        lay = ctx.layout
        i = lay.scale
        if i is None:
            return None
        n = lay.n
        lo, hi = self.bounds(ctx.speed_scale, ctx.dt)
        kept = self._box
        if (kept is None or kept[0] != n or kept[1] != i or not _same(kept[2], lo)
                or not _same(kept[3], hi)):
            lb, ub = unbounded(n)
            lb[i], ub[i] = lo, hi
            lb.setflags(write=False)
            ub.setflags(write=False)
            self._box = kept = (n, i, lo, hi, Box(lb, ub))
        return kept[4]


def _same(a: float, b: float) -> bool:
    """``a`` and ``b`` are the same double: equal, and a zero of the same sign."""
    return a == b and (a != 0.0 or math.copysign(1.0, a) == math.copysign(1.0, b))
