"""`CondensedPrediction.trajectory`'s products in one C call, through numpy's own BLAS.

The MPC predicts node positions and velocities twice a tick (the brake trajectory of its
context, the plan after the solve): ``qf + Lq @ u`` and ``vf + Lv @ u`` with ``Lq, Lv``
(N, N) and ``u`` (N, 9), two matmuls and two sums (~5 us a call in numpy). numpy's matmul
of two C-ordered matrices ends in ``cblas_dgemm(RowMajor, NoTrans, NoTrans, N, 9, N, 1.0,
L, N, u, 9, 0.0, out, 9)`` of its bundled OpenBLAS; `TRAJECTORY_C` calls that routine (found
as `estimators.observer.tail_c.numpy_blas` finds its siblings) with those arguments, then
adds the free response element by element: the same routine on the same data, the same
bits (`tests/test_trajectory_c.py`); a NaN result is left to numpy (which operand's NaN a
sum keeps is up to each compiler). Inputs it cannot take as numpy would (not C-ordered
float64 of the shapes) and builds of numpy on another BLAS take numpy's path.
"""

from __future__ import annotations

import ctypes
import glob
import os

import numpy as np

from estimators.observer.tail_c import numpy_blas
from models.cbuild import address, bind, load_shared

__all__ = ["TRAJECTORY_C", "TrajectoryProducts", "numpy_dgemm"]

TRAJECTORY_C = r"""
#include <math.h>

typedef void (*gemm_fn)(int, int, int, long long, long long, long long, double,
                        const double*, long long, const double*, long long, double, double*,
                        long long);

/* q = qf + Lq @ u, v = vf + Lv @ u: (n, m) each, L (n, n), u (n, m), C order; tmp (n, m)
   scratch. Returns 1 when a sum is NaN (which operand's NaN a sum of two keeps is the
   compiler's choice here and numpy's there: the caller takes numpy's), else 0. */
int trajectory(void* gemm, const double* Lq, const double* Lv, long n, long m,
               const double* qf, const double* vf, const double* u, double* tmp,
               double* q, double* v) {
  long i, k = n * m;
  int nan = 0;
  ((gemm_fn)gemm)(101, 111, 111, n, m, n, 1.0, Lq, n, u, m, 0.0, tmp, m);
  for (i = 0; i < k; ++i) {
    q[i] = qf[i] + tmp[i];
    nan |= isnan(q[i]);
  }
  ((gemm_fn)gemm)(101, 111, 111, n, m, n, 1.0, Lv, n, u, m, 0.0, tmp, m);
  for (i = 0; i < k; ++i) {
    v[i] = vf[i] + tmp[i];
    nan |= isnan(v[i]);
  }
  return nan;
}
"""

_P, _L = ctypes.c_void_p, ctypes.c_long


def _library():
    return load_shared(TRAJECTORY_C, "condensed_trajectory", {
        "trajectory": ([_P] * 3 + [_L] * 2 + [_P] * 6, ctypes.c_int)}, "numpy's matmul")


def numpy_dgemm() -> int | None:
    """The address of the ``cblas_dgemm`` numpy's matmul calls, or None.

    None where `numpy_blas` finds numpy built on another BLAS than its bundled
    ``scipy-openblas`` (64-bit integers, symbols prefixed ``scipy_``).
    """
    if numpy_blas() is None:
        return None
    root = os.path.join(os.path.dirname(os.path.dirname(np.__file__)), "numpy.libs")
    found = sorted(glob.glob(os.path.join(root, "libscipy_openblas64_*.so*")))
    try:
        lib = ctypes.CDLL(found[0])  # numpy's: loaded already, the same handle
        return ctypes.cast(lib.scipy_cblas_dgemm64_, ctypes.c_void_p).value
    except (OSError, AttributeError, IndexError):
        return None


class TrajectoryProducts:
    """``(qf + Lq @ u, vf + Lv @ u)`` for one prediction's factors (N, N) and n axes.

    Args:
        Lq, Lv: The prediction's factors (copied, C order).
        n_axes: Columns of ``u``.
    """

    def __init__(self, lib, gemm: int, Lq: np.ndarray, Lv: np.ndarray, n_axes: int):
        self.Lq = np.array(Lq, float, order="C")
        self.Lv = np.array(Lv, float, order="C")
        self.shape = (self.Lq.shape[0], int(n_axes))
        self._tmp = np.zeros(self.shape)
        self._call = bind(lib.trajectory, gemm, self.Lq, self.Lv, *self.shape)
        self._tmp_at = address(self._tmp)

    @classmethod
    def make(cls, Lq: np.ndarray, Lv: np.ndarray, n_axes: int) -> TrajectoryProducts | None:
        """The products, or None without a compiler or numpy's BLAS."""
        gemm = numpy_dgemm()
        lib = None if gemm is None else _library()
        return None if lib is None else cls(lib, gemm, Lq, Lv, n_axes)

    def run(self, qf, vf, u) -> tuple[np.ndarray, np.ndarray] | None:
        """(positions, velocities), new arrays (N, n); None: numpy must (see the module).

        None as well where a result is NaN (numpy's sum picks which NaN it keeps).
        """
        shape = self.shape
        for a in (qf, vf, u):
            if not (type(a) is np.ndarray and a.shape == shape and a.dtype == np.float64
                    and a.flags.c_contiguous):
                return None
        q, v = np.empty(shape), np.empty(shape)
        if self._call(address(qf), address(vf), address(u), self._tmp_at, address(q),
                      address(v)):
            return None
        return q, v
