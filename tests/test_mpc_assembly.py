"""The MPC's kept-state QP assembly (`wbc.qp.QPBuilder` as `MpcPlanner` keeps it) = the bits of a
fresh builder's (`wbc.qp.build_qp`: no kept Hessian, ``np.concatenate`` of every row block).

Over many ticks of the kinematic plant moving the crane, every QP the planner hands the solver
is compared with a fresh builder's of the same context, array by array as bytes (a -0.0 for a
+0.0 fails); the kept ``G`` must actually be reused on most ticks (the path under test).
"""

import numpy as np
import qpsolvers

from testkit.plant import moving_mpc
from wbc.qp import QP, build_qp

FIELDS = ("P", "q", "G", "h", "A", "b", "lb", "ub")


def _bytes(qp) -> tuple:
    return tuple(None if getattr(qp, k) is None
                 else (getattr(qp, k).shape, getattr(qp, k).tobytes()) for k in FIELDS)


def _run(machine, ticks: int) -> dict:
    ctrl, plant = moving_mpc(machine)
    planner = ctrl.planner
    build = planner.builder.build
    seen = {"ticks": 0, "kept_G": 0, "last_G": None}

    def checked(ctx):
        qp = build(ctx)
        ref = build_qp(ctx, planner.tasks, planner.constraints, planner.regularization)
        assert _bytes(qp) == _bytes(ref)
        assert [(k, b.shape) for k, b in qp.constant_rows] == \
            [(k, b.shape) for k, b in ref.constant_rows]
        assert qp.diagonal_rows == ref.diagonal_rows
        seen["ticks"] += 1
        seen["kept_G"] += qp.G is not None and id(qp.G) == seen["last_G"]
        seen["last_G"] = None if qp.G is None else id(qp.G)
        return qp

    planner.builder.build = checked
    for _ in range(ticks):
        plant.apply(ctrl.step(plant.state))
    return seen


def test_kept_assembly_matches_fresh_builder_bit_for_bit(machine):
    seen = _run(machine, 150)
    assert seen["ticks"] == 150
    assert seen["kept_G"] > 100  # the kept rows' path, not only fresh arrays


def test_checked_qp_is_a_problem_like_qpsolvers_own():
    rng = np.random.default_rng(3)
    P, q = np.eye(3), rng.normal(size=3)
    G, h, lb, ub = rng.normal(size=(2, 3)), rng.normal(size=2), -np.ones(3), np.ones(3)
    fast = QP._of_checked(P, q, G, h, lb, ub, (), ())
    slow = QP(P, q, G, h, None, None, lb, ub)
    assert isinstance(fast, qpsolvers.Problem)
    assert vars(fast).keys() == vars(slow).keys()
    assert all(getattr(fast, k) is getattr(slow, k) for k in FIELDS)


def test_build_profile_names_every_term():
    from benchmarks.mpc_build import profile

    figures = profile(steps=3)
    assert {"build", "glue", "step", "solver", "HorizonNormalForceConstraint"} <= set(figures)
    assert all(np.isfinite(v) for v in figures.values())
