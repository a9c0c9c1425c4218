"""Scenario names -> runners: one entry point for every open-loop and closed-loop scenario."""

from __future__ import annotations

from pathlib import Path

from scenarios.closed_loop import run_closed_loop
from scenarios.closed_loop_scenarios import SCENARIOS as CLOSED_LOOP
from scenarios.errors import RunInputError
from scenarios.noise import DEFAULT_NOISE, MeasurementNoise
from scenarios.openloop import SCENARIOS as OPEN_LOOP
from scenarios.openloop import run_open_loop
from scenarios.scenario import ClosedLoopScenario

__all__ = ["DEFAULT_CONTROLLER", "NOISE_PRESETS", "describe", "is_closed_loop", "names", "run"]

DEFAULT_CONTROLLER = "mpc-full"

# Measurement-noise presets of the command line: name -> noise (None: exact measurements).
NOISE_PRESETS: dict[str, MeasurementNoise | None] = {
    "none": None,
    "default": DEFAULT_NOISE,
}


def names() -> list[str]:
    """Every scenario name: the open-loop ones, then the closed-loop ones."""
    return sorted(OPEN_LOOP) + sorted(CLOSED_LOOP)


def is_closed_loop(name: str) -> bool:
    """Whether scenario ``name`` is a closed-loop one (takes a controller)."""
    return name in CLOSED_LOOP


def describe() -> dict[str, dict[str, str]]:
    """One-line descriptions: ``{"open-loop": {name: text}, "closed-loop": {name: text}}``."""
    return {"open-loop": {n: OPEN_LOOP[n].description for n in sorted(OPEN_LOOP)},
            "closed-loop": {n: CLOSED_LOOP[n].description for n in sorted(CLOSED_LOOP)}}


def run(name: str, out_dir: Path, controller: str | None = None, duration: float | None = None,
        seed: int = 0, progress: bool = True, *, noise: str = "none", delay_periods: int = 0,
        threshold_n: float | None = None, sensors: str = "realistic") -> dict:
    """Run scenario ``name``; returns its metrics (also written to ``out_dir``).

    Closed-loop scenarios take a controller (``tracking``, ``mpc-quasi-static``,
    ``mpc-full``; default ``mpc-full``), measurement noise, delay and threshold; open-loop
    ones take none of these.

    Args:
        name: Scenario name (`names`), or a `ClosedLoopScenario` (e.g. from a scenario file,
            `scenarios.scenario_file.load_scenario_file`).
        out_dir: Output folder.
        controller: Closed-loop controller; None: the default.
        duration: Override the scenario's duration [s].
        seed: Terrain seed.
        progress: Show a progress bar.
        noise: Measurement-noise preset (`NOISE_PRESETS`).
        delay_periods: Measurement delay [control periods].
        threshold_n: Normal-force threshold [N]; None: the scenarios' default.
        sensors: Closed loop: ``realistic``, ``ideal`` or ``oracle`` (`scenarios.sensing`).

    Raises:
        ValueError: Unknown scenario, or an option the scenario does not take.
        RunInputError: A value outside its range.
    """
    if noise not in NOISE_PRESETS:
        raise RunInputError(f"noise preset {noise!r} is not one of "
                            f"{', '.join(NOISE_PRESETS)}")
    if not isinstance(name, ClosedLoopScenario) and name in OPEN_LOOP:
        if controller not in (None, "open-loop"):
            raise ValueError(f"scenario '{name}' is open loop; it takes no controller "
                             f"(got '{controller}')")
        for option, value, default in (("noise", noise, "none"), ("delay", delay_periods, 0),
                                       ("threshold", threshold_n, None),
                                       ("sensors", sensors, "realistic")):
            if value != default:
                raise ValueError(f"scenario '{name}' is open loop; it takes no {option} "
                                 f"(got {value!r}); closed-loop scenarios: "
                                 f"{', '.join(sorted(CLOSED_LOOP))}")
        return run_open_loop(OPEN_LOOP[name], out_dir, seed=seed, duration=duration,
                             progress=progress)
    if isinstance(name, ClosedLoopScenario) or name in CLOSED_LOOP:
        scenario = name if isinstance(name, ClosedLoopScenario) else CLOSED_LOOP[name]
        return run_closed_loop(scenario, out_dir, controller or DEFAULT_CONTROLLER,
                               seed=seed, duration=duration, progress=progress,
                               noise=NOISE_PRESETS[noise], delay_periods=delay_periods,
                               threshold_n=threshold_n, sensors=sensors)
    raise ValueError(f"unknown scenario '{name}'; valid: {', '.join(names())}")
