"""The observer's cost per control tick and the closed loop's real-time factor with it.

Runs the machine's realistic sensors on swing-out for 5 s (the crane swinging, the machine
driving) and times `Observer.update` per tick; then a 5 s closed loop with mpc-full and the
observer against the bare simulation of the same run.
"""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path

import numpy as np


def run(out: Path) -> dict:
    """Median, p99 and max of the observer's update [us]; RTFs with and without it."""
    from estimators.observer import Observer
    from estimators.payload import PayloadEstimator
    from models import build_reference_machine
    from models.sensor_suites import sensor_suite
    from scenarios.closed_loop import run_closed_loop
    from scenarios.closed_loop_scenarios import SCENARIOS, scenario_terrain
    from scenarios.sensors import SensorSimulator
    from scenarios.simulator import Simulator

    sc = SCENARIOS["swing-out"]
    machine = build_reference_machine(payload_mass=sc.payload_mass)
    sim = Simulator(machine, scenario_terrain(sc, 0))
    sim.reset(sc.start_pose.q(machine), sc.start)
    sensors = SensorSimulator(sim, sensor_suite("realistic", 0))
    obs = Observer(machine, sensor_suite("realistic", 0),
                   PayloadEstimator(machine, fourth="cylinder-force", strokes="clip"))
    times = []
    for k in range(500):
        t = k * 0.01
        sim.set_command(cylinder_rates={"slew": 0.1 * np.sin(t)}, wheel_speeds=(1.0, 1.0))
        sim.step(5)
        r = sensors.readings(sim.time)
        t0 = time.perf_counter()
        obs.update(r)
        times.append(time.perf_counter() - t0)
    us = 1e6 * np.array(times[20:])
    short = dataclasses.replace(sc, duration=5.0)
    t0 = time.perf_counter()
    sim2 = Simulator(machine, scenario_terrain(sc, 0))
    sim2.reset(sc.start_pose.q(machine), sc.start)
    t1 = time.perf_counter()
    sim2.step(2500)
    bare_rtf = 5.0 / (time.perf_counter() - t1)
    del t0
    m = run_closed_loop(short, None, "mpc-full", sensors="realistic")
    return {"observer_update_us_median": float(np.median(us)),
            "observer_update_us_p99": float(np.percentile(us, 99)),
            "observer_update_us_max": float(us.max()),
            "observer_goal_us": 50.0,
            "closed_loop_rtf_with_observer": m["real_time_factor"],
            "bare_simulation_rtf": bare_rtf,
            "closed_loop_rtf_ratio": m["real_time_factor"] / bare_rtf}
