"""The rows times the inverse factor in C (`wbc.solvers.product_c`): numpy's bits.

Oracle: numpy's product (OpenBLAS), bit for bit, with one BLAS thread as the application
runs (a threaded BLAS splits a product by its size): random rows and screened subsets on a
factor shaped like the MPC's (per-axis chains, 94 % zeros) and on the recorded MPC problems'
own factor and rows; the numpy path of `FactorRows` where the C pass gives up.
"""

from __future__ import annotations

import numpy as np
import pytest

from tests.test_daqp_backend import _in_one_blas_thread
from wbc.solvers import DaqpBackend
from wbc.solvers.product_c import _reproduces_blas, compiled_product, product_library

pytestmark = pytest.mark.skipif(product_library() is None, reason="no C compiler")


def _chains(rng, axes=9, steps=12, extra=11) -> np.ndarray:
    """An upper-triangular ``L^-T`` like the MPC's: each axis's inputs coupled along the
    horizon (axes 0 and 1 with each other), then slack variables on the diagonal alone."""
    n = axes * steps + extra
    inv_t = np.zeros((n, n))
    for j in range(axes * steps):
        axis, step = j % axes, j // axes
        partners = (0, 1) if axis < 2 else (axis,)
        for k in range(step + 1):
            for a in partners:
                i = k * axes + a
                if i <= j:
                    inv_t[i, j] = rng.normal() * 10.0 ** rng.integers(-2, 3)
    inv_t[range(axes * steps, n), range(axes * steps, n)] = rng.uniform(0.5, 2.0, extra)
    return inv_t


def _check(product, G, kept, constant, rng) -> None:
    """The C product of ``G[kept]`` against numpy's, the constant rows from their products."""
    inv_t = product.inv_t
    products = rng.normal(size=G.shape)  # stands for the constant blocks' kept products
    out = np.full((kept.size, inv_t.shape[0]), np.nan)
    assert product.run(G, kept, constant, products, out)
    inside = constant[kept]
    assert np.array_equal(out[inside], products[kept[inside]])
    rest = kept[~inside]
    if rest.size == 1:  # numpy's one-row product is a matrix-vector one (another order)
        rest = np.repeat(rest, 2)
    assert np.array_equal(out[~inside], (G[rest] @ inv_t)[:(~inside).sum()])


def _random_rows_bits() -> None:
    rng = np.random.default_rng(4)
    for trial in range(30):
        product = compiled_product(_chains(rng))
        assert product is not None, trial  # OpenBLAS sums as the C does
        n = product.n
        m = int(rng.integers(1, 400))
        G = rng.normal(size=(m, n)) * 10.0 ** rng.integers(-6, 6, size=(m, n))
        G[rng.random((m, n)) < 0.5] = 0.0
        kept = np.flatnonzero(rng.random(m) < rng.uniform(0.1, 1.0))
        constant = rng.random(m) < 0.5
        _check(product, G, kept, constant, rng)


def test_random_rows_give_numpys_bits():
    """Random rows, scales, zeros and screened subsets; kept rows of constant blocks copied."""
    _in_one_blas_thread("_random_rows_bits", "tests.test_product_c")


def _recorded_rows_bits() -> None:
    from benchmarks.qp_corpus import load_corpus

    corpus = load_corpus()
    mpc = [p for p, r in zip(corpus.problems, corpus.records) if r["controller"] == "mpc-full"]
    backend = DaqpBackend()
    backend._factor(mpc[0].P)
    inv_t, _ = backend._factor(mpc[0].P)
    product = compiled_product(inv_t)
    assert product is not None
    rng = np.random.default_rng(8)
    for p in mpc[::3]:
        m = p.G.shape[0]
        _check(product, p.G, np.flatnonzero(rng.random(m) < 0.5), rng.random(m) < 0.3, rng)
        _check(product, p.G, np.arange(m), np.zeros(m, dtype=bool), rng)


def test_recorded_mpc_rows_give_numpys_bits():
    """The corpus's MPC problems: their Hessian's factor times their rows."""
    _in_one_blas_thread("_recorded_rows_bits", "tests.test_product_c")


def test_a_product_that_differs_from_numpys_is_not_handed_out():
    """The probe: one entry of the factor off by an ulp in the C's copy is caught."""
    product = compiled_product(_chains(np.random.default_rng(1)))
    assert product is not None and _reproduces_blas(product)
    product.val[product.val.size // 2] = np.nextafter(product.val[product.val.size // 2], 9.0)
    assert not _reproduces_blas(product)
    inv_t = np.eye(3)
    inv_t[0, 2] = np.inf
    assert compiled_product(inv_t) is None


def test_a_non_finite_row_goes_to_numpy():
    """A NaN or an infinity in a row to multiply: the C pass gives up, numpy's product (not
    finite in any column of that row: ``0 * inf`` is NaN) is what `FactorRows` writes."""
    rng = np.random.default_rng(3)
    inv_t = _chains(rng)
    n = inv_t.shape[0]
    G = rng.normal(size=(20, n))
    kept = np.arange(0, 20, 2)
    for bad in (np.nan, np.inf):
        G[4, 7] = bad
        product = compiled_product(inv_t)
        assert not product.run(G, kept, np.zeros(20, dtype=bool), G, np.empty((10, n)))
        c, ref = DaqpBackend(), DaqpBackend()
        ref.compiled = False
        outs = []
        for backend in (c, ref):
            out = np.empty((kept.size, n))
            structure = backend._structure(20, ())
            with np.errstate(invalid="ignore"):
                backend._rows.times_factor(G, kept, inv_t, (), out, structure)
            outs.append(out)
        assert np.array_equal(outs[0], outs[1], equal_nan=True)
        assert not np.isfinite(outs[0][2]).any()


def _kept_buffer_bits() -> None:
    from wbc.solvers.factor_rows import FactorRows, RowStructure

    rng = np.random.default_rng(6)
    inv_t = _chains(rng)
    n = inv_t.shape[0]
    block = rng.normal(size=(150, n))
    block.setflags(write=False)
    G = np.vstack([block, rng.normal(size=(90, n))])
    constant = np.r_[np.ones(150, bool), np.zeros(90, bool)]
    structure = RowStructure((240,), constant, ((150, 240),), constant)
    c, ref = FactorRows(), FactorRows()
    ref.compiled = False
    for tick in range(40):
        if tick % 10 == 7:  # new values in the constant block: its products made again
            block = block + 1.0
            block.setflags(write=False)
            G[:150] = block
        G[150:] = rng.normal(size=(90, n))
        # Mostly the same constant rows from tick to tick, at times others before them.
        kept = np.flatnonzero(rng.random(240) < (0.5 if tick % 4 == 0 else 0.97 ** tick))
        args = ((0, block),), None, structure, None, ()
        if tick % 13 == 5:  # DAQP's rows given, not G's: the buffer written otherwise
            rows = rng.normal(size=(kept.size, n))
            c.least_distance_rows(G, kept, inv_t, ((0, block),), rows)
            ref.least_distance_rows(G, kept, inv_t, ((0, block),), rows)
        a = c.least_distance_rows(G, kept, inv_t, args[0], *args[1:])
        b = ref.least_distance_rows(G, kept, inv_t, args[0], *args[1:])
        assert np.array_equal(a, b), tick


def test_constant_rows_left_in_place_are_numpys():
    """DAQP's rows buffer reused from solve to solve: a constant row already in its place
    is not copied again, and the rows are numpy's whatever was written there in between."""
    _in_one_blas_thread("_kept_buffer_bits", "tests.test_product_c")
