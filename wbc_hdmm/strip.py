"""A strip of frames: the same instants of several runs side by side, one row per run."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from wbc_hdmm.render import frame_at

__all__ = ["frame_strip"]


def frame_strip(runs: dict[str, Path], times: tuple[float, ...], out: Path,
                width: int = 320, height: int = 184) -> Path:
    """A PNG grid of `wbc_hdmm.render.frame_at` views.

    Rows are ``runs`` (label -> run folder), columns ``times`` [s]; a red border marks a wheel
    below the threshold.

    Raises:
        RenderError: No GL context, or a size out of range.
        LogError: A log cannot be read or replayed.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(len(runs), len(times), squeeze=False,
                             figsize=(len(times) * width / 100, len(runs) * height / 100 + 0.3),
                             dpi=100)
    for r, (label, run_dir) in enumerate(runs.items()):
        for c, t in enumerate(times):
            ax = axes[r, c]
            ax.imshow(np.asarray(frame_at(run_dir, t, width, height)))
            ax.set_xticks([])
            ax.set_yticks([])
            if r == 0:
                ax.set_title(f"t = {t:g} s", fontsize=8)
            if c == 0:
                ax.set_ylabel(label, fontsize=8)
    fig.tight_layout(pad=0.3)
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out)
    plt.close(fig)
    return out
