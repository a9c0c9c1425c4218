"""The closed-loop scenarios: terrain, crane poses, goals, driving, payload, and settings.

Each scenario runs with each controller (``tracking``, ``mpc-quasi-static``, ``mpc-full``) on
the same terrain and seed (`scenarios.closed_loop`). The base follows scripted wheel speeds
(the operator's), which the MPC may scale down (`ControlCommand.wheel_speeds`); the tracking
controller's scale is 1.

Scenarios (`SCENARIOS`, read from `scenarios/data/*.toml` in the format of
`scenarios.scenario_file`; terrain: the seeded rough terrain of `models.terrain.rough` with the
given largest slope, added to the side slope of `models.terrain.side_slope`, left side down):

* ``swing-out`` (the default): the machine drives 6 m across a 5 deg side slope with 10 deg
  rough terrain at 0.4 m/s while the crane swings the payload (150 kg) from its transport
  pose out to full reach (slew 45 deg, lift 20 deg, tilt -40 deg, telescope 1.08 m) on the
  downhill side.
* ``pick-place-slope``: standing 8 m out (where the rough terrain is fully developed) on a
  5 deg side slope with 5 deg rough terrain, the crane reaches out to full reach on the
  downhill side (pick), waits 1 s, and swings the payload over to full reach on the uphill
  side (place).
* ``pick-in-motion``: driving 5 m at 0.3 m/s across the 5 deg side slope with 10 deg rough
  terrain, with the crane out on the downhill side (slew 45, lift 30, tilt -60 deg,
  telescope 0.6 m) and an empty grapple (10 kg); at 3 s it grabs a 220 kg log (the payload
  body's mass is changed in MuJoCo) and brings it to the transport pose.

The crane motions follow the operator's profile ``crane_speed`` = (60 %, 20 %) of the axis
velocity and acceleration limits, the same reference for the three controllers.

Why a controller that only tracks gets into trouble here (measured, `wbc.force_models.
feedback`): the suspension servos are stiff, so with the strokes held the chassis cannot
follow the terrain's twist and the crane's moment at long reach takes the load off one
wheel of a diagonal (statically: full reach at 45 deg on flat ground leaves RR at 0 kN held,
5.1 kN with the chassis leveled); the rough ground twists the chassis by 20-40 kN/s at
0.4 m/s; crane swings at long reach load the wheels by up to ~10 kN per m/s^2 of slew
stroke acceleration.
"""

from __future__ import annotations

from models import build_reference_machine
from models.terrain import Terrain, rough, side_slope
from scenarios.scenario import ClosedLoopScenario, CranePose
from scenarios.scenario_file import DATA_DIR, load_scenario_file
from wbc import ControllerConfig, ForceConfig, ReferenceConfig

__all__ = ["CONTROL_PERIOD", "DEFAULT_SCENARIO", "SCENARIOS", "SIDE_RESERVE", "TASK_TOLERANCE",
           "ClosedLoopScenario", "CranePose", "controller_config", "scenario_terrain",
           "threshold"]

CONTROL_PERIOD = 0.01  # [s] 100 Hz
TASK_TOLERANCE = 0.05  # [m] tool point within this of its goal
THRESHOLD_FRACTION = 0.1  # of the reference machine's static wheel load
DEFAULT_SCENARIO = "swing-out"
# [N] each side pair's load sum keeps this above its thresholds while driving (the uphill
# pair's sum swung by +-2.5 kN on rough ground with the crane parked, `wbc/DESIGN.md`)
SIDE_RESERVE = 3000.0


# The built-in scenarios, in the file format a user's scenario uses (scenarios/data/*.toml).
SCENARIOS = {sc.name: sc for sc in (load_scenario_file(DATA_DIR / f"{name}.toml")
                                    for name in ("swing-out", "pick-place-slope",
                                                 "pick-in-motion"))}


def threshold() -> float:
    """The normal-force threshold of the metrics [N]: 10 % of the static wheel load."""
    return float(ForceConfig(threshold_fraction=THRESHOLD_FRACTION)
                 .thresholds_for(build_reference_machine())[0])


def controller_config(threshold_n: float | None = None,
                      crane_speed: tuple[float, float] = (0.6, 0.2)) -> ControllerConfig:
    """The settings every closed-loop scenario runs its controllers with.

    The reference (the operator's motion profile, the same for all three controllers) uses
    ``crane_speed`` = (60 %, 20 %) of the axis velocity and acceleration limits by default:
    a heavy crane at long reach, whose lift cylinder is at 75-85 % of its force statically
    (the description's limits allow 3 rad/s^2 of slew). The MPC keeps no hand-set margin:
    the run adds ``z sigma`` per wheel from the observer's error model every tick
    (`scenarios.closed_loop.uncertainty_margin`; zero for the oracle), and it levels the
    chassis through the suspension with weight 10. While driving, each side pair's load
    sum keeps `SIDE_RESERVE` above the pair's thresholds (`ForceConfig.side_reserve`).

    Args:
        threshold_n: Normal-force threshold of every wheel [N]; `threshold` if None.
        crane_speed: (velocity, acceleration) fractions of the axis limits.

    Returns:
        The controller settings.
    """
    thr = threshold() if threshold_n is None else float(threshold_n)
    return ControllerConfig(
        reference=ReferenceConfig(velocity_fraction=crane_speed[0],
                                  acceleration_fraction=crane_speed[1]),
        force=ForceConfig(thresholds=(thr, thr, thr, thr), margin=0.0,
                          leveling_weight=10.0, side_reserve=SIDE_RESERVE))


def scenario_terrain(scenario: ClosedLoopScenario, seed: int = 0) -> Terrain:
    """The side slope plus the seeded rough terrain, on the rough terrain's grid.

    Raises:
        ValueError: The scenario has neither a side slope nor rough terrain.
    """
    spacing = 0.25
    side = side_slope(scenario.side_slope_deg, spacing=spacing) if scenario.side_slope_deg \
        else None
    if scenario.rough_slope_deg > 0:
        base = rough(seed, scenario.rough_slope_deg, spacing=spacing)
        heights = base.heights + (side.heights if side is not None else 0.0)
        return Terrain("rough_side_slope", heights, base.x_range, base.y_range,
                       base.friction)
    if side is None:
        raise ValueError(f"scenario '{scenario.name}' has neither a side slope nor rough "
                         f"terrain")
    return side
