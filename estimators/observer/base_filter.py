r"""The chassis from its IMU and the wheel-motor speeds: attitude, twist, acceleration.

* **Attitude**: a complementary filter on SO(3). The gyroscope's mean rate over a tick
  propagates ``R <- R exp(w dt)``; the tick's gravity in fb, the specific force at the fb
  origin less the motion the odometry knows (``w x v`` and the speed's change, low-pass
  filtered with `ODOMETRY_ACCELERATION_TIME_CONSTANT`), pulls the estimated up direction
  ``R^T e_z`` towards it with time constant `ATTITUDE_TIME_CONSTANT` (0.05 s at start-up,
  growing to its value over the first seconds). Yaw is the gyroscope's integral only: the
  normal forces do not depend on it. Measured on the flat run (skid-steer turns), ideal
  sensors: 0.11 deg mean error (max 0.23); the former pull towards the specific force
  low-passed in the chassis frame was 1.14 deg (max 2.9): the turns' centripetal
  acceleration and the lag of a vector low-passed in a rotating frame.
* **Angular rate** from the gyroscope (its in-run bias, 10^-4 rad/s, is left: its effect on
  the forces is below a newton); **angular acceleration** from the difference of the tick's
  mean rates, low-pass filtered with `ANGULAR_ACCELERATION_TIME_CONSTANT`.
* **Specific force at the fb origin**: the IMU's, moved by the lever arm ``p``:
  ``f_o = f_p - alpha x p - w x (w x p)``.
* **Linear velocity**: skid-steer odometry, ``v = (r (w_L + w_R) / 2, 0, 0)`` in fb.
* **Acceleration handed to the dynamics**: the estimator's dynamics see the base
  acceleration only through ``v_dot + w x v + R^T g e_z`` (the gravity offset of
  `estimators.spatial`), which is the specific force at the origin. Setting ``v_dot = f_o -
  w x v - R^T g e_z`` makes the dynamics see exactly the measured specific force, whatever
  the attitude error.
"""

from __future__ import annotations

import math

import numpy as np

from estimators.errors import EstimatorError
from estimators.observer import filters_c
from estimators.observer._vec3 import cross, norm
from models.cbuild import bind
from models.rotations import cross3
from models.state import ROTATION_TOLERANCE

_any = np.logical_or.reduce  # `ndarray.any` without its Python dispatch (every tick)

__all__ = ["ANGULAR_ACCELERATION_TIME_CONSTANT", "ATTITUDE_TIME_CONSTANT", "BaseFilter",
           "IMU_FAULT",
           "ODOMETRY_ACCELERATION_TIME_CONSTANT"]

ATTITUDE_TIME_CONSTANT = 2.0  # [s] the accelerometer's pull on the attitude
ANGULAR_ACCELERATION_TIME_CONSTANT = 0.03  # [s]
IMU_FAULT = ("an IMU sample beyond the sensor's full scale: a corrupted sample, not a "
             "measurement")
ODOMETRY_ACCELERATION_TIME_CONSTANT = 0.05  # [s] low-pass of the odometry's speed change
_ROTATION_VALID = filters_c.BASE_STATE["rotation_valid"]
_EYE = np.eye(3)
_EYE.flags.writeable = False

# The filter runs once per control tick on 3-vectors: its arithmetic is on Python floats
# (`_vec3`: the same results as the numpy expressions it replaced, bit for bit).


def _exp(x: float, y: float, z: float) -> np.ndarray:
    """``exp([w dt])`` of the rotation vector (x, y, z): Rodrigues (`axis_rotation`)."""
    angle = norm((x, y, z))
    if angle < 1e-12:
        return np.eye(3)
    ax, ay, az = x / angle, y / angle, z / angle
    n = norm((ax, ay, az))  # `axis_rotation` normalises its axis again
    ax, ay, az = ax / n, ay / n, az / n
    k = np.array(((0.0, -az, ay), (az, 0.0, -ax), (-ay, ax, 0.0)))
    return _EYE + math.sin(angle) * k + (1.0 - math.cos(angle)) * (k @ k)


class BaseFilter:
    """The chassis state from IMU samples and wheel speeds (module docstring).

    Args:
        imu_position: Lever arm ``p`` of the IMU in fb [m], (3,).
        gravity: [m/s^2].
        wheel_radius: [m].
        compiled: Run the tick's arithmetic in C (`filters_c`, the same results to
            round-off) when a C compiler is there; False: Python.
        full_scale: The gyroscope's [rad/s] and the accelerometer's [m/s^2] measurement
            ranges (`models.sensing.ChannelSpec.full_scale`): a tick with a sample beyond
            either is refused (`IMU_FAULT`).
    """

    def __init__(self, imu_position, gravity: float, wheel_radius: float,
                 compiled: bool = True, full_scale: tuple[float, float] = (np.inf, np.inf)):
        self.p = np.asarray(imu_position, float)
        self.full_scale = (float(full_scale[0]), float(full_scale[1]))
        self.g = float(gravity)
        self.r_wheel = float(wheel_radius)
        self._rotation = np.eye(3)
        self._levelled = False
        self._odometry_acceleration = (0.0, 0.0, 0.0)
        self._last_rate: tuple | None = None
        self._last_time: float | None = None
        self._age = 0.0
        # The filter's state as floats (its own arithmetic); the arrays are made when read.
        self._w = self._alpha = self._v = (0.0, 0.0, 0.0)
        self._f = (0.0, 0.0, self.g)
        lib = filters_c.compiled_filters() if compiled else None
        self._c = None
        if lib is not None:  # the state in C's buffer (`filters_c.BASE_STATE`)
            at = filters_c.BASE_STATE
            self._state = np.zeros(filters_c.BASE_STATE_SIZE)
            self._state[at["rotation"]] = _EYE.reshape(-1)
            self._state[at["f"]] = self._f
            self._state[at["rotation_valid"]] = 1.0
            self._consts = np.array([*self.p, self.g, self.r_wheel,
                                     ANGULAR_ACCELERATION_TIME_CONSTANT,
                                     ODOMETRY_ACCELERATION_TIME_CONSTANT,
                                     ATTITUDE_TIME_CONSTANT, ROTATION_TOLERANCE])
            self._in = np.zeros(10)
            self._c = bind(lib.base_step, self._state, self._consts, self._in)
            self._fields = self._state[filters_c.BASE_FIELDS]
            self._fields.flags.writeable = False  # C writes it; readers copy

    def update(self, time: float, rates: np.ndarray, forces: np.ndarray,
               wheel_speeds: np.ndarray | None) -> None:
        """Take one tick's IMU samples ((k, 3) each) and the latest side speeds (2,).

        Raises:
            EstimatorError: A sample beyond its channel's `full_scale` (`IMU_FAULT`, before
                anything changes), or a tick's mean not finite.
        """
        n_w, n_f = rates.shape[0], forces.shape[0]
        gyro, accelerometer = self.full_scale
        if (_any(np.abs(rates) > gyro, None) if n_w else False) or (
                _any(np.abs(forces) > accelerometer, None) if n_f else False):
            raise EstimatorError(IMU_FAULT)
        if n_w == 0 or n_f == 0:
            return  # nothing new: keep the state (the caller flags the gap)
        dt = 0.0 if self._last_time is None else max(time - self._last_time, 0.0)
        if self._c is not None:
            self._update_c(time, dt, rates, forces, n_w, n_f, wheel_speeds)
            return
        # `mean(axis=0)`: the same sum (numpy's own reduction) over the same count
        w_arr = np.add.reduce(rates, 0) / n_w
        f_arr = np.add.reduce(forces, 0) / n_f
        w = wx, wy, wz = w_arr.tolist()
        f_p = f_arr.tolist()
        if not all(map(math.isfinite, w + f_p)):
            raise EstimatorError("IMU samples hold NaN or inf")
        if not self._levelled:  # first tick: level the attitude on gravity at once
            self.level(f_arr)
        alpha = self._alpha
        if dt > 0:
            self._rotation = self._rotation @ _exp(wx * dt, wy * dt, wz * dt)
            a = dt / (ANGULAR_ACCELERATION_TIME_CONSTANT + dt)
            (ax, ay, az), (lx, ly, lz) = alpha, self._last_rate
            alpha = self._alpha = (ax + a * ((wx - lx) / dt - ax), ay + a * ((wy - ly) / dt - ay),
                                   az + a * ((wz - lz) / dt - az))
        self._w = self._last_rate = w
        p = self.p.tolist()
        (c1x, c1y, c1z), (c2x, c2y, c2z) = cross(alpha, p), cross(w, cross(w, p))
        fx, fy, fz = f_p
        f_o = self._f = (fx - c1x - c2x, fy - c1y - c2y, fz - c1z - c2z)
        velocity = self._v
        if wheel_speeds is not None:
            left, right = wheel_speeds.tolist()
            if math.isfinite(left) and math.isfinite(right):
                velocity = (self.r_wheel * 0.5 * (left + right), 0.0, 0.0)
        if dt > 0:
            # Gravity in fb as the tick's specific force at the origin less the motion the
            # odometry knows (v_dot along x, w x v): g R^T e_z = f_o - v_dot - w x v.
            c = dt / (ODOMETRY_ACCELERATION_TIME_CONSTANT + dt)
            (ox, oy, oz), (vx, vy, vz), (v0x, v0y, v0z) = (self._odometry_acceleration,
                                                          velocity, self._v)
            ox, oy, oz = self._odometry_acceleration = (
                ox + c * ((vx - v0x) / dt - ox), oy + c * ((vy - v0y) / dt - oy),
                oz + c * ((vz - v0z) / dt - oz))
            cx, cy, cz = cross(w, velocity)
            gx, gy, gz = f_o[0] - ox - cx, f_o[1] - oy - cy, f_o[2] - oz - cz
            # Converge fast at start-up (the machine stands while the run gets ready).
            self._age += dt
            b = dt / (min(ATTITUDE_TIME_CONSTANT, 0.05 + self._age) + dt)
            n = norm((gx, gy, gz))
            up_meas = (gx / n, gy / n, gz / n)
            up_est = self._rotation[2].tolist()  # R^T e_z
            # Rotate the estimate by a share of the small angle between the up directions.
            x, y, z = cross(up_meas, up_est)
            self._rotation = _orthonormal(self._rotation @ _exp(b * x, b * y, b * z))
        self._v = velocity
        self._last_time = time

    def _update_c(self, time: float, dt: float, rates: np.ndarray, forces: np.ndarray,
                  n_w: int, n_f: int, wheel_speeds: np.ndarray | None) -> None:
        """`update` in C (`filters_c.base_step`): the means written into its input buffer."""
        inp = self._in
        inp[0] = dt
        # `mean(axis=0)` as the Python path's: numpy's reduction, then the division
        w, f = inp[1:4], inp[4:7]
        np.add.reduce(rates, 0, out=w)
        np.divide(w, n_w, out=w)
        np.add.reduce(forces, 0, out=f)
        np.divide(f, n_f, out=f)
        if wheel_speeds is None:
            inp[7] = 0.0
        else:
            inp[7] = 1.0
            inp[8:10] = wheel_speeds
        if not self._levelled:  # first tick: level the attitude on gravity at once
            if not np.isfinite(inp[1:7]).all():
                raise EstimatorError("IMU samples hold NaN or inf")
            self.level(f)
        if self._c():
            raise EstimatorError("IMU samples hold NaN or inf")
        self._last_time = time

    def level(self, specific_force: np.ndarray) -> None:
        """Level the attitude on the (finite) mean specific force [m/s^2] (3,) (yaw zero)."""
        self._levelled = True
        rotation = _level(np.array(specific_force, float))
        if self._c is not None:
            self._state[filters_c.BASE_STATE["rotation"]] = rotation.reshape(-1)
        else:
            self._rotation = rotation

    def _floats(self, name: str) -> list:
        """The field ``name`` (alpha, f, v, w) as floats: C's state buffer's, or Python's."""
        if self._c is not None:
            return self._state[filters_c.BASE_STATE[name]].tolist()
        return list(getattr(self, "_" + name))

    @property
    def rotation(self) -> np.ndarray:
        """The attitude world <- fb, (3, 3)."""
        if self._c is not None:
            return self._state[filters_c.BASE_STATE["rotation"]].reshape(3, 3).copy()
        return self._rotation

    @property
    def up(self) -> list:
        """``R^T e_z``, the third row of `rotation`, as floats (3,)."""
        if self._c is not None:
            return self._state[6:9].tolist()
        return self._rotation[2].tolist()

    @property
    def rate(self) -> np.ndarray:
        """The last tick's mean angular rate [rad/s] in fb, (3,)."""
        return np.array(self._floats("w"))

    @property
    def rotation_valid(self) -> bool:
        """Whether `rotation` passed `models.state.check_rotation`'s test (in C, its step's).

        False: failed, not finite, or not known (without C): the caller checks it.
        """
        return self._c is not None and self._state[_ROTATION_VALID] != 0.0

    def base_fields(self) -> np.ndarray:
        """[rotation (9, row-major); `twist` (6); `acceleration` (6)], (21,).

        With C its buffer's view (read-only; the next `update` writes it: copy to keep).
        """
        if self._c is not None:
            return self._fields
        return np.array([*self._rotation.reshape(-1).tolist(), *self.motion()])

    @property
    def angular_acceleration(self) -> np.ndarray:
        """[rad/s^2] in fb, (3,)."""
        return np.array(self._floats("alpha"))

    @property
    def specific_force(self) -> np.ndarray:
        """The specific force at the fb origin [m/s^2] in fb, (3,)."""
        return np.array(self._floats("f"))

    @property
    def velocity(self) -> np.ndarray:
        """The odometry's linear velocity [m/s] in fb, (3,)."""
        return np.array(self._floats("v"))

    @property
    def twist(self) -> np.ndarray:
        """[v; w] in fb, (6,)."""
        return np.array(self._floats("v") + self._floats("w"))

    def motion(self) -> list:
        """[`twist`; `acceleration`] as floats, (12,): the same numbers, no arrays made."""
        return self._floats("v") + self._floats("w") + self._v_dot() + self._floats("alpha")

    @property
    def acceleration(self) -> np.ndarray:
        """The twist derivative the dynamics get (module docstring), (6,)."""
        return np.array(self._v_dot() + self._floats("alpha"))

    def _v_dot(self) -> list:
        """The linear part of `acceleration`: ``f - w x v - g R^T e_z`` as floats, (3,).

        (C writes it at the end of its step, the same operations.)
        """
        if self._c is not None:
            return self._state[filters_c.BASE_STATE["v_dot"]].tolist()
        g = self.g
        return [fi - ci - g * ui
                for fi, ci, ui in zip(self._f, cross(self._w, self._v), self.up)]


def _orthonormal(r: np.ndarray) -> np.ndarray:
    """The rotation nearest ``r`` for a small drift: rows re-orthonormalised (Gram-Schmidt)."""
    (r0, _, r2) = r.tolist()
    n = norm(r2)
    z = [v / n for v in r2]
    d = r0[0] * z[0] + r0[1] * z[1] + r0[2] * z[2]
    x = [a - d * b for a, b in zip(r0, z)]
    n = norm(x)
    x = [v / n for v in x]
    return np.array([x, list(cross(z, x)), z])


def _level(f: np.ndarray) -> np.ndarray:
    """A rotation world <- fb whose up direction in fb is along ``f`` (yaw zero)."""
    up = f / np.linalg.norm(f)  # R^T e_z: the third row of R
    x = np.array([1.0, 0.0, 0.0]) - up[0] * up
    x /= np.linalg.norm(x)
    y = cross3(up, x)
    return np.vstack([x, y, up])
