"""Axis limits in C (`wbc.constraints.limits_c`): the bounds and brake inputs = numpy's."""

import dataclasses

import numpy as np
import pytest

from testkit.plant import make_state
from wbc import AxisLimits, PositionLimit, QPContext, VariableLayout, VelocityLimit
from wbc.constraints.limits_c import compiled_bounds

DT = 0.01

pytestmark = pytest.mark.skipif(compiled_bounds("velocity_bounds") is None,
                                reason="no C compiler")


def _contexts(machine, limits, n: int, seed: int):
    """States inside, at and past the limits, moving fast both ways; two with a NaN."""
    rng = np.random.default_rng(seed)
    lo, hi = machine.coordinates.lower, machine.coordinates.upper
    st = make_state(machine)
    for k in range(n):
        span = hi[:9] - lo[:9]
        q = lo[:9] + span * rng.uniform(-0.05, 1.05, 9)
        if k % 5 == 0:  # exactly at an end
            q = np.where(rng.random(9) < 0.5, lo[:9], hi[:9])
        qd = rng.normal(0.0, 1.0, 9) * np.abs(limits.velocity_upper)
        if k == n - 1:
            qd[4] = np.nan
        if k == n - 2:  # NaN against a finite brake: numpy's rule gives NaN
            q[2] = np.nan
        ctx = QPContext.from_state(st, DT * rng.uniform(0.5, 2.0), VariableLayout(), limits)
        ctx.__dict__.update(q=q, qd=qd)  # what a state could not hold (past the ends, NaN)
        yield ctx


@pytest.mark.parametrize("make", [lambda: PositionLimit(),
                                  lambda: PositionLimit(horizon=0.3, braking_fraction=0.8),
                                  lambda: VelocityLimit()])
def test_compiled_bounds_are_numpys_to_the_bit(machine, make):
    limits = AxisLimits.from_machine(machine)
    compiled, reference = make(), make()
    reference.compiled = False
    for ctx in _contexts(machine, limits, 60, 3):
        a, b = compiled.compute(ctx), reference.compute(ctx)
        assert compiled._c is not None
        np.testing.assert_array_equal(a.lower, b.lower)
        np.testing.assert_array_equal(a.upper, b.upper)
    # A second limits object (another machine's) reaches the C constants too.
    other = dataclasses.replace(limits, position_upper=limits.position_upper - 0.01,
                                velocity_upper=0.5 * limits.velocity_upper)
    ctx = next(_contexts(machine, other, 1, 4))
    a, b = compiled.compute(ctx), reference.compute(ctx)
    np.testing.assert_array_equal(a.lower, b.lower)
    np.testing.assert_array_equal(a.upper, b.upper)


def test_brake_inputs_in_c_are_numpys_to_the_bit():
    """Moving, at rest, exactly stoppable in one step, a NaN speed; uniform and long steps."""
    from wbc.layout import VariableLayout
    from wbc.mpc.prediction import CondensedPrediction

    rng = np.random.default_rng(8)
    for steps in (0.05, np.r_[0.01, np.full(11, 0.09)]):
        lay = VariableLayout(n_steps=12)
        compiled, reference = CondensedPrediction(lay, steps), CondensedPrediction(lay, steps)
        reference._brake = None
        a = rng.uniform(0.2, 2.0, 9)
        for k in range(40):
            qd = rng.normal(0.0, 0.5, 9) * (k % 4 != 0)  # every fourth at rest
            if k == 5:
                qd[3] = a[3] * 0.01  # stops within the first step
            if k == 7:
                qd[6] = np.nan
            q = rng.normal(0.0, 1.0, 9)
            out_c = compiled.brake_trajectory(q, qd, a)
            out_r = reference.brake_trajectory(q, qd, a)
            assert compiled._brake is not None
            for x, y in zip(out_c, out_r):
                np.testing.assert_array_equal(x, y)
                real = ~np.isnan(y)  # -0 too (a NaN's sign is not arithmetic's)
                np.testing.assert_array_equal(np.signbit(x[real]), np.signbit(y[real]))
