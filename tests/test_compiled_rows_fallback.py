"""The compiled constraint rows hand arrays of another layout to their numpy path: same bits."""

import dataclasses

import numpy as np
import pytest

from estimators.efforts import ActuatorEfforts
from testkit.force_models import AffineForceModel
from testkit.plant import make_state, moving_mpc
from wbc import ControllerConfig, ForceConfig, MpcController
from wbc.constraints import HorizonEffortLimit, SideReserveConstraint
from wbc.constraints.limits_c import CompiledEffortRows, compiled_effort_rows, plain_address
from wbc.constraints.side_reserve_c import CompiledSideReserve

pytestmark = pytest.mark.skipif(compiled_effort_rows(1, 1, 1, 1, 1, 0) is None,
                                reason="no C compiler")


def test_plain_address_takes_c_contiguous_float64_arrays_only():
    a = np.arange(12.0).reshape(3, 4)
    assert plain_address(a) == a.ctypes.data
    read_only = a.copy()
    read_only.setflags(write=False)
    assert plain_address(read_only) == read_only.ctypes.data
    assert plain_address(a[1:]) == a[1:].ctypes.data  # a contiguous view
    for other in (a[:, ::2], a.T, a.astype(np.float32), a.tolist(), np.asfortranarray(a)):
        assert plain_address(other) is None


def _spy(monkeypatch, cls, name):
    made = []
    method = getattr(cls, name)

    def spy(self, *args):
        result = method(self, *args)
        made.append(result is not None)
        return result
    monkeypatch.setattr(cls, name, spy)
    return made


def test_effort_rows_of_fortran_brake_inputs_are_the_numpy_paths(machine, monkeypatch):
    ctrl, plant = moving_mpc(machine, dt=0.01)
    ctx = ctrl.context(plant.state)
    made = _spy(monkeypatch, CompiledEffortRows, "rows_of_pair")
    efforts = ActuatorEfforts(machine)
    compiled, reference = HorizonEffortLimit(efforts), HorizonEffortLimit(efforts, compiled=False)
    for brake in (ctx.brake_inputs, np.asfortranarray(ctx.brake_inputs + 3.0)):
        c = dataclasses.replace(ctx, brake_inputs=brake)
        got, want = compiled.compute(c), reference.compute(c)
        assert got.G.tobytes() == want.G.tobytes() and got.h.tobytes() == want.h.tobytes()
    assert made == [True, False]  # the second through the numpy products, C rows


def test_side_rows_of_a_strided_forces_map_are_the_numpy_paths(machine, monkeypatch):
    st = make_state(machine)
    ctrl = MpcController(machine, ControllerConfig(force=ForceConfig(side_reserve_z=2.0)),
                         force_model=AffineForceModel.reference(machine, st.q))
    ctrl.step(st)
    ctx = ctrl.context(st)
    fc = ctrl.force_constraint
    fc.compute(ctx)
    made = _spy(monkeypatch, CompiledSideReserve, "rows")
    compiled, reference = SideReserveConstraint(fc), SideReserveConstraint(fc, compiled=False)
    A, b = fc.last_forces_map
    wide = np.zeros((A.shape[0], 2 * A.shape[1]))
    wide[:, ::2] = A
    for forces in ((A, b), (wide[:, ::2], b)):
        fc.last_forces_map = forces
        for con in (compiled, reference):
            con.set_reserve([1500.0, 3000.0])
        got, want = compiled.compute(ctx), reference.compute(ctx)
        assert got.G.tobytes() == want.G.tobytes() and got.h.tobytes() == want.h.tobytes()
    assert made == [True, False]
