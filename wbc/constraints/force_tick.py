"""The MPC's normal-force rows at a tick in one C call, from the nodes' kernel rows.

`HorizonNormalForceConstraint.compute` predicts the forces ``A x + b`` and makes the rows
``G x <= h`` of the wheels in contact (`ForceRowsConstraint.compute`). Once prepared, a tick
writes the nominal states into the C force map's buffers, has the model linearize node 0
and the later nodes into kernel rows (`estimators.payload.PayloadEstimator.linearize_nodes`),
and makes ``A``, ``b``, ``G`` and ``h`` in one ``force_rows`` call
(`wbc.constraints.force_map_c.CompiledForceMap.evaluate_tick`): no numpy operation per
term, no row copies, the same bits as the reference path (`tests/test_force_tick_c.py`).
What it keeps (buffers' views, the later nodes' rows, the row plan) is kept with the
horizon's structure, layout and contact flags.
"""

from __future__ import annotations

import numpy as np

from wbc.axes import N_AXES
from wbc.constraints.constraint import Inequality
from wbc.constraints.force_map_c import NW
from wbc.constraints.force_rows import lifted_wheel_thresholds
from wbc.drive_model import speed_scale_factor
from wbc.force_models.protocol import linearize_nodes, linearized_contact_flags

__all__ = ["ELSEWHERE", "ForceTick", "row_plan"]

ELSEWHERE = object()  # `ForceTick.compute`: not here, nothing evaluated
_all = np.logical_and.reduce  # `np.all` of a 1-D array without its Python dispatch
_ALL_IN = np.ones(4, dtype=bool)  # the contact flags of `ForceTick.prepare`


class ForceTick:
    """One `HorizonNormalForceConstraint`'s tick in one C call (not shared).

    Args:
        min_scale: The drift's lowest speed scale (``s_prev = max(s, min_scale)``).

    Attributes:
        rows: ``(RowViews, row_offsets, rows' shape)`` of the model's kernel rows, set by
            the constraint's ``prepare``; None: not prepared, every tick `ELSEWHERE`.
    """

    def __init__(self, min_scale: float):
        self.min_scale = float(min_scale)
        self.rows: tuple | None = None
        # (struct, layout, `rows`, the C's arrays, the nominal buffers and views, the later
        # nodes' rows), and (struct, layout, flags, `row_plan`)
        self._kept: tuple | None = None
        self._plan: tuple | None = None

    def compute(self, con, ctx):
        """``con.compute(ctx)`` in one C call, or `ELSEWHERE` (nothing evaluated).

        `ELSEWHERE`: not prepared for this structure, no C force map. Where the model's
        call gives no kernel rows to use (a tipping state, a node out of range) the tick
        goes on as `HorizonNormalForceConstraint._forces_and_flags` does.
        """
        prepared, kernel, lay = self.rows, con._kernel(), ctx.layout
        if prepared is None or kernel is None or lay.n_axes != N_AXES:
            return ELSEWHERE
        struct = con._structure(ctx)
        kept = self._buffers(kernel, struct, lay)
        if kept is None:
            return ELSEWHERE
        st = ctx.state
        qn, vn = con._nominal(ctx, kept[4])
        at = kept[5]
        first, rows = linearize_nodes(con.model, st, struct.later_times, qn[at], vn[at])
        flags = linearized_contact_flags(st, first)
        fields = first.__dict__
        if rows is not None and fields.get("_views") is prepared[0]:
            all_in = _all(flags)
            warp = ctx.warp if all_in else None
            n_eval = struct.n_eval
            plan = self._row_plan(con, ctx, flags, struct)
            done = kernel.evaluate_tick(
                n_eval, lay.n, prepared[1], ctx, fields["_row"], rows, plan[1],
                con.thresholds if all_in else lifted_wheel_thresholds(con.thresholds, flags),
                zero_suspension=ctx.warp is not None, warp=warp,
                direction=(None if lay.scale is None else
                           speed_scale_factor(ctx.speed_scale, con.drive_time_constant)),
                bias=None if ctx.feedback is None else ctx.feedback.bias,
                drift=ctx.warp_drift if warp is not None else None,
                s_prev=max(ctx.speed_scale, self.min_scale),
                brake_time=con.terminal_brake_time, force_scale=con.force_scale)
            if done is not None:
                A, b, G, h = done
                con.linearization_steps = struct.steps
                con.last_forces_map, con.last_in_contact = (A, b), flags
                return None if plan[0] is None else Inequality(G, h)
        return con._inequality(ctx, *con._map_of(ctx, first, rows, flags, qn, vn), flags)

    def prepare(self, con, ctx, struct) -> None:
        """What `compute` keeps of a structure, now: not at the first tick.

        The nominal buffers' views and the later nodes' rows (`_buffers`) and the row plan
        of all four wheels in contact (`_row_plan`; another contact pattern makes its own at
        its first tick). ``ctx``: a `wbc.structure.StructureContext` (the ticks' layout);
        ``struct``: ``con``'s structure of it; after ``con`` set `rows`.
        """
        kernel = con._kernel()
        if self.rows is None or kernel is None:
            return
        self._buffers(kernel, struct, ctx.layout)
        self._row_plan(con, ctx, _ALL_IN, struct)

    def _buffers(self, kernel, struct, lay) -> tuple | None:
        """The kept ``(struct, layout, rows, C arrays, nominal views, later rows)``.

        Made again when the structure, layout, prepared `rows` or the force map's arrays
        are not those it was made for; None where the force map has no buffers for them.
        """
        prepared, kept = self.rows, self._kept
        if (kept is None or kept[0] is not struct or kept[1] is not lay
                or kept[2] is not prepared or kept[3] is not kernel.arrays):
            buffers = kernel.nominal(struct, lay.n_steps, lay.n, lay.scale, prepared[2])
            if buffers is None:
                return None
            qn, vn = buffers
            kept = self._kept = (struct, lay, prepared, kernel.arrays,
                                 (qn, vn, qn[1:], vn[1:]), _rows_at(struct.later_steps))
        return kept

    def _row_plan(self, con, ctx, flags: np.ndarray, struct) -> tuple:
        """``(rows of A or None, `row_plan`)`` of ``con._row_plan``, kept.

        Kept with the structure, the layout and the flags it was made for (what the row
        plan depends on at the structure's ``n_eval`` nodes).
        """
        flag_bytes, kept = flags.tobytes(), self._plan
        lay = ctx.layout
        if kept is None or kept[0] is not struct or kept[1] is not lay or kept[2] != flag_bytes:
            rows, _, slack = con._row_plan(ctx, flags, struct.n_eval)
            kept = self._plan = (struct, lay, flag_bytes,
                                 (rows, row_plan(rows, slack, struct.n_eval, lay.n)))
        return kept[3]


def row_plan(rows, slack, n_eval: int, n: int) -> tuple[np.ndarray, int]:
    """``force_rows``' plan of `ForceRowsConstraint._row_plan`'s rows and slack entries.

    ``(plan, its address)``: m, the capacity 4 n_eval, then each row's row of A, its wheel
    and its slack column (-1: none), the capacity each. ``rows`` None: no rows (m = 0).

    Raises:
        ValueError: A row outside A's 4 n_eval rows, a slack column outside n.
    """
    cap = NW * n_eval
    plan = np.full(2 + 3 * cap, -1, np.int64)
    if rows is None:
        src = np.zeros(0, np.int64)
    elif isinstance(rows, slice):
        src = np.arange(rows.start, rows.stop, rows.step, dtype=np.int64)
    else:
        src = np.asarray(rows, np.int64).reshape(-1)
    m = src.size
    if not (m <= cap and np.all((src >= 0) & (src < cap))):
        raise ValueError(f"rows {rows} outside the {cap} rows of A")
    plan[0], plan[1] = m, cap
    plan[2:2 + m] = src
    plan[2 + cap:2 + cap + m] = src % NW
    if slack is not None:
        plan[2 + 2 * cap + slack[0]] = slack[1]
    if not np.all(plan[2 + 2 * cap:] < n):
        raise ValueError(f"slack entries {slack} outside the {n} columns of G")
    return plan, plan.ctypes.data


def _rows_at(rows: np.ndarray) -> slice | np.ndarray:
    """``rows`` (increasing) as a slice where they are evenly spaced (a view, not a copy)."""
    step = rows[1] - rows[0] if rows.size > 1 else 1
    if rows.size and step > 0 and np.array_equal(np.diff(rows), np.full(rows.size - 1, step)):
        return slice(int(rows[0]), int(rows[-1]) + 1, int(step))
    return rows
