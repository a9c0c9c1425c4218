"""`np.linalg.inv` and `np.linalg.solve` of small regular matrices, without their wrappers.

The observer inverts or solves a few matrices of size 2 to 4 a tick, each positive definite
by construction (a prior's information added to a Gram matrix; a principal block of the
reflected mass matrix). numpy's Python wrappers spend ~2.5 us a call on dispatch, type
checks and an error-state context; the gufuncs they end in (`numpy.linalg._umath_linalg`)
run the same LAPACK routine on the same data, so the results are the same bit for bit. A
singular matrix gives NaN here (with numpy's RuntimeWarning) instead of `LinAlgError`: the
callers test the result's finiteness. Without the private module: numpy's functions.
"""

from __future__ import annotations

import numpy as np

__all__ = ["inv", "solve"]

try:
    from numpy.linalg import _umath_linalg
except ImportError:  # pragma: no cover - a numpy that moved it
    _umath_linalg = None


def inv(a: np.ndarray) -> np.ndarray:
    """``np.linalg.inv`` of a float (n, n) matrix (NaN where it is singular)."""
    if _umath_linalg is None:  # pragma: no cover
        try:
            return np.linalg.inv(a)
        except np.linalg.LinAlgError:
            return np.full(a.shape, np.nan)
    return _umath_linalg.inv(a, signature="d->d")


def solve(a: np.ndarray, b) -> np.ndarray:
    """``np.linalg.solve`` of a float (n, n) matrix and a vector (n,) (NaN if singular)."""
    if _umath_linalg is None:  # pragma: no cover
        try:
            return np.linalg.solve(a, b)
        except np.linalg.LinAlgError:
            return np.full(len(b), np.nan)
    return _umath_linalg.solve1(a, b, signature="dd->d")
