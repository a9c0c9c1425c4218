"""`wbc.solvers.DaqpBackend`: screened rows are implied by the box; warm solves equal cold ones.

Oracles: points sampled in the box (the corners included) for the screening; DAQP's own cold
solve of the unscreened problem, and the corpus's stored reference, for the solutions.
"""

from __future__ import annotations

import itertools

import numpy as np
import pytest
import qpsolvers

from benchmarks.qp_corpus import load_corpus
from wbc.constraints.constraint import Box
from wbc.errors import ConfigurationError, QPSolveError
from wbc.qp import QPBuilder
from wbc.solvers import DaqpBackend, daqp_backend
from wbc.solvers.daqp_backend import redundant_rows


@pytest.fixture(scope="module")
def corpus():
    return load_corpus()


def test_screened_rows_hold_everywhere_in_the_box():
    rng = np.random.default_rng(3)
    n, m, tol = 4, 200, 1e-7
    G = rng.normal(size=(m, n))
    lb, ub = -rng.uniform(0.5, 2, n), rng.uniform(0.5, 2, n)
    h = rng.uniform(0, 8, m)
    drop = redundant_rows(G, h, lb, ub, tol)
    assert 0 < drop.sum() < m  # both kinds occur
    corners = np.array(list(itertools.product(*zip(lb - tol, ub + tol))))
    inside = rng.uniform(lb, ub, size=(500, n))
    for x in np.vstack([corners, inside]):
        assert np.all(G[drop] @ x <= h[drop] + 1e-12)
    # Every kept row is violated at some corner of the widened box: none is kept needlessly.
    assert np.all((G[~drop] @ corners.T).max(axis=1) > h[~drop])


def test_an_infinite_bound_keeps_the_rows_that_depend_on_it():
    G = np.array([[1.0, 0.0], [0.0, 1.0], [0.0, -1.0]])
    h = np.array([5.0, 5.0, 5.0])
    lb, ub = np.array([-1.0, 0.0]), np.array([1.0, np.inf])
    np.testing.assert_array_equal(redundant_rows(G, h, lb, ub, 1e-7), [True, False, True])
    np.testing.assert_array_equal(redundant_rows(G, h, None, None, 1e-7), [False] * 3)


def test_warm_screened_solves_equal_cold_full_ones(corpus):
    """Against DAQP on the QP as built: its own factorisation, every row, no warm start."""
    warm = DaqpBackend()
    cold = DaqpBackend(warm_start=False, screen=False, least_distance=False)
    n_warm, dropped = 0, 0
    for block in corpus.blocks():
        warm.reset()
        for i in block:
            p = corpus.problems[i]
            a, b = warm.solve(p), cold.solve(p)
            np.testing.assert_allclose(a.x, b.x, rtol=0, atol=1e-6, err_msg=str(i))
            np.testing.assert_allclose(a.x, corpus.reference_x[i], rtol=0, atol=1e-4)
            n_warm += a.warm_started
            dropped += (0 if p.G is None else p.G.shape[0]) - warm.rows_kept
    assert n_warm >= len(corpus.problems) // 2  # the warm path ran
    assert dropped > 0  # and the screening dropped rows


def test_least_distance_form_equals_the_direct_one(corpus):
    """The kept factor: right across Hessian changes (the corpus's blocks switch between
    the MPC's and the whole-body QP's), used from a repeated Hessian on, and the
    multipliers (hence the warm starts) the same as DAQP's on the QP itself."""
    ldp, direct = DaqpBackend(), DaqpBackend(least_distance=False)
    forms = []
    for block in corpus.blocks():
        for i in block:
            p = corpus.problems[i]
            a, b = ldp.solve(p), direct.solve(p)
            forms.append(ldp.form)
            np.testing.assert_allclose(a.x, b.x, rtol=0, atol=1e-8, err_msg=str(i))
            assert a.iterations == b.iterations
            za, zb = ldp.multipliers[0], direct.multipliers[0]
            scale = max(1.0, np.abs(zb).max(initial=0.0))
            np.testing.assert_allclose(za, zb, rtol=0, atol=1e-6 * scale)
    assert forms.count("least-distance") > len(forms) // 2
    assert "direct" in forms  # a new Hessian, and the small whole-body QP


def test_a_hessian_without_a_safe_factor_goes_to_daqp_as_it_is():
    backend = DaqpBackend()
    n = 40
    H = np.eye(n)
    H[0, 0] = 1e-13  # positive, but a pivot below DAQP's relative level
    p = qpsolvers.Problem(H, np.ones(n), lb=-np.ones(n), ub=np.ones(n))
    for _ in range(3):
        x = backend.solve(p).x
        assert backend.form == "direct"
    np.testing.assert_allclose(x[1:], -1.0, atol=1e-9)
    H[0, 0] = 2.0  # a new, well-conditioned Hessian: factorised from its second solve on
    backend.solve(p)
    assert backend.form == "direct"
    x = backend.solve(p).x
    assert backend.form == "least-distance"
    np.testing.assert_allclose(x, np.r_[-0.5, -np.ones(n - 1)], atol=1e-9)


def test_the_kept_factor_follows_the_hessians_values():
    """The factor is kept for a Hessian equal to the last in value (a zero's sign aside,
    as `np.array_equal` says), made again for another value or shape with the same bytes."""
    backend = DaqpBackend()
    H = np.diag(np.arange(1.0, 37.0))
    H[0, 1] = H[1, 0] = 0.0
    assert backend._factor(H) is None  # seen once
    factor = backend._factor(H.copy())
    assert factor is not None
    flipped = H.copy()
    flipped[0, 1] = -0.0  # other bytes, the same values
    assert backend._factor(flipped) is factor
    changed = H.copy()
    changed[5, 5] = np.nextafter(changed[5, 5], 9.0)
    assert backend._factor(changed) is None
    assert backend._factor(changed) is not None
    assert backend._factor(changed.reshape(18, 72)) is None  # the same bytes


def test_a_read_only_hessian_of_its_own_is_known_by_identity(monkeypatch):
    """The builder's kept P (read-only, owning its data) is trusted by identity, not
    compared; a read-only view is not (its base may change)."""
    backend = DaqpBackend()
    H = np.diag(np.arange(1.0, 37.0))
    H.setflags(write=False)
    assert backend._factor(H) is None
    factor = backend._factor(H)
    assert factor is not None
    compared = []
    equal = daqp_backend._equal
    monkeypatch.setattr(daqp_backend, "_equal", lambda *a: compared.append(1) or equal(*a))
    assert backend._factor(H) is factor and not compared  # by identity
    base = np.diag(np.arange(1.0, 37.0))
    view = base[:]
    view.setflags(write=False)
    assert backend._factor(view) is factor and compared  # compared: equal values
    base[3, 3] = 7.5  # the view's base written: its factor must not be kept
    assert backend._factor(view) is None


def test_the_builders_kept_hessian_is_read_only():
    """`QPBuilder` shares P between ticks while the tasks' H are constant: read-only."""
    class Const:
        def __init__(self, H):
            self.H = H

        def is_active(self, ctx):
            return True

        def compute_qp_objective(self, ctx):
            return self.H, np.zeros(3)

    class Layout:
        n = 3

        def default_bounds(self):
            return np.full(3, -np.inf), np.full(3, np.inf)

    H = np.eye(3)
    H.setflags(write=False)
    ctx = type("Ctx", (), {"layout": Layout()})()
    box = Box(np.zeros(3), np.ones(3))
    builder = QPBuilder([Const(H)], [type("B", (), {"compute": lambda self, c: box})()])
    P = builder.build(ctx).P
    assert not P.flags.writeable and P.base is None
    assert builder.build(ctx).P is P


def test_warm_start_from_another_problem_is_still_right(corpus):
    """Multipliers of an unrelated QP of the same size: a poor start, the same answer."""
    mpc = [i for i, r in enumerate(corpus.records) if r["controller"] == "mpc-full"]
    backend = DaqpBackend()
    for i in mpc[::-7][:8]:
        x = backend.solve(corpus.problems[i]).x
        np.testing.assert_allclose(x, corpus.reference_x[i], rtol=0, atol=1e-4)


def test_infeasible_problem_raises_and_the_next_solve_is_cold():
    backend = DaqpBackend()
    P, q = np.eye(2), np.zeros(2)
    ok = qpsolvers.Problem(P, q, np.array([[1.0, 0.0]]), np.array([1.0]),
                           lb=-np.ones(2), ub=np.ones(2))
    backend.solve(ok)
    bad = qpsolvers.Problem(P, q, np.array([[1.0, 0.0]]), np.array([-5.0]),
                            lb=-np.ones(2), ub=np.ones(2))
    with pytest.raises(QPSolveError):
        backend.solve(bad)
    assert not backend.solve(ok).warm_started


def test_bad_settings_are_refused():
    with pytest.raises(ConfigurationError):
        DaqpBackend(primal_tol=0.0)
    with pytest.raises(ConfigurationError):
        DaqpBackend(iter_limit=0)


def test_constant_row_blocks_reuse_their_product_bit_for_bit(corpus):
    """Rows marked constant (`wbc.qp.QP.constant_rows`) are multiplied by the factor once;
    the solves are the same, bit for bit, as without the mark."""
    from wbc.qp import QP

    block = next(b for b in corpus.blocks() if len(b) >= 5)
    first = corpus.problems[block[0]]
    n = first.q.size
    rows = np.random.default_rng(5).normal(size=(40, n)) * 0.1  # far from binding
    constant = np.vstack([rows, -rows])
    constant.setflags(write=False)
    h_const = np.full(2 * rows.shape[0], 1e3)
    h_const[::7] = 0.05  # some rows the box does not make redundant
    marked, plain = DaqpBackend(), DaqpBackend()
    products = []
    for i in block:
        p = corpus.problems[i]
        G = np.vstack([p.G, constant])
        h = np.concatenate([p.h, h_const])
        args = (p.P, p.q, G, h, None, None, p.lb, p.ub)
        a = marked.solve(QP(*args, constant_rows=((p.G.shape[0], constant),)))
        b = plain.solve(qpsolvers.Problem(*args))
        assert np.array_equal(a.x, b.x), i
        if marked.form == "least-distance":  # from the second solve on (the kept factor)
            products.append(marked._rows.products[id(constant)][2])
    assert len(products) == len(block) - 1
    assert all(x is products[0] for x in products)  # computed once


def test_kept_screening_sums_of_constant_blocks_keep_the_same_rows(corpus):
    """A constant block's screening sums, kept while the bounds of its columns stay, select
    the rows `redundant_rows` selects on the whole problem, also when those bounds move."""
    from wbc.qp import QP

    block = next(b for b in corpus.blocks() if len(b) >= 5)
    n = corpus.problems[block[0]].q.size
    rows = np.zeros((30, n))
    rows[:, : n // 2] = np.random.default_rng(7).normal(size=(30, n // 2)) * 0.1
    constant = np.vstack([rows, -rows])
    constant.setflags(write=False)
    h_const = np.full(60, 1e3)
    h_const[::5] = 0.01
    backend = DaqpBackend()
    for k, i in enumerate(block):
        p = corpus.problems[i]
        lb, ub = p.lb.copy(), p.ub.copy()
        if k % 2:  # the block's columns' bounds move: its sums are made again
            lb[0] -= 0.5
        qp = QP(p.P, p.q, np.vstack([constant, p.G]), np.concatenate([h_const, p.h]), None,
                None, lb, ub, constant_rows=((0, constant),))
        expected = np.flatnonzero(~redundant_rows(qp.G, qp.h, lb, ub, 1e-7))
        np.testing.assert_array_equal(backend._screen(qp.G, qp.h, lb, ub, qp.constant_rows),
                                      expected)
        out = np.empty((expected.size, n))
        inv_t = np.triu(np.random.default_rng(k).normal(size=(n, n)))
        _times_factor(backend, qp.G, expected, inv_t, qp.constant_rows, out)
        # The block's rows from its own product, the others' from theirs.
        assert_within_product_bound(out, qp.G[expected], inv_t)


def test_daqp_leaves_the_kept_rows_buffer_as_it_was(corpus):
    """The least-distance rows live in a buffer reused from solve to solve."""
    mpc = [i for i, r in enumerate(corpus.records) if r["controller"] == "mpc-full"]
    backend = DaqpBackend()
    for i in mpc[:3]:
        backend.solve(corpus.problems[i])
    assert backend.form == "least-distance"
    inv_t, buffer = backend._rows.ldp_rows
    kept = backend.rows_kept
    before = buffer[: inv_t.shape[0] + kept].copy()
    backend.solve(corpus.problems[mpc[2]])
    assert np.array_equal(buffer[: inv_t.shape[0] + kept], before)


def assert_within_product_bound(out, rows, inv_t) -> None:
    """``out`` is ``rows @ inv_t`` up to rounding: within twice the bound of a dot product of
    length n in any summation order (``gamma_n sum |a_k b_k|``, Higham's eq. 3.5) of numpy's
    product, whatever order its BLAS sums in on this host."""
    n = inv_t.shape[0]
    u = np.finfo(float).eps / 2
    bound = 2 * (n * u / (1 - n * u)) * (np.abs(rows) @ np.abs(inv_t))
    assert out.shape == (rows.shape[0], n)
    assert (np.abs(out - rows @ inv_t) <= bound).all()


def _numpy_backend() -> DaqpBackend:
    """A backend that screens and multiplies with numpy alone (the definition of the C's)."""
    backend = DaqpBackend()
    backend.compiled = False
    return backend


def _times_factor(backend, G, kept, inv_t, blocks, out, diagonal=()):
    """`FactorRows.times_factor` with the backend's structure of these rows."""
    structure = backend._structure(G.shape[0], blocks, diagonal)
    backend._rows.times_factor(G, kept, inv_t, blocks, out, structure, None, diagonal)


def test_diagonal_blocks_multiply_as_the_dense_rows_do():
    """`DiagonalBlocks` rows times the factor block by block (numpy's path): the dense
    product up to rounding (random rows, scales and screened subsets, among dense rows)."""
    from wbc.constraints import DiagonalBlocks

    rng = np.random.default_rng(11)
    n, steps, width = 117, 12, 9
    for trial in range(60):
        inv_t = np.triu(rng.normal(size=(n, n)))
        rows = 2 * int(rng.integers(1, 5))
        dense = rng.normal(size=(int(rng.integers(1, 60)), n))
        blocks = np.zeros((steps, rows, n))
        for k in range(steps):
            blocks[k, :, k * width:(k + 1) * width] = (rng.normal(size=(rows, width))
                                                       * 10.0 ** rng.integers(-6, 6))
        G = np.vstack([dense, blocks.reshape(-1, n)])
        kept = np.flatnonzero(rng.random(G.shape[0]) < 0.7)
        out = np.empty((kept.size, n))
        _times_factor(_numpy_backend(), G, kept, inv_t, (), out,
                      ((dense.shape[0], DiagonalBlocks(rows, 0, width, steps)),))
        assert_within_product_bound(out, G[kept], inv_t)


def test_the_mpc_effort_rows_are_zero_outside_their_diagonal_blocks():
    """What `HorizonEffortLimit` says of its rows holds, and the MPC's QP solves to the same
    plan with and without the blocks (numpy's path: up to rounding; the C products: the
    same bits) and with the products in C."""
    from benchmarks.bench_wbc import DT
    from models import build_reference_machine
    from testkit.plant import KinematicPlant, make_state
    from wbc import JointGoal, load_estimator, make_controller
    from wbc.qp import QP

    machine = build_reference_machine()
    controller = make_controller("mpc-full", machine,
                                 force_model=load_estimator(machine, "full"))
    st = make_state(machine)
    goal = st.q[2:9].copy()
    goal[3] += 0.3
    controller.set_goal(JointGoal(crane=goal))
    plant = KinematicPlant(st, DT)
    with_blocks, without, compiled = _numpy_backend(), _numpy_backend(), DaqpBackend()
    compiled_without = DaqpBackend()
    for _ in range(5):
        p = controller.prepare(plant.state)
        ((first, d),) = p.diagonal_rows
        G = p.G[first:first + d.rows * d.n_blocks].reshape(d.n_blocks, d.rows, -1).copy()
        for k in range(d.n_blocks):
            G[k, :, d.first + k * d.width:d.first + (k + 1) * d.width] = 0.0
        assert not G.any()
        a = with_blocks.solve(p)
        c = compiled.solve(p)
        plain = QP(p.P, p.q, p.G, p.h, None, None, p.lb, p.ub,
                   constant_rows=p.constant_rows)
        b = without.solve(plain)
        np.testing.assert_allclose(a.x, b.x, rtol=0, atol=1e-9)
        np.testing.assert_allclose(a.x, c.x, rtol=0, atol=1e-9)
        assert np.array_equal(c.x, compiled_without.solve(plain).x)
        plant.apply(controller.step(plant.state))
    assert with_blocks.form == "least-distance"
