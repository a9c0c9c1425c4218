"""`wbc.qp.QPBuilder` keeps its bounds while every box is the last tick's read-only one.

The kept path must give a fresh builder's bytes (`tests/test_mpc_assembly.py` checks the
MPC's QPs); here: that it is taken, that a changed box is taken at once, that a writable
box is never kept, that empty bounds still raise, and `SpeedScaleLimit`'s kept box.
"""

import numpy as np
import pytest

from testkit.plant import make_state, moving_mpc
from wbc import (
    AccelerationLimit,
    AxisLimits,
    Box,
    JointTask,
    QPContext,
    SpeedScaleLimit,
    VariableLayout,
    build_qp,
)
from wbc.errors import WbcError
from wbc.qp import QPBuilder

DT = 0.01


class _Fixed:
    """A constraint returning the box it holds (its arrays as given)."""

    def __init__(self, box):
        self.box = box

    def compute(self, ctx):
        return self.box


def _ctx(machine, scale: float = 1.0):
    st = make_state(machine)
    layout = VariableLayout(speed_scale=True)
    return QPContext.from_state(st, DT, layout, AxisLimits.from_machine(machine), None, scale)


def _bytes(qp):
    return qp.lb.tobytes(), qp.ub.tobytes()


def test_kept_bounds_in_the_mpc_loop(machine):
    ctrl, plant = moving_mpc(machine, ticks=2)
    builder = ctrl.planner.builder
    kept = 0
    for _ in range(20):
        before = builder._bounds_kept
        ctx = ctrl.context(plant.state)
        qp = builder.build(ctx)
        fresh = build_qp(ctx, ctrl.planner.tasks, ctrl.planner.constraints)
        assert _bytes(qp) == _bytes(fresh)
        kept += before is not None and builder._bounds_kept is before
        plant.apply(ctrl.step(plant.state))
    assert kept > 10


def test_changed_box_is_taken(machine):
    speed = SpeedScaleLimit(0.0, rate=0.5)
    builder = QPBuilder([JointTask(range(9), 1.0, 1.0)], [AccelerationLimit(), speed])
    ctx = _ctx(machine)
    first = builder.build(ctx)
    assert _bytes(builder.build(ctx)) == _bytes(first)  # the kept bounds
    speed.cap = 0.5  # a new box
    got = builder.build(ctx)
    fresh = build_qp(ctx, builder.tasks, builder.constraints)
    assert _bytes(got) == _bytes(fresh) and _bytes(got) != _bytes(first)
    assert got.lb is not first.lb and got.ub is not first.ub


def test_writable_box_is_not_kept_and_empty_bounds_raise(machine):
    ctx = _ctx(machine)
    n = ctx.layout.n
    lower, upper = np.full(n, -1.0), np.full(n, 1.0)
    builder = QPBuilder([], [_Fixed(Box(lower, upper))])
    builder.build(ctx)
    assert builder._bounds_kept is None
    lower[3] = 2.0  # written in place: seen at the next build
    with pytest.raises(WbcError, match="empty bounds"):
        builder.build(ctx)
    lower[3] = -1.0
    lower.setflags(write=False)
    upper.setflags(write=False)
    assert builder.build(ctx).lb[3] == -1.0 and builder._bounds_kept is not None


def test_speed_scale_box_is_kept_while_its_bounds_stay(machine):
    lim = SpeedScaleLimit(0.0, rate=0.5)
    box = lim.compute(_ctx(machine))
    assert not box.lower.flags.writeable and not box.upper.flags.writeable
    assert lim.compute(_ctx(machine)) is box
    moved = lim.compute(_ctx(machine, 0.5))
    assert moved is not box
    assert (moved.lower[-1], moved.upper[-1]) == lim.bounds(0.5, DT)
    zero = SpeedScaleLimit(0.0, rate=0.5)
    zero.cap = 0.0
    a = zero.compute(_ctx(machine, 0.0))
    zero.minimum = -0.0  # a zero of the other sign is another bound
    b = zero.compute(_ctx(machine, 0.0))
    assert b is not a and np.signbit(b.lower[-1]) and not np.signbit(a.lower[-1])
