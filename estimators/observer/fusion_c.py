"""The link accelerometers' least-squares fit (`link_fusion`) in C: one call a tick.

`link_fusion.LinkFusion.accelerations` spends ~20 us a tick on a dozen numpy calls about a
6 x 4 system (the residual, the weighted normal equations, a 4 x 4 inverse and its diagonal).
`FUSION_C` is the same fit, compiled once with the system compiler (`models.cbuild`, no
contraction into fused multiply-adds), reading the points kernel's output row in place
(`estimators.efforts_kernel.EffortKernels.points_row`). The products sum left to right and
the inverse is Gauss-Jordan elimination with partial pivoting, where numpy's BLAS may fuse
multiply-adds and LAPACK factors LU: the results agree to round-off
(`tests/test_observer_fusion_c.py`). The readings' tick means before it (``link_mean``) are
numpy's sums, the same bits. Without a compiler the numpy code runs.
"""

from __future__ import annotations

import ctypes

from models.cbuild import load_shared

__all__ = ["FUSION_C", "compiled_fusion"]

FUSION_C = r"""
#include <math.h>

/* The readings' tick means: mean[i] = (x[0][i] + ... + x[n-1][i]) / n over the n rows of x
   (n x m, row-major), the rows summed in order as numpy's reduction over its first axis.
   Returns 1 when a mean is not finite. */
int link_mean(const double* x, double* mean, long m, long n) {
  long i, r;
  int bad = 0;
  for (i = 0; i < m; ++i) {
    double s = x[i];
    for (r = 1; r < n; ++r) s = s + x[r * m + i];
    mean[i] = s / (double)n;
    if (!isfinite(mean[i])) bad = 1;
  }
  return bad;
}

/* LinkFusion.accelerations after its checks. mean (m): the readings' tick means; w (m):
   their weights; prior (4): the prior's information (diagonal) of the axes 2..5; io (13):
   in, the encoders' nine accelerations u_e; out, the fitted ones in io[0..8] and the fit's
   std of the four axes in io[9..12]; ab: the points kernel's row, A (m x 9, row-major)
   then b (m). Returns 0, or 1 when the fit is not finite (io unchanged). */
int link_fuse(long m, const double* mean, const double* w, const double* prior, double* io,
              const double* ab) {
  const double* b = ab + 9 * m;
  double info[4][8], g[4], du[4], res, s;
  long i, j, k, r, piv;
  for (j = 0; j < 4; ++j) {
    g[j] = 0.0;
    for (k = 0; k < 8; ++k) info[j][k] = 0.0;
  }
  for (i = 0; i < m; ++i) {
    const double* ai = ab + 9 * i;
    double dot = 0.0, wa[4];
    for (k = 0; k < 9; ++k) dot = dot + ai[k] * io[k];
    res = mean[i] - dot - b[i];
    for (k = 0; k < 4; ++k) wa[k] = w[i] * ai[2 + k];
    for (j = 0; j < 4; ++j) {
      g[j] = g[j] + ai[2 + j] * (w[i] * res);
      for (k = 0; k < 4; ++k) info[j][k] = info[j][k] + ai[2 + j] * wa[k];
    }
  }
  for (j = 0; j < 4; ++j) {
    info[j][j] = info[j][j] + prior[j];
    info[j][4 + j] = 1.0;
  }
  /* Gauss-Jordan on [info | I]: its right half becomes the covariance. */
  for (j = 0; j < 4; ++j) {
    piv = j;
    for (r = j + 1; r < 4; ++r)
      if (fabs(info[r][j]) > fabs(info[piv][j])) piv = r;
    if (piv != j)
      for (k = 0; k < 8; ++k) { s = info[j][k]; info[j][k] = info[piv][k]; info[piv][k] = s; }
    s = info[j][j];
    if (!(s != 0.0)) return 1;
    for (k = 0; k < 8; ++k) info[j][k] = info[j][k] / s;
    for (r = 0; r < 4; ++r) {
      if (r == j) continue;
      s = info[r][j];
      for (k = 0; k < 8; ++k) info[r][k] = info[r][k] - s * info[j][k];
    }
  }
  for (j = 0; j < 4; ++j) {
    du[j] = 0.0;
    for (k = 0; k < 4; ++k) du[j] = du[j] + info[j][4 + k] * g[k];
    if (!isfinite(du[j])) return 1;
  }
  for (j = 0; j < 4; ++j) {
    io[2 + j] = io[2 + j] + du[j];
    io[9 + j] = sqrt(info[j][4 + j]);
  }
  return 0;
}
"""


def compiled_fusion():
    """The loaded `FUSION_C` (``link_fuse``, ``link_mean``), or None without a compiler."""
    return load_shared(FUSION_C, "observer_fusion", {
        "link_fuse": ([ctypes.c_long] + [ctypes.c_void_p] * 5, ctypes.c_int),
        "link_mean": ([ctypes.c_void_p] * 2 + [ctypes.c_long] * 2, ctypes.c_int)},
        "numpy")
