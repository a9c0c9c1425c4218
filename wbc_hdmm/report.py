"""Human output of the ``wbc`` command: rounded numbers, one fact per line."""

from __future__ import annotations

__all__ = ["acceptance_lines", "comparison_table", "fmt", "metrics_lines", "sweep_lines"]

_METRIC_KEYS = ("sim_seconds", "wall_seconds", "real_time_factor", "max_closure_violation_m",
                "min_normal_force_N", "contact_loss_fraction", "tipped", "task_error_final",
                "task_completion_time_s", "time_below_threshold_s", "control_step_ms",
                "fallbacks")


def fmt(value, digits: int = 4) -> str:
    """``value`` for humans: floats to ``digits`` significant digits, None as ``-``."""
    if value is None:
        return "-"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, float):
        return f"{value:.0f}" if abs(value) >= 10 ** digits else f"{value:.{digits}g}"
    if isinstance(value, dict):
        return ", ".join(f"{k} {fmt(v, digits)}" for k, v in value.items())
    return str(value)


def metrics_lines(title: str, metrics: dict) -> list[str]:
    """The main metrics of one run, one per line, rounded."""
    lines = [f"== {title}" + ("  (PARTIAL: interrupted)" if metrics.get("partial") else "")]
    for key in _METRIC_KEYS:
        if key in metrics:
            lines.append(f"   {key:26s} {fmt(metrics[key])}")
    return lines


def acceptance_lines(acceptance: dict, indent: str = "    ") -> list[str]:
    """The acceptance checks as readable lines: ``[ok] mpc full not tipped``."""
    lines = []
    for key, value in acceptance.items():
        text = key.replace("_", " ")
        if isinstance(value, bool):
            lines.append(f"{indent}[{'ok' if value else 'NO'}] {text}")
        else:
            lines.append(f"{indent}     {text}: {fmt(value, 3)}")
    return lines


def comparison_table(metrics_by_controller: dict) -> list[str]:
    """The controllers side by side (`scenarios.comparison.run_comparison`'s metrics)."""
    head = (f"{'controller':18s} {'min Fz [N]':>10s} {'below thr [s]':>13s} {'tipped':>6s} "
            f"{'task time [s]':>13s} {'step p50 [ms]':>13s} {'fallbacks':>9s}")
    lines = [head, "-" * len(head)]
    for name, m in metrics_by_controller.items():
        task = m.get("task_completion_time_s")
        lines.append(
            f"{name:18s} {min(m['min_normal_force_N'].values()):10.0f} "
            f"{sum(m['time_below_threshold_s'].values()):13.2f} "
            f"{'yes' if m['tipped'] else 'no':>6s} "
            f"{'-' if task is None else f'{task:.1f}':>13s} "
            f"{m['control_step_ms']['median']:13.2f} {m['fallbacks']:9d}")
    return lines


_LISTED_DRAWS = 20  # unsafe or failed draws listed per controller (summary.json has all)


def sweep_lines(summary: dict, controllers, rerun: str | None = None) -> list[str]:
    """One line per controller of a sweep's summary (`scenarios.sweep.summarize`).

    Its unsafe and failed draws follow it; ``rerun``, a command with ``{controller}`` and
    ``{index}`` fields, is shown for the first of them: how to run that draw again.
    """
    out = []
    first = None
    for name in controllers:
        s = summary.get(name, {})
        out.append(f"   {name:18s} draws {s.get('draws', 0):4d}  below threshold "
                   f"{s.get('draws_below_threshold', 0):4d}  safe {s.get('fraction_safe')}  "
                   f"unsafe <= {s.get('unsafe_upper_95', 1.0):.3f} (95 %)  tip-overs "
                   f"{s.get('tipovers', 0)}  exceptions {s.get('exceptions', 0)}")
        cov = s.get("force_margin_coverage")
        if cov:
            out.append(f"   {'':18s} force margin covered the feedback's error on "
                       f"{100 * cov['pooled']:.1f} % of {cov['samples']} four-wheel samples "
                       f"(stated {100 * cov['stated']:.0f} %; worst draw "
                       f"{100 * cov['worst_draw']:.1f} %)")
        for what in ("unsafe_draws", "failed_draws"):
            draws = s.get(what) or []
            if draws:
                more = f" and {len(draws) - _LISTED_DRAWS} more" if len(draws) > _LISTED_DRAWS \
                    else ""
                out.append(f"   {'':18s} {what.replace('_', ' ')}: "
                           f"{', '.join(map(str, draws[:_LISTED_DRAWS]))}{more}")
                first = first or (name, draws[0])
    if rerun and first:
        out.append("   run one again, with its log: " + rerun.format(controller=first[0],
                                                                     index=first[1]))
    return out
