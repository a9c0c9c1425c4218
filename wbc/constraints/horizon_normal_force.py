"""MPC: per-wheel normal force above a threshold along the whole horizon."""

from __future__ import annotations

import numpy as np

from models.coordinates import N_INDEPENDENT, WHEELS
from models.state import MachineState
from wbc.axes import N_AXES
from wbc.constraints.constraint import Constraint, Inequality
from wbc.constraints.normal_force import check_thresholds
from wbc.drive_model import speed_scale_direction
from wbc.errors import ConfigurationError
from wbc.force_models.protocol import (
    ForceLinearization,
    NormalForceModel,
    contact_flags,
    linearize_forces,
)
from wbc.mpc.prediction import predict_base_pose

__all__ = ["HorizonNormalForceConstraint"]

_AXES_IN_A = slice(6, 6 + N_AXES)


class HorizonNormalForceConstraint(Constraint):
    r"""``f_z,i(t_k) >= f_min,i`` at the steps k = 0..N-1, for every wheel i in contact now.

    Real-time iteration: the model is linearized at ``n_linearizations`` nodes ``j`` of the
    *nominal* trajectory, the previous plan shifted to now (``ctx.nominal_inputs``), with the
    base pose predicted at constant twist and the wheels at constant speed. Node k uses the
    last linearization point ``j <= k``:

    .. math:: f_k = g_{0,j} + G_{j} a_k + \frac{\partial f}{\partial q}\Big|_j (q_k - \bar q_j)
              + \frac{\partial f}{\partial \dot q}\Big|_j (\dot q_k - \bar{\dot q}_j),

    ``a_k = [a_base(s, t_k), u_k, qdd_wheels(s, t_k)]`` at the step's start time ``t_k``
    (`wbc.drive_model`, decaying as ``exp(-t_k/tau)``), ``q_k, \dot q_k`` the condensed
    prediction (``q_0`` measured).
    G and g_0 are exact at the linearization points (the model's affine form); the
    configuration enters to first order. Rows are scaled by ``1 / force_scale``, and with
    slacks in the layout (one per wheel, shared by all steps) they read
    ``f_k >= f_min - force_scale * eps``.

    Args:
        model: Normal-force model.
        thresholds: f_min [N], scalar or (4,), order FL, RL, FR, RR.
        n_linearizations: Number of model evaluations per tick (>= 1), spread evenly over
            the steps, the first at step 0 (the measured state).
        force_scale: Row scaling [N].
        drive_time_constant: tau [s] of the base drive.

    Attributes:
        last_forces_map: ``(A, b)``, the predicted forces ``A x + b`` [N] of all wheels,
            step-major (N * 4,); for logging and tests.
        last_in_contact: Contact flags used, shape (4,).
        linearization_steps: Steps at which the model was evaluated at the last call.
    """

    def __init__(self, model: NormalForceModel, thresholds, n_linearizations: int = 3,
                 force_scale: float = 1e4, drive_time_constant: float = 0.5):
        if not (n_linearizations >= 1 and force_scale > 0 and drive_time_constant > 0):
            raise ConfigurationError(f"need n_linearizations >= 1, force_scale > 0, "
                                     f"drive_time_constant > 0; got {n_linearizations}, "
                                     f"{force_scale}, {drive_time_constant}")
        self.model = model
        self.thresholds = check_thresholds(thresholds)
        self.n_linearizations = int(n_linearizations)
        self.force_scale = float(force_scale)
        self.drive_time_constant = float(drive_time_constant)
        self.last_forces_map: tuple[np.ndarray, np.ndarray] | None = None
        self.last_in_contact: np.ndarray | None = None
        self.linearization_steps: np.ndarray = np.zeros(0, dtype=int)

    def _nominal_state(self, ctx, t: float, q_axes, qd_axes) -> MachineState:
        st = ctx.state
        pos, rot = predict_base_pose(st, t)
        q = st.q.copy()
        qd = st.qd.copy()
        q[:N_AXES], qd[:N_AXES] = q_axes, qd_axes
        q[WHEELS] += t * st.qd[WHEELS]
        return MachineState(pos, rot, st.base_twist, np.zeros(6), q, qd,
                            np.zeros(N_INDEPENDENT), st.time + t, st.contacts,
                            st.suspension_force, st.payload_mass)

    def linearize(self, ctx) -> tuple[np.ndarray, list[ForceLinearization], np.ndarray,
                                      np.ndarray]:
        """Evaluate the model along the nominal trajectory.

        Returns:
            (steps j, linearizations, nominal positions (N + 1, 9), nominal velocities
            (N + 1, 9)) with node 0 the measured state.
        """
        N = ctx.layout.n_steps
        start = ctx.prediction.start_times
        qn, vn = ctx.prediction.trajectory(ctx.q, ctx.qd, ctx.nominal_inputs)
        qn = np.vstack([ctx.q, qn])
        vn = np.vstack([ctx.qd, vn])
        steps = np.unique(np.round(np.linspace(0, N - 1, self.n_linearizations)).astype(int))
        lins = []
        for j in steps:
            st = ctx.state if j == 0 else self._nominal_state(ctx, start[j], qn[j], vn[j])
            lins.append(linearize_forces(self.model, st))
        return steps, lins, qn, vn

    def forces_map(self, ctx) -> tuple[np.ndarray, np.ndarray]:
        """``(A, b)``: predicted forces ``A x + b`` [N], A (4N, n), b (4N,), step-major."""
        lay, pred = ctx.layout, ctx.prediction
        N, na = lay.n_steps, lay.n_axes
        start = pred.start_times
        steps, lins, qn, vn = self.linearize(ctx)
        self.linearization_steps = steps
        which = np.searchsorted(steps, np.arange(N), side="right") - 1
        st = ctx.state
        direction = (speed_scale_direction(st, ctx.speed_scale, self.drive_time_constant)
                     if lay.scale is not None else None)
        A = np.zeros((4 * N, lay.n))
        b = np.zeros(4 * N)
        omega = st.qd[N_AXES:N_INDEPENDENT]
        for k in range(N):
            j = steps[which[k]]
            lin = lins[which[k]]
            r = slice(4 * k, 4 * k + 4)
            dq, dqd = lin.dq[:, :N_AXES], lin.dqd[:, :N_AXES]
            A[r, lay.step(k)] = lin.G[:, _AXES_IN_A]
            b[r] = lin.g0 + lin.dq[:, N_AXES:] @ (omega * (start[k] - start[j]))
            if k == 0:
                b[r] += dq @ (ctx.q - qn[j]) + dqd @ (ctx.qd - vn[j])
            else:
                rows = slice((k - 1) * na, k * na)
                A[r] += dq @ pred.Pq[rows] + dqd @ pred.Pv[rows]
                b[r] += (dq @ (ctx.free_positions[k - 1] - qn[j])
                         + dqd @ (ctx.free_velocities[k - 1] - vn[j]))
            if direction is not None:
                col = (lin.G @ direction) * np.exp(-start[k] / self.drive_time_constant)
                A[r, lay.scale] += col
                b[r] -= col * ctx.speed_scale
        return A, b

    def compute(self, ctx) -> Inequality | None:
        """Rows ``-(A x + b) / f_s - eps <= -f_min / f_s`` of the wheels in contact now."""
        A, b = self.forces_map(ctx)
        flags = contact_flags(self.model, ctx.state)
        self.last_forces_map, self.last_in_contact = (A, b), flags
        wheels = np.flatnonzero(flags)
        if wheels.size == 0:
            return None
        N = ctx.layout.n_steps
        rows = (4 * np.arange(N)[:, None] + wheels[None, :]).ravel()
        G = -A[rows] / self.force_scale
        h = (b[rows] - np.tile(self.thresholds[wheels], N)) / self.force_scale
        if ctx.layout.slack is not None:
            G[np.arange(rows.size), ctx.layout.slack.start + np.tile(wheels, N)] = -1.0
        return Inequality(G, h)
