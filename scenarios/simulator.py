"""MuJoCo simulator of the machine: commands in, consistent machine state and contacts out.

Units and frames: SI; the world has z up; ``fb`` is the floating-base (chassis) frame. Every
per-wheel array is ordered FL, RL, FR, RR.

Commands (`ActuatorCommand`, `Simulator.set_command`): stroke rates of the six hydraulic
cylinders [m/s] (bogie_L, bogie_R, slew, lift, tilt, telescope), joint rates of the wrist
[rad/s] (wrist_pitch, wrist_roll, rotator), and one wheel speed per side [rad/s] (left
drives FL and RL, right drives FR and RR). Each servo is a valve-controlled cylinder (see
`models.mujoco_model`): its setpoint moves at the commanded rate, clipped to the valve's
rate range and the stroke range, and the cylinder follows with ``F = kp (s - x) - kv x_dot``
up to its force limit; the damping term is applied here, explicitly, before every step.

Consistent instants. `mujoco.mj_step` first evaluates the dynamics at the current state
``(q, v)`` (accelerations, actuator and contact forces, body poses) and then integrates to
``(q', v')``. After a step MuJoCo's derived quantities therefore belong to the state *before*
the step. `Simulator.step` keeps that pre-step state, and `Simulator.measure` reports it
together with those derived quantities, so pose, twist, acceleration, actuator forces and
contact forces all belong to the same instant ``MachineState.time``, one timestep behind
`Simulator.time` (`Simulator.measured_instant` gives MuJoCo's full ``qpos``, ``qvel`` of it).
After `Simulator.reset` the model is evaluated at the current state and both times agree.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Mapping
from dataclasses import dataclass

import mujoco
import numpy as np

from models.coordinates import N_INDEPENDENT
from models.description import Machine
from models.errors import TerrainError
from models.mujoco_model import (
    DEFAULT_TIMESTEP,
    MujocoIndex,
    build_model,
    home_keyframe,
    servo_specs,
)
from models.state import MachineState, WheelContacts
from models.terrain import Terrain

__all__ = ["ActuatorCommand", "CommandError", "MeasurementNoise", "SimulationError",
           "Simulator", "SimulatorError", "base_motion_from_free_joint"]

CONTACT_FORCE_THRESHOLD = 1.0  # [N] normal force above which a wheel counts as in contact
_CONTACT_ROWS = np.arange(3)  # an elliptic condim-3 contact: normal, tangent 1, tangent 2
DEFAULT_SETTLE_TIME = 1.5  # [s]
_SETTLE_DECAY_FRACTION = 2.0 / 3.0  # of the settling time spent with decaying velocities
_SETTLE_DECAY_PER_STEP = 0.02  # velocity lost per step meanwhile
_SETTLED_CACHE = 4  # settled states kept by reset()
_WINDUP_STEPS = 5  # anti-windup applied every this many steps
_ANTI_WINDUP = 1.5  # servo setpoint kept within this many full-force deflections of the joint
_FATAL_WARNINGS = tuple(int(w) for w in (
    mujoco.mjtWarning.mjWARN_BADQPOS, mujoco.mjtWarning.mjWARN_BADQVEL,
    mujoco.mjtWarning.mjWARN_BADQACC, mujoco.mjtWarning.mjWARN_BADCTRL))


class SimulatorError(Exception):
    """Base class of the simulator's errors."""


class CommandError(SimulatorError, ValueError):
    """A command has a wrong shape, an unknown name or a non-finite entry."""


class SimulationError(SimulatorError, RuntimeError):
    """The simulation diverged (MuJoCo flagged a bad position, velocity or acceleration)."""


def _vector(name: str, value, n: int) -> np.ndarray:
    try:
        a = np.array(value, dtype=float)  # a copy: the caller may reuse its buffer
    except (TypeError, ValueError) as exc:
        raise CommandError(f"{name} must be numbers, got {value!r}") from exc
    if a.shape != (n,):
        raise CommandError(f"{name} must have shape ({n},), got {a.shape}")
    if not np.isfinite(a).all():
        raise CommandError(f"{name} has non-finite entries: {a}")
    return a


def _rates(name: str, value, names: tuple[str, ...]):
    """Rates from None (zeros), a mapping by name, or a sequence in ``names`` order.

    Sequences pass through unchecked: `ActuatorCommand` checks them.
    """
    if value is None:
        return np.zeros(len(names))
    if isinstance(value, Mapping):
        unknown = set(value) - set(names)
        if unknown:
            raise CommandError(f"{name}: unknown names {sorted(unknown)}; valid: {list(names)}")
        return [value.get(n, 0.0) for n in names]
    return value


@dataclass(frozen=True)
class ActuatorCommand:
    """One command for every actuator; rates beyond the actuator limits are clipped.

    Attributes:
        cylinder_rates: Stroke rates of the hydraulic cylinders [m/s], shape (6,), order
            bogie_L, bogie_R, slew, lift, tilt, telescope (the first six independent
            coordinates). Positive extends.
        wrist_rates: Joint rates [rad/s], shape (3,), order wrist_pitch, wrist_roll, rotator.
        wheel_speeds: Wheel spin speeds [rad/s], shape (2,): (left pair FL+RL, right pair
            FR+RR). Positive drives forward (+x of fb).
    """

    cylinder_rates: np.ndarray
    wrist_rates: np.ndarray
    wheel_speeds: np.ndarray

    def __post_init__(self):
        for name, n in (("cylinder_rates", 6), ("wrist_rates", 3), ("wheel_speeds", 2)):
            a = _vector(name, getattr(self, name), n)
            a.setflags(write=False)
            object.__setattr__(self, name, a)

    @classmethod
    def zero(cls) -> ActuatorCommand:
        """Hold every servo and brake the wheels."""
        return cls(np.zeros(6), np.zeros(3), np.zeros(2))

    @property
    def servo_rates(self) -> np.ndarray:
        """Rates of the nine servos in independent order [m/s, rad/s], shape (9,)."""
        return np.concatenate([self.cylinder_rates, self.wrist_rates])


@dataclass(frozen=True)
class MeasurementNoise:
    """Zero-mean Gaussian noise added to the measured `MachineState` (not the ground truth).

    Attributes:
        base_twist: Std of each twist component [m/s, rad/s].
        base_acceleration: Std of each acceleration component [m/s^2, rad/s^2].
        q: Std of each independent coordinate [m or rad].
        qd: Std of each independent velocity [m/s or rad/s].
        qdd: Std of each independent acceleration [m/s^2 or rad/s^2].
        contact_force: Std of each wheel force component in `MachineState.contacts` [N].
        suspension_force: Std of each suspension cylinder force [N].
        seed: Seed of the noise generator.
    """

    base_twist: float = 0.0
    base_acceleration: float = 0.0
    q: float = 0.0
    qd: float = 0.0
    qdd: float = 0.0
    contact_force: float = 0.0
    suspension_force: float = 0.0
    seed: int = 0

    def __post_init__(self):
        for name in ("base_twist", "base_acceleration", "q", "qd", "qdd", "contact_force",
                     "suspension_force"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise SimulatorError(f"noise '{name}' must be a finite std >= 0, got {v!r}")
        if isinstance(self.seed, bool) or not isinstance(self.seed, int) or self.seed < 0:
            raise SimulatorError(f"noise seed must be a non-negative integer, got {self.seed!r}")


def base_motion_from_free_joint(qpos7, qvel6, qacc6
                                ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Base pose, body twist and its derivative from MuJoCo free-joint coordinates.

    MuJoCo's free joint has ``qvel = [v_world; w_fb]`` (linear velocity of the fb origin in
    world axes, angular velocity in fb axes) and ``qacc`` their time derivatives. With
    ``R`` = rotation world <- fb, the body twist is ``[v_fb; w_fb] = [R^T v_world; w_fb]`` and
    its time derivative (Pinocchio's free-flyer ``a``) is
    ``[R^T a_world - w_fb x v_fb; w_dot_fb]``, since ``d(R^T)/dt = -[w_fb]x R^T``.

    Args:
        qpos7: Position [m] and unit quaternion (w, x, y, z), shape (7,).
        qvel6: Free-joint velocity, shape (6,).
        qacc6: Free-joint acceleration, shape (6,).

    Returns:
        (position [m] (3,), rotation world <- fb (3, 3), twist [m/s, rad/s] (6,),
        twist derivative [m/s^2, rad/s^2] (6,)).
    """
    qpos7, qvel6, qacc6 = (np.asarray(a, float) for a in (qpos7, qvel6, qacc6))
    rotation = np.zeros(9)
    mujoco.mju_quat2Mat(rotation, qpos7[3:7] / np.linalg.norm(qpos7[3:7]))
    rotation = rotation.reshape(3, 3)
    twist, accel = _body_motion(rotation, qvel6, qacc6)
    return qpos7[:3].copy(), rotation, twist, accel


def _body_motion(rotation: np.ndarray, qvel6: np.ndarray,
                 qacc6: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Twist [R^T v; w] and its derivative [R^T a - w x v_fb; w_dot] (see above)."""
    v = rotation.T @ qvel6[:3]
    w = qvel6[3:6]
    w_cross_v = (w[1] * v[2] - w[2] * v[1], w[2] * v[0] - w[0] * v[2], w[0] * v[1] - w[1] * v[0])
    twist = np.empty(6)
    twist[:3], twist[3:] = v, w
    accel = np.empty(6)
    accel[:3] = rotation.T @ qacc6[:3]
    accel[:3] -= w_cross_v
    accel[3:] = qacc6[3:6]
    return twist, accel


class Simulator:
    """The machine on a terrain in MuJoCo, driven like the real one.

    Args:
        machine: The machine description.
        terrain: The ground.
        timestep: Simulation timestep [s].
        noise: Noise added to the measured state; None for exact measurements.

    Attributes:
        machine, terrain: As given.
        model, data: The MuJoCo model and data (read them; change them at your own risk).
        index: Addresses in the model (`MujocoIndex`).
        coordinates: Independent <-> tree coordinate map.
        servos: Limits and gains of the nine servos (`ServoSpec`), independent order.
    """

    def __init__(self, machine: Machine, terrain: Terrain, timestep: float = DEFAULT_TIMESTEP,
                 noise: MeasurementNoise | None = None):
        if noise is not None and not isinstance(noise, MeasurementNoise):
            raise SimulatorError(f"noise must be a MeasurementNoise or None, got {noise!r}")
        self.machine = machine
        self.terrain = terrain
        self.noise = noise
        self.model = build_model(machine, terrain, timestep)
        self.data = mujoco.MjData(self.model)
        self.index = MujocoIndex(self.model, machine)
        self.coordinates = machine.coordinates
        self._rng = np.random.default_rng(noise.seed if noise else 0)
        self._cylinders = self.index.independent_names[:6]
        self._wrist = self.index.independent_names[6:9]
        self._wheel_of_geom = np.full(self.model.ngeom, -1)
        self._wheel_of_geom[self.index.wheel_geoms] = np.arange(4)
        terrain_geom = self.index.terrain_geom
        if (self.model.opt.cone != mujoco.mjtCone.mjCONE_ELLIPTIC
                or self.model.geom_condim[terrain_geom] != 3
                or self.model.geom_priority[terrain_geom] <= 0):
            raise SimulatorError("wheel contacts are read as elliptic condim-3 contacts, "
                                 "which this model does not have")
        self.servos = servo_specs(machine, self.model.opt.timestep)
        servos = self.servos
        self._rate_range = np.array([sp.rate_range for sp in servos])
        self._wheel_range = self.model.actuator_ctrlrange[self.index.wheel_actuators].T.copy()
        self._stroke_range = np.array([sp.stroke_range for sp in servos])
        self._damping_lead = np.array([sp.kv / sp.kp for sp in servos])  # [s]
        servos_ids = self.index.servos
        if not np.array_equal(servos_ids, np.arange(servos_ids[0], servos_ids[0] + len(servos))):
            raise SimulatorError("the servo actuators must be consecutive")
        self._servo_ctrl = slice(int(servos_ids[0]), int(servos_ids[0]) + len(servos))
        self._windup_band = _ANTI_WINDUP * np.array(
            [max(map(abs, sp.force_range)) / sp.kp for sp in servos])
        self._setpoint = np.zeros(len(servos))
        self._rates = np.zeros(len(servos))
        self._chain_rates = [
            (i, machine.chains[n].chain, self.index.dof_adr[machine.chains[n].driven_joint])
            for i, n in enumerate(self.index.independent_names) if n in machine.chains]
        self._command = ActuatorCommand.zero()
        self._snapshot = (self.data.qpos.copy(), self.data.qvel.copy(), 0.0)
        self._snapshot_setpoint = self._setpoint.copy()
        self._settled: dict = {}  # reset() arguments -> (settled MjData, servo setpoints)
        self.reset()

    # ------------------------------------------------------------------ commands
    @property
    def command(self) -> ActuatorCommand:
        """The command applied at every step until the next `set_command`."""
        return self._command

    def set_command(self, cylinder_rates=None, wrist_rates=None, wheel_speeds=None) -> None:
        """Set the actuator command (held until changed). A part left None is zero.

        Args:
            cylinder_rates: Stroke rates [m/s]: a mapping by name (bogie_L, bogie_R, slew,
                lift, tilt, telescope; missing names are zero) or an array of shape (6,) in
                that order.
            wrist_rates: Joint rates [rad/s]: a mapping by name (wrist_pitch, wrist_roll,
                rotator) or an array of shape (3,).
            wheel_speeds: (left, right) wheel speeds [rad/s]; each drives both wheels of its
                side.

        Raises:
            CommandError: Wrong shape, unknown name or non-finite value.
        """
        self.apply(ActuatorCommand(_rates("cylinder_rates", cylinder_rates, self._cylinders),
                                   _rates("wrist_rates", wrist_rates, self._wrist),
                                   _rates("wheel_speeds", wheel_speeds, ("left", "right"))))

    def apply(self, command: ActuatorCommand) -> None:
        """Set the actuator command from an `ActuatorCommand` (held until changed)."""
        if not isinstance(command, ActuatorCommand):
            raise CommandError(f"expected an ActuatorCommand, got {command!r}")
        lo, hi = self._rate_range[:, 0], self._rate_range[:, 1]
        self._rates = np.minimum(np.maximum(command.servo_rates, lo), hi)
        left, right = command.wheel_speeds
        lo, hi = self._wheel_range
        self.data.ctrl[self.index.wheel_actuators] = np.minimum(np.maximum(
            np.array((left, left, right, right)), lo), hi)  # FL, RL, FR, RR
        self._command = command

    # ------------------------------------------------------------------ time stepping
    @property
    def time(self) -> float:
        """Simulation time of MuJoCo's current state [s]."""
        return float(self.data.time)

    @property
    def timestep(self) -> float:
        """[s]."""
        return float(self.model.opt.timestep)

    def reset(self, q_ind=None, base_xy_yaw=(0.0, 0.0, 0.0),
              settle_time: float = DEFAULT_SETTLE_TIME, reuse_settled: bool = True) -> None:
        """Place the machine on the terrain with its chains closed and let it settle.

        The base is fitted to the terrain under the wheels (`place_on_terrain`), lifted until
        no wheel penetrates MuJoCo's ground, and the servos are preloaded with their static
        loads. It is then simulated for ``settle_time`` with every servo holding and the
        wheels braked, during the first two thirds with all velocities decaying by 2 % per
        step. The clock then restarts at 0 and the command is zero. The settled state is
        kept, so resetting again with the same arguments only copies it back.

        Args:
            q_ind: Independent coordinates, shape (13,); `TreeCoordinates.home` if None.
            base_xy_yaw: Base (x [m], y [m], heading [rad]) in the world.
            settle_time: Settling time [s], >= 0.
            reuse_settled: Reuse the state settled earlier with the same arguments; pass
                False after changing `model` parameters.
        """
        if not (isinstance(settle_time, (int, float)) and math.isfinite(settle_time)
                and settle_time >= 0):
            raise SimulatorError(f"settle_time must be a finite time >= 0 s, got {settle_time!r}")
        m, d = self.model, self.data
        try:
            q_key = self.coordinates.home() if q_ind is None else q_ind
            key = (tuple(np.asarray(q_key, float).ravel().tolist()),
                   tuple(float(v) for v in base_xy_yaw), float(settle_time))
        except (TypeError, ValueError):
            key = None  # bad arguments: home_keyframe says what is wrong
        if not reuse_settled:
            self._settled.clear()
        if key in self._settled:
            settled, setpoint = self._settled[key]
            mujoco.mj_copyData(d, m, settled)
            self._setpoint = setpoint.copy()
            self.apply(ActuatorCommand.zero())
            self._take_snapshot()
            return
        mujoco.mj_resetData(m, d)
        qpos, ctrl = home_keyframe(self.machine, self.terrain, q_ind, base_xy_yaw)
        d.qpos[:] = qpos
        self.apply(ActuatorCommand.zero())
        for _ in range(5):  # MuJoCo's own distances: lift out of any residual penetration
            mujoco.mj_forward(m, d)
            dist = [d.contact[i].dist for i in range(d.ncon)]
            if not dist or min(dist) >= -1e-6:
                break
            d.qpos[self.index.base_qpos[2]] -= min(dist)
        self._setpoint = ctrl[:len(self.index.servos)].copy()  # preloaded by gravity
        # Settle: first with every velocity decaying (a uniform scaling keeps the chains'
        # velocities consistent), so the lightly damped crane need not ring out by itself.
        n = int(round(settle_time / self.timestep))
        n_decay = int(_SETTLE_DECAY_FRACTION * n) // _WINDUP_STEPS
        for _ in range(n_decay):
            self.step(_WINDUP_STEPS)
            d.qvel[:] *= (1.0 - _SETTLE_DECAY_PER_STEP) ** _WINDUP_STEPS
        if n > n_decay * _WINDUP_STEPS:
            self.step(n - n_decay * _WINDUP_STEPS)
        d.time = 0.0
        d.ctrl[self._servo_ctrl] = self._setpoint - self._damping_lead * d.qvel[
            self.index.servo_dof]
        mujoco.mj_forward(m, d)
        self._take_snapshot()
        self._check_warnings()
        if key is not None:
            if len(self._settled) >= _SETTLED_CACHE:
                self._settled.pop(next(iter(self._settled)))
            self._settled[key] = (copy.copy(d), self._setpoint.copy())

    def step(self, n: int = 1) -> None:
        """Advance ``n`` timesteps with the current command.

        Raises:
            SimulationError: MuJoCo flagged a bad state (the simulation diverged).
        """
        if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
            raise SimulatorError(f"n must be a positive integer, got {n!r}")
        m, d, ix = self.model, self.data, self.index
        lo, hi = self._stroke_range[:, 0], self._stroke_range[:, 1]
        band, lead = self._windup_band, self._damping_lead
        servo_ctrl, servo_dof = d.ctrl[self._servo_ctrl], ix.servo_dof
        done = 0
        while done < n:
            # The valve: the setpoint moves at the commanded rate within the stroke range (its
            # path over a few steps is known in advance), and no further than full-force
            # deflection from the stroke (anti-windup of a stalled cylinder, applied after
            # every _WINDUP_STEPS steps).
            chunk = min(_WINDUP_STEPS, n - done)
            path = self._setpoint + np.outer(np.arange(chunk + 1), self.timestep * self._rates)
            path = np.minimum(np.maximum(path, lo), hi)
            for k in range(chunk):
                if done + k == n - 1:
                    self._setpoint = path[k]
                    self._take_snapshot()
                # Servo force kp (u - x) with u = setpoint - (kv / kp) x_dot: the damping is
                # explicit, outside MuJoCo's implicit integration (see `models.mujoco_model`).
                np.subtract(path[k], lead * d.qvel[servo_dof], out=servo_ctrl)
                mujoco.mj_step(m, d)
            x = d.qpos[ix.servo_qpos]
            self._setpoint = np.minimum(np.maximum(path[chunk], x - band), x + band)
            done += chunk
        self._check_warnings()

    def _take_snapshot(self) -> None:
        d = self.data
        self._snapshot = (d.qpos.copy(), d.qvel.copy(), float(d.time))
        self._snapshot_setpoint = self._setpoint.copy()

    def _check_warnings(self) -> None:
        counts = self.data.warning.number
        for w in _FATAL_WARNINGS:
            if counts[w]:
                name = mujoco.mjtWarning(w).name
                raise SimulationError(f"MuJoCo warning {name} at t = {self.time:.4f} s: the "
                                      f"simulation diverged")

    def warning_counts(self) -> dict[str, int]:
        """MuJoCo's warning counters since the last reset, by warning name."""
        counts = self.data.warning.number
        return {name: int(counts[int(w)])
                for name, w in mujoco.mjtWarning.__members__.items() if name != "mjNWARNING"}

    # ------------------------------------------------------------------ measurements
    @property
    def measured_instant(self) -> tuple[np.ndarray, np.ndarray, float]:
        """(qpos, qvel, time) of the instant `measure` reports, in MuJoCo's layout (copies).

        ``data.qacc``, the contact list and every other derived quantity in `data` belong to
        this state, not to ``data.qpos``/``data.qvel`` (see the module docstring).
        """
        qpos, qvel, t = self._snapshot
        return qpos.copy(), qvel.copy(), t

    def closure_violation(self) -> float:
        """Largest distance between the two points of a loop closure [m], measured instant."""
        pairs = self.index.loop_site_pairs
        gap = self.data.site_xpos[pairs[:, 0]] - self.data.site_xpos[pairs[:, 1]]
        return float(np.sqrt(np.einsum("ij,ij->i", gap, gap).max()))

    def measure(self) -> tuple[MachineState, WheelContacts]:
        """The machine state and the ground-truth wheel contacts at the last instant evaluated.

        Returns:
            (state, contacts): ``state`` is what sensors would give (with `MeasurementNoise`
            if set): base pose, twist and its derivative, independent q, qd, qdd (strokes are
            the piston joints; stroke rates come through the driven joints), measured
            contacts, suspension cylinder forces (positive extends) and the nine axis
            servos' setpoints (`MachineState.servo_setpoint`). All 13 actuator forces
            [N, N m] in independent order are `actuator_forces`.
            ``contacts`` is MuJoCo's exact contact state (see `wheel_contacts`); without noise
            ``state.contacts`` is that same object.
        """
        qpos, qvel, t = self._snapshot
        d, ix = self.data, self.index
        rotation = d.xmat[ix.base_body].reshape(3, 3).copy()  # of the measured instant
        position = d.xpos[ix.base_body].copy()
        twist, accel = _body_motion(rotation, qvel[ix.base_dof], d.qacc[ix.base_dof])
        truth = self.wheel_contacts(position, rotation)
        q = qpos[ix.independent_qpos]
        qd = qvel[ix.independent_dof].copy()
        qdd = d.qacc[ix.independent_dof].copy()
        # Stroke rates through the driven joint (eq. 6: x_dot = theta_dot / k1): MuJoCo's
        # soft loop closures let the light piston's acceleration differ from the heavy driven
        # link's by their stabilisation term, and the driven link carries the dynamics.
        for i, chain, dof in self._chain_rates:
            k1, dk1 = chain.driven_rate_coefficients(q[i])
            qd[i] = qvel[dof] / k1
            qdd[i] = (d.qacc[dof] - dk1 * qd[i] * qd[i]) / k1
        suspension = d.actuator_force[ix.suspension_actuators]
        measured = truth
        if self.noise is not None:
            nz, rng = self.noise, self._rng
            twist = twist + rng.normal(0.0, nz.base_twist, 6)
            accel = accel + rng.normal(0.0, nz.base_acceleration, 6)
            q = q + rng.normal(0.0, nz.q, N_INDEPENDENT)
            qd = qd + rng.normal(0.0, nz.qd, N_INDEPENDENT)
            qdd = qdd + rng.normal(0.0, nz.qdd, N_INDEPENDENT)
            suspension = suspension + rng.normal(0.0, nz.suspension_force, 2)
            measured = WheelContacts(
                truth.in_contact.copy(),
                truth.force_in_fb + rng.normal(0.0, nz.contact_force, (4, 3)),
                truth.point_in_fb.copy(), truth.normal_in_fb.copy())
        state = MachineState(
            base_position=position, base_rotation=rotation, base_twist=twist,
            base_acceleration=accel, q=q, qd=qd, qdd=qdd, time=t, contacts=measured,
            suspension_force=suspension, servo_setpoint=self._snapshot_setpoint)
        return state, truth

    def actuator_forces(self) -> np.ndarray:
        """All 13 actuator forces [N, N m] in independent order (MuJoCo's, oracle data)."""
        return self.data.actuator_force[self.index.actuators].copy()

    def wheel_contacts(self, base_position=None, base_rotation=None) -> WheelContacts:
        """Ground-truth wheel contacts from MuJoCo at the measured instant.

        For each wheel, the ground's force on it is summed over the wheel's contacts. Per
        contact this is ``mj_contactForce`` (in the contact frame, acting on the contact's
        second geom; its sign is flipped when the wheel is the first geom), which for the
        model's elliptic cones is the contact's rows of ``efc_force``, read here for all
        contacts at once. The contact point is the normal-force-weighted mean of the contact
        points, the normal the normalised weighted mean of the contact normals (out of the
        ground). A wheel is in contact when its normal force exceeds
        `CONTACT_FORCE_THRESHOLD`; otherwise its point is the wheel's point nearest the
        terrain plane below it and its normal that plane's normal. Everything in fb.

        Args:
            base_position: fb origin in the world [m], shape (3,); measured if None.
            base_rotation: Rotation world <- fb, shape (3, 3); measured if None.
        """
        d, ix = self.data, self.index
        if base_position is None or base_rotation is None:
            base_position = d.xpos[ix.base_body]
            base_rotation = d.xmat[ix.base_body].reshape(3, 3)
        force, point, normal, normal_force = (np.zeros((4, 3)), np.zeros((4, 3)),
                                              np.zeros((4, 3)), np.zeros(4))
        n = d.ncon
        if n:
            contact = d.contact
            geoms = contact.geom
            wheel = self._wheel_of_geom[geoms[:, 1]]
            sign = 1.0
            rows = contact.efc_address
            if (wheel < 0).any() or (rows < 0).any():  # not the usual (ground, wheel) pairs
                first = wheel < 0
                wheel = np.where(first, self._wheel_of_geom[geoms[:, 0]], wheel)
                sign = np.where(first, -1.0, 1.0)[:, None]
                keep = (wheel >= 0) & (rows >= 0)
                wheel, rows, sign = wheel[keep], rows[keep], sign[keep]
                frames = contact.frame[keep].reshape(-1, 3, 3)
                positions = contact.pos[keep]
            else:
                frames = contact.frame.reshape(n, 3, 3)
                positions = contact.pos
            if wheel.size:
                f_contact = d.efc_force[rows[:, None] + _CONTACT_ROWS]  # normal, t1, t2
                fn = f_contact[:, :1]
                select = np.zeros((4, wheel.size))
                select[wheel, np.arange(wheel.size)] = 1.0
                # Rows of frames are the normal (geom 0 -> geom 1) and tangents: f^T frame.
                force = select @ (sign * (f_contact[:, None, :] @ frames)[:, 0])
                normal_force = select @ fn[:, 0]
                point = select @ (fn * positions)
                normal = select @ (sign * fn * frames[:, 0])
        in_contact = normal_force > CONTACT_FORCE_THRESHOLD
        if in_contact.all():
            point /= normal_force[:, None]
            normal /= np.sqrt(np.einsum("ij,ij->i", normal, normal))[:, None]
        else:
            touching = np.flatnonzero(in_contact)
            point[touching] /= normal_force[touching, None]
            normal[touching] /= np.sqrt(np.einsum("ij,ij->i", normal[touching],
                                                  normal[touching]))[:, None]
            radius = self.machine.wheel_radius
            for k in np.flatnonzero(~in_contact):
                c = d.xpos[ix.wheel_bodies[k]]
                try:
                    normal[k] = self.terrain.normal(c[0], c[1])
                except TerrainError:  # driven off the terrain
                    normal[k] = (0.0, 0.0, 1.0)
                point[k] = c - radius * normal[k]
        rotation = np.asarray(base_rotation)  # rows of (f @ R) are R^T f
        return WheelContacts(in_contact=in_contact, force_in_fb=force @ rotation,
                             point_in_fb=(point - base_position) @ rotation,
                             normal_in_fb=normal @ rotation)
