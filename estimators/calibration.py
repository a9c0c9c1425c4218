"""Calibration of the parameters D and beta of eq. (29) by eq. (30).

With four wheels in contact the three equilibrium rows (eqs. 25-28) leave one direction ``n``
(the null vector of ``A``) free: ``x = x_p + t n``. The fourth row ``r(D) x = beta`` fixes
``t = (beta - r(D) x_p) / (r(D) n)``, so for every sample the forces are a cheap closed form
of (D, beta); eq. (30),

    minimise_{D, beta}  1/2 sum_samples sum_k (f_zk(D, beta) - f_zk_gt)^2,

is then solved over all samples at once: a profile over a grid of D (beta has a closed form
for fixed D, the problem being linear in beta) followed by a local least-squares refinement
(``scipy``) or CasADi's Ipopt (``ipopt``). D is not bounded: the paper's optimum lies near
1.5 although eq. (29) introduces D in [0, 1].
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from estimators.errors import EstimatorInputError
from estimators.full_dynamics import D_BETA_COEFFICIENTS

__all__ = [
    "CalibrationResult",
    "SlidingCalibration",
    "calibrate_batch",
    "calibrate_d_beta",
    "calibrate_d_beta_sliding",
    "forces_d_beta",
    "null_space_form",
]

_GRID = np.linspace(-3.0, 4.0, 71)


@dataclass
class CalibrationResult:
    """Optimal (D, beta) of eq. (30) for one set of samples.

    Attributes:
        D: [-]. beta: [N].
        cost: Value of eq. (30) at the optimum [N^2].
        rmse: Root-mean-square force error over samples and wheels [N].
        n_samples: Samples used (four wheels in contact).
        solver: ``scipy`` or ``ipopt``.
        success: The local solver reported convergence.
    """

    D: float  # noqa: N815
    beta: float
    cost: float
    rmse: float
    n_samples: int
    solver: str
    success: bool


@dataclass
class SlidingCalibration:
    """(D, beta) fitted over sliding windows of a log (paper Fig. 9).

    Attributes:
        start, stop: Sample index range of each window, shape (W,).
        D, beta, cost, rmse: Per window, shape (W,) (NaN where a window had no sample).
        n_samples: Valid samples per window, shape (W,).
    """

    start: np.ndarray
    stop: np.ndarray
    D: np.ndarray  # noqa: N815
    beta: np.ndarray
    cost: np.ndarray
    rmse: np.ndarray
    n_samples: np.ndarray


def null_space_form(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Particular solution and null vector of the 3x4 systems, shapes (N, 4) each.

    Args:
        a: ``A`` of eq. (26), shape (N, 3, 4).
        b: ``b`` of eq. (28), shape (N, 3).

    Returns:
        ``(x_p, n)`` with ``A x_p = b`` (minimum norm) and ``A n = 0``.
    """
    a = np.asarray(a, float)
    b = np.asarray(b, float)
    n = np.empty(a.shape[:-2] + (4,))
    for j in range(4):
        cols = [i for i in range(4) if i != j]
        n[..., j] = (-1) ** j * np.linalg.det(a[..., cols])
    aat = a @ np.swapaxes(a, -1, -2)
    try:
        xp = np.einsum("nji,nj->ni", a, np.linalg.solve(aat, b[..., None])[..., 0])
    except np.linalg.LinAlgError as exc:
        raise EstimatorInputError("a system matrix A is rank deficient (a wheel out of "
                                  "contact?); calibrate on four-contact samples only") from exc
    return xp, n


def forces_d_beta(xp: np.ndarray, n: np.ndarray, d: float, beta: float) -> np.ndarray:
    """Normal forces of the 4x4 system closed by eq. (29), shape (N, 4), order FL RL FR RR."""
    a, c = D_BETA_COEFFICIENTS[:, 0], D_BETA_COEFFICIENTS[:, 1]
    r = a * d + c
    return xp + n * ((beta - xp @ r) / (n @ r))[:, None]


def _profile(xp, n, gt, d):
    """Best beta for a fixed D and the cost there."""
    a, c = D_BETA_COEFFICIENTS[:, 0], D_BETA_COEFFICIENTS[:, 1]
    r = a * d + c
    s = n @ r
    with np.errstate(divide="ignore", invalid="ignore"):
        q = n / s[:, None]
        p = xp - q * (xp @ r)[:, None] - gt
        beta = -np.sum(p * q) / np.sum(q * q)
        cost = 0.5 * np.sum((p + q * beta) ** 2)
    return (beta, cost) if np.isfinite(cost) else (0.0, np.inf)


def calibrate_d_beta(a: np.ndarray, b: np.ndarray, normal_forces_gt: np.ndarray,
                     x0: tuple[float, float] | None = None,
                     solver: str = "scipy") -> CalibrationResult:
    """Fit one (D, beta) pair to samples with all four wheels in contact, eq. (30).

    Args:
        a: System matrices ``A`` (eq. 26), shape (N, 3, 4).
        b: Right-hand sides ``b`` (eq. 28), shape (N, 3).
        normal_forces_gt: Ground-truth f_z [N], shape (N, 4), order FL, RL, FR, RR.
        x0: Initial (D, beta); default the best point of a profile over D in [-3, 4].
        solver: ``scipy`` or ``ipopt``.

    Raises:
        EstimatorInputError: Wrong shapes, no sample, or an unknown solver.
    """
    a = np.asarray(a, float)
    b = np.asarray(b, float)
    gt = np.asarray(normal_forces_gt, float)
    if a.ndim != 3 or a.shape[1:] != (3, 4) or b.shape != (a.shape[0], 3) \
            or gt.shape != (a.shape[0], 4):
        raise EstimatorInputError(f"expected A (N, 3, 4), b (N, 3), normal_forces_gt (N, 4); "
                                  f"got {a.shape}, {b.shape}, {gt.shape}")
    if a.shape[0] == 0:
        raise EstimatorInputError("no sample with four wheels in contact to calibrate on")
    if solver not in ("scipy", "ipopt"):
        raise EstimatorInputError(f"solver={solver!r} is not one of ('scipy', 'ipopt')")
    if not (np.isfinite(a).all() and np.isfinite(b).all() and np.isfinite(gt).all()):
        raise EstimatorInputError("calibration data has non-finite entries")
    xp, n = null_space_form(a, b)
    if x0 is None:
        prof = [_profile(xp, n, gt, d) for d in _GRID]
        k = int(np.argmin([c for _, c in prof]))
        x0 = (float(_GRID[k]), float(prof[k][0]))
    scale = max(1.0, float(np.abs(gt).mean()))
    if solver == "scipy":
        from scipy.optimize import least_squares

        def res(theta):
            return (forces_d_beta(xp, n, theta[0], theta[1]) - gt).ravel()

        sol = least_squares(res, np.array(x0, float), x_scale=np.array([1.0, scale]),
                            method="lm", xtol=1e-12, ftol=1e-12)
        d, beta, ok = float(sol.x[0]), float(sol.x[1]), bool(sol.success)
    else:
        d, beta, ok = _ipopt(xp, n, gt, x0, scale)
    err = forces_d_beta(xp, n, d, beta) - gt
    return CalibrationResult(d, beta, 0.5 * float(np.sum(err ** 2)),
                             float(np.sqrt(np.mean(err ** 2))), int(a.shape[0]), solver, ok)


def _ipopt(xp, n, gt, x0, scale):
    import casadi as ca

    d = ca.MX.sym("D")
    beta_s = ca.MX.sym("beta_scaled")  # beta / scale keeps the variables of one size
    a, c = D_BETA_COEFFICIENTS[:, 0], D_BETA_COEFFICIENTS[:, 1]
    s = ca.DM(n @ a) * d + ca.DM(n @ c)
    u = ca.DM(xp @ a) * d + ca.DM(xp @ c)
    t = (beta_s * scale - u) / s
    cost = 0
    for k in range(4):
        e = ca.DM(xp[:, k] - gt[:, k]) + ca.DM(n[:, k]) * t
        cost += 0.5 * ca.sumsqr(e)
    nlp = {"x": ca.vertcat(d, beta_s), "f": cost / (scale * scale)}
    opts = {"ipopt.print_level": 0, "print_time": False, "ipopt.tol": 1e-12,
            "ipopt.sb": "yes"}
    sol = ca.nlpsol("calibrate_d_beta", "ipopt", nlp, opts)(x0=[x0[0], x0[1] / scale])
    xs = np.asarray(sol["x"]).ravel()
    return float(xs[0]), float(xs[1] * scale), True


def calibrate_d_beta_sliding(a: np.ndarray, b: np.ndarray, normal_forces_gt: np.ndarray,
                             window: int, stride: int | None = None,
                             valid: np.ndarray | None = None,
                             solver: str = "scipy",
                             min_samples: int = 1) -> SlidingCalibration:
    """Fit (D, beta) on sliding windows of a log (paper Fig. 9).

    Args:
        a: System matrices of all N samples of the log, shape (N, 3, 4).
        b: Right-hand sides, shape (N, 3).
        normal_forces_gt: Ground-truth f_z [N], shape (N, 4).
        window: Window length [samples], >= 2.
        stride: Step between window starts [samples], default ``window // 2``.
        valid: Samples usable for the fit (four wheels in contact), shape (N,).
        solver: ``scipy`` or ``ipopt``.
        min_samples: Windows with fewer valid samples are not fitted (NaN): with one or two
            samples the pair (D, beta) is a whole line of optima and the fit returns an
            arbitrary, often huge, point of it.
    """
    a = np.asarray(a, float)
    n_total = a.shape[0]
    if not (isinstance(window, (int, np.integer)) and window >= 2):
        raise EstimatorInputError(f"window must be an integer >= 2, got {window!r}")
    stride = max(1, window // 2) if stride is None else int(stride)
    if stride < 1:
        raise EstimatorInputError(f"stride must be >= 1, got {stride}")
    valid = np.ones(n_total, bool) if valid is None else np.asarray(valid, bool)
    starts = np.arange(0, max(n_total - window, 0) + 1, stride)
    out = {k: np.full(len(starts), np.nan) for k in ("D", "beta", "cost", "rmse")}
    counts = np.zeros(len(starts), int)
    x0 = None
    for w, s in enumerate(starts):
        sl = slice(s, s + window)
        use = np.flatnonzero(valid[sl]) + s
        counts[w] = use.size
        if use.size < max(1, min_samples):
            continue
        r = calibrate_d_beta(a[use], np.asarray(b)[use], np.asarray(normal_forces_gt)[use],
                             x0=None if x0 is None else x0, solver=solver)
        x0 = (r.D, r.beta)
        out["D"][w], out["beta"][w], out["cost"][w], out["rmse"][w] = r.D, r.beta, r.cost, r.rmse
    return SlidingCalibration(starts, np.minimum(starts + window, n_total), out["D"],
                              out["beta"], out["cost"], out["rmse"], counts)


def calibrate_batch(res, normal_forces_gt: np.ndarray, window: int | None = None,
                    stride: int | None = None, solver: str = "scipy"):
    """`NormalForceEstimator.calibrate` on its `BatchEstimate` ``res`` (four-wheel rows)."""
    gt = np.asarray(normal_forces_gt, float)
    if gt.shape != res.normal_forces.shape:
        raise EstimatorInputError(f"'normal_forces_gt' must have shape "
                                  f"{res.normal_forces.shape}, got {gt.shape}")
    use = ~res.tipping & (res.in_contact.sum(axis=1) == 4)
    if window is None:
        return calibrate_d_beta(res.system_matrix[use], res.system_rhs[use], gt[use],
                                solver=solver)
    return calibrate_d_beta_sliding(res.system_matrix, res.system_rhs, gt, window, stride,
                                    valid=use, solver=solver)
