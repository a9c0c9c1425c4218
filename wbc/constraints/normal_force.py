"""Per-wheel normal force above a threshold, from the model's exact affine form."""

from __future__ import annotations

import numpy as np

from models.coordinates import N_INDEPENDENT
from wbc.axes import N_AXES
from wbc.constraints.force_rows import ForceRowsConstraint
from wbc.drive_model import speed_scale_direction
from wbc.errors import ConfigurationError
from wbc.force_models.protocol import (
    NormalForceModel,
    linearize_forces,
    linearized_contact_flags,
)

__all__ = ["NormalForceConstraint"]

_AXES_IN_A = slice(6, 6 + N_AXES)  # columns of the nine axes in a = [base (6), qdd (13)]


class NormalForceConstraint(ForceRowsConstraint):
    r"""``f_z,i >= f_min,i`` for every wheel i in contact (whole-body QP).

    The model gives the forces exactly affine in the generalized accelerations,
    ``f_z = G a + g_0`` with ``a = [a_base (6), qdd (13)]`` (paper eqs. 20-28). The nine axis
    accelerations are the decision variables; the base and wheel accelerations come from the
    base-drive model (`wbc.drive_model`: zero at constant speed, linear in the speed scale
    ``s`` when it is a decision variable). With ``lookahead = T > 0`` the configuration
    change over T enters through ``df_z/dq``:

    .. math:: f_z(x) = g_0 + G_{axes} \ddot q + (G\, \partial a/\partial s)(s - s_{prev})
              + \frac{\partial f_z}{\partial q}_{axes} (\dot q T + \tfrac12 \ddot q T^2).

    Rows (`ForceRowsConstraint`) at the one node, now: ``f_z(x) >= f_min - force_scale *
    eps``, scaled by ``1 / force_scale``, with ``eps`` the wheel's slack if the layout has
    slacks.

    Args:
        model: The normal-force model.
        thresholds: f_min [N], scalar or shape (4,), order FL, RL, FR, RR.
        lookahead: T [s] (0: accelerations only).
        force_scale: Row scaling [N].
        drive_time_constant: tau of the base drive [s] (`wbc.drive_model`).

    Attributes:
        last_forces_map: ``(A, b)`` of the last call, the predicted forces ``A x + b`` [N]
            of all four wheels; for logging and tests.
        last_in_contact: Contact flags of the last call, shape (4,).
    """

    def __init__(self, model: NormalForceModel, thresholds, lookahead: float = 0.0,
                 force_scale: float = 1e4, drive_time_constant: float = 0.5):
        if not (lookahead >= 0 and force_scale > 0 and drive_time_constant > 0):
            raise ConfigurationError(f"need lookahead >= 0, force_scale > 0, "
                                     f"drive_time_constant > 0; got {lookahead}, "
                                     f"{force_scale}, {drive_time_constant}")
        super().__init__(model, thresholds, force_scale, drive_time_constant)
        self.lookahead = float(lookahead)

    def forces_map(self, ctx, in_contact=None) -> tuple[np.ndarray, np.ndarray]:
        """``(A, b)``: predicted forces ``A x + b`` [N], A shape (4, n), b (4,)."""
        return self._forces_map(ctx, linearize_forces(self.model, ctx.state))

    def _forces_and_flags(self, ctx) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """`forces_map`, the flags from its linearization at ``ctx.state``."""
        lin = linearize_forces(self.model, ctx.state)
        return (*self._forces_map(ctx, lin), linearized_contact_flags(ctx.state, lin))

    def _forces_map(self, ctx, lin) -> tuple[np.ndarray, np.ndarray]:
        st, lay = ctx.state, ctx.layout
        T = self.lookahead
        A = np.zeros((4, lay.n))
        b = lin.g0.copy()
        A[:, lay.step(0)] = lin.G[:, _AXES_IN_A]
        if T > 0:
            dq = lin.d_q[:, :N_AXES]
            A[:, lay.step(0)] += 0.5 * T * T * dq
            b += dq @ (ctx.qd * T) + lin.d_q[:, N_AXES:N_INDEPENDENT] @ (
                st.qd[N_AXES:N_INDEPENDENT] * T)
        if lay.scale is not None:
            col = lin.G @ speed_scale_direction(st, ctx.speed_scale, self.drive_time_constant)
            A[:, lay.scale] = col
            b -= col * ctx.speed_scale
        return A, b
