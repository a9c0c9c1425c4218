"""The tasks' linear terms in C (`wbc.tasks.linear_c`) = the numpy loop's ``q``, bit for bit.

`wbc.qp.QPBuilder` writes the MPC's ``q`` with one compiled call while every active task
says its term, and skips asking the tasks while the terms' guards hold. The oracle is the
same builder with ``compiled=False`` (each task's ``compute_qp_objective`` and the in-place
sum): on real ticks of a moving crane, with the terms' variants (axes that are not a slice,
no warp drift, changed weights) and with context arrays the C does not read (then the
numpy loop runs).
"""

import copy
import dataclasses

import numpy as np
import pytest

from testkit.plant import moving_mpc
from wbc.qp import QPBuilder
from wbc.tasks import (
    HorizonInputTask,
    HorizonLevelingTask,
    HorizonSmoothnessTask,
    HorizonTrackingTask,
    SlackPenaltyTask,
    SpeedScaleTask,
    linear_c,
    object_fields_c,
)


def _ticks(machine, ticks: int):
    """``(ctrl, ctx)`` of ``ticks`` ticks of the MPC moving the crane."""
    ctrl, plant = moving_mpc(machine, ticks=2)
    for _ in range(ticks):
        yield ctrl, ctrl.context(plant.state)
        plant.apply(ctrl.step(plant.state))


def _same_q(builder: QPBuilder, oracle: QPBuilder, ctx) -> np.ndarray:
    got, want = builder.build(ctx), oracle.build(ctx)
    assert got.q.tobytes() == want.q.tobytes()
    assert got.P is want.P or got.P.tobytes() == want.P.tobytes()
    return got.q


def test_mpc_q_is_the_numpy_loops_bits_and_the_guard_skips_the_tasks(machine):
    seen, asked = 0, []
    for ctrl, ctx in _ticks(machine, 40):
        builder = ctrl.planner.builder
        if not asked:  # count the ticks that ask the tasks for their terms
            program = builder._program
            builder._program = lambda c: asked.append(1) or program(c)
        oracle = QPBuilder(builder.tasks, builder.constraints, builder.regularization,
                           compiled=False)
        assert builder._linear[2] is not None  # the compiled program runs
        q = _same_q(builder, oracle, ctx)
        seen += bool(np.any(q[:ctx.layout.n_axes * ctx.layout.n_steps]))
    assert seen > 30
    assert len(asked) <= 1  # the guards held from the prepared structure on


@pytest.fixture
def contexts(machine):
    return [ctx for _, ctx in _ticks(machine, 6)]


def _variants():
    return [HorizonTrackingTask([1, 4, 6], 10.0, 1.0, 3.0),  # columns not a slice
            HorizonTrackingTask([0, 1], [30.0, 20.0], 3.0),
            HorizonInputTask(np.linspace(0.1, 0.9, 9)),
            HorizonSmoothnessTask(np.linspace(1, 2, 9)),
            SpeedScaleTask(3.0), SlackPenaltyTask(5.0, 2.0),
            HorizonLevelingTask(2.0, 5e3)]


def test_every_kind_and_variant(contexts):
    tasks = _variants()
    builder, oracle = QPBuilder(tasks, []), QPBuilder(tasks, [], compiled=False)
    kinds = set()
    for ctx in contexts:
        for c in (ctx, dataclasses.replace(ctx, warp_drift=None),
                  dataclasses.replace(ctx, leveling_offset=-1234.5)):
            _same_q(builder, oracle, c)
            assert builder._linear[2] is not None
            kinds |= {t.kind for t in builder._linear[0]}
    assert kinds == {linear_c.CONSTANT, linear_c.TRACKING, linear_c.INPUT,
                     linear_c.SMOOTHNESS, linear_c.LEVELING}


def test_changed_tasks_are_asked_again(contexts):
    tasks = _variants()
    builder, oracle = QPBuilder(tasks, []), QPBuilder(tasks, [], compiled=False)
    ctx = contexts[-1]
    _same_q(builder, oracle, ctx)
    tasks[0].position_weight = np.full(3, 7.0)  # writable: asked every tick
    tasks[0].terminal_factor = 2.0
    _same_q(builder, oracle, ctx)
    assert builder._guard is None
    tasks[0].position_weight.setflags(write=False)
    tasks[2].weight = np.full(9, 0.7)
    tasks[2].weight.setflags(write=False)
    tasks[5].linear = 9.0
    tasks[6].force_scale = 2e4
    _same_q(builder, oracle, ctx)
    assert builder._guard is not None
    tasks[3].weight.setflags(write=True)  # a guarded array made writable again
    tasks[3].weight[0] = 5.0
    _same_q(builder, oracle, ctx)
    tasks.append(HorizonInputTask(0.2))  # the owner's list grows
    _same_q(builder, oracle, ctx)
    tasks[6].weight = np.array(0.0)  # the leveling inactive
    _same_q(builder, oracle, ctx)
    assert len(builder._linear[0]) == len(tasks) - 1


def test_without_terms_or_with_other_arrays_the_numpy_loop(contexts):
    class Tracking(HorizonTrackingTask):  # a subclass may read more: no term
        pass

    ctx = contexts[-1]
    tasks = [Tracking([0, 1], 1.0, 1.0), HorizonInputTask(1.0)]
    builder, oracle = QPBuilder(tasks, []), QPBuilder(tasks, [], compiled=False)
    _same_q(builder, oracle, ctx)
    assert builder._refused is tasks[0]
    tasks = _variants()
    builder, oracle = QPBuilder(tasks, []), QPBuilder(tasks, [], compiled=False)
    fp = ctx.free_positions
    for c in (dataclasses.replace(ctx, free_positions=np.asfortranarray(fp)),
              dataclasses.replace(ctx, free_positions=fp.astype(">f8")),
              dataclasses.replace(ctx, q=ctx.q.astype(np.float32))):
        assert builder._linear is None or builder._linear[2](c) is None
        _same_q(builder, oracle, c)
    short = dataclasses.replace(ctx, warp_drift=ctx.warp_drift[1:])
    assert builder._linear[2](short) is None
    with pytest.raises(ValueError):  # numpy's error, as without the C
        builder.build(short)
    read_only = fp.copy()
    read_only.setflags(write=False)
    c = dataclasses.replace(ctx, free_positions=read_only)
    assert builder._linear[2](c) is not None  # read, not written
    _same_q(builder, oracle, c)


def test_the_addresses_taken_in_python(contexts):
    """Where the C does not read numpy's fields: the shapes and addresses in Python."""
    tasks = _variants()
    builder, oracle = QPBuilder(tasks, []), QPBuilder(tasks, [], compiled=False)
    _same_q(builder, oracle, contexts[0])
    program = builder._linear[2]
    program._objects = None
    ctx = contexts[-1]
    fp = ctx.free_positions
    read_only = fp.copy()
    read_only.setflags(write=False)
    for c in (*contexts, dataclasses.replace(ctx, warp_drift=None),
              dataclasses.replace(ctx, free_positions=read_only)):
        assert program(c) is not None
        _same_q(builder, oracle, c)
    for c in (dataclasses.replace(ctx, free_positions=np.asfortranarray(fp)),
              dataclasses.replace(ctx, free_positions=fp.astype(">f8")),
              dataclasses.replace(ctx, q=ctx.q.astype(np.float32))):
        assert program(c) is None
        _same_q(builder, oracle, c)


def test_a_copied_builder_has_its_own_program(contexts):
    tasks = _variants()
    builder, oracle = QPBuilder(tasks, []), QPBuilder(tasks, [], compiled=False)
    _same_q(builder, oracle, contexts[0])
    twin = copy.deepcopy(builder)
    assert twin._linear[2] is not builder._linear[2]
    del builder
    for ctx in contexts:
        want = QPBuilder(twin.tasks, [], compiled=False).build(ctx)
        assert twin.build(ctx).q.tobytes() == want.q.tobytes()


def test_the_array_fields_are_read_where_numpy_keeps_them():
    assert object_fields_c.fields_readable()  # numpy's wheel, CPython, on this host
    assert linear_c._objects_function() is not None


def test_the_sum_starts_at_plus_zero(contexts):
    """``+0 + c_1``: a first term's -0 becomes +0, as the numpy loop's (a user's task)."""
    from wbc.tasks import ConstantJacobianTask

    class NegativeZeros(ConstantJacobianTask):
        constant_error = True

        def compute_error(self, ctx):
            return np.zeros(ctx.layout.n)

        def compute_jacobian(self, ctx):
            return np.eye(ctx.layout.n)

        def _linear_term(self, ctx):
            return np.full(ctx.layout.n, -0.0)

    tasks = [NegativeZeros()]  # alone: a later +0 would make +0 too
    builder, oracle = QPBuilder(tasks, []), QPBuilder(tasks, [], compiled=False)
    q = _same_q(builder, oracle, contexts[0])
    assert builder._linear[2] is not None and builder._guard is None  # a term, no guard
    assert not np.any(np.signbit(q))


def test_same_objects():
    a, b = np.zeros(3), np.ones(2)
    a.setflags(write=False)
    b.setflags(write=False)
    same = object_fields_c.SameObjects.make((a, 1.5, b))
    assert same((a, same.objects[1], b)) and same.call((a, same.objects[1], b)) == 1
    assert not same((a, 1.5 + 0.0 * a.sum(), b))  # an equal float, another object
    assert not same((a, same.objects[1])) and not same((b, same.objects[1], b))
    b.setflags(write=True)
    assert not same((a, same.objects[1], b))


def test_terms_that_do_not_fit_leave_it_to_the_numpy_loop(contexts):
    from wbc.errors import WbcError
    from wbc.tasks import ConstantJacobianTask

    class Constant(ConstantJacobianTask):
        constant_error = True
        size, step = 0, 1

        def compute_error(self, ctx):
            return np.zeros(ctx.layout.n)

        def compute_jacobian(self, ctx):
            return np.eye(ctx.layout.n)

        def _linear_term(self, ctx):
            return np.arange((ctx.layout.n + self.size) * self.step, dtype=float)[::self.step]

    ctx = contexts[0]
    strided = Constant()
    strided.step = 2  # a view that is not one block: no program, the numpy loop
    builder, oracle = QPBuilder([strided], []), QPBuilder([strided], [], compiled=False)
    _same_q(builder, oracle, ctx)
    assert builder._linear[2] is None
    longer = Constant()
    longer.size = 1
    with pytest.raises(WbcError, match="returned H"):
        QPBuilder([longer], []).build(ctx)


def test_without_the_library_the_builder_stays_with_numpy(contexts, monkeypatch):
    monkeypatch.setattr(linear_c, "numpy_blas", lambda: None)  # not numpy's BLAS
    linear_c.available.cache_clear()
    try:
        tasks = _variants()
        builder, oracle = QPBuilder(tasks, []), QPBuilder(tasks, [], compiled=False)
        for ctx in contexts:
            _same_q(builder, oracle, ctx)
        assert not builder.compiled and builder._guard is None
    finally:
        linear_c.available.cache_clear()
