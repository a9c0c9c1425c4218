"""Open-loop traversals of the paper (Sec. IV): flat, rough, and contact loss.

Wheel profile. The paper commands ``q_w = b (t - sin t)``, ``qd_w = b (1 - cos t)`` and
``qdd_w = a b sin t`` (a = 35 or 30), which are not consistent: ``a b sin t`` is not the
derivative of ``b (1 - cos t)`` unless a = 1. We keep the position and velocity and use the
consistent acceleration ``qdd_w = b sin t``; the wheels are velocity-commanded, so the
velocity profile is what the machine gets. ``b`` is given per side as (right, left) in the
paper (``b = [0.9; 0.8] pi`` flat, ``[0.15; 0.15] pi`` rough); we keep that naming.

Crane and suspension commands are sinusoids about the home pose, ``x_i(t) = x0_i + A_i
sin(w_i t + phi_i)``, sent as rates ``A_i w_i cos(w_i t + phi_i)`` to the rate-commanded
servos (the servo integrates them back to the sinusoid).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from models import build_reference_machine
from models.description import WHEEL_ORDER
from models.log import OBSERVED_SUITES, SETTLE_SECONDS, ScenarioLog
from models.terrain import Terrain, flat, rough
from scenarios.errors import RunInterrupted
from scenarios.json_io import write_json
from scenarios.physics_rate import NormalForceRecorder
from scenarios.progress import Progress
from scenarios.run_args import check_duration, check_seed
from scenarios.sensing import Sensing
from scenarios.simulator import Simulator

# (amplitude, angular frequency [rad/s], phase [rad]) per servo, independent order:
# bogie_L, bogie_R [m], slew, lift, tilt [m], telescope [m], wrist_pitch, wrist_roll,
# rotator [rad]. Chosen like the XS031 test inputs (lift +-10 deg at 1 rad/s, tilt +-15 deg
# at 2 rad/s, telescope +-0.2 m at 1 rad/s) and within every valve's flow limit.
_CRANE_WAVES = ((0.04, 0.5, 0.0), (0.06, 0.3, 0.0), (0.05, 1.0, 0.0), (0.05, 2.0, 0.0),
                (0.2, 1.0, 0.0), (0.2, 0.5, 0.0), (0.1, 0.7, 0.0), (0.4, 0.5, 0.0))


@dataclass(frozen=True)
class OpenLoopScenario:
    """An open-loop traversal.

    Attributes:
        name: Scenario name.
        duration: [s].
        terrain: Function of the seed returning the terrain.
        wheel_b: Paper's ``b`` as (right, left) [rad/s].
        suspension_waves: (amplitude [m], frequency [rad/s], phase [rad]) for bogie_L, bogie_R.
        crane_waves: The same for the 7 crane coordinates, order slew, lift, tilt, telescope,
            wrist_pitch, wrist_roll, rotator.
        log_rate: Samples per second in the log [Hz].
        description: One line for humans.
    """

    name: str
    duration: float
    terrain: object
    wheel_b: tuple[float, float]
    suspension_waves: tuple = ((0.02, 0.5, 0.0), (0.02, 0.5, 0.0))
    crane_waves: tuple = _CRANE_WAVES[1:]
    log_rate: float = 100.0
    description: str = ""
    home_overrides: dict = field(default_factory=dict)

    def waves(self) -> np.ndarray:
        """(9, 3) array of (amplitude, frequency, phase) for the nine servos."""
        return np.array(self.suspension_waves + tuple(self.crane_waves), float)

    def servo_rates(self, t: float) -> np.ndarray:
        """Commanded rates of the nine servos at time ``t`` [m/s, rad/s], shape (9,)."""
        w = self.waves()
        return w[:, 0] * w[:, 1] * np.cos(w[:, 1] * t + w[:, 2])

    def wheel_speeds(self, t: float) -> tuple[float, float]:
        """(left, right) wheel speeds ``b (1 - cos t)`` [rad/s]."""
        b_right, b_left = self.wheel_b
        s = 1.0 - math.cos(t)
        return b_left * s, b_right * s


def _rough_terrain(seed: int) -> Terrain:
    return rough(seed, max_slope_deg=26.7)


SCENARIOS = {
    "flat": OpenLoopScenario(
        "flat", 25.0, lambda seed: flat(), (0.9 * math.pi, 0.8 * math.pi),
        description="25 s on flat ground, b = [0.9; 0.8] pi (paper Figs. 5-6)"),
    "rough": OpenLoopScenario(
        "rough", 40.0, _rough_terrain, (0.15 * math.pi, 0.15 * math.pi),
        description="40 s on rough ground, slopes up to 26.7 deg, b = 0.15 pi (Figs. 7-8)"),
    "contact-loss": OpenLoopScenario(
        "contact-loss", 200.0, _rough_terrain, (0.15 * math.pi, 0.15 * math.pi),
        suspension_waves=((0.05, 0.4, 0.0), (0.05, 0.4, math.pi)),
        description="200 s on rough ground with the bogies pitched in opposition (Fig. 10)"),
}


def _summary(log: dict, machine, settle: float) -> dict:
    t = log["time"]
    keep = t >= settle
    if not keep.any():  # a partial run (Ctrl-C) within the settling: judge all of it
        keep = np.ones_like(keep)
    fz = log["normal_force"][keep]
    contact = log["in_contact"][keep]
    per_wheel = lambda a: {w: float(v) for w, v in zip(WHEEL_ORDER, a)}  # noqa: E731
    return {
        "min_normal_force_N": per_wheel(fz.min(axis=0)),
        "mean_normal_force_N": per_wheel(fz.mean(axis=0)),
        "contact_loss_fraction": per_wheel(1.0 - contact.mean(axis=0)),
        "max_closure_violation_m": float(log["closure_violation"].max()),
        "static_wheel_load_N": machine.total_mass * machine.gravity / 4,
    }


def _observed(sensing: dict, tick: float) -> dict:
    """The observers' states at the tick, as log columns ``obs_<suite>_<field>``."""
    out = {}
    for suite, sens in sensing.items():
        o = sens.observe(tick)
        st = o.state
        fields = {"base_rotation": st.base_rotation, "base_twist": st.base_twist,
                  "base_acceleration": st.base_acceleration, "q": st.q, "qd": st.qd,
                  "qdd": st.qdd, "in_contact": st.contacts.in_contact,
                  "point_in_fb": st.contacts.point_in_fb,
                  "force_in_fb": st.contacts.force_in_fb,
                  "suspension_force": st.suspension_force,
                  "servo_setpoint": st.servo_setpoint, "payload": o.payload_mass,
                  "payload_std": o.payload_std}
        out.update({f"obs_{suite}_{k}": v for k, v in fields.items()})
    return out


def run_open_loop(scenario: OpenLoopScenario, out_dir: Path, seed: int = 0,
                  duration: float | None = None, progress: bool = True,
                  observe: bool = True, machine=None, physics_rate: bool = False) -> dict:
    """Run an open-loop scenario; write ``log.npz`` and ``metrics.json`` to ``out_dir``.

    Args:
        scenario: The scenario.
        out_dir: Output folder.
        seed: Terrain seed (the flat terrain has none; it is checked all the same).
        duration: Override the scenario's duration [s].
        progress: Show a progress bar.
        observe: Also run the machine's sensors and observer (`OBSERVED_SUITES`) and log
            their states (`models.log.OBSERVED_COLUMNS`).
        machine: The machine (a payload other than the description's); None: the reference
            machine.
        physics_rate: Also log MuJoCo's normal forces at every physics step
            (`models.log.PHYSICS_COLUMNS`, as the closed loop does; a Python call per step).

    Returns:
        The metrics written to ``metrics.json``, with ``"partial": False``.

    Raises:
        RunInputError: ``duration`` or ``seed`` outside its range (`scenarios.run_args`).
        RunInterrupted: Ctrl-C during the run; the log and metrics so far were written
            (``"partial": True``).
    """
    duration = check_duration(duration, scenario.duration)
    seed = check_seed(seed)
    machine = build_reference_machine() if machine is None else machine
    terrain = scenario.terrain(seed)
    sim = Simulator(machine, terrain)
    q0 = machine.coordinates.home()
    sim.reset(q0)
    recorder = NormalForceRecorder(sim) if physics_rate else None
    # The machine's sensors and observer beside the truth, one per suite (payload not told:
    # the observers start from an empty grapple's 10 kg).
    sensing = {suite: Sensing(sim, machine, suite, seed, initial_payload=10.0)
               for suite in OBSERVED_SUITES} if observe else {}
    every = max(1, int(round(1.0 / (scenario.log_rate * sim.timestep))))
    n_samples = int(duration / (every * sim.timestep))
    log = ScenarioLog(scenario=scenario.name, seed=seed, payload_mass=machine.body(
        machine.payload).inertia.mass, timestep=sim.timestep, terrain=terrain.name)
    interrupted = False
    wall0 = time.perf_counter()
    with Progress(duration, f"{scenario.name:>12s}", enabled=None if progress else False) as bar:
        try:
            for k in range(n_samples):
                t = sim.time
                rates = scenario.servo_rates(t)
                left, right = scenario.wheel_speeds(t)
                sim.set_command(rates[:6], rates[6:], (left, right))
                sim.step(every)
                state, contacts = sim.measure()
                qpos, qvel, _ = sim.measured_instant
                log.append(state, contacts, np.concatenate([rates, (left, right)]),
                           sim.closure_violation(), qpos=qpos, qvel=qvel,
                           **_observed(sensing, state.time))
                if k % 50 == 0:
                    bar.update(sim.time)
        except KeyboardInterrupt:
            interrupted = True
        else:
            bar.update(duration)
    wall = time.perf_counter() - wall0
    n_done = len(log) if interrupted else n_samples
    if n_done == 0:  # nothing to save
        raise KeyboardInterrupt
    if recorder is not None:
        recorder.close()
        log.set_physics(physics_time=recorder.time, physics_normal_force=recorder.normal_force)
    out_dir = Path(out_dir)
    log.save(out_dir / "log.npz")
    arrays = log.arrays()
    metrics = {
        "scenario": scenario.name,
        "description": scenario.description,
        "controller": "open-loop",
        "terrain": terrain.name,
        "seed": seed,
        "partial": interrupted,
        "sim_seconds": float(n_done * every * sim.timestep),
        "wall_seconds": wall,
        "real_time_factor": float(n_done * every * sim.timestep / wall),
        "timestep_s": sim.timestep,
        "log_rate_hz": 1.0 / (every * sim.timestep),
        **_summary(arrays, machine, SETTLE_SECONDS),
    }
    write_json(out_dir / "metrics.json", metrics)
    if interrupted:
        raise RunInterrupted(out_dir, metrics)
    return metrics
