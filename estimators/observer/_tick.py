"""The first part of the observer's tick in one C call (`filters_c.observer_tick`).

Before the state exists `Observer._update` checks the wheel and drive streams, runs the
chassis filter (the IMU's tick means, its step), the joint filter (the samples, the
prediction to the tick), the wheels' odometry and the cylinder forces, and fills the state's
buffer: a dozen calls and some thirty numpy operations, ~25 us of Python about ~2 us of
arithmetic. `TickPass` copies the tick's samples into bound buffers and makes one call on the
filters' own state buffers: those steps' operations in their order (the means row after row
as numpy's reduction sums, `np.clip`'s comparisons), the same bits
(`tests/test_observer_tick_c.py`).
"""

from __future__ import annotations

import numpy as np

from estimators.errors import EstimatorError
from estimators.observer._states import STATE_SIZE
from estimators.observer.base_filter import IMU_FAULT, BaseFilter
from estimators.observer.joint_filter import POSITION_FAULT, JointFilter
from models.cbuild import bind
from models.sensing import SensorReadings

__all__ = ["TickPass"]

_ERRORS = {1: "wheel-speed or drive-torque readings hold NaN or inf",
           2: "IMU samples hold NaN or inf", 3: "position samples hold NaN or inf",
           4: "pressure readings hold NaN or inf", 6: POSITION_FAULT, 7: IMU_FAULT}
_LEVEL = 5  # `observer_tick`: the IMU's means are in, the attitude is not levelled yet
_CHANNELS = (3, 3, 9, 10, 2, 2)  # the streams' (`_streams`)


def _streams(r: SensorReadings) -> tuple:
    """The sample arrays `observer_tick` reads, in its order."""
    return (r.angular_rate.value, r.specific_force.value, r.positions.value,
            r.pressures.value, r.wheel_speeds.value, r.drive_torques.value)


class TickPass:
    """`observer_tick` bound to the filters' state and to the observer's buffers.

    Args:
        lib: The loaded `filters_c` library.
        base: The chassis filter (compiled). joints: The joint filter (compiled, 9 axes).
        areas: The cylinders' (A_A, A_B) [m^2], (5, 2).
        lower, upper: The servo axes' ranges (9,): the state's q is clipped into them.
        gate_lower, gate_upper: The position samples' gate (9,): a sample outside is a
            sensor fault (`POSITION_FAULT`), refused before the joint filter sees it.
        wheel_time_constant: The wheels' acceleration low-pass [s].
        imu_full_scale: The gyroscope's [rad/s] and the accelerometer's [m/s^2] full scales:
            a sample beyond is a fault (`IMU_FAULT`), refused before the chassis filter.

    Attributes:
        wheels: The wheels' angles [rad], rates [rad/s], accelerations [rad/s^2], (12,).
        forces: The cylinders' forces [N] (5,): the last tick's with pressures.
    """

    def __init__(self, lib, base: BaseFilter, joints: JointFilter, areas: np.ndarray,
                 lower: np.ndarray, upper: np.ndarray, gate_lower: np.ndarray,
                 gate_upper: np.ndarray, wheel_time_constant: float,
                 imu_full_scale: tuple[float, float] = (np.inf, np.inf)):
        self.base, self.joints, self._lib = base, joints, lib
        self.wheels = np.zeros(12)
        self.forces = np.zeros(5)
        self._out = np.zeros(STATE_SIZE)
        self._sc = np.zeros(15)
        self._sc[3] = wheel_time_constant
        self._sc[13:] = imu_full_scale
        self._has_forces = False  # a tick brought pressures (`forces` holds theirs)
        self._consts = (np.ascontiguousarray(areas[:, 0]), np.ascontiguousarray(areas[:, 1]),
                        np.concatenate([lower, gate_lower]).astype(float),
                        np.concatenate([upper, gate_upper]).astype(float))
        self._bind(16)

    def _bind(self, rows: int) -> None:
        """Sample buffers of ``rows`` rows each, and the call bound to them."""
        self._rows = rows
        self._samples = [np.zeros((rows, k)) for k in _CHANNELS]
        b, j = self.base, self.joints
        aa, ab, lo, hi = self._consts
        self._c = bind(self._lib.observer_tick, self._sc, b._state, b._consts, b._in, j.x,
                       j._f_c, j.K, self.wheels, aa, ab, self.forces, self._out, lo, hi,
                       *self._samples)

    def run(self, r: SensorReadings, dt: float, copy: bool = True) -> np.ndarray:
        """The state's float fields (`_states.StateBuffer` layout), a fresh array.

        ``dt``: the time since the observer's last tick [s] (the wheels' odometry);
        ``copy``: False, the buffer itself (`_out`, written again by the next call).

        Raises:
            EstimatorError: A non-finite reading (the steps before it done, as the Python
                code's).
        """
        t = r.time
        streams = _streams(r)
        counts = [v.shape[0] for v in streams]
        if max(counts) > self._rows:
            self._bind(2 * max(counts))
        for buf, v, k in zip(self._samples, streams, counts):
            if k:
                buf[:k] = v
        base, joints = self.base, self.joints
        kz = counts[2]
        sc = self._sc
        sc[:3] = (0.0 if base._last_time is None else max(t - base._last_time, 0.0), dt,
                  max(t - r.positions.time[-1], 0.0) if kz else 0.0)
        sc[4:13] = (*counts, base._levelled, joints.initialized,
                  self._has_forces or counts[3] > 0)
        code = self._c()
        if code == _LEVEL:  # first IMU tick: level the attitude on gravity, then again
            base.level(base._in[4:7])
            sc[10] = 1.0
            code = self._c()
        if code not in (1, 2, 7) and counts[0] and counts[1]:
            base._last_time = t
        if code in (0, 4) and kz:  # (6: the joint filter has not seen the samples)
            joints.initialized = True
        if code:
            raise EstimatorError(_ERRORS[code])
        self._has_forces = bool(sc[12])
        return self._out.copy() if copy else self._out
