"""Run logs: states, commands, ground-truth wheel forces, contact flags.

The log schema lives in `models` so that both the scenarios (which write logs) and the
estimators' evaluation (which reads them) can use it without importing each other.

A log is a compressed ``.npz`` of arrays sampled at the log rate, first axis time:

=====================  ==============  ==================================================
key                    shape           meaning
=====================  ==============  ==================================================
time                   (N,)            simulation time [s]
base_position          (N, 3)          fb origin in the world [m]
base_rotation          (N, 3, 3)       rotation world <- fb
base_twist             (N, 6)          body twist [v; w] of fb in fb [m/s, rad/s]
base_acceleration      (N, 6)          its time derivative [m/s^2, rad/s^2]
q, qd, qdd             (N, 13)         independent coordinates (`models.coordinates`)
command                (N, 11)         commands sent: 9 stroke/joint rates, 2 wheel speeds
force_in_fb            (N, 4, 3)       ground force on each wheel in fb axes [N]
point_in_fb            (N, 4, 3)       contact point of each wheel in fb [m]
normal_in_fb           (N, 4, 3)       terrain normal at the contact in fb axes
in_contact             (N, 4)          contact flags
normal_force           (N, 4)          ground truth: force along the terrain normal [N]
fz_in_fb               (N, 4)          ground truth: force along fb z (the paper's f_z) [N]
suspension_force       (N, 2)          suspension cylinder forces, L, R [N]
closure_violation      (N,)            largest loop-point gap [m]
=====================  ==============  ==================================================

Per-wheel axes are ordered FL, RL, FR, RR (paper eq. 1). Scalars (scenario name, payload
mass, timestep) are stored as 0-d arrays under ``meta_*`` keys.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from models.state import MachineState, WheelContacts

SETTLE_SECONDS = 1.0  # [s] metrics and scores skip a log's first second (the machine settles)

_STATE_KEYS = ("base_position", "base_rotation", "base_twist", "base_acceleration", "q", "qd",
               "qdd")


class ScenarioLog:
    """Accumulates samples in memory and writes them as one compressed ``.npz``."""

    def __init__(self, **meta):
        self.meta = meta
        self._rows: dict[str, list] = {}

    def __len__(self) -> int:
        return len(self._rows.get("time", []))

    def append(self, state: MachineState, contacts: WheelContacts, command: np.ndarray,
               closure_violation: float, **columns) -> None:
        """Record one sample (state, ground-truth contacts, command sent, closure gap).

        Further keyword arguments are extra columns of the log (one value per sample).
        """
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
        out.update({f"meta_{k}": np.asarray(v) for k, v in self.meta.items()})
        return out

    def save(self, path: str | Path) -> Path:
        """Write the log as compressed npz; returns the path."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        np.savez_compressed(path, **self.arrays())
        return path


def load_log(path: str | Path) -> dict[str, np.ndarray]:
    """Load a log written by `ScenarioLog.save` into a dict of arrays."""
    path = Path(path)
    if path.is_dir():
        path = path / "log.npz"
    if not path.exists():
        raise FileNotFoundError(f"no scenario log at '{path}' (expected a log.npz or its folder)")
    with np.load(path) as f:
        return {k: f[k] for k in f.files}


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
