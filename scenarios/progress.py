"""A dependency-free progress bar for long runs (stderr, quiet when not a terminal)."""

from __future__ import annotations

import sys
import time


class Progress:
    """Text progress bar: ``with Progress(total, label) as p: p.update(done)``.

    Args:
        total: Amount at 100 % (e.g. simulated seconds).
        label: Text in front of the bar.
        enabled: Draw at all; by default only when stderr is a terminal, else one line
            every 10 %.
    """

    def __init__(self, total: float, label: str = "", enabled: bool | None = None):
        self.total = max(float(total), 1e-12)
        self.label = label
        self.tty = sys.stderr.isatty() if enabled is None else enabled
        self.enabled = True if enabled is None else enabled
        self._t0 = time.perf_counter()
        self._last_decile = -1

    def __enter__(self) -> Progress:
        return self

    def __exit__(self, *exc) -> None:
        if self.enabled and self.tty:
            sys.stderr.write("\n")

    def update(self, done: float) -> None:
        """Show progress ``done`` out of ``total``."""
        if not self.enabled:
            return
        frac = min(max(done / self.total, 0.0), 1.0)
        elapsed = time.perf_counter() - self._t0
        if self.tty:
            n = int(30 * frac)
            sys.stderr.write(f"\r{self.label} [{'#' * n}{'.' * (30 - n)}] {100 * frac:5.1f}% "
                             f"{elapsed:6.1f}s")
            sys.stderr.flush()
        elif int(10 * frac) > self._last_decile:
            self._last_decile = int(10 * frac)
            sys.stderr.write(f"{self.label} {100 * frac:5.1f}% ({elapsed:.1f}s)\n")
