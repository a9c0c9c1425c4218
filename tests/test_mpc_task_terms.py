"""The MPC tasks' linear terms written on kept buffers = the formula's bits, tick after tick.

`HorizonTrackingTask` writes its error into kept arrays: ``c`` must be the bytes of
``(J^T W) e`` of `compute_error` (the base class's product). `HorizonInputTask` and
`HorizonSmoothnessTask` write ``W e`` where ``J`` has its one entry per column: the bytes of
``w * e`` there and zeros elsewhere, and the full product up to a zero's sign.
"""

import numpy as np

from testkit.plant import moving_mpc
from wbc.tasks import HorizonInputTask, HorizonSmoothnessTask, HorizonTrackingTask


def _contexts(machine, ticks: int):
    ctrl, plant = moving_mpc(machine, ticks=2)
    for _ in range(ticks):
        yield ctrl.context(plant.state)
        plant.apply(ctrl.step(plant.state))


def test_linear_terms_are_the_formulas_bits(machine):
    tracking = [HorizonTrackingTask([2, 3, 4, 5, 6, 7, 8], 50.0, 5.0),
                HorizonTrackingTask([0, 1], [30.0, 20.0], 3.0),
                HorizonTrackingTask([1, 4, 6], 10.0, 1.0)]  # columns not a slice
    smooth, inputs = HorizonSmoothnessTask(np.linspace(1, 2, 9)), HorizonInputTask(0.3)
    seen = 0
    for ctx in _contexts(machine, 8):
        lay = ctx.layout
        for task in tracking:
            H, c = task.compute_qp_objective(ctx)
            want = task._jw @ task.compute_error(ctx)
            assert c.tobytes() == want.tobytes()
        for task in (smooth, inputs):
            H, c = task.compute_qp_objective(ctx)
            jac, w, e = task.compute_jacobian(ctx), task.compute_weight(ctx), \
                task.compute_error(ctx)
            want = np.zeros(lay.n)
            if task is inputs:
                want[lay.accelerations] = w * e
            else:
                want[lay.step(0)] = w[lay.step(0)] * e[lay.step(0)]
            assert c.tobytes() == want.tobytes()
            np.testing.assert_array_equal(c, (jac.T * w) @ e)
            seen += bool(np.any(c))
    assert seen > 8  # nonzero terms: a moving crane


def test_tracking_differences_are_kept_per_context(machine):
    """One context's differences serve every tracking task; another context's are its own."""
    import dataclasses

    from wbc.tasks.horizon_tracking_task import _differences

    ctx = next(_contexts(machine, 1))
    d = _differences(ctx)
    assert _differences(ctx) is d and not d.flags.writeable
    moved = dataclasses.replace(ctx, free_positions=ctx.free_positions + 1.0)
    task = HorizonTrackingTask([0, 1], 1.0, 1.0)
    for c in (moved, ctx):  # each context's own numbers, in turn
        assert task.compute_qp_objective(c)[1].tobytes() == \
            (task._jw @ task.compute_error(c)).tobytes()
    assert _differences(moved) is not d
    want = moved.free_positions - moved.reference.position[1:]
    assert _differences(moved)[0].tobytes() == want.tobytes()
