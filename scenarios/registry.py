"""Scenario names -> runners: one entry point for every open-loop and closed-loop scenario."""

from __future__ import annotations

from pathlib import Path

from scenarios.closed_loop import run_closed_loop
from scenarios.closed_loop_scenarios import SCENARIOS as CLOSED_LOOP
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

