"""Track the axis reference with a PD law at acceleration level."""

from __future__ import annotations

import numpy as np

from wbc.axes import N_AXES, axis_index
from wbc.errors import ConfigurationError
from wbc.tasks.task import ConstantJacobianTask

__all__ = ["JointTask"]


def _axes(axes) -> np.ndarray:
    a = np.asarray(axes, dtype=int).reshape(-1)
    if a.size == 0 or np.any(a < 0) or np.any(a >= N_AXES) or len(set(a.tolist())) != a.size:
        raise ConfigurationError(f"axes must be distinct indices in [0, {N_AXES}), got {axes}")
    return a


def _gain(name: str, value, n: int) -> np.ndarray:
    g = np.broadcast_to(np.asarray(value, dtype=float), (n,)).copy()
    if not np.all(np.isfinite(g)) or np.any(g < 0):
        raise ConfigurationError(f"{name} must be finite and >= 0, got {value}")
    return g


class JointTask(ConstantJacobianTask):
    r"""Axis accelerations follow the reference with PD feedback.

    .. math:: \ddot q^* = \ddot q_{ref} + K_p (q_{ref} - q) + K_d (\dot q_{ref} - \dot q),
              \qquad r(x) = \ddot q_{axes} - \ddot q^*_{axes}.

    The task is inactive while the context has no reference.

    Args:
        axes: Indices of the controlled axes (see `wbc.axes`).
        kp: Proportional gain(s) [1/s^2], scalar or one per axis.
        kd: Derivative gain(s) [1/s], scalar or one per axis.
        weight: Scalar or one per axis.
    """

    def __init__(self, axes, kp, kd, weight=1.0):
        self.axes = _axes(axes)
        n = self.axes.size
        self._index = axis_index(self.axes)
        super().__init__(np.broadcast_to(np.asarray(weight, float), (n,)).copy())
        self.kp = _gain("kp", kp, n)
        self.kd = _gain("kd", kd, n)
        self.kp.setflags(write=False)  # fixed, as the weight (a compiled tick reads them once)
        self.kd.setflags(write=False)

    def is_active(self, ctx) -> bool:
        """Active while a reference is given."""
        return ctx.reference is not None

    def desired_acceleration(self, ctx) -> np.ndarray:
        """The PD law's acceleration of the task's axes, shape (len(axes),)."""
        ref = ctx.reference
        i = self._index
        return (ref.acceleration[i] + self.kp * (ref.position[i] - ctx.q[i])
                + self.kd * (ref.velocity[i] - ctx.qd[i]))

    def compute_error(self, ctx) -> np.ndarray:
        """``-qdd*`` of the task's axes.

        Computed as ``K_p (q - q_ref) - qdd_ref + K_d (qd - qd_ref)``, in place: each
        difference, product and sum is the negated one of `desired_acceleration` (rounding
        is symmetric in sign), so the very same numbers, with one operation and three
        arrays less per tick.
        """
        ref, i = ctx.reference, self._index
        err = np.subtract(ctx.q[i], ref.position[i])
        err *= self.kp
        err -= ref.acceleration[i]
        damp = np.subtract(ctx.qd[i], ref.velocity[i])
        damp *= self.kd
        err += damp
        return err

    def compute_jacobian(self, ctx) -> np.ndarray:
        """Selection of the task's axes in step 0."""
        jac = np.zeros((self.axes.size, ctx.layout.n))
        jac[np.arange(self.axes.size), ctx.layout.step(0).start + self.axes] = 1.0
        return jac
