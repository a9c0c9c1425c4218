"""MPC: per-wheel normal force above a threshold along the whole horizon."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from estimators.linearization import ForceLinearization
from models.coordinates import N_INDEPENDENT, SUSPENSION
from wbc.axes import N_AXES
from wbc.constraints.constraint import Inequality
from wbc.constraints.force_map_c import compiled_force_map, row_offsets
from wbc.constraints.force_rows import ForceRowsConstraint
from wbc.constraints.force_tick import ELSEWHERE, ForceTick
from wbc.drive_model import speed_scale_direction
from wbc.errors import ConfigurationError
from wbc.force_models.feedback import DIAGONAL
from wbc.force_models.protocol import (
    NormalForceModel,
    linearize_forces,
    linearize_nodes,
    linearized_contact_flags,
)
from wbc.mpc.prediction import nominal_state, predict_base_rotations

__all__ = ["HorizonNormalForceConstraint"]

_AXES_IN_A = slice(6, 6 + N_AXES)
_MIN_SCALE = 0.05  # below this the drift is not attributed to the driving speed
_all = np.logical_and.reduce  # `np.all` of a 1-D array without its Python dispatch


_SUSPENSION_IN_A = slice(6 + SUSPENSION.start, 6 + SUSPENSION.stop)


def _stacked(lins: list[ForceLinearization], which: np.ndarray, warp: bool
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``(G, d_q, d_qd, g0)`` of linearization ``which[k]`` for every node k: (n_eval, 4, .).

    With ``warp`` the suspension axes' columns are zeroed: the model holds the base
    acceleration and the contact points fixed, so its columns for the bogie strokes describe
    wheels pushed into the ground, not the machine: there the chassis moves instead (common
    mode) or warps (difference, `ctx.warp`).
    """
    G, dq, dqd, g0 = ForceLinearization.stacked(lins, which, ("G", "d_q", "d_qd", "g0"))
    if warp:
        G[:, :, _SUSPENSION_IN_A] = 0.0
        dq[:, :, SUSPENSION] = 0.0
        dqd[:, :, SUSPENSION] = 0.0
    return G, dq, dqd, g0


class HorizonNormalForceConstraint(ForceRowsConstraint):
    r"""``f_z,i(t_k) >= f_min,i`` at the steps k = 0..N-1, for every wheel i in contact now.

    Real-time iteration: the model is linearized at ``n_linearizations`` nodes ``j`` of the
    *nominal* trajectory, the previous plan shifted to now (``ctx.nominal_inputs``), with the
    base pose predicted at constant twist and the wheels at constant speed. Node k uses the
    last linearization point ``j <= k``:

    .. math:: f_k = g_{0,j} + G_{j} a_k + \frac{\partial f}{\partial q}\Big|_j (q_k - \bar q_j)
              + \frac{\partial f}{\partial \dot q}\Big|_j (\dot q_k - \bar{\dot q}_j),

    ``a_k = [a_base(s, t_k), u_k, qdd_wheels(s, t_k)]`` at the step's start time ``t_k``
    (`wbc.drive_model`, decaying as ``exp(-t_k/tau)``), ``q_k, \dot q_k`` the condensed
    prediction from ``ctx.q`` (step 0 is the measured state itself).
    G and g_0 are exact at the linearization points (the model's affine form); the
    configuration enters to first order.

    With ``ctx.feedback`` (`wbc.force_models.feedback`) its bias, the measured load split
    minus the model's, is added at every step (exact at step 0), and with ``ctx.warp`` and
    all four wheels in contact the chassis warp ``W (q_k - q_0)`` of the suspension setpoints
    is added at steps k >= 1 (the model's own suspension columns are dropped whenever there
    is a warp model, `_stacked`: on three wheels the warp is free);
    ``ctx.warp_drift`` adds the terrain's predicted twist along the diagonal, proportional
    to the wheel-speed scale (``drift * s / s_prev``). A terminal node (``T_b``) constrains
    the forces while every axis brakes to rest after the horizon (`forces_map`).

    Rows (`ForceRowsConstraint`) are scaled by ``1 / force_scale``, and with slacks in the
    layout they read ``f_k >= f_min - force_scale * eps``: one slack per wheel shared by all
    steps, or, with eight slacks, one per wheel for step 0 and another for the later steps
    and the terminal node. Step 0 is the measured state (only the accelerations act on it),
    and a wheel below its threshold *now* must not relax the plan for the rest of the
    horizon.

    Args:
        model: Normal-force model.
        thresholds: f_min [N], scalar or (4,), order FL, RL, FR, RR.
        n_linearizations: Number of model evaluations per tick (>= 1), spread evenly over
            the steps, the first at step 0 (the measured state).
        force_scale: Row scaling [N].
        drive_time_constant: tau [s] of the base drive.
        terminal_brake_time: T_b [s] of the terminal rows (see `forces_map`); None: none.
        start_time: Steps starting before this time [s] get no rows (their forces are
            still predicted): what happens within it follows from the state now, and
            constraining it only makes the QP push the wheels with crane accelerations.

    Attributes:
        last_forces_map: ``(A, b)``, the predicted forces ``A x + b`` [N] of all wheels,
            step-major (4 N,), then the terminal rows if any; for logging and tests.
        last_in_contact: Contact flags used, shape (4,).
        linearization_steps: Steps at which the model was evaluated at the last call.
        compiled: `forces_map` in C (`wbc.constraints.force_map_c`: one call a tick, the
            same numbers to round-off) when a C compiler is there; False: numpy (the
            reference). With a model that gives its nodes' kernel rows
            (`estimators.payload.PayloadEstimator.linearize_nodes`), a tick's rows are made
            from those rows without a `ForceLinearization` per node (`_rows_map`, the bits
            of the C `forces_map`); prepared (`prepare`), the force map and the rows
            ``G x <= h`` in one C call (`wbc.constraints.force_tick`, the bits of
            `ForceRowsConstraint.compute`).
    """

    def __init__(self, model: NormalForceModel, thresholds, n_linearizations: int = 3,
                 force_scale: float = 1e4, drive_time_constant: float = 0.5,
                 terminal_brake_time: float | None = None, start_time: float = 0.0):
        if not (n_linearizations >= 1 and force_scale > 0 and drive_time_constant > 0):
            raise ConfigurationError(f"need n_linearizations >= 1, force_scale > 0, "
                                     f"drive_time_constant > 0; got {n_linearizations}, "
                                     f"{force_scale}, {drive_time_constant}")
        if terminal_brake_time is not None and not terminal_brake_time > 0:
            raise ConfigurationError(f"terminal_brake_time must be > 0 s or None, got "
                                     f"{terminal_brake_time}")
        self.terminal_brake_time = (None if terminal_brake_time is None
                                    else float(terminal_brake_time))
        if not start_time >= 0:
            raise ConfigurationError(f"start_time must be >= 0 s, got {start_time}")
        self.start_time = float(start_time)
        super().__init__(model, thresholds, force_scale, drive_time_constant)
        self.n_linearizations = int(n_linearizations)
        self.compiled = True  # `forces_map` in C (`force_map_c`) when a compiler is there
        # Its `CompiledForceMap` (None without a compiler): built, or loaded from the cache,
        # here, never inside a control tick.
        self._compiled_map = compiled_force_map()
        self.linearization_steps: np.ndarray = np.zeros(0, dtype=int)
        self._structure_cache: tuple | None = None  # (key, structure, last context)
        self._offsets: tuple = (None, None)  # (row views, `row_offsets`) of `_rows_map`
        self._tick = ForceTick(_MIN_SCALE)  # `compute` in one C call, once prepared
        self._warp_cache: tuple | None = None

    def _structure(self, ctx) -> SimpleNamespace:
        """What the layout, step lengths, period and settings fix: built once for them.

        ``steps`` (the linearization steps, ``later_steps`` those after 0, at the start
        times ``later_times``), ``which`` (the one each evaluation node uses),
        ``j = steps[which]``, ``n_eval``, ``times`` (the nodes' times), ``since_j`` (time
        since node ``j``, (n_eval, 1)), ``decay`` (the drive's ``exp(-t / tau)``,
        (n_eval, 1)), ``u_flat`` (flat indices of the input blocks in A), ``Pq``, ``Pv``
        (the later nodes' prediction rows, (n_eval - 1, 9, n)), ``lq``, ``lv`` (their
        scalar factors, `CondensedPrediction.Lq`, ``Lv``) and the constrained
        ``nodes`` with their ``later`` flags.
        """
        settings = (self.n_linearizations, self.terminal_brake_time, self.drive_time_constant,
                    self.start_time)
        cache = self._structure_cache
        if cache is not None and cache[2] is ctx and cache[0][1:] == settings:
            return cache[1]  # the context of the last call (a tick asks three times; frozen)
        key = (ctx.structure_key, *settings)
        if cache is None or cache[0] != key:
            lay, pred = ctx.layout, ctx.prediction
            N, na = lay.n_steps, lay.n_axes
            steps = np.unique(np.round(np.linspace(0, N - 1, self.n_linearizations))
                              .astype(int))
            n_eval = N + (self.terminal_brake_time is not None)
            which = np.minimum(np.searchsorted(steps, np.arange(n_eval), side="right") - 1,
                               len(steps) - 1)
            times = np.append(pred.start_times, pred.horizon)  # evaluation times, N + 1
            j = steps[which]
            n_u = min(n_eval, N)  # steps with their own input; the rest is the terminal node
            u_cols = lay.step(0).start + np.arange(n_u * na).reshape(n_u, 1, na)
            u_flat = np.ravel_multi_index(np.broadcast_arrays(
                np.arange(n_u)[:, None, None], np.arange(4)[None, :, None], u_cols),
                (n_eval, 4, lay.n)).ravel()
            nodes = np.flatnonzero(times[:n_eval] >= self.start_time - 1e-12)
            cache = (key, SimpleNamespace(
                steps=steps, which=which, j=j, n_eval=n_eval, n_u=n_u, times=times,
                later_steps=steps[1:], later_times=times[steps[1:]],
                since_j=(times[:n_eval] - times[j])[:, None],
                decay=np.exp(-times[:n_eval] / self.drive_time_constant)[:, None],
                u_flat=u_flat, Pq=pred.Pq.reshape(N, na, lay.n)[:n_eval - 1],
                Pv=pred.Pv.reshape(N, na, lay.n)[:n_eval - 1], lq=pred.Lq, lv=pred.Lv,
                nodes=nodes,
                later=times[:n_eval][nodes] > ctx.dt / 2))
        self._structure_cache = (*cache[:2], ctx)
        return cache[1]

    def prepare(self, ctx) -> int:
        """What ``ctx``'s structure fixes, before the first tick (`Constraint.prepare`).

        `_structure`; with the C force map and a model that prepares its nodes' kernel rows
        (``prepare_nodes(n, m)``, `estimators.payload.PayloadEstimator`: its buffers and
        C call for the later nodes, returning the rows' `RowViews` and width), the row
        offsets, the force map's buffers for those rows (`_rows_map`) and the C tick's row
        plan of all four wheels in contact (`ForceTick.prepare`); and the rows of
        all four wheels in contact (`ForceRowsConstraint._rows`: other flags at the first
        tick make theirs): their number.
        """
        struct = self._structure(ctx)
        lay = ctx.layout
        self._rows(ctx, np.ones(4, dtype=bool), struct.n_eval)
        n_rows = 4 * struct.nodes.size  # the four wheels at each constrained node
        prepare_nodes = getattr(self.model, "prepare_nodes", None)
        if (self._kernel() is None or lay.n_axes != N_AXES or prepare_nodes is None
                or not hasattr(self.model, "linearize_nodes")):
            return n_rows
        kernel_rows = prepare_nodes(struct.later_steps.size, N_AXES)
        if kernel_rows is not None and getattr(kernel_rows[0], "slices", None) is not None:
            views, width = kernel_rows
            self._offsets = (views, row_offsets(views))
            self._tick.rows = (*self._offsets, (struct.steps.size, width))
            self._compiled_map.prepare(struct, lay.n_steps, lay.n, lay.scale,
                                       (struct.steps.size, width))
            self._tick.prepare(self, ctx, struct)
        return n_rows

    def compute(self, ctx) -> Inequality | None:
        """`ForceRowsConstraint.compute`: in one C call where prepared (`ForceTick`)."""
        done = self._tick.compute(self, ctx)
        return super().compute(ctx) if done is ELSEWHERE else done

    def linearize(self, ctx) -> tuple[np.ndarray, list[ForceLinearization], np.ndarray,
                                      np.ndarray]:
        """Evaluate the model along the nominal trajectory.

        The nodes after now in one compiled call where the model offers one
        (``linearize_states``, `estimators.payload.PayloadEstimator`: no `MachineState` per
        node, the same numbers), else one `nominal_state` each.

        Returns:
            (steps j, linearizations, nominal positions (N + 1, 9), nominal velocities
            (N + 1, 9)) with node 0 the measured state (its measured axes, which may differ
            from the prediction's start ``ctx.q`` by the servo deflection's vibration).
        """
        return self._linearize(ctx, linearize_forces(self.model, ctx.state),
                               *self._nominal(ctx))

    def _nominal(self, ctx, out: tuple | None = None) -> tuple[np.ndarray, np.ndarray]:
        """The nominal positions and velocities (N + 1, 9), node 0 the measured state's.

        Written into ``out`` if given: ``(qn, vn, qn[1:], vn[1:])`` (the C force map's
        buffers and their views, `ForceTick`).
        """
        pred, u = ctx.prediction, ctx.nominal_inputs
        if out is None:
            qn = np.empty((u.shape[0] + 1, N_AXES))
            vn = np.empty_like(qn)
            out = (qn, vn, qn[1:], vn[1:])
        qn, vn, q_later, v_later = out
        qn[0], vn[0] = ctx.state.q[:N_AXES], ctx.state.qd[:N_AXES]
        np.add(ctx.free_positions, pred.Lq @ u, out=q_later)  # `CondensedPrediction.trajectory`
        np.add(ctx.free_velocities, pred.Lv @ u, out=v_later)
        return qn, vn

    def _linearize(self, ctx, first: ForceLinearization, qn: np.ndarray, vn: np.ndarray
                   ) -> tuple:
        """`linearize` with node 0's linearization ``first`` and the nominal ``qn``, ``vn``."""
        start = ctx.prediction.start_times
        steps = self._structure(ctx).steps
        st = ctx.state
        lins = [first]  # steps[0] = 0: the measured state
        later = steps[1:]
        batch = getattr(self.model, "linearize_states", None)
        if batch is not None and later.size:  # the later nodes in one compiled call
            t = start[later]
            nodes = batch(st, t, predict_base_rotations(st, t), qn[later], vn[later])
            if nodes is not None:
                return steps, lins + nodes, qn, vn
        for j in later:
            lins.append(linearize_forces(self.model, nominal_state(st, start[j], qn[j], vn[j])))
        return steps, lins, qn, vn

    def forces_map(self, ctx, in_contact=None) -> tuple[np.ndarray, np.ndarray]:
        """``(A, b)``: predicted forces ``A x + b`` [N], step-major.

        Rows ``4k..4k+3`` are step k = 0..N-1; with a terminal brake time ``T_b`` four more
        rows give the forces at node N while every axis brakes to rest at ``-qd_N / T_b``:
        the plan must end in a state the machine can stop from, so it cannot borrow load
        from an acceleration it would have to undo just past the horizon. Shapes: A
        (4 (N + t), n), b (4 (N + t),), t = 1 with the terminal rows, else 0.
        ``in_contact`` None: the flags of the linearization at ``ctx.state`` (node 0).
        """
        return self._forces_map(ctx, self.linearize(ctx), in_contact)

    def _forces_and_flags(self, ctx) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """`forces_map`, the flags from its linearization at node 0, ``ctx.state``.

        With the C force map and a model that linearizes the horizon's nodes into kernel
        rows (``linearize_nodes``, `estimators.payload.PayloadEstimator`: node 0 and the
        later nodes in one compiled call), the rows go to the C without a linearization
        object per later node (`_rows_map`): the bits of `forces_map`.
        """
        st = ctx.state
        qn, vn = self._nominal(ctx)
        rows = None
        if (self._kernel() is not None and ctx.layout.n_axes == N_AXES
                and hasattr(self.model, "linearize_nodes")):
            struct = self._structure(ctx)
            later = struct.later_steps
            first, rows = linearize_nodes(self.model, st, struct.later_times, qn[later],
                                          vn[later])
        else:
            first = linearize_forces(self.model, st)
        flags = linearized_contact_flags(st, first)
        return (*self._map_of(ctx, first, rows, flags, qn, vn), flags)

    def _map_of(self, ctx, first: ForceLinearization, rows: np.ndarray | None, flags,
                qn: np.ndarray, vn: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """`forces_map` from node 0's linearization and the later nodes' kernel rows."""
        if rows is not None:
            fast = self._rows_map(ctx, first, rows, flags, qn, vn)
            if fast is not None:
                return fast
        return self._forces_map(ctx, self._linearize(ctx, first, qn, vn), flags)

    def _rows_map(self, ctx, first: ForceLinearization, rows: np.ndarray, in_contact,
                  qn: np.ndarray, vn: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
        """`_forces_map` in C on node 0's kernel row and the later nodes' ``rows``.

        None where that needs the objects: node 0 without a kernel row (a tipping state's
        least squares), rows of another length.
        """
        fields = first.__dict__
        views = fields.get("_views")
        row0 = fields.get("_row")
        if (getattr(views, "slices", None) is None or row0 is None
                or rows.shape[1] != row0.size):
            return None
        lay = ctx.layout
        struct = self._structure(ctx)
        self.linearization_steps = struct.steps
        if self._offsets[0] is not views:
            self._offsets = (views, row_offsets(views))
        direction, warp, drift, s_prev = self._terms(ctx, in_contact)
        return self._compiled_map.evaluate_rows(
            struct, lay.n_steps, lay.n, lay.scale, row0, rows, self._offsets[1], ctx, qn,
            vn, zero_suspension=ctx.warp is not None, warp=warp, direction=direction,
            bias=None if ctx.feedback is None else ctx.feedback.bias, drift=drift,
            s_prev=s_prev, brake_time=self.terminal_brake_time)

    def _terms(self, ctx, in_contact) -> tuple:
        """``(direction, warp, drift, s_prev)`` of `_forces_map` (None: no such term)."""
        lay, st = ctx.layout, ctx.state
        direction = (speed_scale_direction(st, ctx.speed_scale, self.drive_time_constant)
                     if lay.scale is not None else None)
        # On three wheels the warp is free: the suspension sets the lifted wheel down
        # without moving load (`lifted_wheel_thresholds` keeps the load it will need).
        warp = ctx.warp if _all(np.asarray(in_contact, dtype=bool)) else None
        drift = (ctx.warp_drift if warp is not None and ctx.warp_drift is not None
                 else None)
        return direction, warp, drift, max(ctx.speed_scale, _MIN_SCALE)

    def _forces_map(self, ctx, linearized: tuple, in_contact) -> tuple[np.ndarray, np.ndarray]:
        """`forces_map` from `linearize`'s result."""
        lay, pred = ctx.layout, ctx.prediction
        N, na = lay.n_steps, lay.n_axes
        struct = self._structure(ctx)
        steps, lins, qn, vn = linearized
        self.linearization_steps = steps
        n_eval, which, j = struct.n_eval, struct.which, struct.j
        st = ctx.state
        omega = st.qd[N_AXES:N_INDEPENDENT]
        if in_contact is None:
            in_contact = linearized_contact_flags(st, lins[0])
        direction, warp, drift, s_prev = self._terms(ctx, in_contact)
        kernel = self._kernel() if na == N_AXES else None
        if kernel is not None:
            return kernel.evaluate(
                struct, N, lay.n, lay.scale, lins, ctx, qn, vn,
                zero_suspension=ctx.warp is not None, warp=warp, direction=direction,
                bias=None if ctx.feedback is None else ctx.feedback.bias, drift=drift,
                s_prev=s_prev, brake_time=self.terminal_brake_time)
        # Every step at once: (n_eval, 4, .) stacks of the linearization each step uses
        # (the suspension acts through the warp model only when there is one).
        G, d_q, d_qd, g0 = _stacked(lins, which, ctx.warp is not None)
        dq, dqd = d_q[:, :, :N_AXES], d_qd[:, :, :N_AXES]
        G_axes = G[:, :, _AXES_IN_A]
        A = np.zeros((n_eval, 4, lay.n))
        b = g0 + (d_q[:, :, N_AXES:] @ omega) * struct.since_j
        # Steps k >= 1: the configuration moves along the condensed prediction.
        later = slice(1, n_eval)
        Pq, Pv = struct.Pq, struct.Pv
        A[later] = dq[later] @ Pq + dqd[later] @ Pv
        b[later] += (dq[later] @ (ctx.free_positions[:n_eval - 1] - qn[j[later]])[:, :, None]
                     + dqd[later] @ (ctx.free_velocities[:n_eval - 1]
                                     - vn[j[later]])[:, :, None])[:, :, 0]
        A.reshape(-1)[struct.u_flat] = G_axes[:struct.n_u].reshape(-1)
        if n_eval > N:  # terminal: brake to rest, a = -qd_N / T_b
            Tb = self.terminal_brake_time
            A[N] -= G_axes[N] @ pred.Pv[(N - 1) * na:N * na] / Tb
            b[N] -= G_axes[N] @ ctx.free_velocities[N - 1] / Tb
        if warp is not None:  # the suspension twists the chassis
            A[later] += self._warp_rows(warp, Pq)
            b[later] += (ctx.free_positions[:n_eval - 1] - ctx.q) @ ctx.warp.T
        if direction is not None:
            col = (G @ direction) * struct.decay
            A[:, :, lay.scale] += col
            b -= col * ctx.speed_scale
        A = A.reshape(4 * n_eval, lay.n)
        b = b.reshape(4 * n_eval)
        if ctx.feedback is not None:  # the load split measured now, held over the horizon
            b.reshape(n_eval, 4)[:] += ctx.feedback.bias
        if drift is not None:  # the terrain keeps twisting
            drift = (drift[:n_eval, None] * DIAGONAL).reshape(-1)  # kron(drift, D)
            b += drift
            if lay.scale is not None:
                A[:, lay.scale] += drift / s_prev
                b -= drift * ctx.speed_scale / s_prev
        return A, b

    def _kernel(self):
        """This constraint's `CompiledForceMap` if `compiled` (None without a compiler)."""
        return self._compiled_map if self.compiled else None

    def _warp_rows(self, warp: np.ndarray, Pq: np.ndarray) -> np.ndarray:
        """``warp @ Pq`` (n_eval - 1, 4, n), kept while the warp matrix stays the same."""
        if (self._warp_cache is None or self._warp_cache[1] is not Pq
                or not np.array_equal(self._warp_cache[0], warp)):
            self._warp_cache = (warp.copy(), Pq, warp @ Pq)
        return self._warp_cache[2]

    def _constrained_nodes(self, ctx, n_nodes: int) -> tuple[np.ndarray, np.ndarray]:
        """The nodes from `start_time` on; later: those after the first control period."""
        struct = self._structure(ctx)
        if n_nodes == struct.n_eval:
            return struct.nodes, struct.later
        times = np.append(ctx.prediction.start_times, ctx.prediction.horizon)[:n_nodes]
        nodes = np.flatnonzero(times >= self.start_time - 1e-12)
        return nodes, times[nodes] > ctx.dt / 2
