"""Assemble tasks and constraints into a `qpsolvers.Problem` (building apart from solving)."""

from __future__ import annotations

import operator
import sys
import types
from collections.abc import Sequence

import numpy as np
import qpsolvers

from wbc.constraints.constraint import Box, Constraint, Inequality
from wbc.errors import ConfigurationError, WbcError
from wbc.tasks import linear_c
from wbc.tasks.linear_c import LinearProgram
from wbc.tasks.object_fields_c import SameObjects
from wbc.tasks.task import Task

__all__ = ["QP", "QPBuilder", "build_qp"]

_any = np.logical_or.reduce  # `ndarray.any` of a 1-D array without its Python dispatch


class QP(qpsolvers.Problem):
    """A `qpsolvers.Problem` that also says which blocks of its ``G`` rows are constant.

    Attributes:
        constant_rows: ``(first row, block)`` pairs: ``G[first:first + len(block)]`` is the
            read-only array ``block``, the very object a constraint returned at earlier ticks
            too. `wbc.solvers.DaqpBackend` keeps what it derives from such a block (its rows
            times the Hessian's inverse factor) while the block and the factor stay the same.
        diagonal_rows: ``(first row, DiagonalBlocks)`` pairs: the rows from ``first`` on
            are zero outside those blocks (`wbc.constraints.DiagonalBlocks`), and not
            constant. `wbc.solvers.DaqpBackend` multiplies each block's columns alone.
    """

    def __init__(self, *args, constant_rows: tuple = (), diagonal_rows: tuple = (),
                 **kwargs):
        super().__init__(*args, **kwargs)
        self.constant_rows = constant_rows
        self.diagonal_rows = diagonal_rows

    @classmethod
    def _of_checked(cls, P, q, G, h, lb, ub, constant_rows: tuple,
                    diagonal_rows: tuple) -> QP:
        """The QP of arrays `QPBuilder.build` made and checked, without `__init__`.

        ``qpsolvers.Problem.__init__`` only reshapes a 1-D matrix or a 2-D vector, and the
        builder's P and G are 2-D, its vectors 1-D: the same object, six calls fewer.
        """
        qp = cls.__new__(cls)
        qp.P, qp.q, qp.G, qp.h, qp.A, qp.b, qp.lb, qp.ub = P, q, G, h, None, None, lb, ub
        qp.constant_rows, qp.diagonal_rows = constant_rows, diagonal_rows
        return qp


class QPBuilder:
    r"""Builds the QP of every tick from fixed tasks and constraints (see `build_qp`).

    A controller keeps one: the Hessian is reused while the active tasks return the very same
    read-only ``H`` arrays as at the last tick (constant-Jacobian tasks cache theirs), the
    same sum in the same order, so the same bits, without its per-tick additions. The
    problem's ``P`` is then shared between ticks, and read-only (an array of its own: a
    solver may keep what it derives from it while it gets the same object again). So are the rows
    of ``G`` that hold constant blocks (`QP.constant_rows`): ``G`` is the last tick's array
    again when nothing else holds that any more, with only the other rows written
    (`_stacked_rows`). The bounds are the last tick's numbers again (fresh copies) while
    every box is the last tick's read-only one (`_bounds`).

    When every active task says its term (`Task.linear_term`: the MPC's do), ``q`` is
    written by one compiled call (`wbc.tasks.linear_c.LinearProgram`, kept while the terms
    are the same objects) instead of each task's ``compute_qp_objective`` and the sum in
    numpy: the same bits (`_compiled_objective`).

    Args:
        tasks: Cost terms.
        constraints: Constraints.
        regularization: Tikhonov term added to P's diagonal (> 0 keeps P definite).
        compiled: Write ``q`` in C when the tasks allow it; False: always the numpy loop.
    """

    def __init__(self, tasks: Sequence[Task], constraints: Sequence[Constraint],
                 regularization: float = 1e-9, compiled: bool = True):
        if not regularization >= 0:
            raise ConfigurationError(f"regularization must be >= 0, got {regularization}")
        self.tasks = tasks  # the owner's lists: what it appends later counts
        self.constraints = constraints
        self.regularization = regularization
        self.compiled = bool(compiled)
        self._linear: tuple | None = None  # (terms, layout, program or None, P)
        self._guard: tuple | None = None  # `_guarded`: the terms' guards, checked at once
        self._refused: Task | None = None  # the task that said no term: the numpy loop
        self._hessians: list | None = None  # the H arrays the cached P sums
        self._P: np.ndarray | None = None
        self._layout = None  # the layout of `_defaults`
        self._defaults: tuple[np.ndarray, np.ndarray] | None = None
        self._bounds_kept: tuple | None = None  # (layout, boxes, lb, ub): `_bounds`
        self._zero: np.ndarray | None = None  # `_zeros`
        self._rows: tuple | None = None  # (the last G, its constant blocks' places)
        self._spare: np.ndarray | None = None  # `prepare`'s G for the first `_stacked_rows`

    def _stacked_rows(self, Gs: list, constant: tuple, diagonal: tuple, m: int) -> np.ndarray:
        """``np.concatenate(Gs)``, shape (m, n); the constant blocks' rows kept from the last.

        The last tick's array is reused when only this builder holds it (the problem that
        carried it, and every view of it, is gone: its reference count says so) and the
        constant blocks are the same objects in the same places: then only the other rows
        are written (the MPC's 430 constant rows of 580 are not copied every tick). Of rows
        whose `DiagonalBlocks` are the last tick's in the same place only the blocks are
        written: the rest of those rows is zeros in both (the MPC's effort rows: 3 % of
        their entries). Else a fresh array: the first time the one `prepare` made, if it
        has the shape (its pages already mapped: the first tick does not fault them in).
        """
        last, self._rows = self._rows, None
        spare, self._spare = self._spare, None
        n = Gs[0].shape[1]
        # References to the last array: the tuple `last`, getrefcount's argument and the
        # kept views of its diagonal blocks.
        if (last is None or last[0].shape != (m, n)
                or sys.getrefcount(last[0]) != 2 + len(last[3]) or len(last[1]) != len(constant)
                or not all(a[0] == b[0] and a[1] is b[1] for a, b in zip(last[1], constant))):
            G = np.concatenate(Gs, out=spare if spare is not None and spare.shape == (m, n)
                               and all(b.dtype == spare.dtype for b in Gs) else None)
            views = {}
        else:
            G, kept, views = last[0], last[2], last[3]
            first = 0
            for block in Gs:
                if block.flags.writeable:  # not a constant block
                    d = diagonal.get(first)
                    if (d is not None and _same(kept.get(first), d)
                            and block.flags.c_contiguous):
                        view = views.get(first)
                        if view is None or not _same(view[0], d):  # their view of G, kept
                            view = views[first] = (d, _blocks(G, first, d))
                        view[1][...] = _blocks(block, 0, d)
                    else:
                        G[first:first + block.shape[0]] = block
                first += block.shape[0]
        self._rows = (G, constant, diagonal, views)
        return G

    def _hessian(self, n: int, hessians: list) -> np.ndarray:
        """``regularization * I + sum(H)``, reused when every H is the last tick's array."""
        if (self._hessians is not None and len(hessians) == len(self._hessians)
                and all(map(operator.is_, hessians, self._hessians))):
            return self._P
        P = self.regularization * np.eye(n)
        for H in hessians:
            P += H
        constant = all(not H.flags.writeable for H in hessians)
        if constant:  # shared from tick to tick: read-only, so a solver may keep what it
            P.setflags(write=False)  # derives from it while it is the same object
        self._hessians, self._P = (hessians, P) if constant else (None, None)
        return P

    def _bounds(self, layout, boxes: list) -> tuple[np.ndarray, np.ndarray]:
        """``(lb, ub)``: the layout's default bounds narrowed by ``boxes`` in order, fresh.

        Reused (copied) while the layout and every box are the last tick's objects, with
        read-only arrays (`AccelerationLimit`'s and `SpeedScaleLimit`'s kept boxes): the
        same maxima and minima of the same numbers, without their ufuncs and the check.

        Raises:
            WbcError: The bounds are empty (lower > upper).
        """
        kept = self._bounds_kept
        if (kept is not None and kept[0] is layout and len(kept[1]) == len(boxes)
                and all(map(operator.is_, boxes, kept[1]))):
            return kept[2].copy(), kept[3].copy()
        if layout is not self._layout:
            self._defaults, self._layout = layout.default_bounds(), layout
        lb, ub = self._defaults[0].copy(), self._defaults[1].copy()
        constant = True
        for box in boxes:
            np.maximum(lb, box.lower, out=lb)
            np.minimum(ub, box.upper, out=ub)
            constant = constant and not (box.lower.flags.writeable
                                         or box.upper.flags.writeable)
        if _any(lb > ub):
            i = int(np.argmax(lb > ub))
            raise WbcError(f"empty bounds on x[{i}]: [{lb[i]}, {ub[i]}]")
        self._bounds_kept = (layout, boxes, lb.copy(), ub.copy()) if constant else None
        return lb, ub

    def prepare(self, ctx) -> list:
        """Make what the structure alone fixes before the first tick (`wbc.structure`).

        ``ctx``: a `wbc.structure.StructureContext`. Each active task's and every
        constraint's ``prepare`` (`Task.prepare`, `Constraint.prepare`), then, when every
        active task gave its constant ``H``, their sum (`_hessian`: the first tick finds the
        same arrays in the same order, or sums its own); when every constraint said its
        number of rows, an array for the first ``G`` with its pages mapped
        (`_stacked_rows`; every entry is written there); the default bounds and the zeros
        of ``q``; with `compiled`, the program of the tasks' terms (`_compiled_objective`:
        its library loaded now). Nothing that depends on the state.

        Returns:
            Each constraint's number of rows (``prepare``'s: None where not known).
        """
        lay = ctx.layout
        hessians = [task.prepare(ctx) for task in self.tasks if task.is_active(ctx)]
        rows = [con.prepare(ctx) for con in self.constraints]
        if hessians and all(H is not None for H in hessians):
            self._hessian(lay.n, hessians)
            if self.compiled:
                self._program(ctx)
        if self._rows is None and rows and None not in rows and sum(rows) > 0:
            self._spare = np.full((sum(rows), lay.n), 0.0)  # written: its pages mapped
        if lay is not self._layout:
            self._defaults, self._layout = lay.default_bounds(), lay
        self._zeros(lay.n)
        return rows

    def build(self, ctx) -> QP:
        r"""The QP at ``ctx`` (a context with a ``layout``: `QPContext` or `HorizonContext`).

        Raises:
            WbcError: A task or constraint returned arrays of the wrong shape, or the boxes
                are empty (lower > upper).
        """
        n = ctx.layout.n
        objective = self._compiled_objective(ctx) if self.compiled else None
        P, q = self._objective(ctx, n) if objective is None else objective
        Gs, hs, constant, diagonal, boxes = [], [], [], [], []
        rows = 0
        for con in self.constraints:
            r = con.compute(ctx)
            if r is None:
                continue
            if isinstance(r, Box):
                boxes.append(r)
            elif isinstance(r, Inequality):
                G = r.G
                if G.ndim != 2 or G.shape[1] != n or r.h.shape != (G.shape[0],):
                    raise WbcError(f"{type(con).__name__} returned G {G.shape}, h "
                                   f"{r.h.shape}; expected (m, {n}), (m,)")
                if not G.flags.writeable:
                    constant.append((rows, G))
                elif r.diagonal is not None:
                    d = r.diagonal
                    if (d.rows * d.n_blocks != G.shape[0] or d.rows < 1 or d.first < 0
                            or d.width < 1 or d.first + d.n_blocks * d.width > n):
                        raise WbcError(f"{type(con).__name__} returned {d} for G "
                                       f"{G.shape}: need rows * n_blocks = "
                                       f"{G.shape[0]} and the blocks within {n} columns")
                    diagonal.append((rows, d))
                rows += G.shape[0]
                Gs.append(G)
                hs.append(r.h)
            else:
                raise WbcError(f"{type(con).__name__}.compute returned {type(r).__name__}, "
                               f"expected Inequality, Box or None")
        lb, ub = self._bounds(ctx.layout, boxes)
        constant = tuple(constant)
        G = self._stacked_rows(Gs, constant, dict(diagonal), rows) if Gs else None
        h = np.concatenate(hs) if hs else None
        return QP._of_checked(P, q, G, h, lb, ub, constant, tuple(diagonal))

    def _objective(self, ctx, n: int) -> tuple[np.ndarray, np.ndarray]:
        """``(P, q)``: each active task's ``compute_qp_objective``, ``q`` their in-place sum.

        Raises:
            WbcError: A task returned arrays of the wrong shape.
        """
        hessians = []
        q = None
        for task in self.tasks:
            if not task.is_active(ctx):
                continue
            H, c = task.compute_qp_objective(ctx)
            if H.shape != (n, n) or c.shape != (n,):
                raise WbcError(f"{type(task).__name__} returned H {H.shape}, c {c.shape}; "
                               f"expected ({n}, {n}), ({n},)")
            hessians.append(H)
            if q is None:  # +0 + c, as zeros(n) += c (a -0 becomes +0), into a new array
                q = np.add(self._zeros(n), c)
            else:
                q += c
        if q is None:
            q = np.zeros(n)
        return self._hessian(n, hessians), q

    def _compiled_objective(self, ctx) -> tuple[np.ndarray, np.ndarray] | None:
        """`_objective`'s ``(P, q)`` by the kept program of the active tasks' terms.

        None (the numpy loop then runs) when a task says no term (remembered while it is
        one of the tasks), without a compiler, or when a term or a context array does not
        fit the layout (the numpy loop then raises the error it finds).
        """
        guard = self._guard
        if guard is not None and self._guard_holds(ctx, guard):
            kept = self._linear
        else:
            refused = self._refused
            if refused is not None and refused in self.tasks:
                return None
            kept = self._program(ctx)
            if kept is None or kept[2] is None:
                return None
        q = kept[2](ctx)
        return None if q is None else (kept[3], q)

    def _guard_holds(self, ctx, guard: tuple) -> bool:
        """Whether every task would return the last tick's term (`_guarded`)."""
        structure, idle, get, same, holder = guard
        holder.ctx = ctx
        try:
            now = get(holder)
        except AttributeError:  # another kind of context
            return False
        finally:
            holder.ctx = None  # not kept past the tick
        return (same.call(tuple(self.tasks) + now) and ctx.structure_key == structure
                and not (idle and any(task.is_active(ctx) for task in idle)))

    def _guarded(self, ctx, terms: list) -> tuple | None:
        """What `_guard_holds` checks, from the terms of ``ctx`` (`LinearTerm.guard`).

        ``(structure key, inactive tasks, getter, check, holder)``: the getter reads every
        attribute the terms' guards name, of the context and of the tasks (``holder.ctx``
        and ``holder.t0``, ...), in one C call, and the check compares the tasks and those
        with the objects now in one more (`wbc.tasks.object_fields_c.SameObjects`: the
        same objects, arrays still read-only), instead of every task's checks. None when a
        term has no guard or names what the context lacks, an array it names is writable,
        or without the compiled check (the tasks are asked every tick).
        """
        tasks = tuple(self.tasks)
        active = [task for task in tasks if task.is_active(ctx)]
        idle = tuple(task for task in tasks if not any(task is a for a in active))
        paths = []
        for task, term in zip(active, terms):
            if term.guard is None:
                return None
            for path in term.guard:
                owner, _, rest = path.partition(".")
                if owner not in ("ctx", "task") or not rest:
                    return None
                paths.append(path if owner == "ctx" else f"t{tasks.index(task)}.{rest}")
        holder = types.SimpleNamespace(ctx=ctx, **{f"t{i}": t for i, t in enumerate(tasks)})
        get = operator.attrgetter(*dict.fromkeys(paths), "__class__")  # a tuple, always
        try:
            now = get(holder)
        except AttributeError:
            return None
        finally:
            holder.ctx = None
        if any(isinstance(x, np.ndarray) and x.flags.writeable for x in now):
            return None
        same = SameObjects.make(tasks + now)
        return None if same is None else (ctx.structure_key, idle, get, same, holder)

    def _program(self, ctx) -> tuple | None:
        """``(terms, layout, program, P)`` of the active tasks' terms at ``ctx``, kept.

        A new program only when a term or the layout is not the last one (the tasks keep
        their terms with their caches: once per structure). None: a task said no term.
        """
        terms = []
        for task in self.tasks:
            if task.is_active(ctx):
                say = getattr(task, "linear_term", None)  # a duck-typed task: none
                term = None if say is None else say(ctx)
                if term is None:
                    self._refused = task
                    return None
                terms.append(term)
        self._refused = None
        kept, lay = self._linear, ctx.layout
        if (kept is None or len(kept[0]) != len(terms) or not (kept[1] is lay or kept[1] == lay)
                or not all(map(operator.is_, terms, kept[0]))):
            program = LinearProgram.make(tuple(terms), lay) if terms else None
            if program is None and not linear_c.available():
                self.compiled = False  # no compiler or not numpy's BLAS: the numpy loop
            P = self._hessian(lay.n, [t.H for t in terms]) if program is not None else None
            kept = self._linear = (terms, lay, program, P)
        self._guard = None if kept[2] is None else self._guarded(ctx, terms)
        return kept

    def _zeros(self, n: int) -> np.ndarray:
        """Read-only zeros (n,), kept."""
        if self._zero is None or self._zero.shape != (n,):
            self._zero = np.zeros(n)
            self._zero.setflags(write=False)
        return self._zero


def _same(a, b) -> bool:
    """``a == b``, the same object first (a constraint's kept `DiagonalBlocks`)."""
    return a is b or a == b


def _blocks(G: np.ndarray, first: int, d) -> np.ndarray:
    """The `DiagonalBlocks` ``d`` of C-contiguous ``G``'s rows from ``first`` on, a view.

    Shape (n_blocks, rows, width): block k at rows ``first + k rows``, columns
    ``d.first + k width``.
    """
    row, item = G.strides
    return np.ndarray((d.n_blocks, d.rows, d.width), G.dtype, G,
                      first * row + d.first * item,
                      (d.rows * row + d.width * item, row, item))


def build_qp(ctx, tasks: Sequence[Task], constraints: Sequence[Constraint],
             regularization: float = 1e-9) -> qpsolvers.Problem:
    r"""The QP of one control step.

    .. math:: \min_x \tfrac12 x^T P x + q^T x \;\; \text{s.t.}\;\; G x \le h,\;
              lb \le x \le ub,

    with ``P = sum_t J_t^T W_t J_t + regularization * I`` and ``q = sum_t J_t^T W_t e_t``
    over the active tasks, ``G, h`` the stacked inequalities and ``lb, ub`` the intersection
    of the boxes of the active constraints (and the layout's default bounds: slacks >= 0).

    Args:
        ctx: A context with a ``layout`` (`QPContext` or `HorizonContext`).
        tasks: Cost terms.
        constraints: Constraints.
        regularization: Tikhonov term added to P's diagonal (> 0 keeps P definite).

    Raises:
        WbcError: A task or constraint returned arrays of the wrong shape, or the boxes
            are empty (lower > upper).
    """
    return QPBuilder(tasks, constraints, regularization).build(ctx)
