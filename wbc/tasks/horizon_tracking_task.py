"""MPC: follow the axis reference at every node of the horizon."""

from __future__ import annotations

import numpy as np

from wbc.errors import ConfigurationError
from wbc.tasks.joint_task import _axes, _gain
from wbc.tasks.linear_c import TRACKING, LinearTerm
from wbc.tasks.task import ConstantJacobianTask

__all__ = ["HorizonTrackingTask"]


class HorizonTrackingTask(ConstantJacobianTask):
    r"""Position and velocity tracking over the horizon, for some axes.

    .. math:: \sum_{k=1}^{N} c_k \big(\|q_k - q^{ref}_k\|^2_{W_q}
              + \|\dot q_k - \dot q^{ref}_k\|^2_{W_v}\big),

    ``c_k = 1`` and ``c_N = terminal_factor``; ``q_k = Pq x + q_free`` (condensed
    prediction). The reference is the Ruckig trajectory sampled at the node times, so the
    MPC sees where the reference goes over the whole horizon.

    Args:
        axes: Axis indices.
        position_weight: W_q, scalar or per axis.
        velocity_weight: W_v, scalar or per axis.
        terminal_factor: c_N >= 1.
    """

    def __init__(self, axes, position_weight, velocity_weight, terminal_factor: float = 10.0):
        self.axes = _axes(axes)
        n = self.axes.size
        self.position_weight = _gain("position_weight", position_weight, n)
        self.velocity_weight = _gain("velocity_weight", velocity_weight, n)
        self.position_weight.setflags(write=False)  # replace the arrays to change them
        self.velocity_weight.setflags(write=False)
        if not terminal_factor >= 1:
            raise ConfigurationError(f"terminal_factor must be >= 1, got {terminal_factor}")
        self.terminal_factor = float(terminal_factor)
        a = self.axes  # consecutive axes are read as a slice (views, no index copies)
        self._columns = (slice(int(a[0]), int(a[-1]) + 1)
                         if a.size and np.all(np.diff(a) == 1) else a)
        self._weight_cache: tuple | None = None  # (key, the weight arrays, `compute_weight`)
        self._error: np.ndarray | None = None  # `_linear_term`'s e, (2, N, axes)
        super().__init__(1.0)

    def _rows(self, ctx) -> np.ndarray:
        """Rows of the task's axes in the node-major stacked prediction."""
        return (np.arange(ctx.layout.n_steps)[:, None] * ctx.layout.n_axes
                + self.axes[None, :]).ravel()

    def compute_weight(self, ctx) -> np.ndarray:
        """Per-row weights: positions then velocities, node-major, terminal node scaled.

        Read-only, built again only when N or a weight changes (asked every tick).
        """
        N = ctx.layout.n_steps
        pw, vw = self.position_weight, self.velocity_weight
        kept = self._weight_cache
        # the arrays of the last tick, read-only: the same weights (no bytes compared)
        if (kept is not None and kept[1] is pw and kept[2] is vw and kept[0][0] == N
                and kept[0][1] == self.terminal_factor and not pw.flags.writeable
                and not vw.flags.writeable):
            return kept[3]
        key = (N, self.terminal_factor, pw.tobytes(), vw.tobytes())
        if kept is None or kept[0] != key:
            c = np.ones(N)
            c[-1] = self.terminal_factor
            w = np.concatenate([(c[:, None] * pw).ravel(), (c[:, None] * vw).ravel()])
            w.setflags(write=False)
            kept = (key, pw, vw, w)
        self._weight_cache = (key, pw, vw, kept[3])
        return kept[3]

    def prepare(self, ctx) -> np.ndarray:
        """`ConstantJacobianTask.prepare` and `_linear_term`'s array of e."""
        N = ctx.layout.n_steps
        if self._error is None or self._error.shape[1] != N:
            self._error = np.empty((2, N, self.axes.size))
        return super().prepare(ctx)

    def compute_error(self, ctx) -> np.ndarray:
        """Zero-input prediction minus reference, positions then velocities."""
        i = self._columns
        ref = ctx.reference
        # Whole (N, 9) differences, then the columns: a ufunc on contiguous arrays costs
        # less than on the column views (the same numbers).
        e = np.empty((2, ctx.free_positions.shape[0], self.axes.size))
        e[0] = (ctx.free_positions - ref.position[1:])[:, i]
        e[1] = (ctx.free_velocities - ref.velocity[1:])[:, i]
        return e.reshape(-1)

    def _linear_term(self, ctx) -> np.ndarray:
        """``J^T W e`` with `compute_error`'s numbers, from the context's kept differences.

        The same whole (N, 9) differences (`_differences`: made once per context, the
        tasks of other axes read them too), then the task's columns into an array made
        once per N: the same product of the same operands (a contiguous e).
        """
        d = _differences(ctx)
        e = self._error
        if e is None or e.shape[1] != d.shape[1]:
            e = self._error = np.empty((2, d.shape[1], self.axes.size))
        e[...] = d[:, :, self._columns]
        return self._jw @ e.reshape(-1)

    def _make_term(self, ctx) -> LinearTerm | None:
        """`TRACKING` on the task's axes: `_linear_term` in C (`wbc.tasks.linear_c`).

        This class's own arithmetic: None for a subclass (it says its own).
        """
        if type(self) is not HorizonTrackingTask:
            return None
        return LinearTerm(TRACKING, self._H, tuple(int(a) for a in self.axes), (self._jw,),
                          ("ctx.layout", "task.position_weight", "task.velocity_weight",
                           "task.terminal_factor"))

    def compute_jacobian(self, ctx) -> np.ndarray:
        """Rows of Pq and Pv of the task's axes."""
        rows = self._rows(ctx)
        return np.vstack([ctx.prediction.Pq[rows], ctx.prediction.Pv[rows]])


class _LastDifferences:
    """The zero-input prediction minus the reference, kept for the last context.

    ``(2, N, 9)``: positions, then velocities, at the nodes 1..N. Every tracking task of a
    tick reads the same context: the second one takes the first one's differences. A new
    array per context (never written after), published with the context in one tuple:
    a thread that asks about another context makes its own.
    """

    def __init__(self):
        self._kept: tuple = (None, None)  # (the context, its differences)

    def __call__(self, ctx) -> np.ndarray:
        """The differences of ``ctx`` (read-only)."""
        kept = self._kept
        if kept[0] is ctx:
            return kept[1]
        fp, ref = ctx.free_positions, ctx.reference
        d = np.empty((2, *fp.shape))
        np.subtract(fp, ref.position[1:], out=d[0])
        np.subtract(ctx.free_velocities, ref.velocity[1:], out=d[1])
        d.setflags(write=False)
        self._kept = (ctx, d)
        return d


_differences = _LastDifferences()
