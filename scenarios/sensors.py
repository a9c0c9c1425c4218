"""The machine's sensors in the simulator: each physics instant turned into sensor readings.

`SensorSimulator` is a step listener (`Simulator.add_step_listener`): at every physics step
it samples the streams that are due (each at its own rate, on the 2 ms grid), from the
instant the step started at (to which MuJoCo's accelerations and forces belong), adds the
errors of `models.sensing.ChannelSpec` and queues the reading until its latency has passed.
`readings` hands the controller what has been delivered by a tick, as
`models.sensing.SensorReadings`. Both run in C where a compiler is there
(`scenarios.listeners_c`: the same bits, a fifth of the cost), else in the Python below.

What each sensor measures (the truth before the errors):

* IMU at ``p`` (fb axes): specific force ``a_p + R^T g e_z`` with ``a_p = a_o + alpha x p +
  w x (w x p)`` the acceleration of the mounting point (MuJoCo's free-joint acceleration of
  the chassis), and the chassis angular rate;
* stroke sensors and encoders: the nine servo axes' coordinates (piston strokes, joints);
* pressure transducers: the hydraulics deliver the servo's force ``F`` (MuJoCo's actuator
  force: the seal friction, if any, acts on the mechanism besides it). It is split into the
  chambers with the return side at the back pressure `BACK_PRESSURE`: ``F >= 0``: ``p_B =
  p_0``, ``p_A = (F + p_0 A_B) / A_A``; else ``p_A = p_0``, ``p_B = (p_0 A_A - F) / A_B``;
* wheel-motor speeds: the mean spin rate of each side's two wheels;
* drive torques: the sum of each side's two wheel drive torques (MuJoCo's actuator forces);
* link accelerometers at ``p`` on body ``b`` (its axes): ``a_o + alpha x p + w x (w x p)``
  with ``a_o`` the specific force of the body frame's origin and ``w``, ``alpha`` the body's
  angular velocity and acceleration, all in the body's axes (MuJoCo's
  `mj_objectAcceleration` after `mj_rnePostConstraint`, whose root acceleration is
  ``-g``: the specific force).
"""

from __future__ import annotations

import operator

import mujoco
import numpy as np

from models.cbuild import address
from models.rotations import cross3
from models.sensing import (
    N_PRESSURE,
    PRESSURE_CYLINDERS,
    ChannelSpec,
    Samples,
    SensorReadings,
    SensorSpec,
    cylinder_areas,
)
from models.state import N_SERVO_AXES, frozen_array
from scenarios.errors import SimulatorError
from scenarios.listeners_c import N_STREAMS, compiled_delivery, compiled_sensors, sensors_hooks
from scenarios.simulator import Simulator
from scenarios.step_c import StepHook

__all__ = ["BACK_PRESSURE", "SensorSimulator"]

BACK_PRESSURE = 15e5  # [Pa] return-line pressure of a valve-controlled cylinder (15 bar)
_F64 = np.dtype(np.float64)


class _Stream:
    """One stream: its spec, per-channel scale and bias, and the readings waiting.

    The step listener only records the true value (`record`); the errors are applied in one
    vectorized pass when the readings are delivered (`deliver`), bias random walk included,
    so the per-step cost is one row copy.

    Args:
        spec: The channels' error model.
        n: Channels in the reading.
        dt: The physics step [s].
        rng: The suite's random generator.
        transform: Maps the recorded truths (k, m) to the measured quantity (k, n); None:
            identity (m = n).
        m: Width of the recorded truth (default n).
        counts, slot: The readings waiting are ``counts[slot]`` (int64 array shared with
            the compiled listener, `scenarios.listeners_c`); None: the stream's own.
    """

    def __init__(self, spec: ChannelSpec, n: int, dt: float, rng: np.random.Generator,
                 transform=None, m: int | None = None, counts: np.ndarray | None = None,
                 slot: int = 0):
        self.spec = spec
        self.every = max(1, int(round(1.0 / (spec.rate * dt))))
        self.latency = spec.latency
        self.scale = 1.0 + spec.scale * rng.standard_normal(n)
        # Without scale errors the factor is exactly 1.0, whose product changes no bit.
        self._scaled = bool(np.any(self.scale != 1.0))
        self.bias = spec.bias * rng.standard_normal(n)
        self.walk = spec.bias_drift * np.sqrt(self.every * dt)
        self.rng = rng
        self.n = n
        self.transform = transform
        self.times = np.zeros(256)
        self.truths = np.zeros((256, n if m is None else m))
        self._counts = np.zeros(1, np.int64) if counts is None else counts
        self._slot = slot
        self.count = 0

    @property
    def count(self) -> int:
        """Readings recorded and not delivered yet."""
        return int(self._counts[self._slot])

    @count.setter
    def count(self, value: int) -> None:
        self._counts[self._slot] = value

    def grow(self) -> None:
        """Twice the room for readings (a new buffer: the compiled listener's pointers change)."""
        self.times = np.concatenate([self.times, np.zeros_like(self.times)])
        self.truths = np.concatenate([self.truths, np.zeros_like(self.truths)])

    def record(self, t: float, truth) -> None:
        """Record the true value measured at ``t``."""
        c = self.count
        if c == self.times.shape[0]:
            self.grow()
        self.times[c] = t
        self.truths[c] = truth
        self.count = c + 1

    def _errors(self, truth: np.ndarray) -> np.ndarray:
        sp, k = self.spec, truth.shape[0]
        y = self.transform(truth) if self.transform is not None else truth
        if self.walk:
            steps = self.walk * self.rng.standard_normal((k, self.n))
            bias = self.bias + np.cumsum(steps, axis=0) - steps  # the bias at each sample
            self.bias = bias[-1] + steps[-1] if k else self.bias
        else:
            bias = self.bias
        y = self.scale * y + bias if self._scaled else y + bias  # a new array: truths kept
        if sp.noise:
            y += sp.noise * self.rng.standard_normal((k, self.n))
        if sp.resolution:
            np.divide(y, sp.resolution, out=y)
            y.round(out=y)  # np.round's own call, without its Python wrapper
            y *= sp.resolution
        return y

    def deliver(self, tick: float) -> Samples:
        """The readings whose latency has passed by ``tick`` (removed from the queue)."""
        c = self.count
        # The count of times <= the limit (they increase): from the end, where the few still
        # in flight are, rather than a search over all.
        limit, times, k = tick - self.latency + 1e-9, self.times, c
        while k and times[k - 1] > limit:
            k -= 1
        out = Samples.trusted(times[:k].copy(), self._errors(self.truths[:k]))
        rest = c - k
        if rest:
            times[:rest] = times[k:c]
            self.truths[:rest] = self.truths[k:c]
        self.count = rest
        return out


def _body_id(sim: Simulator, name: str) -> int:
    """MuJoCo's id of the description's body ``name``."""
    i = mujoco.mj_name2id(sim.model, mujoco.mjtObj.mjOBJ_BODY, name)
    if i < 0:
        raise SimulatorError(f"a link accelerometer sits on body {name!r}, which the model "
                             f"does not have")
    return i


class SensorSimulator:
    """Samples the machine's sensors from a running `Simulator` (module docstring).

    Args:
        sim: The simulator (the sensors attach as a step listener; `close` detaches them).
        spec: The sensor suite (``spec.oracle`` suites have no sensors: refused).
        compiled: Record in C (`scenarios.listeners_c`, the same bits), if a compiler is
            there; False: in Python.

    Raises:
        SimulatorError: An oracle suite, or a spec that is not a `SensorSpec`.
    """

    def __init__(self, sim: Simulator, spec: SensorSpec, compiled: bool = True):
        if not isinstance(spec, SensorSpec) or spec.oracle:
            raise SimulatorError(f"SensorSimulator needs a SensorSpec with sensors, got "
                                 f"{getattr(spec, 'name', spec)!r}")
        self.sim, self.spec = sim, spec
        rng = np.random.default_rng(spec.seed)
        dt = sim.timestep
        counts = self._counts = np.zeros(N_STREAMS, np.int64)  # in `listeners_c`'s order
        self._acc = _Stream(spec.imu.accelerometer, 3, dt, rng, counts=counts, slot=0)
        self._gyro = _Stream(spec.imu.gyroscope, 3, dt, rng, counts=counts, slot=1)
        self._pos_lin = _Stream(spec.stroke, 6, dt, rng, counts=counts, slot=2)
        self._pos_ang = _Stream(spec.angle, 3, dt, rng, counts=counts, slot=3)
        self._press = _Stream(spec.pressure, 2 * N_PRESSURE, dt, rng,
                              transform=self.chamber_pressures, m=N_PRESSURE, counts=counts,
                              slot=4)
        self._wheels = _Stream(spec.wheel_speed, 2, dt, rng, counts=counts, slot=5)
        self._drive = _Stream(spec.drive_torque, 2, dt, rng, counts=counts, slot=6)
        links = spec.link_accelerometers
        self._link = (_Stream(links[0].accelerometer, 3 * len(links), dt, rng, counts=counts,
                              slot=7) if links else None)
        self._link_bodies = [_body_id(sim, a.body) for a in links]
        self._link_points = [np.asarray(a.position, float) for a in links]
        self._link_f = np.zeros(3 * len(links))
        self._acc6, self._vel6 = np.zeros(6), np.zeros(6)  # MuJoCo's outputs, every step
        self._streams = (self._acc, self._gyro, self._pos_lin, self._pos_ang, self._press,
                         self._wheels, self._drive) + ((self._link,) if links else ())
        self._slots = (*self._streams[:7], self._link)  # by slot of `listeners_c`
        ix = sim.index
        self._p_floats = tuple(np.asarray(spec.imu.position, float).tolist())
        self._g = sim.machine.gravity
        self._base = ix.base_body
        self._base_dof = ix.base_dof
        self._axes_qpos = ix.independent_qpos[:9]
        self._wheel_dof = ix.independent_dof[9:13]
        self._wheel_act = ix.wheel_actuators
        names = sim.coordinates.independent_names
        self._press_act = ix.actuators[[names.index(c) for c in PRESSURE_CYLINDERS]]
        self._areas = cylinder_areas(sim.machine)
        self._n_step = np.zeros(1, np.int64)  # physics steps seen (shared with the C hook)
        self._hook: np.ndarray | None = None  # `SENSORS_C`'s sensors_hook: counter, arguments
        self._compiled = self._bind_compiled(compiled)
        self._delivery = self._bind_delivery(rng)
        self._prime()
        sim.add_step_listener(self)

    def _prime(self) -> None:
        """One reading of every stream, of the measured instant, delivered at once.

        The sensors ran while the machine settled; their last readings are there when the
        run starts (the errors are those of any reading).
        """
        qpos, qvel, t = self.sim.measured_instant
        latency = max(s.latency for s in self._streams)
        self(self.sim, qpos, qvel, t - latency)
        self._n_step[0] = 0

    def _bind_compiled(self, compiled: bool):
        """The arguments of `listeners_c.SENSORS_C` after the step's own; None: Python."""
        record = compiled_sensors() if compiled else None
        if record is None:
            return None
        ix = np.concatenate([[self._base], self._base_dof, self._axes_qpos, self._press_act,
                             self._wheel_dof, self._wheel_act, self._link_bodies]).astype(
                                 np.int64)
        par = np.concatenate([self._p_floats, [self._g], *self._link_points, np.zeros(0)])
        every = np.array([1 if s is None else s.every for s in self._slots], np.int64)
        # Filled by `_buffers`: capacities, times' and truths' addresses (they change on growth)
        caps, times, truths = (np.zeros(N_STREAMS, np.int64), np.zeros(N_STREAMS, np.uint64),
                               np.zeros(N_STREAMS, np.uint64))
        self._c_arrays = (ix, par, every, caps, times, truths)  # kept alive: the C reads them
        self._buffers()
        return record, (every.ctypes.data, self._counts.ctypes.data, caps.ctypes.data,
                        times.ctypes.data, truths.ctypes.data, ix.ctypes.data,
                        par.ctypes.data, len(self._link_bodies))

    def step_hook(self) -> StepHook | None:
        """The recording in C for the simulator's compiled steps (`scenarios.step_c`)."""
        hooks = sensors_hooks() if self._compiled is not None else None
        if hooks is None:
            return None
        if self._hook is None:
            self._hook = np.array([self._n_step.ctypes.data, *self._compiled[1]], np.int64)
        return StepHook(*hooks, self._hook.ctypes.data, self._make_room)

    def _make_room(self, steps: int) -> None:
        for s in self._streams:
            while s.count + steps > s.times.shape[0]:
                s.grow()
        self._buffers()

    def _buffers(self) -> None:
        """The compiled listener's capacities and buffer addresses, after a growth."""
        _, _, _, caps, times, truths = self._c_arrays
        for k, s in enumerate(self._slots):
            if s is not None:
                caps[k] = s.times.shape[0]
                times[k] = s.times.ctypes.data
                truths[k] = s.truths.ctypes.data

    def __call__(self, sim: Simulator, qpos, qvel, t: float) -> None:
        """Sample the streams due at the step that started at ``t`` (a step listener)."""
        n = int(self._n_step[0])
        self._n_step[0] = n + 1
        if self._compiled is not None:
            record, args = self._compiled
            while record(sim.model._address, sim.data._address, qpos.ctypes.data,
                         qvel.ctypes.data, t, n, *args):  # a stream is full
                for s in self._streams:
                    if s.count == s.times.shape[0]:
                        s.grow()
                self._buffers()
            return
        d = sim.data
        acc, gyro = self._acc, self._gyro
        acc_due, gyro_due = n % acc.every == 0, n % gyro.every == 0
        if acc_due or gyro_due:
            # Python floats: the IEEE operations of numpy's scalars, at a fraction of the cost
            rot = d.xmat[self._base].tolist()  # row-major world <- fb
            v6 = qvel[self._base_dof].tolist()
            w0, w1, w2 = v6[3], v6[4], v6[5]
            if acc_due:
                a6 = d.qacc[self._base_dof].tolist()
                al0, al1, al2 = a6[3], a6[4], a6[5]
                p0, p1, p2 = self._p_floats
                # a_p = R^T a_o + alpha x p + w x (w x p), plus R^T g e_z
                c0, c1, c2 = w1 * p2 - w2 * p1, w2 * p0 - w0 * p2, w0 * p1 - w1 * p0
                ax, ay, az = a6[0], a6[1], a6[2] + self._g
                acc.record(t, (rot[0] * ax + rot[3] * ay + rot[6] * az + al1 * p2 - al2 * p1
                               + w1 * c2 - w2 * c1,
                               rot[1] * ax + rot[4] * ay + rot[7] * az + al2 * p0 - al0 * p2
                               + w2 * c0 - w0 * c2,
                               rot[2] * ax + rot[5] * ay + rot[8] * az + al0 * p1 - al1 * p0
                               + w0 * c1 - w1 * c0))
            if gyro_due:
                gyro.record(t, (w0, w1, w2))
        lin, ang = self._pos_lin, self._pos_ang
        lin_due, ang_due = n % lin.every == 0, n % ang.every == 0
        if lin_due or ang_due:
            q = qpos[self._axes_qpos]
            if lin_due:
                lin.record(t, q[:6])
            if ang_due:
                ang.record(t, q[6:])
        if n % self._press.every == 0:
            self._press.record(t, d.actuator_force[self._press_act])
        if n % self._wheels.every == 0:
            wd = qvel[self._wheel_dof].tolist()  # FL, RL, FR, RR
            self._wheels.record(t, (0.5 * (wd[0] + wd[1]), 0.5 * (wd[2] + wd[3])))
        if n % self._drive.every == 0:
            tau = d.actuator_force[self._wheel_act].tolist()  # FL, RL, FR, RR
            self._drive.record(t, (tau[0] + tau[1], tau[2] + tau[3]))
        if self._link is not None and n % self._link.every == 0:
            self._link.record(t, self._link_specific_force(sim))

    def _link_specific_force(self, sim: Simulator) -> np.ndarray:
        """Each link accelerometer's specific force, in its body's axes, (3 k,) [m/s^2]."""
        m, d = sim.model, sim.data
        mujoco.mj_rnePostConstraint(m, d)  # fills cacc (outputs only: the physics is as is)
        acc, vel = self._acc6, self._vel6
        for i, (body, p) in enumerate(zip(self._link_bodies, self._link_points)):
            mujoco.mj_objectAcceleration(m, d, mujoco.mjtObj.mjOBJ_XBODY, body, acc, 1)
            mujoco.mj_objectVelocity(m, d, mujoco.mjtObj.mjOBJ_XBODY, body, vel, 1)
            w, alpha = vel[:3], acc[:3]
            # `cross3`: numpy's cross to the bit, without its ~30 us a call
            self._link_f[3 * i:3 * i + 3] = (acc[3:] + cross3(alpha, p)
                                             + cross3(w, cross3(w, p)))
        return self._link_f

    def chamber_pressures(self, forces) -> np.ndarray:
        """``p_A, p_B`` [Pa] for cylinder forces [N] (module docstring): (..., 5) -> (..., 10)."""
        f = np.asarray(forces, float)
        a_a, a_b = self._areas[:, 0], self._areas[:, 1]
        out = np.empty(f.shape + (2,))  # (..., cylinder, chamber): the layout of the readings
        p_a, p_b = out[..., 0], out[..., 1]
        np.divide(f + BACK_PRESSURE * a_b, a_a, out=p_a)
        np.divide(BACK_PRESSURE * a_a - f, a_b, out=p_b)
        pushing = f >= 0
        p_a[~pushing] = BACK_PRESSURE
        p_b[pushing] = BACK_PRESSURE
        return out.reshape(f.shape[:-1] + (2 * N_PRESSURE,))

    def _bind_delivery(self, rng: np.random.Generator):
        """`listeners_c.DELIVER_C`'s functions and arguments; None: `_Stream.deliver`."""
        passes = compiled_delivery() if self._compiled is not None else None  # its bind
        if passes is None or max(s.n for s in self._streams) > 64:
            return None
        slots = self._slots

        def per_slot(value, dtype=float) -> np.ndarray:
            return np.array([0 if s is None else value(s) for s in slots], dtype)

        latency, walk = per_slot(lambda s: s.latency), per_slot(lambda s: s.walk)
        noise, res = per_slot(lambda s: s.spec.noise), per_slot(lambda s: s.spec.resolution)
        width, twidth = per_slot(lambda s: s.n, np.int64), per_slot(
            lambda s: s.truths.shape[1], np.int64)
        scale, bias = (per_slot(lambda s: s.scale.ctypes.data, np.uint64),
                       per_slot(lambda s: s.bias.ctypes.data, np.uint64))
        scaled = per_slot(lambda s: s._scaled, np.int32)
        # the order the Python path draws its normals in (`readings`)
        ordered = (self._pos_lin, self._pos_ang, self._acc, self._gyro, self._press,
                   self._wheels, self._drive) + (() if self._link is None else (self._link,))
        order = np.array([slots.index(s) for s in ordered], np.int64)
        k = np.zeros(N_STREAMS, np.int64)
        areas = np.ascontiguousarray(self._areas, float)
        _, _, _, _, times, truths = self._c_arrays
        words = dict(ns=N_STREAMS, count=self._counts, times=times, latency=latency,
                     width=width, walk=walk, noise=noise, k=k, n_order=len(ordered),
                     order=order, truths=truths, twidth=twidth, scale=scale, scaled=scaled,
                     bias=bias, res=res, press=slots.index(self._press), areas=areas,
                     back=np.array([BACK_PRESSURE]))
        count, fill, packed = passes(words)
        self._d_arrays = (words, packed)  # kept alive: the C reads them
        return count, fill, rng, k, [slots.index(s) for s in ordered], [s.n for s in ordered]

    def _readings_compiled(self, tick: float) -> SensorReadings:
        """`readings` by `DELIVER_C`: the Python path's numbers.

        The streams in the order `_bind_delivery` draws them (the linear and the angular
        positions first, then acceleration, angular rate, pressure, wheel speed, drive
        torque, link accelerometers), their times and values in one new read-only array
        (times first) that each stream's `Samples` views; the two positions' joined.
        """
        count, fill, rng, k, order, widths = self._delivery
        z = rng.standard_normal(count(tick))
        ks = k.tolist()
        sizes = [ks[i] for i in order]
        n_t = sum(sizes)
        n_y = n_t + sum(map(operator.mul, sizes, widths))
        out = np.empty(n_y + N_SERVO_AXES)  # times, values, then the servos' setpoints
        at, sp = address(out), self.sim.measured_arrays()[3]
        # the setpoints copied by the C where they are a contiguous (9,) float64 array (else
        # it copies the slot onto itself) and finite; else `frozen_array`'s copy or error
        plain = (type(sp) is np.ndarray and sp.dtype == _F64 and sp.shape == (N_SERVO_AXES,)
                 and sp.strides == (8,))
        copied = not fill(address(z), at, at + 8 * n_t, address(sp) if plain
                          else at + 8 * n_y, at + 8 * n_y) and plain
        out.flags.writeable = False  # the views below are read-only too
        setpoint = out[n_y:] if copied else frozen_array("servo_setpoint", sp, (N_SERVO_AXES,))
        out_t, out_y = out[:n_t], out[n_t:n_y]
        wrap = Samples.of_read_only
        got, first, first_y = [], 0, 0
        for kk, n in zip(sizes, widths):
            last, last_y = first + kk, first_y + kk * n
            got.append((out_t[first:last], out_y[first_y:last_y].reshape(kk, n)))
            first, first_y = last, last_y
        (lin_t, lin_y), (ang_t, ang_y), acc, gyro, press, wheels, drive, *link = got
        n = min(lin_t.shape[0], ang_t.shape[0])
        positions = Samples.trusted(lin_t[:n], np.concatenate((lin_y[:n], ang_y[:n]), axis=1))
        return SensorReadings.trusted(
            tick, wrap(*acc), wrap(*gyro), positions, wrap(*press), wrap(*wheels),
            wrap(*drive), setpoint, wrap(*link[0]) if link else None)

    def readings(self, tick: float) -> SensorReadings:
        """What the sensors delivered by ``tick`` [s] since the previous call."""
        if self._delivery is not None:
            return self._readings_compiled(float(tick))
        lin = self._pos_lin.deliver(tick)
        ang = self._pos_ang.deliver(tick)
        n = min(len(lin), len(ang))
        positions = Samples.trusted(lin.time[:n], np.concatenate((lin.value[:n], ang.value[:n]),
                                                                 axis=1))
        return SensorReadings(
            time=float(tick), specific_force=self._acc.deliver(tick),
            angular_rate=self._gyro.deliver(tick), positions=positions,
            pressures=self._press.deliver(tick), wheel_speeds=self._wheels.deliver(tick),
            drive_torques=self._drive.deliver(tick),
            servo_setpoint=self.sim.servo_setpoint,
            link_specific_force=None if self._link is None else self._link.deliver(tick))

    def close(self) -> None:
        """Detach from the simulator."""
        self.sim.remove_step_listener(self)
