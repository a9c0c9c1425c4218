"""Run logs: the versioned schema, writing (`ScenarioLog`) and reading (`load_log`).

The log schema lives in `models` so that both the scenarios (which write logs) and the
estimators' evaluation (which reads them) can use it without importing each other.

A log is a compressed ``.npz`` of arrays sampled at the log rate, first axis time. `COLUMNS`
is the one source of truth of its keys: shape (N samples first), unit and meaning of each;
`META` lists the run's scalars, stored as 0-d arrays under ``meta_<name>``. Per-wheel axes are
ordered FL, RL, FR, RR (paper eq. 1). `ScenarioLog` refuses a key the schema does not know
and writes the schema version, the package version and the git commit; `load_log` refuses a
missing, truncated or foreign file and a newer schema with one clear `LogError`.
"""

from __future__ import annotations

import functools
import os
import pickle
import subprocess
import zipfile
from dataclasses import dataclass
from importlib import metadata
from pathlib import Path

import numpy as np

from models.errors import ModelError
from models.state import MachineState, WheelContacts

__all__ = ["COLUMNS", "META", "OBSERVED_COLUMNS", "OBSERVED_SUITES", "PHYSICS_COLUMNS",
           "SCHEMA_VERSION", "SETTLE_SECONDS", "Column", "LogError", "ScenarioLog", "check_log",
           "load_log", "state_at"]

# 1: the unversioned logs before the schema; 2: this table, qpos/qvel; 3: `PHYSICS_COLUMNS`
SCHEMA_VERSION = 3


class LogError(ModelError, ValueError):
    """A run log is missing, unreadable, not a log, or written by a newer schema."""


@dataclass(frozen=True)
class Column:
    """One key of a run log.

    Attributes:
        shape: Shape with N the number of samples (``nq``, ``nv``: MuJoCo's model sizes).
        unit: Unit in brackets notation, ``-`` when none.
        meaning: What it is.
        closed_loop: Written by closed-loop runs only.
    """

    shape: str
    unit: str
    meaning: str
    closed_loop: bool = False


COLUMNS = {
    "time": Column("(N,)", "s", "simulation time of the measured instant"),
    "base_position": Column("(N, 3)", "m", "fb origin in the world"),
    "base_rotation": Column("(N, 3, 3)", "-", "rotation world <- fb"),
    "base_twist": Column("(N, 6)", "m/s, rad/s", "body twist [v; w] of fb in fb"),
    "base_acceleration": Column("(N, 6)", "m/s^2, rad/s^2", "time derivative of the twist"),
    "q": Column("(N, 13)", "m, rad", "independent coordinates (models.coordinates)"),
    "qd": Column("(N, 13)", "m/s, rad/s", "their velocities"),
    "qdd": Column("(N, 13)", "m/s^2, rad/s^2", "their accelerations"),
    "command": Column("(N, 11)", "m/s, rad/s", "commands sent: 9 stroke/joint rates, 2 wheel "
                                               "speeds (left, right)"),
    "force_in_fb": Column("(N, 4, 3)", "N", "ground force on each wheel in fb axes (truth)"),
    "point_in_fb": Column("(N, 4, 3)", "m", "contact point of each wheel in fb (truth)"),
    "normal_in_fb": Column("(N, 4, 3)", "-", "terrain normal at each contact in fb axes"),
    "in_contact": Column("(N, 4)", "-", "contact flags (truth)"),
    "normal_force": Column("(N, 4)", "N", "ground truth: force along the terrain normal"),
    "fz_in_fb": Column("(N, 4)", "N", "ground truth: force along fb z (the paper's f_z)"),
    "suspension_force": Column("(N, 2)", "N", "suspension cylinder forces L, R; NaN if none"),
    "closure_violation": Column("(N,)", "m", "largest loop-point gap of the closed chains"),
    "qpos": Column("(N, nq)", "m, rad, -", "MuJoCo's qpos of the measured instant (replay)"),
    "qvel": Column("(N, nv)", "m/s, rad/s", "MuJoCo's qvel of the measured instant"),
    "tcp_error": Column("(N,)", "m", "tool point distance to the current goal", True),
    "goal_index": Column("(N,)", "-", "index of the goal being given", True),
    "last_goal_given": Column("(N,)", "-", "the last goal has been given", True),
    "distance": Column("(N,)", "m", "base distance driven along the start heading", True),
    "speed_scale": Column("(N,)", "-", "wheel-speed scale the controller applied", True),
    "fallback": Column("(N,)", "-", "the controller took its safe action this tick", True),
    "step_ms": Column("(N,)", "ms", "wall time of the controller's step", True),
    "measured_forces": Column("(N, 4)", "N", "the MPC's measured load split (NaN if none)",
                              True),
    "payload_now": Column("(N,)", "kg", "payload mass held by the machine", True),
    "payload_estimate": Column("(N,)", "kg", "payload the controller assumed (estimate)", True),
    "force_margin": Column("(N, 4)", "N", "uncertainty margin over each wheel's threshold",
                           True),
    "observer_ms": Column("(N,)", "ms", "wall time of the observer's update", True),
    "com_world": Column("(N, 3)", "m", "ground truth: the machine's centre of mass in the world",
                        True),
}

# What the observer made of the sensors, per suite (open-loop runs record every suite beside
# the truth, so the estimators can be scored on each: `estimators.evaluate_sensors`).
OBSERVED_SUITES = ("ideal", "realistic")
_OBSERVED_FIELDS = {
    "base_rotation": ("(N, 3, 3)", "-", "rotation world <- fb"),
    "base_twist": ("(N, 6)", "m/s, rad/s", "twist"),
    "base_acceleration": ("(N, 6)", "m/s^2, rad/s^2", "twist derivative (the dynamics' input)"),
    "q": ("(N, 13)", "m, rad", "independent coordinates"),
    "qd": ("(N, 13)", "m/s, rad/s", "their velocities"),
    "qdd": ("(N, 13)", "m/s^2, rad/s^2", "their accelerations"),
    "in_contact": ("(N, 4)", "-", "contact flags"),
    "point_in_fb": ("(N, 4, 3)", "m", "contact points"),
    "force_in_fb": ("(N, 4, 3)", "N", "ground forces known to the observer (traction)"),
    "suspension_force": ("(N, 2)", "N", "suspension cylinder forces from the pressures"),
    "servo_setpoint": ("(N, 9)", "m, rad", "the servos' setpoints"),
    "payload": ("(N,)", "kg", "payload estimate"),
    "payload_std": ("(N,)", "kg", "its standard deviation"),
}
OBSERVED_COLUMNS = {
    f"obs_{suite}_{field}": Column(shape, unit, f"observer, {suite} sensors: {meaning}")
    for suite in OBSERVED_SUITES for field, (shape, unit, meaning) in _OBSERVED_FIELDS.items()}
COLUMNS.update(OBSERVED_COLUMNS)
COLUMNS["servo_setpoint"] = Column("(N, 9)", "m, rad", "the nine axis servos' setpoints")

# Sampled at every physics step (M samples, M >= N): what a control-rate sample misses (a
# 2-4 ms drop of a wheel's force to 0 N). Written by runs that count metrics at that rate.
PHYSICS_COLUMNS = {
    "physics_time": Column("(M,)", "s", "time of every physics step's starting instant"),
    "physics_normal_force": Column("(M, 4)", "N", "ground truth: each wheel's normal contact "
                                                  "force summed over its contacts"),
}

META = {
    "schema_version": "log schema version (`SCHEMA_VERSION`)",
    "package_version": "wbc-hdmm version that wrote the log",
    "git_commit": "git commit of the source tree that wrote the log, or 'unknown'",
    "scenario": "scenario name",
    "scenario_toml": "closed loop: the scenario in the TOML file format (replays any run)",
    "controller": "closed loop: controller name",
    "seed": "terrain seed",
    "payload_mass": "payload at the start [kg]",
    "timestep": "physics timestep [s]",
    "control_period": "closed loop: control period [s]",
    "terrain": "terrain name",
    "threshold": "closed loop: normal-force threshold [N]",
    "delay_periods": "closed loop: measurement delay [control periods]",
}
REQUIRED = ("time", "base_position", "base_rotation", "base_twist", "base_acceleration", "q",
            "qd", "qdd", "in_contact", "normal_force", "fz_in_fb")


@functools.cache
def _provenance() -> tuple[str, str]:
    """(package version, git commit) of the running source tree."""
    try:
        version = metadata.version("wbc-hdmm")
    except metadata.PackageNotFoundError:
        version = "unknown"
    try:
        out = subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True,
                             timeout=5, cwd=Path(__file__).resolve().parent)
        commit = out.stdout.strip() if out.returncode == 0 else "unknown"
    except (OSError, subprocess.SubprocessError):
        commit = "unknown"
    return version, commit or "unknown"

SETTLE_SECONDS = 1.0  # [s] metrics and scores skip a log's first second (the machine settles)

_SCALARS = frozenset((float, int, bool, np.float64, np.int64, np.bool_))
_STATE_KEYS = ("base_position", "base_rotation", "base_twist", "base_acceleration", "q", "qd",
               "qdd")


class ScenarioLog:
    """Accumulates samples in memory and writes them as one compressed ``.npz``.

    Args:
        **meta: The run's scalars, names from `META`.

    Raises:
        LogError: A name `META` does not know.
    """

    def __init__(self, **meta):
        unknown = sorted(set(meta) - set(META))
        if unknown:
            raise LogError(f"unknown log metadata {unknown}; valid: {sorted(META)}")
        self.meta = meta
        self._rows: dict[str, list] = {}
        self._columns: dict[str, np.ndarray] = {}
        self.physics: dict[str, np.ndarray] = {}

    def __len__(self) -> int:
        if "time" in self._columns:
            return len(self._columns["time"])
        return len(self._rows.get("time", []))

    def append(self, state: MachineState, contacts: WheelContacts, command: np.ndarray,
               closure_violation: float, **columns) -> None:
        """Record one sample (state, ground-truth contacts, command sent, closure gap).

        Further keyword arguments are further columns of the log (one value per sample),
        names from `COLUMNS`.

        Raises:
            LogError: A column `COLUMNS` does not know.
        """
        if not columns.keys() <= COLUMNS.keys():
            unknown = sorted(set(columns) - set(COLUMNS))
            raise LogError(f"unknown log column(s) {unknown}; the schema (models.log.COLUMNS) "
                           f"has {sorted(COLUMNS)}")
        row = {k: getattr(state, k) for k in _STATE_KEYS}
        row.update(
            time=state.time,
            command=np.asarray(command, float),
            force_in_fb=contacts.force_in_fb,
            point_in_fb=contacts.point_in_fb,
            normal_in_fb=contacts.normal_in_fb,
            in_contact=contacts.in_contact,
            normal_force=contacts.normal_force,
            fz_in_fb=contacts.fz_in_fb,
            suspension_force=(state.suspension_force if state.suspension_force is not None
                              else np.full(2, np.nan)),
            servo_setpoint=(state.servo_setpoint if state.servo_setpoint is not None
                            else np.full(9, np.nan)),
            closure_violation=closure_violation,
            **columns,
        )
        rows = self._rows
        for k, v in row.items():
            # Scalars are immutable: kept as they are, `arrays` makes them the same 0-d arrays.
            v = v if type(v) in _SCALARS else np.array(v, copy=True)
            column = rows.get(k)
            if column is None:
                rows[k] = [v]
            else:
                column.append(v)

    def set_columns(self, **columns) -> None:
        """Attach whole columns (names from `COLUMNS`), the samples along the first axis.

        For a run that fills arrays of its own in place, row by row (`scenarios.closed_loop`):
        they are kept as given (not copied) and stand for `append`'s rows of their names.

        Raises:
            LogError: A name `COLUMNS` does not know, or columns of different lengths.
        """
        unknown = sorted(set(columns) - set(COLUMNS))
        if unknown:
            raise LogError(f"unknown log column(s) {unknown}; the schema (models.log.COLUMNS) "
                           f"has {sorted(COLUMNS)}")
        self._columns.update(columns)
        lengths = {len(v) for v in self._columns.values()}
        if len(lengths) > 1:
            raise LogError(f"log columns of different lengths {sorted(lengths)}")

    def set_physics(self, **columns) -> None:
        """Attach the physics-rate arrays (names from `PHYSICS_COLUMNS`).

        Raises:
            LogError: A name `PHYSICS_COLUMNS` does not know.
        """
        unknown = sorted(set(columns) - set(PHYSICS_COLUMNS))
        if unknown:
            raise LogError(f"unknown physics-rate column(s) {unknown}; valid: "
                           f"{sorted(PHYSICS_COLUMNS)}")
        self.physics.update({k: np.asarray(v) for k, v in columns.items()})

    def arrays(self) -> dict[str, np.ndarray]:
        """The samples stacked along a leading time axis (and the physics-rate arrays)."""
        out = {k: np.stack(v) for k, v in self._rows.items() if k not in self._columns}
        out.update(self._columns)
        out.update(self.physics)
        version, commit = _provenance()
        meta = {"schema_version": SCHEMA_VERSION, "package_version": version,
                "git_commit": commit, **self.meta}
        out.update({f"meta_{k}": np.asarray(v) for k, v in meta.items()})
        return out

    def save(self, path: str | Path) -> Path:
        """Write the log as compressed npz; returns the path."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        np.savez_compressed(path, **self.arrays())
        return path


def _shape_tokens(column: Column) -> tuple[str, ...]:
    """The documented shape as tokens, e.g. ``("N", "4", "3")`` for ``"(N, 4, 3)"``."""
    return tuple(t.strip() for t in column.shape.strip("()").split(",") if t.strip())


def check_log(log: dict[str, np.ndarray], source: str = "log") -> int:
    """Check a log's arrays against the schema; returns the number of samples N.

    Every key of `COLUMNS` present must be a numeric or boolean array of its documented
    shape (``nq``, ``nv``: any size); `REQUIRED` keys must be present; ``time`` must be
    finite and hold at least one sample. Keys the schema does not know are left alone (a
    newer minor writer may add columns).

    Args:
        log: Arrays by key, as `load_log` returns them.
        source: What to call the log in messages (its path).

    Returns:
        N, the number of samples.

    Raises:
        LogError: A required key missing, a column of the wrong shape or type, or no samples.
    """
    missing = [k for k in REQUIRED if k not in log]
    if missing:
        raise LogError(f"'{source}' is not a scenario log: it lacks {missing}")
    time = np.asarray(log["time"])
    if time.ndim != 1 or time.shape[0] == 0:
        raise LogError(f"'{source}': key 'time' must have shape (N,) with N >= 1, got "
                       f"{time.shape}")
    n = time.shape[0]
    for key, column in COLUMNS.items():
        if key not in log:
            continue
        a = np.asarray(log[key])
        tokens = _shape_tokens(column)
        ok = a.dtype.kind in "biuf" and a.ndim == len(tokens) and a.shape[0] == n and all(
            t in ("nq", "nv") or int(t) == d for t, d in zip(tokens[1:], a.shape[1:]))
        if not ok:
            raise LogError(f"'{source}': key '{key}' must be a numeric array of shape "
                           f"{column.shape} with N = {n}, got shape {a.shape} of "
                           f"{a.dtype}")
    if not np.all(np.isfinite(time.astype(float))):
        raise LogError(f"'{source}': key 'time' holds NaN or inf")
    if "physics_time" in log:
        m = np.asarray(log["physics_time"]).shape[0] if np.ndim(log["physics_time"]) else -1
        for key, column in PHYSICS_COLUMNS.items():
            a = np.asarray(log.get(key, np.zeros(0)))
            tokens = _shape_tokens(column)
            if not (a.dtype.kind in "biuf" and a.ndim == len(tokens) and a.shape[0] == m
                    and all(int(t) == d for t, d in zip(tokens[1:], a.shape[1:]))):
                raise LogError(f"'{source}': key '{key}' must be a numeric array of shape "
                               f"{column.shape} with M = {m}, got shape {a.shape}")
    return n


def load_log(path: str | Path) -> dict[str, np.ndarray]:
    """Load a log written by `ScenarioLog.save` into a dict of arrays.

    Logs without a schema version (written before it) load as version 1. The arrays are
    checked against the schema (`check_log`).

    Args:
        path: A ``log.npz`` or the run folder holding it.

    Raises:
        LogError: ``path`` not a path, no file, not a readable ``.npz`` (truncated, foreign,
            pickled objects), a schema version that is not an integer or is newer than
            `SCHEMA_VERSION`, a required key missing or a column of the wrong shape.
    """
    if not isinstance(path, (str, os.PathLike)):
        raise LogError(f"log path must be a str or os.PathLike, got {type(path).__name__}")
    path = Path(path)
    if path.is_dir():
        path = path / "log.npz"
    if not path.is_file():
        raise LogError(f"no scenario log at '{path}' (expected a log.npz or its folder)")
    try:
        with np.load(path, allow_pickle=False) as f:
            log = {k: f[k] for k in f.files}
    except (zipfile.BadZipFile, ValueError, OSError, EOFError, KeyError,
            pickle.UnpicklingError) as exc:
        raise LogError(f"'{path}' is not a readable scenario log ({type(exc).__name__}: "
                       f"{exc})") from None
    except (TypeError, AttributeError):  # np.load of a plain .npy gives a bare array
        raise LogError(f"'{path}' is not a scenario log (an .npz archive of named arrays)"
                       ) from None
    raw = log.get("meta_schema_version", np.asarray(1))
    if raw.ndim != 0 or raw.dtype.kind not in "iu":
        raise LogError(f"'{path}': meta_schema_version must be an integer in [1, "
                       f"{SCHEMA_VERSION}], got {raw!r}")
    version = int(raw)
    if version > SCHEMA_VERSION:
        raise LogError(f"'{path}' was written with log schema {version}; this version reads "
                       f"up to {SCHEMA_VERSION}")
    if version < 1:
        raise LogError(f"'{path}': meta_schema_version must be an integer in [1, "
                       f"{SCHEMA_VERSION}], got {version}")
    check_log(log, str(path))
    return log


def state_at(log: dict[str, np.ndarray], i: int, with_contacts: bool = True) -> MachineState:
    """The `MachineState` of sample ``i`` of a log, with the measured contacts attached."""
    contacts = None
    if with_contacts:
        contacts = WheelContacts(log["in_contact"][i], log["force_in_fb"][i],
                                 log["point_in_fb"][i], log["normal_in_fb"][i])
    susp = log["suspension_force"][i]
    return MachineState(
        base_position=log["base_position"][i], base_rotation=log["base_rotation"][i],
        base_twist=log["base_twist"][i], base_acceleration=log["base_acceleration"][i],
        q=log["q"][i], qd=log["qd"][i], qdd=log["qdd"][i], time=float(log["time"][i]),
        contacts=contacts, suspension_force=None if np.any(np.isnan(susp)) else susp,
    )
