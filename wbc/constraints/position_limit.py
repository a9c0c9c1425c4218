"""Stroke and joint position limits as acceleration bounds."""

from __future__ import annotations

import numpy as np

from wbc.axes import N_AXES
from wbc.constraints.constraint import Box, Constraint, unbounded
from wbc.constraints.limits_c import compiled_bounds
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

    Attributes:
        compiled: Evaluate in C (`wbc.constraints.limits_c`, the same bits) when a C
            compiler is there; False: numpy.
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
        self.compiled = True
        self._c = compiled_bounds("position_bounds")  # None without a C compiler
        self._c_const: tuple | None = None  # the constants its input buffer holds

    def _constants(self, ctx) -> tuple:
        """What depends on the limits, the period and the layout only, kept while they do.

        ``(-b dt, (b dt)^2, 2 b)`` of both sides (18,), ``T`` and ``T^2``, and the scratch
        arrays (18,) of `compute` (this object's own, overwritten on every call).
        """
        lim, dt = ctx.limits, ctx.dt
        key = self._key
        if key is None or key[0] is not lim or key[1] != dt:
            self._key = (lim, dt)
            self._const = (*self.constants(lim, dt), np.empty(2 * N_AXES),
                           np.empty(2 * N_AXES), np.empty(2 * N_AXES))
        return self._const

    def constants(self, limits, dt: float) -> tuple:
        """``(-b dt, (b dt)^2, 2 b)`` of both sides (18,), ``T`` [s] and ``T^2`` [s^2].

        What the bounds take from ``limits`` (`AxisLimits`) and the period ``dt`` [s] alone
        (`wbc.controllers.tracking_c` reads them too).
        """
        b = self.braking_fraction * limits.acceleration
        bdt = np.concatenate((b, b)) * dt
        T = dt if self.horizon is None else self.horizon
        return -bdt, bdt**2, 2.0 * np.concatenate((b, b)), T, T**2

    def _compiled(self, const: tuple, lim, dt: float):
        """The C evaluation with ``const`` in its input buffer, or None (numpy)."""
        c = self._c if self.compiled else None
        if c is not None and self._c_const is not const:
            na = N_AXES
            inp = c.inp
            inp[3 * na:4 * na], inp[4 * na:5 * na] = lim.position_upper, lim.position_lower
            inp[5 * na:7 * na], inp[7 * na:9 * na], inp[9 * na:11 * na] = const[:3]
            inp[11 * na:] = const[3], const[4], dt
            self._c_const = const
        return c

    def compute(self, ctx) -> Box:
        """Box on step 0's accelerations."""
        lim, dt, q, qd = ctx.limits, ctx.dt, ctx.q, ctx.qd
        const = self._constants(ctx)
        c = self._compiled(const, lim, dt)
        if c is not None:
            inp = c.inp
            inp[:N_AXES], inp[N_AXES:2 * N_AXES], inp[2 * N_AXES:3 * N_AXES] = q, qd, ctx.brake
            c.call()
            lb, ub = unbounded(ctx.layout.n)
            s = ctx.layout.step(0)
            lb[s], ub[s] = c.out
            return Box(lb, ub)
        neg_bdt, bdt2, two_b, T, T2, d, v, x = const
        # Both sides in one pass: the upper side (distance d = q_hi - q, speed v = qd towards
        # it) and the lower side mirrored (d = q - q_lo, v = -qd), whose bound is the negated
        # upper one. Written into scratch arrays, in the order of the operations of
        # rest = max(d - 0.5 v dt, 0), viable = -b dt + sqrt((b dt)^2 + 2 b rest) and
        # bound = min(2 (d - v T) / T^2, (viable - v) / dt) on each element.
        np.subtract(lim.position_upper, q, out=d[:N_AXES])
        np.subtract(q, lim.position_lower, out=d[N_AXES:])
        v[:N_AXES] = qd
        np.negative(qd, out=v[N_AXES:])
        np.multiply(v, 0.5, out=x)
        x *= dt
        np.subtract(d, x, out=x)
        np.maximum(x, 0.0, out=x)  # the distance left after the period
        np.multiply(two_b, x, out=x)
        x += bdt2
        np.sqrt(x, out=x)
        x += neg_bdt  # the largest speed that can still stop
        x -= v
        x /= dt
        np.multiply(v, T, out=v)
        np.subtract(d, v, out=d)
        d *= 2.0
        d /= T2
        bound = np.minimum(d, x, out=x)
        brake = ctx.brake
        lb, ub = unbounded(ctx.layout.n)
        s = ctx.layout.step(0)
        np.minimum(np.negative(bound[N_AXES:]), brake, out=lb[s])
        np.maximum(bound[:N_AXES], brake, out=ub[s])
        return Box(lb, ub)
