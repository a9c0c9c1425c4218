"""Minimum-norm least squares on the wheels in contact.

The tipping case of Sec. III-B: with fewer than three contacts the forces are finite but
not unique.
"""

from __future__ import annotations

import numpy as np

__all__ = ["least_squares", "masked_pinv"]


def masked_pinv(a: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Pseudo-inverse of ``a`` (3, 4) on the columns in ``mask``, zero rows elsewhere, (4, 3)."""
    cols = np.flatnonzero(np.asarray(mask) > 0)
    pinv = np.zeros((4, 3))
    if cols.size:
        pinv[cols] = np.linalg.pinv(a[:, cols])
    return pinv


def least_squares(a: np.ndarray, b: np.ndarray, mask) -> tuple[np.ndarray, float]:
    """Minimum-norm least squares on the wheels in contact; (x, condition)."""
    cols = np.flatnonzero(np.asarray(mask) > 0)
    x = np.zeros(4)
    if cols.size == 0:
        return x, float("inf")
    sub = a[:, cols]
    x[cols] = np.linalg.lstsq(sub, b, rcond=None)[0]
    return x, float(np.linalg.cond(sub))
