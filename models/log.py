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
import subprocess
import zipfile
from dataclasses import dataclass
from importlib import metadata
from pathlib import Path

import numpy as np

from models.errors import ModelError
from models.state import MachineState, WheelContacts

__all__ = ["COLUMNS", "META", "SCHEMA_VERSION", "SETTLE_SECONDS", "Column", "LogError",
           "ScenarioLog", "load_log", "state_at"]

SCHEMA_VERSION = 2  # 1: the unversioned logs before the schema; 2: this table, qpos/qvel


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

    def __len__(self) -> int:
        return len(self._rows.get("time", []))

    def append(self, state: MachineState, contacts: WheelContacts, command: np.ndarray,
               closure_violation: float, **columns) -> None:
        """Record one sample (state, ground-truth contacts, command sent, closure gap).

        Further keyword arguments are further columns of the log (one value per sample),
        names from `COLUMNS`.

        Raises:
            LogError: A column `COLUMNS` does not know.
        """
        unknown = sorted(set(columns) - set(COLUMNS))
        if unknown:
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
            closure_violation=closure_violation,
            **columns,
        )
        for k, v in row.items():
            self._rows.setdefault(k, []).append(np.array(v, copy=True))

    def arrays(self) -> dict[str, np.ndarray]:
        """The samples stacked along a leading time axis."""
        out = {k: np.stack(v) for k, v in self._rows.items()}
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


def load_log(path: str | Path) -> dict[str, np.ndarray]:
    """Load a log written by `ScenarioLog.save` into a dict of arrays.

    Logs without a schema version (written before it) load as version 1.

    Raises:
        LogError: No file, not a readable ``.npz`` (truncated, foreign, pickled objects), a
            required key missing, or a schema newer than `SCHEMA_VERSION`.
    """
    path = Path(path)
    if path.is_dir():
        path = path / "log.npz"
    if not path.is_file():
        raise LogError(f"no scenario log at '{path}' (expected a log.npz or its folder)")
    try:
        with np.load(path, allow_pickle=False) as f:
            log = {k: f[k] for k in f.files}
    except (zipfile.BadZipFile, ValueError, OSError, EOFError, KeyError) as exc:
        raise LogError(f"'{path}' is not a readable scenario log ({type(exc).__name__}: "
                       f"{exc})") from None
    if not isinstance(log, dict):  # np.load of a plain .npy gives an array
        raise LogError(f"'{path}' is not a scenario log (an .npz archive of named arrays)")
    version = int(log.get("meta_schema_version", 1))
    if version > SCHEMA_VERSION:
        raise LogError(f"'{path}' was written with log schema {version}; this version reads "
                       f"up to {SCHEMA_VERSION}")
    missing = [k for k in REQUIRED if k not in log]
    if missing:
        raise LogError(f"'{path}' is not a scenario log: it lacks {missing}")
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
