"""`DaqpBackend`'s row screening in C: the same kept rows as numpy's, proven row by row.

The screening keeps row ``i`` of ``G x <= h`` unless ``w_i <= h_i``, with ``w_i`` the row's
worst value over the widened box (`wbc.solvers.box_screen.worst`: two or four BLAS
matrix-vector products). In numpy that is ~18 us a tick for the MPC's ~170 rows outside its
constant blocks, plus the comparison and the index list. `SCREEN_C` does it in one pass, but
its sums are not numpy's bits (OpenBLAS's gemv sums in its own order, with fused
multiply-adds), so it does not compare its own ``w_i`` with ``h_i``: it decides a row only
when numpy's ``w_i`` must fall on the same side. Every evaluation order of a sum of ``N``
rounded products lies within ``gamma_N * S_i`` of the exact value (Higham, Accuracy and
Stability of Numerical Algorithms, 2nd ed., eq. (3.5); ``gamma_N = N u / (1 - N u)``,
``u = 2^-53``, ``S_i`` the sum of the terms' magnitudes), so numpy's ``w_i`` lies within
``margin_i = 2 gamma_N S_i`` (both errors, and that of ``S_i``, with room; plus an underflow
allowance) of the C value. A row whose C value is not farther than that from ``h_i`` (or
that is not finite) makes the pass give up: the caller then runs the numpy screening, whose
result is the definition. The rows of the constant blocks, whose numpy sums the caller
keeps, are compared in C as numpy compares them (``!(w <= h)``: NaN keeps the row).
`tests/test_screen_c.py` checks the C pass against numpy on random and on recorded problems.
"""

from __future__ import annotations

import ctypes
import functools

import numpy as np

from models.cbuild import address, load_shared

__all__ = ["SCREEN_C", "CompiledScreen", "compiled_screen", "screen_library"]

SCREEN_C = r"""
#include <math.h>
#include <stdint.h>
#include <string.h>
typedef double v8 __attribute__((vector_size(64)));
typedef long long v8i __attribute__((vector_size(64)));
#define M 0x7fffffffffffffffLL
static const v8i ABS = {M, M, M, M, M, M, M, M};  /* clears the sign bit: fabs */
#undef M

/* nextafter(x, -INFINITY) and nextafter(x, INFINITY), inline: the neighbours of x. */
static inline double next_down(double x) {
  if (x != x || x == -INFINITY) return x;
  if (x == 0.0) return -4.9406564584124654e-324;
  uint64_t b;
  memcpy(&b, &x, sizeof b);
  b = x > 0.0 ? b - 1 : b + 1;
  memcpy(&x, &b, sizeof x);
  return x;
}

static inline double next_up(double x) { return -next_down(-x); }

/* Rows 0..m-1 of G (row stride ld): kept[] gets the kept rows in order, rest[] those of
   them in a gap and not done[]; counts = (kept, rest). A gap row (inside one of the
   n_gaps [first, stop) pairs) is decided from its own sums when numpy's must agree
   (module docstring), else the pass returns -1 (nothing decided); other rows compare
   worst[i] with h[i] as numpy does. Returns 0. */
int screen_rows(const double* G, long m, long n, long ld, const double* worst,
                const double* h, const int64_t* gaps, long n_gaps,
                const unsigned char* done, const double* mid, const double* spread,
                const int64_t* open, long n_open, const double* hi_open,
                const double* lo_open, double gamma, int64_t* kept, int64_t* rest,
                int64_t* counts) {
  long i, k, j, g = 0, n_kept = 0, n_rest = 0;
  for (i = 0; i < m; ++i) {
    int keep;
    while (g < n_gaps && i >= gaps[2 * g + 1]) ++g;
    if (g < n_gaps && i >= gaps[2 * g]) {
      const double* row = G + i * ld;
      double w = 0.0, s = 0.0, lo, hi;
      /* eight lanes of vectors (a sum's order does not matter to the margin) */
      v8 wv = {0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0}, sv = wv, wu = wv, su = wv;
      for (k = 0; k + 16 <= n; k += 16) {  /* two accumulators: the adds' latency */
        v8 x, y, a, b, c, d;
        memcpy(&x, row + k, sizeof x);
        memcpy(&y, row + k + 8, sizeof y);
        memcpy(&a, mid + k, sizeof a);
        memcpy(&c, mid + k + 8, sizeof c);
        memcpy(&b, spread + k, sizeof b);
        memcpy(&d, spread + k + 8, sizeof d);
        a *= x;
        c *= y;
        b *= (v8)((v8i)x & ABS);
        d *= (v8)((v8i)y & ABS);
        wv += a + b;
        wu += c + d;
        sv += (v8)((v8i)a & ABS) + (v8)((v8i)b & ABS);  /* b < 0 only if a box is empty */
        su += (v8)((v8i)c & ABS) + (v8)((v8i)d & ABS);
      }
      wv += wu;
      sv += su;
      for (; k < n; ++k) {
        double a = row[k] * mid[k], b = fabs(row[k]) * spread[k];
        w += a + b;
        s += fabs(a) + fabs(b);
      }
      w += ((wv[0] + wv[1]) + (wv[2] + wv[3])) + ((wv[4] + wv[5]) + (wv[6] + wv[7]));
      s += ((sv[0] + sv[1]) + (sv[2] + sv[3])) + ((sv[4] + sv[5]) + (sv[6] + sv[7]));
      for (j = 0; j < n_open; ++j) {
        double x = row[open[j]];
        double a = x > 0.0 ? x * hi_open[j] : (x < 0.0 ? x * lo_open[j] : 0.0);
        w += a;
        s += fabs(a);
      }
      if (!isfinite(w) || !(s < 1e300) || isnan(h[i])) return -1;  /* no overflow */
      s = gamma * s + 1e-300;  /* the margin; 1e-300: products that underflow */
      lo = next_down(w - s);  /* below the exact w - margin */
      hi = next_up(w + s);
      if (lo > h[i]) keep = 1;
      else if (hi <= h[i]) keep = 0;
      else return -1;
      if (keep && !done[i]) rest[n_rest++] = i;
    } else {
      keep = !(worst[i] <= h[i]);
    }
    if (keep) kept[n_kept++] = i;
  }
  counts[0] = n_kept;
  counts[1] = n_rest;
  return 0;
}

"""

_U = 2.0 ** -53


@functools.cache
def screen_library():
    """`SCREEN_C` compiled and loaded once per process; None without a compiler."""
    p, lg = ctypes.c_void_p, ctypes.c_long
    return load_shared(SCREEN_C, "daqp_screen", {
        "screen_rows": ([p, lg, lg, lg, p, p, p, lg, p, p, p, p, lg, p, p, ctypes.c_double,
                         p, p, p], ctypes.c_int)}, "numpy")


class CompiledScreen:
    """``screen_rows`` for one problem's shape: ``m`` rows, ``n`` columns, fixed gaps.

    Holds the index buffers and the box's arguments; `run` passes the per-tick arrays.
    Not shared between threads (each `DaqpBackend` makes its own).
    """

    def __init__(self, fun, m: int, n: int, gaps: tuple, done: np.ndarray):
        self.m, self.n = m, n
        self.gaps = np.array(gaps, dtype=np.int64).reshape(-1, 2)
        self.done = np.ascontiguousarray(done, dtype=np.uint8)
        self.kept = np.empty(m, dtype=np.int64)
        self.rest = np.empty(m, dtype=np.int64)
        self.counts = np.zeros(2, dtype=np.int64)
        self._gaps, self._done = self.gaps.ctypes.data, self.done.ctypes.data
        self._fun = fun
        self._box = None  # (the `BoxTerms`, its arrays as C reads them, the addresses)

    def run(self, G: np.ndarray, worst: np.ndarray, h: np.ndarray, box
            ) -> tuple[np.ndarray, np.ndarray] | None:
        """``(kept, rest)`` row indices (views of kept buffers, valid until the next run).

        ``G``: shape (m, n) with unit column stride; ``worst``: the block rows' numpy sums,
        (m,); ``box``: the `wbc.solvers.box_screen.BoxTerms` of the bounds. None: a row
        could not be decided (module docstring); the caller screens in numpy.
        """
        if self._box is None or self._box[0] is not box:
            n_terms = 2 * self.n + 2 * box.open.size + 4  # roundings on a term's way, both
            gamma = 2.02 * n_terms * _U / (1.0 - n_terms * _U)  # sums' and S's, with room
            terms = (box.mid, box.spread, box.open.astype(np.int64),
                     np.ascontiguousarray(box.hi_open), np.ascontiguousarray(box.lo_open))
            args = (*(t.ctypes.data for t in terms[:3]), box.open.size,
                    *(t.ctypes.data for t in terms[3:]), gamma, self.kept.ctypes.data,
                    self.rest.ctypes.data, self.counts.ctypes.data)
            self._box = (box, terms, args)  # the arrays outlive their addresses
        if self._fun(address(G), self.m, self.n, G.strides[0] // 8, address(worst),
                     address(h), self._gaps, self.gaps.shape[0], self._done,
                     *self._box[2]) != 0:
            return None
        return self.kept[:self.counts[0]], self.rest[:self.counts[1]]


def compiled_screen(m: int, n: int, gaps: tuple, done: np.ndarray) -> CompiledScreen | None:
    """A new `CompiledScreen`; None without a working C compiler."""
    lib = screen_library()
    return None if lib is None else CompiledScreen(lib.screen_rows, m, n, gaps, done)
