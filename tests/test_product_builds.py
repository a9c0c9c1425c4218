"""`wbc.solvers.product_c` built for this host's vector units and without them: the same bits.

The host build moves the rows into the tile and the sums out of it in 8 x 8 blocks
transposed in registers (AVX-512), the portable build element by element; the sums are the
same fused multiply-adds in the same order. Oracle: the portable build, on rows of a factor
shaped like the MPC's, tiles of every fill (1 to 16 rows), a width that is not a multiple of
8, rows left in place (``held``) and a non-finite row (both give up).
"""

from __future__ import annotations

import ctypes

import numpy as np
import pytest

from models.cbuild import compile_shared
from tests.test_product_c import _chains
from wbc.solvers.product_c import PRODUCT_C, CompiledProduct, product_library

pytestmark = pytest.mark.skipif(product_library() is None, reason="no C compiler")


def _times_factor(host: bool):
    lib = ctypes.CDLL(str(compile_shared(PRODUCT_C, "daqp_product", "-O3", host=host)))
    fun = lib.times_factor
    fun.argtypes = product_library().times_factor.argtypes
    fun.restype = ctypes.c_int
    return fun


@pytest.fixture(scope="module")
def builds():
    return _times_factor(True), _times_factor(False)


@pytest.mark.parametrize("extra", [11, 4])  # n = 119, 112
def test_host_and_portable_builds_give_the_same_bits(builds, extra):
    rng = np.random.default_rng(extra)
    inv_t = _chains(rng, extra=extra)
    n = inv_t.shape[0]
    host, portable = (CompiledProduct(fun, inv_t) for fun in builds)
    G = rng.normal(size=(90, n)) * (rng.random(size=(90, n)) < 0.3)
    constant = np.zeros(90, dtype=bool)
    constant[::5] = True
    products = rng.normal(size=G.shape)
    for m in (1, 7, 8, 9, 16, 17, 40, 90):
        kept = np.sort(rng.choice(90, size=m, replace=False)).astype(np.int64)
        outs, sames = [], []
        for product in (host, portable):
            out = np.full((m, n), np.nan)
            same = np.full(m, 7, dtype=np.uint8)
            assert product.run(G, kept, constant, products, out)
            assert product.run(G, kept, constant, products, out, True, same)  # held
            outs.append(out)
            sames.append(same)
        assert outs[0].tobytes() == outs[1].tobytes(), m
        assert np.array_equal(sames[0], constant[kept]) and np.array_equal(*sames), m
    bad = G.copy()
    bad[33, 5] = np.inf
    kept = np.arange(40, dtype=np.int64)
    for product in (host, portable):
        assert not product.run(bad, kept, constant, products, np.empty((40, n)))
