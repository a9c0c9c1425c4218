"""The BLAS and LAPACK routines numpy itself calls, for C code that must keep numpy's bits.

numpy's wheels carry their own OpenBLAS (``scipy-openblas``, 64-bit integers, symbols
prefixed ``scipy_``); its ``ndarray.dot`` and ``@`` of a matrix and a vector end in
``cblas_dgemv`` (a row and a vector: ``cblas_ddot``), ``linalg.solve`` in ``dgesv``. C code
that calls the same routines with the arguments numpy passes gets the same bits (the
observer's tail, `estimators.observer.tail_c`; the MPC's load-split chain,
`wbc.force_models.chain_c`; DAQP's least-distance step, `wbc.solvers.ldp_step`; the MPC's
brake trajectory, `wbc.controllers.servo_state_c`, through ``cblas_dgemm``).
"""

from __future__ import annotations

import ctypes
import functools
import glob
import os

import numpy as np

__all__ = ["numpy_blas", "numpy_gemm"]

_BLAS_SYMBOLS = ("scipy_cblas_dgemv64_", "scipy_cblas_ddot64_", "scipy_dgesv_64_")


def numpy_blas() -> tuple[int, int, int] | None:
    """The addresses of ``cblas_dgemv``, ``cblas_ddot`` and ``dgesv`` that numpy calls.

    numpy's wheels carry their own OpenBLAS (``scipy-openblas``, 64-bit integers, symbols
    prefixed ``scipy_``); its ``ndarray.dot`` and ``@`` of a matrix and a vector end in
    ``cblas_dgemv`` (a row and a vector: ``cblas_ddot``), ``linalg.solve`` in ``dgesv``. The
    same routines on the same data give the same bits. None where numpy was built
    otherwise (the callers then keep numpy's own calls).
    """
    lib = _numpy_openblas()
    try:
        return None if lib is None else tuple(_symbol(lib, name) for name in _BLAS_SYMBOLS)
    except AttributeError:
        return None


def numpy_gemm() -> int | None:
    """The address of the ``cblas_dgemm`` numpy's ``@`` of two matrices calls, or None.

    numpy's matmul of two C-ordered float64 matrices passes ``(101, 111, 111, m, p, n, 1.0,
    A, n, B, p, 0.0, C, p)`` (row-major, no transposes); `wbc.controllers.servo_state_c`
    calls it so for the MPC's brake trajectory.
    """
    lib = _numpy_openblas()
    try:
        return None if lib is None else _symbol(lib, "scipy_cblas_dgemm64_")
    except AttributeError:
        return None


@functools.cache
def _numpy_openblas() -> ctypes.CDLL | None:
    """The OpenBLAS numpy carries (loaded already: the same handle), or None (another build)."""
    try:
        deps = np.show_config(mode="dicts")["Build Dependencies"]
        blas, lapack = deps["blas"], deps["lapack"]
        ok = (blas["name"] == lapack["name"] == "scipy-openblas"
              and "USE64BITINT" in blas.get("openblas configuration", ""))
    except (KeyError, TypeError, AttributeError):
        return None
    root = os.path.join(os.path.dirname(os.path.dirname(np.__file__)), "numpy.libs")
    found = sorted(glob.glob(os.path.join(root, "libscipy_openblas64_*.so*")))
    if not ok or len(found) != 1:
        return None
    try:
        return ctypes.CDLL(found[0])
    except OSError:
        return None


def _symbol(lib: ctypes.CDLL, name: str) -> int:
    """The address of ``name`` in ``lib`` (AttributeError: not there)."""
    return ctypes.cast(getattr(lib, name), ctypes.c_void_p).value
