"""The sensor suites: ``oracle``, ``ideal`` and ``realistic`` (`models.sensing.SensorSpec`).

``realistic`` takes its error figures from public datasheets of industrial parts of the kind a
forestry or construction machine carries (figures as read from the datasheets; a noise
density ``d`` becomes a per-sample standard deviation ``d sqrt(rate / 2)`` for a reading
band-limited to the Nyquist frequency of its sample rate):

=====================  ===================================  ==============================
channel                part                                 datasheet figures used
=====================  ===================================  ==============================
IMU accelerometer      Xsens MTi-630 (MTi 600-series)        noise density 60 ug/sqrt(Hz),
                                                            in-run bias stability 10 ug;
                                                            400 Hz output; range +-10 g
IMU gyroscope          Xsens MTi-630                        noise density 0.007 deg/s/
                                                            sqrt(Hz), in-run bias
                                                            stability 8 deg/h; range
                                                            +-2000 deg/s
link accelerometers    Xsens MTi-630R (the IP68 version of  as the IMU's accelerometer
(boom, telescope tip)  the same unit), accelerometer only
stroke sensors         MTS Temposonics R-series (SSI),      resolution 1 um, repeatability
                       in-cylinder magnetostrictive         +-0.001 % FS (min 2.5 um),
                                                            linearity < +-0.01 % FS
angle encoders         14-bit absolute single-turn encoder  resolution 360/2^14 deg,
                       (e.g. Kuebler Sendix M3663)          accuracy +-0.1 deg
pressure transducers   WIKA MH-3 (mobile hydraulics),       accuracy <= +-0.5 % FS
                       0-400 bar                            (non-linearity, hysteresis,
                                                            zero and span error)
wheel-motor speed      Hall pulse pick-up on the hydraulic  pulses counted over the sample
                       motor (e.g. Danfoss PPU), 60         period
                       pulses/rev, 40:1 final drive
drive torque           WIKA MH-3 on each drive motor's A    <= +-0.5 % FS of the motor's
                       and B lines (torque = dp x           pressure range (full scale:
                       displacement x gear / 2 pi)          the side's 8 kN m)
=====================  ===================================  ==============================

What the model makes of them, and what it simplifies:

* turn-on biases (the part that does not average out): the accelerometer's and the
  gyroscope's are set at five times their in-run stability (a field calibration at
  start-up leaves that much); the pressure transducer's zero error is the accuracy class
  split into a constant zero offset (0.3 % FS, per transducer) and noise; the stroke
  sensors' linearity error is a constant offset per cylinder over the few millimetres a
  cylinder moves while it holds a load;
* bias drift: the in-run stability as a random walk over one minute;
* latency: one sample period of each bus (CAN at 500 Hz and 100 Hz, the IMU at 400 Hz), as
  multiples of the 2 ms physics step;
* no temperature effects, no misalignment of the IMU, no cross-axis sensitivity;
* the link accelerometers sit on rigid links: a real boom bends, and its accelerometers
  also read the bending modes (10-20 Hz on booms of this size), which the simulated links
  do not have.

``ideal`` is the same set of sensors and rates without any error; ``oracle`` hands the
controller MuJoCo's exact state (contacts, accelerations, cylinder forces) instead.
`chassis_only` takes the link accelerometers away from a suite (the sensor set before them,
for comparison).
"""

from __future__ import annotations

import dataclasses
import math

from models.errors import ModelError
from models.sensing import ChannelSpec, ImuSpec, LinkAccelerometer, SensorSpec

__all__ = ["IDEAL", "ORACLE", "REALISTIC", "SUITES", "chassis_only", "sensor_suite"]

_G = 9.81
_DEG = math.pi / 180.0


def _density(d: float, rate: float) -> float:
    """Per-sample std of white noise of density ``d`` [unit/sqrt(Hz)] sampled at ``rate``."""
    return d * math.sqrt(rate / 2.0)


IMU_RATE, FAST_RATE, SLOW_RATE = 400.0, 500.0, 100.0  # [Hz]
IMU_POSITION = (0.60, 0.25, 0.45)  # [m] in fb: on the chassis beside the crane base
# [m] in the body's frame: on the boom 0.4 m inboard of the tilt joint (at 1.60, 0, 0.10),
# and on the telescope's extension at its tip (the wrist hangs at 0.40, 0.04, -0.12).
BOOM_ACCELEROMETER = ("lift", (1.20, 0.0, 0.15))
TIP_ACCELEROMETER = ("telescope", (0.35, 0.0, 0.0))
_ACC_DENSITY = 60e-6 * _G  # [m/s^2/sqrt(Hz)]
_GYRO_DENSITY = 0.007 * _DEG  # [rad/s/sqrt(Hz)]
_ACC_BIAS_STABILITY = 10e-6 * _G  # [m/s^2]
_GYRO_BIAS_STABILITY = 8.0 * _DEG / 3600.0  # [rad/s]
_PRESSURE_FS = 400e5  # [Pa]
_WHEEL_COUNTS = 60 * 40  # pulses per wheel revolution
_DRIVE_TORQUE_FS = 8000.0  # [N m] a side's two wheels at the drive's 4 kN m each
_ACC_RANGE = 10.0 * _G  # [m/s^2] the MTi 600-series' standard full ranges
_GYRO_RANGE = 2000.0 * _DEG  # [rad/s]

_REALISTIC_IMU = ImuSpec(
    accelerometer=ChannelSpec(
        rate=IMU_RATE, noise=_density(_ACC_DENSITY, IMU_RATE), bias=5 * _ACC_BIAS_STABILITY,
        bias_drift=_ACC_BIAS_STABILITY / math.sqrt(60.0), latency=0.002,
        full_scale=_ACC_RANGE,
        source="Xsens MTi-630: 60 ug/sqrt(Hz), in-run bias stability 10 ug, +-10 g"),
    gyroscope=ChannelSpec(
        rate=IMU_RATE, noise=_density(_GYRO_DENSITY, IMU_RATE), bias=5 * _GYRO_BIAS_STABILITY,
        bias_drift=_GYRO_BIAS_STABILITY / math.sqrt(60.0), latency=0.002,
        full_scale=_GYRO_RANGE,
        source="Xsens MTi-630: 0.007 deg/s/sqrt(Hz), in-run bias stability 8 deg/h, "
               "+-2000 deg/s"),
    position=IMU_POSITION)

REALISTIC = SensorSpec(
    name="realistic",
    imu=_REALISTIC_IMU,
    link_accelerometers=tuple(
        LinkAccelerometer(body, position, dataclasses.replace(
            _REALISTIC_IMU.accelerometer,
            source="Xsens MTi-630R (accelerometer): 60 ug/sqrt(Hz), in-run bias stability "
                   "10 ug"))
        for body, position in (BOOM_ACCELEROMETER, TIP_ACCELEROMETER)),
    stroke=ChannelSpec(rate=FAST_RATE, noise=2.5e-6, bias=20e-6, resolution=1e-6,
                       latency=0.002,
                       source="MTS Temposonics R-series: 1 um resolution, repeatability "
                              "2.5 um, linearity < 0.01 % FS"),
    angle=ChannelSpec(rate=FAST_RATE, noise=0.0, bias=0.1 * _DEG / 3.0,
                      resolution=2 * math.pi / 2 ** 14, latency=0.002,
                      source="14-bit absolute encoder: 0.022 deg steps, +-0.1 deg accuracy"),
    pressure=ChannelSpec(rate=FAST_RATE, noise=0.2e-2 * _PRESSURE_FS / 3.0,
                         bias=0.3e-2 * _PRESSURE_FS / 3.0, resolution=_PRESSURE_FS / 2 ** 12,
                         latency=0.002,
                         source="WIKA MH-3, 0-400 bar: accuracy <= 0.5 % FS"),
    wheel_speed=ChannelSpec(rate=SLOW_RATE, resolution=2 * math.pi * SLOW_RATE / _WHEEL_COUNTS,
                            latency=0.01,
                            source="Hall pick-up, 60 pulses/rev on the motor, 40:1 drive"),
    drive_torque=ChannelSpec(rate=FAST_RATE, noise=0.2e-2 * _DRIVE_TORQUE_FS / 3.0,
                             bias=0.3e-2 * _DRIVE_TORQUE_FS / 3.0, latency=0.002,
                             source="WIKA MH-3 on the drive motor lines: <= 0.5 % FS"),
)

IDEAL = dataclasses.replace(  # the same parts, their ranges included, without errors
    REALISTIC, name="ideal",
    imu=ImuSpec(ChannelSpec(rate=IMU_RATE, full_scale=_ACC_RANGE),
                ChannelSpec(rate=IMU_RATE, full_scale=_GYRO_RANGE), IMU_POSITION),
    link_accelerometers=tuple(LinkAccelerometer(body, position,
                                                ChannelSpec(rate=IMU_RATE, full_scale=_ACC_RANGE))
                              for body, position in (BOOM_ACCELEROMETER, TIP_ACCELEROMETER)),
    stroke=ChannelSpec(rate=FAST_RATE), angle=ChannelSpec(rate=FAST_RATE),
    pressure=ChannelSpec(rate=FAST_RATE), wheel_speed=ChannelSpec(rate=SLOW_RATE),
    drive_torque=ChannelSpec(rate=FAST_RATE))

ORACLE = dataclasses.replace(IDEAL, name="oracle", oracle=True)

SUITES = {s.name: s for s in (ORACLE, IDEAL, REALISTIC)}


def chassis_only(spec: SensorSpec) -> SensorSpec:
    """``spec`` without its link accelerometers (the sensor set before them: comparisons)."""
    return dataclasses.replace(spec, link_accelerometers=())


def sensor_suite(name: str, seed: int = 0) -> SensorSpec:
    """The suite ``name`` with its errors drawn from ``seed``.

    Raises:
        ModelError: Unknown name or a bad seed.
    """
    if name not in SUITES:
        raise ModelError(f"unknown sensor suite {name!r}; valid: {', '.join(SUITES)}")
    return dataclasses.replace(SUITES[name], seed=seed)
