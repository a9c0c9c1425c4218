"""`SideReserveConstraint`'s rows in C: the right-hand sides and the scaled rows in one call.

In numpy the right-hand sides after the product with the nominal plan are seven ufunc
calls on a few dozen rows, then a scatter of the slack entries (~5 us a tick for a few
hundred flops). `SIDE_RESERVE_C` is
the same IEEE operations in the same order (numpy's ``maximum`` NaN rule included),
compiled once with the system compiler (`models.cbuild`, no contraction into fused
multiply-adds) and called through ctypes on kept buffers: the same bits
(`tests/test_side_reserve_c.py`). The product ``A_sum x`` stays numpy's (BLAS's sums stay
BLAS's), and so does the division of the rows by ``-f_s`` (numpy's vectorized loop is
faster than this one's). Without a compiler the numpy code runs.
"""

from __future__ import annotations

import ctypes
import functools

import numpy as np

from models.cbuild import address, bind, load_shared

__all__ = ["SIDE_RESERVE_C", "CompiledSideRows", "compiled_side_rows", "side_reserve_library"]

SIDE_RESERVE_C = r"""
#include <math.h>
/* numpy's maximum: NaN in either gives NaN; equal values give the first. */
static double np_max(double a, double b) { return (a >= b || isnan(a)) ? a : b; }

/* in = b (m), need (m), decay (m), then f_s; slack: each row's slack column (m).
   On entry h holds S = A x (m); on return
   h = (b - (need - max(need - (S + b), 0) decay)) / f_s and -1 in each row of G (m, n)
   at its slack column. */
int side_rows(const double* restrict in, const long* restrict slack, long m, long n,
              double* restrict G, double* restrict h) {
  const double *b = in, *need = in + m, *decay = in + 2 * m;
  const double fs = in[3 * m];
  long r;
  if (m < 0 || n < 1) return -1;
  for (r = 0; r < m; ++r) {
    if (slack[r] < 0 || slack[r] >= n) return -1;
  }
  for (r = 0; r < m; ++r) {
    double x = h[r] + b[r];
    x = need[r] - x;
    x = np_max(x, 0.0);
    x = x * decay[r];
    x = need[r] - x;
    x = b[r] - x;
    h[r] = x / fs;
  }
  for (r = 0; r < m; ++r) G[r * n + slack[r]] = -1.0;
  return 0;
}
"""


class CompiledSideRows:
    """``side_rows`` on kept buffers for ``m`` rows of ``n`` columns.

    ``b`` and ``need`` (m,) are filled by the caller each tick; ``decay`` and the slack
    columns are fixed. Not shared between threads (each constraint makes its own).
    """

    def __init__(self, fun, decay: np.ndarray, slack_columns: np.ndarray, n: int):
        m = decay.size
        self._in = np.zeros(3 * m + 1)
        self.b, self.need = self._in[:m], self._in[m:2 * m]
        self._in[2 * m:3 * m] = decay
        self._slack = np.ascontiguousarray(slack_columns, dtype=np.int64)
        self.m, self.n = m, n
        self._call = bind(fun, self._in, self._slack, m, n)

    def rows(self, A_sum: np.ndarray, h: np.ndarray, force_scale: float) -> None:
        """``h`` (``A_sum x``, m) into the right-hand sides and G's slack entries, in place.

        ``A_sum`` (m, n) is G already divided by ``-force_scale``.

        Raises:
            ValueError: The arrays are not the kept shapes (both are fresh C-contiguous
                float64 arrays: the caller's sum and product).
        """
        if A_sum.shape != (self.m, self.n) or h.shape != (self.m,):
            raise ValueError(f"side rows: need ({self.m}, {self.n}) and ({self.m},), got "
                             f"{A_sum.shape} and {h.shape}")
        self._in[-1] = force_scale
        if self._call(address(A_sum), address(h)) != 0:
            raise ValueError("side rows: a slack column outside the rows")


@functools.cache
def side_reserve_library():
    """`SIDE_RESERVE_C` compiled and loaded (once per process); None without a compiler."""
    return load_shared(SIDE_RESERVE_C, "side_reserve", {
        "side_rows": ([ctypes.c_void_p] * 2 + [ctypes.c_long] * 2 + [ctypes.c_void_p] * 2,
                      ctypes.c_int)}, "numpy")


def compiled_side_rows(decay, slack_columns, n: int) -> CompiledSideRows | None:
    """A new `CompiledSideRows`; None without a working C compiler."""
    lib = side_reserve_library()
    return None if lib is None else CompiledSideRows(lib.side_rows, np.asarray(decay, float),
                                                     slack_columns, n)
