"""`SideReserveConstraint`'s rows in C: the pairs' sums, the product and the rows in one call.

In numpy a tick's rows are the gather of each pair's two wheel rows at the late nodes (two
fancy-indexed copies and their sum, ~50 kB), the nominal plan's vector, the product with it,
seven ufunc calls on a few dozen right-hand sides, the division of the rows by ``-f_s`` and a
scatter of the slack entries: ~17 us a tick in the closed loop for what is one pass over the
rows. `SIDE_RESERVE_C` is the same IEEE operations in the same order (numpy's ``maximum``
NaN rule included), compiled once with the system compiler (`models.cbuild`, no contraction
into fused multiply-adds) and called through ctypes on kept buffers; the product is the call
numpy's ``@`` makes, numpy's own ``cblas_dgemv`` (`models.numpy_blas`: column-major,
transposed, ``(102, 112, n, m, 1.0, A, n, x, 1, 0.0, y, 1)``) on a C-contiguous sum like
numpy's: the same bits (`tests/test_side_reserve_c.py`, `tests/test_side_reserve_ticks.py`).
Without a compiler, without numpy's BLAS, for a single row (numpy's product is then a dot) or
for arrays of another layout the numpy code runs.
"""

from __future__ import annotations

import ctypes
import functools

import numpy as np

from models.cbuild import address, bind, load_shared
from models.numpy_blas import numpy_blas
from wbc.constraints.limits_c import plain_address

SIDE_PAIRS = np.array([[0, 1], [2, 3]])  # left (FL, RL), right (FR, RR) in the wheel order

__all__ = ["SIDE_PAIRS", "SIDE_RESERVE_C", "CompiledSideReserve", "compiled_side_reserve",
           "side_reserve_library"]

SIDE_RESERVE_C = r"""
#include <math.h>
typedef void (*gemv_fn)(int, int, long long, long long, double, const double*, long long,
                        const double*, long long, double, double*, long long);
/* Eight doubles at any address: the element-wise sums and quotients in vector registers
   (the same IEEE operations on each element; -O2 leaves these loops scalar). */
typedef double v8 __attribute__((vector_size(64), aligned(8)));
/* numpy's maximum: NaN in either gives NaN; equal values give the first. */
static double np_max(double a, double b) { return (a >= b || isnan(a)) ? a : b; }

/* dims = m_nodes, m_sides, n, rows of A, first input column, inputs, scale column (-1:
   none); index = the nodes (m_nodes), the sides (m_sides: 0 left, 1 right), their pairs'
   first wheels (m_sides), second wheels (m_sides), each row's slack column (m = m_nodes
   m_sides); decay (m); x (n): the nominal plan, zeros outside its inputs and scale (kept).
   Per tick: A (rows, n), b (rows), the nominal inputs (inputs), the left and right sides'
   needs, f_s, -f_s and the scale; out G (m, n),
   h (m) (-f_s an argument: the compiler may not turn a / -f_s into -(a / f_s), which
   flips a NaN's sign):
     G = (A[first] + A[second]) / -f_s, with -1 at each row's slack column,
     h = (b_s - (need - max(need - (S + b_s), 0) decay)) / f_s,  S = (A[first] + A[second]) x,
   row r = node i, side s: r = i m_sides + s; b_s = b[first] + b[second]. */
int side_reserve_rows(const long* dims, const long* index, const double* decay,
                      void* gemv, double* x, const double* A, const double* b,
                      const double* nominal, double need0, double need1, double fs,
                      double neg_fs, double scale, double* G, double* h) {
  const long m_nodes = dims[0], m_sides = dims[1], n = dims[2], n_a = dims[3];
  const long col0 = dims[4], n_in = dims[5], scale_col = dims[6], m = m_nodes * m_sides;
  const long *nodes = index, *side = index + m_nodes, *first = side + m_sides;
  const long *second = first + m_sides, *slack = second + m_sides;
  const double needs[2] = {need0, need1};
  long i, s, j;
  if (m_sides < 1 || m_sides > 2 || m < 2 || col0 < 0 || col0 + n_in > n || scale_col >= n)
    return -1;
  for (i = 0; i < m; ++i)
    if (slack[i] < 0 || slack[i] >= n) return -1;
  for (s = 0; s < m_sides; ++s)
    if (side[s] < 0 || side[s] > 1) return -1;
  for (i = 0; i < n_in; ++i) x[col0 + i] = nominal[i];
  if (scale_col >= 0) x[scale_col] = scale;
  for (i = 0; i < m_nodes; ++i)
    for (s = 0; s < m_sides; ++s) {
      const double* p = A + (4 * nodes[i] + first[s]) * n;
      const double* q = A + (4 * nodes[i] + second[s]) * n;
      double* g = G + (i * m_sides + s) * n;
      if (nodes[i] < 0 || first[s] < 0 || second[s] < 0
          || 4 * nodes[i] + (first[s] > second[s] ? first[s] : second[s]) >= n_a)
        return -1;
      for (j = 0; j + 8 <= n; j += 8) *(v8*)(g + j) = *(const v8*)(p + j) + *(const v8*)(q + j);
      for (; j < n; ++j) g[j] = p[j] + q[j];
    }
  ((gemv_fn)gemv)(102, 112, n, m, 1.0, G, n, x, 1, 0.0, h, 1);
  for (i = 0; i < m_nodes; ++i)
    for (s = 0; s < m_sides; ++s) {
      const long r = i * m_sides + s, k = 4 * nodes[i];
      const double b_s = b[k + first[s]] + b[k + second[s]], need = needs[side[s]];
      double y = h[r] + b_s;
      y = need - y;
      y = np_max(y, 0.0);
      y = y * decay[r];
      y = need - y;
      y = b_s - y;
      h[r] = y / fs;
    }
  {
    const v8 d = {neg_fs, neg_fs, neg_fs, neg_fs, neg_fs, neg_fs, neg_fs, neg_fs};
    for (i = 0; i + 8 <= m * n; i += 8) *(v8*)(G + i) = *(v8*)(G + i) / d;
    for (; i < m * n; ++i) G[i] = G[i] / neg_fs;
  }
  for (i = 0; i < m; ++i) G[i * n + slack[i]] = -1.0;
  return 0;
}
"""


class CompiledSideReserve:
    """``side_reserve_rows`` on kept buffers, for one structure of the rows.

    Args:
        lib: `side_reserve_library`.
        gemv: The address of numpy's ``cblas_dgemv``.
        nodes: The nodes after now (m_nodes,).
        sides: The sides with rows (m_sides,), 0 left, 1 right (`SIDE_PAIRS`' order).
        slack_columns: Each row's slack column (m,), node-major.
        decay: ``exp(-t_k / T)`` per row (m,).
        n: Columns of G.
        n_forces: Rows of the forces map (4 per node).
        inputs: The layout's input columns (a slice of step 1 of the n).
        scale: The scale's column, or None.

    Not shared between threads (each constraint makes its own).
    """

    def __init__(self, lib, gemv: int, nodes, sides, slack_columns, decay, n: int,
                 n_forces: int, inputs: slice, scale: int | None):
        nodes, sides = np.asarray(nodes, int), np.asarray(sides, int)
        pairs = SIDE_PAIRS[sides]
        self.m = nodes.size * sides.size
        self.n, self.n_forces = n, n_forces
        start, stop, _ = inputs.indices(n)
        self.n_inputs = stop - start
        self._dims = np.array([nodes.size, pairs.shape[0], n, n_forces, start,
                               self.n_inputs, -1 if scale is None else scale], np.int_)
        self._index = np.concatenate([nodes, sides, pairs[:, 0], pairs[:, 1],
                                      np.asarray(slack_columns, int)]).astype(np.int_)
        self._decay = np.array(decay, float)
        self._x = np.zeros(n)  # the nominal plan: its slacks stay zero
        self.shape = (self.m, n)
        self._call = bind(lib.side_reserve_rows, self._dims, self._index, self._decay, gemv,
                          self._x)

    def rows(self, A: np.ndarray, b: np.ndarray, nominal_inputs, need_left: float,
             need_right: float, force_scale: float, speed_scale: float) -> tuple | None:
        """``(G (m, n), h (m,))``, fresh; None: the arrays are not float64 C-contiguous.

        ``A`` (n_forces, n), ``b`` (n_forces,): the forces map; ``nominal_inputs``: the
        inputs' ``n_inputs`` entries; ``need_left``, ``need_right``: ``f_min,a + f_min,b +
        r_j`` of the sides.

        Raises:
            ValueError: Other shapes than kept (the structure's), or nodes past ``A``.
        """
        pointers = (plain_address(A), plain_address(b), plain_address(nominal_inputs))
        if None in pointers:
            return None
        if (A.shape != (self.n_forces, self.n) or b.shape != (self.n_forces,)
                or nominal_inputs.size != self.n_inputs):
            raise ValueError(f"side rows: need A ({self.n_forces}, {self.n}), b "
                             f"({self.n_forces},) and {self.n_inputs} inputs, got {A.shape}, "
                             f"{b.shape} and {nominal_inputs.size}")
        G, h = np.empty(self.shape), np.empty(self.m)
        if self._call(*pointers, need_left, need_right, force_scale, -force_scale, speed_scale,
                      address(G), address(h)) != 0:
            raise ValueError(f"side rows: inconsistent structure {self._dims.tolist()}")
        return G, h


@functools.cache
def side_reserve_library():
    """`SIDE_RESERVE_C` compiled and loaded (once per process); None without a compiler."""
    return load_shared(SIDE_RESERVE_C, "side_reserve", {
        "side_reserve_rows": ([ctypes.c_void_p] * 8 + [ctypes.c_double] * 5
                              + [ctypes.c_void_p] * 2, ctypes.c_int)}, "numpy")


def compiled_side_reserve(nodes, sides, slack_columns, decay, n: int, n_forces: int,
                          inputs, scale) -> CompiledSideReserve | None:
    """A new `CompiledSideReserve`, or None.

    None without a C compiler or numpy's BLAS, for fewer than two rows (numpy's product is
    then a dot) or inputs that are not one slice of columns.
    """
    lib = side_reserve_library()
    blas = numpy_blas()
    if (lib is None or blas is None or len(nodes) * len(sides) < 2
            or not isinstance(inputs, slice) or inputs.step not in (None, 1)):
        return None
    return CompiledSideReserve(lib, blas[0], nodes, sides, slack_columns, decay, n,
                               n_forces, inputs, scale)
