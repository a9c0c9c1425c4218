"""Minimum-norm least squares on the wheels in contact.

The tipping case of Sec. III-B: with fewer than three contacts the forces are finite but
not unique. Their sensitivities to the configuration and the velocities have no compiled
kernel: `central_differences` perturbs the kernel's packed input row and evaluates every
perturbed row in one batch call.
"""

from __future__ import annotations

import numpy as np

__all__ = ["central_differences", "least_squares", "masked_pinv"]


def masked_pinv(a: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Pseudo-inverse of ``a`` (3, 4) on the columns in ``mask``, zero rows elsewhere, (4, 3)."""
    cols = np.flatnonzero(np.asarray(mask) > 0)
    pinv = np.zeros((4, 3))
    if cols.size:
        pinv[cols] = np.linalg.pinv(a[:, cols])
    return pinv


def least_squares(a: np.ndarray, b: np.ndarray, mask) -> tuple[np.ndarray, float]:
    """Minimum-norm least squares on the wheels in contact; (x, 2-norm condition).

    The condition is the ratio of the extreme singular values the least-squares solve
    computes anyway (no second decomposition); only reported, never used in a decision.
    """
    cols = np.flatnonzero(np.asarray(mask) > 0)
    x = np.zeros(4)
    if cols.size == 0:
        return x, float("inf")
    sub = a[:, cols]
    x[cols], _, _, sv = np.linalg.lstsq(sub, b, rcond=None)
    with np.errstate(divide="ignore", invalid="ignore"):
        cond = float(sv[0] / sv[-1])
    if cond != cond and np.isfinite(sub).all():  # 0 / 0: singular, as `numpy.linalg.cond`
        cond = float("inf")
    return x, cond


def _min_norm(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Least-squares ``x`` of each ``a x = b``, a (n, 3, k) with k <= 2 columns, b (n, 3).

    The normal equations (a k x k solve per row, ~10x faster than a batched SVD) when every
    ``a`` has full column rank by a wide margin (the columns of a tipping system are a
    wheel's unit force and its moment arms, about 1 m); otherwise the pseudo-inverse.
    """
    with np.errstate(invalid="ignore", over="ignore"):  # the caller checks finiteness
        gram = np.swapaxes(a, 1, 2) @ a
        rhs = (np.swapaxes(a, 1, 2) @ b[:, :, None])
        scale = np.trace(gram, axis1=1, axis2=2)
        if np.all(np.linalg.det(gram) > 1e-8 * scale ** a.shape[2]):
            return np.linalg.solve(gram, rhs)[:, :, 0]
        try:
            return (np.linalg.pinv(a) @ b[:, :, None])[:, :, 0]
        except np.linalg.LinAlgError:  # non-finite entries: NaN out, the caller raises
            return np.full(b.shape[:1] + a.shape[2:], np.nan)


def central_differences(kernel, layout, row: np.ndarray, mask, lower: np.ndarray,
                        upper: np.ndarray, step: float, zeroed: np.ndarray | None
                        ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Minimum-norm forces and their central differences in q and qd, one kernel batch.

    Args:
        kernel: The compiled ``nf_estimate`` kernel (its ``batch(inp, out)``).
        layout: The kernels' row layout (`estimators._symbolic.LAYOUT`): where q and qd sit
            in the input row, the system ``a`` (3 x 4) and ``b`` (3) in the output row.
        row: The packed input row of the state.
        mask: The wheels in contact (the columns solved for), held fixed.
        lower: The coordinates' lower ends: a step in q stays inside the range (one-sided
            at an end, zero when the range has no room).
        upper: Their upper ends.
        step: The difference step [m, rad; m/s, rad/s].
        zeroed: Input positions the method zeroes (the quasi-static method's), or None.

    Returns:
        ``(f_z (4,), df_z/dq (4, n), df_z/dqd (4, n))``, n the coordinates in q.
    """
    q_slice, qd_slice = layout.q, layout.qd
    q0 = row[q_slice]
    n = q0.size
    lo = np.full(2 * n, -step)
    hi = np.full(2 * n, step)
    lo[:n] = np.maximum(lo[:n], lower - q0)
    hi[:n] = np.minimum(hi[:n], upper - q0)
    cols = np.concatenate([np.arange(q_slice.start, q_slice.stop),
                           np.arange(qd_slice.start, qd_slice.stop)])
    rows = np.repeat(row[None, :], 1 + 4 * n, axis=0)
    k = np.arange(2 * n)
    rows[1 + 2 * k, cols] += lo
    rows[2 + 2 * k, cols] += hi
    if zeroed is not None:
        rows[:, zeroed] = 0.0
    out = np.empty((rows.shape[0], kernel.n_out))
    kernel.batch(rows, out)
    contact = np.flatnonzero(np.asarray(mask) > 0)
    x = np.zeros((rows.shape[0], 4))
    if contact.size:
        a = out[:, layout.out_a].reshape(-1, 3, 4)[:, :, contact]
        x[:, contact] = _min_norm(a, out[:, layout.out_b])
    span = hi - lo
    with np.errstate(invalid="ignore", divide="ignore"):
        d = np.where(span > 0, (x[2::2] - x[1::2]).T / np.where(span > 0, span, 1.0), 0.0)
    return x[0], d[:, :n], d[:, n:]
