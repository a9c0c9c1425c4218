"""Placing the machine on a terrain.

The base pose that rests every wheel on the ground, and the ``home`` keyframe.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.optimize import least_squares

from models.description import Machine
from models.errors import PlacementError, StateError
from models.mujoco.elements import body_poses_in_fb, dfs_bodies, quat
from models.mujoco.servos import gravity_loads, servo_limits
from models.rotations import rpy_rotation
from models.terrain import Terrain


def place_on_terrain(machine: Machine, terrain: Terrain, q_ind=None,
                     base_xy_yaw=(0.0, 0.0, 0.0)) -> tuple[np.ndarray, np.ndarray]:
    """Base pose that sets the wheels on the terrain, touching without penetration.

    The base keeps the requested x, y and heading; its height, roll and pitch are fitted by
    least squares so that each wheel sphere's clearance to the terrain plane under its centre is
    zero; the base is then raised until no wheel penetrates. On uneven ground a wheel may hang
    a little above it (the simulator lets the machine settle).

    Args:
        machine: The machine description.
        terrain: The ground.
        q_ind: Independent coordinates, shape (13,); `TreeCoordinates.home` if None.
        base_xy_yaw: Base (x [m], y [m], heading [rad]) in the world.

    Returns:
        (fb origin in the world [m] (3,), rotation world <- fb (3, 3)).

    Raises:
        PlacementError: The wheels are off the terrain or the fit fails.
    """
    coords = machine.coordinates
    q_ind = coords.home() if q_ind is None else q_ind
    try:
        x, y, yaw = (float(v) for v in base_xy_yaw)
    except (TypeError, ValueError) as exc:
        raise PlacementError(f"base_xy_yaw must be (x, y, yaw), got {base_xy_yaw!r}") from exc
    if not all(map(math.isfinite, (x, y, yaw))):
        raise PlacementError(f"base_xy_yaw must be finite, got {base_xy_yaw!r}")
    if not terrain.contains(x, y):
        raise PlacementError(f"base (x, y) = ({x:g}, {y:g}) m is off terrain '{terrain.name}' "
                             f"(x in {terrain.x_range} m, y in {terrain.y_range} m)")
    poses = body_poses_in_fb(machine, coords.joint_positions(q_ind))
    wheels_in_fb = np.array([poses[w][1] for w in machine.wheels])
    radius = machine.wheel_radius

    def clearance(z: float, roll: float, pitch: float) -> np.ndarray:
        centres = np.array([x, y, z]) + wheels_in_fb @ rpy_rotation(yaw, pitch, roll).T
        if not np.all(terrain.contains(centres[:, 0], centres[:, 1])):
            raise PlacementError(f"a wheel at base (x, y) = ({x:g}, {y:g}) m is off terrain "
                                 f"'{terrain.name}'")
        h = terrain.height(centres[:, 0], centres[:, 1])
        nz = terrain.normal(centres[:, 0], centres[:, 1])[:, 2]
        return (centres[:, 2] - h) * nz - radius  # exact for a locally planar terrain

    z0 = float(terrain.height(x, y)) - float(wheels_in_fb[:, 2].mean()) + radius
    fit = least_squares(lambda p: clearance(*p), np.array([z0, 0.0, 0.0]), xtol=1e-12,
                        ftol=1e-12, gtol=1e-12)
    if not fit.success:
        raise PlacementError(f"placing the machine on terrain '{terrain.name}' failed: "
                             f"{fit.message}")
    z, roll, pitch = fit.x
    for _ in range(5):  # lift until no wheel penetrates (the normals may change as it rises)
        lowest = float(clearance(z, roll, pitch).min())
        if lowest >= -1e-9:
            break
        z -= lowest * 1.001
    return np.array([x, y, z]), rpy_rotation(yaw, pitch, roll)


def home_keyframe(machine: Machine, terrain: Terrain, q_ind=None,
                  base_xy_yaw=(0.0, 0.0, 0.0)) -> tuple[np.ndarray, np.ndarray]:
    """(qpos, ctrl) of the machine placed on the terrain with its chains closed.

    Args:
        machine: The machine description.
        terrain: The ground.
        q_ind: Independent coordinates, shape (13,); `TreeCoordinates.home` if None.
        base_xy_yaw: Base (x [m], y [m], heading [rad]) in the world.

    Returns:
        qpos in MuJoCo order (free joint position and quaternion, then the tree joints in
        depth-first body order), and ctrl, shape (13,): the nine servo setpoints (the
        strokes plus the static servo deflection under gravity), then zero wheel speeds.
    """
    coords = machine.coordinates
    q_ind = coords.home() if q_ind is None else np.asarray(q_ind, float)
    q_tree = coords.joint_positions(q_ind)  # checks shape, finiteness and chain strokes
    servos = servo_limits(machine)
    for sp, q in zip(servos, q_ind):
        lo, hi = sp["stroke_range"]
        if not lo - 1e-12 <= q <= hi + 1e-12:
            raise StateError(f"independent coordinate '{sp['name']}' = {q:.6g} outside its "
                             f"range [{lo:.6g}, {hi:.6g}]")
    position, rotation = place_on_terrain(machine, terrain, q_ind, base_xy_yaw)
    q_of = dict(zip(machine.moving_joints, q_tree))
    joints = [q_of[n] for n in dfs_bodies(machine) if n in q_of]
    qpos = np.concatenate([position, quat(rotation), joints])
    # Servo setpoints preloaded by the static load, u = x + tau / kp, so that the machine
    # starts in equilibrium instead of first sagging by the servo deflection.
    loads = gravity_loads(machine, q_ind, rotation)[:len(servos)]
    setpoints = q_ind[:len(servos)] + loads / np.array([sp["kp"] for sp in servos])
    return qpos, np.concatenate([setpoints, np.zeros(len(machine.wheels))])
