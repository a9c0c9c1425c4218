"""Servo design from the tree's inertia.

Reflected inertias and gravity loads of the tree (MuJoCo's), the proportional gains and
explicit damping of every axis servo (`servo_specs`), and the damping each servo can take at
the pose the machine is in (`DampingSchedule`).
"""

from __future__ import annotations

import functools
import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass

import mujoco
import numpy as np

try:
    from numpy.linalg import _umath_linalg
except ImportError:  # pragma: no cover - a numpy that moved it
    _umath_linalg = None

from models.coordinates import N_INDEPENDENT
from models.description import Machine
from models.errors import ModelError
from models.mujoco.constants import (
    DEFAULT_TIMESTEP,
    JOINT_TYPE,
    SERVO_DAMPING_RATIO,
    SERVO_EXPLICIT_DAMPING,
    SERVO_EXPLICIT_LIMIT,
    SERVO_POSITION_ERROR,
    SERVO_STABILITY_MARGIN,
    check_timestep,
)
from models.mujoco.elements import add_body, children_of, fmt, quat, root_body


@functools.lru_cache(maxsize=4)
def compile_xml(text: str) -> mujoco.MjModel:
    """Compile MJCF text; cached by content (the model is only read, never changed)."""
    return mujoco.MjModel.from_xml_string(text)


def _tree_model(machine: Machine, q_ind, base_rotation=None) -> tuple[mujoco.MjModel,
                                                                       mujoco.MjData, list]:
    """The bare tree (no actuators, loops or ground) evaluated at rest at ``q_ind``."""
    root = ET.Element("mujoco")
    ET.SubElement(root, "compiler", angle="radian", autolimits="true", inertiafromgeom="false")
    ET.SubElement(root, "option", gravity=fmt((0.0, 0.0, -machine.gravity)))
    defaults = ET.SubElement(ET.SubElement(root, "default"), "default", {"class": "machine"})
    for cls in ("visual", "collision", "loop_point"):
        ET.SubElement(defaults, "default", {"class": cls})
    add_body(ET.SubElement(root, "worldbody"), machine, root_body(machine), children_of(machine))
    model = compile_xml(ET.tostring(root, encoding="unicode"))
    data = mujoco.MjData(model)
    joints = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, n)
              for n in machine.moving_joints]
    data.qpos[model.jnt_qposadr[joints]] = machine.coordinates.joint_positions(q_ind)
    if base_rotation is not None:  # the free joint is the first: qpos[0:7], dofs 0-5
        data.qpos[3:7] = quat(base_rotation)
    mujoco.mj_forward(model, data)
    return model, data, joints


def reduced_inertia(machine: Machine, q_ind=None) -> np.ndarray:
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
    reduced = reduced_inertia(machine, q_ind)
    return np.diag(reduced)[6:].copy(), free_inertia(reduced)


def free_inertia(reduced: np.ndarray) -> np.ndarray:
    """``1 / (M_r^-1)[i, i]`` of each independent coordinate of a (19, 19) reduced inertia."""
    return 1.0 / np.diag(np.linalg.inv(reduced))[6:]


def _free_inertia(reduced: np.ndarray) -> np.ndarray:
    """`free_inertia` by the gufunc `np.linalg.inv` ends in, without its wrapper (~2.5 us).

    The same LAPACK call on the same data, so the same bits; the simulator's damping asks
    every few steps. A diagonal that does not sum to a finite number (NaN: a singular or
    non-finite matrix, not a mass matrix's) takes `free_inertia`, which raises numpy's
    `LinAlgError` as before (after the gufunc's RuntimeWarning) or gives the same numbers.
    """
    if _umath_linalg is None:  # pragma: no cover - a numpy that moved it
        return free_inertia(reduced)
    diagonal = np.diag(_umath_linalg.inv(reduced, signature="d->d"))
    if not math.isfinite(diagonal.sum()):
        return free_inertia(reduced)
    return 1.0 / diagonal[6:]


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


def servo_limits(machine: Machine) -> list[dict]:
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
        kind = JOINT_TYPE[machine.body(joint).joint.kind]
        out.append(dict(name=name, joint=joint, tendon=tendon, offset=offset,
                        rate_range=tuple(map(float, rate)),
                        stroke_range=tuple(map(float, stroke)),
                        force_range=tuple(map(float, force)),
                        kp=max(abs(force[0]), abs(force[1])) / SERVO_POSITION_ERROR[kind]))
    return out


def explicit_step_radius(reduced_inertia: np.ndarray, kp: np.ndarray, kv: np.ndarray,
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
    h = check_timestep(timestep)
    reduced = reduced_inertia(machine)
    limits = servo_limits(machine)
    n = len(limits)
    locked = np.diag(reduced)[6:6 + n]
    free = free_inertia(reduced)[:n]
    kp = np.array([lim["kp"] for lim in limits])
    critical = 2.0 * np.sqrt(kp * locked)
    # Designed at the default step or the given one, whichever is longer, so that smaller
    # steps simulate the same servos (and converge), not better-damped ones.
    h_design = max(h, DEFAULT_TIMESTEP)
    kv = np.minimum(SERVO_DAMPING_RATIO * critical, SERVO_EXPLICIT_DAMPING * free / h_design)

    def stable(scale: float) -> bool:
        radius = explicit_step_radius(reduced, kp, scale * kv,
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


class DampingSchedule:
    """Each servo's explicit damping, capped at what the pose the machine is in allows.

    `servo_specs` designs the damping at the home pose, where the crane is folded over the
    chassis. Elsewhere a coordinate's free reflected inertia can be far smaller: with the boom
    and jib upright the slew's is 938 kg against 13 948 kg at home, and the slew damper's
    ``h kv / m_free`` is 3.2, past the explicit step's limit of 2: the slew then rings at
    half the step rate and the wheels' forces jump between 0 and 38 kN from step to step. So
    at every call the damping is ``min(kv, c m_free(q) / h)`` with ``c`` =
    `SERVO_EXPLICIT_LIMIT` and the free inertia from MuJoCo's mass matrix of the current
    state (payload included) mapped through the chains (`TreeCoordinates.jacobian`): the
    designed damping wherever it is stable, the most an explicit damper can take where it is
    not. ``h`` is the design step of `servo_specs`.

    Args:
        model: The machine's MuJoCo model.
        index: Its addresses (`MujocoIndex`).
        machine: The machine description.
        specs: The servos (`servo_specs`), independent order.
        timestep: Simulation timestep [s].
    """

    def __init__(self, model: mujoco.MjModel, index, machine: Machine,
                 specs: tuple[ServoSpec, ...], timestep: float):
        self._model = model
        self._coordinates = machine.coordinates
        self._tree_dof = index.tree_dof
        self._kp = np.array([sp.kp for sp in specs])
        self._kv = np.array([sp.kv for sp in specs])
        self._n = len(specs)
        self._stroke_range = np.array([sp.stroke_range for sp in specs]).T
        self._q = np.zeros(N_INDEPENDENT)
        self._limit = SERVO_EXPLICIT_LIMIT / max(check_timestep(timestep), DEFAULT_TIMESTEP)
        self._jac = np.zeros((model.nv, 6 + N_INDEPENDENT))
        self._jac[index.base_dof, :6] = np.eye(6)
        # `TreeCoordinates.jacobian`'s entries: ones but for each chain's driven joint and
        # barrel, which `damping` writes (their k1, k2, by the same operations)
        coords = self._coordinates
        self._jac[self._tree_dof, 6:], _ = coords.jacobian(coords.home())
        self._chain_entries = [
            (i, b.chain, index.tree_dof[coords.index[b.driven_joint]],
             index.tree_dof[coords.index[b.barrel]], 6 + i)
            for i, b in ((i, coords.binding(i)) for i in coords.chain_indices)]
        self._mass = np.zeros((model.nv, model.nv))

    @property
    def designed(self) -> np.ndarray:
        """The designed damping gains ``kv`` [N s/m or N m s/rad], shape (9,) (a copy)."""
        return self._kv.copy()

    def damping(self, data: mujoco.MjData, q_ind) -> np.ndarray:
        """Damping gains ``kv`` at ``data``'s state with independent coordinates ``q_ind``.

        MuJoCo's mass matrix in ``data`` must be current (after `mujoco.mj_step` or
        `mujoco.mj_forward`). Strokes a little past their range (MuJoCo's limits are soft)
        are taken at the range's end.
        """
        q = self._q
        q[:] = q_ind
        np.clip(q[:self._n], self._stroke_range[0], self._stroke_range[1], out=q[:self._n])
        if not np.isfinite(q).all():
            self._coordinates.jacobian(q)  # raises, naming the coordinate
        strokes, jac = q.tolist(), self._jac
        for i, chain, driven, barrel, column in self._chain_entries:
            jac[driven, column], jac[barrel, column] = chain.driven_rates(strokes[i])
        mujoco.mj_fullM(self._model, data, self._mass)
        free = _free_inertia(self._jac.T @ self._mass @ self._jac)[:self._n]
        return np.minimum(self._kv, self._limit * free)

    def lead(self, data: mujoco.MjData, q_ind) -> np.ndarray:
        """``kv / kp`` [s] at ``data``'s state: the simulator's ``u = s - lead x_dot``."""
        return self.damping(data, q_ind) / self._kp
