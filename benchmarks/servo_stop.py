"""How far the lift coasts after a stop command, by boom angle (`docs/sweeps.md`).

The lift is commanded 40 mm/s for 0.5 s and then 0, with the other axes held at development
draw 71's first goal pose (master seed 1, `random`) and 163 kg on flat ground; printed per
start stroke: the boom angle and linkage gain at the stop command, the speed then, how far
the stroke runs on, and when it is below 2 mm/s. A measurement of the simulated servo near
the lift linkage's dead centre, not a benchmark of the code's speed.

    .venv/bin/python -m benchmarks.servo_stop
"""

from __future__ import annotations

import math

import numpy as np

from models import build_reference_machine
from models import terrain as T
from scenarios.families import draw
from scenarios.simulator import Simulator

STARTS = (0.30, 0.45, 0.49, 0.505)  # [m] lift strokes at the start of the 0.5 s motion


def main() -> list[dict]:
    machine = build_reference_machine(payload_mass=163.0)
    goal = draw("random", 71, 1).scenario.goals[0]
    chain = machine.chains["lift"].chain
    rows = []
    for start in STARTS:
        sim = Simulator(machine, T.flat())
        q = machine.coordinates.home()
        q[2:9] = goal.coordinates(machine)
        q[3] = start
        sim.reset(q, settle_time=1.5)
        dt = sim.model.opt.timestep
        moving = []
        sim.set_command(cylinder_rates={"lift": 0.04})
        for _ in range(int(round(0.5 / dt))):
            sim.step()
            moving.append(sim.measure()[0].q[3])
        sim.set_command(cylinder_rates={"lift": 0.0})
        after = []
        for _ in range(int(round(1.0 / dt))):
            sim.step()
            after.append(sim.measure()[0].q[3])
        after = np.array(after)
        x0 = moving[-1]
        slow = np.flatnonzero(np.abs(np.gradient(after, dt)) < 0.002)
        row = {"angle_deg": math.degrees(chain.joint_angle(x0)),
               "gain_rad_per_m": abs(chain.driven_rate_coefficients(x0)[0]),
               "speed_mm_s": 1e3 * (moving[-1] - moving[-20]) / (19 * dt),
               "coast_mm": 1e3 * (after.max() - x0),
               "below_2mm_s_after_s": float(slow[0] * dt) if slow.size else math.nan}
        rows.append(row)
        print(f"boom {row['angle_deg']:6.1f} deg, gain {row['gain_rad_per_m']:4.1f} rad/m, "
              f"{row['speed_mm_s']:5.1f} mm/s at the stop: coasts {row['coast_mm']:5.1f} mm, "
              f"below 2 mm/s after {row['below_2mm_s_after_s']:.3f} s")
    return rows


if __name__ == "__main__":
    main()
