"""Accuracy of every normal-force method on a scenario log (``wbc estimate LOG``).

`evaluate_log` runs, on one log written by `models.log.ScenarioLog`:

* ``full/d-beta``: the paper's full dynamics closed by eq. (29) at the default D, beta;
* ``full/cylinder-force``: full dynamics closed by the bogie balances with the logged
  suspension cylinder forces (no calibration; only when the log has them);
* ``full/calibrated``: eq. (29) with one (D, beta) fitted by eq. (30) on the whole run
  (in-sample), and ``full/calibrated-holdout``: fitted on the first half of the evaluated
  samples and scored on the second half only (the honest, out-of-sample figure);
* ``full/sliding-window``: (D, beta) fitted by eq. (30) on sliding windows (paper Fig. 9),
  each sample scored with the pair of the window centred nearest to it (in-sample by
  construction: an upper bound of what eq. (29) can do, not an estimator);
* ``quasi-static/d-beta`` and ``quasi-static/cylinder-force``: the baseline of the paper's
  ref. [13] (`estimators.quasi_static`) with the same fourth-equation options;
* ``full/d-beta/no-contact-flags``: only when a wheel loses contact: the same as
  ``full/d-beta`` with the contact flags ignored, to show what Sec. III-B buys.

Every method uses the logged contact flags (Sec. III-B: a wheel out of contact drops its
column; fewer than three contacts is ``tipping``, solved in least squares).

Error metric (the project's acceptance definition): per method and wheel, the mean absolute
error over every sample at least `SETTLE_SECONDS` after the log's start, divided by the
static wheel load ``m g / 4``, in percent. The ground truth is the force component the
estimator estimates: ``fz_in_fb``, the ground force along the fb z axis (contact frames
aligned with fb, eqs. 22-24). The same figure against the terrain-normal force
(``normal_force``) uses `BatchEstimate.normal_forces_terrain`.

Diagnostics, to tell *why* a method misses:

* ``equilibrium_rows``: ``A f_gt - b`` of the three equilibrium rows (eqs. 25-28) with the
  ground-truth forces. In a consistent log they vanish to round-off; what is left is an error
  of the dynamics (the state's accelerations do not produce the logged contact forces), not
  of the fourth equation. ``dynamics_pct`` is the same in the error metric: the size of the
  minimum-norm force correction ``A^+ (A f_gt - b)``.
* Per method, the error on four-contact samples split into its part along the null vector
  ``n`` of ``A`` (``fourth_row_pct``: the diagonal load split that eqs. 25-28 cannot see and
  the fourth equation must supply) and the rest (``dynamics_pct``).
* ``acceleration_consistency``: per independent coordinate, the RMS of the logged
  acceleration against the RMS of the finite difference of the logged velocity. A ratio far
  above one means motion faster than the log rate (vibration), which the equilibrium rows
  then show whether the estimator sees consistently.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from pathlib import Path

import numpy as np

from estimators import calibration
from estimators.errors import EstimatorInputError
from estimators.estimator import NormalForceEstimator
from estimators.evaluate_sensors import check_suites, suites_report
from estimators.full_dynamics import D_BETA_COEFFICIENTS
from estimators.log_batch import log_to_batch
from estimators.results import BatchEstimate
from models.description import WHEEL_ORDER, Machine
from models.log import SETTLE_SECONDS
from models.state_batch import StateBatch

__all__ = ["GOALS", "PAPER", "SETTLE_SECONDS", "SLIDING_WINDOW_SECONDS", "error_percent",
           "evaluate_log", "log_to_batch", "null_split"]

SLIDING_WINDOW_SECONDS = 1.0  # [s] window of the sliding (D, beta) fit (paper Fig. 9)

# Project goals [%] by scenario name, and the paper's figures (Sec. IV) for reference.
GOALS = {
    "flat": {"full/d-beta": 1.0, "full/calibrated": 0.3},
    "rough": {"full/d-beta": 2.5, "full/cylinder-force": 1.5},
}
PAPER = {
    "flat": {"full/d-beta": 2.02, "full/calibrated": 0.42, "quasi-static/d-beta": 4.84},
    "rough": {"full/d-beta": 5.0, "quasi-static/d-beta": 9.46},
}



def _per_wheel(values) -> dict:
    return {w: float(v) for w, v in zip(WHEEL_ORDER, values)}


def error_percent(estimate: np.ndarray, truth: np.ndarray, static_load: float) -> np.ndarray:
    """Mean absolute error per wheel in percent of the static wheel load, shape (4,)."""
    if len(estimate) == 0:
        return np.full(4, np.nan)
    return 100.0 * np.abs(np.asarray(estimate) - np.asarray(truth)).mean(axis=0) / static_load


def null_split(a: np.ndarray, error: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Split force errors into the null direction of ``A`` and the rest.

    Args:
        a: System matrices of four-contact samples, shape (N, 3, 4).
        error: Force errors ``f - f_gt`` [N], shape (N, 4).

    Returns:
        ``(along_null, rest)``, shapes (N, 4): ``along_null`` is the part of the error that
        eqs. (25)-(28) cannot see (fixed by the fourth equation), ``rest = A^+ A error``.
    """
    _, n = calibration.null_space_form(a, np.zeros(a.shape[:2]))
    t = np.einsum("ni,ni->n", error, n) / np.einsum("ni,ni->n", n, n)
    along = n * t[:, None]
    return along, error - along


def _method_report(res: BatchEstimate, gt: np.ndarray, gt_terrain: np.ndarray | None,
                   rows: np.ndarray, static_load: float) -> dict:
    x = res.normal_forces
    err = error_percent(x[rows], gt[rows], static_load)
    out = {"error_pct": {**_per_wheel(err), "mean": float(np.mean(err))},
           "max_abs_error_N": float(np.abs(x[rows] - gt[rows]).max()) if rows.size else None,
           "rmse_N": float(np.sqrt(np.mean((x[rows] - gt[rows]) ** 2))) if rows.size else None,
           "n_samples": int(rows.size)}
    modes, counts = np.unique(res.mode[rows].astype(str), return_counts=True)
    out["modes"] = {str(m): int(c) for m, c in zip(modes, counts)}
    if gt_terrain is not None and res.normals is not None:
        et = error_percent(res.normal_forces_terrain[rows], gt_terrain[rows], static_load)
        out["error_pct_terrain_normal"] = {**_per_wheel(et), "mean": float(np.mean(et))}
    nc = res.in_contact[rows].sum(axis=1)
    subsets = {}
    for label, sel in (("four_contact", nc == 4), ("three_contact", nc == 3),
                       ("tipping", nc < 3)):
        r = rows[sel]
        e = error_percent(x[r], gt[r], static_load)
        subsets[label] = {"n_samples": int(r.size),
                          "error_pct_mean": float(np.mean(e)) if r.size else None,
                          "error_pct": _per_wheel(e) if r.size else None}
    out["by_contacts"] = subsets
    four = rows[nc == 4]
    if four.size:
        along, rest = null_split(res.system_matrix[four], x[four] - gt[four])
        out["four_contact_split"] = {
            "fourth_row_pct": float(np.mean(np.abs(along)) * 100 / static_load),
            "dynamics_pct": float(np.mean(np.abs(rest)) * 100 / static_load)}
    return out


def _acceleration_consistency(log: dict, names: tuple[str, ...]) -> dict:
    t = np.asarray(log["time"], float)
    if t.size < 3:
        return {}
    fd = np.gradient(np.asarray(log["qd"], float), t, axis=0)
    rms = np.sqrt(np.mean(np.asarray(log["qdd"], float) ** 2, axis=0))
    rms_fd = np.sqrt(np.mean(fd ** 2, axis=0))
    out = {n: {"qdd_rms": float(a), "d_qd_dt_rms": float(b),
               "ratio": float(a / b) if b > 0 else None}
           for n, a, b in zip(names, rms, rms_fd)}
    base = np.gradient(np.asarray(log["base_twist"], float), t, axis=0)
    ba = np.sqrt(np.mean(np.asarray(log["base_acceleration"], float) ** 2, axis=0))
    bf = np.sqrt(np.mean(base ** 2, axis=0))
    out["base"] = {"acc_rms": ba.tolist(), "d_twist_dt_rms": bf.tolist()}
    return out


def _equilibrium_rows(res: BatchEstimate, gt: np.ndarray, rows: np.ndarray,
                      static_load: float) -> dict:
    a, b = res.system_matrix[rows], res.system_rhs[rows]
    r = np.einsum("nij,nj->ni", a, gt[rows]) - b
    pinv = np.linalg.pinv(a)
    dx = np.einsum("nij,nj->ni", pinv, r)
    return {
        "rows": ["force z [N]", "roll moment [N m]", "pitch moment [N m]"],
        "mean_abs_residual": np.abs(r).mean(axis=0).tolist() if rows.size else None,
        "p99_abs_residual": np.percentile(np.abs(r), 99, axis=0).tolist() if rows.size
        else None,
        "mean_abs_rhs": np.abs(b).mean(axis=0).tolist() if rows.size else None,
        "force_row_pct_of_weight": float(100 * np.abs(r[:, 0]).mean() / (4 * static_load))
        if rows.size else None,
        "dynamics_pct": float(100 * np.abs(dx).mean() / static_load) if rows.size else None,
        "residual": r,
    }


def evaluate_log(log_path, out_dir=None, plots: bool = True, *, machine: Machine | None = None,
                 settle: float = SETTLE_SECONDS, window_seconds: float = SLIDING_WINDOW_SECONDS,
                 D: float = 0.5, beta: float = 0.0,  # noqa: N803
                 progress: Callable[[float], None] | None = None,
                 suites=None) -> dict:
    """Evaluate every normal-force method on a scenario log; write ``estimation.json``.

    Args:
        log_path: A ``log.npz`` or its folder.
        out_dir: Where ``estimation.json`` and the figures go (default: the log's folder).
        plots: Also write the figures (`estimators.plots`).
        machine: The machine the log was simulated with (default: the reference machine).
        settle: Seconds after the log start that are not scored [s].
        window_seconds: Window of the sliding (D, beta) calibration [s].
        D: Default D of eq. (29) for ``full/d-beta`` and ``quasi-static/d-beta`` [-].
        beta: Default beta of eq. (29) [N].
        progress: Called with the fraction done (0 to 1) after each stage, or None.
        suites: The sensor suites to score in ``sensor_suites`` (``oracle``, ``ideal``,
            ``realistic``; default: every suite the log has). The other entries are the
            oracle's (the simulator's measured state).

    Returns:
        The report (also written as JSON): ``summary`` (a short table, what the CLI prints),
        ``methods`` (per method: ``error_pct`` per wheel and mean, against ``fz_in_fb``;
        ``error_pct_terrain_normal``; errors by number of contacts; the fourth-row /
        dynamics split; modes used), ``calibration``, ``equilibrium_rows``,
        ``acceleration_consistency``, ``samples`` and ``figures``.

    Raises:
        FileNotFoundError: No log at ``log_path``.
        EstimatorInputError: The log lacks fields or its strokes leave their ranges, or a
            suite asked for is unknown or not in the log.
    """
    from models import build_reference_machine
    from models.log import load_log

    log_path = Path(log_path)
    log = load_log(log_path)
    suites = check_suites(log, suites)  # a bad name fails before the work, not after it
    log_file = log_path / "log.npz" if log_path.is_dir() else log_path
    out_dir = Path(out_dir) if out_dir is not None else log_file.parent
    out_dir.mkdir(parents=True, exist_ok=True)
    machine = machine if machine is not None else build_reference_machine()
    static_load = machine.total_mass * machine.gravity / 4
    if "fz_in_fb" not in log:
        raise EstimatorInputError("log lacks 'fz_in_fb' (ground truth f_z along fb z)")
    gt = np.asarray(log["fz_in_fb"], float)
    gt_terrain = np.asarray(log["normal_force"], float) if "normal_force" in log else None
    sb, notes = log_to_batch(log, machine)
    time = np.asarray(log["time"], float)
    rows = np.flatnonzero(time >= time[0] + settle)
    if rows.size < 4:
        raise EstimatorInputError(f"log has {rows.size} samples after {settle} s of settling; "
                                  "too short to evaluate")
    scenario = str(log["meta_scenario"]) if "meta_scenario" in log else log_file.parent.name
    has_cyl = sb.suspension_force is not None

    results: dict[str, BatchEstimate] = {}
    for method in ("full", "quasi-static"):
        for fourth in ("d-beta",) + (("cylinder-force",) if has_cyl else ()):
            est = NormalForceEstimator(machine, method=method, fourth=fourth, D=D, beta=beta)
            results[f"{method}/{fourth}"] = est.estimate_batch(sb, strict=False)
    tick = progress if progress is not None else (lambda fraction: None)
    tick(0.3)
    base = results["full/d-beta"]
    a, b = base.system_matrix, base.system_rhs
    nc = base.in_contact.sum(axis=1)
    four = nc == 4

    # Eq. (30), global (in-sample) and 2-fold (fit on one half, score on the other).
    cal_rows = rows[four[rows]]
    calib: dict = {}
    glob = None
    if cal_rows.size:
        glob = calibration.calibrate_d_beta(a[cal_rows], b[cal_rows], gt[cal_rows])
        calib["global"] = _cal_dict(glob)
        results["full/calibrated"] = NormalForceEstimator(
            machine, D=glob.D, beta=glob.beta).estimate_batch(sb, strict=False)
    else:
        calib["global"] = {"skipped": "no four-contact sample: (D, beta) play no role"}
    half = rows.size // 2
    folds = {"first_to_second": (rows[:half], rows[half:]),
             "second_to_first": (rows[half:], rows[:half])}
    holdout_rows = {}
    fold_results = {}
    for name, (fit, score) in folds.items():
        fit4 = fit[four[fit]]
        if fit4.size == 0:
            continue
        c = calibration.calibrate_d_beta(a[fit4], b[fit4], gt[fit4])
        r = NormalForceEstimator(machine, D=c.D, beta=c.beta).estimate_batch(sb, strict=False)
        e = error_percent(r.normal_forces[score], gt[score], static_load)
        calib[name] = {**_cal_dict(c), "fit_samples": int(fit4.size),
                       "scored_samples": int(score.size),
                       "error_pct": {**_per_wheel(e), "mean": float(np.mean(e))}}
        fold_results[name] = r
        holdout_rows[name] = score
    if "first_to_second" in fold_results:
        results["full/calibrated-holdout"] = fold_results["first_to_second"]

    # Sliding window (Fig. 9): in-sample per window.
    dt = float(np.median(np.diff(time))) if time.size > 1 else 0.01
    window = max(2, int(round(window_seconds / dt)))
    min_samples = max(10, window // 4)
    sliding = {"skipped": f"fewer scored samples than one {window_seconds} s window"}
    if rows.size >= window:
        sl = calibration.calibrate_d_beta_sliding(a[rows], b[rows], gt[rows], window,
                                                  valid=four[rows], min_samples=min_samples)
        centres = (sl.start + sl.stop - 1) // 2
        ok = np.flatnonzero(np.isfinite(sl.D))
        sliding = {"skipped": f"no {window_seconds} s window has {min_samples} four-contact "
                              "samples to fit (D, beta) on"}
        if ok.size:
            nearest = ok[np.argmin(np.abs(np.arange(rows.size)[:, None] - centres[ok][None]),
                                   axis=1)]
            # Four-contact samples get eq. (29) with their window's pair; the others do not
            # depend on (D, beta).
            x = base.normal_forces.copy()
            sub4 = np.flatnonzero(four[rows])
            xp, nv = calibration.null_space_form(a[rows][sub4], b[rows][sub4])
            r_row = D_BETA_COEFFICIENTS[:, 0][None] * sl.D[nearest][sub4][:, None] \
                + D_BETA_COEFFICIENTS[:, 1][None]
            t = (sl.beta[nearest][sub4] - np.einsum("ni,ni->n", xp, r_row)) \
                / np.einsum("ni,ni->n", nv, r_row)
            x[rows[sub4]] = xp + nv * t[:, None]
            results["full/sliding-window"] = _replace_forces(base, x)
            sliding = {"window_s": window * dt, "stride_s": (window // 2) * dt,
                       "time": time[rows][centres].tolist(), "D": sl.D.tolist(),
                       "beta": sl.beta.tolist(), "rmse_N": sl.rmse.tolist(),
                       "n_samples": sl.n_samples.tolist(), "min_samples": min_samples,
                       "D_range": [float(np.nanmin(sl.D)), float(np.nanmax(sl.D))],
                       "beta_range": [float(np.nanmin(sl.beta)), float(np.nanmax(sl.beta))]}
    calib["sliding_window"] = sliding
    tick(0.6)

    lost_any = bool((~base.in_contact[rows]).any())
    if lost_any:
        flags = StateBatch(**{**_batch_fields(sb), "in_contact": np.ones((len(sb), 4), bool)})
        results["full/d-beta/no-contact-flags"] = NormalForceEstimator(
            machine, D=D, beta=beta).estimate_batch(flags, strict=False)

    tick(0.7)
    methods = {}
    for name, res in results.items():
        score = holdout_rows.get("first_to_second") if name == "full/calibrated-holdout" \
            else rows
        methods[name] = _method_report(res, gt, gt_terrain, score, static_load)
    if glob is not None:
        methods["full/calibrated"]["D"] = glob.D
        methods["full/calibrated"]["beta"] = glob.beta
    if "full/calibrated-holdout" in methods:
        methods["full/calibrated-holdout"]["D"] = calib["first_to_second"]["D"]
        methods["full/calibrated-holdout"]["beta"] = calib["first_to_second"]["beta"]
        methods["full/calibrated-holdout"]["note"] = (
            "D, beta fitted on the first half of the scored samples, error on the second half")

    eq_full = _equilibrium_rows(base, gt, rows, static_load)
    eq_qs = _equilibrium_rows(results["quasi-static/d-beta"], gt, rows, static_load)
    names = machine.coordinates.independent_names
    contact_loss = {
        "samples_three_contact": int((nc[rows] == 3).sum()),
        "samples_tipping": int((nc[rows] < 3).sum()),
        "loss_fraction": _per_wheel(1.0 - base.in_contact[rows].mean(axis=0)),
    }
    if lost_any:
        three = rows[nc[rows] == 3]
        for name in ("full/d-beta", "full/d-beta/no-contact-flags"):
            e = error_percent(results[name].normal_forces[three], gt[three], static_load)
            contact_loss[f"{name} on three-contact samples"] = {
                **_per_wheel(e), "mean": float(np.mean(e)) if three.size else None}
    report = {
        "log": str(log_file),
        "scenario": scenario,
        "ground_truth": "fz_in_fb: ground force along the fb z axis (the paper's f_z, "
                        "contact frames aligned with fb, eqs. 22-24); "
                        "error_pct_terrain_normal compares with 'normal_force' instead",
        "metric": f"mean |f_est - f_gt| / (m g / 4) * 100 per wheel, samples with t >= "
                  f"{time[0] + settle:.3g} s; 'mean' is the mean over the four wheels",
        "static_wheel_load_N": static_load,
        "defaults": {"D": D, "beta": beta},
        "samples": {"total": int(time.size), "scored": int(rows.size),
                    "four_contact": int(four[rows].sum()),
                    "three_contact": contact_loss["samples_three_contact"],
                    "tipping": contact_loss["samples_tipping"],
                    "singular": int(base.singular[rows].sum())},
        "tipping_count": contact_loss["samples_tipping"],
        "notes": notes,
        "methods": methods,
        "calibration": calib,
        "contact_loss": contact_loss,
        "equilibrium_rows": {"full": _strip(eq_full), "quasi-static": _strip(eq_qs)},
        "acceleration_consistency": _acceleration_consistency(log, names),
        "goals_pct": GOALS.get(scenario, {}),
        "paper_pct": PAPER.get(scenario, {}),
    }
    report["sensor_suites"] = suites_report(log, machine, sb, rows, static_load, suites)
    report["summary"] = _summary(report)
    figures = []
    tick(0.8)
    if plots:
        from estimators import plots as plotting

        figures = plotting.make_figures(
            out_dir, time=time, rows=rows, gt=gt, results=results, static_load=static_load,
            sliding=sliding, calibration=calib, equilibrium=eq_full["residual"],
            scenario=scenario)
    report["figures"] = [str(p) for p in figures]
    (out_dir / "estimation.json").write_text(json.dumps(_jsonable(report), indent=2))
    tick(1.0)
    return report


def _cal_dict(c: calibration.CalibrationResult) -> dict:
    return {"D": c.D, "beta": c.beta, "rmse_N": c.rmse, "n_samples": c.n_samples,
            "success": c.success, "solver": c.solver}


def _batch_fields(sb: StateBatch) -> dict:
    keys = ("base_rotation", "base_twist", "base_acceleration", "q", "qd", "qdd", "in_contact",
            "force_in_fb", "point_in_fb", "normal_in_fb", "suspension_force", "time")
    return {k: getattr(sb, k) for k in keys}


def _replace_forces(res: BatchEstimate, x: np.ndarray) -> BatchEstimate:
    return BatchEstimate(x, res.in_contact, res.wrench_xi, res.condition, res.mode,
                         res.tipping, np.einsum("nij,nj->ni", res.system_matrix, x)
                         - res.system_rhs, res.contact_points, res.system_matrix,
                         res.system_rhs, res.singular, res.backend, res.normals, res.friction)


def _strip(eq: dict) -> dict:
    return {k: v for k, v in eq.items() if k != "residual"}


def _summary(report: dict) -> dict:
    methods = report["methods"]
    table = {name: round(m["error_pct"]["mean"], 3) for name, m in methods.items()}
    goals = report["goals_pct"]
    out = {
        "scenario": report["scenario"],
        "samples": report["samples"]["scored"],
        "error_pct_mean_over_wheels": table,
        "calibrated_D_beta": [round(report["calibration"]["global"]["D"], 4),
                              round(report["calibration"]["global"]["beta"], 1)]
        if "D" in report["calibration"]["global"] else None,
        "equilibrium_rows_dynamics_pct": round(
            report["equilibrium_rows"]["full"]["dynamics_pct"], 3),
        "tipping_count": report["tipping_count"],
    }
    out["sensor_suites_pct"] = {
        suite: {m: (v["four_contact"], v["three_contact"]) for m, v in e["methods"].items()}
        for suite, e in report["sensor_suites"].items()}
    if goals:
        out["goals"] = {name: {"goal_pct": g, "measured_pct": table.get(name),
                               "met": bool(table.get(name, math.inf) <= g)}
                        for name, g in goals.items()}
    return out


def _jsonable(x):
    if isinstance(x, dict):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return _jsonable(x.tolist())
    if isinstance(x, (np.floating, float)):
        return float(x) if math.isfinite(x) else None
    if isinstance(x, np.integer):
        return int(x)
    if isinstance(x, np.bool_):
        return bool(x)
    return x
