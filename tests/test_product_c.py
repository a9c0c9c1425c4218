"""The rows times the inverse factor in C (`wbc.solvers.product_c`).

Oracles: numpy's product (its BLAS), within the rounding bound of a dot product
(`tests.test_daqp_backend.assert_within_product_bound`), on random rows and screened subsets
of a factor shaped like the MPC's (per-axis chains, 94 % zeros) and on the recorded MPC
problems' own factor and rows; the C product of each row alone (a row's bits do not depend
on the rows it comes with, which the kept constant products rely on); the numpy path of
`FactorRows` where the C pass gives up.
"""

from __future__ import annotations

import numpy as np
import pytest

from tests.test_daqp_backend import assert_within_product_bound
from wbc.solvers import DaqpBackend
from wbc.solvers.factor_rows import FactorRows, RowStructure
from wbc.solvers.product_c import compiled_product, product_library

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


def _check(product, G, kept, constant, rng) -> np.ndarray:
    """The C product of ``G[kept]`` against numpy's and against each row's own product, the
    constant rows copied from their products."""
    inv_t = product.inv_t
    products = rng.normal(size=G.shape)  # stands for the constant blocks' kept products
    out = np.full((kept.size, inv_t.shape[0]), np.nan)
    assert product.run(G, kept, constant, products, out)
    inside = constant[kept]
    assert np.array_equal(out[inside], products[kept[inside]])
    rest = kept[~inside]
    assert_within_product_bound(out[~inside], G[rest], inv_t)
    for i in rng.choice(rest.size, size=min(rest.size, 3), replace=False):
        alone = product.times(np.ascontiguousarray(G[rest[i]:rest[i] + 1]))
        assert np.array_equal(alone[0], out[~inside][i])
    return out


def test_random_rows_are_the_product_and_the_same_bits_in_any_company():
    """Random rows, scales, zeros and screened subsets; kept rows of constant blocks copied."""
    rng = np.random.default_rng(4)
    for _ in range(30):
        product = compiled_product(_chains(rng))
        n = product.n
        m = int(rng.integers(1, 400))
        G = rng.normal(size=(m, n)) * 10.0 ** rng.integers(-6, 6, size=(m, n))
        G[rng.random((m, n)) < 0.5] = 0.0
        kept = np.flatnonzero(rng.random(m) < rng.uniform(0.1, 1.0))
        constant = rng.random(m) < 0.5
        _check(product, G, kept, constant, rng)


def test_recorded_mpc_rows_are_the_product():
    """The corpus's MPC problems: their Hessian's factor times their rows."""
    from benchmarks.qp_corpus import load_corpus

    corpus = load_corpus()
    mpc = [p for p, r in zip(corpus.problems, corpus.records) if r["controller"] == "mpc-full"]
    backend = DaqpBackend()
    backend._factor(mpc[0].P)
    inv_t, _ = backend._factor(mpc[0].P)
    product = compiled_product(inv_t)
    rng = np.random.default_rng(8)
    for p in mpc[::3]:
        m = p.G.shape[0]
        _check(product, p.G, np.flatnonzero(rng.random(m) < 0.5), rng.random(m) < 0.3, rng)
        _check(product, p.G, np.arange(m), np.zeros(m, dtype=bool), rng)


def test_a_wrong_factor_entry_is_caught_by_the_bound():
    """The oracle has power: one nonzero of the C's copy of the factor off by one part in
    1e9 fails the bound on rows that use it."""
    rng = np.random.default_rng(1)
    product = compiled_product(_chains(rng))
    G = rng.normal(size=(40, product.n))
    out = product.times(G)
    assert_within_product_bound(out, G, product.inv_t)
    product.val[product.val.size // 2] *= 1 + 1e-9
    with pytest.raises(AssertionError):
        assert_within_product_bound(product.times(G), G, product.inv_t)
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


def test_constant_rows_left_in_place_are_the_products():
    """DAQP's rows buffer reused from solve to solve: a constant row already in its place
    is not copied again, and the rows are those of a fresh `FactorRows` (the same bits)
    whatever was written there in between, and numpy's product up to rounding."""
    rng = np.random.default_rng(6)
    inv_t = _chains(rng)
    n = inv_t.shape[0]
    block = rng.normal(size=(150, n))
    block.setflags(write=False)
    G = np.vstack([block, rng.normal(size=(90, n))])
    constant = np.r_[np.ones(150, bool), np.zeros(90, bool)]
    structure = RowStructure((240,), constant, ((150, 240),), constant)
    kept_rows = FactorRows()
    for tick in range(40):
        if tick % 10 == 7:  # new values in the constant block: its products made again
            block = block + 1.0
            block.setflags(write=False)
            G[:150] = block
        G[150:] = rng.normal(size=(90, n))
        # Mostly the same constant rows from tick to tick, at times others before them.
        kept = np.flatnonzero(rng.random(240) < (0.5 if tick % 4 == 0 else 0.97 ** tick))
        if tick % 13 == 5:  # DAQP's rows given, not G's: the buffer written otherwise
            rows = rng.normal(size=(kept.size, n))
            kept_rows.least_distance_rows(G, kept, inv_t, ((0, block),), rows)
        a = kept_rows.least_distance_rows(G, kept, inv_t, ((0, block),), None, structure)
        b = FactorRows().least_distance_rows(G, kept, inv_t, ((0, block),), None, structure)
        assert np.array_equal(a, b), tick
        assert_within_product_bound(a[n:], G[kept], inv_t)
