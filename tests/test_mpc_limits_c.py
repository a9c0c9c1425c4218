"""The MPC's effort rows and horizon limits in C (`wbc.constraints.limits_c`): numpy's."""

import dataclasses

import numpy as np
import pytest

from estimators.efforts import ActuatorEfforts
from testkit.plant import moving_mpc
from wbc.constraints import HorizonEffortLimit, HorizonPositionLimit, HorizonVelocityLimit
from wbc.constraints.limits_c import compiled_effort_rows

DT = 0.01

pytestmark = pytest.mark.skipif(compiled_effort_rows(1, 1, 1, 1, 1, 0) is None,
                                reason="no C compiler")


@pytest.fixture(scope="module")
def mpc_context(machine):
    """A context of the MPC a few ticks into a crane move (nominal inputs nonzero)."""
    ctrl, plant = moving_mpc(machine, dt=DT)
    return ctrl.context(plant.state)


def _brakes(ctx, rng):
    """The context's brake inputs, and ones far past every limit both ways, and a NaN."""
    big = ctx.brake_inputs + rng.normal(0.0, 50.0, ctx.brake_inputs.shape)
    nan = big.copy()
    nan[3, 4] = np.nan
    return ctx.brake_inputs, big, -big, nan


@pytest.mark.parametrize("n_linearizations", [1, 3])
def test_compiled_rows_are_numpys_to_the_bit(machine, mpc_context, n_linearizations):
    efforts = ActuatorEfforts(machine)
    compiled = HorizonEffortLimit(efforts, 0.05, n_linearizations)
    reference = HorizonEffortLimit(efforts, 0.05, n_linearizations, compiled=False)
    assert compiled._structure(mpc_context)[-1] is not None
    assert reference._structure(mpc_context)[-1] is None
    for brake in _brakes(mpc_context, np.random.default_rng(3)):
        ctx = dataclasses.replace(mpc_context, brake_inputs=brake)
        got, want = compiled.compute(ctx), reference.compute(ctx)
        assert got.G.shape == want.G.shape and got.h.shape == want.h.shape
        assert got.G.tobytes() == want.G.tobytes()
        assert got.h.tobytes() == want.h.tobytes()
        assert got.diagonal == want.diagonal
        np.testing.assert_array_equal(compiled.last_efforts, reference.last_efforts)
    # the relaxed bounds were exercised: some rows at the brake input's effort
    assert np.any(want.h > (1.0 - 0.05) * 2.0)


def test_new_bounds_are_taken(machine, mpc_context):
    """Replaced bound arrays reach the compiled rows (they are kept between ticks)."""
    efforts = ActuatorEfforts(machine)
    compiled = HorizonEffortLimit(efforts)
    reference = HorizonEffortLimit(efforts, compiled=False)
    compiled.compute(mpc_context)
    for con in (compiled, reference):
        con.upper = 0.5 * con.upper
        con.lower = 0.25 * con.lower
    got, want = compiled.compute(mpc_context), reference.compute(mpc_context)
    assert got.h.tobytes() == want.h.tobytes()


@pytest.mark.parametrize("limit", [HorizonPositionLimit, HorizonVelocityLimit])
def test_compiled_horizon_bounds_are_numpys_to_the_bit(mpc_context, limit):
    compiled, reference = limit(), limit(compiled=False)
    rng = np.random.default_rng(4)
    lim = mpc_context.limits
    for k, brake in enumerate(_brakes(mpc_context, rng)):
        free = mpc_context.free_positions + rng.normal(0.0, 0.5, brake.shape)
        if k == 3:
            free[5, 1] = np.nan
        ctx = dataclasses.replace(mpc_context, brake_positions=brake, brake_velocities=brake,
                                  free_positions=free, free_velocities=free)
        if k == 2:  # other bound arrays: copied again
            wide = {f: getattr(lim, f) * 3.0 for f in ("position_lower", "position_upper",
                                                        "velocity_lower", "velocity_upper")}
            ctx = dataclasses.replace(ctx, limits=dataclasses.replace(lim, **wide))
        got, want = compiled.compute(ctx), reference.compute(ctx)
        assert compiled._c[1] is not None and reference._c is None
        assert got.G is want.G or np.array_equal(got.G, want.G)
        assert got.h.tobytes() == want.h.tobytes()


@pytest.mark.parametrize("payload_mass, axes", [(None, None), (0.0, None), (613.0, None),
                                                 (613.0, (2, 4, 5, 8))])
def test_kept_rows_on_real_ticks_are_numpys_to_the_bit(machine, payload_mass, axes):
    """Tick after tick the compiled rows reuse their G when it is free, and stay numpy's.

    A G still held (here by ``held``) is not written again: the next tick gets a new one.
    The payload masses: the description's, none, and one past the anchors (the rows
    blended from the two masses' maps as `ActuatorEfforts.affine` blends them); the
    default axes (a slice) and others (an index).
    """
    ctrl, plant = moving_mpc(machine, ticks=2, dt=DT)
    efforts = ActuatorEfforts(machine, payload_mass)
    kwargs = {} if axes is None else {"axes": axes}
    compiled = HorizonEffortLimit(efforts, **kwargs)
    reference = HorizonEffortLimit(efforts, compiled=False, **kwargs)
    held, kept = None, None
    for tick in range(6):
        ctx = ctrl.context(plant.state)
        got, want = compiled.compute(ctx), reference.compute(ctx)
        assert got.G.tobytes() == want.G.tobytes()
        assert got.h.tobytes() == want.h.tobytes()
        assert compiled.last_efforts.tobytes() == reference.last_efforts.tobytes()
        if tick == 2:
            held, held_bytes = got.G, got.G.tobytes()
        elif tick > 2:
            assert got.G is not held  # not written while held
            assert held.tobytes() == held_bytes
        if tick == 4:
            kept = id(got.G)
        if tick == 5:
            assert id(got.G) == kept  # the free G again
        del got, want
        plant.apply(ctrl.step(plant.state))
