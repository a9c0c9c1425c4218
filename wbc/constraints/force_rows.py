"""What the whole-body and the MPC normal-force constraints share: thresholds, rows, slacks."""

from __future__ import annotations

import abc

import numpy as np

from wbc.constraints.constraint import Constraint, Inequality
from wbc.errors import ConfigurationError
from wbc.force_models.feedback import DIAGONAL
from wbc.force_models.protocol import NormalForceModel, contact_flags

__all__ = ["ForceRowsConstraint", "check_margins", "check_thresholds",
           "lifted_wheel_thresholds"]

# `np.all`, `np.any` of 1-D arrays without their Python dispatch (margins: every tick)
_all, _any = np.logical_and.reduce, np.logical_or.reduce


def check_thresholds(thresholds) -> np.ndarray:
    """Per-wheel thresholds [N] as a finite array of shape (4,), order FL, RL, FR, RR."""
    t = np.broadcast_to(np.asarray(thresholds, dtype=float), (4,)).copy()
    if not np.all(np.isfinite(t)):
        raise ConfigurationError(f"force thresholds must be finite, got {thresholds}")
    return t


def check_margins(value, n: int, what: str) -> np.ndarray:
    """``n`` finite forces >= 0 [N] as an array of shape (n,) (margins, reserves).

    Raises:
        ConfigurationError: Anything else; the message names ``what``.
    """
    m = np.asarray(value, float)
    if m.shape != (n,) or not _all(np.isfinite(m)) or _any(m < 0):
        raise ConfigurationError(f"{what} must be {n} finite forces >= 0 [N], got {value!r}")
    return m


def lifted_wheel_thresholds(thresholds: np.ndarray, in_contact) -> np.ndarray:
    r"""The thresholds with each lifted wheel's added to its two neighbours', shape (4,).

    On three wheels the forces are those of the four-contact statics with the lifted wheel's
    force zero; the free (warp) direction `DIAGONAL` moves load between the diagonals, one
    unit from each of the lifted wheel's neighbours (the other diagonal) to the lifted wheel
    and its partner. The suspension can set the wheel down with ``f_min,i`` on it only if
    each neighbour carries ``f_min,i`` more than its own threshold: a wheel in the air asks
    its neighbours, not its partner, for the load it needs.
    """
    t = np.array(thresholds, dtype=float)
    for i in np.flatnonzero(~np.asarray(in_contact, dtype=bool)):
        t[DIAGONAL != DIAGONAL[i]] += thresholds[i]
    return t


class ForceRowsConstraint(Constraint):
    r"""``f_z,i(t_k) >= f_min,i`` at some nodes k, for every wheel i in contact now.

    A lifted wheel's threshold is added to its two neighbours' (`lifted_wheel_thresholds`):
    they must carry the load the wheel needs when the suspension sets it down.

    A subclass predicts the forces of all four wheels at its nodes, ``A x + b`` node-major
    (`forces_map`), and says which nodes get rows (`_constrained_nodes`). The rows are
    scaled by ``1 / force_scale``: ``-(A x + b) / f_s - eps <= -f_min / f_s``, with
    ``eps`` the wheel's slack when the layout has slacks (else no ``eps``): one per wheel,
    or with eight slacks or more one per wheel for the node now and another for the later
    nodes (the side reserve's two come after them, `SideReserveConstraint`).

    Args:
        model: The normal-force model.
        thresholds: f_min [N], scalar or shape (4,), order FL, RL, FR, RR.
        force_scale: Row scaling [N].
        drive_time_constant: tau of the base drive [s] (`wbc.drive_model`).

    Attributes:
        last_forces_map: ``(A, b)`` of the last call, the predicted forces ``A x + b`` [N]
            of all four wheels; for logging and tests.
        last_in_contact: Contact flags of the last call, shape (4,).
    """

    def __init__(self, model: NormalForceModel, thresholds, force_scale: float,
                 drive_time_constant: float):
        self.model = model
        self.thresholds = check_thresholds(thresholds)
        self.force_scale = float(force_scale)
        self.drive_time_constant = float(drive_time_constant)
        self.last_forces_map: tuple[np.ndarray, np.ndarray] | None = None
        self.last_in_contact: np.ndarray | None = None
        self._rows_cache: tuple | None = None  # (key, `_rows`, nodes, later, layout)

    @abc.abstractmethod
    def forces_map(self, ctx, in_contact=None) -> tuple[np.ndarray, np.ndarray]:
        """``(A, b)``: predicted forces ``A x + b`` [N], four rows per node.

        ``in_contact``: the contact flags now, (4,), if the caller has them (else the
        subclass asks `contact_flags` when it needs them).
        """

    def _constrained_nodes(self, ctx, n_nodes: int) -> tuple[np.ndarray, np.ndarray]:
        """``(nodes, later)``: the nodes that get rows and whether each lies after now."""
        return np.zeros(1, dtype=int), np.zeros(1, dtype=bool)

    def _forces_and_flags(self, ctx) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(A, b, contact flags now)``: `forces_map` with the flags of `contact_flags`.

        A subclass that linearizes the model at ``ctx.state`` anyway reads the flags from
        that linearization instead (`linearized_contact_flags`: one model evaluation less).
        """
        flags = contact_flags(self.model, ctx.state)
        A, b = self.forces_map(ctx, flags)
        return A, b, flags

    def compute(self, ctx) -> Inequality | None:
        """Rows ``-(A x + b) / f_s - eps <= -f_min / f_s`` of the wheels in contact now."""
        A, b, flags = self._forces_and_flags(ctx)
        return self._inequality(ctx, A, b, flags)

    def _inequality(self, ctx, A: np.ndarray, b: np.ndarray, flags: np.ndarray
                    ) -> Inequality | None:
        """`compute`'s rows of the forces ``A x + b`` and the contact flags (kept as last)."""
        self.last_forces_map, self.last_in_contact = (A, b), flags
        rows, thresholds, slack = self._rows(ctx, flags, A.shape[0] // 4)
        if rows is None:
            return None
        G = np.divide(A[rows], -self.force_scale)  # = -A[rows] / f_s, the same bits
        h = (b[rows] - thresholds) / self.force_scale
        if slack is not None:
            G[slack] = -1.0
        return Inequality(G, h)

    def _rows(self, ctx, flags: np.ndarray, n_nodes: int) -> tuple:
        """``(rows of A, their thresholds [N], slack entries of G)`` for these contact flags.

        None rows without a wheel in contact. The rows and slack entries are kept while the
        flags, the constrained nodes and the slacks stay the same (they change when a wheel
        lifts); the thresholds, which the MPC's margin moves every tick, are made each call.
        The rows are an index array, or a slice where they follow each other (all four
        wheels in contact).
        """
        rows, wheels, slack = self._row_plan(ctx, flags, n_nodes)
        if rows is None:
            return None, None, None
        # `np.tile(thresholds[wheels], nodes.size)`, written into its array at once
        per_node = (self.thresholds if wheels.size == 4
                    else lifted_wheel_thresholds(self.thresholds, flags)[wheels])
        thresholds = np.empty((self._rows_cache[2].size, wheels.size))
        thresholds[:] = per_node
        return rows, thresholds.reshape(-1), slack

    def _row_plan(self, ctx, flags: np.ndarray, n_nodes: int) -> tuple:
        """``(rows of A, wheels in contact, slack entries of G)`` of `_rows`, kept.

        The same tuple object while the flags, the constrained nodes and the slacks stay the
        same; rows None without a wheel in contact.
        """
        nodes, later = self._constrained_nodes(ctx, n_nodes)
        lay = ctx.layout
        flag_bytes, cache = flags.tobytes(), self._rows_cache
        if (cache is not None and cache[2] is nodes and cache[3] is later
                and cache[4] is lay and cache[0][0] == flag_bytes):
            key = cache[0]  # the same (kept, frozen) nodes and layout: no key to build
        else:
            key = (flag_bytes, nodes.tobytes(), later.tobytes(),
                   None if lay.slack is None else lay.slack.start, lay.n_slack)
        if cache is None or cache[0] != key:
            wheels = np.flatnonzero(flags)
            if wheels.size == 0:
                cache = (key, (None, wheels, None))
            else:
                rows = (4 * nodes[:, None] + wheels[None, :]).ravel()
                slack = None
                if rows.size and np.array_equal(rows, np.arange(rows[0], rows[0] + rows.size)):
                    rows = slice(int(rows[0]), int(rows[0]) + rows.size)  # no index copy
                if lay.slack is not None:
                    col = lay.slack.start + np.tile(wheels, nodes.size)
                    if lay.n_slack >= 8:  # the later nodes' own slacks
                        col = col + 4 * np.repeat(later, wheels.size)
                    slack = (np.arange(col.size), col)
                cache = (key, (rows, wheels, slack))
        self._rows_cache = (*cache[:2], nodes, later, lay)
        return cache[1]
