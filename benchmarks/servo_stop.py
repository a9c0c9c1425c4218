"""How far the lift coasts after a stop command, by boom angle (`docs/sweeps.md`).

The lift is commanded 40 mm/s for 0.5 s and then 0, with the other axes held at the first goal
pose of development draw 71 before the lift's end stop (master seed 1, `random`: the pose
is written out below) and 163 kg on flat ground; printed per start stroke: the boom angle and
linkage gain at the stop command, the speed then, how far the stroke runs on, and when it is
below 2 mm/s. Measured on the machine without the end stop (the published stroke, which
runs to the lift linkage's dead centre) and on the reference machine up to its stop. A
measurement of the simulated servo, not a benchmark of the code's speed.

    .venv/bin/python -m benchmarks.servo_stop
"""

from __future__ import annotations

import math

import numpy as np

from models import build_reference_machine
from models import terrain as T
from models.reference_machine import LIFT_STROKE_END
from scenarios.scenario import CranePose
from scenarios.simulator import Simulator

# Development draw 71's first goal (master seed 1) as drawn before the end stop: boom past
# vertical; it tipped over.
POSE = CranePose(slew_deg=-35.52337364703586, lift_deg=94.92989235638606,
                 tilt_deg=-20.056774957348832, telescope=0.39245156318102725)
# Per machine (where its lift stroke ends [m]): the lift strokes at the start of the 0.5 s
# motion [m].
STARTS = ((0.59, (0.30, 0.45, 0.49, 0.505)), (LIFT_STROKE_END, (0.30, 0.45, 0.465)))


def main() -> list[dict]:
    rows = []
    for end, starts in STARTS:
        machine = build_reference_machine(payload_mass=163.0, lift_stroke_end=end)
        top = machine.chains["lift"].chain.stroke_range[1]
        print(f"lift stroke ends at {top:.4f} m"
              + (" (the reference machine's end stop)" if end == LIFT_STROKE_END else
                 " (the published stroke, to the dead centre)"))
        rows += _coasts(machine, starts)
    return rows


def _coasts(machine, starts) -> list[dict]:
    chain = machine.chains["lift"].chain
    # Its strokes on the machine that reaches its lift angle; each start replaces the lift's.
    pose = POSE.coordinates(build_reference_machine(lift_stroke_end=0.59))
    rows = []
    for start in starts:
        sim = Simulator(machine, T.flat())
        q = machine.coordinates.home()
        q[2:9] = pose
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
        row = {"stroke_end_m": chain.stroke_range[1],
               "angle_deg": math.degrees(chain.joint_angle(x0)),
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
