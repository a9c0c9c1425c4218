"""The closed-loop scenario types: a crane pose and a scenario (terrain, goals, driving).

Files in the TOML format of `scenarios.scenario_file` describe them; the built-in ones are
`scenarios/data/*.toml` (`scenarios.closed_loop_scenarios.SCENARIOS`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from models.description import Machine

__all__ = ["DRIVE_RAMP_SECONDS", "GRAPPLE_CLOSE_SECONDS", "TRANSPORT", "ClosedLoopScenario",
           "CranePose"]

DRIVE_RAMP_SECONDS = 1.0  # the scripted wheel speeds ramp up smoothly over this
GRAPPLE_CLOSE_SECONDS = 1.0  # the operator's grapple command comes this long before a pick


@dataclass(frozen=True)
class CranePose:
    """A crane pose by joint angles; the wrist pitch keeps the tool vertical.

    Attributes:
        slew_deg: Slew angle [deg], positive to the left, within about +-69 deg.
        lift_deg, tilt_deg: Lift and tilt joint angles [deg].
        telescope: Telescope extension [m].
    """

    slew_deg: float
    lift_deg: float
    tilt_deg: float
    telescope: float

    def coordinates(self, machine: Machine) -> np.ndarray:
        """The seven crane coordinates (strokes, telescope, wrist), shape (7,)."""
        ch = machine.chains
        return np.array([
            ch["slew"].chain.stroke_from_angle(math.radians(self.slew_deg)),
            ch["lift"].chain.stroke_from_angle(math.radians(self.lift_deg)),
            ch["tilt"].chain.stroke_from_angle(math.radians(self.tilt_deg)),
            self.telescope, -math.radians(self.lift_deg + self.tilt_deg), 0.0, 0.0])

    def q(self, machine: Machine) -> np.ndarray:
        """Independent coordinates at home with this crane pose, shape (13,)."""
        q = machine.coordinates.home()
        q[2:9] = self.coordinates(machine)
        return q


TRANSPORT = CranePose(0.0, 45.0, -90.0, 0.5)  # the home pose: folded over the chassis


@dataclass(frozen=True)
class ClosedLoopScenario:
    """A closed-loop scenario.

    Attributes:
        name, description: For humans and the command line.
        duration: Simulated time [s].
        side_slope_deg: Side slope [deg]; negative: the left (+y) side is down.
        rough_slope_deg: Largest slope of the added rough terrain [deg]; 0: none.
        start_pose: Crane pose at the start.
        goals: Crane poses given one after the other: the first at ``first_goal_time``,
            each next one ``dwell`` after the tool point has reached the previous one.
        first_goal_time: [s].
        dwell: [s].
        drive_speed: Scripted driving speed [m/s] (both sides), ramped up over
            `DRIVE_RAMP_SECONDS`; 0: standing.
        drive_distance: Distance the base must cover for the task [m].
        payload_mass: Payload at the start [kg].
        payload_event: (time [s], new payload mass [kg]) or None. A heavier mass is a pick:
            the operator's grapple command comes `GRAPPLE_CLOSE_SECONDS` before it
            (`grapple_close_time`).
        start: Base (x [m], y [m], heading [rad]) at the start. The rough terrain is level
            within 3 m of the origin (`models.terrain.rough`), so a machine that does not
            drive starts farther out.
        crane_speed: (velocity, acceleration) fractions of the axis limits the operator's
            motions (the controllers' references) use.
    """

    name: str
    description: str
    duration: float
    side_slope_deg: float
    rough_slope_deg: float
    start_pose: CranePose
    goals: tuple[CranePose, ...]
    first_goal_time: float = 1.0
    dwell: float = 1.0
    drive_speed: float = 0.0
    drive_distance: float = 0.0
    payload_mass: float = 150.0
    payload_event: tuple[float, float] | None = None
    start: tuple[float, float, float] = (0.0, 0.0, 0.0)
    crane_speed: tuple[float, float] = (0.6, 0.2)

    def grapple_close_time(self) -> float | None:
        """When the operator closes the grapple on a load [s], or None (no pick)."""
        if self.payload_event is None or self.payload_event[1] <= self.payload_mass:
            return None
        return max(self.payload_event[0] - GRAPPLE_CLOSE_SECONDS, 0.0)

    def wheel_speed(self, t: float, radius: float) -> float:
        """The operator's wheel speed at time ``t`` [rad/s] (both sides)."""
        ramp = min(max(t / DRIVE_RAMP_SECONDS, 0.0), 1.0)
        return self.drive_speed / radius * ramp * ramp * (3.0 - 2.0 * ramp)
