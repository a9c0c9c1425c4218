"""The MPC force rows in one C call (`wbc.constraints.force_tick`, ``force_rows``).

A prepared constraint's tick writes the force map ``(A, b)`` and the rows ``G x <= h`` in
one C call from the nodes' kernel rows; `ForceRowsConstraint.compute` on `_forces_and_flags`
(the C force map on the same rows, then numpy's rows) is the reference: the same bits on
real ticks, with and without the speed scale, the feedback, the warp drift, on three wheels
and on none.
"""

import dataclasses

import numpy as np
import pytest

from models.state import WheelContacts
from testkit.plant import turning_mpc
from wbc.constraints.force_map_c import compiled_force_map
from wbc.constraints.force_rows import ForceRowsConstraint
from wbc.constraints.force_tick import row_plan
from wbc.force_models.feedback import ForceFeedback

pytestmark = pytest.mark.skipif(compiled_force_map() is None, reason="no C compiler")


def _both(con, ctx):
    """(`compute` on the tick path, its logged map), the same of the reference; C used."""
    used = []
    fmap = con._compiled_map
    evaluate = fmap.evaluate_tick

    def spy(*args, **kwargs):
        result = evaluate(*args, **kwargs)
        used.append(result is not None)
        return result

    fmap.evaluate_tick = spy
    try:
        got = con.compute(ctx)
    finally:
        del fmap.evaluate_tick
    logged = (*con.last_forces_map, con.last_in_contact, con.linearization_steps)
    ref = ForceRowsConstraint.compute(con, ctx)
    ref_logged = (*con.last_forces_map, con.last_in_contact, con.linearization_steps)
    return (got, logged), (ref, ref_logged), used


def _same(con, ctx, tick: bool = True):
    (got, logged), (ref, ref_logged), used = _both(con, ctx)
    assert used == ([True] if tick else [])
    for a, b in zip(logged, ref_logged):
        assert a.shape == b.shape and a.tobytes() == b.tobytes()
    if ref is None:
        assert got is None
        return None
    assert got.G.shape == ref.G.shape and got.G.tobytes() == ref.G.tobytes()
    assert got.h.shape == ref.h.shape and got.h.tobytes() == ref.h.tobytes()
    assert got.diagonal is None and got.G.flags.writeable
    return got


@pytest.mark.parametrize("speed_scale", [False, True])
def test_the_tick_is_the_reference_rows_bits(machine, speed_scale):
    ctrl, states = turning_mpc(machine, speed_scale)
    con = ctrl.force_constraint
    assert con._tick.rows is not None  # prepared by the controller
    for st in states[-3:]:
        ctx = ctrl.context(st)
        assert ctx.warp is not None and ctx.feedback is not None
        assert (ctx.layout.scale is not None) == speed_scale
        got = _same(con, ctx)
        assert got.G.shape[0] == 4 * con._structure(ctx).nodes.size
        assert np.any(got.G[:, ctx.layout.slack] == -1.0)
        fb = ctx.feedback  # a load split the model misses: a bias in every row
        split = ForceFeedback.of(fb.forces + [120.0, -40.0, 75.0, -300.0], fb.model_forces,
                                 fb.in_contact, fb.time)
        assert np.all(split.bias != 0)
        _same(con, dataclasses.replace(ctx, feedback=split))


def _lifted(ctrl, st):
    points = ctrl.force_constraint.model.estimate(st).contact_points
    contacts = WheelContacts(np.array([True, True, True, False]), np.zeros((4, 3)), points,
                             np.tile(st.base_rotation[2], (4, 1)))  # a rear wheel lifted
    return ctrl.context(dataclasses.replace(st, contacts=contacts))


def test_three_wheels_thresholds_a_drift_and_no_feedback(machine):
    ctrl, states = turning_mpc(machine, True)
    con = ctrl.force_constraint
    st = states[-1]
    ctx = _lifted(ctrl, st)
    con.thresholds = np.array([1500.0, 2500.0, 3500.0, 4500.0])  # the lifted wheel's moves
    drifting = dataclasses.replace(ctrl.context(st),
                                   warp_drift=np.linspace(-50.0, 80.0, ctx.n_steps + 1))
    for c, wheels in ((ctx, 3), (dataclasses.replace(ctx, feedback=None), 3), (drifting, 4)):
        got = _same(con, c)
        assert con.last_in_contact.sum() == wheels
        assert got.G.shape[0] == wheels * con._structure(c).nodes.size


def test_no_wheel_in_contact_logs_the_map_and_has_no_rows(machine):
    """No wheel: a tipping state, no kernel rows; the tick goes on as the reference."""
    ctrl, states = turning_mpc(machine, False)
    con = ctrl.force_constraint
    st = states[-1]
    points = con.model.estimate(st).contact_points
    none = WheelContacts(np.zeros(4, bool), np.zeros((4, 3)), points,
                         np.tile(st.base_rotation[2], (4, 1)))
    ctx = ctrl.context(dataclasses.replace(st, contacts=none))
    assert _same(con, ctx, tick=False) is None


def test_unprepared_or_other_rows_take_the_reference_path(machine):
    ctrl, states = turning_mpc(machine, False)
    con = ctrl.force_constraint
    ctx = ctrl.context(states[-1])
    con._tick.rows = None  # not prepared: `ForceRowsConstraint.compute`
    got = con.compute(ctx)
    ref = ForceRowsConstraint.compute(con, ctx)
    assert got.G.tobytes() == ref.G.tobytes() and got.h.tobytes() == ref.h.tobytes()


def test_row_plan():
    plan, at = row_plan(slice(4, 12), (np.arange(8), 100 + np.arange(8) % 4), 3, 110)
    assert at == plan.ctypes.data
    np.testing.assert_array_equal(plan[:2], [8, 12])
    np.testing.assert_array_equal(plan[2:10], np.arange(4, 12))
    np.testing.assert_array_equal(plan[14:22], np.arange(8) % 4)
    np.testing.assert_array_equal(plan[26:34], 100 + np.arange(8) % 4)
    assert np.all(plan[34:] == -1)
    plan, _ = row_plan(np.array([0, 2, 5]), None, 2, 10)
    np.testing.assert_array_equal(plan[:5], [3, 8, 0, 2, 5])
    np.testing.assert_array_equal(plan[10:13], [0, 2, 1])
    assert np.all(plan[18:] == -1)
    assert row_plan(None, None, 2, 10)[0][0] == 0
    with pytest.raises(ValueError):
        row_plan(np.array([8]), None, 2, 10)  # past the 4 n_eval rows of A
    with pytest.raises(ValueError):
        row_plan(slice(0, 2), (np.arange(2), np.array([3, 10])), 2, 10)  # a column past n
