"""Scenario names -> runners, for the ``wbc`` command."""

from __future__ import annotations

from pathlib import Path

from scenarios.openloop import SCENARIOS as OPEN_LOOP
from scenarios.openloop import run_open_loop


def names() -> list[str]:
    """Every scenario name."""
    return sorted(OPEN_LOOP)


def run(name: str, out_dir: Path, controller: str | None = None, duration: float | None = None,
        seed: int = 0, progress: bool = True) -> dict:
    """Run scenario ``name``; returns its metrics (also written to ``out_dir``)."""
    if name in OPEN_LOOP:
        if controller not in (None, "open-loop"):
            raise ValueError(f"scenario '{name}' is open loop; it takes no controller "
                             f"(got '{controller}')")
        return run_open_loop(OPEN_LOOP[name], out_dir, seed=seed, duration=duration,
                             progress=progress)
    raise ValueError(f"unknown scenario '{name}'; valid: {', '.join(names())}")


def demo(out: Path, progress: bool = True) -> int:
    """The main job: the open-loop flat and rough traversals, with a summary."""
    for name in ("flat", "rough"):
        m = run(name, out / name, progress=progress)
        print(f"{name:>6s}: {m['sim_seconds']:.0f} s simulated in {m['wall_seconds']:.1f} s "
              f"({m['real_time_factor']:.1f}x real time); min normal force "
              + ", ".join(f"{w} {v:.0f} N" for w, v in m["min_normal_force_N"].items())
              + f"; max closure gap {1e3 * m['max_closure_violation_m']:.3f} mm")
    return 0
