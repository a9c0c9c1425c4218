"""MPC: room in each side pair's load for the swing measured while driving (late nodes)."""

from __future__ import annotations

import numpy as np

from wbc.constraints.constraint import Constraint, Inequality
from wbc.constraints.force_rows import check_margins
from wbc.constraints.horizon_normal_force import HorizonNormalForceConstraint
from wbc.constraints.side_reserve_c import (
    SIDE_PAIRS,
    compiled_side_reserve,
    side_reserve_library,
)
from wbc.errors import ConfigurationError

__all__ = ["SIDE_PAIRS", "SideReserveConstraint"]

(_FL, _RL), (_FR, _RR) = SIDE_PAIRS.tolist()  # the pairs' wheels, as indices


class SideReserveConstraint(Constraint):
    r"""Each side pair's load sum closes its shortfall to ``f_min,a + f_min,b + r_j``.

    A side pair's load sum is what the warp does not move (it moves load *within* each
    pair, `wbc.force_models.feedback.DIAGONAL`): only the crane's pose and the ground's roll
    move it, so a reserve ``r_j`` on it (a floor while driving, or ``z sigma_j`` from the
    swing measured on that side, `wbc.force_models.fluctuation.SideLoadFluctuation`) cannot
    be bought with the suspension. With ``S_k`` a side pair's predicted sum at node k,
    ``n = f_min,a + f_min,b + r_j`` and ``S_k^0`` the sum the nominal plan (the previous
    plan shifted, at the last speed scale) predicts there, the rows at the nodes after now
    (k >= 1 and the terminal node) are

    .. math:: S_k \ge n - \max(n - S_k^0, 0)\, e^{-t_k / T},

    a contraction: the plan must close the shortfall the previous plan left at node k by the
    fraction ``1 - exp(-t_k / T)`` (1 % one period ahead with T = 1 s, 63 % a second ahead),
    so the crane takes the load inward or uphill over about ``T`` instead of at once with
    accelerations (the per-wheel margin for the same swing, in every row, rang the chassis
    at 2-3 Hz, `wbc/DESIGN.md`, pitfalls). Rows only at the late nodes would not do: the
    plan keeps promising the move for later and never makes it (development draw 17,
    master seed 1: the terminal sum met, the measured one 3 kN short).

    The forces are those `HorizonNormalForceConstraint` predicted at this tick
    (``last_forces_map``: this constraint must come after it in the list), its thresholds
    (with the uncertainty margin) included. Rows only with all four wheels on the ground
    and for sides with ``r_j > 0``; each side has its own slack (layout slacks 8 and 9), so
    a reserve out of reach never relaxes the per-wheel rows:
    ``-(A_a + A_b) x / f_s - eps_j <= (b_a + b_b - n + max(n - S_k^0, 0) e_k) / f_s``.

    Args:
        force_constraint: The per-wheel rows whose predicted forces and thresholds it uses.
        time_constant: T [s].
        compiled: Make the rows in C, the pairs' sums, the product with the nominal plan
            and the right-hand sides in one call (`wbc.constraints.side_reserve_c`, the
            same bits); False, or without a C compiler: numpy.

    Attributes:
        reserve: ``r`` [N], shape (2,), order left, right; zeros: inactive.
    """

    def __init__(self, force_constraint: HorizonNormalForceConstraint,
                 time_constant: float = 1.0, compiled: bool = True):
        if not time_constant > 0:
            raise ConfigurationError(f"time_constant must be > 0 s, got {time_constant}")
        self.force_constraint = force_constraint
        self.time_constant = float(time_constant)
        self.compiled = bool(compiled)
        if self.compiled:
            side_reserve_library()  # compiled (or loaded) now, not in a control loop
        self.reserve = np.zeros(2)
        self._cache: tuple | None = None  # (key, `_structure`): see `compute`

    def set_reserve(self, reserve) -> None:
        """Set ``r`` [N] (2,), order left, right.

        Raises:
            ConfigurationError: Not two finite numbers >= 0.
        """
        self.reserve = check_margins(reserve, 2, "side reserve")

    def prepare(self, ctx) -> int | None:
        """No rows while no reserve is set, as at a first tick standing (`Constraint.prepare`).

        None (not known) with a reserve: its rows then depend on the state's contact flags.
        """
        left, right = self.reserve.tolist()
        return None if left > 0 or right > 0 else 0

    @staticmethod
    def nodes(ctx, n_nodes: int) -> tuple[np.ndarray, np.ndarray]:
        """``(nodes, times [s])``: every node after now (k >= 1), the terminal one last."""
        times = np.append(ctx.prediction.start_times, ctx.prediction.horizon)[:n_nodes]
        nodes = np.flatnonzero(times > ctx.dt / 2)
        return nodes, times[nodes]

    @staticmethod
    def nominal(ctx) -> np.ndarray:
        """The decision vector of the nominal plan: its inputs, the last scale, no slack."""
        lay = ctx.layout
        x = np.zeros(lay.n)
        x[lay.accelerations] = np.asarray(ctx.nominal_inputs, float).reshape(-1)
        if lay.scale is not None:
            x[lay.scale] = ctx.speed_scale
        return x

    def compute(self, ctx) -> Inequality | None:
        """The rows of the sides with a reserve, after now; None: inactive."""
        fc = self.force_constraint
        left, right = self.reserve.tolist()
        flags, forces = fc.last_in_contact, fc.last_forces_map
        if (not (left > 0 or right > 0) or forces is None or flags is None
                or not all(flags.tolist())):
            return None
        A, b = forces
        key = (ctx.structure_key, A.shape, left > 0, right > 0, self.time_constant,
               self.compiled)
        kept = self._cache
        if kept is None or kept[0] != key:
            kept = self._cache = (key, self._structure(ctx, A.shape, key[2:4]))
        sides, nodes, first, second, decay, slack, rows = kept[1]
        if rows is not None:
            f = fc.thresholds.tolist()
            made = rows.rows(A, b, ctx.nominal_inputs,
                             f[_FL] + f[_RL] + left, f[_FR] + f[_RR] + right, fc.force_scale,
                             0.0 if ctx.layout.scale is None else ctx.speed_scale)
            if made is not None:
                return Inequality(*made)
        # (node, side) rows of each pair's two wheels, node-major: by basic indexing
        n_nodes = A.shape[0] // 4
        A_3, b_2 = A.reshape(n_nodes, 4, -1), b.reshape(n_nodes, 4)
        A_sum = (A_3[nodes, first] + A_3[nodes, second]).reshape(-1, A.shape[1])
        b_sum = (b_2[nodes, first] + b_2[nodes, second]).reshape(-1)
        need = np.empty((b_sum.size // sides.size, sides.size))  # every node's the same
        need[:] = fc.thresholds[first] + fc.thresholds[second] + self.reserve[sides]
        need = need.reshape(-1)
        short = np.maximum(need - (A_sum @ self.nominal(ctx) + b_sum), 0.0)
        wanted = need - short * decay
        G = np.divide(A_sum, -fc.force_scale, out=A_sum)
        G[slack] = -1.0
        return Inequality(G, (b_sum - wanted) / fc.force_scale)

    def _structure(self, ctx, forces_shape: tuple, on: tuple) -> tuple:
        """What the layout, the nodes and the sides fix (`compute` keeps it while they stay).

        ``sides``: the sides with a reserve (``on``: per side, whether it has one);
        ``nodes``: the nodes after now (`nodes`), a slice where they follow each other
        (they do: the last ones);
        ``(first, second)``: the pairs' first and second wheels (slices, `SIDE_PAIRS`);
        ``decay``, ``exp(-t_k / T)`` per row; the slack entries of G; the compiled rows
        (`wbc.constraints.side_reserve_c.CompiledSideReserve` for the forces map of shape
        ``forces_shape``) or None.

        Raises:
            ConfigurationError: The layout has fewer than 10 slacks.
        """
        lay = ctx.layout
        if lay.slack is None or lay.n_slack < 10:
            raise ConfigurationError("SideReserveConstraint needs a layout with 10 slacks")
        sides = np.flatnonzero(on)
        nodes, times = self.nodes(ctx, forces_shape[0] // 4)
        pairs = SIDE_PAIRS[sides]  # (m, 2): a side's wheels, the sides' 2 apart
        first, second = (slice(int(pairs[0, w]), int(pairs[-1, w]) + 1, 2) for w in (0, 1))
        at = (slice(int(nodes[0]), int(nodes[-1]) + 1)
              if nodes.size and nodes[-1] - nodes[0] == nodes.size - 1 else nodes)
        decay = np.repeat(np.exp(-times / self.time_constant), sides.size)
        slack = (np.arange(nodes.size * sides.size),
                 lay.slack.start + 8 + np.tile(sides, nodes.size))
        rows = (compiled_side_reserve(nodes, sides, slack[1], decay, forces_shape[1],
                                      forces_shape[0], lay.accelerations, lay.scale)
                if self.compiled else None)
        return sides, at, first, second, decay, slack, rows
