"""The closure's error at touch-downs against the instant's and the tick's mean truth.

``python -m benchmarks.touchdown [--duration 200] [--out out/bench]`` runs the open-loop
``contact-loss`` scenario (a rear wheel off the ground half of the time; its four-wheel
samples are the landings) with MuJoCo's normal forces logged at every physics step
(``run_open_loop(..., physics_rate=True)``), and scores the cylinder-force closure of each
observed sensor suite on the four- and three-wheel samples against

* the truth at the tick's instant (``fz_in_fb``, what `wbc estimate` and the README's table
  score), and
* the truth's mean over the tick: ``fz_in_fb`` moved by the normal force's mean over the
  tick's physics steps less its value at the instant (the pressures the closure reads are
  tick means too).

It also reports how far the truth itself moves within a tick at those samples (the mean of
``|instant - tick mean|`` and of the tick's range). Prints the figures and writes
``touchdown.json``.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

__all__ = ["main", "score", "tick_windows"]


def tick_windows(tick_times, step_times, step_forces, steps_per_tick: int) -> np.ndarray:
    """The physics steps of each tick [N], shape (n_ticks, steps_per_tick, 4).

    The tick at ``t`` reports the step that starts at ``t`` (the simulator's measured
    instant); its window is that step and the ``steps_per_tick - 1`` before it.
    """
    step_times = np.asarray(step_times, float)
    idx = np.searchsorted(step_times, np.asarray(tick_times, float) - 1e-9)
    cols = [np.clip(idx - j, 0, len(step_times) - 1) for j in range(steps_per_tick)]
    return np.stack([np.asarray(step_forces, float)[c] for c in cols[::-1]], axis=1)


def score(log: dict, step_times, step_forces, steps_per_tick: int, machine,
          settle: float = 1.0) -> dict:
    """The figures of the module docstring from a log and its physics-rate forces."""
    from estimators.evaluate_sensors import OBSERVED_SUITES, suite_batch, suite_forces

    t = np.asarray(log["time"], float)
    instant = np.asarray(log["normal_force"], float)
    truth = np.asarray(log["fz_in_fb"], float)
    win = tick_windows(t, step_times, step_forces, steps_per_tick)
    truth_mean = truth + (win.mean(axis=1) - instant)
    rows = np.flatnonzero(t >= settle)
    four = np.asarray(log["in_contact"], bool).all(axis=1)
    four_rows, three_rows = rows[four[rows]], rows[~four[rows]]
    static = machine.total_mass * machine.gravity / 4.0
    out = {"samples": {"four_contact": int(four_rows.size), "three_contact": int(three_rows.size)},
           "instant_matches_step": float(np.abs(win[:, -1] - instant).max()),
           "truth_within_tick_pct": None, "closure_pct": {}}
    if four_rows.size:
        w = win[four_rows]
        out["truth_within_tick_pct"] = {
            "instant_minus_mean": float(np.abs(w[:, -1] - w.mean(1)).mean() / static * 100),
            "range": float((w.max(1) - w.min(1)).mean() / static * 100)}
    for suite in OBSERVED_SUITES:
        sb, payload = suite_batch(log, suite)
        f = suite_forces(machine, sb, payload, "full", "cylinder-force",
                    log[f"obs_{suite}_servo_setpoint"])
        entry = {}
        for name, g in (("instant", truth), ("tick_mean", truth_mean)):
            e = np.abs(f - g) / static * 100
            entry[name] = {"four_contact": float(e[four_rows].mean()) if four_rows.size else None,
                           "three_contact": float(e[three_rows].mean())
                           if three_rows.size else None}
        out["closure_pct"][suite] = entry
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=200.0)
    ap.add_argument("--out", type=Path, default=Path("out/bench"))
    a = ap.parse_args(argv)
    from models import build_reference_machine
    from models.log import load_log
    from scenarios.openloop import SCENARIOS, run_open_loop

    run_dir = a.out / "touchdown_run"
    run_open_loop(SCENARIOS["contact-loss"], run_dir, duration=a.duration, progress=False,
                  physics_rate=True)
    log = load_log(run_dir / "log.npz")
    steps = int(round(float(np.diff(np.asarray(log["time"], float)).mean())
                      / float(log["meta_timestep"])))
    figures = {"scenario": "contact-loss", "duration_s": a.duration, "steps_per_tick": steps,
               **score(log, log["physics_time"], log["physics_normal_force"], steps,
                     build_reference_machine())}
    a.out.mkdir(parents=True, exist_ok=True)
    (a.out / "touchdown.json").write_text(json.dumps(figures, indent=1))
    print(json.dumps(figures, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
