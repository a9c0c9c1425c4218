"""Monte Carlo sweeps: many draws of a scenario family, run in parallel, with bounds.

`run_sweep` runs every (draw, controller) pair of a family (`scenarios.families`) through
the closed loop, in a local process pool (``jobs`` processes) or on a Ray cluster, and writes

* ``sweep.jsonl``: one row per run as soon as it finishes (family, index, master seed, the
  drawn parameters, controller, every metric, or the error of a run that raised: a failing
  run never stops the sweep, and an interrupted sweep keeps the rows it has);
* ``summary.json`` (`summarize`): per controller, the share of draws that stayed safe with a
  one-sided 95 % Clopper-Pearson upper bound on the unsafe share, tip-overs, fallbacks,
  exceptions, time below the threshold, the minimum margin's quantiles and the task time
  against the tracking controller on the same draws.

A run is *unsafe* when any wheel's ground-truth normal force is below the threshold at any
physics step after settling (``time_below_threshold_s`` > 0 on a wheel) or it tipped.
"""

from __future__ import annotations

import contextlib
import json
import multiprocessing
import os
import time
import traceback
from collections.abc import Callable, Iterable
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path

import numpy as np
from scipy.stats import beta as beta_distribution

from scenarios.families import draw
from scenarios.json_io import write_json
from scenarios.metrics import json_default

__all__ = ["clopper_pearson_upper", "run_one", "run_sweep", "summarize"]


def run_one(family: str, index: int, master_seed: int, controller: str,
            options: dict | None = None) -> dict:
    """Run one draw with one controller; returns its row (never raises on a failed run)."""
    from scenarios.closed_loop import run_closed_loop

    row = {"family": family, "index": int(index), "master_seed": int(master_seed),
           "controller": controller}
    t0 = time.perf_counter()
    try:
        d = draw(family, index, master_seed)
        row["scenario"] = d.scenario.name
        row["parameters"] = d.parameters
        row["metrics"] = run_closed_loop(d.scenario, None, controller, seed=d.terrain_seed,
                                         **(options or {}))
    except Exception as exc:  # noqa: BLE001 - a sweep records every failure and goes on
        row["error"] = f"{type(exc).__name__}: {exc}"
        row["traceback"] = traceback.format_exc(limit=8)
    row["wall_seconds"] = time.perf_counter() - t0
    return row


def _tasks(family: str, draws: int, master_seed: int, controllers: Iterable[str],
           first: int = 0) -> list[tuple]:
    return [(family, i, master_seed, c) for i in range(first, first + draws)
            for c in controllers]


def run_sweep(family: str, draws: int, controllers: Iterable[str], out_dir: Path,
              master_seed: int = 0, jobs: int = 1, ray_address: str | None = None,
              options: dict | None = None, first: int = 0,
              progress: Callable[[int, int], None] | None = None) -> dict:
    """Run the sweep, write ``sweep.jsonl`` and ``summary.json``; returns the summary.

    Args:
        family: Scenario family.
        draws: Number of draws (indices ``first .. first + draws - 1``).
        controllers: Controller names.
        out_dir: Output folder.
        master_seed: Master seed of the draws (keep one apart for acceptance runs).
        jobs: Local worker processes (ignored with Ray).
        ray_address: ``"local"`` to start Ray here, or a cluster address; None: no Ray.
        options: Further keyword arguments of `run_closed_loop` (e.g. ``sensors``).
        first: Index of the first draw.
        progress: Called with (runs done, runs in all) after each run.
    """
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    tasks = _tasks(family, draws, master_seed, list(controllers), first)
    rows: list[dict] = []
    path = out_dir / "sweep.jsonl"
    with path.open("w") as out:
        def keep(row: dict) -> None:
            rows.append(row)
            out.write(json.dumps(row, default=json_default) + "\n")
            out.flush()
            if progress is not None:
                progress(len(rows), len(tasks))

        try:
            if ray_address is not None:
                _run_ray(tasks, options, ray_address, keep)
            elif jobs <= 1:
                for t in tasks:
                    keep(run_one(*t, options))
            else:
                with _single_threaded_env(), ProcessPoolExecutor(
                        max_workers=jobs, mp_context=multiprocessing.get_context("spawn")) as pool:
                    futures = [pool.submit(run_one, *t, options) for t in tasks]
                    for f in as_completed(futures):
                        keep(f.result())
        finally:
            summary = summarize(rows)
            summary.update(family=family, master_seed=master_seed, runs=len(rows),
                           runs_planned=len(tasks))
            write_json(out_dir / "summary.json", summary)
    return summary


# Every worker runs its linear algebra on one thread: the runs are independent and parallel
# already, and a BLAS that splits a product over threads rounds differently with their count
# (a closed loop amplifies that), so the pool and Ray would not give the same rows.
_ONE_THREAD = {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}


@contextlib.contextmanager
def _single_threaded_env():
    """Spawned workers inherit these variables before they import numpy."""
    old = {k: os.environ.get(k) for k in _ONE_THREAD}
    os.environ.update(_ONE_THREAD)
    try:
        yield
    finally:
        for k, v in old.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


def _run_ray(tasks: list[tuple], options: dict | None, address: str, keep) -> None:
    try:
        import ray
    except ImportError as exc:
        raise RuntimeError("Ray is not installed: pip install 'wbc-hdmm[ray]'") from exc
    started = not ray.is_initialized()
    if started:
        ray.init(address=None if address == "local" else address, include_dashboard=False,
                 log_to_driver=False, runtime_env={"env_vars": dict(_ONE_THREAD)})
    try:
        remote = ray.remote(run_one)
        pending = [remote.remote(*t, options) for t in tasks]
        while pending:
            done, pending = ray.wait(pending, num_returns=1)
            keep(ray.get(done[0]))
    finally:
        if started:
            ray.shutdown()


def clopper_pearson_upper(unsafe: int, n: int, confidence: float = 0.95) -> float:
    """One-sided Clopper-Pearson upper bound on a proportion (``unsafe`` of ``n``)."""
    if n <= 0:
        return 1.0
    if unsafe >= n:
        return 1.0
    return float(beta_distribution.ppf(confidence, unsafe + 1, n - unsafe))


def _unsafe(metrics: dict) -> bool:
    return bool(metrics["tipped"]) or any(v > 0 for v in
                                          metrics["time_below_threshold_s"].values())


def _quantiles(values: list[float]) -> dict | None:
    if not values:
        return None
    q = np.quantile(values, [0.0, 0.05, 0.5, 0.95, 1.0])
    return dict(zip(("min", "p05", "median", "p95", "max"), map(float, q)))


def _auc(scores: list[float], positive: list[bool]) -> float | None:
    """Area under the ROC curve of ``-score`` predicting ``positive`` (Mann-Whitney)."""
    pos = [s for s, p in zip(scores, positive) if p]
    neg = [s for s, p in zip(scores, positive) if not p]
    if not pos or not neg:
        return None
    wins = sum((p < n) + 0.5 * (p == n) for p in pos for n in neg)
    return float(wins / (len(pos) * len(neg)))


def lift_off_prediction(rows: list[dict]) -> dict:
    """How well each stability measure's minimum predicts a wheel lift-off, over all runs.

    A run lifted a wheel when a wheel's smallest normal force was 0 N. Per measure (the
    smallest normal force over the threshold, the force-angle measure, the ZMP margin): the
    area under the ROC curve of a low minimum predicting a lift-off (1: perfect, 0.5: none).
    """
    ok = [r["metrics"] for r in rows if "metrics" in r]
    lifted = [min(m["min_normal_force_N"].values()) <= 0.0 for m in ok]
    out = {"runs": len(ok), "runs_with_lift_off": int(sum(lifted))}
    for key, name in (("min_normal_force_N", "min_normal_force"),
                      ("min_force_angle_measure_Nm", "force_angle_measure"),
                      ("min_zmp_margin_m", "zmp_margin")):
        if ok and all(key in m for m in ok):
            scores = [min(m[key].values()) if isinstance(m[key], dict) else m[key]
                      for m in ok]
            out[name + "_auc"] = _auc(scores, lifted)
    return out


def _coverage(rows: list[dict]) -> dict | None:
    """The margin's coverage over the draws (`scenarios.metrics.margin_coverage`).

    Pooled over every wheel sample, and the worst draw's.
    """
    cov = [r["metrics"].get("force_margin_coverage") for r in rows]
    cov = [c for c in cov if c]
    if not cov:
        return None
    n = sum(c["samples"] for c in cov)
    return {"stated": cov[0]["stated"],
            "pooled": sum(c["covered"] * c["samples"] for c in cov) / n,
            "worst_draw": min(c["covered"] for c in cov), "samples": n, "draws": len(cov)}


def summarize(rows: list[dict]) -> dict:
    """The per-controller summary of sweep rows (module docstring)."""
    by_controller: dict[str, list[dict]] = {}
    for r in rows:
        by_controller.setdefault(r["controller"], []).append(r)
    tracking_time = {(r["family"], r["index"]): r["metrics"].get("task_completion_time_s")
                     for r in by_controller.get("tracking", []) if "metrics" in r}
    out = {}
    for name, rs in sorted(by_controller.items()):
        ok = [r for r in rs if "metrics" in r]
        unsafe = [r for r in ok if _unsafe(r["metrics"])]
        thr = [r["metrics"]["threshold_N"] for r in ok]
        margins = [min(r["metrics"]["min_normal_force_N"].values()) - t
                   for r, t in zip(ok, thr)]
        below = [sum(r["metrics"]["time_below_threshold_s"].values()) for r in ok]
        ratios = []
        for r in ok:
            t_ref = tracking_time.get((r["family"], r["index"]))
            t = r["metrics"].get("task_completion_time_s")
            if t_ref and t:
                ratios.append(t / t_ref)
        n = len(ok)
        out[name] = {
            "draws": n,
            "draws_below_threshold": len(unsafe),
            "fraction_safe": (n - len(unsafe)) / n if n else None,
            "unsafe_upper_95": clopper_pearson_upper(len(unsafe), n),
            "tipovers": sum(bool(r["metrics"]["tipped"]) for r in ok),
            "fallbacks": int(sum(r["metrics"].get("fallbacks", 0) for r in ok)),
            "exceptions": len(rs) - n,
            "tasks_completed": sum(bool(r["metrics"]["task_completed"]) for r in ok),
            "time_below_s": ({"median": float(np.median(below)), "max": float(max(below))}
                             if below else None),
            "min_margin_N": _quantiles(margins),
            "task_time_ratio": ({"median": float(np.median(ratios)),
                                 "max": float(max(ratios)), "pairs": len(ratios)}
                                if ratios else None),
            "force_margin_coverage": _coverage(ok),
            "unsafe_draws": sorted(r["index"] for r in unsafe),
            "failed_draws": sorted(r["index"] for r in rs if "error" in r),
        }
    out["lift_off_prediction"] = lift_off_prediction(rows)
    return out
