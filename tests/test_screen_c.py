"""`DaqpBackend`'s screening in C (`wbc.solvers.screen_c`) keeps numpy's rows exactly.

Oracle: the numpy screening (`compiled = False`), the definition; random problems with
open bounds, infinite and NaN right-hand sides and rows exactly at their bound (which the C
pass must leave to numpy), and the recorded MPC problems of the QP corpus.
"""

from __future__ import annotations

import numpy as np
import pytest

from benchmarks.qp_corpus import load_corpus
from wbc.solvers import DaqpBackend
from wbc.solvers.daqp_backend import _box_terms, _worst
from wbc.solvers.screen_c import compiled_screen

pytestmark = pytest.mark.skipif(compiled_screen(1, 1, (), np.zeros(1, bool)) is None,
                                reason="no C compiler")


def _both(G, h, lb, ub, blocks=(), diagonal=()):
    """(C, numpy) screenings' kept rows and the C's `(kept, rest)` (None: it gave up)."""
    c, ref = DaqpBackend(), DaqpBackend()
    ref.compiled = False
    kept = c._screen(G, h, lb, ub, blocks, diagonal)
    return kept, ref._screen(G, h, lb, ub, blocks, diagonal), c._kept_rest


def _random_problem(rng, m=300, n=37):
    G = rng.normal(size=(m, n)) * (rng.random((m, n)) < 0.6)
    lb, ub = -rng.uniform(0.1, 2, n), rng.uniform(0.1, 2, n)
    lb[rng.random(n) < 0.1] = -np.inf
    ub[rng.random(n) < 0.1] = np.inf
    x = rng.uniform(lb.clip(-3), ub.clip(None, 3), size=(m, n))
    h = np.einsum("ij,ij->i", G, x) + rng.normal(0, 1, m)
    return G, h, lb, ub


def test_random_problems_keep_numpys_rows():
    rng = np.random.default_rng(11)
    decided = 0
    for k in range(40):
        G, h, lb, ub = _random_problem(rng)
        block = G[:100].copy()
        block.setflags(write=False)
        G[:100] = block
        h[rng.random(h.size) < 0.05] = np.inf
        h[rng.random(h.size) < 0.05] = -np.inf
        h[5] = np.nan  # in the block: kept, as numpy's ``~(worst <= h)`` keeps it
        kept, ref, found = _both(G, h, lb, ub, ((0, block),))
        np.testing.assert_array_equal(kept, ref)
        decided += found is not None
        if found is not None:  # the rows outside the block, in order
            np.testing.assert_array_equal(found[1], ref[ref >= 100])
    assert decided == 40


def test_undecidable_rows_go_to_numpy():
    """A row exactly at its bound, a NaN bound, a NaN entry: the C pass gives up."""
    rng = np.random.default_rng(5)
    G, h, lb, ub = _random_problem(rng, 50, 12)
    ub[:] = lb[:] = 0.0  # every box a point: worst = |g|_1 tol
    block = np.zeros((1, 12))
    block.setflags(write=False)
    G[0] = 0.0
    h[1] = np.nan
    for edit in (lambda: h.__setitem__(2, 0.0), lambda: G.__setitem__((3, 4), np.nan),
                 lambda: None):
        edit()
        kept, ref, found = _both(G, h, lb, ub, ((0, block),))
        np.testing.assert_array_equal(kept, ref)
        assert found is None
    h[1] = 5.0
    G[3, 4] = 1.0
    h[2] = 1.0  # row 0 (zero) sums to exactly 0 <= 1: decided
    kept, ref, found = _both(G, h, lb, ub, ((0, block),))
    np.testing.assert_array_equal(kept, ref)
    assert found is not None


def test_rows_within_rounding_of_their_bound_keep_numpys_rows():
    """A row's ``h`` a few ulps from numpy's own worst value: only the margin keeps the C
    pass, which sums in another order, from deciding it, so it must give up."""
    rng = np.random.default_rng(2)
    for _ in range(40):
        G, h, lb, ub = _random_problem(rng, 60, 37)
        worst = _worst(G, _box_terms(lb, ub, G.shape[1], DaqpBackend().tolerances["primal_tol"]))
        far = 1.0 + 1e-3 * np.abs(worst)  # (an open bound's rows sum to ~1e20)
        h = worst + np.where(rng.random(worst.size) < 0.5, -far, far)  # clear rows
        k = rng.integers(1, h.size)  # and one near tie
        h[k] = worst[k]
        for _ in range(k % 4 + 1):  # 1 to 4 ulps above or below
            h[k] = np.nextafter(h[k], np.inf if k % 2 else -np.inf)
        block = np.zeros((1, G.shape[1]))
        block.setflags(write=False)
        kept, ref, found = _both(G, h, lb, ub, ((0, block),))
        np.testing.assert_array_equal(kept, ref)
        assert found is None


def test_recorded_mpc_problems_keep_numpys_rows():
    """The corpus's problems, their first rows as a constant block."""
    corpus = load_corpus()
    decided, total = 0, 0
    for p in corpus.problems:
        if p.G is None:
            continue
        total += 1
        block = p.G[:p.G.shape[0] // 3].copy()
        block.setflags(write=False)
        kept, ref, found = _both(p.G, p.h, p.lb, p.ub, ((0, block),))
        np.testing.assert_array_equal(kept, ref)
        decided += found is not None
    assert decided == total > 0
