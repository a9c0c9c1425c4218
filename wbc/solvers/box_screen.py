"""The box's screening sums of `wbc.solvers.DaqpBackend`: which rows the box makes redundant.

A row ``g x <= h`` is redundant when even the worst point of the variable box ``lb <= x <=
ub`` widened by DAQP's primal tolerance keeps it (`wbc.solvers.daqp_backend`'s docstring):
`worst` sums ``max g x`` over that box, `redundant_rows` compares. `BlockSums` keeps the sums
of a QP's constant blocks (``constant_rows``) from solve to solve: a block's sums depend
only on the bounds of the columns where it has entries.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

__all__ = ["BIG", "BlockSums", "BoxTerms", "box_terms", "redundant_rows", "worst"]

BIG = 1e20  # stands in for an infinite bound in the screening sums


class BoxTerms(NamedTuple):
    """What `worst` needs of the box ``lb <= x <= ub`` widened by a tolerance.

    ``mid`` and ``spread`` (half the width plus the tolerance) of the finite intervals, 0
    where a bound is infinite; ``open`` the variables with an infinite bound, ``hi_open`` and
    ``lo_open`` their bounds clipped to +-`BIG`.
    """

    mid: np.ndarray
    spread: np.ndarray
    open: np.ndarray
    hi_open: np.ndarray
    lo_open: np.ndarray


def box_terms(lb: np.ndarray | None, ub: np.ndarray | None, n: int,
              tolerance: float) -> BoxTerms:
    """The `BoxTerms` of ``lb <= x <= ub`` (None: infinite) widened by ``tolerance``."""
    lo = np.full(n, -np.inf) if lb is None else np.asarray(lb, float)
    hi = np.full(n, np.inf) if ub is None else np.asarray(ub, float)
    box = np.isfinite(lo) & np.isfinite(hi)
    # Over a finite interval the worst of g_i x_i is g_i mid_i + |g_i| half_i (one pass over G).
    lo_box, hi_box = np.where(box, lo, 0.0), np.where(box, hi, 0.0)
    mid, half = 0.5 * (lo_box + hi_box), 0.5 * (hi_box - lo_box)
    open_ = np.flatnonzero(~box)  # the few variables with an infinite bound, exactly
    return BoxTerms(mid, half + tolerance, open_, np.minimum(hi[open_], BIG),
                    np.maximum(lo[open_], -BIG))


def worst(G: np.ndarray, box: BoxTerms) -> np.ndarray:
    """``max g x`` of every row of ``G`` over the widened box, shape (rows,).

    A column of ``G`` that is zero adds exact zeros, whatever the box says of its variable:
    the sums of the rows that are zero there do not depend on those bounds.
    """
    sums = G @ box.mid + np.abs(G) @ box.spread
    if box.open.size:
        g = G[:, box.open]
        sums += np.maximum(g, 0.0) @ box.hi_open + np.minimum(g, 0.0) @ box.lo_open
    return sums


def redundant_rows(G: np.ndarray, h: np.ndarray, lb: np.ndarray | None,
                   ub: np.ndarray | None, tolerance: float) -> np.ndarray:
    """Rows of ``G x <= h`` that every ``x`` in the box (widened by ``tolerance``) satisfies.

    Returns:
        Boolean mask, shape (rows,). An infinite or missing bound keeps every row that
        depends on its variable.
    """
    return worst(G, box_terms(lb, ub, G.shape[1], tolerance)) <= h


def _same_place(a: tuple, b: tuple) -> bool:
    """Two ``(first row, block)`` pairs: the same block object at the same row."""
    return a[1] is b[1] and a[0] == b[0]


class BlockSums:
    """The screening sums of a QP's constant blocks, kept from solve to solve.

    Args:
        tolerance: The box's widening (DAQP's primal tolerance).

    Not shared between threads (each `DaqpBackend` makes its own).
    """

    def __init__(self, tolerance: float):
        self.tolerance = tolerance
        self._box: tuple | None = None  # (the bounds' bytes, their `BoxTerms`)
        self._screens: dict = {}  # id(block) -> (block, columns, their bounds, sums)
        self._sums: tuple | None = None  # (rows, blocks, `_block_sums`'s sums)

    def sums(self, m_in: int, n: int, blocks: tuple, lb, ub) -> tuple[BoxTerms, np.ndarray]:
        """The box's `BoxTerms` and `worst` of the rows of the constant ``blocks``.

        ``blocks``: ``(first row, read-only block)`` pairs of a ``G`` (m_in, n). The
        sums, shape (m_in,), are undefined outside the blocks (the caller's to write). The
        same blocks in the same places under the same bounds: the last call's array (the
        tick after tick case); else each block's sums kept while the bounds of its columns
        stay (the MPC's stroke and speed limits depend on the acceleration limits only).
        """
        lo = np.full(n, -np.inf) if lb is None else np.asarray(lb, float)
        hi = np.full(n, np.inf) if ub is None else np.asarray(ub, float)
        bounds = lo.tobytes() + hi.tobytes()
        box_kept = self._box is not None and self._box[0] == bounds
        if not box_kept:
            self._box = (bounds, box_terms(lo, hi, n, self.tolerance))
        box = self._box[1]
        kept = self._sums
        if (box_kept and kept is not None and kept[0] == m_in and len(kept[1]) == len(blocks)
                and all(map(_same_place, kept[1], blocks))):
            return box, kept[2]
        sums = self._block_sums(m_in, blocks, lo, hi, box)
        self._sums = (m_in, blocks, sums)
        return box, sums

    def _block_sums(self, m_in: int, blocks: tuple, lo: np.ndarray, hi: np.ndarray,
                    box: BoxTerms) -> np.ndarray:
        sums = np.empty(m_in)  # the other rows' sums written only by the numpy screening
        screens = {}
        for first, block in blocks:
            entry = self._screens.get(id(block))
            if entry is None or entry[0] is not block:
                nonzero = np.flatnonzero(np.abs(block).sum(axis=0))
                cols = (slice(int(nonzero[0]), int(nonzero[-1]) + 1) if nonzero.size
                        else slice(0, 0))
                entry = (block, cols, None, None)
            cols = entry[1]
            key = lo[cols].tobytes() + hi[cols].tobytes()
            if entry[2] != key:
                entry = (block, cols, key, worst(block, box))
            screens[id(block)] = entry
            sums[first:first + block.shape[0]] = entry[3]
        self._screens = screens  # the blocks of this problem only
        return sums
