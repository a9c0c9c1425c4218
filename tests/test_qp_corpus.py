"""The recorded QP corpus (`benchmarks.qp_corpus`): well-formed, and solved by every solver.

A solver solves a QP when the benchmark's test holds (`benchmarks.bench_qp_solvers.solved`:
finite, primal residual <= 1e-6 in the QP's units, objective not more than 1e-6 relative
above the stored reference) and x is within 1e-4 of that reference (ProxQP cold at 1e-10,
itself checked against DAQP's active-set solution here). 1e-4 on x: PIQP's interior point
stops 1e-5..4e-5 away in weakly determined directions at the same objective (7e-9).
"""

from __future__ import annotations

import numpy as np
import pytest
import qpsolvers

from benchmarks.bench_qp_solvers import solved
from benchmarks.qp_corpus import FIELDS, VERSION, load_corpus, objective
from wbc.controllers import ControllerConfig
from wbc.solvers import ProxQPWorkspace, make_solver

PRIMAL_TOL = 1e-6
X_TOL = 1e-4


@pytest.fixture(scope="module")
def corpus():
    return load_corpus()


def _primal_residual(p, x) -> float:
    r = [0.0, float(np.max(p.lb - x)), float(np.max(x - p.ub))]
    if p.G is not None:
        r.append(float(np.max(p.G @ x - p.h)))
    return max(r)


def _check(p, x, x_ref) -> str | None:
    """None if ``x`` solves ``p``, else what is wrong."""
    if x is None or not np.all(np.isfinite(x)):
        return "no finite solution"
    r = _primal_residual(p, x)
    if r > PRIMAL_TOL:
        return f"primal residual {r:.1e}"
    f, f_ref = objective(p, x), objective(p, x_ref)
    if not solved(True, r, f, f_ref):
        return f"objective {f:.9g} above the reference {f_ref:.9g}"
    dx = float(np.max(np.abs(x - x_ref)))
    if dx > X_TOL:
        return f"|x - x_ref| = {dx:.1e}"
    return None


def test_corpus_header_and_provenance(corpus):
    h = corpus.header
    assert h["version"] == VERSION
    assert len(h["commit"]) >= 40
    assert len(corpus.problems) == len(corpus.records) == len(corpus.reference_x) >= 90
    controllers = {r["controller"] for r in corpus.records}
    assert {"mpc-full", "tracking"} <= controllers
    for block in corpus.blocks():  # consecutive ticks: a warm-start sequence
        ticks = [corpus.records[i]["tick"] for i in block]
        assert ticks == list(range(ticks[0], ticks[0] + len(ticks)))


def test_problems_are_well_formed(corpus):
    for i, p in enumerate(corpus.problems):
        n = p.q.size
        assert p.P.shape == (n, n) and p.P.dtype == np.float64, i
        np.testing.assert_allclose(p.P, p.P.T, rtol=0, atol=1e-12 * np.abs(p.P).max())
        assert np.linalg.eigvalsh(p.P).min() > -1e-9 * np.abs(p.P).max(), i
        assert p.A is None and p.b is None
        assert p.lb.shape == p.ub.shape == (n,) and np.all(p.lb <= p.ub)
        for f in ("P", "q", "G", "h"):
            a = getattr(p, f)
            assert a is None or np.all(np.isfinite(a)), (i, f)
        assert p.G is None or p.G.shape == (p.h.size, n)
        assert not np.any(np.isnan(p.lb)) and not np.any(np.isnan(p.ub))
        assert corpus.reference_x[i].shape == (n,)
    assert set(FIELDS) == {"P", "q", "G", "h", "A", "b", "lb", "ub"}


def test_reference_is_optimal(corpus):
    """The stored reference against an independent oracle (DAQP, active set: a core
    dependency, the controllers' default solver)."""
    for i, p in enumerate(corpus.problems):
        x = qpsolvers.solve_problem(p, solver="daqp", primal_tol=1e-9).x
        assert _check(p, corpus.reference_x[i], x) is None, i
        f = objective(p, x)
        assert abs(corpus.reference_objective[i] - f) <= 1e-7 * max(1.0, abs(f)), i


@pytest.mark.parametrize("warm", [True, False], ids=["warm", "cold"])
def test_proxqp_solves_every_problem(corpus, warm):
    cfg = ControllerConfig()
    bad = {}
    for block in corpus.blocks():
        ws = ProxQPWorkspace(eps_abs=cfg.eps_abs, eps_rel=cfg.eps_rel, max_iter=cfg.max_iter,
                             warm_start=warm, retry_infeasible=True)
        for i in block:
            sol = ws.solve(corpus.problems[i])
            err = _check(corpus.problems[i], sol.x, corpus.reference_x[i])
            if err:
                bad[i] = err
    assert not bad, bad


@pytest.mark.parametrize("solver", ["daqp", "piqp", "osqp"])
def test_other_solvers_solve_every_problem(corpus, solver):
    """Through the controller's own path (`make_solver`, the controller's tolerances).

    DAQP is a core dependency (never skipped); PIQP and OSQP come with the dev extras.
    """
    if solver != "daqp" and solver not in qpsolvers.available_solvers:
        pytest.skip(f"{solver} not installed")
    cfg = ControllerConfig(solver=solver)
    backend = make_solver(cfg.solver, cfg.eps_abs, cfg.eps_rel, cfg.max_iter)
    problems = corpus.problems if solver != "osqp" else corpus.problems[::5]  # OSQP: slow
    bad = {}
    for i, p in enumerate(problems):
        k = i if solver != "osqp" else 5 * i
        sol = backend.solve(p)
        err = _check(p, sol.x, corpus.reference_x[k])
        if err:
            bad[k] = err
    assert not bad, f"{solver} got wrong answers: {bad}"


def test_check_catches_a_wrong_answer(corpus):
    """The acceptance test can fail: a perturbed or infeasible answer is refused."""
    i = next(i for i, r in enumerate(corpus.records) if r["controller"] == "mpc-full")
    p, x = corpus.problems[i], corpus.reference_x[i]
    assert _check(p, x, x) is None
    assert _check(p, x + 1e-4, x) is not None
    assert _check(p, np.zeros_like(x) + np.nan, x) is not None
