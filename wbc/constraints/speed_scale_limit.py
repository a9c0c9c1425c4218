"""Bounds and rate limit of the base-drive wheel-speed scale."""

from __future__ import annotations

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

    def bounds(self, previous: float, dt: float) -> tuple[float, float]:
        """(lower, upper) for a previous scale and a period [s]."""
        lo = max(self.minimum, min(previous, 1.0) - self.rate * dt)
        hi = min(1.0, max(previous, self.minimum) + self.rate * dt)
        hi = max(lo, min(hi, self.cap))
        return lo, hi

    def compute(self, ctx) -> Box | None:
        """Box on s; None when the layout has no speed scale."""
        if ctx.layout.scale is None:
            return None
        lb, ub = unbounded(ctx.layout.n)
        lb[ctx.layout.scale], ub[ctx.layout.scale] = self.bounds(ctx.speed_scale, ctx.dt)
        return Box(lb, ub)
