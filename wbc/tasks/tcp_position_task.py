"""Track a tool-point position in fb with a PD law at acceleration level."""

from __future__ import annotations

import numpy as np

from wbc.axes import N_AXES
from wbc.errors import WbcInputError
from wbc.kinematics.tcp_kinematics import TcpKinematics
from wbc.tasks.task import Task

__all__ = ["TcpPositionTask"]


class TcpPositionTask(Task):
    r"""TCP acceleration follows a PD law towards a target position in fb.

    .. math:: \ddot p^* = K_p (p^* - p) - K_d \dot p, \qquad
              r(x) = J \ddot q + \dot J \dot q - \ddot p^*,

    ``J`` the TCP Jacobian of the nine axes (`TcpKinematics.jacobian`).

    Args:
        kinematics: TCP kinematics.
        target_in_fb: Target TCP position in fb [m], shape (3,); None: inactive.
        kp: [1/s^2]. kd: [1/s]. weight: Scalar or per-axis (x, y, z).
    """

    def __init__(self, kinematics: TcpKinematics, target_in_fb=None, kp: float = 4.0,
                 kd: float = 4.0, weight=1.0):
        super().__init__(weight)
        self.kinematics = kinematics
        self.kp = float(kp)
        self.kd = float(kd)
        self.target = None
        if target_in_fb is not None:
            self.set_target(target_in_fb)

    def set_target(self, target_in_fb) -> None:
        """Set the target position in fb [m], shape (3,)."""
        t = np.asarray(target_in_fb, dtype=float)
        if t.shape != (3,) or not np.all(np.isfinite(t)):
            raise WbcInputError(f"TCP target must be finite with shape (3,), got {target_in_fb}")
        self.target = t

    def is_active(self, ctx) -> bool:
        """Active when a target is set."""
        return self.target is not None

    def compute_error(self, ctx) -> np.ndarray:
        """``Jdot qd - pdd*`` [m/s^2], shape (3,)."""
        st = ctx.state
        p = self.kinematics.position(st.q)
        v = self.kinematics.velocity(st.q, st.qd)
        bias = self.kinematics.bias_acceleration(st.q, st.qd)
        return bias - (self.kp * (self.target - p) - self.kd * v)

    def compute_jacobian(self, ctx) -> np.ndarray:
        """TCP Jacobian on step 0's accelerations, shape (3, n)."""
        jac = np.zeros((3, ctx.layout.n))
        jac[:, ctx.layout.step(0)] = self.kinematics.jacobian(ctx.state.q)[:, :N_AXES]
        return jac
