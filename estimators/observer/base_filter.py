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

import numpy as np

from estimators.errors import EstimatorError
from models.rotations import axis_rotation, cross3

__all__ = ["ANGULAR_ACCELERATION_TIME_CONSTANT", "ATTITUDE_TIME_CONSTANT", "BaseFilter",
           "ODOMETRY_ACCELERATION_TIME_CONSTANT"]

ATTITUDE_TIME_CONSTANT = 2.0  # [s] the accelerometer's pull on the attitude
ANGULAR_ACCELERATION_TIME_CONSTANT = 0.03  # [s]
ODOMETRY_ACCELERATION_TIME_CONSTANT = 0.05  # [s] low-pass of the odometry's speed change


def _exp(w_dt: np.ndarray) -> np.ndarray:
    angle = float(np.linalg.norm(w_dt))
    if angle < 1e-12:
        return np.eye(3)
    return axis_rotation(w_dt / angle, angle)


class BaseFilter:
    """The chassis state from IMU samples and wheel speeds (module docstring).

    Args:
        imu_position: Lever arm ``p`` of the IMU in fb [m], (3,).
        gravity: [m/s^2].
        wheel_radius: [m].
    """

    def __init__(self, imu_position, gravity: float, wheel_radius: float):
        self.p = np.asarray(imu_position, float)
        self.g = float(gravity)
        self.r_wheel = float(wheel_radius)
        self.rotation = np.eye(3)
        self.rate = np.zeros(3)
        self.angular_acceleration = np.zeros(3)
        self.specific_force = np.array([0.0, 0.0, self.g])
        self.velocity = np.zeros(3)
        self._levelled = False
        self._odometry_acceleration = np.zeros(3)
        self._last_rate: np.ndarray | None = None
        self._last_time: float | None = None
        self._age = 0.0

    def update(self, time: float, rates: np.ndarray, forces: np.ndarray,
               wheel_speeds: np.ndarray | None) -> None:
        """Take one tick's IMU samples ((k, 3) each) and the latest side speeds (2,)."""
        if rates.shape[0] == 0 or forces.shape[0] == 0:
            return  # nothing new: keep the state (the caller flags the gap)
        w = rates.mean(axis=0)
        f_p = forces.mean(axis=0)
        if not (np.all(np.isfinite(w)) and np.all(np.isfinite(f_p))):
            raise EstimatorError("IMU samples hold NaN or inf")
        dt = 0.0 if self._last_time is None else max(time - self._last_time, 0.0)
        if not self._levelled:  # first tick: level the attitude on gravity at once
            self._levelled = True
            self.rotation = _level(f_p)
        if dt > 0:
            self.rotation = self.rotation @ _exp(w * dt)
            a = dt / (ANGULAR_ACCELERATION_TIME_CONSTANT + dt)
            raw = (w - self._last_rate) / dt
            self.angular_acceleration = self.angular_acceleration + a * (
                raw - self.angular_acceleration)
        self.rate = w
        self._last_rate = w
        alpha, p = self.angular_acceleration, self.p
        self.specific_force = f_p - cross3(alpha, p) - cross3(w, cross3(w, p))
        velocity = self.velocity
        if wheel_speeds is not None and np.all(np.isfinite(wheel_speeds)):
            velocity = np.array([self.r_wheel * 0.5 * (wheel_speeds[0] + wheel_speeds[1]),
                                 0.0, 0.0])
        if dt > 0:
            # Gravity in fb as the tick's specific force at the origin less the motion the
            # odometry knows (v_dot along x, w x v): g R^T e_z = f_o - v_dot - w x v.
            c = dt / (ODOMETRY_ACCELERATION_TIME_CONSTANT + dt)
            self._odometry_acceleration += c * ((velocity - self.velocity) / dt
                                                - self._odometry_acceleration)
            gravity = (self.specific_force - self._odometry_acceleration
                       - cross3(w, velocity))
            # Converge fast at start-up (the machine stands while the run gets ready).
            self._age += dt
            b = dt / (min(ATTITUDE_TIME_CONSTANT, 0.05 + self._age) + dt)
            up_meas = gravity / np.linalg.norm(gravity)
            up_est = self.rotation[2]  # R^T e_z
            # Rotate the estimate by a share of the small angle between the up directions.
            self.rotation = self.rotation @ _exp(b * cross3(up_meas, up_est))
            self.rotation = _orthonormal(self.rotation)
        self.velocity = velocity
        self._last_time = time

    @property
    def twist(self) -> np.ndarray:
        """[v; w] in fb, (6,)."""
        return np.concatenate([self.velocity, self.rate])

    @property
    def acceleration(self) -> np.ndarray:
        """The twist derivative the dynamics get (module docstring), (6,)."""
        v_dot = (self.specific_force - cross3(self.rate, self.velocity)
                 - self.g * self.rotation[2])
        return np.concatenate([v_dot, self.angular_acceleration])


def _orthonormal(r: np.ndarray) -> np.ndarray:
    """The rotation nearest ``r`` for a small drift: rows re-orthonormalised (Gram-Schmidt)."""
    z = r[2] / np.linalg.norm(r[2])
    x = r[0] - (r[0] @ z) * z
    x /= np.linalg.norm(x)
    return np.vstack([x, cross3(z, x), z])


def _level(f: np.ndarray) -> np.ndarray:
    """A rotation world <- fb whose up direction in fb is along ``f`` (yaw zero)."""
    up = f / np.linalg.norm(f)  # R^T e_z: the third row of R
    x = np.array([1.0, 0.0, 0.0]) - up[0] * up
    x /= np.linalg.norm(x)
    y = cross3(up, x)
    return np.vstack([x, y, up])
