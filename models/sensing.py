"""What the machine's sensors report: error models, suites, and the sampled streams.

This is the seam between the simulator's sensor models (`scenarios.sensors`, which turn each
simulated instant into sensor samples) and the observer (`estimators.observer`, which turns
the samples back into a machine state). Neither side sees the other; both read the specs
here, so the observer knows the error model it must live with (and the controller's force
margin is derived from it).

The sensor set of the machine (what a forwarder or harvester carries):

* a chassis IMU at `ImuSpec.position` in fb (axes aligned with fb): specific force
  ``R^T (a_p - g)`` [m/s^2] at its mounting point and angular rate [rad/s], in its own axes;
* a position sensor in every servo axis (`POSITION_AXES`, order of ``q[:9]``): stroke
  sensors in the five cylinders and the telescope [m], angle encoders on the wrist and
  rotator [rad];
* pressure transducers on both chambers of the five chain cylinders (`PRESSURE_CYLINDERS`)
  [Pa]; the cylinder force is ``p_A A_A - p_B A_B`` (`cylinder_force`);
* one wheel-motor speed per side [rad/s] (left drives FL and RL, right FR and RR);
* one drive torque per side [N m]: the hydrostatic drive motors' pressure difference times
  their displacement and gear ratio, read by pressure transducers on the motor lines;
* accelerometers on the crane's links (`LinkAccelerometer`: on the boom and at the
  telescope's tip, as the link-mounted MEMS units of crane automation and payload weighing
  systems): specific force ``R_b^T (a_p - g)`` [m/s^2] at a point of a body, in the body's
  axes.

No contact force, contact flag, contact point, friction force, payload mass or acceleration
is measured. Every stream is sampled at its own rate and delivered after its latency
(`Samples`). The servo setpoints travel beside the streams: they are the axis controllers'
own references, known to the machine.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from models.description import Machine
from models.errors import ModelError, StateError
from models.state import N_SERVO_AXES, frozen_array, shaped_array

__all__ = [
    "ChannelSpec", "ImuSpec", "LinkAccelerometer", "N_LINEAR_AXES", "N_PRESSURE", "POSITION_AXES",
    "PRESSURE_CYLINDERS", "Samples", "SensorReadings", "SensorSpec", "cylinder_areas",
    "cylinder_force",
]

# The nine servo axes (q[:9]) carry a position sensor each; the first six are linear [m].
POSITION_AXES = ("bogie_L", "bogie_R", "slew", "lift", "tilt", "telescope",
                 "wrist_pitch", "wrist_roll", "rotator")
N_LINEAR_AXES = 6
# Cylinders with pressure transducers on both chambers (the machine's chain cylinders).
PRESSURE_CYLINDERS = ("bogie_L", "bogie_R", "slew", "lift", "tilt")
N_PRESSURE = len(PRESSURE_CYLINDERS)


def _finite_at_least(name: str, value, low: float = 0.0) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) \
            or not math.isfinite(value) or value < low:
        raise ModelError(f"sensor spec '{name}' must be a finite number >= {low:g}, "
                         f"got {value!r}")
    return float(value)


@dataclass(frozen=True)
class ChannelSpec:
    """Error model of one kind of sensor channel (every channel of the kind alike).

    A reading is ``(1 + s) x + b(t) + n`` quantized to `resolution`, taken every
    ``1 / rate`` seconds and delivered `latency` later. ``s ~ N(0, scale^2)`` and
    ``b(0) ~ N(0, bias^2)`` are drawn once per channel and run; ``b`` then walks with
    ``bias_drift`` [unit / sqrt(s)]; ``n ~ N(0, noise^2)`` is white, per sample.

    Attributes:
        rate: Sample rate [Hz], > 0.
        noise: White-noise standard deviation per sample [unit].
        bias: Turn-on bias standard deviation [unit].
        bias_drift: Bias random walk [unit / sqrt(s)].
        scale: Scale-factor error standard deviation [-].
        resolution: Quantization step [unit]; 0 for none.
        latency: Delay from the instant measured to the report [s].
        full_scale: The largest magnitude the sensor reports [unit] (its measurement
            range); inf: none given. The observer refuses a tick whose IMU sample lies
            beyond it (a corrupted sample, not a measurement).
        source: Where the figures come from (part and datasheet), for the docs.
    """

    rate: float
    noise: float = 0.0
    bias: float = 0.0
    bias_drift: float = 0.0
    scale: float = 0.0
    resolution: float = 0.0
    latency: float = 0.0
    full_scale: float = math.inf
    source: str = ""

    def __post_init__(self):
        if _finite_at_least("rate", self.rate) <= 0:
            raise ModelError(f"sensor spec 'rate' must be > 0 Hz, got {self.rate!r}")
        for name in ("noise", "bias", "bias_drift", "scale", "resolution", "latency"):
            _finite_at_least(name, getattr(self, name))
        fs = self.full_scale
        if isinstance(fs, bool) or not isinstance(fs, (int, float)) or not fs > 0:
            raise ModelError(f"sensor spec 'full_scale' must be a number > 0 (inf: none), "
                             f"got {fs!r}")

    @property
    def exact(self) -> bool:
        """True when the channel adds no error at all (latency aside)."""
        return not (self.noise or self.bias or self.bias_drift or self.scale
                    or self.resolution)

    @property
    def sample_std(self) -> float:
        """Std of one reading's error at a fixed bias [unit]: noise and quantization."""
        return math.sqrt(self.noise ** 2 + self.resolution ** 2 / 12.0)


@dataclass(frozen=True)
class ImuSpec:
    """The chassis IMU.

    Attributes:
        accelerometer: Specific force channels [m/s^2].
        gyroscope: Angular-rate channels [rad/s].
        position: Mounting point in fb [m], shape (3,); the axes are fb's.
    """

    accelerometer: ChannelSpec
    gyroscope: ChannelSpec
    position: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def __post_init__(self):
        p = np.asarray(self.position, float)
        if p.shape != (3,) or not np.isfinite(p).all():
            raise ModelError(f"IMU position must be 3 finite numbers [m], got {self.position!r}")


@dataclass(frozen=True)
class LinkAccelerometer:
    """An accelerometer fixed to one of the crane's bodies.

    Attributes:
        body: The body it is mounted on (a name of the machine description).
        position: Mounting point in the body's frame [m], shape (3,); its axes are the
            body's.
        accelerometer: Its specific-force channels [m/s^2].
    """

    body: str
    position: tuple[float, float, float]
    accelerometer: ChannelSpec

    def __post_init__(self):
        if not isinstance(self.body, str) or not self.body:
            raise ModelError(f"a link accelerometer needs a body name, got {self.body!r}")
        p = np.asarray(self.position, float)
        if p.shape != (3,) or not np.isfinite(p).all():
            raise ModelError(f"link accelerometer position must be 3 finite numbers [m], got "
                             f"{self.position!r}")
        if not isinstance(self.accelerometer, ChannelSpec):
            raise ModelError("a link accelerometer's channels must be a ChannelSpec")


@dataclass(frozen=True)
class SensorSpec:
    """A machine's sensor set and its error models (a *suite*).

    Attributes:
        name: ``oracle``, ``ideal``, ``realistic`` or a user's name.
        imu: The chassis IMU.
        stroke: Stroke sensors of the five cylinders and the telescope [m].
        angle: Angle encoders of the wrist and the rotator [rad].
        pressure: Pressure transducers, each chamber [Pa].
        wheel_speed: Wheel-motor speed sensors, per side [rad/s].
        drive_torque: Drive torque per side [N m] (motor line pressures).
        link_accelerometers: The crane's link accelerometers (may be empty).
        oracle: True: no sensors at all; the controller reads the simulator's exact state
            (the reference the other suites are compared with).
        seed: Seed of every random draw of the suite's errors.
    """

    name: str
    imu: ImuSpec
    stroke: ChannelSpec
    angle: ChannelSpec
    pressure: ChannelSpec
    wheel_speed: ChannelSpec
    drive_torque: ChannelSpec
    link_accelerometers: tuple[LinkAccelerometer, ...] = ()
    oracle: bool = False
    seed: int = 0
    notes: tuple[str, ...] = field(default=())

    def __post_init__(self):
        if not all(isinstance(a, LinkAccelerometer) for a in self.link_accelerometers):
            raise ModelError("link_accelerometers must be LinkAccelerometer entries")
        if isinstance(self.seed, bool) or not isinstance(self.seed, int) or self.seed < 0:
            raise ModelError(f"sensor seed must be a non-negative integer, got {self.seed!r}")


@dataclass(frozen=True, eq=False)
class Samples:
    """Readings of one stream delivered at a tick, oldest first.

    Attributes:
        time: The instant each reading measured [s], shape (n,), increasing.
        value: The readings, shape (n, k) (k channels); NaN where a sensor reported an
            invalid value (the observer refuses such a reading and holds its estimate).
    """

    time: np.ndarray
    value: np.ndarray

    def __post_init__(self):
        t = shaped_array("time", self.time, np.shape(self.time))
        if t.ndim != 1:
            raise StateError(f"'time' must be one-dimensional, got shape {t.shape}")
        v = np.asarray(self.value, float)
        if v.ndim != 2 or v.shape[0] != t.shape[0]:
            raise StateError(f"'value' must have shape (n, k) with n = {t.shape[0]}, got "
                             f"{v.shape}")
        object.__setattr__(self, "time", frozen_array("time", t, t.shape))
        v = shaped_array("value", v, v.shape)  # a sensor may report an invalid (NaN) value
        v.flags.writeable = False
        object.__setattr__(self, "value", v)

    @classmethod
    def trusted(cls, time: np.ndarray, value: np.ndarray) -> Samples:
        """Wrap arrays a sensor simulator made, without the checks of the constructor.

        For the per-tick path of `scenarios.sensors` (seven streams a tick): the caller
        guarantees float arrays of shapes (n,) and (n, k), finite increasing times, and
        arrays nobody else writes; they are made read-only here (not copied).
        """
        time.flags.writeable = False
        value.flags.writeable = False
        return cls.of_read_only(time, value)

    @classmethod
    def of_read_only(cls, time: np.ndarray, value: np.ndarray) -> Samples:
        """`trusted` for arrays already read-only: nothing is set on them.

        For views of one delivery's read-only buffers (`scenarios.sensors`: eight streams a
        tick, 0.4 us each on the flags alone); the caller guarantees what `trusted` asks
        and that both arrays are read-only.
        """
        obj = object.__new__(cls)
        d = obj.__dict__
        d["time"], d["value"] = time, value
        return obj

    def __len__(self) -> int:
        return int(self.time.shape[0])

    @property
    def latest(self) -> np.ndarray:
        """The newest reading, shape (k,). Raises `StateError` when there is none."""
        if not len(self):
            raise StateError("no reading delivered")
        return self.value[-1]


@dataclass(frozen=True, eq=False)
class SensorReadings:
    """Everything the machine's sensors delivered up to one control tick.

    Attributes:
        time: The tick [s]: no reading measured later than this (less its latency) is here.
        specific_force: IMU specific force, (n, 3) [m/s^2], IMU axes.
        angular_rate: IMU angular rate, (n, 3) [rad/s].
        positions: The nine servo axes' positions, (n, 9) [m, rad], order `POSITION_AXES`.
        pressures: Chamber pressures (n, 10) [Pa]: ``p_A, p_B`` of each cylinder of
            `PRESSURE_CYLINDERS`, in that order.
        wheel_speeds: Wheel-motor speeds (n, 2) [rad/s]: left, right.
        drive_torques: Drive torques (n, 2) [N m]: left, right (both wheels of a side).
        servo_setpoint: The axis controllers' setpoints at the tick, (9,) [m, rad].
        link_specific_force: The link accelerometers' specific forces, (n, 3 k) [m/s^2]
            (k accelerometers, each in its body's axes, order of
            `SensorSpec.link_accelerometers`); None without link accelerometers.
    """

    time: float
    specific_force: Samples
    angular_rate: Samples
    positions: Samples
    pressures: Samples
    wheel_speeds: Samples
    drive_torques: Samples
    servo_setpoint: np.ndarray
    link_specific_force: Samples | None = None

    def __post_init__(self):
        _check_time(self.time)
        for name, k in (("specific_force", 3), ("angular_rate", 3),
                        ("positions", N_SERVO_AXES), ("pressures", 2 * N_PRESSURE),
                        ("wheel_speeds", 2), ("drive_torques", 2)):
            s = getattr(self, name)
            if not isinstance(s, Samples):
                raise StateError(f"'{name}' must be Samples, got {type(s).__name__}")
            if s.value.shape[1] != k:
                raise StateError(f"'{name}' must have {k} channels, got {s.value.shape[1]}")
        link = self.link_specific_force
        if link is not None and (not isinstance(link, Samples) or link.value.shape[1] % 3):
            raise StateError("'link_specific_force' must be Samples with 3 channels per "
                             "accelerometer")
        object.__setattr__(self, "servo_setpoint", frozen_array(
            "servo_setpoint", self.servo_setpoint, (N_SERVO_AXES,)))

    @classmethod
    def trusted(cls, time: float, specific_force: Samples, angular_rate: Samples,
                positions: Samples, pressures: Samples, wheel_speeds: Samples,
                drive_torques: Samples, servo_setpoint: np.ndarray,
                link_specific_force: Samples | None) -> SensorReadings:
        """The readings a sensor simulator made, without the constructor's per-field checks.

        For the per-tick path of `scenarios.sensors` (3 us a tick): the caller guarantees
        `Samples` of the channel counts above and a read-only finite ``servo_setpoint``
        (9,) nobody else writes (`models.state.frozen_array`'s). ``time`` is still checked.
        """
        _check_time(time)
        obj = object.__new__(cls)
        obj.__dict__.update(time=time, specific_force=specific_force,
                            angular_rate=angular_rate, positions=positions,
                            pressures=pressures, wheel_speeds=wheel_speeds,
                            drive_torques=drive_torques, servo_setpoint=servo_setpoint,
                            link_specific_force=link_specific_force)
        return obj


def _check_time(t) -> None:
    """Raise `StateError` unless ``t`` is a finite number (a tick [s])."""
    if not (isinstance(t, (int, float)) and math.isfinite(t)):
        raise StateError(f"'time' must be a finite number [s], got {t!r}")


def cylinder_areas(machine: Machine) -> np.ndarray:
    """(A_A, A_B) [m^2] of each cylinder of `PRESSURE_CYLINDERS`, shape (5, 2)."""
    try:
        cyl = [machine.chains[name].cylinder for name in PRESSURE_CYLINDERS]
    except KeyError as exc:
        raise ModelError(f"the machine has no cylinder chain {exc}; pressure transducers "
                         f"sit on {', '.join(PRESSURE_CYLINDERS)}") from None
    return np.array([(c.area_piston, c.area_rod) for c in cyl])


def cylinder_force(machine: Machine, pressures) -> np.ndarray:
    """Cylinder forces ``p_A A_A - p_B A_B`` [N] (positive extends), shape (..., 5).

    Args:
        machine: The machine (chamber areas).
        pressures: Chamber pressures [Pa], shape (..., 10), layout of
            `SensorReadings.pressures`.
    """
    p = np.asarray(pressures, float)
    areas = cylinder_areas(machine)
    p = p.reshape(p.shape[:-1] + (N_PRESSURE, 2))
    return p[..., 0] * areas[:, 0] - p[..., 1] * areas[:, 1]
