"""Scenario names -> runners, for the ``wbc`` command."""

from __future__ import annotations

from pathlib import Path

from scenarios.closed_loop import SCENARIOS as CLOSED_LOOP
from scenarios.closed_loop import run_closed_loop
from scenarios.openloop import SCENARIOS as OPEN_LOOP
from scenarios.openloop import run_open_loop

DEFAULT_CONTROLLER = "mpc-full"


def names() -> list[str]:
    """Every scenario name: the open-loop ones, then the closed-loop ones."""
    return sorted(OPEN_LOOP) + sorted(CLOSED_LOOP)


def run(name: str, out_dir: Path, controller: str | None = None, duration: float | None = None,
        seed: int = 0, progress: bool = True) -> dict:
    """Run scenario ``name``; returns its metrics (also written to ``out_dir``).

    Closed-loop scenarios take a controller (``tracking``, ``mpc-quasi-static``,
    ``mpc-full``; default ``mpc-full``); open-loop ones take none.
    """
    if name in OPEN_LOOP:
        if controller not in (None, "open-loop"):
            raise ValueError(f"scenario '{name}' is open loop; it takes no controller "
                             f"(got '{controller}')")
        return run_open_loop(OPEN_LOOP[name], out_dir, seed=seed, duration=duration,
                             progress=progress)
    if name in CLOSED_LOOP:
        return run_closed_loop(CLOSED_LOOP[name], out_dir, controller or DEFAULT_CONTROLLER,
                               seed=seed, duration=duration, progress=progress)
    raise ValueError(f"unknown scenario '{name}'; valid: {', '.join(names())}")


def demo(out: Path, progress: bool = True) -> int:
    """The main job: the paper's open-loop runs with the estimators, then the controllers.

    1. Open-loop flat and rough traversals in MuJoCo (logs and metrics under ``out/``).
    2. Every estimator method on both logs (``estimation.json`` and the paper's figures).
    3. The default closed-loop scenario with the three controllers and their comparison plot.
    """
    from estimators.evaluate import evaluate_log
    from scenarios.closed_loop import DEFAULT_SCENARIO, run_comparison

    for name in ("flat", "rough"):
        m = run(name, out / name, progress=progress)
        print(f"{name:>6s}: {m['sim_seconds']:.0f} s simulated in {m['wall_seconds']:.1f} s "
              f"({m['real_time_factor']:.1f}x real time); min normal force "
              + ", ".join(f"{w} {v:.0f} N" for w, v in m["min_normal_force_N"].items())
              + f"; max closure gap {1e3 * m['max_closure_violation_m']:.3f} mm")
        report = evaluate_log(out / name, out / name, plots=True)
        errors = report["summary"]["error_pct_mean_over_wheels"]
        print(f"{'':>8s}normal-force error (mean |error| / static wheel load):")
        for method, err in errors.items():
            print(f"{'':>10s}{method:34s} {err:7.3f} %")
    result = run_comparison(DEFAULT_SCENARIO, out / "closed_loop")
    print(f"closed loop '{DEFAULT_SCENARIO}' (results and plot in {out / 'closed_loop'}):")
    print(f"    acceptance: {result['acceptance']}")
    for controller, metrics in result["metrics"].items():
        if isinstance(metrics, dict) and "min_normal_force_N" in metrics:
            print(f"{'':>4s}{controller:18s} min normal force "
                  + ", ".join(f"{w} {v:.0f} N" for w, v in metrics["min_normal_force_N"].items())
                  + f"; below threshold {sum(metrics['time_below_threshold_s'].values()):.2f} s"
                  f"; tipped {metrics.get('tipped')}; task time "
                  f"{metrics.get('task_completion_time_s')}")
    return 0
