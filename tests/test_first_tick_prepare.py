"""What the MPC's first tick would make of its structure alone is made when it is built.

`wbc.structure.prepare_planner` (run by the controller's construction) also makes the C
force tick's kept buffers and its row plan of every wheel in contact
(`wbc.constraints.force_tick.ForceTick.prepare`), and the solver's row structure, C
screening and constant blocks' screening sums of the rows the constraints fix
(`wbc.structure.PreparedRows`, `wbc.solvers.DaqpBackend.prepare`): the first tick, all wheels in
contact, finds them and makes none again. Their bits are the unprepared controller's
(`tests/test_structure_prepare.py` compares every QP, plan and command).
"""

from dataclasses import replace

import numpy as np
import pytest

from estimators.margin_kernel import MARGIN_STEP
from estimators.uncertainty import prepare_margin
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


def test_a_prepared_margin_is_found_and_gives_an_unprepared_ones_bits(machine):
    """`estimators.uncertainty.prepare_margin` (the closed loop, before its clock starts)."""
    pairs = []
    for _ in range(2):
        model, split = estimator_models(machine, "full")
        ctrl = MpcController(machine, ControllerConfig(), force_model=model, feedback=split)
        pairs.append((ctrl.force_model, ctrl.feedback.closure))
    (model, closure), (plain, plain_closure) = pairs
    if model._est._kernels is None or not model._est._kernels.compiled:
        pytest.skip("no compiled kernels")
    calls = model._est._calls.__dict__
    before = set(calls)
    kept = (model._last, model.n_clipped, closure._stepped)
    prepare_margin(closure, model)
    made = set(calls) - before
    assert len(made) == 1  # the joint kernel's terms
    key = made.pop()
    terms = calls[key]
    assert (model._last, model.n_clipped, closure._stepped) == kept  # nothing of a state
    state = replace(make_state(machine), suspension_force=np.array([3e4, 4e4]))
    got = model.linearize_with_margin(state, closure, MARGIN_STEP)
    ref = plain.linearize_with_margin(state, plain_closure, MARGIN_STEP)
    assert calls[key] is terms and set(calls) == before | {key}  # found, not made again
    assert got[0]._row.tobytes() == ref[0]._row.tobytes()
    assert len(got[1]) == len(ref[1])
    assert all(np.asarray(a).tobytes() == np.asarray(b).tobytes()
               for a, b in zip(got[1], ref[1]))


def test_the_side_reserve_says_no_rows_without_a_reserve(machine):
    model, split = estimator_models(machine, "full")
    config = ControllerConfig()
    config = replace(config, force=replace(config.force, side_reserve=500.0))
    ctrl = MpcController(machine, config, force_model=model, feedback=split)
    side = ctrl.side_reserve
    pl = ctrl.planner
    ctx = StructureContext(pl.layout, pl.prediction, pl.dt, pl.limits, ctrl.warp)
    assert side.prepare(ctx) == 0
    side.set_reserve(np.array([1000.0, 0.0]))
    assert side.prepare(ctx) is None
