"""Compiling the MJCF in memory (`build_model`) and writing it to disk (`write_mjcf`)."""

from __future__ import annotations

from pathlib import Path

import mujoco

from models.description import Machine
from models.errors import ModelError
from models.mujoco.constants import DEFAULT_TIMESTEP, MACHINE_FILE
from models.mujoco.mjcf import machine_xml, scene_xml
from models.terrain import Terrain, flat, ramp, rough, side_slope


def build_spec(machine: Machine, terrain: Terrain, timestep: float = DEFAULT_TIMESTEP,
               q_ind=None, base_xy_yaw=(0.0, 0.0, 0.0)) -> mujoco.MjSpec:
    """The scene as an `mujoco.MjSpec`, parsed from the same text `write_mjcf` writes.

    Args:
        machine: The machine description.
        terrain: The ground.
        timestep: Simulation timestep [s].
        q_ind: Independent coordinates of the home keyframe; `TreeCoordinates.home` if None.
        base_xy_yaw: Base (x [m], y [m], heading [rad]) of the home keyframe.
    """
    scene, files = scene_xml(machine, terrain, q_ind, base_xy_yaw)
    include = {MACHINE_FILE: machine_xml(machine, timestep).encode()}
    return mujoco.MjSpec.from_string(scene, include=include, assets=files)


def build_model(machine: Machine, terrain: Terrain,
                timestep: float = DEFAULT_TIMESTEP) -> mujoco.MjModel:
    """Compile the machine on the terrain. Keyframe 0 is ``home``.

    Args:
        machine: The machine description.
        terrain: The ground.
        timestep: Simulation timestep [s]; at most 5 ms (the contact time constant spans
            two steps), and the servos limit it further (`servo_specs`).

    Returns:
        The compiled model.
    """
    return build_spec(machine, terrain, timestep).compile()


def default_terrains() -> tuple[Terrain, ...]:
    """The terrains of the standard scenes: flat, rough (seed 0), 20 deg ramp, 15 deg side slope."""
    return (flat(), rough(seed=0), ramp(20.0), side_slope(15.0))


def write_mjcf(machine: Machine, directory, timestep: float = DEFAULT_TIMESTEP,
               terrains=None) -> dict[str, Path]:
    """Write ``machine.xml`` and one ``scene_<terrain>.xml`` per terrain (menagerie layout).

    Args:
        machine: The machine description.
        directory: Output folder (created if missing).
        timestep: Simulation timestep [s].
        terrains: Terrains to write scenes for; `default_terrains` if None. Names must differ.

    Returns:
        ``{"machine": path, "<terrain name>": scene path, ...}``.
    """
    terrains = default_terrains() if terrains is None else tuple(terrains)
    names = [t.name for t in terrains]
    if len(set(names)) != len(names):
        raise ModelError(f"terrain names must be unique, got {names}")
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    out = {"machine": directory / MACHINE_FILE}
    out["machine"].write_text(machine_xml(machine, timestep))
    for terrain in terrains:
        text, files = scene_xml(machine, terrain)
        for rel, data in files.items():
            (directory / rel).parent.mkdir(parents=True, exist_ok=True)
            (directory / rel).write_bytes(data)
        out[terrain.name] = directory / f"scene_{terrain.name}.xml"
        out[terrain.name].write_text(text)
    return out
