"""Closed-loop scenarios as TOML files: the documented format, read and written.

The built-in scenarios are shipped in this format (`scenarios/data/*.toml`) and a user's
own file runs with ``wbc run --scenario-file my.toml``. Every field is validated on reading;
an error names the file, the field and the valid range. The format (units in brackets; a
field left out takes the default shown)::

    name = "my-swing"                 # letters, digits, '-', '_'
    description = "what happens"
    duration = 20.0                   # [s], in (1, 3600]
    side_slope_deg = -5.0             # [deg], in [-20, 20]; negative: left (+y) side down
    rough_slope_deg = 10.0            # [deg], in [0, 30]; 0: no rough terrain
    first_goal_time = 1.0             # [s], in [0, duration]
    dwell = 1.0                       # [s] after a goal is reached, in [0, duration]
    drive_speed = 0.4                 # [m/s], in [0, 2]; 0: standing
    drive_distance = 6.0              # [m] the base must cover, in [0, 100]
    payload_mass = 150.0              # [kg], in [0, 500]
    start = [0.0, 0.0, 0.0]           # base x [m], y [m] in [-10, 10], heading [rad]
    crane_speed = [0.6, 0.2]          # velocity, acceleration fractions, each in (0, 1]

    [start_pose]                      # crane pose at the start (default: transport)
    slew_deg = 0.0                    # each angle within its cylinder chain's range
    lift_deg = 45.0
    tilt_deg = -90.0
    telescope = 0.5                   # [m], within the telescope's range

    [[goals]]                         # one or more, given one after the other
    slew_deg = 45.0
    lift_deg = 20.0
    tilt_deg = -40.0
    telescope = 1.08

    [payload_event]                   # optional: the payload mass changes at a time
    time = 3.0                        # [s], in [0, duration]
    mass = 220.0                      # [kg], in [0, 500]

Crane angles are checked against the reference machine's chains (the slew four-bar reaches
about +-69 deg); a pose the crane cannot take is refused before any simulation.
"""

from __future__ import annotations

import json
import math
import re
import tomllib
from pathlib import Path

from models import build_reference_machine
from models.errors import ModelError
from scenarios.errors import ScenarioFileError
from scenarios.scenario import TRANSPORT, ClosedLoopScenario, CranePose

__all__ = ["DATA_DIR", "load_scenario_file", "scenario_from_dict", "scenario_to_toml"]

DATA_DIR = Path(__file__).resolve().parent / "data"
_NAME = re.compile(r"^[A-Za-z0-9_-]{1,64}$")
# field: (lower, upper, default) [units in the module docstring]
_RANGES = {
    "duration": (1.0, 3600.0, None),
    "side_slope_deg": (-20.0, 20.0, 0.0),
    "rough_slope_deg": (0.0, 30.0, 0.0),
    "drive_speed": (0.0, 2.0, 0.0),
    "drive_distance": (0.0, 100.0, 0.0),
    "payload_mass": (0.0, 500.0, 150.0),
}
_TIMES = {"first_goal_time": 1.0, "dwell": 1.0}
_POSE_FIELDS = ("slew_deg", "lift_deg", "tilt_deg", "telescope")
_TOP = {"name", "description", "start_pose", "goals", "payload_event", "start",
        "crane_speed", *_RANGES, *_TIMES}


def _fail(where: str, field: str, message: str) -> ScenarioFileError:
    return ScenarioFileError(f"{where}: '{field}' {message}")


def _number(where: str, field: str, value, lower: float, upper: float,
            open_lower: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) \
            or not math.isfinite(value):
        raise _fail(where, field, f"must be a finite number, got {value!r}")
    ok = (lower < value if open_lower else lower <= value) and value <= upper
    if not ok:
        bracket = "(" if open_lower else "["
        raise _fail(where, field, f"= {value!r} outside {bracket}{lower:g}, {upper:g}]")
    return float(value)


def _pose(where: str, field: str, table, machine) -> CranePose:
    if not isinstance(table, dict):
        raise _fail(where, field, f"must be a table with {', '.join(_POSE_FIELDS)}")
    unknown = sorted(set(table) - set(_POSE_FIELDS))
    missing = [k for k in _POSE_FIELDS if k not in table]
    if unknown or missing:
        raise _fail(where, field, f"must have exactly {', '.join(_POSE_FIELDS)} "
                                  f"(unknown: {unknown}, missing: {missing})")
    values = [_number(where, f"{field}.{k}", table[k], -360.0, 360.0) for k in _POSE_FIELDS]
    pose = CranePose(*values)
    try:
        q = pose.coordinates(machine)
    except ModelError as exc:
        raise _fail(where, field, f"is not a pose the crane can take: {exc}") from None
    lo, hi = machine.coordinates.lower[5], machine.coordinates.upper[5]
    if not lo <= q[3] <= hi:
        raise _fail(where, f"{field}.telescope", f"= {q[3]:g} m outside [{lo:g}, {hi:g}] m")
    return pose


def scenario_from_dict(data: dict, where: str = "scenario") -> ClosedLoopScenario:
    """A validated `ClosedLoopScenario` from the parsed TOML table (format: module docstring).

    Raises:
        ScenarioFileError: A field is unknown, missing, of the wrong type or out of range
            (the message names it and the valid range).
    """
    if not isinstance(data, dict):
        raise ScenarioFileError(f"{where}: a scenario is a TOML table")
    unknown = sorted(set(data) - _TOP)
    if unknown:
        raise ScenarioFileError(f"{where}: unknown field(s) {unknown}; valid: {sorted(_TOP)}")
    name = data.get("name")
    if not isinstance(name, str) or not _NAME.match(name):
        raise _fail(where, "name", f"must be 1-64 letters, digits, '-' or '_', got {name!r}")
    description = data.get("description", "")
    if not isinstance(description, str):
        raise _fail(where, "description", "must be a string")
    if "duration" not in data:
        raise _fail(where, "duration", "is required (seconds, in (1, 3600])")
    kw = {}
    for field, (lo, hi, default) in _RANGES.items():
        kw[field] = _number(where, field, data.get(field, default), lo, hi,
                            open_lower=field == "duration")
    for field, default in _TIMES.items():
        kw[field] = _number(where, field, data.get(field, default), 0.0, kw["duration"])
    machine = build_reference_machine()
    start_pose = (_pose(where, "start_pose", data["start_pose"], machine)
                  if "start_pose" in data else TRANSPORT)
    goals = data.get("goals")
    if not isinstance(goals, list) or not goals:
        raise _fail(where, "goals", "must be one or more [[goals]] tables")
    poses = tuple(_pose(where, f"goals[{i}]", g, machine) for i, g in enumerate(goals))
    event = None
    if "payload_event" in data:
        ev = data["payload_event"]
        if not isinstance(ev, dict) or set(ev) != {"time", "mass"}:
            raise _fail(where, "payload_event", "must be a table with exactly time, mass")
        event = (_number(where, "payload_event.time", ev["time"], 0.0, kw["duration"]),
                 _number(where, "payload_event.mass", ev["mass"], 0.0, 500.0))
    start = data.get("start", [0.0, 0.0, 0.0])
    if not isinstance(start, list) or len(start) != 3:
        raise _fail(where, "start", f"must be [x, y, heading], got {start!r}")
    start = (_number(where, "start[0]", start[0], -10.0, 10.0),
             _number(where, "start[1]", start[1], -10.0, 10.0),
             _number(where, "start[2]", start[2], -math.pi, math.pi))
    speed = data.get("crane_speed", [0.6, 0.2])
    if not isinstance(speed, list) or len(speed) != 2:
        raise _fail(where, "crane_speed", f"must be [velocity, acceleration], got {speed!r}")
    speed = (_number(where, "crane_speed[0]", speed[0], 0.0, 1.0, open_lower=True),
             _number(where, "crane_speed[1]", speed[1], 0.0, 1.0, open_lower=True))
    if kw["side_slope_deg"] == 0.0 and kw["rough_slope_deg"] == 0.0:
        raise _fail(where, "side_slope_deg", "and 'rough_slope_deg' are both 0: the closed-loop "
                                             "scenarios need a slope or rough terrain")
    return ClosedLoopScenario(name, description, kw["duration"], kw["side_slope_deg"],
                              kw["rough_slope_deg"], start_pose, poses,
                              first_goal_time=kw["first_goal_time"], dwell=kw["dwell"],
                              drive_speed=kw["drive_speed"],
                              drive_distance=kw["drive_distance"],
                              payload_mass=kw["payload_mass"], payload_event=event,
                              start=start, crane_speed=speed)


def load_scenario_file(path) -> ClosedLoopScenario:
    """Read and validate a scenario file.

    Raises:
        ScenarioFileError: The file cannot be read, is not TOML, or a field is invalid.
    """
    path = Path(path)
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as exc:
        raise ScenarioFileError(f"cannot read scenario file '{path}': {exc}") from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ScenarioFileError(f"{path}: not valid TOML: {exc}") from None
    return scenario_from_dict(data, str(path))


def _pose_toml(pose: CranePose) -> str:
    return "".join(f"{k} = {float(getattr(pose, k))!r}\n" for k in _POSE_FIELDS)


def scenario_to_toml(scenario: ClosedLoopScenario) -> str:
    """The scenario in the file format (reads back to an equal scenario)."""
    s = scenario
    lines = [f"name = {json.dumps(s.name)}", f"description = {json.dumps(s.description)}"]
    for field in ("duration", "side_slope_deg", "rough_slope_deg", "first_goal_time", "dwell",
                  "drive_speed", "drive_distance", "payload_mass"):
        lines.append(f"{field} = {float(getattr(s, field))!r}")
    lines.append(f"start = [{', '.join(repr(float(v)) for v in s.start)}]")
    lines.append(f"crane_speed = [{', '.join(repr(float(v)) for v in s.crane_speed)}]")
    text = "\n".join(lines) + "\n\n[start_pose]\n" + _pose_toml(s.start_pose)
    for g in s.goals:
        text += "\n[[goals]]\n" + _pose_toml(g)
    if s.payload_event is not None:
        text += (f"\n[payload_event]\ntime = {float(s.payload_event[0])!r}\n"
                 f"mass = {float(s.payload_event[1])!r}\n")
    return text
