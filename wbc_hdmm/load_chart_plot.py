"""``wbc machine --load-chart``: the rated payload by reach and slew, printed and plotted."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from models.description import Machine
from models.load_chart import load_chart
from scenarios.closed_loop_scenarios import threshold

__all__ = ["print_and_plot"]

SLEWS_DEG = (-60.0, -30.0, 0.0, 30.0, 60.0)
TELESCOPES = tuple(np.round(np.linspace(0.05, 1.05, 6), 3))


def print_and_plot(machine: Machine, path: Path, slope_deg: float = 0.0) -> str:
    """Compute the chart, write the figure to ``path``; returns the printed table."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    if not (math.isfinite(slope_deg) and abs(slope_deg) < 45.0):
        raise ValueError(f"--slope must be within (-45, 45) deg, got {slope_deg}")
    thr = threshold()
    a = math.radians(slope_deg)
    # Left (+y) side down for a positive slope: the crane's left (positive slew) downhill.
    rot = np.array([[1, 0, 0], [0, math.cos(a), math.sin(a)], [0, -math.sin(a), math.cos(a)]])
    chart = load_chart(machine, thr, SLEWS_DEG, TELESCOPES, base_rotation=rot)
    lines = [f"load chart: rated payload [kg] (limit), outer boom level, {slope_deg:g} deg "
             f"side slope, threshold {thr:.0f} N per wheel",
             "reach [m]  " + "".join(f"slew {s:+5.0f} deg      " for s in SLEWS_DEG)]
    fig, ax = plt.subplots(figsize=(7, 4))
    for slew in SLEWS_DEG:
        rows = [r for r in chart if r["slew_deg"] == slew]
        ax.plot([r["reach_m"] for r in rows], [r["rated_kg"] for r in rows], marker="o",
                label=f"slew {slew:+.0f} deg")
    for tel in TELESCOPES:
        rows = [r for r in chart if r["telescope_m"] == tel]
        lines.append(f"{rows[0]['reach_m']:9.2f}  " + "".join(
            f"{r['rated_kg']:7.0f} ({r['limit'][:7]:7s})  " for r in rows))
    ax.set_xlabel("reach from the slew axis [m]")
    ax.set_ylabel("rated payload [kg]")
    ax.set_title(f"load chart, {slope_deg:g} deg side slope")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    lines.append(f"wrote {path}")
    return "\n".join(lines)
