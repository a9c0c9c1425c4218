"""Progress bars with an ETA for long runs (tqdm on stderr)."""

from __future__ import annotations

import sys

from tqdm import tqdm

__all__ = ["Progress"]


class Progress:
    """Progress bar with elapsed time and ETA: ``with Progress(total, label) as p: p.update(done)``.

    Args:
        total: Amount at 100 % (e.g. simulated seconds [s]).
        label: Text in front of the bar.
        enabled: Draw at all; None: draw (a live bar on a terminal, a line every 10 % else).
        unit: Unit of ``total`` shown in the bar.
    """

    def __init__(self, total: float, label: str = "", enabled: bool | None = None,
                 unit: str = "s"):
        self.total = max(float(total), 1e-12)
        self.enabled = True if enabled is None else bool(enabled)
        self._done = 0.0
        self._bar = None
        if self.enabled:
            tty = sys.stderr.isatty()
            self._bar = tqdm(total=round(self.total, 3), desc=label, unit=unit,
                             file=sys.stderr, leave=True, dynamic_ncols=True,
                             mininterval=0.2 if tty else 0.0,
                             miniters=None if tty else max(self.total / 10, 1e-12),
                             bar_format="{desc} {percentage:3.0f}%|{bar}| {n:.1f}/{total:.1f} "
                                        "{unit} [{elapsed}<{remaining}]")

    def __enter__(self) -> Progress:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def update(self, done: float) -> None:
        """Show progress ``done`` out of ``total`` (absolute, not an increment)."""
        if self._bar is None:
            return
        done = min(max(float(done), 0.0), self.total)
        step = round(done - self._done, 3)
        if step > 0:
            self._bar.update(step)
            self._done += step

    def close(self) -> None:
        """Finish the bar (idempotent)."""
        if self._bar is not None:
            self._bar.close()
            self._bar = None
