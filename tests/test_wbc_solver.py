"""ProxQP workspace: warm-started solves equal cold solves; failures are typed errors."""

import numpy as np
import pytest
import qpsolvers

from testkit.force_models import AffineForceModel
from testkit.plant import KinematicPlant, make_state
from wbc import (
    JointGoal,
    MpcConfig,
    ProxQPWorkspace,
    QPSolveError,
    UnknownSolverError,
    make_controller,
    make_solver,
)
from wbc.controllers import ControllerConfig


def _mpc_problems(machine, n=40):
    """A stream of MPC problems along a closed loop (what the workspace sees in use)."""
    st = make_state(machine)
    model = AffineForceModel.reference(machine, st.q)
    cfg = ControllerConfig(mpc=MpcConfig())
    ctrl = make_controller("mpc-full", machine, cfg, force_model=model)
    goal = st.q[2:9].copy()
    goal[0] += 0.15
    goal[3] += 0.4
    ctrl.set_goal(JointGoal(crane=goal, suspension=st.q[:2] + 0.03))
    plant = KinematicPlant(st, 0.01)
    out = []
    for _ in range(n):
        out.append(ctrl.prepare(plant.state))
        plant.apply(ctrl.step(plant.state))
    return out


def test_warm_started_proxqp_equals_cold_solve(machine):
    problems = _mpc_problems(machine)
    warm = ProxQPWorkspace(eps_abs=1e-9)
    for i, prob in enumerate(problems):
        sol = warm.solve(prob)
        assert sol.warm_started == (i > 0)
        cold = ProxQPWorkspace(eps_abs=1e-9, warm_start=False).solve(prob)
        ref = qpsolvers.solve_problem(prob, solver="proxqp", eps_abs=1e-9, eps_rel=0.0)
        assert ref.found
        np.testing.assert_allclose(sol.x, cold.x, atol=1e-6)
        np.testing.assert_allclose(sol.x, ref.x, atol=1e-6)
    assert warm.n_init == 1


def test_random_feasible_problems_warm_vs_cold():
    """Feasible by construction (x0 satisfies all rows): never reported infeasible."""
    rng = np.random.default_rng(7)
    n, m = 12, 30
    M = rng.standard_normal((n, n))
    P = M @ M.T + np.eye(n)
    G = rng.standard_normal((m, n))
    ws = ProxQPWorkspace(eps_abs=1e-9)
    for i in range(60):
        x0 = rng.uniform(-0.5, 0.5, n)
        h = G @ x0 + rng.uniform(0.0, 0.3, m)
        q = 5.0 * rng.standard_normal(n)
        prob = qpsolvers.Problem(P, q, G, h, None, None, -np.ones(n), np.ones(n))
        sol = ws.solve(prob)
        assert sol.warm_started == (i > 0)  # no cold retry was needed
        x_warm = sol.x
        x_cold = ProxQPWorkspace(eps_abs=1e-9, warm_start=False).solve(prob).x
        np.testing.assert_allclose(x_warm, x_cold, atol=1e-6)


def test_dimension_change_reinitializes():
    ws = ProxQPWorkspace()
    P = np.eye(2)
    ws.solve(qpsolvers.Problem(P, np.ones(2), np.ones((1, 2)), np.ones(1)))
    ws.solve(qpsolvers.Problem(P, np.ones(2), np.ones((2, 2)), np.ones(2)))
    assert ws.n_init == 2


def test_infeasible_problem_raises_typed_error():
    ws = ProxQPWorkspace()
    prob = qpsolvers.Problem(np.eye(2), np.zeros(2), np.array([[1.0, 0.0], [-1.0, 0.0]]),
                             np.array([-1.0, -1.0]))
    with pytest.raises(QPSolveError) as err:
        ws.solve(prob)
    assert "INFEASIBLE" in err.value.status or "MAX_ITER" in err.value.status
    # The workspace recovers on the next, feasible problem.
    x = ws.solve(qpsolvers.Problem(np.eye(2), -np.ones(2))).x
    np.testing.assert_allclose(x, 1.0, atol=1e-6)


def test_solver_by_name():
    assert isinstance(make_solver("proxqp"), ProxQPWorkspace)
    with pytest.raises(UnknownSolverError, match="available"):
        make_solver("no-such-solver")
    backend = make_solver(qpsolvers.available_solvers[0])
    x = backend.solve(qpsolvers.Problem(np.eye(2), -np.ones(2), lb=np.zeros(2),
                                        ub=0.5 * np.ones(2))).x
    np.testing.assert_allclose(x, 0.5, atol=1e-6)
