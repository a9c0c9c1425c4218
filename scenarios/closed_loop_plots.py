"""Figure of a closed-loop comparison: the four wheels' ground-truth forces per controller."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import numpy as np

from models.log import SETTLE_SECONDS, load_log

__all__ = ["plot_comparison"]

# Panels laid out as the wheels sit on the machine (seen from above, heading up the page):
# front row FL, FR; rear row RL, RR.
_LAYOUT = {"FL": (0, 0), "FR": (0, 1), "RL": (1, 0), "RR": (1, 1)}
_INDEX = {"FL": 0, "RL": 1, "FR": 2, "RR": 3}
_STYLE = {"tracking": ("tab:red", "-", 1.1), "mpc-quasi-static": ("tab:orange", "-", 1.1),
          "mpc-full": ("tab:blue", "-", 1.6)}
_LABEL = {"tracking": "tracking only", "mpc-quasi-static": "MPC, quasi-static model",
          "mpc-full": "MPC, full-dynamics model"}


def plot_comparison(out_dirs_by_controller: Mapping[str, Path], png_path: Path) -> Path:
    """Plot the ground-truth normal forces of several closed-loop runs of one scenario.

    One panel per wheel (front row FL, FR; rear row RL, RR) with every controller's force
    along the terrain normal over time, the threshold (dashed black) and, shaded, the
    time that controller spent below it; the legend gives each run's minimum and time
    below the threshold after the settling second, as in ``metrics.json``. Each panel has
    its own force scale, from just below zero so that lift-offs show.

    Args:
        out_dirs_by_controller: Controller name -> folder with its ``log.npz``.
        png_path: Where to write the PNG.

    Returns:
        ``png_path``.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    logs = {name: load_log(d) for name, d in out_dirs_by_controller.items()}
    if not logs:
        raise ValueError("plot_comparison needs at least one run")
    first = next(iter(logs.values()))
    thr = float(first["meta_threshold"]) if "meta_threshold" in first else None
    scenario = str(first.get("meta_scenario", ""))
    fig, axes = plt.subplots(2, 2, figsize=(14, 8), sharex=True, constrained_layout=True)
    fig.suptitle(f"Closed loop '{scenario}': ground-truth wheel normal forces "
                 f"(threshold {thr / 1e3:.2f} kN)" if thr else scenario, fontsize=13)
    for wheel, (r, c) in _LAYOUT.items():
        ax = axes[r][c]
        i = _INDEX[wheel]
        top = max(float(np.percentile(log["normal_force"][:, i], 99.5)) for log in logs.values())
        for name, log in logs.items():
            color, ls, lw = _STYLE.get(name, ("tab:gray", "-", 1.0))
            t, f = log["time"], log["normal_force"][:, i]
            settled = t >= min(SETTLE_SECONDS, t[-1])
            dt = float(np.median(np.diff(t))) if t.size > 1 else 0.0
            below = float((f[settled] < thr).sum() * dt) if thr else 0.0
            label = (f"{_LABEL.get(name, name)}: min {f[settled].min() / 1e3:.2f} kN, "
                     f"{below:.2f} s below")
            ax.plot(t, f, color=color, ls=ls, lw=lw, label=label)
            if thr:
                ax.fill_between(t, 0, 1.1 * top, where=f < thr, color=color, alpha=0.12,
                                lw=0)
        if thr:
            ax.axhline(thr, color="k", ls="--", lw=1.0, label="threshold")
        ax.set_title(wheel, fontsize=12, fontweight="bold", loc="left")
        ax.set_ylim(-0.03 * top, 1.1 * top)
        ax.yaxis.set_major_formatter(plt.FuncFormatter(lambda v, _: f"{v / 1e3:g}"))
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8, loc="best", framealpha=0.9)
        if r == 1:
            ax.set_xlabel("time [s]")
        if c == 0:
            ax.set_ylabel("normal force [kN]")
    png_path = Path(png_path)
    png_path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(png_path, dpi=110)
    plt.close(fig)
    return png_path
