"""The MPC force rows' tick path on kernel rows (`HorizonNormalForceConstraint._rows_map`).

The tick linearizes node 0 and the later nodes in one compiled call
(`estimators.payload.PayloadEstimator.linearize_nodes`, base rotations predicted in C) and
hands the rows straight to the C force map; `forces_map` (the model's `linearize`, one
`ForceLinearization` per node, the rotations of `wbc.mpc.prediction.predict_base_rotations`)
is the reference: the same bits, on real ticks.
"""

import dataclasses

import numpy as np
import pytest

from models.state import WheelContacts
from testkit.plant import turning_mpc
from wbc.constraints.force_map_c import compiled_force_map

pytestmark = pytest.mark.skipif(compiled_force_map() is None, reason="no C compiler")


def _both(con, ctx):
    """(A, b, flags) of the tick path, of `forces_map` on the objects; and the rows path ran."""
    used = []
    rows_map = con._rows_map

    def spy(*args):
        result = rows_map(*args)
        used.append(result is not None)
        return result

    con._rows_map = spy
    try:
        A, b, flags = con._forces_and_flags(ctx)
    finally:
        del con._rows_map
    steps = con.linearization_steps
    if hasattr(con.model, "_last"):
        con.model._last = None  # node 0 linearized again by `linearize`, not the tick's
    A_ref, b_ref = con.forces_map(ctx, flags)
    np.testing.assert_array_equal(steps, con.linearization_steps)
    return (A, b, flags), (A_ref, b_ref), used


@pytest.mark.parametrize("speed_scale", [False, True])
def test_the_tick_path_is_forces_maps_bits(machine, speed_scale):
    ctrl, states = turning_mpc(machine, speed_scale)
    con = ctrl.force_constraint
    for st in states[-3:]:
        ctx = ctrl.context(st)
        assert np.any(ctx.nominal_inputs != 0) and np.any(st.base_twist[3:] != 0)
        (A, b, flags), (A_ref, b_ref), used = _both(con, ctx)
        assert used == [True] and len(con.linearization_steps) > 1
        np.testing.assert_array_equal(A, A_ref)
        np.testing.assert_array_equal(b, b_ref)
        np.testing.assert_array_equal(flags, con.model.linearize(st).in_contact)


def test_three_wheels_a_drift_and_no_feedback(machine):
    ctrl, states = turning_mpc(machine, True)
    con = ctrl.force_constraint
    st = states[-1]
    points = con.model.estimate(st).contact_points  # the wheels' lowest points
    lifted = WheelContacts(np.array([True, True, True, False]), np.zeros((4, 3)), points,
                           np.tile(st.base_rotation[2], (4, 1)))  # a rear wheel lifted
    ctx = ctrl.context(dataclasses.replace(st, contacts=lifted))
    drifting = dataclasses.replace(ctrl.context(st),
                                   warp_drift=np.linspace(-50.0, 80.0, ctx.n_steps + 1))
    assert drifting.warp is not None
    for c, wheels in ((ctx, 3), (dataclasses.replace(ctx, feedback=None), 3), (drifting, 4)):
        (A, b, flags), (A_ref, b_ref), used = _both(con, c)
        assert used == [True] and flags.sum() == wheels
        np.testing.assert_array_equal(A, A_ref)
        np.testing.assert_array_equal(b, b_ref)


class _ObjectsOnly:
    """The model without ``linearize_nodes``: the tick takes the objects' path."""

    def __init__(self, model):
        self.model = model

    def estimate(self, state):
        return self.model.estimate(state)

    def linearize(self, state):
        return self.model.linearize(state)

    def linearize_states(self, *args):
        return self.model.linearize_states(*args)

    @property
    def n_clipped(self):
        return self.model.n_clipped


def test_without_rows_the_objects_path_gives_the_same(machine):
    ctrl, states = turning_mpc(machine, False)
    con = ctrl.force_constraint
    ctx = ctrl.context(states[-1])
    A, b, flags = con._forces_and_flags(ctx)
    model = con.model
    con.model = _ObjectsOnly(model)
    try:
        (A_obj, b_obj, flags_obj), _, used = _both(con, ctx)
    finally:
        con.model = model
    assert not any(used)
    np.testing.assert_array_equal(A, A_obj)
    np.testing.assert_array_equal(b, b_obj)
    np.testing.assert_array_equal(flags, flags_obj)


def test_nodes_it_leaves_to_one_by_one_fall_back(machine):
    """A later node out of range: no rows; the objects' path clips it (node 0 kept)."""
    ctrl, states = turning_mpc(machine, False)
    con = ctrl.force_constraint
    ctx = ctrl.context(states[-1])
    far = ctx.nominal_inputs.copy()
    far[:] = 0.0
    far[:, 1] = 40.0  # the telescope far past its range at the later nodes
    ctx = dataclasses.replace(ctx, nominal_inputs=far)
    clipped = con.model.n_clipped
    (A, b, _), (A_ref, b_ref), used = _both(con, ctx)
    assert not any(used) and con.model.n_clipped > clipped
    np.testing.assert_array_equal(A, A_ref)
    np.testing.assert_array_equal(b, b_ref)
