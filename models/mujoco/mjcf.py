"""MJCF text of the machine (``machine.xml``) and of a scene (``scene_<terrain>.xml``)."""

from __future__ import annotations

import struct
import xml.etree.ElementTree as ET

import numpy as np

from models.description import Machine
from models.mujoco.constants import (
    CONTACT_IMPRATIO,
    CONTACT_SOLIMP,
    CONTACT_SOLREF,
    DEFAULT_TIMESTEP,
    EQUALITY_SOLIMP,
    EQUALITY_SOLREF_STEPS,
    MACHINE_FILE,
    SOLVER_TOLERANCE,
    TERRAIN_BASE_DEPTH,
    WHEEL_VELOCITY_GAIN,
    check_timestep,
)
from models.mujoco.elements import add_body, chain_loop, children_of, fmt, pretty, root_body
from models.mujoco.placement import home_keyframe
from models.mujoco.servos import servo_specs
from models.terrain import Terrain


def _actuator_elements(machine: Machine, timestep: float) -> list[tuple[str, dict]]:
    """MJCF actuator elements, one per independent coordinate, in independent order."""
    elements = []
    for sp in servo_specs(machine, timestep):
        common = {"class": "machine", "name": sp.name, "forcerange": fmt(sp.force_range)}
        if sp.tendon is not None:
            # F = kp (u - x) with x = L - offset: the stroke read off the pin-to-pin length.
            elements.append(("general", dict(common, tendon=sp.tendon, gaintype="fixed",
                                             gainprm=fmt(sp.kp), biastype="affine",
                                             biasprm=fmt((sp.kp * sp.offset, -sp.kp, 0.0)))))
        else:
            elements.append(("position", dict(common, joint=sp.joint, kp=fmt(sp.kp))))
    vmax, tmax = machine.wheel_drive
    for name in machine.wheels:
        elements.append(("velocity", {"class": "machine", "name": name, "joint": name,
                                      "kv": fmt(WHEEL_VELOCITY_GAIN),
                                      "ctrlrange": fmt((-vmax, vmax)),
                                      "forcerange": fmt((-tmax, tmax))}))
    return elements


def machine_xml(machine: Machine, timestep: float = DEFAULT_TIMESTEP) -> str:
    """The robot file ``machine.xml``: bodies, joints, loop closures and actuators.

    Args:
        machine: The machine description (the single source of geometry and inertia).
        timestep: Simulation timestep [s]; the loop-closure time constant follows it.

    Returns:
        MJCF text.
    """
    timestep = check_timestep(timestep)
    root_body(machine)
    root = ET.Element("mujoco", model="machine")
    ET.SubElement(root, "compiler", angle="radian", autolimits="true", inertiafromgeom="false")
    option = ET.SubElement(root, "option", timestep=fmt(timestep), integrator="implicitfast",
                           cone="elliptic", tolerance=fmt(SOLVER_TOLERANCE),
                           gravity=fmt((0.0, 0.0, -machine.gravity)),
                           impratio=fmt(CONTACT_IMPRATIO))
    ET.SubElement(option, "flag", island="disable")  # one machine: one island, 5 % faster
    defaults = ET.SubElement(ET.SubElement(root, "default"), "default", {"class": "machine"})
    ET.SubElement(defaults, "geom", contype="0", conaffinity="0")
    ET.SubElement(defaults, "equality", solref=fmt((EQUALITY_SOLREF_STEPS * timestep, 1.0)),
                  solimp=fmt(EQUALITY_SOLIMP))
    visual = ET.SubElement(defaults, "default", {"class": "visual"})
    ET.SubElement(visual, "geom", group="2", contype="0", conaffinity="0")
    collision = ET.SubElement(defaults, "default", {"class": "collision"})
    ET.SubElement(collision, "geom", group="3", contype="1", conaffinity="0", condim="3")
    sites = ET.SubElement(defaults, "default", {"class": "loop_point"})
    ET.SubElement(sites, "site", group="4", size="0.02", rgba="0.9 0.1 0.1 1")

    worldbody = ET.SubElement(root, "worldbody")
    children = children_of(machine)
    add_body(worldbody, machine, root_body(machine), children)

    equality = ET.SubElement(root, "equality")
    for loop in machine.loops:
        ET.SubElement(equality, "connect", {"name": loop.name, "class": "machine",
                                            "site1": f"{loop.name}_a",
                                            "site2": f"{loop.name}_b"})
    tendon = ET.SubElement(root, "tendon")
    for chain_name, binding in machine.chains.items():
        spatial = ET.SubElement(tendon, "spatial", name=f"{chain_name}_cylinder", width="0.01")
        ET.SubElement(spatial, "site", site=f"{chain_name}_cylinder_pivot")
        ET.SubElement(spatial, "site", site=f"{chain_loop(machine, chain_name).name}_b")
    actuator = ET.SubElement(root, "actuator")
    for tag, attrs in _actuator_elements(machine, timestep):
        ET.SubElement(actuator, tag, attrs)
    return pretty(root)


def hfield_bytes(terrain: Terrain) -> bytes:
    """MuJoCo's binary height-field format: int32 nrow, ncol, then float32 data in [0, 1]."""
    lo, hi = terrain.height_range
    data = ((terrain.heights - lo) / (hi - lo)).astype(np.float32)
    n_y, n_x = terrain.shape
    return struct.pack("<ii", n_y, n_x) + data.astype("<f4").tobytes()


def hfield_file(terrain: Terrain) -> str:
    """Asset path of a terrain's height-field file, relative to the scene file."""
    return f"assets/terrain_{terrain.name}.bin"


def scene_xml(machine: Machine, terrain: Terrain, q_ind=None,
              base_xy_yaw=(0.0, 0.0, 0.0)) -> tuple[str, dict[str, bytes]]:
    """A scene file including ``machine.xml``: ground, lights and the ``home`` keyframe.

    Args:
        machine: The machine description.
        terrain: The ground: a plane if flat, else a height field.
        q_ind: Independent coordinates of the home keyframe; `TreeCoordinates.home` if None.
        base_xy_yaw: Base (x [m], y [m], heading [rad]) of the home keyframe.

    Returns:
        (MJCF text, {relative path: bytes} of the asset files it references).
    """
    root = ET.Element("mujoco", model=f"machine on {terrain.name} terrain")
    ET.SubElement(root, "include", file=MACHINE_FILE)
    cx, cy = terrain.center_xy
    hx, hy = terrain.half_extent
    lo, hi = terrain.height_range
    ET.SubElement(root, "statistic", center="0 0 1", extent="8")
    visual = ET.SubElement(root, "visual")
    ET.SubElement(visual, "headlight", diffuse="0.6 0.6 0.6", ambient="0.3 0.3 0.3",
                  specular="0 0 0")
    ET.SubElement(visual, "rgba", haze="0.15 0.25 0.35 1")
    ET.SubElement(visual, "global", azimuth="150", elevation="-20")
    asset = ET.SubElement(root, "asset")
    ET.SubElement(asset, "texture", type="skybox", builtin="gradient", rgb1="0.3 0.5 0.7",
                  rgb2="0 0 0", width="512", height="3072")
    ET.SubElement(asset, "texture", type="2d", name="ground", builtin="checker", mark="edge",
                  rgb1="0.35 0.3 0.2", rgb2="0.3 0.25 0.17", markrgb="0.8 0.8 0.8",
                  width="300", height="300")
    ET.SubElement(asset, "material", name="ground", texture="ground", texuniform="true",
                  texrepeat="2 2", reflectance="0.05")
    files: dict[str, bytes] = {}
    geom = {"name": "terrain", "material": "ground", "contype": "0", "conaffinity": "1",
            "condim": "3", "priority": "1", "friction": fmt((terrain.friction, 0.005, 1e-4)),
            "solref": fmt(CONTACT_SOLREF), "solimp": fmt(CONTACT_SOLIMP)}
    if terrain.is_flat:
        geom.update(type="plane", pos=fmt((cx, cy, lo)), size=fmt((hx, hy, 0.05)))
    else:
        path = hfield_file(terrain)
        files[path] = hfield_bytes(terrain)
        ET.SubElement(asset, "hfield", name="terrain", file=path,
                      size=fmt((hx, hy, hi - lo, TERRAIN_BASE_DEPTH)))
        geom.update(type="hfield", hfield="terrain", pos=fmt((cx, cy, lo)))
    worldbody = ET.SubElement(root, "worldbody")
    ET.SubElement(worldbody, "light", pos="0 0 30", dir="0.2 0.3 -1", directional="true")
    ET.SubElement(worldbody, "geom", geom)
    qpos, ctrl = home_keyframe(machine, terrain, q_ind, base_xy_yaw)
    keyframe = ET.SubElement(root, "keyframe")
    ET.SubElement(keyframe, "key", name="home", qpos=fmt(qpos), ctrl=fmt(ctrl))
    return pretty(root), files
