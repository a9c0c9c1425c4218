"""`DaqpBackend`'s rows times the inverse factor in C, from the factor's nonzeros.

DAQP's rows of the least-distance form are ``G[kept] @ L^-T`` (`wbc.solvers.factor_rows`);
the MPC's ``L^-T`` is 94 % zeros (per-axis chains along the horizon), which the BLAS product
multiplies all the same: ~0.07 ms a tick for the ~120 kept rows outside constant blocks,
with the gather of the kept rows. `PRODUCT_C` reads the factor by columns, its nonzeros
only, sixteen rows at a time (one vector lane a row), and copies the constant blocks' rows
from their kept products in the same pass: ~0.02 ms.

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

__all__ = ["PRODUCT_C", "ROWS", "CompiledProduct", "compiled_product", "product_library"]

ROWS = 16  # rows multiplied together: a lane each of two vectors (`PRODUCT_C`'s VECS)

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

/* `columns` with as few vectors as hold the `used` rows (the others' lanes: stale), then
   row l of the products to out[slot[l] * n]. */
static void flush(const double* tile, long used, const int64_t* slot, long n,
                  const int64_t* start, const int64_t* row, const double* val, double* sums,
                  double* out) {
  switch ((used + LANES - 1) / LANES) {
    case 1: columns(tile, 1, n, start, row, val, sums); break;
    case 2: columns(tile, 2, n, start, row, val, sums); break;
    case 3: columns(tile, 3, n, start, row, val, sums); break;
    default: columns(tile, VECS, n, start, row, val, sums);
  }
  for (long l = 0; l < used; ++l)
    for (long j = 0; j < n; ++j) out[slot[l] * n + j] = sums[j * ROWS + l];
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
  for (long t = 0; t < m_kept; ++t) {
    const int64_t r = kept[t];
    if (constant[r]) {
      const int left = t < m_last && last[t] == r;
      if (!left) memcpy(out + t * n, products + r * ld_products, n * sizeof(double));
      if (same) same[t] = (unsigned char)left;
      continue;
    }
    if (same) same[t] = 0;
    const double* g = G + r * ld;
    for (long k = 0; k < n; ++k) {
      if (!isfinite(g[k])) return -1;
      tile[k * ROWS + used] = g[k];
    }
    slot[used++] = t;
    if (used == ROWS) {
      flush(tile, used, slot, n, start, row, val, sums, out);
      used = 0;
    }
  }
  if (used) flush(tile, used, slot, n, start, row, val, sums, out);
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
        "numpy")


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
