"""Stroke and joint position limits as acceleration bounds."""

from __future__ import annotations

import numpy as np

from wbc.constraints.constraint import Box, Constraint
from wbc.errors import ConfigurationError

__all__ = ["PositionLimit"]


class PositionLimit(Constraint):
    r"""Keep each axis inside ``[q_lo, q_hi]`` through bounds on its acceleration.

    Two bounds, the tighter one kept (upper side; the lower side is symmetric), with
    ``d = q_hi - q`` the distance left:

    * horizon: the position after ``T`` at constant acceleration stays inside,
      ``q + \dot q T + \tfrac12 \ddot q T^2 \le q_{hi}``, i.e.
      ``\ddot q \le 2 (d - \dot q T) / T^2``;
    * viability: after one period ``dt`` the axis can still stop before the limit at the
      braking deceleration ``b = braking_fraction * a_max``. With ``v' = \dot q + \ddot q\, dt``
      and the distance left after the period ``d' = d - (\dot q + v') dt / 2`` (trapezoidal
      rule), a discrete stop from ``v'`` covers at most ``v'^2 / (2 b) + v' dt / 2``; asking
      for no more than ``d'`` gives
      ``v' \le -b\, dt + \sqrt{b^2 dt^2 + 2 b (d - \dot q\, dt / 2)}``.

    Both are relaxed to admit the braking acceleration (`AxisLimits.brake_acceleration`),
    so that a state past its limit is braked rather than declared infeasible.

    Args:
        horizon: T [s]; None: the control period.
        braking_fraction: Fraction of the acceleration limit used for braking, in (0, 1].
    """

    def __init__(self, horizon: float | None = None, braking_fraction: float = 0.5):
        if horizon is not None and not horizon > 0:
            raise ConfigurationError(f"horizon must be > 0, got {horizon}")
        if not 0 < braking_fraction <= 1:
            raise ConfigurationError(f"braking_fraction must be in (0, 1], got "
                                     f"{braking_fraction}")
        self.horizon = horizon
        self.braking_fraction = float(braking_fraction)
        self._key: tuple | None = None
        self._const: tuple = ()

    def _constants(self, lim, dt: float) -> tuple:
        """``(b dt, (b dt)^2, 2 b)`` of both sides (18,), kept for the limits and period."""
        if self._key is None or self._key[0] is not lim or self._key[1] != dt:
            b = self.braking_fraction * lim.acceleration
            bdt = np.concatenate((b, b)) * dt
            self._key = (lim, dt)
            self._const = (bdt, bdt**2, 2.0 * np.concatenate((b, b)))
        return self._const

    def compute(self, ctx) -> Box:
        """Box on step 0's accelerations."""
        lim, dt, q, qd = ctx.limits, ctx.dt, ctx.q, ctx.qd
        T = dt if self.horizon is None else self.horizon
        bdt, bdt2, two_b = self._constants(lim, dt)
        # Both sides in one pass: the upper side (distance d = q_hi - q, speed v = qd towards
        # it) and the lower side mirrored (d = q - q_lo, v = -qd), whose bound is the negated
        # upper one: the same operations on each element as side by side.
        d = np.concatenate((lim.position_upper - q, q - lim.position_lower))
        v = np.concatenate((qd, -qd))
        rest = np.maximum(d - 0.5 * v * dt, 0.0)
        viable = -bdt + np.sqrt(bdt2 + two_b * rest)  # the largest speed that can still stop
        bound = np.minimum(2.0 * (d - v * T) / T**2, (viable - v) / dt)
        brake = ctx.brake
        n, s = ctx.layout.n, ctx.layout.step(0)
        lb, ub = np.full(n, -np.inf), np.full(n, np.inf)
        m = s.stop - s.start
        lb[s], ub[s] = np.minimum(-bound[m:], brake), np.maximum(bound[:m], brake)
        return Box(lb, ub)
