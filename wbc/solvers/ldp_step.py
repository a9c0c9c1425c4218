"""`LeastDistanceWorkspace.step`: `wbc.solvers.DaqpBackend`'s numpy around a solve, in C.

`STEP_C` is part of `wbc.solvers.daqp_c`'s library (it calls its ``solve_rows``): the
least-distance form's shifts, bounds, warm start, cold retry, iterate and multipliers in
the call that solves (`wbc.solvers.daqp_backend`'s docstring), its products through numpy's
own BLAS routines with the arguments numpy's matmul passes (a matrix and a vector:
``cblas_dgemv``, transposed, row-major for a transposed view, else column-major; one row:
``cblas_ddot``), so the bits are numpy's.
"""

from __future__ import annotations

import numpy as np

from models.cbuild import address

__all__ = ["STEP_C", "step"]

STEP_C = r"""
/* numpy's own BLAS routines (`estimators.observer.tail_c.numpy_blas`), called as numpy's
   matmul calls them: a matrix and a vector in cblas_dgemv (transposed, the matrix's
   rows as columns: 101/102 = row/column major, 112 = transposed), one row in cblas_ddot. */
typedef void (*gemv_fn)(int, int, long long, long long, double, const double*, long long,
                        const double*, long long, double, double*, long long);
typedef double (*ddot_fn)(long long, const double*, long long, const double*, long long);

static double clip20(double x) { /* numpy's clip to [-1e20, 1e20]: NaN stays */
  return x != x ? x : (x < -1e20 ? -1e20 : (x > 1e20 ? 1e20 : x));
}

static double now(void) { /* time.perf_counter's clock [s] */
  struct timespec t;
  clock_gettime(CLOCK_MONOTONIC, &t);
  return t.tv_sec + 1e-9 * t.tv_nsec;
}

static int all_finite(const double* x, long n) {
  for (long i = 0; i < n; ++i)
    if (!isfinite(x[i])) return 0;
  return 1;
}

/* DaqpBackend.solve's least-distance tail in one call (`LeastDistanceWorkspace.step`):
   v = inv_t' f, shift = inv_t v; DAQP's bounds [lower, upper]: the box (ub, lb; NULL:
   infinite) plus shift, h[kept[t]] (and -inf) for the m_k kept rows, b for the m_eq
   equalities, the rows' plus A[n:] v, all clipped to +-1e20; the warm start gathered from
   lam_prev (n + m_in + m_eq, NULL: cold) and a cold retry of a warm solve that fails; then
   x = inv_t u - shift and, if the exit flag is positive and x finite, lam (n + m_in +
   m_eq, zeros) gets DAQP's multipliers at their rows. A: DAQP's rows, (n + m_k + m_eq)
   x n, C-contiguous. v, shift (n), upper, lower, dual, lam_daqp (n + m_k + m_eq), u (n):
   the caller's scratch. same (NULL: none): 1 for a row of A with the bits of the same
   row of the last solve's A (`normalize` keeps what it formed from it). out = {exit
   flag, iterations, path (ldp_solve's), warm, solved: x and lam written}, time = the
   seconds inside ldp_solve. Returns 0; -1 out of memory. */
int ldp_step(void* p, void* gemv_p, void* ddot_p, long n, long m_in, long m_k, long m_eq,
             const double* A, const double* inv_t, const double* f, const double* ub,
             const double* lb, const double* h, const int64_t* kept, const double* b,
             const double* lam_prev, double* v, double* shift, double* upper,
             double* lower, double* dual, double* u, double* lam_daqp, double* x,
             double* lam, int* out, double* time, const unsigned char* same) {
  const gemv_fn gemv = (gemv_fn)gemv_p;
  const long m = n + m_k + m_eq, rows = m_k + m_eq;
  gemv(101, 112, n, n, 1.0, inv_t, n, f, 1, 0.0, v, 1);      /* inv_t.T @ f */
  gemv(102, 112, n, n, 1.0, inv_t, n, v, 1, 0.0, shift, 1);  /* inv_t @ v */
  for (long i = 0; i < n; ++i) {
    upper[i] = (ub ? ub[i] : INFINITY) + shift[i];
    lower[i] = (lb ? lb[i] : -INFINITY) + shift[i];
  }
  for (long t = 0; t < m_k; ++t) upper[n + t] = h[kept[t]], lower[n + t] = -INFINITY;
  for (long e = 0; e < m_eq; ++e) upper[n + m_k + e] = lower[n + m_k + e] = b[e];
  if (rows == 1) { /* a_all[n:] @ v: one row, numpy's dot */
    const double s = ((ddot_fn)ddot_p)(n, A + n * n, 1, v, 1);
    upper[n] += s, lower[n] += s;
  } else if (rows > 1) {
    gemv(102, 112, n, rows, 1.0, A + n * n, n, v, 1, 0.0, dual, 1); /* dual: scratch */
    for (long i = 0; i < rows; ++i) upper[n + i] += dual[i], lower[n + i] += dual[i];
  }
  for (long i = 0; i < m; ++i) upper[i] = clip20(upper[i]), lower[i] = clip20(lower[i]);
  int warm = lam_prev != NULL;
  if (warm) {
    memcpy(dual, lam_prev, n * sizeof(double));
    for (long t = 0; t < m_k; ++t) dual[n + t] = lam_prev[n + kept[t]];
    for (long e = 0; e < m_eq; ++e) dual[n + m_k + e] = lam_prev[n + m_in + e];
  }
  double t0 = now();
  if (solve_rows(p, n, m, n + m_k, A, upper, lower, warm ? dual : NULL, u, lam_daqp, out,
                 same))
    return -1;
  int iterations = out[1];
  if (warm && !(out[0] > 0 && all_finite(u, n))) {
    warm = 0;
    if (solve_rows(p, n, m, n + m_k, A, upper, lower, NULL, u, lam_daqp, out, same))
      return -1;
    iterations += out[1];
  }
  *time = now() - t0;
  out[1] = iterations;
  out[3] = warm;
  out[4] = 0;
  if (out[0] <= 0) return 0;
  gemv(102, 112, n, n, 1.0, inv_t, n, u, 1, 0.0, x, 1);  /* inv_t @ u */
  for (long i = 0; i < n; ++i) x[i] -= shift[i];
  if (!all_finite(x, n)) return 0;
  out[4] = 1;
  memset(lam, 0, (n + m_in + m_eq) * sizeof(double));
  memcpy(lam, lam_daqp, n * sizeof(double));
  for (long t = 0; t < m_k; ++t) lam[n + kept[t]] = lam_daqp[n + t];
  for (long e = 0; e < m_eq; ++e) lam[n + m_in + e] = lam_daqp[n + m_k + e];
  return 0;
}
"""


def step(self, blas: tuple[int, int], a: np.ndarray, inv_t: np.ndarray, f: np.ndarray,
         ub: np.ndarray | None, lb: np.ndarray | None, h: np.ndarray | None,
         kept: np.ndarray, b: np.ndarray | None, m_in: int, lam_prev: np.ndarray | None,
         same: np.ndarray | None = None
         ) -> tuple[np.ndarray, np.ndarray, int, int, bool, float, bool]:
    """`wbc.solvers.DaqpBackend.solve`'s numpy around `solve` in one C call, its bits.

    A method of `wbc.solvers.daqp_c.LeastDistanceWorkspace` (``self``), on its workspace.

    ``v = inv_t.T @ f``, ``shift = inv_t @ v``; the bounds ``[lower, upper]`` (the box
    plus ``shift``, ``h[kept]`` and ``b``, the rows' plus ``a[n:] @ v``, clipped to
    +-1e20); the warm start from ``lam_prev`` (``[box; G rows; A rows]``, None: cold),
    retried cold if that fails; ``x = inv_t @ u - shift``; the multipliers scattered to
    the rows of ``G`` and ``A``. The products through numpy's own ``cblas_dgemv`` /
    ``cblas_ddot`` (``blas``: their addresses, `estimators.observer.tail_c.numpy_blas`)
    as numpy's matmul calls them.

    Args:
        self: The workspace.
        blas: ``(cblas_dgemv, cblas_ddot)`` numpy calls.
        a: DAQP's rows ``[inv_t; G[kept] inv_t; A inv_t]``, float64, C-contiguous.
        inv_t: ``L^-T``, float64 (n, n), C-contiguous.
        f: The linear term, float64 (n,), contiguous.
        ub: The upper bounds on ``x``, float64 (n,), contiguous; None: infinite.
        lb: The lower bounds on ``x``, likewise.
        h: The right-hand side of ``G``, float64 (m_in,), contiguous; None if no rows.
        b: The right-hand side of ``A``, float64 (m_eq,), contiguous; None if no rows.
        kept: The kept rows of ``G``, int64, contiguous.
        m_in: The rows of ``G``.
        lam_prev: The last multipliers, float64 (n + m_in + m_eq,), contiguous.
        same: uint8, contiguous, at least as long as ``a``, or None: 1 marks a row of
            ``a`` with the bits of the same row of the rows this workspace solved last
            (the caller vouches); those DAQP normalised then are not normalised again.

    Returns:
        ``(x, lam, exit flag, iterations, warm, seconds in DAQP, solved)``: ``x`` (n,)
        and ``lam`` (n + m_in + m_eq,) new arrays, written when ``solved`` (a positive
        exit flag and a finite ``x``); ``warm``: the solve that counted started warm.

    Raises:
        MemoryError: No memory for the workspace.
    """
    m, n = a.shape
    scratch = self._scratch
    if scratch[0] != n or scratch[1] < m:
        cap = 2 * m  # v, shift (n each), upper, lower, dual, the multipliers (cap each), u
        buffer = np.empty(3 * n + 4 * cap)
        at = address(buffer)
        scratch = self._scratch = (n, cap, buffer, (
            at, at + 8 * n, *(at + 8 * (2 * n + k * cap) for k in range(3)),
            at + 8 * (2 * n + 4 * cap), at + 8 * (2 * n + 3 * cap)))  # C's order: u first
    x = np.empty(n)
    lam = np.empty(m_in + m - kept.size)
    if self._step(*blas, n, m_in, kept.size, m - n - kept.size, address(a), address(inv_t),
                  address(f), None if ub is None else address(ub),
                  None if lb is None else address(lb),
                  None if h is None else address(h), address(kept),
                  None if b is None else address(b),
                  None if lam_prev is None else address(lam_prev), *scratch[3],
                  address(x), address(lam), self._step_out_address,
                  self._time_address, None if same is None else address(same)) != 0:
        raise MemoryError("no memory for the DAQP workspace")
    flag, iterations, path, warm, solved = self._step_out.tolist()
    self.kept = path == 1
    return x, lam, flag, iterations, warm == 1, self._time.item(), solved == 1
