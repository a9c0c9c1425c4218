r"""The crane's accelerations from its link accelerometers and the encoders' estimate.

The stroke sensors' accelerations come from differentiating positions twice: the joint
filter (`joint_filter.JointFilter`) smooths them, and lags a sudden change by several ticks.
An accelerometer fixed to a link reads its specific force without that lag; it is affine in
the axes' accelerations ``u`` (`estimators.efforts.ActuatorEfforts.point_specific_forces`):
``f = A u + b`` at the state's positions, velocities and base motion. The slew, lift, tilt
and telescope accelerations (`AXES`) are the weighted least-squares fit of the encoders'
estimate (the prior, its std per axis) and the accelerometers' tick means (their std):

.. math:: u = u_e + (A^T W A + \Sigma_e^{-1})^{-1} A^T W (f - A u_e - b)

The wrist and the suspension axes are not seen by these accelerometers (downstream of the
telescope's tip, or not in the crane's chain) and keep the encoders' estimate. The fit's
std per axis is the square root of the diagonal of the inverse.
"""

from __future__ import annotations

import numpy as np

from estimators.efforts import ActuatorEfforts
from estimators.observer import fusion_c
from estimators.observer._linalg import inv
from models.cbuild import bind
from models.sensing import LinkAccelerometer, Samples
from models.state import N_SERVO_AXES, MachineState

__all__ = ["AXES", "LINK_EXPECTED_PICK_TICKS", "LINK_LEVER", "LINK_PAYLOAD_FILTER_TIME",
           "MODEL_STD", "LinkFusion"]

AXES = np.array([2, 3, 4, 5])  # slew, lift, tilt, telescope: q[:9] indices
_AXES_SLICE = slice(2, 6)  # the same, as a slice (a view: cheaper to update in place)
# [m/s^2] what a reading's prediction misses besides the sensor and the base: the tick's
# mean (the pressures' window too) against the tick's instant (the positions').
MODEL_STD = 0.02
LINK_LEVER = 4.0  # [m] from the chassis IMU to the link accelerometers (a typical reach)
# With link accelerometers the regression's accelerations carry less noise: the observer's
# payload low-pass is shorter, and an expected pick an event after one tick (`docs/sweeps.md`).
LINK_PAYLOAD_FILTER_TIME = 0.01  # [s]
LINK_EXPECTED_PICK_TICKS = 1


class LinkFusion:
    """Fuses the link accelerometers into the crane's accelerations (module docstring).

    Args:
        efforts: The machine's `ActuatorEfforts` (its kinematics).
        accelerometers: The link accelerometers' specs.
        base_std: Std of the base's acceleration estimate at the accelerometers [m/s^2]
            (it enters every reading's prediction).
        prior_std: Std of the encoders' acceleration estimate of each of the nine axes
            [m/s^2], shape (9,).
        compiled: Fit in C (`fusion_c`, the same results to round-off) when a C compiler
            and the efforts' kernels are there; False: numpy.
    """

    def __init__(self, efforts: ActuatorEfforts, accelerometers: tuple[LinkAccelerometer, ...],
                 base_std: float, prior_std, compiled: bool = True):
        self.efforts = efforts
        self.accelerometers = tuple(accelerometers)
        prior = np.asarray(prior_std, float)[AXES]
        self._prior_info = np.diag(1.0 / prior ** 2)
        self._mounts = tuple((a.body, a.position) for a in self.accelerometers)
        efforts.prepare_points(self._mounts)  # compiled before the loop's first tick
        # Per reading: the sample noise (averaged over the tick's n samples), and the floor
        # n does not lower (bias, the base's error, a tick's mean against its instant).
        self._variance = np.repeat([a.accelerometer.sample_std ** 2
                                    for a in self.accelerometers], 3)
        self._floor = np.repeat([a.accelerometer.bias ** 2 + float(base_std) ** 2
                                 + MODEL_STD ** 2 for a in self.accelerometers], 3)
        self.std = prior.copy()
        self._weights_of: dict[int, tuple] = {}  # `_weights`: a handful of sample counts
        lib = fusion_c.compiled_fusion() if compiled else None
        self._c = None
        if lib is not None:  # the fit's inputs and outputs in buffers C reads and writes
            m = 3 * len(self.accelerometers)
            self._mean, self._w = np.zeros(m), np.zeros(m)
            self._prior_diag = np.ascontiguousarray(self._prior_info.diagonal())
            self._io = np.zeros(N_SERVO_AXES + len(AXES))
            self._row, self._row_at = None, 0
            self._w_of = 0  # the sample count `_w` holds the weights of (0: none yet)
            self._c = bind(lib.link_fuse, m, self._mean, self._w, self._prior_diag, self._io)
            self._lib = lib
            self._bind_samples(16)

    def _bind_samples(self, rows: int) -> None:
        """A samples buffer of ``rows`` rows and ``link_mean`` bound to it (`_tick_mean`)."""
        self._samples = np.zeros((rows, self._mean.size))
        self._mean_c = bind(self._lib.link_mean, self._samples, self._mean, self._mean.size)

    def _tick_mean(self, value: np.ndarray, n: int) -> bool:
        """The readings' tick means into ``_mean`` in C (numpy's sums); whether finite."""
        if n > self._samples.shape[0]:
            self._bind_samples(2 * n)
        self._samples[:n] = value
        return self._mean_c(n) == 0

    def accelerations(self, state: MachineState, readings: Samples | None) -> np.ndarray:
        """``state.qdd`` with the four crane axes' fitted to the accelerometers' tick means.

        Without readings this tick (or with a non-finite one) the encoders' estimate stays.
        """
        qdd = state.qdd.copy()
        if readings is None:
            return qdd
        value = readings.value
        n = value.shape[0]
        if not n:
            return qdd
        if self._c is not None:
            if not self._tick_mean(value, n):
                return qdd
            row = self.efforts.point_specific_forces_row(state, self._mounts)
            if row is not None:
                return self._fit_c(qdd, row, n)
            mean = self._mean.copy()
        else:
            mean = np.add.reduce(value, 0) / n
            if not np.isfinite(mean).all():
                return qdd
        a, b = self.efforts.point_specific_forces(state, self._mounts)
        residual = mean - a @ qdd[:N_SERVO_AXES] - b
        a = a[:, AXES]
        w, w_column = self._weights(n)
        cov = inv(a.T @ (w_column * a) + self._prior_info)
        du = cov @ (a.T @ (w * residual))
        if np.isfinite(du).all():
            qdd[_AXES_SLICE] += du
            self.std = np.sqrt(cov.diagonal())
        return qdd

    def _fit_c(self, qdd: np.ndarray, row: np.ndarray, n: int) -> np.ndarray:
        """`accelerations`' fit in C (`fusion_c`) on the points kernel's output ``row``.

        The readings' means are in ``_mean`` (`_tick_mean`).
        """
        if row is not self._row:  # this thread's kernel buffer: the same one every tick
            self._row, self._row_at = row, row.ctypes.data
        if n != self._w_of:
            self._w[:] = self._weights(n)[0]
            self._w_of = n
        io = self._io
        io[:N_SERVO_AXES] = qdd[:N_SERVO_AXES]
        if self._c(self._row_at) == 0:
            qdd[_AXES_SLICE] = io[_AXES_SLICE]
            self.std = io[N_SERVO_AXES:].copy()
        return qdd

    def _weights(self, n: int) -> tuple[np.ndarray, np.ndarray]:
        """The readings' weights of a tick of ``n`` samples, (3 k,) and as a column (kept)."""
        hit = self._weights_of.get(n)
        if hit is None:
            w = 1.0 / (self._variance / n + self._floor)
            hit = self._weights_of[n] = (w, w[:, None])
        return hit
