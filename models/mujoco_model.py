"""MuJoCo model of a `Machine` on a `Terrain`, generated as MJCF and compiled through `MjSpec`.

The generator writes the menagerie layout: ``machine.xml`` (bodies, inertias, joints, loop
closures, cylinder tendons, actuators, default classes ``visual``, ``collision`` and
``loop_point``) and one ``scene_<terrain>.xml`` per terrain that includes it and adds the
ground, lights and the ``home`` keyframe (the machine placed on that ground with its chains
closed, from `TreeCoordinates.home`). `build_model` compiles exactly the same text in memory,
so the files on disk and the model used in code cannot differ. Body and joint names are the
description's; the free joint is named after the root body, actuators after the independent
coordinates they drive.

The model, and why (figures measured for the reference machine, see the tests and report):

* **Integrator** ``implicitfast``, **timestep** `DEFAULT_TIMESTEP` = 2 ms. Measured on the
  paper's open-loop scenarios: the chains stay closed to 0.015 mm; normal forces agree with a
  0.5 ms run to 1 % of the static wheel load until the trajectories part (stick-slip events
  are timing-sensitive); one step costs about 35 us. At 1 ms the scenarios run at half the
  speed for no visible gain; at 2.5 ms the explicit servo damping (below) must drop to
  ``zeta`` 0.02 and at 3 ms the stiff servos are unstable. Solver tolerance 1e-10: the
  contact forces of a state are reproducible to 1e-7 relative at no measurable cost.
* **Loop closures**: one ``connect`` equality per `Loop`, between two sites at the loop
  points (site form, so the chains need not be closed at ``qpos0``), ``solref = (2 h, 1)``
  (the stiffest MuJoCo accepts) and ``solimp = (0.99, 0.999, 1 mm)``. With MuJoCo's default
  ``solref``/``solimp`` the chains open by half a millimetre in the same scenarios.
* **Hydraulic cylinders** push along their pin-to-pin line: a spatial tendon from the base
  pivot (on the base link) to the rod eye (on the driven link), whose length is
  ``L_c0 + x + L_c``. The actuator ``F = kp (u - x)`` (``x`` read off the tendon) is clipped
  to `HydraulicCylinder.force_range`. Acting on the tendon rather than on the 10-kg piston
  joint keeps the cylinder force out of the loop constraint, which then only carries the
  piston's own inertia; the piston and barrel ride along passively.
* **Servo damping is explicit**. MuJoCo's ``implicitfast`` integrates actuator damping with
  ``M + h D`` while it solves the loop constraints with ``M``; with damping gains large
  enough to matter this mismatch opened the chains by 0.1-1 mm on rough terrain. The
  `scenarios.simulator.Simulator` therefore sets ``u = s - (kv / kp) x_dot`` before each
  step, which applies ``F = kp (s - x) - kv x_dot`` with the damping evaluated at the start of
  the step, and moves the setpoint ``s`` at the commanded rate (the valve): rate limited by
  `HydraulicCylinder.velocity_range`, kept within the stroke range and within full-force
  deflection of the stroke (anti-windup). Explicit damping is bounded by stability, so the
  crane's lift, tilt and telescope servos end up lightly damped (``zeta`` 0.04-0.08); see
  `servo_specs`. Standalone (in a viewer) ``ctrl`` is the stroke setpoint and the servos are
  undamped.
* **Telescope and wrist**: the same servo on their joints (``position`` actuators), limits
  from `Machine.direct_drives`.
* **Wheels**: ``velocity`` actuators ``tau = kv (u - omega)``, ``kv`` = `WHEEL_VELOCITY_GAIN`,
  speed and torque limits from `Machine.wheel_drive`; the simulator drives each side's pair
  with one command. ``kv`` = 5 kN m s/rad is a hydrostatic drive's speed droop (0.8 rad/s at
  full torque): with a near-rigid 20 kN m s/rad the skid-steering machine's rear wheels hop
  at the torque limit (stick-slip of the lateral scrub; 5 % contact loss on the flat run),
  which no real tyre's compliance would allow.
* **Contacts**: only the wheel spheres (class ``collision``) and the terrain collide (visual
  geoms have ``contype = conaffinity = 0``): one contact point per wheel on a plane, the
  paper's assumption. The terrain geom has ``priority = 1`` so its friction
  (`Terrain.friction`, condim 3, elliptic cone) and ``solref = (10 ms, 1)`` (critically
  damped, a nearly rigid ground like the paper's Simscape contact; a few millimetres of
  penetration under a 4.3 t machine) govern.
"""

from __future__ import annotations

import functools
import math
import struct
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np
from scipy.optimize import least_squares

from models.coordinates import N_INDEPENDENT
from models.description import Loop, Machine
from models.errors import ModelError, PlacementError, StateError
from models.terrain import Terrain, flat, ramp, rough, side_slope

__all__ = [
    "CONTACT_SOLIMP", "CONTACT_SOLREF", "DEFAULT_TIMESTEP", "EQUALITY_SOLIMP", "MujocoIndex",
    "SERVO_DAMPING_RATIO", "SERVO_POSITION_ERROR", "ServoSpec", "WHEEL_VELOCITY_GAIN",
    "body_poses_in_fb", "build_model", "build_spec", "default_terrains", "gravity_loads",
    "home_keyframe", "machine_xml", "place_on_terrain", "reflected_inertia", "scene_xml",
    "servo_specs", "write_mjcf",
]

DEFAULT_TIMESTEP = 0.002  # [s]
EQUALITY_SOLREF_STEPS = 2.0  # loop-closure time constant in timesteps (MuJoCo's minimum)
EQUALITY_SOLIMP = (0.99, 0.999, 0.001, 0.5, 2.0)
CONTACT_SOLREF = (0.01, 1.0)  # [s], [-]
CONTACT_SOLIMP = (0.9, 0.95, 0.001, 0.5, 2.0)
SERVO_POSITION_ERROR = {"slide": 2e-3, "hinge": 1e-2}  # [m], [rad] deflection at full force
SERVO_DAMPING_RATIO = 0.5  # [-] target at the locked reflected inertia (see servo_specs)
SERVO_EXPLICIT_DAMPING = 0.3  # [-] cap of h kv / m_free (one explicit damper: stable < 2)
SERVO_STABILITY_MARGIN = 1.25  # explicit damping must stay stable at this times the timestep
WHEEL_VELOCITY_GAIN = 5e3  # [N m s/rad]
SOLVER_TOLERANCE = 1e-10  # Newton converges in the same 2-4 iterations; forces repeatable
TERRAIN_BASE_DEPTH = 1.0  # [m] thickness of the height field below its lowest point
MACHINE_FILE = "machine.xml"

_JOINT_TYPE = {"revolute": "hinge", "prismatic": "slide"}


# ---------------------------------------------------------------------- small helpers
def _fmt(values) -> str:
    """Numbers as MJCF text, shortest exact form (MuJoCo's own writer keeps 6 digits)."""
    return " ".join(repr(float(v)) for v in np.atleast_1d(np.asarray(values, float)))


def _quat(rotation: np.ndarray) -> np.ndarray:
    """Unit quaternion (w, x, y, z) of a rotation matrix."""
    q = np.zeros(4)
    mujoco.mju_mat2Quat(q, np.ascontiguousarray(rotation, dtype=float).reshape(9))
    return q


def _axis_rotation(axis, angle: float) -> np.ndarray:
    """Rotation by ``angle`` [rad] about the unit ``axis`` (Rodrigues)."""
    a = np.asarray(axis, float)
    a = a / np.linalg.norm(a)
    k = np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])
    return np.eye(3) + math.sin(angle) * k + (1.0 - math.cos(angle)) * k @ k


def _children(machine: Machine) -> dict[str | None, list[str]]:
    out: dict[str | None, list[str]] = {}
    for b in machine.bodies:
        out.setdefault(b.parent, []).append(b.name)
    return out


def _dfs_bodies(machine: Machine) -> list[str]:
    """Body names in MJCF (depth-first) order: the order of MuJoCo's body and joint arrays."""
    children = _children(machine)
    order: list[str] = []

    def visit(name: str) -> None:
        order.append(name)
        for child in children.get(name, []):
            visit(child)

    for root in children.get(None, []):
        visit(root)
    return order


def _root(machine: Machine) -> str:
    root = machine.bodies[0]
    if root.parent is not None or root.joint.kind != "free":
        raise ModelError(f"the first body '{root.name}' must be the free-floating root")
    return root.name


# ---------------------------------------------------------------------- kinematics
def body_poses_in_fb(machine: Machine, q_tree) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Pose of every body frame in the floating-base (root body) frame fb.

    Args:
        machine: The machine description.
        q_tree: Tree joint coordinates [rad or m], shape (n_tree,), order
            `Machine.moving_joints`.

    Returns:
        ``{body name: (rotation fb <- body (3, 3), body origin in fb [m] (3,))}``.
    """
    names = machine.moving_joints
    q_tree = np.asarray(q_tree, float)
    if q_tree.shape != (len(names),):
        raise ModelError(f"q_tree must have shape ({len(names)},), got {q_tree.shape}")
    q_of = dict(zip(names, q_tree))
    poses: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    for b in machine.bodies:
        if b.parent is None:
            poses[b.name] = (np.eye(3), np.zeros(3))
            continue
        rot_p, pos_p = poses[b.parent]
        rot = rot_p @ b.rotation
        pos = pos_p + rot_p @ b.position
        if b.joint.kind == "revolute":
            rot = rot @ _axis_rotation(b.joint.axis, q_of[b.name])
        elif b.joint.kind == "prismatic":
            axis = np.asarray(b.joint.axis, float)
            pos = pos + rot @ (axis / np.linalg.norm(axis)) * q_of[b.name]
        poses[b.name] = (rot, pos)
    return poses


def _rpy(yaw: float, pitch: float, roll: float) -> np.ndarray:
    """Rotation Rz(yaw) Ry(pitch) Rx(roll)."""
    return (_axis_rotation((0, 0, 1), yaw) @ _axis_rotation((0, 1, 0), pitch)
            @ _axis_rotation((1, 0, 0), roll))


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
        centres = np.array([x, y, z]) + wheels_in_fb @ _rpy(yaw, pitch, roll).T
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
    return np.array([x, y, z]), _rpy(yaw, pitch, roll)


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
    servos = _servo_limits(machine)
    for sp, q in zip(servos, q_ind):
        lo, hi = sp["stroke_range"]
        if not lo - 1e-12 <= q <= hi + 1e-12:
            raise StateError(f"independent coordinate '{sp['name']}' = {q:.6g} outside its "
                             f"range [{lo:.6g}, {hi:.6g}]")
    position, rotation = place_on_terrain(machine, terrain, q_ind, base_xy_yaw)
    q_of = dict(zip(machine.moving_joints, q_tree))
    joints = [q_of[n] for n in _dfs_bodies(machine) if n in q_of]
    qpos = np.concatenate([position, _quat(rotation), joints])
    # Servo setpoints preloaded by the static load, u = x + tau / kp, so that the machine
    # starts in equilibrium instead of first sagging by the servo deflection.
    loads = gravity_loads(machine, q_ind, rotation)[:len(servos)]
    setpoints = q_ind[:len(servos)] + loads / np.array([sp["kp"] for sp in servos])
    return qpos, np.concatenate([setpoints, np.zeros(len(machine.wheels))])


# ---------------------------------------------------------------------- servos
@functools.lru_cache(maxsize=4)
def _compile_xml(text: str) -> mujoco.MjModel:
    """Compile MJCF text; cached by content (the model is only read, never changed)."""
    return mujoco.MjModel.from_xml_string(text)


def _tree_model(machine: Machine, q_ind, base_rotation=None) -> tuple[mujoco.MjModel,
                                                                       mujoco.MjData, list]:
    """The bare tree (no actuators, loops or ground) evaluated at rest at ``q_ind``."""
    root = ET.Element("mujoco")
    ET.SubElement(root, "compiler", angle="radian", autolimits="true", inertiafromgeom="false")
    ET.SubElement(root, "option", gravity=_fmt((0.0, 0.0, -machine.gravity)))
    defaults = ET.SubElement(ET.SubElement(root, "default"), "default", {"class": "machine"})
    for cls in ("visual", "collision", "loop_point"):
        ET.SubElement(defaults, "default", {"class": cls})
    _add_body(ET.SubElement(root, "worldbody"), machine, _root(machine), _children(machine))
    model = _compile_xml(ET.tostring(root, encoding="unicode"))
    data = mujoco.MjData(model)
    joints = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, n)
              for n in machine.moving_joints]
    data.qpos[model.jnt_qposadr[joints]] = machine.coordinates.joint_positions(q_ind)
    if base_rotation is not None:  # the free joint is the first: qpos[0:7], dofs 0-5
        data.qpos[3:7] = _quat(base_rotation)
    mujoco.mj_forward(model, data)
    return model, data, joints


def _reduced_inertia(machine: Machine, q_ind=None) -> np.ndarray:
    """``J^T M J`` over (base twist, independent velocities), shape (19, 19)."""
    coords = machine.coordinates
    q_ind = coords.home() if q_ind is None else q_ind
    model, data, joints = _tree_model(machine, q_ind)
    full = np.zeros((model.nv, model.nv))
    mujoco.mj_fullM(model, data, full)
    jac = np.zeros((model.nv, 6 + N_INDEPENDENT))
    jac[:6, :6] = np.eye(6)
    jac[model.jnt_dofadr[joints], 6:], _ = coords.jacobian(q_ind)
    return jac.T @ full @ jac


def reflected_inertia(machine: Machine, q_ind=None) -> tuple[np.ndarray, np.ndarray]:
    """Inertia reflected to each independent coordinate, others locked and others free.

    With ``M`` the joint-space inertia (MuJoCo's) and ``J`` the map from (base twist,
    independent velocities) to tree velocities (`TreeCoordinates.jacobian`: k1, k2 and 1 for
    a cylinder chain, eqs. 6-7), the reduced inertia is ``M_r = J^T M J``. Locked:
    ``M_r[i, i]`` with the base fixed and every other coordinate held. Free:
    ``1 / (M_r^-1)[i, i]``, with the base and every other coordinate free: what a force on
    coordinate ``i`` accelerates within one timestep, before the other servos react.

    Args:
        machine: The machine description.
        q_ind: Independent coordinates, shape (13,); `TreeCoordinates.home` if None.

    Returns:
        (locked, free), each [kg] for strokes, [kg m^2] for angles, shape (13,),
        independent order.
    """
    reduced = _reduced_inertia(machine, q_ind)
    locked = np.diag(reduced)[6:].copy()
    free = 1.0 / np.diag(np.linalg.inv(reduced))[6:]
    return locked, free


def gravity_loads(machine: Machine, q_ind=None, base_rotation=None) -> np.ndarray:
    """Force each independent coordinate's actuator needs to hold the machine still.

    ``tau = J^T g(q)``: MuJoCo's gravity force on the tree joints mapped through the chains
    by virtual work (`TreeCoordinates.jacobian`).

    Args:
        machine: The machine description.
        q_ind: Independent coordinates, shape (13,); `TreeCoordinates.home` if None.
        base_rotation: Rotation world <- fb, shape (3, 3); level if None.

    Returns:
        [N] for strokes (positive extends), [N m] for angles, shape (13,), independent order.
    """
    coords = machine.coordinates
    q_ind = coords.home() if q_ind is None else q_ind
    model, data, joints = _tree_model(machine, q_ind, base_rotation)
    jac, _ = coords.jacobian(q_ind)
    return jac.T @ data.qfrc_bias[model.jnt_dofadr[joints]]


@dataclass(frozen=True)
class ServoSpec:
    """A hydraulic cylinder (or wrist motor) servo: limits, gains and transmission.

    The force is ``F = kp (s - x) - kv x_dot``, clipped to ``force_range``, where the
    setpoint ``s`` moves at the commanded rate. MuJoCo applies ``kp (u - x)``; the simulator
    sets ``u = s - (kv / kp) x_dot`` before each step (see the module docstring).

    Attributes:
        name: Independent coordinate it drives (also the actuator name).
        joint: Joint carrying the coordinate (the piston joint of a cylinder chain).
        tendon: Pin-to-pin tendon of a cylinder chain, None for a directly driven joint.
        offset: Tendon length at zero stroke, ``L_c0 + L_c`` [m] (0 without tendon).
        rate_range: Valve-limited rate range [m/s or rad/s].
        stroke_range: Stroke (joint) range the setpoint stays in [m or rad].
        force_range: Force (torque) range [N or N m].
        kp: Position gain [N/m or N m/rad].
        kv: Damping gain [N s/m or N m s/rad].
        damping_ratio: ``kv / (2 sqrt(kp m_locked))`` at the home pose [-].
    """

    name: str
    joint: str
    tendon: str | None
    offset: float
    rate_range: tuple[float, float]
    stroke_range: tuple[float, float]
    force_range: tuple[float, float]
    kp: float
    kv: float
    damping_ratio: float


def _servo_limits(machine: Machine) -> list[dict]:
    """Transmission, limits and position gain of the nine servos, independent order."""
    out = []
    for name in machine.coordinates.independent_names:
        tendon, offset = None, 0.0
        if name in machine.chains:
            binding = machine.chains[name]
            joint = binding.piston
            rate = binding.cylinder.velocity_range
            force = binding.cylinder.force_range
            stroke = binding.chain.stroke_range
            tendon = f"{name}_cylinder"
            offset = binding.chain.dead_length + binding.chain.rod_length
        elif name in machine.direct_drives:
            drive = machine.direct_drives[name]
            joint = drive.joint
            rate = (-drive.velocity_limit, drive.velocity_limit)
            force = (-drive.effort_limit, drive.effort_limit)
            stroke = machine.body(joint).joint.range
            if stroke is None:
                raise ModelError(f"directly driven joint '{joint}' needs a range")
        elif name in machine.wheels:
            continue
        else:
            raise ModelError(f"independent coordinate '{name}' has no actuator")
        kind = _JOINT_TYPE[machine.body(joint).joint.kind]
        out.append(dict(name=name, joint=joint, tendon=tendon, offset=offset,
                        rate_range=tuple(map(float, rate)),
                        stroke_range=tuple(map(float, stroke)),
                        force_range=tuple(map(float, force)),
                        kp=max(abs(force[0]), abs(force[1])) / SERVO_POSITION_ERROR[kind]))
    return out


def _explicit_step_radius(reduced_inertia: np.ndarray, kp: np.ndarray, kv: np.ndarray,
                          h: float) -> float:
    """Spectral radius of one step of the linearised servo dynamics, gains explicit.

    Coordinates: base twist (6) then the independent coordinates; ``kp`` and ``kv`` are
    diagonal over the first servo coordinates. One step is
    ``v+ = v - h M^-1 (K x + C v)``, ``x+ = x + h v+`` (MuJoCo's semi-implicit Euler with
    forces from the start of the step); rigid-body modes give exactly 1.
    """
    n = reduced_inertia.shape[0]
    stiffness, damping = np.zeros((n, n)), np.zeros((n, n))
    stiffness[6:6 + kp.size, 6:6 + kp.size] = np.diag(kp)
    damping[6:6 + kv.size, 6:6 + kv.size] = np.diag(kv)
    inv = np.linalg.inv(reduced_inertia)
    damp = np.eye(n) - h * inv @ damping
    push = -h * inv @ stiffness
    step = np.block([[np.eye(n) + h * push, h * damp], [push, damp]])
    return float(np.abs(np.linalg.eigvals(step)).max())


def servo_specs(machine: Machine, timestep: float = DEFAULT_TIMESTEP) -> tuple[ServoSpec, ...]:
    """The nine servos (cylinders, telescope, wrist) in independent-coordinate order.

    ``kp = F_max / e`` with ``e`` = `SERVO_POSITION_ERROR` (deflection at full force).
    The damping is applied explicitly by the simulator (see the module docstring), so it is
    bounded by stability rather than chosen freely:
    ``kv = min(2 zeta sqrt(kp m_locked), c m_free / h)`` with ``zeta`` =
    `SERVO_DAMPING_RATIO`, ``c`` = `SERVO_EXPLICIT_DAMPING` and the `reflected_inertia` at
    the home pose (one explicit damper alone is stable for ``h kv / m_free < 2``). The gains
    are then scaled down together, if needed, until the coupled linearised step is stable at
    `SERVO_STABILITY_MARGIN` times the timestep. The crane's light coupled motions (lift, tilt
    and telescope against each other) leave those three servos lightly damped. ``h`` is the
    longer of the timestep and `DEFAULT_TIMESTEP`: the servos are the same at any shorter
    step.

    Args:
        machine: The machine description.
        timestep: Simulation timestep [s].

    Raises:
        ModelError: The servos are unstable at this timestep even without damping.
    """
    h = _check_timestep(timestep)
    reduced = _reduced_inertia(machine)
    limits = _servo_limits(machine)
    n = len(limits)
    locked = np.diag(reduced)[6:6 + n]
    free = 1.0 / np.diag(np.linalg.inv(reduced))[6:6 + n]
    kp = np.array([lim["kp"] for lim in limits])
    critical = 2.0 * np.sqrt(kp * locked)
    # Designed at the default step or the given one, whichever is longer, so that smaller
    # steps simulate the same servos (and converge), not better-damped ones.
    h_design = max(h, DEFAULT_TIMESTEP)
    kv = np.minimum(SERVO_DAMPING_RATIO * critical, SERVO_EXPLICIT_DAMPING * free / h_design)

    def stable(scale: float) -> bool:
        radius = _explicit_step_radius(reduced, kp, scale * kv,
                                       SERVO_STABILITY_MARGIN * h_design)
        return radius <= 1.0 + 1e-7

    if not stable(0.0):
        raise ModelError(f"the servos are unstable at timestep {h:g} s even without damping; "
                         f"use a smaller timestep or softer servos")
    scale = 1.0
    if not stable(1.0):
        lo, hi = 0.0, 1.0
        for _ in range(30):
            lo, hi = ((lo + hi) / 2, hi) if stable((lo + hi) / 2) else (lo, (lo + hi) / 2)
        scale = lo
    return tuple(ServoSpec(**lim, kv=float(scale * k), damping_ratio=float(scale * k / c))
                 for lim, k, c in zip(limits, kv, critical))


# ---------------------------------------------------------------------- MJCF generation
def _actuator_elements(machine: Machine, timestep: float) -> list[tuple[str, dict]]:
    """MJCF actuator elements, one per independent coordinate, in independent order."""
    elements = []
    for sp in servo_specs(machine, timestep):
        common = {"class": "machine", "name": sp.name, "forcerange": _fmt(sp.force_range)}
        if sp.tendon is not None:
            # F = kp (u - x) with x = L - offset: the stroke read off the pin-to-pin length.
            elements.append(("general", dict(common, tendon=sp.tendon, gaintype="fixed",
                                             gainprm=_fmt(sp.kp), biastype="affine",
                                             biasprm=_fmt((sp.kp * sp.offset, -sp.kp, 0.0)))))
        else:
            elements.append(("position", dict(common, joint=sp.joint, kp=_fmt(sp.kp))))
    vmax, tmax = machine.wheel_drive
    for name in machine.wheels:
        elements.append(("velocity", {"class": "machine", "name": name, "joint": name,
                                      "kv": _fmt(WHEEL_VELOCITY_GAIN),
                                      "ctrlrange": _fmt((-vmax, vmax)),
                                      "forcerange": _fmt((-tmax, tmax))}))
    return elements


def _add_body(parent: ET.Element, machine: Machine, name: str, children) -> None:
    b = machine.body(name)
    attrs = dict(name=name, pos=_fmt(b.position))
    if not np.allclose(b.rotation, np.eye(3)):
        attrs["quat"] = _fmt(_quat(b.rotation))
    if b.parent is None:
        attrs["childclass"] = "machine"
    el = ET.SubElement(parent, "body", attrs)
    i = b.inertia.inertia
    ET.SubElement(el, "inertial", pos=_fmt(b.inertia.com), mass=_fmt(b.inertia.mass),
                  fullinertia=_fmt((i[0, 0], i[1, 1], i[2, 2], i[0, 1], i[0, 2], i[1, 2])))
    if b.joint.kind == "free":
        ET.SubElement(el, "freejoint", name=name)
    elif b.joint.kind in _JOINT_TYPE:
        j = b.joint
        jattrs = dict(name=name, type=_JOINT_TYPE[j.kind], axis=_fmt(j.axis))
        if j.range is not None:
            jattrs["range"] = _fmt(j.range)
        if j.damping:
            jattrs["damping"] = _fmt(j.damping)
        if j.armature:
            jattrs["armature"] = _fmt(j.armature)
        ET.SubElement(el, "joint", jattrs)
    n_visual = 0
    for g in b.geoms:
        gattrs = {"class": "collision" if g.collision else "visual", "type": g.kind,
                  "size": _fmt(g.size), "rgba": _fmt(g.rgba)}
        if g.collision:
            gattrs["name"] = f"{name}_collision"
        else:
            gattrs["name"] = f"{name}_visual{n_visual}"
            n_visual += 1
        if np.any(np.asarray(g.position) != 0):
            gattrs["pos"] = _fmt(g.position)
        if not np.allclose(g.rotation, np.eye(3)):
            gattrs["quat"] = _fmt(_quat(g.rotation))
        ET.SubElement(el, "geom", gattrs)
    for loop in machine.loops:
        for side, body, point in (("a", loop.body_a, loop.point_a),
                                  ("b", loop.body_b, loop.point_b)):
            if body == name:
                ET.SubElement(el, "site", {"name": f"{loop.name}_{side}", "class": "loop_point",
                                           "pos": _fmt(point)})
    for chain_name, binding in machine.chains.items():
        barrel = machine.body(binding.barrel)
        if barrel.parent == name:
            ET.SubElement(el, "site", {"name": f"{chain_name}_cylinder_pivot",
                                       "class": "loop_point", "pos": _fmt(barrel.position)})
    if name == machine.tcp_body:
        ET.SubElement(el, "site", {"name": "tcp", "class": "loop_point",
                                   "pos": _fmt(machine.tcp_position)})
    for child in children.get(name, []):
        _add_body(el, machine, child, children)


def _chain_loop(machine: Machine, chain_name: str) -> Loop:
    """The loop closing a cylinder chain: piston rod eye on the driven link."""
    binding = machine.chains[chain_name]
    for loop in machine.loops:
        if {loop.body_a, loop.body_b} == {binding.piston, binding.driven_joint}:
            return loop
    raise ModelError(f"no loop closes chain '{chain_name}' (piston '{binding.piston}' to "
                     f"driven link '{binding.driven_joint}')")


def _pretty(root: ET.Element) -> str:
    ET.indent(root, space="  ")
    return ET.tostring(root, encoding="unicode") + "\n"


def machine_xml(machine: Machine, timestep: float = DEFAULT_TIMESTEP) -> str:
    """The robot file ``machine.xml``: bodies, joints, loop closures and actuators.

    Args:
        machine: The machine description (the single source of geometry and inertia).
        timestep: Simulation timestep [s]; the loop-closure time constant follows it.

    Returns:
        MJCF text.
    """
    timestep = _check_timestep(timestep)
    _root(machine)
    root = ET.Element("mujoco", model="machine")
    ET.SubElement(root, "compiler", angle="radian", autolimits="true", inertiafromgeom="false")
    option = ET.SubElement(root, "option", timestep=_fmt(timestep), integrator="implicitfast",
                           cone="elliptic", tolerance=_fmt(SOLVER_TOLERANCE),
                           gravity=_fmt((0.0, 0.0, -machine.gravity)))
    ET.SubElement(option, "flag", island="disable")  # one machine: one island, 5 % faster
    defaults = ET.SubElement(ET.SubElement(root, "default"), "default", {"class": "machine"})
    ET.SubElement(defaults, "geom", contype="0", conaffinity="0")
    ET.SubElement(defaults, "equality", solref=_fmt((EQUALITY_SOLREF_STEPS * timestep, 1.0)),
                  solimp=_fmt(EQUALITY_SOLIMP))
    visual = ET.SubElement(defaults, "default", {"class": "visual"})
    ET.SubElement(visual, "geom", group="2", contype="0", conaffinity="0")
    collision = ET.SubElement(defaults, "default", {"class": "collision"})
    ET.SubElement(collision, "geom", group="3", contype="1", conaffinity="0", condim="3")
    sites = ET.SubElement(defaults, "default", {"class": "loop_point"})
    ET.SubElement(sites, "site", group="4", size="0.02", rgba="0.9 0.1 0.1 1")

    worldbody = ET.SubElement(root, "worldbody")
    children = _children(machine)
    _add_body(worldbody, machine, _root(machine), children)

    equality = ET.SubElement(root, "equality")
    for loop in machine.loops:
        ET.SubElement(equality, "connect", {"name": loop.name, "class": "machine",
                                            "site1": f"{loop.name}_a",
                                            "site2": f"{loop.name}_b"})
    tendon = ET.SubElement(root, "tendon")
    for chain_name, binding in machine.chains.items():
        spatial = ET.SubElement(tendon, "spatial", name=f"{chain_name}_cylinder", width="0.01")
        ET.SubElement(spatial, "site", site=f"{chain_name}_cylinder_pivot")
        ET.SubElement(spatial, "site", site=f"{_chain_loop(machine, chain_name).name}_b")
    actuator = ET.SubElement(root, "actuator")
    for tag, attrs in _actuator_elements(machine, timestep):
        ET.SubElement(actuator, tag, attrs)
    return _pretty(root)


def _hfield_bytes(terrain: Terrain) -> bytes:
    """MuJoCo's binary height-field format: int32 nrow, ncol, then float32 data in [0, 1]."""
    lo, hi = terrain.height_range
    data = ((terrain.heights - lo) / (hi - lo)).astype(np.float32)
    n_y, n_x = terrain.shape
    return struct.pack("<ii", n_y, n_x) + data.astype("<f4").tobytes()


def _hfield_file(terrain: Terrain) -> str:
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
            "condim": "3", "priority": "1", "friction": _fmt((terrain.friction, 0.005, 1e-4)),
            "solref": _fmt(CONTACT_SOLREF), "solimp": _fmt(CONTACT_SOLIMP)}
    if terrain.is_flat:
        geom.update(type="plane", pos=_fmt((cx, cy, lo)), size=_fmt((hx, hy, 0.05)))
    else:
        path = _hfield_file(terrain)
        files[path] = _hfield_bytes(terrain)
        ET.SubElement(asset, "hfield", name="terrain", file=path,
                      size=_fmt((hx, hy, hi - lo, TERRAIN_BASE_DEPTH)))
        geom.update(type="hfield", hfield="terrain", pos=_fmt((cx, cy, lo)))
    worldbody = ET.SubElement(root, "worldbody")
    ET.SubElement(worldbody, "light", pos="0 0 30", dir="0.2 0.3 -1", directional="true")
    ET.SubElement(worldbody, "geom", geom)
    qpos, ctrl = home_keyframe(machine, terrain, q_ind, base_xy_yaw)
    keyframe = ET.SubElement(root, "keyframe")
    ET.SubElement(keyframe, "key", name="home", qpos=_fmt(qpos), ctrl=_fmt(ctrl))
    return _pretty(root), files


def _check_timestep(timestep: float) -> float:
    try:
        timestep = float(timestep)
    except (TypeError, ValueError) as exc:
        raise ModelError(f"timestep must be a number [s], got {timestep!r}") from exc
    if not (math.isfinite(timestep) and 0 < timestep <= CONTACT_SOLREF[0] / 2):
        raise ModelError(f"timestep {timestep:g} s outside (0, {CONTACT_SOLREF[0] / 2:g}] s "
                         f"(the contact time constant must span two steps)")
    return timestep


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


# ---------------------------------------------------------------------- index
class MujocoIndex:
    """Addresses of the machine's joints, actuators, geoms and sites in a compiled model.

    Args:
        model: A model built by `build_model` (or loaded from `write_mjcf` files).
        machine: The description it was built from.

    Attributes:
        base_body: Body id of the floating base.
        base_qpos: qpos addresses of the free joint (position, quaternion), shape (7,).
        base_dof: dof addresses of the free joint (world linear, local angular), shape (6,).
        qpos_adr: qpos address of every tree joint, by joint name.
        dof_adr: dof address of every tree joint, by joint name.
        tree_qpos: qpos addresses in `Machine.moving_joints` order, shape (n_tree,).
        tree_dof: dof addresses in `Machine.moving_joints` order, shape (n_tree,).
        independent_names: The 13 independent coordinates (order of `models.coordinates`).
        independent_qpos: qpos address carrying each independent coordinate (the piston
            joint for a cylinder chain), shape (13,).
        independent_dof: Same for dofs, shape (13,).
        actuator_id: Actuator id by independent coordinate name (actuator names are those).
        actuators: Actuator ids in independent order, shape (13,).
        servos: The nine servo actuators (cylinders, telescope, wrist), shape (9,).
        servo_qpos: qpos addresses of their joints (piston joints for chains), shape (9,).
        servo_dof: dof addresses of their joints, shape (9,).
        suspension_actuators: Actuator ids of the two suspension cylinders (L, R).
        wheel_actuators: Wheel actuator ids, order FL, RL, FR, RR.
        wheel_bodies: Wheel body ids, order FL, RL, FR, RR.
        wheel_geoms: Wheel collision geom ids, order FL, RL, FR, RR.
        loop_sites: ``{loop name: (site id on body_a, site id on body_b)}``.
        loop_site_pairs: The same as an array, shape (n_loops, 2).
        tcp_site: Site id of the tool centre point.
        terrain_geom: Geom id of the terrain, -1 if the model has none.
    """

    def __init__(self, model: mujoco.MjModel, machine: Machine):
        def find(objtype, name: str) -> int:
            i = mujoco.mj_name2id(model, objtype, name)
            if i < 0:
                raise ModelError(f"model has no {objtype.name[6:].lower()} '{name}'; was it "
                                 f"built from this machine?")
            return i

        joint, body = mujoco.mjtObj.mjOBJ_JOINT, mujoco.mjtObj.mjOBJ_BODY
        root = _root(machine)
        free = find(joint, root)
        self.base_body = find(body, root)
        self.base_qpos = np.arange(model.jnt_qposadr[free], model.jnt_qposadr[free] + 7)
        self.base_dof = np.arange(model.jnt_dofadr[free], model.jnt_dofadr[free] + 6)
        ids = {n: find(joint, n) for n in machine.moving_joints}
        self.qpos_adr = {n: int(model.jnt_qposadr[i]) for n, i in ids.items()}
        self.dof_adr = {n: int(model.jnt_dofadr[i]) for n, i in ids.items()}
        self.tree_qpos = np.array([self.qpos_adr[n] for n in machine.moving_joints])
        self.tree_dof = np.array([self.dof_adr[n] for n in machine.moving_joints])
        coords = machine.coordinates
        self.independent_names = coords.independent_names
        carrier = [machine.chains[n].piston if n in machine.chains else n
                   for n in self.independent_names]
        self.independent_qpos = np.array([self.qpos_adr[n] for n in carrier])
        self.independent_dof = np.array([self.dof_adr[n] for n in carrier])
        actuator = mujoco.mjtObj.mjOBJ_ACTUATOR
        self.actuator_id = {n: find(actuator, n) for n in self.independent_names}
        self.actuators = np.array([self.actuator_id[n] for n in self.independent_names])
        n_servo = N_INDEPENDENT - len(machine.wheels)
        self.servos = self.actuators[:n_servo]
        self.servo_qpos = self.independent_qpos[:n_servo]
        self.servo_dof = self.independent_dof[:n_servo]
        self.suspension_actuators = np.array([self.actuator_id[n]
                                              for n in machine.suspension_coordinates])
        self.wheel_actuators = np.array([self.actuator_id[n] for n in machine.wheels])
        self.wheel_bodies = np.array([find(body, n) for n in machine.wheels])
        geom = mujoco.mjtObj.mjOBJ_GEOM
        self.wheel_geoms = np.array([find(geom, f"{n}_collision") for n in machine.wheels])
        site = mujoco.mjtObj.mjOBJ_SITE
        self.loop_sites = {lp.name: (find(site, f"{lp.name}_a"), find(site, f"{lp.name}_b"))
                           for lp in machine.loops}
        self.loop_site_pairs = np.array(list(self.loop_sites.values()), dtype=int).reshape(-1, 2)
        self.tcp_site = find(site, "tcp")
        self.terrain_geom = mujoco.mj_name2id(model, geom, "terrain")
