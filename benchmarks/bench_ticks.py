"""Control ticks across a sample of closed-loop runs: does every tick fit the period?

The real-time item of the speed work: across a sample of 20 closed-loop runs, no control
tick after the first longer than the control period (10 ms). Each run is a `random` family
draw (`scenarios.families`; development master seed 1 by default) with mpc-full and the
default realistic sensors, run one after another in this process; a tick is the observer,
the uncertainty margin and the controller's step (`scenarios.closed_loop`'s
``control_step_ms``). Run it alone on the machine: another process on the other core
changes these figures. Not part of ``make bench`` (about 4 min on the 2-core machine):

    python -m benchmarks --only ticks
"""

from __future__ import annotations

from pathlib import Path

DRAWS = 20
MASTER_SEED = 1  # development draws (docs/sweeps.md)
FAMILY = "random"
CONTROLLER = "mpc-full"


def sample(draws: int = DRAWS, master_seed: int = MASTER_SEED, family: str = FAMILY,
           duration: float | None = None) -> dict:
    """Run the sample; per run its tick figures [ms], and the sample's verdict."""
    from scenarios.closed_loop import run_closed_loop
    from scenarios.closed_loop_scenarios import CONTROL_PERIOD
    from scenarios.families import draw

    period_ms = 1e3 * CONTROL_PERIOD
    runs = []
    for index in range(draws):
        d = draw(family, index, master_seed)
        ticks = run_closed_loop(d.scenario, None, CONTROLLER, seed=d.terrain_seed,
                                duration=duration)["control_step_ms"]
        runs.append({"index": index, **{k: round(float(v), 3) for k, v in ticks.items()}})
        print(f"   {family} {index:3d}: median {ticks['median']:.2f} ms, p99 "
              f"{ticks['p99']:.2f} ms, longest after the first {ticks['max_after_first']:.2f} ms",
              flush=True)
    worst = max(r["max_after_first"] for r in runs)
    over = [r["index"] for r in runs if r["max_after_first"] > period_ms]
    return {"family": family, "master_seed": master_seed, "controller": CONTROLLER,
            "draws": draws, "period_ms": period_ms, "runs": runs,
            "worst_tick_after_first_ms": worst, "runs_over_period": over,
            "goal_met": not over}


def run(out_dir: Path | None = None) -> dict:
    """The default sample (`DRAWS` development draws)."""
    return sample()
