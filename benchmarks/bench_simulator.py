"""Simulator speed: real-time factor of the rough open-loop scenario on one core."""

from __future__ import annotations

import time
from pathlib import Path

from models import build_reference_machine
from scenarios.openloop import SCENARIOS, run_open_loop
from scenarios.simulator import Simulator

SIM_SECONDS = 40.0  # the full rough scenario


def run(out_dir: Path) -> dict:
    """Time the rough scenario with logging, and bare stepping without it."""
    scenario = SCENARIOS["rough"]
    m = run_open_loop(scenario, Path(out_dir) / "rough_run", duration=SIM_SECONDS,
                      progress=False)
    machine = build_reference_machine()
    sim = Simulator(machine, scenario.terrain(0))
    sim.reset(machine.coordinates.home())
    n = int(10.0 / sim.timestep)
    sim.set_command(wheel_speeds=(0.3, 0.3))
    t0 = time.perf_counter()
    sim.step(n)
    bare = time.perf_counter() - t0
    return {
        "rough_scenario_real_time_factor": round(m["real_time_factor"], 2),
        "rough_scenario_sim_seconds": m["sim_seconds"],
        "rough_scenario_wall_seconds": round(m["wall_seconds"], 3),
        "bare_stepping_real_time_factor": round(n * sim.timestep / bare, 2),
        "step_us": round(1e6 * bare / n, 2),
        "timestep_s": sim.timestep,
        "goal_real_time_factor": 20.0,
    }
