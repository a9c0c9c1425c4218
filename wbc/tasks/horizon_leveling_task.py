"""MPC: twist the chassis with the suspension towards the largest smallest-wheel margin."""

from __future__ import annotations

import numpy as np

from wbc.errors import ConfigurationError
from wbc.force_models.feedback import DIAGONAL
from wbc.tasks.linear_c import LEVELING, LinearTerm
from wbc.tasks.task import ConstantJacobianTask

__all__ = ["HorizonLevelingTask"]


class HorizonLevelingTask(ConstantJacobianTask):
    r"""Warp of the chassis towards the load split with the largest smallest margin.

    .. math:: \sum_{k=1}^{N} \Big(\frac{w_k - \delta^*}{F_s}\Big)^2, \qquad
              w_k = \tfrac14\, n^T W (q_k - q_0),

    with ``W = ctx.warp`` (`wbc.force_models.feedback.warp_matrix`), ``n`` the diagonal
    direction, ``q_k`` the predicted axes (suspension servo setpoints) and ``delta* =
    ctx.leveling_offset`` the warp change that equalizes the smallest margins of the two
    diagonals, from the load split measured now (`leveling_offset`). This is feedback on the
    measured split through the suspension, active whatever the force constraint does; the
    constraint keeps its own, predictive, use of the same lever.

    Args:
        weight: Weight of each node's residual.
        force_scale: F_s [N].
    """

    def __init__(self, weight: float = 1.0, force_scale: float = 1e4):
        if not force_scale > 0:
            raise ConfigurationError(f"force_scale must be > 0, got {force_scale}")
        super().__init__(weight)
        self.force_scale = float(force_scale)
        self._kept_row: tuple | None = None  # `_kept`

    def is_active(self, ctx) -> bool:
        """Active when the context has a warp model."""
        return ctx.warp is not None and float(self.weight) > 0

    def prepare(self, ctx) -> np.ndarray | None:
        """`ConstantJacobianTask.prepare` for ``ctx.warp``; None (nothing) without one."""
        return None if ctx.warp is None else super().prepare(ctx)

    def structure_key(self, ctx):
        """The prediction's structure and the warp matrix (the Jacobian is ``row @ Pq``)."""
        return (ctx.structure_key, self._kept(ctx.warp)[0], self.force_scale)

    def _kept(self, warp: np.ndarray) -> tuple:
        """``(warp bytes, F_s, row, warp)``, row ``n^T W / (4 F_s)`` (9,), kept.

        Kept while the warp matrix and F_s stay the same; a read-only warp array seen
        before is the same matrix (the MPC's is: no bytes made each tick).
        """
        kept = self._kept_row
        if (kept is not None and kept[3] is warp and not warp.flags.writeable
                and kept[1] == self.force_scale):
            return kept
        data = warp.tobytes()
        if kept is None or kept[0] != data or kept[1] != self.force_scale:
            row = DIAGONAL @ warp / (4.0 * self.force_scale)
            row.setflags(write=False)
            kept = (data, self.force_scale, row)
        self._kept_row = kept = (*kept[:3], warp)
        return kept

    def _row(self, ctx) -> np.ndarray:
        """``n^T W / (4 F_s)``, (9,), kept while the warp matrix and F_s stay the same."""
        return self._kept(ctx.warp)[2]

    def compute_error(self, ctx) -> np.ndarray:
        """Zero-input warp change (with the terrain's drift) minus the wanted one, (N,)."""
        w = (ctx.free_positions - ctx.q[None, :]) @ self._row(ctx)
        if ctx.warp_drift is not None:
            w += ctx.warp_drift[1:] / self.force_scale
        w -= ctx.leveling_offset / self.force_scale
        return w

    def _make_term(self, ctx) -> LinearTerm | None:
        """`LEVELING`: `compute_error` and ``J^T W e`` in C (`wbc.tasks.linear_c`).

        This class's own arithmetic: None for a subclass (it says its own).
        """
        if type(self) is not HorizonLevelingTask:
            return None
        return LinearTerm(LEVELING, self._H, (),
                          (self._row(ctx), self._jw, np.array([self.force_scale])),
                          ("ctx.layout", "ctx.warp", "task.weight", "task.force_scale"))

    def compute_jacobian(self, ctx) -> np.ndarray:
        """``row @ Pq`` of each node, (N, n)."""
        lay = ctx.layout
        Pq = ctx.prediction.Pq.reshape(lay.n_steps, lay.n_axes, lay.n)
        return np.einsum("a,kan->kn", self._row(ctx), Pq)
