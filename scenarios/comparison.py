"""The three controllers on one closed-loop scenario, and the issue's acceptance checks."""

from __future__ import annotations

from pathlib import Path

from scenarios.closed_loop import run_closed_loop
from scenarios.closed_loop_plots import plot_comparison
from scenarios.closed_loop_scenarios import DEFAULT_SCENARIO
from scenarios.json_io import write_json
from scenarios.scenario import ClosedLoopScenario
from wbc import CONTROLLER_NAMES

__all__ = ["acceptance", "run_comparison"]


def acceptance(results: dict) -> dict:
    """The issue's acceptance checks on one scenario's metrics by controller.

    Args:
        results: Controller name -> its metrics (`run_closed_loop`).

    Returns:
        Check name -> result (booleans, and the task-time ratio), with ``all_met``.
    """
    full, trk = results.get("mpc-full"), results.get("tracking")
    out = {}
    if full is not None:
        out["mpc_full_never_below_threshold"] = all(
            v == 0.0 for v in full["time_below_threshold_s"].values())
        out["mpc_full_not_tipped"] = not full["tipped"]
        out["mpc_full_completes_task"] = full["task_completed"]
    if trk is not None:
        out["tracking_below_threshold_or_tipped"] = bool(
            trk["tipped"] or any(v > 0 for v in trk["time_below_threshold_s"].values()))
    if full is not None and trk is not None:
        tf, tt = full["task_completion_time_s"], trk["task_completion_time_s"]
        out["task_time_ratio_full_over_tracking"] = (None if tf is None or tt is None
                                                     else tf / tt)
        out["mpc_full_within_30_percent_of_tracking"] = bool(
            tf is not None and (tt is None or tf <= 1.3 * tt))
    out["all_met"] = all(v for k, v in out.items() if isinstance(v, bool))
    return out


def run_comparison(scenario: str | ClosedLoopScenario = DEFAULT_SCENARIO,
                   out_root: Path = Path("out/compare"), duration: float | None = None,
                   seed: int = 0,
                   progress: bool = False) -> dict:
    """Run the three controllers on ``scenario`` (same terrain and seed).

    Writes ``out_root/<controller>/{log.npz, metrics.json}``, ``out_root/forces.png``
    (`plot_comparison`) and ``out_root/comparison.json`` (metrics by controller and the
    acceptance checks).

    Args:
        scenario: Name of a closed-loop scenario, or the `ClosedLoopScenario` itself.
        out_root: Output folder.
        duration: Override the scenario's duration [s].
        seed: Terrain seed.
        progress: Show progress bars.

    Returns:
        The content of ``comparison.json``.
    """
    out_root = Path(out_root)
    results, dirs = {}, {}
    for name in CONTROLLER_NAMES:
        dirs[name] = out_root / name
        results[name] = run_closed_loop(scenario, dirs[name], name, seed=seed,
                                        duration=duration, progress=progress)
    png = plot_comparison(dirs, out_root / "forces.png")
    name = scenario.name if isinstance(scenario, ClosedLoopScenario) else scenario
    report = {"scenario": name, "seed": seed, "plot": str(png),
              "metrics": results, "acceptance": acceptance(results)}
    write_json(out_root / "comparison.json", report)
    return report
