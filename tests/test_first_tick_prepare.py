"""What the MPC's first tick would make of its structure alone is made when it is built.

`wbc.structure.prepare_planner` (run by the controller's construction) also makes the C
force tick's kept buffers and its row plan of every wheel in contact
(`wbc.constraints.force_tick.ForceTick.prepare`), and the solver's row structure, C
screening and constant blocks' screening sums of the rows the constraints fix
(`wbc.structure.PreparedRows`, `wbc.solvers.DaqpBackend.prepare`): the first tick, all wheels in
contact, finds them and makes none again. Their bits are the unprepared controller's
(`tests/test_structure_prepare.py` compares every QP, plan and command).
"""

import numpy as np
import pytest

from testkit.plant import KinematicPlant, make_state
from wbc import ControllerConfig, JointGoal, MpcController
from wbc.controllers.registry import estimator_models
from wbc.solvers import DaqpBackend
from wbc.structure import StructureContext, prepared_rows


def _first_tick(machine):
    model, split = estimator_models(machine, "full")
    ctrl = MpcController(machine, ControllerConfig(), force_model=model, feedback=split)
    st = make_state(machine)
    ctrl.set_goal(JointGoal(crane=st.q[2:9] + 0.1, suspension=st.q[:2] + 0.03))
    return ctrl, lambda: ctrl.step(KinematicPlant(st, 0.01).state)


def test_the_prepared_rows_are_the_first_qps(machine):
    ctrl, step = _first_tick(machine)
    pl = ctrl.planner
    ctx = StructureContext(pl.layout, pl.prediction, pl.dt, pl.limits, ctrl.warp)
    rows = prepared_rows(pl.constraints, pl.builder.prepare(ctx), ctx)  # made again: the same
    assert rows.constant_rows and rows.diagonal_rows
    qps = []
    build = ctrl.planner.builder.build
    ctrl.planner.builder.build = lambda ctx: qps.append(build(ctx)) or qps[-1]
    assert not step().fallback
    qp = qps[0]
    assert rows.m == qp.G.shape[0]
    assert [f for f, _ in rows.constant_rows] == [f for f, _ in qp.constant_rows]
    assert all(a is b for (_, a), (_, b) in zip(rows.constant_rows, qp.constant_rows))
    assert rows.diagonal_rows == qp.diagonal_rows
    # the bounds the constant blocks' columns have at the tick
    for _, block in rows.constant_rows:
        cols = np.flatnonzero(np.abs(block).sum(axis=0))
        assert rows.lb[cols].tobytes() == qp.lb[cols].tobytes()
        assert rows.ub[cols].tobytes() == qp.ub[cols].tobytes()


def test_the_first_solve_finds_the_solvers_structure_screen_and_sums(machine):
    ctrl, step = _first_tick(machine)
    solver = ctrl.planner.solver
    if not isinstance(solver, DaqpBackend) or not solver.screen:
        pytest.skip("not the screening DAQP backend")
    structure, screen = solver._rows_structure, solver._screen_c
    sums = dict(solver._sums._screens)
    assert structure is not None and sums
    assert (screen is not None) == solver.compiled
    assert solver._lam is None and solver._inv_factor is None  # nothing of a solve
    assert not step().fallback
    assert solver._rows_structure is structure and solver._screen_c is screen
    assert all(solver._sums._screens[k][3] is v[3] for k, v in sums.items())


def test_the_first_tick_finds_the_force_ticks_buffers_and_row_plan(machine):
    model, split = estimator_models(machine, "full")
    ctrl = MpcController(machine, ControllerConfig(), force_model=model, feedback=split)
    tick = ctrl.force_constraint._tick
    if tick.rows is None:
        pytest.skip("no compiled force map or node kernel (no C compiler)")
    kept, plan = tick._kept, tick._plan
    assert kept is not None and plan is not None
    assert plan[2] == bytes([1, 1, 1, 1])  # the flags of every wheel in contact
    st = make_state(machine)
    ctrl.set_goal(JointGoal(crane=st.q[2:9] + 0.1, suspension=st.q[:2] + 0.03))
    cmd = ctrl.step(KinematicPlant(st, 0.01).state)
    assert not cmd.fallback and ctrl.force_constraint.last_in_contact.all()
    assert tick._kept is kept and tick._plan is plan  # found, not made again
