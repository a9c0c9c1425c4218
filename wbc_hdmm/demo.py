"""The demo (``wbc demo``, ``make run``): the paper's open-loop runs, then the controllers."""

from __future__ import annotations

from pathlib import Path

from estimators.evaluate import evaluate_log
from scenarios import registry
from scenarios.closed_loop_scenarios import DEFAULT_SCENARIO
from scenarios.comparison import run_comparison
from wbc_hdmm.report import acceptance_lines
from wbc_hdmm.strip import frame_strip

__all__ = ["STRIP_TIMES", "demo"]

STRIP_TIMES = (4.0, 10.0, 15.0)  # [s] instants of the default scenario shown side by side


def demo(out: Path, progress: bool = True) -> int:
    """The main job: the paper's open-loop runs with the estimators, then the controllers.

    1. Open-loop flat and rough traversals in MuJoCo (logs and metrics under ``out/``).
    2. Every estimator method on both logs (``estimation.json`` and the paper's figures).
    3. The default closed-loop scenario with the three controllers, their comparison plot
       and a strip of frames of the three runs.

    A summary of each step is printed.

    Args:
        out: Output folder.
        progress: Show progress bars.

    Returns:
        The exit status, 0.
    """
    for name in ("flat", "rough"):
        m = registry.run(name, out / name, progress=progress)
        print(f"{name:>6s}: {m['sim_seconds']:.0f} s simulated in {m['wall_seconds']:.1f} s "
              f"({m['real_time_factor']:.1f}x real time); min normal force "
              + ", ".join(f"{w} {v:.0f} N" for w, v in m["min_normal_force_N"].items())
              + f"; max closure gap {1e3 * m['max_closure_violation_m']:.3f} mm")
        report = evaluate_log(out / name, out / name, plots=True)
        errors = report["summary"]["error_pct_mean_over_wheels"]
        print(f"{'':>8s}normal-force error (mean |error| / static wheel load):")
        for method, err in errors.items():
            print(f"{'':>10s}{method:34s} {err:7.3f} %")
    result = run_comparison(DEFAULT_SCENARIO, out / "closed_loop", progress=progress)
    print(f"closed loop '{DEFAULT_SCENARIO}' (results and plot in {out / 'closed_loop'}):")
    print("    acceptance:")
    print("\n".join(acceptance_lines(result["acceptance"], indent="      ")))
    for controller, metrics in result["metrics"].items():
        if isinstance(metrics, dict) and "min_normal_force_N" in metrics:
            task = metrics.get("task_completion_time_s")
            print(f"{'':>4s}{controller:18s} min normal force "
                  + ", ".join(f"{w} {v:.0f} N" for w, v in metrics["min_normal_force_N"].items())
                  + f"; below threshold {sum(metrics['time_below_threshold_s'].values()):.2f} s"
                  f"; tipped {'yes' if metrics.get('tipped') else 'no'}; task time "
                  + ("not completed" if task is None else f"{task:.1f} s"))
    strip = frame_strip({c: out / "closed_loop" / c for c in result["metrics"]},
                        STRIP_TIMES, out / "closed_loop" / "frames.png")
    print(f"    frames of the three runs at {', '.join(f'{t:g}' for t in STRIP_TIMES)} s: "
          f"{strip} (wbc render RUN_DIR for a video)")
    return 0
