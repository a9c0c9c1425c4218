"""The MPC's ``q`` (`wbc.qp.QPBuilder.build`) = the bytes of ``+0 + c_1 + c_2 + ...`` in task order.

On real ticks of the kinematic plant moving the crane: the builder's sum of the active tasks'
linear terms (the first into the kept read-only zeros, the rest added in place by the ufunc's
own call) must be the bytes of the plain in-place sum of each task's ``c``.
`tests/test_mpc_assembly.py` compares the kept builder with a fresh one, which runs the same
loop: this checks the loop itself.
"""

import numpy as np

from testkit.plant import moving_mpc


def test_q_is_the_plain_in_place_sum_of_the_tasks_terms(machine):
    ctrl, plant = moving_mpc(machine)
    planner = ctrl.planner
    build = planner.builder.build
    seen = {"ticks": 0, "terms": 0}

    def checked(ctx):
        qp = build(ctx)
        want = np.zeros(ctx.layout.n)
        for task in planner.tasks:
            if task.is_active(ctx):
                want += task.compute_qp_objective(ctx)[1]
                seen["terms"] += 1
        assert qp.q.tobytes() == want.tobytes()
        seen["ticks"] += 1
        return qp

    planner.builder.build = checked
    for _ in range(60):
        plant.apply(ctrl.step(plant.state))
    assert seen["ticks"] == 60 and seen["terms"] >= 5 * 60
