"""`DaqpBackend`'s rows times the inverse factor in C, from the factor's nonzeros.

DAQP's rows of the least-distance form are ``G[kept] @ L^-T`` (`wbc.solvers.factor_rows`);
the MPC's ``L^-T`` is 94 % zeros (per-axis chains along the horizon), which the BLAS product
multiplies all the same: ~0.07 ms a tick for the ~120 kept rows outside constant blocks,
with the gather of the kept rows. `PRODUCT_C` reads the factor by columns, its nonzeros
only, sixteen rows at a time (one vector lane a row; in and out of those lanes in 8 x 8 blocks
transposed in registers where there is AVX-512), and copies the constant blocks' rows
from their kept products in the same pass: ~0.01 ms. It marks the rows it left in place
(``same``), which DAQP's kept workspace then need not normalise again.

Each entry is summed over the inner dimension in order, one fused multiply-add a term from
zero (one rounding a term, whether the AVX-512 instruction or C's ``fma`` does it), so the
product has the same bits on every host, where numpy's depends on the kernel its BLAS picks
for the CPU and the size (OpenBLAS sums the odd rows of a small product in another order on
some CPUs). Against numpy's product it agrees within the rounding bound of a dot product
(`tests/test_product_c.py`). A row with a non-finite entry makes the pass give up (numpy's
product would spread its NaN to every column): the caller then multiplies with numpy.
"""

from __future__ import annotations

import ctypes
import functools

import numpy as np

from models.cbuild import address, load_shared

__all__ = [
    "PRODUCT_C", "ROWS", "TRANSPOSE8_C", "CompiledProduct", "compiled_product",
    "product_library",
]

ROWS = 16  # rows multiplied together: a lane each of two vectors (`PRODUCT_C`'s VECS)

# An 8 x 8 block of doubles transposed in AVX-512 registers (also `wbc.solvers.daqp_c`'s
# row normalisation): C put into a source after its ``immintrin.h`` include.
TRANSPOSE8_C = r"""
#if defined(__AVX512F__)
/* c[q] = column q of the 8 x 8 block whose rows are v[0..7] (lane l: row l). */
static inline void transpose8(const __m512d v[8], __m512d c[8]) {
  const __m512i lo2 = _mm512_set_epi64(13, 12, 5, 4, 9, 8, 1, 0);
  const __m512i hi2 = _mm512_set_epi64(15, 14, 7, 6, 11, 10, 3, 2);
  const __m512i lo4 = _mm512_set_epi64(11, 10, 9, 8, 3, 2, 1, 0);
  const __m512i hi4 = _mm512_set_epi64(15, 14, 13, 12, 7, 6, 5, 4);
  __m512d t[8], u[8];
  for (int p = 0; p < 4; ++p) {
    t[2 * p] = _mm512_unpacklo_pd(v[2 * p], v[2 * p + 1]);     /* cols 0 2 4 6 */
    t[2 * p + 1] = _mm512_unpackhi_pd(v[2 * p], v[2 * p + 1]); /* cols 1 3 5 7 */
  }
  for (int h = 0; h < 2; ++h)
    for (int odd = 0; odd < 2; ++odd) {
      const __m512d a = t[4 * h + odd], b = t[4 * h + 2 + odd];
      u[4 * h + odd] = _mm512_permutex2var_pd(a, lo2, b);     /* cols odd, odd + 4 */
      u[4 * h + 2 + odd] = _mm512_permutex2var_pd(a, hi2, b); /* cols 2 + odd, 6 + odd */
    }
  for (int q = 0; q < 4; ++q) {
    c[q] = _mm512_permutex2var_pd(u[q], lo4, u[4 + q]);
    c[q + 4] = _mm512_permutex2var_pd(u[q], hi4, u[4 + q]);
  }
}
#endif
"""

PRODUCT_C = r"""
#include <math.h>
#include <stdint.h>
#include <string.h>
#if defined(__AVX512F__)
#include <immintrin.h>
#endif
#define LANES 8
#define VECS 2  /* vectors of rows in flight: independent sums, against the FMA's latency */
#define ROWS (LANES * VECS)
typedef double v8 __attribute__((vector_size(64)));

/* c + a * b in every lane, one rounding (the BLAS's fused multiply-add). */
static inline v8 fma8(v8 a, double b, v8 c) {
#if defined(__AVX512F__)
  return (v8)_mm512_fmadd_pd((__m512d)a, _mm512_set1_pd(b), (__m512d)c);
#else
  for (int l = 0; l < LANES; ++l) c[l] = fma(a[l], b, c[l]);
  return c;
#endif
}

/* The tile's rows (tile[k * ROWS + l]: row l's entry k; nv vectors of them) times the
   factor, whose column j has its nonzeros val[p] in rows row[p], p in [start[j],
   start[j+1]), rows increasing: sums[j * ROWS + l] (the same layout). */
static inline __attribute__((always_inline)) void columns(
    const double* tile, const int nv, long n, const int64_t* start, const int64_t* row,
    const double* val, double* sums) {
  for (long j = 0; j < n; ++j) {
    v8 acc[VECS];
    for (int w = 0; w < nv; ++w) acc[w] = (v8){0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0};
    for (int64_t p = start[j]; p < start[j + 1]; ++p) {
      const double* t = tile + row[p] * ROWS;
      for (int w = 0; w < nv; ++w) {
        v8 g;
        memcpy(&g, t + w * LANES, sizeof g);
        acc[w] = fma8(g, val[p], acc[w]);
      }
    }
    for (int w = 0; w < nv; ++w) memcpy(sums + j * ROWS + w * LANES, &acc[w], sizeof(v8));
  }
}

""" + TRANSPOSE8_C + r"""
/* The `used` rows g[l] (n long) into the tile (tile[k * ROWS + l]: row l's entry k; the
   lanes past `used` of the vectors that hold them: copies of the last row, or stale, all
   finite), `columns` with as few vectors as hold them, then row l of the products to
   out[slot[l] * n]. Returns 0; -1 if a row has a non-finite entry (nothing written). */
static int flush(const double* const* g, long used, const int64_t* slot, long n,
                 const int64_t* start, const int64_t* row, const double* val, double* tile,
                 double* sums, double* out) {
  const int nv = (int)((used + LANES - 1) / LANES);
#if defined(__AVX512F__)
  /* 8 x 8 blocks transposed in registers, both ways. */
  for (int w = 0; w < nv; ++w) {
    const double* r[8];
    for (int l = 0; l < 8; ++l) r[l] = g[w * 8 + l < used ? w * 8 + l : used - 1];
    for (long j = 0; j < n; j += 8) {
      const __mmask8 k = n - j >= 8 ? 0xFF : (__mmask8)((1u << (n - j)) - 1);
      __m512d v[8], c[8];
      for (int l = 0; l < 8; ++l) {
        v[l] = _mm512_maskz_loadu_pd(k, r[l] + j);
        /* x - x: 0 for a finite x, NaN otherwise */
        if (_mm512_mask_cmp_pd_mask(k, _mm512_sub_pd(v[l], v[l]), _mm512_setzero_pd(),
                                    _CMP_EQ_OQ) != k)
          return -1;
      }
      transpose8(v, c);
      for (long q = 0; q < 8 && j + q < n; ++q)
        _mm512_storeu_pd(tile + (j + q) * ROWS + w * LANES, c[q]);
    }
  }
#else
  for (long l = 0; l < used; ++l)
    for (long k = 0; k < n; ++k) {
      if (!isfinite(g[l][k])) return -1;
      tile[k * ROWS + l] = g[l][k];
    }
#endif
  switch (nv) {
    case 1: columns(tile, 1, n, start, row, val, sums); break;
    case 2: columns(tile, 2, n, start, row, val, sums); break;
    case 3: columns(tile, 3, n, start, row, val, sums); break;
    default: columns(tile, VECS, n, start, row, val, sums);
  }
#if defined(__AVX512F__)
  for (int w = 0; w < nv; ++w)
    for (long j = 0; j < n; j += 8) {
      const __mmask8 k = n - j >= 8 ? 0xFF : (__mmask8)((1u << (n - j)) - 1);
      __m512d v[8], c[8];
      for (int q = 0; q < 8; ++q)  /* column j + q of the 8 rows (past n: unused) */
        v[q] = _mm512_loadu_pd(sums + (j + q < n ? j + q : n - 1) * ROWS + w * LANES);
      transpose8(v, c);
      for (long l = 0; l < 8 && w * 8 + l < used; ++l)
        _mm512_mask_storeu_pd(out + slot[w * 8 + l] * n + j, k, c[l]);
    }
#else
  for (long l = 0; l < used; ++l)
    for (long j = 0; j < n; ++j) out[slot[l] * n + j] = sums[j * ROWS + l];
#endif
  return 0;
}

/* out[t] = G[kept[t]] @ factor for t < m_kept (out's rows n long): a row marked in
   constant[] copied from products[kept[t]] unless out holds it already (last[t] == kept[t],
   t < m_last: the rows of the last pass, the caller vouches for out and products), the
   others multiplied; last[] then gets kept[]. Returns 0; -1 if a multiplied row has a
   non-finite entry (out and last then partly written). same (NULL: not wanted): 1 for the
   rows of out left as they were, 0 for the others. */
int times_factor(const double* G, long ld, long n, const int64_t* kept, long m_kept,
                 const unsigned char* constant, const double* products, long ld_products,
                 const int64_t* start, const int64_t* row, const double* val, double* tile,
                 double* sums, int64_t* slot, double* out, int64_t* last, long m_last,
                 unsigned char* same) {
  long used = 0;
  const double* g[ROWS];
  for (long t = 0; t < m_kept; ++t) {
    const int64_t r = kept[t];
    if (constant[r]) {
      const int left = t < m_last && last[t] == r;
      if (!left) memcpy(out + t * n, products + r * ld_products, n * sizeof(double));
      if (same) same[t] = (unsigned char)left;
      continue;
    }
    if (same) same[t] = 0;
    g[used] = G + r * ld;
    slot[used++] = t;
    if (used == ROWS) {
      if (flush(g, used, slot, n, start, row, val, tile, sums, out)) return -1;
      used = 0;
    }
  }
  if (used && flush(g, used, slot, n, start, row, val, tile, sums, out)) return -1;
  memcpy(last, kept, m_kept * sizeof(int64_t));
  return 0;
}
"""

@functools.cache
def product_library():
    """`PRODUCT_C` compiled and loaded once per process; None without a compiler."""
    p, lg = ctypes.c_void_p, ctypes.c_long
    return load_shared(PRODUCT_C, "daqp_product", {
        "times_factor": ([p, lg, lg, p, lg, p, p, lg, p, p, p, p, p, p, p, p, lg, p],
                         ctypes.c_int)},
        "numpy", opt="-O3")


class CompiledProduct:
    """``times_factor`` for one factor ``inv_t`` (shape (n, n)): its nonzeros by column.

    Holds the factor (the caller keys this object on it), its nonzeros and a tile of
    `ROWS` rows. Not shared between threads (each `DaqpBackend` makes its own).
    """

    def __init__(self, fun, inv_t: np.ndarray):
        self.inv_t = inv_t
        self.n = n = inv_t.shape[0]
        columns = np.ascontiguousarray(inv_t.T)
        nonzero = columns != 0
        self.start = np.zeros(n + 1, dtype=np.int64)
        np.cumsum(nonzero.sum(axis=1), out=self.start[1:])
        self.row = np.nonzero(nonzero)[1].astype(np.int64)  # row-major: rows increasing
        self.val = np.ascontiguousarray(columns[nonzero])
        self.tile = np.zeros(n * ROWS)  # stale lanes hold finite numbers
        self.sums = np.empty(n * ROWS)
        self.slot = np.empty(ROWS, dtype=np.int64)
        self._fun = fun
        self._args = tuple(a.ctypes.data for a in (self.start, self.row, self.val, self.tile,
                                                   self.sums, self.slot))
        self._arrays = (None, 0, None, 0)  # (constant, its address, products, its address)
        self._last = (np.empty(0, dtype=np.int64), 0, 0)  # (the last kept, address, size)

    def run(self, G: np.ndarray, kept: np.ndarray, constant: np.ndarray,
            products: np.ndarray, out: np.ndarray, held: bool = False,
            same: np.ndarray | None = None) -> bool:
        """``out[:] = G[kept] @ inv_t``, the rows ``constant`` marks from ``products``.

        ``G``: float64 (m, n), unit column stride; ``kept``: int64 row indices, contiguous;
        ``constant``: bool (m,), contiguous; ``products``: float64 (m, n), unit column
        stride, the constant rows' products; ``out``: float64 (kept.size, n), C-contiguous.
        ``held``: ``out`` is the last run's (it returned True), unwritten since, and the
        constant rows of ``products`` are the same: a constant row already at its place is
        not copied again (the MPC's ~170 rows, 0.16 MB, mostly out of the caches by then).
        ``same``: uint8, at least ``kept.size`` long, contiguous, or None: gets 1 for the
        rows of ``out`` left as they were (``held``), 0 for the others (if True is returned).
        False: a row to multiply has a non-finite entry (``out`` is then undefined).
        """
        last = self._last
        if last[0].size < kept.size:
            buffer = np.empty(2 * kept.size, dtype=np.int64)
            last = (buffer, buffer.ctypes.data, 0)
        # The caller's arrays kept from solve to solve, by identity; never G (the QP builder
        # reuses its G only if no one else holds it).
        arrays = self._arrays
        if arrays[0] is not constant or arrays[2] is not products:
            arrays = self._arrays = (constant, address(constant), products,
                                     address(products))
        ok = self._fun(address(G), G.strides[0] // 8, self.n, address(kept),
                       kept.size, arrays[1], arrays[3], products.strides[0] // 8, *self._args,
                       address(out), last[1], last[2] if held else 0,
                       None if same is None else address(same)) == 0
        self._last = (last[0], last[1], kept.size if ok else 0)
        return ok


    def times(self, rows: np.ndarray) -> np.ndarray | None:
        """``rows @ inv_t`` as a new array; None if a row has a non-finite entry.

        ``rows``: float64 (m, n), unit column stride.
        """
        m = rows.shape[0]
        out = np.empty((m, self.n))
        every = np.arange(m, dtype=np.int64)
        return out if self.run(rows, every, np.zeros(m, dtype=bool), rows, out) else None


def compiled_product(inv_t: np.ndarray) -> CompiledProduct | None:
    """The C product for the factor ``inv_t`` (shape (n, n)).

    None without a compiler and for a factor with a non-finite entry: the caller then
    multiplies with numpy.
    """
    lib = product_library()
    if lib is None or not np.isfinite(inv_t).all():
        return None
    return CompiledProduct(lib.times_factor, np.ascontiguousarray(inv_t, dtype=float))
