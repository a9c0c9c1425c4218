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

    @staticmethod
    def _viable_speed(b, dt, d, v):
        """Largest speed towards the limit after one period that can still stop [m/s]."""
        rest = np.maximum(d - 0.5 * v * dt, 0.0)
        return -b * dt + np.sqrt((b * dt) ** 2 + 2.0 * b * rest)

    def compute(self, ctx) -> Box:
        """Box on step 0's accelerations."""
        lim, dt, q, qd = ctx.limits, ctx.dt, ctx.q, ctx.qd
        T = dt if self.horizon is None else self.horizon
        b = self.braking_fraction * lim.acceleration
        d_up = lim.position_upper - q
        d_lo = q - lim.position_lower
        upper = np.minimum(2.0 * (d_up - qd * T) / T**2,
                           (self._viable_speed(b, dt, d_up, qd) - qd) / dt)
        lower = np.maximum(-2.0 * (d_lo + qd * T) / T**2,
                           (-self._viable_speed(b, dt, d_lo, -qd) - qd) / dt)
        brake = lim.brake_acceleration(qd, dt)
        n = ctx.layout.n
        lb, ub = np.full(n, -np.inf), np.full(n, np.inf)
        s = ctx.layout.step(0)
        lb[s], ub[s] = np.minimum(lower, brake), np.maximum(upper, brake)
        return Box(lb, ub)
