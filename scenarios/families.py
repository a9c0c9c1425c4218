"""Scenario families: seeded random closed-loop scenarios, each draw named and reproducible.

A draw is ``(family, index, master_seed)``; its random stream is NumPy's
``SeedSequence([master_seed, family id, index])``, so a draw does not depend on which other
draws ran, in which order or on how many processes. Its terrain seed is drawn from the same
stream (>= 100: the hand-made scenarios use seeds below 100).

Families (ranges drawn uniformly; slopes in degrees, the side slope's downhill side random):

* ``random``: side slope 0-12, rough terrain 0-20, payload 50-300 kg, heading +-30 deg from
  +x (driving) or any (standing), driving 0-0.6 m/s (a third of the draws stand), 1-3 goals
  anywhere in the reachable workspace, crane speed 30-80 % of the velocity and 10-40 % of
  the acceleration limits, and in a third of the draws a pick (an empty 10 kg grapple grabs
  100-300 kg) or a release (the payload drops to the 10 kg grapple).
* ``heavy-pick-downhill``: standing on a 5-12 deg side slope with 5-15 deg rough terrain,
  the empty grapple at long reach on the downhill side grabs 230-300 kg and brings it in.
* ``fast-swing-steep``: driving 0.3-0.6 m/s on a 8-12 deg side slope with 10-20 deg rough
  terrain, fast swings (70-80 % / 30-40 %) between the two sides at long reach.
* ``standing-on-rough``: standing on 12-20 deg rough terrain (side slope 0-8), 1-3 goals.

Every goal is checked at construction against the limits the controller uses
(`check_reachable`): an unreachable goal is a `ScenarioFileError` before the run. Goals are
also drawn where the crane can hold the heaviest payload of the draw (its rated payload from
the load chart, `models.load_chart.rated_payload`, with the cylinder forces the MPC allows
itself, `EFFORT_FRACTION` of each range, at least 1 / `HOLD_FRACTION` times that mass), both
on level ground and with the chassis on the draw's side slope at its heading
(`ground_attitude`; the rough terrain's local tilt is not in the check): an operator does
not command a pose the cylinders cannot hold where the machine stands, and the controller
would not move the load there; whether the machine stays on four wheels there is the
controller's business.
"""

from __future__ import annotations

import math
import zlib
from dataclasses import dataclass

import numpy as np

from models import build_reference_machine
from models.description import Machine
from models.load_chart import rated_payload
from scenarios.errors import RunInputError, ScenarioFileError
from scenarios.scenario import TRANSPORT, ClosedLoopScenario, CranePose
from wbc.controllers.config import MpcConfig

__all__ = ["EFFORT_FRACTION", "FAMILIES", "GRAPPLE_MASS", "HOLD_FRACTION", "POSITION_MARGIN",
           "SUMMARIES", "Draw", "check_reachable", "draw", "ground_attitude"]

GRAPPLE_MASS = 10.0  # [kg] an empty grapple
POSITION_MARGIN = 0.01  # the controller's margin (`wbc.ControllerConfig.position_margin`)
_EDGE = 0.03  # goals keep this fraction of each range from its ends (inside the margin)
_WRIST_LIMIT_DEG = 88.0  # the wrist keeps the tool vertical: |lift + tilt| within this
HOLD_FRACTION = 0.8  # a goal's payload is at most this fraction of its rated payload
EFFORT_FRACTION = 1.0 - MpcConfig().effort_margin  # of each force range, as the MPC's bounds


@dataclass(frozen=True)
class Draw:
    """One draw of a family.

    Attributes:
        family, index, master_seed: What names it.
        scenario: The scenario (named ``<family>-<index>``).
        terrain_seed: Seed of its rough terrain.
        parameters: The drawn numbers, flat, for the sweep's table.
    """

    family: str
    index: int
    master_seed: int
    scenario: ClosedLoopScenario
    terrain_seed: int
    parameters: dict


def ground_attitude(side_slope_deg: float, heading: float) -> np.ndarray:
    """The chassis attitude (world <- fb) standing on the side slope at ``heading`` [rad].

    The plane ``h = y tan(side_slope)`` of `models.terrain.side_slope`: its normal is world
    z turned about world x by the slope angle, and the chassis is yawed by the heading
    about that normal. Written out, not `models.rotations.axis_rotation` (its Rodrigues form
    differs in the last bits on 4 of 10 angles, and a draw's pose rejections depend on them).
    """
    a = math.radians(side_slope_deg)
    ca, sa, cy, sy = math.cos(a), math.sin(a), math.cos(heading), math.sin(heading)
    tilt = np.array([[1.0, 0.0, 0.0], [0.0, ca, -sa], [0.0, sa, ca]])
    yaw = np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]])
    return tilt @ yaw


def _holds(machine: Machine, q: np.ndarray, mass: float, attitudes) -> bool:
    return all(HOLD_FRACTION * rated_payload(machine, q, 0.0, base_rotation=rot,
                                             effort_fraction=EFFORT_FRACTION).mass >= mass
               for rot in attitudes)


def _pose_in_workspace(rng: np.random.Generator, machine: Machine, slew_deg=None,
                       reach: tuple[float, float] = (0.0, 1.0), hold: float = 0.0,
                       attitude: np.ndarray | None = None) -> CranePose:
    """A random pose inside the controller's ranges; ``reach`` picks the telescope range.

    ``hold`` [kg]: the pose must hold this payload with the room `HOLD_FRACTION` leaves, on
    level ground and, if given, with the chassis at ``attitude`` (world <- fb).
    """
    attitudes = (None,) if attitude is None else (None, attitude)
    ch = machine.chains
    for _ in range(1000):
        angles = []
        for name in ("slew", "lift", "tilt"):
            lo, hi = ch[name].chain.stroke_range
            x = rng.uniform(lo + _EDGE * (hi - lo), hi - _EDGE * (hi - lo))
            angles.append(math.degrees(ch[name].chain.joint_angle(x)))
        if slew_deg is not None:
            angles[0] = slew_deg
        if abs(angles[1] + angles[2]) > _WRIST_LIMIT_DEG:
            continue
        t_lo, t_hi = machine.coordinates.lower[5], machine.coordinates.upper[5]
        span = t_hi - t_lo
        telescope = rng.uniform(t_lo + max(_EDGE, reach[0]) * span,
                                t_lo + min(1 - _EDGE, reach[1]) * span)
        pose = CranePose(*angles, telescope)
        if hold > 0 and not _holds(machine, pose.q(machine), hold, attitudes):
            continue
        return pose
    raise RunInputError(f"no crane pose found in the workspace that holds {hold:.0f} kg "
                        "(1000 tries)")


def check_reachable(scenario: ClosedLoopScenario, machine: Machine | None = None,
                    margin: float = POSITION_MARGIN) -> None:
    """Raise `ScenarioFileError` unless every pose of ``scenario`` is within reach.

    Within reach: inside the ranges the controller uses, each range less ``margin`` of its
    span at both ends.
    """
    machine = machine if machine is not None else build_reference_machine()
    coords = machine.coordinates
    names = coords.independent_names
    for k, pose in enumerate((scenario.start_pose,) + tuple(scenario.goals)):
        where = "start_pose" if k == 0 else f"goals[{k - 1}]"
        try:
            q = pose.coordinates(machine)
        except (ValueError, ArithmeticError) as exc:
            raise ScenarioFileError(f"{scenario.name}: {where} is not a crane pose: {exc}"
                                    ) from None
        for i, v in enumerate(q, start=2):
            lo, hi = coords.lower[i], coords.upper[i]
            m = margin * (hi - lo)
            if not (lo + m - 1e-12 <= v <= hi - m + 1e-12):
                raise ScenarioFileError(
                    f"{scenario.name}: {where} puts '{names[i]}' at {v:.4g}, outside the "
                    f"controller's range [{lo + m:.4g}, {hi - m:.4g}] (its range "
                    f"[{lo:.4g}, {hi:.4g}] less {margin:.0%} at each end)")


def _downhill_slew(side_slope_deg: float) -> float:
    """Slew [deg] pointing the crane to the downhill side (left side down for < 0)."""
    return 60.0 if side_slope_deg < 0 else -60.0


def _random(rng, machine, name):
    standing = rng.uniform() < 1 / 3
    side = rng.uniform(0, 12) * rng.choice([-1.0, 1.0])
    rough = rng.uniform(0, 20)
    speed = 0.0 if standing else rng.uniform(0.1, 0.6)
    n_goals = int(rng.integers(1, 4))
    payload = rng.uniform(50, 300)
    event = None
    kind = rng.choice(["none", "none", "pick", "release"])
    first = rng.uniform(1.0, 3.0)
    if kind == "pick":
        event = (first - 0.5, rng.uniform(100, 300))
        payload = GRAPPLE_MASS
    elif kind == "release":
        event = (first + rng.uniform(3.0, 6.0), GRAPPLE_MASS)
    heaviest = max(payload, event[1] if event else 0.0)
    heading = rng.uniform(-math.pi, math.pi) if standing else rng.uniform(-0.5, 0.5)
    duration = 10.0 + 5.0 * n_goals
    start = (rng.uniform(6, 12), rng.uniform(-2, 2), heading) if standing else (
        0.0, rng.uniform(-2, 2), heading)
    goals = tuple(_pose_in_workspace(rng, machine, hold=heaviest,
                                     attitude=ground_attitude(side, heading))
                  for _ in range(n_goals))
    crane_speed = (rng.uniform(0.3, 0.8), rng.uniform(0.1, 0.4))
    return dict(name=name, side_slope_deg=side, rough_slope_deg=rough, drive_speed=speed,
                drive_distance=0.8 * speed * (duration - 2.0), goals=goals,
                payload_mass=payload, payload_event=event, first_goal_time=first,
                start=start, crane_speed=crane_speed, duration=duration,
                start_pose=TRANSPORT if kind != "pick" else goals[0])


def _heavy_pick(rng, machine, name):
    side = -rng.uniform(5, 12)
    down = _downhill_slew(side)
    mass = rng.uniform(230, 300)
    grab = _pose_in_workspace(rng, machine, slew_deg=down * rng.uniform(0.6, 1.0),
                              reach=(0.7, 1.0), hold=mass, attitude=ground_attitude(side, 0.0))
    return dict(name=name, side_slope_deg=side, rough_slope_deg=rng.uniform(5, 15),
                drive_speed=0.0, drive_distance=0.0, goals=(TRANSPORT,),
                payload_mass=GRAPPLE_MASS, payload_event=(2.0, mass),
                first_goal_time=2.5, start=(rng.uniform(6, 12), rng.uniform(-2, 2), 0.0),
                crane_speed=(0.6, 0.2), duration=15.0, start_pose=grab)


def _fast_swing(rng, machine, name):
    side = rng.uniform(8, 12) * rng.choice([-1.0, 1.0])
    speed = rng.uniform(0.3, 0.6)
    payload = rng.uniform(100, 250)
    start = (0.0, rng.uniform(-2, 2), rng.uniform(-0.3, 0.3))
    out = [_pose_in_workspace(rng, machine, slew_deg=s * rng.uniform(40, 60),
                              reach=(0.6, 1.0), hold=payload,
                              attitude=ground_attitude(side, start[2])) for s in (1.0, -1.0)]
    return dict(name=name, side_slope_deg=side, rough_slope_deg=rng.uniform(10, 20),
                drive_speed=speed, drive_distance=0.8 * speed * 13.0, goals=tuple(out),
                payload_mass=payload, payload_event=None,
                first_goal_time=rng.uniform(1.0, 2.0), start=start,
                crane_speed=(rng.uniform(0.7, 0.8), rng.uniform(0.3, 0.4)), duration=15.0,
                start_pose=TRANSPORT)


def _standing_rough(rng, machine, name):
    n_goals = int(rng.integers(1, 4))
    payload = rng.uniform(50, 300)
    side = rng.uniform(0, 8) * rng.choice([-1.0, 1.0])
    rough = rng.uniform(12, 20)
    start = (rng.uniform(6, 12), rng.uniform(-2, 2), rng.uniform(-math.pi, math.pi))
    return dict(name=name, side_slope_deg=side,
                rough_slope_deg=rough, drive_speed=0.0, drive_distance=0.0,
                goals=tuple(_pose_in_workspace(rng, machine, hold=payload,
                                               attitude=ground_attitude(side, start[2]))
                            for _ in range(n_goals)),
                payload_mass=payload, payload_event=None,
                first_goal_time=rng.uniform(1.0, 2.0), start=start,
                crane_speed=(rng.uniform(0.3, 0.8), rng.uniform(0.1, 0.4)),
                duration=10.0 + 5.0 * n_goals, start_pose=TRANSPORT)


FAMILIES = {"random": _random, "heavy-pick-downhill": _heavy_pick,
            "fast-swing-steep": _fast_swing, "standing-on-rough": _standing_rough}
SUMMARIES = {  # one line each, for `wbc list` (the ranges: module docstring)
    "random": "side slope 0-12 deg, rough 0-20 deg, 50-300 kg, driving 0-0.6 m/s or "
              "standing, 1-3 goals, picks and releases",
    "heavy-pick-downhill": "standing on a 5-12 deg side slope, the empty grapple grabs "
                           "230-300 kg at long reach downhill",
    "fast-swing-steep": "driving 0.3-0.6 m/s on an 8-12 deg side slope, 10-20 deg rough, "
                        "fast swings side to side at long reach",
    "standing-on-rough": "standing on 12-20 deg rough ground, 1-3 goals",
}


def draw(family: str, index: int, master_seed: int = 0,
         machine: Machine | None = None) -> Draw:
    """Draw number ``index`` of ``family`` (module docstring).

    Raises:
        RunInputError: Unknown family, or an index or seed that is not an integer >= 0.
        ScenarioFileError: The drawn scenario is not reachable (a bug in the family).
    """
    if family not in FAMILIES:
        raise RunInputError(f"unknown scenario family {family!r}; valid: "
                            f"{', '.join(FAMILIES)}")
    for what, v in (("index", index), ("master seed", master_seed)):
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 0:
            raise RunInputError(f"draw {what} must be an integer >= 0, got {v!r}")
    machine = machine if machine is not None else build_reference_machine()
    family_id = zlib.crc32(family.encode())
    rng = np.random.default_rng(np.random.SeedSequence([int(master_seed), family_id,
                                                        int(index)]))
    terrain_seed = int(rng.integers(100, 2 ** 31 - 1))
    fields = FAMILIES[family](rng, machine, f"{family}-{index:04d}")
    if fields["rough_slope_deg"] < 0.5 and abs(fields["side_slope_deg"]) < 0.5:
        fields["rough_slope_deg"] = 0.5  # the terrain needs one of the two
    fields = {k: float(v) if isinstance(v, np.floating) else v for k, v in fields.items()}
    scenario = ClosedLoopScenario(
        description=f"draw {index} of family '{family}' (master seed {master_seed})",
        dwell=1.0, **fields)
    check_reachable(scenario, machine)
    parameters = {
        "side_slope_deg": scenario.side_slope_deg, "rough_slope_deg": scenario.rough_slope_deg,
        "drive_speed": scenario.drive_speed, "payload_mass": scenario.payload_mass,
        "payload_event_mass": scenario.payload_event[1] if scenario.payload_event else None,
        "n_goals": len(scenario.goals), "heading_deg": math.degrees(scenario.start[2]),
        "crane_speed": list(scenario.crane_speed), "terrain_seed": terrain_seed,
        "max_reach_telescope": max(p.telescope for p in scenario.goals),
    }
    return Draw(family, int(index), int(master_seed), scenario, terrain_seed, parameters)
