"""DAQP's rows of the least-distance form: the kept rows of ``G`` times the inverse factor.

`wbc.solvers.DaqpBackend` hands DAQP ``[L^-T; G[kept] L^-T]`` (its module docstring). The
rows of a block that stays the same tick after tick (``constant_rows`` of a `wbc.qp.QP`:
the MPC's stroke and speed limits, ~60 % of the kept rows) are multiplied by ``L^-T`` once
and then read from that product (each row's product is the same BLAS sum whichever rows it
is computed with). The other kept rows are multiplied in C from the factor's nonzeros
(`wbc.solvers.product_c`: the same bits on every host) when it can; else with numpy:
rows that are zero outside blocks along a diagonal (``diagonal_rows``,
`wbc.constraints.DiagonalBlocks`: the MPC's effort rows, each step's on that step's inputs)
block by block, a ninth of the dense work, the rest in one BLAS product. DAQP's rows are
written into a buffer kept from solve to solve, where the C pass leaves a constant row that
the last pass put in the same place (most of them: the screening keeps much the same rows);
`FactorRows.same_rows` says which rows those are, for the pass after the one the last
solve took.
"""

from __future__ import annotations

import operator
from typing import NamedTuple

import numpy as np

from models.cbuild import address
from wbc.solvers.product_c import CompiledProduct, compiled_product

__all__ = ["FactorRows", "RowStructure", "row_structure"]


class RowStructure(NamedTuple):
    """Where a problem's kinds of rows sit (`DaqpBackend._structure`).

    ``key``: what it was made from (rows, blocks' places, diagonal blocks); ``constant``:
    bool (m,), the rows of the constant blocks; ``gaps``: the ``(first, stop)`` row ranges
    between them; ``done``: the constant rows and those of the `DiagonalBlocks` of two
    rows or more (`_diagonal_product`).
    """

    key: tuple
    constant: np.ndarray
    gaps: tuple
    done: np.ndarray


def row_structure(key: tuple, m_in: int, blocks: tuple, diagonal: tuple) -> RowStructure:
    """The `RowStructure` of ``m_in`` rows with these constant blocks and diagonal rows.

    ``blocks``: ``(first row, block)`` pairs; ``diagonal``: ``(first row, DiagonalBlocks)``
    pairs (`wbc.qp.QP`); ``key``: the caller's key of them.
    """
    constant = np.zeros(m_in, dtype=bool)
    for first, block in blocks:
        constant[first:first + block.shape[0]] = True
    edges = np.flatnonzero(np.diff(np.r_[True, constant, True]))
    gaps = tuple((int(a), int(b)) for a, b in zip(edges[::2], edges[1::2]))
    done = constant.copy()
    for first, d in diagonal:
        if d.rows >= 2:
            done[first:first + d.rows * d.n_blocks] = True
    return RowStructure(key, constant, gaps, done)


def _diagonal_product(G: np.ndarray, first: int, d, inv_t: np.ndarray,
                      out: np.ndarray) -> None:
    """``out[rows] = G[rows] @ inv_t`` for the rows of `DiagonalBlocks` ``d`` from ``first``.

    Each block's ``width`` columns times the factor's matching rows, every block in one
    stacked product: ``width / n`` of the dense product's work, within the dense product's
    rounding bound (`tests/test_daqp_backend.py`; the same bits where the BLAS sums each
    entry over the inner dimension in order, as OpenBLAS's gemm does on most CPUs).
    ``d.rows >= 2`` keeps every block a matrix product.
    """
    n = inv_t.shape[0]
    G = np.ascontiguousarray(G, dtype=float)  # G itself, as the QP builds it
    row = G.strides[0]
    g = np.ndarray((d.n_blocks, d.rows, d.width), float, G, first * row + 8 * d.first,
                   (d.rows * row + 8 * d.width, row, 8))  # the blocks: a view (as_strided)
    u = inv_t[d.first:d.first + d.n_blocks * d.width].reshape(d.n_blocks, d.width, n)
    np.matmul(g, u, out=out[first:first + d.rows * d.n_blocks].reshape(d.n_blocks, d.rows, n))


class FactorRows:
    """The products of one `DaqpBackend`, kept from solve to solve (module docstring).

    Attributes:
        compiled: Multiply in C when it can (`wbc.solvers.product_c`); False: numpy.
        products: ``id(block) -> (block, L^-T, block @ L^-T)`` of the last problem's
            constant blocks.
        ldp_rows: ``(L^-T, buffer of DAQP's rows)``, None before the first product.
        passes: `least_distance_rows` calls so far.
    """

    def __init__(self):
        self.compiled = True
        self.products: dict = {}
        self.ldp_rows: tuple | None = None
        self._rows_t: tuple | None = None  # (key, G's rows times L^-T, block products)
        self._product: tuple | None = None  # (L^-T, its `CompiledProduct` or None)
        # What the last C pass wrote: (out's array, its address, `_rows_t`); None after
        # any other write into DAQP's rows.
        self._written: tuple | None = None
        self.passes = 0
        # 1 for DAQP's rows left as the last pass had them (uint8; the factor's first), and
        # the pass it holds (that of a C pass onto the rows it held, `same_rows`), else -1
        self._same = np.ones(0, dtype=np.uint8)
        self._same_pass = -1

    def _compiled(self, G: np.ndarray, kept: np.ndarray, inv_t: np.ndarray
                  ) -> CompiledProduct | None:
        """The C product for ``inv_t`` if it can take these arrays; None: numpy's."""
        if not (self.compiled and G.dtype == np.float64 and G.strides[1] == 8
                and kept.dtype == np.int64 and kept.strides[0] == 8):
            return None
        if self._product is None or self._product[0] is not inv_t:
            self._product = (inv_t, compiled_product(inv_t))
        return self._product[1]

    def times_factor(self, G: np.ndarray, kept: np.ndarray, inv_t: np.ndarray, blocks: tuple,
                     out: np.ndarray, structure: RowStructure, found: tuple | None = None,
                     diagonal: tuple = ()) -> None:
        """``out = G[kept] @ inv_t``, the rows of constant blocks from their kept products.

        ``blocks``: ``(first row, read-only block)`` pairs (`wbc.qp.QP.constant_rows`). A
        block's product is kept while the same block object comes with the same factor; the
        products sit in a buffer of all rows, from which the kept rows are read.
        ``structure``: the problem's `RowStructure`; ``found``: the C
        screening's ``(kept, rest)``, if it ran (numpy's path multiplies ``rest``).
        ``diagonal``: ``(first row, DiagonalBlocks)`` pairs (`wbc.qp.QP.diagonal_rows`),
        whose rows numpy multiplies block by block (`_diagonal_product`).
        """
        key, constant, _, done = structure
        c = self._compiled(G, kept, inv_t)
        products = {}
        for first, block in blocks:
            entry = self.products.get(id(block))
            if entry is None or entry[0] is not block or entry[1] is not inv_t:
                # The C product's bits where the other rows get them (a block's rows are
                # then the same numbers whether or not the QP marks it constant).
                product = None if c is None else c.times(np.ascontiguousarray(block, dtype=float))
                entry = (block, inv_t, block @ inv_t if product is None else product)
            products[id(block)] = entry
        self.products = products  # the blocks of this problem only
        filled = tuple(products[id(block)][2] for _, block in blocks)
        last = self._rows_t
        if (last is None or last[0] != key or last[1].shape != G.shape
                or not all(map(operator.is_, last[2], filled))):
            buffer = np.empty(G.shape) if last is None or last[1].shape != G.shape else last[1]
            for (first, block), product in zip(blocks, filled):
                buffer[first:first + block.shape[0]] = product
            self._rows_t = (key, buffer, filled)
        buffer = self._rows_t[1]
        if c is not None:
            written = (out if out.base is None else out.base, address(out), self._rows_t)
            last = self._written
            held = (last is not None and last[0] is written[0] and last[1] == written[1]
                    and last[2] is written[2])
            same = None
            if held:  # the factor's rows before out's: the same buffer, the same factor
                n = inv_t.shape[0]
                if self._same.size < n + out.shape[0]:
                    self._same = np.ones(n + 2 * out.shape[0], dtype=np.uint8)
                same = self._same[n:]
            ok = c.run(G, kept, constant, buffer, out, held, same)
            self._written = written if ok else None
            if ok:
                self._same_pass = self.passes if held else -1
                return
        self._written = None
        for first, d in diagonal:
            if d.rows >= 2:
                _diagonal_product(G, first, d, inv_t, buffer)
        rest = found[1] if found is not None and found[0] is kept else kept[~done[kept]]
        if rest.size == 1:  # as two rows: numpy makes one row a matrix-vector product,
            rest = np.repeat(rest, 2)  # which sums in another order than the matrix product
        if rest.size:
            buffer[rest] = G[rest] @ inv_t
        np.take(buffer, kept, axis=0, out=out, mode="clip")  # 'raise' buffers `out`

    def least_distance_rows(self, G: np.ndarray | None, kept: np.ndarray, inv_t: np.ndarray,
                            blocks: tuple, rows: np.ndarray | None,
                            structure: RowStructure | None = None, found: tuple | None = None,
                            diagonal: tuple = ()) -> np.ndarray:
        """DAQP's rows of the least-distance form, ``[L^-T; rows L^-T]``.

        ``rows`` None: ``G[kept]`` (`times_factor`, with these arguments). Written into a
        buffer kept from solve to solve (a fresh array of this size costs its page faults
        every tick; DAQP leaves its arguments as they are); its first rows are rewritten
        when the factor changes.
        """
        self.passes += 1
        self._same_pass = -1
        m = kept.size if rows is None else rows.shape[0]
        n = inv_t.shape[0]
        buf = self.ldp_rows
        if buf is None or buf[0] is not inv_t or buf[1].shape[0] < n + m:
            buf = (inv_t, np.empty((n + max(m, 0 if G is None else G.shape[0]), n)))
            buf[1][:n] = inv_t
            self.ldp_rows = buf
        out = buf[1][:n + m]
        if rows is None:
            self.times_factor(G, kept, inv_t, blocks, out[n:], structure, found, diagonal)
        else:
            np.matmul(rows, inv_t, out=out[n:])
            self._written = None
        return out

    def same_rows(self, consumed: int) -> np.ndarray | None:
        """Which of this pass's rows have the bits of the same rows of pass ``consumed``.

        uint8, 1 for a row the C pass left as it was (`CompiledProduct.run`'s ``same``)
        and for the factor's rows, when ``consumed`` is the pass before this one; None
        (nothing known) otherwise.
        """
        if self._same_pass != self.passes or consumed != self.passes - 1:
            return None
        return self._same
