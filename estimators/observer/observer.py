r"""The observer: from the machine's sensor streams to the state the estimator and MPC read.

Once per control tick (`Observer.update`) it takes the readings delivered since the last tick
(`models.sensing.SensorReadings`) and returns an `ObserverEstimate`:

* the chassis (`base_filter.BaseFilter`): attitude, twist and the acceleration the
  dynamics need (the measured specific force, whatever the attitude error);
* the nine servo axes' positions, velocities and accelerations (`joint_filter.JointFilter`,
  run over every sample, predicted to the tick), the wheels' angles and speeds from the
  wheel-motor speeds;
* the suspension cylinder forces from their chamber pressures (mean over the tick);
* the contact flags from the forces themselves (`contacts.ContactTracker`): a wheel whose
  estimated normal force falls below `CONTACT_OFF_N` is out of contact until its four-wheel
  estimate has stayed above `CONTACT_ON_N` for `CONTACT_TICKS` ticks (a wheel bouncing off
  the ground reads high before it lands) or exceeds `CONTACT_LANDING_N` once (an impact;
  `docs/sensors.md`); the estimator then solves the three-wheel system of Sec. III-B. The
  contact points are the wheels' lowest points (the estimator's geometry), the friction
  forces zero: no per-wheel measurement exists, and the estimator takes the tangential
  forces the dynamics require at the contacts' mean height (`estimators.full_dynamics`),
  except the longitudinal forces, which each side's drive torque gives
  (`ContactTracker.longitudinal`);
* the payload mass from the lift and tilt cylinder pressures (`payload_rls.PayloadRLS`),
  with pick and release events;
* `uncertainty`: the standard deviations of its errors (`estimators.uncertainty`).

The contact flags need the forces: `update` runs the given force model (a closure estimator,
cylinder-force fourth row, with the payload estimate) once per tick at the four-wheel
state; its forces are in the estimate (``forces_four``).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from estimators.efforts import ActuatorEfforts
from estimators.errors import EstimatorError
from estimators.linearization import N_GENERALIZED
from estimators.observer import _tail, filters_c, link_fusion
from estimators.observer._states import StateBuffer, wheel_contacts, with_fields
from estimators.observer._tick import TickPass
from estimators.observer.base_filter import ANGULAR_ACCELERATION_TIME_CONSTANT, BaseFilter
from estimators.observer.contacts import (
    CONTACT_LANDING_N,
    CONTACT_OFF_N,
    CONTACT_ON_N,
    CONTACT_TICKS,
    ContactTracker,
)
from estimators.observer.crane_pressures import SLIDING_SPEED, CranePressures
from estimators.observer.joint_filter import POSITION_FAULT, POSITION_GATE, JointFilter
from estimators.observer.payload_rls import EXPECTED_PICK_TICKS, PayloadRLS, without_seal_friction
from estimators.uncertainty import StateUncertainty, model_normal_forces
from models.coordinates import N_INDEPENDENT
from models.description import Machine
from models.numeric import clip
from models.records import trusted
from models.sensing import (
    N_LINEAR_AXES,
    PRESSURE_CYLINDERS,
    SensorReadings,
    SensorSpec,
    cylinder_areas,
)
from models.state import N_SERVO_AXES, MachineState

__all__ = ["CONTACT_LANDING_N", "CONTACT_OFF_N", "CONTACT_ON_N", "CONTACT_TICKS", "Observer",
           "ObserverEstimate"]

WHEEL_ACCELERATION_TIME_CONSTANT = 0.05  # [s]
_LIFT, _TILT = 3, 4  # independent coordinates of the lift and tilt cylinders
_LIFT_TILT = (_LIFT, _TILT)
SLIDING_FRICTION_STD = 0.2  # std of a sliding seal's friction about its rating [-]
PAYLOAD_FILTER_TIME = 0.05  # [s] low-pass of the payload regression (`Observer._filtered`)
EVENT_VARIANCE_SCALE = 0.1  # filtered over raw innovation variance: 0.01 still, 0.05-0.08 moving
_PRESS_LIFT_TILT = [PRESSURE_CYLINDERS.index("lift"), PRESSURE_CYLINDERS.index("tilt")]
_NO_FORCES = np.zeros(5)  # [N] the cylinders' forces before any pressure reading
_NO_FORCES.flags.writeable = False
_ONES = np.ones(4)  # the first tick's "previous" forces (`ContactTracker.longitudinal`: even)
_ALL_FOUR = np.ones(4, bool)  # the flags' estimate: every wheel down (shared, read-only)
_ALL_FOUR.flags.writeable = False
# Per tick the observer works on a handful of numbers: where numpy's per-call cost (~1 us)
# dominated, the arithmetic is on Python floats in the same order (`_vec3`: the same results,
# bit for bit); matrix products and solves stay numpy's.


@dataclasses.dataclass(frozen=True, eq=False)
class ObserverEstimate:
    """The observer's output at one tick.

    Attributes:
        state: The machine state (contacts: estimated flags, the wheels' lowest points,
            zero friction; suspension forces from the pressures).
        payload_mass: Estimated payload [kg]. payload_std: Its std [kg].
        payload_event: ``pick`` or ``release`` when one was detected this tick, else None.
        uncertainty: Standard deviations of the state's errors.
        forces_four: The force model's forces at the four-wheel state [N], (4,).
        stale: True when a stream delivered nothing new this tick (the estimate is held).
    """

    state: MachineState
    payload_mass: float
    payload_std: float
    payload_event: str | None
    uncertainty: StateUncertainty
    forces_four: np.ndarray
    stale: bool = False


class Observer:
    """Sensor streams -> machine state, once per control tick (module docstring).

    Args:
        machine: The machine description.
        spec: The sensor suite (its error model sets the filters and the uncertainty).
        force_model: An estimator with a settable ``payload_mass``, ``contact_points`` and
            the cylinder-force fourth row (`estimators.payload.PayloadEstimator`), run once
            per tick.
        initial_payload: Prior of the payload [kg] (the empty grapple's mass is a fair one);
            None: the description's.
        initial_payload_std: Its std [kg].
        compiled: Run the filters', the fit's and the contacts' arithmetic in C
            (`filters_c`, `fusion_c`, `contacts_c`: the same results to round-off; the
            state's first part in one call, `_tick`; the rest of the tick, the payload
            filter too, in one more, `_tail`, the Python steps' bits) when a C compiler is
            there; False: Python and numpy.
    """

    crane_from_pressures = True  # `crane_pressures`; False: the encoders' alone

    def __init__(self, machine: Machine, spec: SensorSpec, force_model,
                 initial_payload: float | None = None, initial_payload_std: float = 150.0,
                 compiled: bool = True):
        if not isinstance(spec, SensorSpec) or spec.oracle:
            raise EstimatorError("the observer needs a sensor suite with sensors (not oracle)")
        self.machine, self.spec, self.force_model = machine, spec, force_model
        imu_range = (spec.imu.gyroscope.full_scale, spec.imu.accelerometer.full_scale)
        self.base = BaseFilter(spec.imu.position, machine.gravity, machine.wheel_radius,
                               compiled=compiled, full_scale=imu_range)
        dt_pos = 1.0 / spec.stroke.rate
        noise = np.r_[np.full(N_LINEAR_AXES, spec.stroke.sample_std),
                      np.full(N_SERVO_AXES - N_LINEAR_AXES, spec.angle.sample_std)]
        self.joints = JointFilter(N_SERVO_AXES, dt_pos, noise, compiled=compiled)
        self.efforts = ActuatorEfforts(machine)
        areas = cylinder_areas(machine)
        a_norm = np.hypot(areas[:, 0], areas[:, 1])
        n_press = max(1, round(spec.pressure.rate * 0.01))
        self._force_std = a_norm * spec.pressure.sample_std / math.sqrt(n_press)
        self._force_bias = a_norm * spec.pressure.bias
        # The seals' friction is between the pressures' force and the mechanism's. Standing
        # still: unknown sign and size up to its rating (for the normal-force uncertainty:
        # uniform, std F_c / sqrt(3); for the payload: a dead band). Sliding
        # (`SLIDING_SPEED`): the rating against the motion, known to `SLIDING_FRICTION_STD`.
        self._seal = np.array([machine.chains[c].cylinder.seal_friction
                               for c in PRESSURE_CYLINDERS])
        self._friction_std = self._seal / math.sqrt(3.0)
        body = next(b for b in machine.bodies if b.name == machine.payload)
        m0 = body.inertia.mass if initial_payload is None else float(initial_payload)
        # The lift and tilt forces the model predicts carry the joint accelerations' errors
        # (through the reflected inertia, at the home pose) besides the transducers' noise.
        home = machine.coordinates.home()
        zero = np.zeros(N_INDEPENDENT)
        e_home, _ = self.efforts.affine(MachineState(np.zeros(3), np.eye(3), np.zeros(6),
                                                     np.zeros(6), home, zero, zero))
        _, qdd_std = self.joints.std
        model_std = np.sqrt(((e_home[[_LIFT, _TILT]] * qdd_std) ** 2).sum(axis=1))
        lt = _PRESS_LIFT_TILT
        has_links = bool(spec.link_accelerometers)
        self._payload_filter_time = (link_fusion.LINK_PAYLOAD_FILTER_TIME if has_links
                                     else PAYLOAD_FILTER_TIME)
        self.payload = PayloadRLS(
            m0, initial_payload_std,
            np.sqrt(self._force_std[lt] ** 2 + model_std ** 2
                    + (SLIDING_FRICTION_STD * self._seal[lt]) ** 2),
            self._force_bias[lt], event_variance_scale=EVENT_VARIANCE_SCALE,
            expected_pick_ticks=(link_fusion.LINK_EXPECTED_PICK_TICKS if has_links
                                 else EXPECTED_PICK_TICKS))
        self._regression = np.zeros(7)  # `_filtered`'s state
        self._previous_four = _ONES.copy()  # the last estimate's four-wheel forces [N]
        self._wheel_angle = [0.0] * 4
        self._wheel_rate = [0.0] * 4
        self._wheel_acc = [0.0] * 4
        self._suspension = None
        wheel = machine.body(machine.wheels[0])
        self._last_time: float | None = None
        self._last: ObserverEstimate | None = None
        self._uncertainty_const = self._uncertainty_parts()
        self.contacts = ContactTracker(
            machine.wheel_radius, float(wheel.inertia.inertia[1, 1] + wheel.joint.armature),
            bool(getattr(getattr(force_model, "tree", None), "wheel_is_sphere", True)),
            compiled)
        # Constant per tick: areas, ranges, the error model (checked once), the crane rows.
        self._area_a, self._area_b = areas[:, 0].copy(), areas[:, 1].copy()
        self._q_lo = machine.coordinates.lower[:N_SERVO_AXES]
        self._q_hi = machine.coordinates.upper[:N_SERVO_AXES]
        span = POSITION_GATE * (self._q_hi - self._q_lo)
        self._gate = (self._q_lo - span, self._q_hi + span)
        lib = filters_c.compiled_filters() if compiled else None
        self._tick = None  # the state's first part in one C call (`_tick`), else Python
        if lib is not None and self.base._c is not None and self.joints._c is not None:
            self._tick = TickPass(lib, self.base, self.joints, areas, self._q_lo,
                                  self._q_hi, *self._gate, WHEEL_ACCELERATION_TIME_CONSTANT,
                                  imu_range)
            self.contacts.wheel_acceleration = self._tick.wheels[8:]  # read in place
        accel_std, qd_std = self._uncertainty_const
        self._uncertainty = StateUncertainty(
            acceleration=accel_std, qd=qd_std,
            suspension_force=np.sqrt(self._force_std[:2] ** 2 + self._force_bias[:2] ** 2
                                     + self._friction_std[:2] ** 2))
        self._seal_lift_tilt = self._seal[_PRESS_LIFT_TILT].tolist()
        self.crane = CranePressures(self.efforts, self._seal)
        # The flags' four-wheel state is asked about once: nothing of it kept if the model
        # can (`PayloadEstimator.normal_forces_once`).
        self._four_wheel_forces = getattr(force_model, "normal_forces_once", None) or (
            lambda s: model_normal_forces(force_model, s))
        # The link accelerometers' predictions carry the base's acceleration errors, its
        # angular acceleration's through the lever arm to the crane (`LINK_LEVER`).
        base_std = float(np.hypot(accel_std[0], link_fusion.LINK_LEVER * accel_std[3]))
        self.links = (link_fusion.LinkFusion(self.efforts, spec.link_accelerometers, base_std,
                                             qdd_std, compiled) if has_links else None)
        # The tick after the filters' pass in one C call, where it applies (`_tail`).
        self._tail = _tail.tail_pass(self) if compiled else None

    # ------------------------------------------------------------------ uncertainty
    def _uncertainty_parts(self) -> tuple[np.ndarray, np.ndarray]:
        """(acceleration std (19,), qd std (13,)) from the specs and the filters' gains."""
        sp = self.spec
        n_imu = max(1, round(sp.imu.accelerometer.rate * 0.01))
        acc = sp.imu.accelerometer
        gyro = sp.imu.gyroscope
        # Angular acceleration: difference of two tick means of the gyro, low-passed.
        dt = 0.01
        a = dt / (ANGULAR_ACCELERATION_TIME_CONSTANT + dt)
        raw = math.sqrt(2.0) * gyro.sample_std / math.sqrt(n_imu) / dt
        alpha_std = raw * math.sqrt(a / (2.0 - a))
        lever = float(np.linalg.norm(sp.imu.position))
        f_std = math.sqrt(acc.sample_std ** 2 / n_imu + acc.bias ** 2
                          + (lever * alpha_std) ** 2)
        qd_std, qdd_std = self.joints.std
        accel = np.zeros(N_GENERALIZED)
        accel[:3] = f_std
        accel[3:6] = alpha_std
        accel[6:6 + N_SERVO_AXES] = qdd_std
        qd = np.zeros(N_INDEPENDENT)
        qd[:N_SERVO_AXES] = qd_std
        qd[N_SERVO_AXES:] = sp.wheel_speed.sample_std
        return accel, qd

    # ------------------------------------------------------------------ update
    def expect_pick(self, time: float) -> None:
        """The operator's grapple command at ``time`` [s]: a pick may come (`PayloadRLS`)."""
        self.payload.expect_pick(time)

    def update(self, readings: SensorReadings) -> ObserverEstimate:
        """One control tick (module docstring).

        A reading with NaN or inf, a position far outside its axis's range or an IMU sample
        beyond its full scale is refused: the last estimate comes back marked ``stale``.

        Raises:
            EstimatorError: Not `SensorReadings`, or a non-finite reading before any good one.
        """
        if not isinstance(readings, SensorReadings):
            raise EstimatorError(f"expected SensorReadings, got {type(readings).__name__}")
        try:
            return self._update(readings)
        except EstimatorError:
            if self._last is None:
                raise
            return dataclasses.replace(self._last, stale=True)

    def _update(self, r: SensorReadings) -> ObserverEstimate:
        t = r.time
        dt = 0.0 if self._last_time is None else t - self._last_time
        stale = r.positions.value.shape[0] == 0 or r.pressures.value.shape[0] == 0
        if self._tail is not None:  # the rest of the tick in one C call (`_tail`)
            return self._tail.update(r, dt, stale)
        if self._tick is not None:
            buf = StateBuffer(self._tick.run(r, dt))
            if r.pressures.value.shape[0]:
                self._suspension = self._tick.forces.copy()
            forces = self._suspension if self._suspension is not None else _NO_FORCES
        else:
            buf, forces = self._state_fields(r, dt)
        state = buf.state(t, r.servo_setpoint, self.base.rotation_valid)
        return self._from_links(state, r, forces, dt, stale)

    # The tick's steps after the state's first part, each handing on to the next (`_tail`
    # takes over from any of them when its C does not cover the tick).
    def _from_links(self, state: MachineState, r: SensorReadings, forces: np.ndarray,
                    dt: float, stale: bool) -> ObserverEstimate:
        """The crane's accelerations from the link accelerometers, then `_from_payload`."""
        if self.links is not None:
            state = with_fields(state, qdd=self.links.accelerations(state,
                                                                     r.link_specific_force))
        return self._from_payload(state, r, forces, dt, stale)

    def _from_payload(self, state: MachineState, r: SensorReadings, forces: np.ndarray,
                      dt: float, stale: bool) -> ObserverEstimate:
        """The payload from the lift and tilt cylinders, then `_from_crane`."""
        t = r.time
        f0, y = self.efforts.payload_regressor_at(state, _LIFT_TILT)
        f = forces.tolist()
        qd = state.qd
        measured, band = without_seal_friction([f[i] for i in _PRESS_LIFT_TILT],
                                               (qd[_LIFT], qd[_TILT]), self._seal_lift_tilt,
                                               SLIDING_SPEED)
        self.payload.update(t, dt, *self._filtered(dt, measured, f0, y), band)
        mass = min(max(self.payload.mass, 0.0), 1e4)
        if self.crane_from_pressures:
            state = with_fields(state, qdd=self.crane.accelerations(state, forces, mass))
        return self._from_contacts(state, r, mass, stale)

    def _from_contacts(self, state: MachineState, r: SensorReadings, mass: float,
                       stale: bool) -> ObserverEstimate:
        """The contact points and flags at the payload ``mass`` [kg], then the estimate."""
        self.force_model.payload_mass = mass
        drive_torques = r.drive_torques.value
        if drive_torques.shape[0]:
            self.contacts.set_drive(drive_torques)
        # The wheels' centres from the geometry (without contacts the estimator gives their
        # lowest points), the contact points below them along the ground's normal, then the
        # four-wheel forces at those points for the flags.
        points, normals, force, finite, force_finite = self.contacts.points(
            self.force_model.contact_points(state), self.base.up, self._previous_four)
        all_four = wheel_contacts(_ALL_FOUR, force, points, normals, finite and force_finite)
        four = np.asarray(self._four_wheel_forces(with_fields(state, contacts=all_four)),
                          float)
        flags, force, force_finite = self.contacts.update(four)
        contacts = wheel_contacts(flags, force, points, normals, finite and force_finite)
        self._previous_four[:] = four
        return self._estimate(with_fields(state, contacts=contacts), mass, four, r.time, stale)

    def _estimate(self, state: MachineState, mass: float, four: np.ndarray, t: float,
                  stale: bool, std: float | None = None) -> ObserverEstimate:
        """The tick's `ObserverEstimate`, kept as the last.

        Its fields are valid: made without the frozen dataclass's per-field setting.
        ``std``: the payload filter's `PayloadRLS.std` if known (`_tail`'s C), else asked.
        """
        if std is None:
            std = self.payload.std
        est = trusted(ObserverEstimate, state=state, payload_mass=mass, payload_std=std,
                      payload_event=self.payload.event,
                      uncertainty=self._uncertainty.with_payload_mass(std),
                      forces_four=four, stale=stale)
        self._last_time = t
        self._last = est
        return est

    def _state_fields(self, r: SensorReadings, dt: float) -> tuple[StateBuffer, np.ndarray]:
        """The state's float fields and the cylinder forces [N] (5,), in Python (`_tick`).

        ``dt``: the time since the last tick [s].
        """
        wheel_speeds, drive_torques = r.wheel_speeds.value, r.drive_torques.value
        if not (np.isfinite(wheel_speeds).all() and np.isfinite(drive_torques).all()):
            raise EstimatorError("wheel-speed or drive-torque readings hold NaN or inf")
        t = r.time
        wheels = wheel_speeds[-1] if wheel_speeds.shape[0] else None
        base = self.base
        base.update(t, r.angular_rate.value, r.specific_force.value, wheels)
        positions, p = r.positions, r.pressures.value
        if positions.value.shape[0]:
            z = positions.value
            if (np.isfinite(z).all() and (np.logical_or.reduce(z < self._gate[0], None)
                                          or np.logical_or.reduce(z > self._gate[1], None))):
                raise EstimatorError(POSITION_FAULT)
            self.joints.update(z)
            x = self.joints.predict_rows(max(t - positions.time[-1], 0.0))
        else:
            x = self.joints.predict_rows(0.0)
        if wheels is not None:
            left, right = wheels.tolist()
            rate = [left, left, right, right]  # FL, RL, FR, RR
            if dt > 0:  # low-passed: the pick-ups' counts are coarse
                a = dt / (WHEEL_ACCELERATION_TIME_CONSTANT + dt)
                self._wheel_acc = [acc + a * ((w - w0) / dt - acc) for acc, w, w0
                                   in zip(self._wheel_acc, rate, self._wheel_rate)]
            self._wheel_rate = rate
            self.contacts.wheel_acceleration = self._wheel_acc
        self._wheel_angle = [q + dt * w for q, w in zip(self._wheel_angle, self._wheel_rate)]
        if p.shape[0]:
            self._suspension = self._cylinder_forces(p)
        forces = self._suspension if self._suspension is not None else _NO_FORCES
        # The state's float fields in one buffer: q, qd, qdd are the rows of `joints`.
        buf = StateBuffer()
        buf.set_base(base.base_fields())
        joints = buf.joints
        joints[:, :N_SERVO_AXES] = x
        joints[:, N_SERVO_AXES:] = (self._wheel_angle, self._wheel_rate, self._wheel_acc)
        q = joints[0, :N_SERVO_AXES]
        clip(q, self._q_lo, self._q_hi, out=q)
        buf.set_suspension(forces)
        return buf, forces

    def _cylinder_forces(self, p: np.ndarray) -> np.ndarray:
        """`models.sensing.cylinder_force` [N] (5,), the mean over the tick's samples (k, 10).

        Raises:
            EstimatorError: A force is not finite.
        """
        forces = np.add.reduce(p[:, 0::2] * self._area_a - p[:, 1::2] * self._area_b,
                               0) / p.shape[0]
        if not np.isfinite(forces).all():
            raise EstimatorError("pressure readings hold NaN or inf")
        return forces

    def _filtered(self, dt: float, measured, f0, y):
        """The payload regression's three sides through one first-order low-pass.

        ``F = F_0 + m Y`` holds after the same linear filter on both sides while ``m`` is
        constant; it takes out most of the white noise the joint accelerations' estimates
        put into ``F_0`` and ``Y`` (the boom's inertia reflected onto the lift stroke makes
        0.04 m/s^2 of noise several kN).
        """
        now = [*measured, *f0, *y]
        reg = self._regression  # [started, the three sides (6)]: `_tail`'s C writes it too
        if reg[0] == 0.0 or not dt > 0:
            z = now
        else:
            a = dt / (self._payload_filter_time + dt)
            z = [zi + a * (n - zi) for zi, n in zip(reg[1:].tolist(), now)]
        reg[0] = 1.0
        reg[1:] = z
        return z[:2], z[2:4], z[4:]
