"""The side reserve's compiled rows against its numpy rows: the same bits."""

from __future__ import annotations

import numpy as np
import pytest

from testkit.force_models import AffineForceModel
from testkit.plant import make_state
from wbc import ControllerConfig, ForceConfig, MpcController
from wbc.constraints import SideReserveConstraint
from wbc.constraints.side_reserve_c import compiled_side_reserve


def _rows(nodes=(1, 2), sides=(0,), slack=(3, 3), n=4, n_forces=12):
    return compiled_side_reserve(np.array(nodes), np.array(sides), np.array(slack),
                                 np.ones(len(slack)), n, n_forces, slice(0, 2), 2)


pytestmark = pytest.mark.skipif(_rows() is None, reason="no C compiler or numpy's BLAS")


@pytest.fixture
def side_context(machine):
    """A controller with the side rows after one step, its context, the rows' forces."""
    st = make_state(machine)
    model = AffineForceModel.reference(machine, st.q)
    ctrl = MpcController(machine, ControllerConfig(force=ForceConfig(side_reserve_z=2.0)),
                         force_model=model)
    ctrl.step(st)
    ctx = ctrl.context(st)
    ctrl.force_constraint.compute(ctx)
    return ctrl, ctx


@pytest.mark.parametrize("reserve", [[0.0, 2500.0], [1200.0, 0.0], [4000.0, 1e5]])
def test_compiled_side_rows_are_numpys_to_the_bit(side_context, reserve):
    ctrl, ctx = side_context
    fc = ctrl.force_constraint
    compiled = SideReserveConstraint(fc)
    reference = SideReserveConstraint(fc, compiled=False)
    A0, b0 = (a.copy() for a in fc.last_forces_map)
    rng = np.random.default_rng(3)
    for trial in range(4):
        # other forces each trial, some nominal sums short and some with room; a NaN in
        # a row at the last (numpy's maximum keeps it, C's fmax would not)
        A = A0 * rng.uniform(0.5, 1.5)
        if trial == 3:
            A[[8, 10], 0] = np.nan  # node 2, a wheel of each side
        fc.last_forces_map = (A, b0 + rng.normal(scale=2000.0, size=b0.shape))
        for con in (compiled, reference):
            con.set_reserve(reserve)
        got, want = compiled.compute(ctx), reference.compute(ctx)
        assert compiled._cache[1][-1] is not None and reference._cache[1][-1] is None
        assert got.G.tobytes() == want.G.tobytes()
        assert got.h.tobytes() == want.h.tobytes()
        assert got.h.size > 0 and np.isnan(got.h).any() == (trial == 3)


def test_other_shapes_are_refused():
    rows = _rows()
    ok = (np.zeros((12, 4)), np.zeros(12), np.zeros(2))
    assert rows.rows(*ok, 1.0, 2.0, 1.0, 1.0) is not None
    with pytest.raises(ValueError, match="side rows"):
        rows.rows(np.zeros((12, 5)), *ok[1:], 1.0, 2.0, 1.0, 1.0)
    with pytest.raises(ValueError, match="side rows"):
        rows.rows(*ok[:2], np.zeros(3), 1.0, 2.0, 1.0, 1.0)
    # another layout than one C array: the numpy path's
    assert rows.rows(np.zeros((12, 8))[:, ::2], *ok[1:], 1.0, 2.0, 1.0, 1.0) is None
    assert rows.rows(ok[0], ok[1].astype(np.float32), ok[2], 1.0, 2.0, 1.0, 1.0) is None
    for bad in ({"slack": (3, 4)}, {"nodes": (1, 3)}):  # past G's columns, past A's nodes
        with pytest.raises(ValueError, match="inconsistent"):
            _rows(**bad).rows(*ok, 1.0, 2.0, 1.0, 1.0)
    assert _rows(nodes=(1,)) is None  # one row: numpy's product is a dot
