"""`DaqpBackend`'s fused least-distance solve (`LeastDistanceWorkspace.step`): numpy's bits.

The fused C call forms DAQP's bounds (the shifts through numpy's own BLAS), gathers the warm
start, retries cold, recovers ``x`` and scatters the multipliers; and the kept workspace
leaves the rows it normalised last unnormalised again where the product pass vouches for
them (`FactorRows.same_rows`). Oracles: the same backend with the numpy tail around the
kept workspace (``fused = False``) and with ``daqp.solve`` (``compiled = False``), solve by
solve: iterate, multipliers, iterations, warm start, all bit for bit.
"""

from __future__ import annotations

import numpy as np
import pytest
import qpsolvers

from benchmarks.qp_corpus import load_corpus
from wbc.errors import QPSolveError
from wbc.solvers import DaqpBackend, daqp_backend
from wbc.solvers.daqp_c import LeastDistanceWorkspace


def _backends(**settings) -> tuple[DaqpBackend, DaqpBackend, DaqpBackend]:
    """(fused, numpy tail on the kept workspace, daqp.solve), with these settings."""
    fused, tail, reference = (DaqpBackend(**settings) for _ in range(3))
    if not fused.fused:
        pytest.skip("no compiled DAQP workspace or numpy's BLAS not reachable")
    tail.fused = False
    reference.compiled = False
    assert tail.kept_workspace and not tail.fused and not reference.kept_workspace
    return fused, tail, reference


def _assert_same(solutions, backends, what) -> None:
    first = solutions[0]
    for s, b in zip(solutions[1:], backends[1:]):
        assert s.x.tobytes() == first.x.tobytes(), what
        assert s.iterations == first.iterations, what
        assert s.warm_started == first.warm_started, what
        for u, v in zip(b.multipliers, backends[0].multipliers):
            assert u.tobytes() == v.tobytes(), what


def _counting(monkeypatch) -> dict:
    """Counts of fused steps and of those given rows to leave as they were."""
    counts = {"steps": 0, "same": 0}
    step = LeastDistanceWorkspace.step

    def counted(self, *args):
        counts["steps"] += 1
        counts["same"] += args[-1] is not None
        return step(self, *args)

    monkeypatch.setattr(LeastDistanceWorkspace, "step", counted)
    return counts


def test_the_mpc_ticks_solve_to_the_same_bits(monkeypatch):
    """The MPC's QPs along a motion, every solve fused and nearly all of them on rows the
    last solve normalised."""
    from benchmarks.bench_wbc import DT
    from models import build_reference_machine
    from testkit.plant import KinematicPlant, make_state
    from wbc import JointGoal, load_estimator, make_controller

    machine = build_reference_machine()
    controller = make_controller("mpc-full", machine,
                                 force_model=load_estimator(machine, "full"))
    st = make_state(machine)
    goal = st.q[2:9].copy()
    goal[3] += 0.3
    goal[0] -= 0.2
    controller.set_goal(JointGoal(crane=goal))
    plant = KinematicPlant(st, DT)
    backends = _backends()
    counts = _counting(monkeypatch)
    for tick in range(50):
        p = controller.prepare(plant.state)
        _assert_same([b.solve(p) for b in backends], backends, tick)
        plant.apply(controller.step(plant.state))
    assert counts["steps"] >= 48 and counts["same"] >= 45


def test_the_corpus_solves_to_the_same_bits(monkeypatch):
    """The corpus's blocks (cold and warm starts, rows screened in and out, the whole-body
    QP's direct form)."""
    corpus = load_corpus()
    backends = _backends()
    counts = _counting(monkeypatch)
    for block in corpus.blocks():
        for b in backends:
            b.reset()
        for i in block:
            p = corpus.problems[i]
            _assert_same([b.solve(p) for b in backends], backends, i)
    assert counts["steps"] > 0


def _problem(rng, n, m_in, m_eq, box=True):
    """A random strictly convex QP, feasible at a point inside its box."""
    root = rng.normal(size=(n, n))
    P = root @ root.T + n * np.eye(n)
    inside = rng.uniform(-0.5, 0.5, n)
    G = rng.normal(size=(m_in, n)) if m_in else None
    h = G @ inside + rng.uniform(0.0, 0.3, m_in) if m_in else None
    A = rng.normal(size=(m_eq, n)) if m_eq else None
    b = A @ inside if m_eq else None
    lb, ub = (-np.ones(n), np.ones(n)) if box else (None, None)
    return qpsolvers.Problem(P, rng.normal(size=n) * 5, G, h, A, b, lb, ub)


@pytest.mark.parametrize("m_in, m_eq, box", [
    (60, 0, True), (60, 3, True), (1, 0, True), (0, 1, True), (0, 0, True), (0, 0, False),
    (40, 0, False), (2, 2, True)])
def test_rows_equalities_and_boxes_keep_the_bits(m_in, m_eq, box):
    """A single row (numpy's dot), none, equalities, no box: the same Hessian with new
    linear terms and bounds, so the factor is kept and the warm start taken."""
    rng = np.random.default_rng(11 + m_in + 7 * m_eq + box)
    n = 40
    first = _problem(rng, n, m_in, m_eq, box)
    backends = _backends()
    for k in range(6):
        p = _problem(rng, n, m_in, m_eq, box)
        p = qpsolvers.Problem(first.P, p.q, p.G, p.h, p.A, p.b, p.lb, p.ub)
        _assert_same([b.solve(p) for b in backends], backends, k)
    assert backends[0].form == "least-distance" and backends[0].rows_kept <= m_in


def test_an_infeasible_problem_raises_and_the_next_solve_is_cold():
    rng = np.random.default_rng(5)
    n = 40
    ok = _problem(rng, n, 30, 0)
    bad = qpsolvers.Problem(ok.P, ok.q, np.vstack([ok.G, np.eye(n)[:1], -np.eye(n)[:1]]),
                            np.r_[ok.h, -0.5, -0.5], lb=ok.lb, ub=ok.ub)
    backends = _backends()
    for p in (ok, ok):
        _assert_same([b.solve(p) for b in backends], backends, "ok")
    for b in backends:
        with pytest.raises(QPSolveError):
            b.solve(bad)
        assert b.multipliers == (None, None)
    solutions = [b.solve(ok) for b in backends]
    _assert_same(solutions, backends, "after")
    assert not solutions[0].warm_started


def test_arguments_the_c_does_not_read_take_numpy():
    """A linear term that is not float64 goes around the fused call, with the same bits."""
    rng = np.random.default_rng(2)
    p = _problem(rng, 40, 30, 0)
    backends = _backends()
    for q in (p.q, p.q.astype(np.float32), p.q[::-1].copy()[::-1]):
        problem = qpsolvers.Problem(p.P, q, p.G, p.h, lb=p.lb, ub=p.ub)
        _assert_same([b.solve(problem) for b in backends], backends, str(q.dtype))


def test_rows_are_vouched_for_only_after_the_pass_the_last_solve_took():
    rows = DaqpBackend()._rows
    assert rows.same_rows(-1) is None and rows.same_rows(0) is None
    rows.passes, rows._same_pass = 3, 3
    assert rows.same_rows(2) is not None
    assert rows.same_rows(1) is None  # a pass in between: rows the workspace did not see


def test_without_numpys_blas_the_backend_runs_the_numpy_tail(monkeypatch):
    monkeypatch.setattr(daqp_backend, "numpy_blas", lambda: None)
    backend = DaqpBackend()
    assert backend.kept_workspace and not backend.fused
    monkeypatch.undo()
    backend.compiled = True
    assert backend.fused
    backend.compiled = False
    assert not backend.fused and not backend.kept_workspace


def test_constant_rows_the_screening_moves_are_normalised_again(monkeypatch):
    """A constant block (`wbc.qp.QP.constant_rows`) whose kept rows change from tick to tick:
    its rows land in other places of DAQP's rows, which the workspace must normalise again;
    the rows that stay in place are left (the same bits all the same)."""
    from wbc.qp import QP

    rng = np.random.default_rng(17)
    n = 40
    base = _problem(rng, n, 0, 0)
    block = rng.normal(size=(48, n)) * 0.3
    block.setflags(write=False)
    backends = _backends()
    counts = _counting(monkeypatch)
    for k in range(12):
        h = np.full(48, 1e3)
        h[(np.arange(48) + k // 2) % 3 == 0] = 0.05  # the same rows two ticks in a row
        q = base.q + rng.normal(size=n)
        solutions = [b.solve(QP(base.P, q, block, h, None, None, base.lb, base.ub,
                                constant_rows=((0, block),))) for b in backends]
        _assert_same(solutions, backends, k)
        assert backends[0].rows_kept == 16
    assert counts["same"] >= 9


def test_a_warm_solve_that_fails_is_retried_cold():
    """Warm started from many rows that bind no more (the multipliers of another problem),
    DAQP runs out of iterations; the cold retry needs few: solved, not warm."""
    rng = np.random.default_rng(23)
    n = 40
    box = _problem(rng, n, 0, 0)
    G = np.vstack([np.eye(n), -np.eye(n)])
    pushed = qpsolvers.Problem(box.P, box.q * 40, G, np.full(2 * n, 0.1), lb=box.lb,
                               ub=box.ub)  # many rows bind
    free = qpsolvers.Problem(box.P, box.q * 1e-3, G, np.full(2 * n, 0.1), lb=box.lb,
                             ub=box.ub)  # none binds
    helper = DaqpBackend()
    helper.solve(pushed)
    start = helper.solve(pushed)
    assert start.iterations <= 1 and np.count_nonzero(helper._lam) > 8
    backends = _backends(iter_limit=8)
    for b in backends:
        b.solve(free)  # the factor kept
        b._lam = helper._lam.copy()
    solutions = [b.solve(free) for b in backends]
    _assert_same(solutions, backends, "")
    assert not solutions[0].warm_started and solutions[0].iterations > 8


def test_kept_block_sums_follow_the_blocks_and_the_bounds():
    """The screening's sums of constant blocks are reused only for the same blocks in the
    same places under the same bounds: other blocks, or moved bounds, are summed again."""
    from wbc.qp import QP
    from wbc.solvers.daqp_backend import redundant_rows

    rng = np.random.default_rng(29)
    n = 40
    base = _problem(rng, n, 0, 0)
    scales = np.geomspace(0.002, 0.05, 30)[:, None]  # rows on both sides of h
    blocks = [rng.normal(size=(30, n)) * scales, rng.normal(size=(30, n)) * scales[::-1]]
    for block in blocks:
        block.setflags(write=False)
    h = np.full(30, 0.8)
    backend = DaqpBackend()
    for k, (i, lb_shift) in enumerate([(0, 0), (0, 0), (1, 0), (1, 0), (0, 0), (0, 0.5),
                                       (0, 0.5), (0, 0)]):
        lb = base.lb - lb_shift
        qp = QP(base.P, base.q, blocks[i].copy(), h, None, None, lb, base.ub,
                constant_rows=((0, blocks[i]),))
        backend.solve(qp)
        expected = np.flatnonzero(~redundant_rows(blocks[i], h, lb, base.ub, 1e-7))
        assert backend.rows_kept == expected.size and 3 < expected.size < 27, k
        np.testing.assert_array_equal(
            backend._screen(qp.G, qp.h, lb, base.ub, qp.constant_rows), expected)
