"""MuJoCo simulator of the machine: commands in, consistent machine state and contacts out.

Units and frames: SI; the world has z up; ``fb`` is the floating-base (chassis) frame. Every
per-wheel array is ordered FL, RL, FR, RR.

Commands (`ActuatorCommand`, `Simulator.set_command`): stroke rates of the six hydraulic
cylinders [m/s] (bogie_L, bogie_R, slew, lift, tilt, telescope), joint rates of the wrist
[rad/s] (wrist_pitch, wrist_roll, rotator), and one wheel speed per side [rad/s] (left
drives FL and RL, right drives FR and RR). Each servo is a valve-controlled cylinder (see
`models.mujoco`): its setpoint moves at the commanded rate, clipped to the valve's
rate range and the stroke range, and the cylinder follows with ``F = kp (s - x) - kv x_dot``
up to its force limit; the damping term is applied here, explicitly, before every step.

Contacts: MuJoCo steps through `models.mujoco.ContactMerge`, which keeps one contact per wheel
and terrain face where the height field reports several coincident ones (one per triangle
prism the wheel reaches).

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

import mujoco
import numpy as np

from models.description import Machine
from models.mujoco import (
    DEFAULT_TIMESTEP,
    ContactMerge,
    DampingSchedule,
    MujocoIndex,
    build_model,
    home_keyframe,
    servo_specs,
)
from models.state import MachineState, WheelContacts
from models.terrain import Terrain
from scenarios.commands import ActuatorCommand, rates_by_name
from scenarios.errors import CommandError, SimulationError, SimulatorError
from scenarios.measured import Measurement
from scenarios.noise import MeasurementNoise
from scenarios.step_c import compiled_step

__all__ = ["Simulator"]

DEFAULT_SETTLE_TIME = 1.5  # [s]
_SETTLE_DECAY_FRACTION = 2.0 / 3.0  # of the settling time spent with decaying velocities
_SETTLE_DECAY_PER_STEP = 0.02  # velocity lost per step meanwhile
_SETTLED_CACHE = 4  # settled states kept by reset()
_WINDUP_STEPS = 5  # anti-windup applied every this many steps
# The servos' damping cap (`DampingSchedule`) follows the pose every this many steps: the
# inertias change over seconds of crane motion, and the cap keeps a factor 2 to the limit.
_DAMPING_UPDATE_STEPS = 25
# With a zero drive command on both sides the hydrostatic drive holds the wheels where they
# stand (zero swashplate angle, then the parking brake): each wheel's velocity servo is
# given ``WHEEL_HOLD_GAIN (angle_held - angle)`` [rad/s], a stiff position hold within the
# drive's torque. Without it a velocity servo lets the machine creep down a slope (0.66 m in
# 10 s facing down a 12 deg slope).
WHEEL_HOLD_GAIN = 20.0  # [1/s]
_ANTI_WINDUP = 1.5  # servo setpoint kept within this many full-force deflections of the joint
_FATAL_WARNINGS = tuple(int(w) for w in (
    mujoco.mjtWarning.mjWARN_BADQPOS, mujoco.mjtWarning.mjWARN_BADQVEL,
    mujoco.mjtWarning.mjWARN_BADQACC, mujoco.mjtWarning.mjWARN_BADCTRL))


class Simulator:
    """The machine on a terrain in MuJoCo, driven like the real one.

    Args:
        machine: The machine description.
        terrain: The ground.
        timestep: Simulation timestep [s].
        noise: Noise added to the measured state; None for exact measurements.
        compiled: Step in C (`scenarios.step_c`, the same bits) where a compiler is there
            and every step listener has a step hook; False: in Python.

    Attributes:
        machine, terrain: As given.
        model, data: The MuJoCo model and data (read them; change them at your own risk).
        index: Addresses in the model (`MujocoIndex`).
        coordinates: Independent <-> tree coordinate map.
        servos: Limits and gains of the nine servos (`ServoSpec`), independent order.
    """

    def __init__(self, machine: Machine, terrain: Terrain, timestep: float = DEFAULT_TIMESTEP,
                 noise: MeasurementNoise | None = None, compiled: bool = True):
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
        self._measurement = Measurement(self.model, self.data, self.index, machine, terrain,
                                        noise, self._rng)
        self.servos = servo_specs(machine, self.model.opt.timestep)
        servos = self.servos
        self._rate_range = np.array([sp.rate_range for sp in servos]).T.copy()  # lo, hi
        self._wheel_range = self.model.actuator_ctrlrange[self.index.wheel_actuators].T.copy()
        self._stroke_range = np.array([sp.stroke_range for sp in servos])
        self._damping = DampingSchedule(self.model, self.index, machine, servos,
                                        self.model.opt.timestep)
        self._damping_lead = np.zeros(len(servos))
        self._damping_age = _DAMPING_UPDATE_STEPS  # steps since the lead was computed
        # MuJoCo's step and forward with each wheel's coincident height-field contacts merged
        self._contact_merge = ContactMerge(self.model, self.index.wheel_geoms)
        servos_ids = self.index.servos
        if not np.array_equal(servos_ids, np.arange(servos_ids[0], servos_ids[0] + len(servos))):
            raise SimulatorError("the servo actuators must be consecutive")
        self._servo_ctrl = slice(int(servos_ids[0]), int(servos_ids[0]) + len(servos))
        self._windup_band = _ANTI_WINDUP * np.array(
            [max(map(abs, sp.force_range)) / sp.kp for sp in servos])
        self._setpoint = np.zeros(len(servos))
        self._rates = np.zeros(len(servos))
        self._command = ActuatorCommand.zero()
        self._wheel_qpos = self.index.independent_qpos[9:13]
        self._wheel_ctrl = self.index.wheel_actuators
        self._wheel_ctrl_list = [int(i) for i in self._wheel_ctrl]  # `apply`'s, as ints
        self._wheel_range_lists = self._wheel_range.tolist()  # lo (4,), hi (4,)
        self._hold: np.ndarray | None = None  # wheel angles held at a zero drive command
        self._snapshot = (self.data.qpos.copy(), self.data.qvel.copy(), 0.0)
        self._snapshot_setpoint = self._setpoint.copy()
        self._settled: dict = {}  # reset() arguments -> (settled MjData, servo setpoints)
        self._listeners: list = []
        self._compiled = compiled
        self._bind_step()
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
        self.apply(ActuatorCommand(
            rates_by_name("cylinder_rates", cylinder_rates, self._cylinders),
            rates_by_name("wrist_rates", wrist_rates, self._wrist),
            rates_by_name("wheel_speeds", wheel_speeds, ("left", "right"))))

    def apply(self, command: ActuatorCommand) -> None:
        """Set the actuator command from an `ActuatorCommand` (held until changed)."""
        if not isinstance(command, ActuatorCommand):
            raise CommandError(f"expected an ActuatorCommand, got {command!r}")
        lo, hi = self._rate_range
        np.minimum(np.maximum(command.servo_rates, lo), hi, out=self._rates)  # C reads it
        left, right = command.wheel_speeds.tolist()
        ctrl = self.data.ctrl  # np.minimum(np.maximum(...)) of finite floats: its choices
        for i, v, lo_i, hi_i in zip(self._wheel_ctrl_list, (left, left, right, right),
                                    *self._wheel_range_lists):  # FL, RL, FR, RR
            ctrl[i] = min(max(v, lo_i), hi_i)
        if left == 0.0 and right == 0.0:
            if self._hold is None:
                self._hold = self.data.qpos[self._wheel_qpos].copy()
        else:
            self._hold = None
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
            self._damping_age = _DAMPING_UPDATE_STEPS  # recomputed at the settled pose
            self._setpoint = setpoint.copy()
            self._hold = None
            self.apply(ActuatorCommand.zero())
            self._take_snapshot()
            return
        mujoco.mj_resetData(m, d)
        qpos, ctrl = home_keyframe(self.machine, self.terrain, q_ind, base_xy_yaw)
        d.qpos[:] = qpos
        self._hold = None
        self.apply(ActuatorCommand.zero())
        self._damping_age = _DAMPING_UPDATE_STEPS
        for _ in range(5):  # MuJoCo's own distances: lift out of any residual penetration
            self._contact_merge.forward(d)
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
        self._damping_age = _DAMPING_UPDATE_STEPS  # as after restoring the settled state
        d.ctrl[self._servo_ctrl] = self._setpoint - self._lead() * d.qvel[self.index.servo_dof]
        self._contact_merge.forward(d)
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
        done = 0
        while done < n:
            # The valve: the setpoint moves at the commanded rate within the stroke range (its
            # path over a few steps is known in advance), and no further than full-force
            # deflection from the stroke (anti-windup of a stalled cylinder, applied after
            # every _WINDUP_STEPS steps).
            chunk = min(_WINDUP_STEPS, n - done)
            lead = self._lead()  # the damping this pose allows (`DampingSchedule`)
            self._damping_age += chunk
            if self._c_step is None:
                self._chunk(chunk, n - 1 - done, lead)
            else:  # `_chunk` in C, the setpoint written in place
                snap, warned = self._c_step.run(chunk, n - 1 - done, self._setpoint, self._hold)
                if snap is not None:
                    self._snapshot, self._snapshot_setpoint = snap
                if warned:
                    self._check_warnings()
            done += chunk
        if self._c_step is None:
            self._check_warnings()

    def _chunk(self, chunk: int, snap: int, lead: np.ndarray) -> None:
        """``chunk`` steps; the snapshot taken before step ``snap`` (if in the chunk)."""
        d, ix = self.data, self.index
        lo, hi = self._stroke_range[:, 0], self._stroke_range[:, 1]
        servo_ctrl, servo_dof = d.ctrl[self._servo_ctrl], ix.servo_dof
        path = self._setpoint + np.outer(np.arange(chunk + 1), self.timestep * self._rates)
        path = np.minimum(np.maximum(path, lo), hi)
        for k in range(chunk):
            if k == snap:
                self._setpoint = path[k]
                self._take_snapshot()
            # Servo force kp (u - x) with u = setpoint - (kv / kp) x_dot: the damping is
            # explicit, outside MuJoCo's implicit integration (see `models.mujoco`).
            np.subtract(path[k], lead * d.qvel[servo_dof], out=servo_ctrl)
            if self._hold is not None:
                self._hold_wheels()
            if self._listeners:
                self._step_with_listeners()
            else:
                self._contact_merge.step(d)
        x = d.qpos[ix.servo_qpos]
        band = self._windup_band
        self._setpoint = np.minimum(np.maximum(path[chunk], x - band), x + band)

    def _lead(self) -> np.ndarray:
        if self._damping_age >= _DAMPING_UPDATE_STEPS:
            self._damping_lead[:] = self._damping.lead(  # in place: the C reads it
                self.data, self.data.qpos[self.index.independent_qpos])
            self._damping_age = 0
        return self._damping_lead

    def _hold_wheels(self) -> None:
        d = self.data
        lo, hi = self._wheel_range
        d.ctrl[self._wheel_ctrl] = np.minimum(np.maximum(
            WHEEL_HOLD_GAIN * (self._hold - d.qpos[self._wheel_qpos]), lo), hi)

    def add_step_listener(self, listener) -> None:
        """Call ``listener(sim, qpos, qvel, t)`` after every physics step.

        ``qpos``, ``qvel`` (read-only; copy to keep) and ``t`` are the state the step started
        from: every derived quantity in `data` (accelerations, contact and actuator forces,
        poses, MuJoCo sensors) belongs to that instant (see the module docstring). Listeners
        sample sensors and count physics-rate metrics; they must not change the simulation.
        Settling (`reset`) calls them too; remove them with `remove_step_listener`.
        """
        if not callable(listener):
            raise SimulatorError(f"a step listener must be callable, got {listener!r}")
        self._listeners.append(listener)
        self._bind_step()

    def remove_step_listener(self, listener) -> None:
        """Stop calling ``listener`` (no error if it was not added)."""
        if listener in self._listeners:
            self._listeners.remove(listener)
            self._bind_step()

    def _bind_step(self) -> None:
        """The steps in C (`scenarios.step_c`) if compiled and every listener has a hook."""
        ix, (wheel_lo, wheel_hi) = self.index, self._wheel_range
        self._c_step = compiled_step(self.model, self.data, self._contact_merge, dict(
            servo_ctrl=self._servo_ctrl.start, servo_dof=ix.servo_dof,
            servo_qpos=ix.servo_qpos, lo=self._stroke_range[:, 0], hi=self._stroke_range[:, 1],
            band=self._windup_band, wheel_qpos=self._wheel_qpos, wheel_ctrl=self._wheel_ctrl,
            wheel_lo=wheel_lo, wheel_hi=wheel_hi, hold_gain=WHEEL_HOLD_GAIN,
            rates=self._rates, lead=self._damping_lead),
            self._listeners) if self._compiled else None

    def _step_with_listeners(self) -> None:
        d = self.data
        qpos, qvel, t = d.qpos.copy(), d.qvel.copy(), float(d.time)
        qpos.flags.writeable = False
        qvel.flags.writeable = False
        self._contact_merge.step(d)
        for listener in self._listeners:
            listener(self, qpos, qvel, t)

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

    # ------------------------------------------------------------------ measurements
    @property
    def measured_instant(self) -> tuple[np.ndarray, np.ndarray, float]:
        """(qpos, qvel, time) of the instant `measure` reports, in MuJoCo's layout (copies).

        ``data.qacc``, the contact list and every other derived quantity in `data` belong to
        this state, not to ``data.qpos``/``data.qvel`` (see the module docstring).
        """
        qpos, qvel, t = self._snapshot
        return qpos.copy(), qvel.copy(), t

    def measured_arrays(self) -> tuple[np.ndarray, np.ndarray, float, np.ndarray]:
        """`measured_instant` and `servo_setpoint`, the simulator's own: read, not kept."""
        return (*self._snapshot, self._snapshot_setpoint)

    @property
    def servo_setpoint(self) -> np.ndarray:
        """The nine axis servos' setpoints at the measured instant [m, rad], (9,) (a copy)."""
        return self._snapshot_setpoint.copy()

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
        return self._measurement.measure(self._snapshot, self._snapshot_setpoint)

    def actuator_forces(self) -> np.ndarray:
        """All 13 actuator forces [N, N m] in independent order (MuJoCo's, oracle data)."""
        return self.data.actuator_force[self.index.actuators].copy()

    def wheel_contacts(self, base_position=None, base_rotation=None) -> WheelContacts:
        """Ground-truth wheel contacts from MuJoCo at the measured instant, in fb.

        MuJoCo's contact forces summed per wheel (`scenarios.ground_truth`).

        Args:
            base_position: fb origin in the world [m], shape (3,); measured if None.
            base_rotation: Rotation world <- fb, shape (3, 3); measured if None.
        """
        if base_position is None or base_rotation is None:
            base_position = self.data.xpos[self.index.base_body]
            base_rotation = self.data.xmat[self.index.base_body].reshape(3, 3)
        return self._measurement.contacts.read(self.data, base_position, base_rotation)
