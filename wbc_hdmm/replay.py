"""What a run log needs to be replayed: the machine, its terrain and the threshold.

The log's metadata say which scenario ran: a closed-loop run carries its scenario in the TOML
file format (`meta_scenario_toml`), so any scenario, built-in or from a file, replays; an
open-loop run is named (`meta_scenario`). With the terrain seed and the payload mass this
rebuilds the same MuJoCo model, whose ``qpos`` the log holds sample by sample.
"""

from __future__ import annotations

import tomllib
from pathlib import Path

import numpy as np

from models import build_reference_machine
from models.description import Machine
from models.log import LogError, load_log
from models.terrain import Terrain

__all__ = ["ReplayError", "replay_scene"]


class ReplayError(LogError):
    """A log cannot be replayed (no ``qpos``, or a scenario this version does not know)."""


def _meta(log: dict, name: str, default=None):
    key = f"meta_{name}"
    if key not in log:
        return default
    value = log[key]
    return value.item() if isinstance(value, np.ndarray) and value.ndim == 0 else value


def replay_scene(run_dir) -> tuple[dict, Machine, Terrain, float | None]:
    """(log arrays, machine, terrain, threshold [N] or None) of a run folder or log file.

    Raises:
        LogError: The log cannot be read.
        ReplayError: It holds no ``qpos`` (written before schema 2) or names an unknown
            scenario.
    """
    from scenarios.closed_loop_scenarios import SCENARIOS as CLOSED_LOOP
    from scenarios.closed_loop_scenarios import scenario_terrain
    from scenarios.openloop import SCENARIOS as OPEN_LOOP
    from scenarios.scenario_file import scenario_from_dict

    path = Path(run_dir)
    log = load_log(path)
    if "qpos" not in log:
        raise ReplayError(f"'{path}' holds no qpos (a log of schema 1); run the scenario again "
                          f"to replay it")
    name = str(_meta(log, "scenario", ""))
    seed = int(_meta(log, "seed", 0))
    toml = _meta(log, "scenario_toml")
    if toml is not None:
        terrain = scenario_terrain(scenario_from_dict(tomllib.loads(str(toml)), str(path)), seed)
    elif name in OPEN_LOOP:
        terrain = OPEN_LOOP[name].terrain(seed)
    elif name in CLOSED_LOOP:
        terrain = scenario_terrain(CLOSED_LOOP[name], seed)
    else:
        raise ReplayError(f"'{path}': unknown scenario {name!r}; known: "
                          f"{', '.join(sorted(OPEN_LOOP) + sorted(CLOSED_LOOP))}")
    machine = build_reference_machine(payload_mass=float(_meta(log, "payload_mass", 150.0)))
    threshold = _meta(log, "threshold")
    return log, machine, terrain, None if threshold is None else float(threshold)
