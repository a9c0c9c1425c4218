"""DAQP called directly: redundant rows screened out, warm started from the last multipliers.

DAQP (a dual active-set method) spends most of a solve of the MPC's dense QP in its setup,
which grows with the number of inequality rows times ``n^2``, and the MPC's condensed QP
carries many rows that cannot bind: stroke and speed limits of the predicted trajectory far
from their ends. A row ``g x <= h`` is dropped when even the worst point of the variable box
``lb <= x <= ub`` (widened by DAQP's primal tolerance, the most by which it lets a bound
slip) keeps it: ``sum_i max(g_i lb_i, g_i ub_i) + |g|_1 tol <= h``. That changes nothing in
the solution: the box implies the row. The remaining rows are warm started from the previous
solve's multipliers (DAQP's ``dual_start``: its initial working set is the rows with nonzero
multipliers) when the problem has the same rows; a warm solve that fails is retried cold.
The rows outside constant blocks are screened in C when a compiler is there
(`wbc.solvers.screen_c`: numpy's kept rows, proven row by row, else numpy decides).

DAQP solves the least-distance form of the QP: with ``H = L L'`` and ``x = L^-T (u - v)``,
``v = L^-1 f``, the cost is ``|u|^2 / 2`` up to a constant and every row ``g x`` reads
``(g L^-T) u - g L^-T v``. Its own set-up forms ``M = A L^-T`` in plain loops (0.65 ms of a
0.8 ms solve of the MPC's QP: 108 variables, ~220 kept rows); here the factor is kept while
``H`` is unchanged (the MPC's Hessian is constant tick after tick) and ``M`` is formed by
`wbc.solvers.factor_rows` (the rows of constant blocks from products kept from solve to
solve, the others from the factor's nonzeros in C), and DAQP gets an identity
Hessian, which it recognises as diagonal (no factorisation, no products), and no linear
term. The rows and hence the multipliers are the same as the QP's, so the warm start and the
tolerance mean what they did. A Hessian that is not numerically positive definite goes to
DAQP as it is (its own regularisation). A constant block's screening sums are kept too,
while the bounds of the columns it has entries in stay the same.

DAQP's own set-up of the least-distance problem (allocating its workspace, copying and
normalising the rows: ~75 us of a ~80 us warm solve of the MPC's ~400 rows) is done on a
workspace kept from solve to solve when its C API can be reached
(`wbc.solvers.daqp_c`: ``daqp.solve``'s bits, set up in ~20 us); ``daqp.solve`` is the
reference (``kept_workspace = False``) and solves the direct form.

On that workspace the rest of a least-distance solve is one C call too
(`LeastDistanceWorkspace.step`, ``fused``): the shifts ``v = L^-1 f`` and ``L^-T v``, the
bounds, the rows' shifts ``M v``, the clips, the warm start's gather, the cold retry,
``x = L^-T u - shift`` and the multipliers' scatter, ~15 us of numpy calls a tick before. Its
products are numpy's own BLAS routines (`estimators.observer.tail_c.numpy_blas`:
``cblas_dgemv``, and ``cblas_ddot`` for a single row) called with the arguments numpy's
matmul passes them (a transposed view: row-major, else column-major, both transposed), so
the bits are numpy's; where numpy's BLAS cannot be reached the numpy path runs
(`tests/test_daqp_fused.py` compares both, and ``daqp.solve``, solve by solve). The rows
the product pass left in place since the last solve (the factor's, most constant rows) are
not normalised again (`FactorRows.same_rows`).
"""

from __future__ import annotations

import time

import daqp
import numpy as np
import qpsolvers
from scipy.linalg import lapack

from models.numeric import clip
from models.numpy_blas import numpy_blas
from wbc.errors import ConfigurationError, QPSolveError
from wbc.solvers.box_screen import BIG as _BIG
from wbc.solvers.box_screen import BlockSums, redundant_rows
from wbc.solvers.box_screen import box_terms as _box_terms
from wbc.solvers.box_screen import worst as _worst
from wbc.solvers.daqp_c import LeastDistanceWorkspace, ldp_library
from wbc.solvers.factor_rows import FactorRows, RowStructure, row_structure
from wbc.solvers.product_c import product_library
from wbc.solvers.screen_c import CompiledScreen, compiled_screen, screen_library
from wbc.solvers.solution import QPSolution

__all__ = ["DaqpBackend", "redundant_rows"]

_all = np.logical_and.reduce  # `np.all` of a 1-D array without its Python dispatch
_EQUALITY = 5  # DAQP's sense flags: active (1) | immutable (4)
# Below this many variables DAQP's own set-up costs less than the extra numpy calls of the
# least-distance form (the whole-body QP, 9 variables: 41 us direct, 67 us with the form).
_LEAST_DISTANCE_SIZE = 32


def _frozen(H) -> bool:
    """``H`` is a read-only array that owns its data: no one can write it in place.

    (Only its owner could set it writable again: `wbc.qp.QPBuilder`'s kept ``P``, which it
    never does.) A read-only view is not frozen: its base may be written.
    """
    return isinstance(H, np.ndarray) and not H.flags.writeable and H.base is None


def _equal(H, kept: tuple) -> bool:
    """``H`` equals the kept Hessian ``kept[0]`` (its bytes ``kept[1]``).

    The same bits are equal (a copy and a compare, half the time of `np.array_equal`), else
    the values decide (+-0; a NaN: not equal).
    """
    return (H.dtype == kept[0].dtype and H.shape == kept[0].shape
            and H.tobytes() == kept[1] or np.array_equal(kept[0], H))


def _vector(a, size: int) -> bool:
    """``a`` is a contiguous float64 array of shape ``(size,)``, as C reads it."""
    return (isinstance(a, np.ndarray) and a.dtype == np.float64 and a.shape == (size,)
            and a.flags.c_contiguous)


def _senses(size: int, first_equality: int) -> np.ndarray:
    """DAQP's sense flags (it writes into them): rows from ``first_equality`` on equalities."""
    sense = np.zeros(size, dtype=np.intc)
    sense[first_equality:] = _EQUALITY
    return sense


class DaqpBackend:
    """The MPC's QP solver: DAQP with row screening and warm starts (module docstring).

    Args:
        primal_tol: DAQP's primal feasibility tolerance (the controller's ``eps_abs``).
        iter_limit: Cap on active-set iterations.
        warm_start: Start from the previous solve's multipliers when the rows match.
        screen: Drop the rows the variable box makes redundant.
        least_distance: Hand DAQP the least-distance form with a kept factor of ``H``
            (module docstring); False: DAQP factorises ``H`` itself on every solve.
    """

    solver = "daqp"

    def __init__(self, primal_tol: float = 1e-7, iter_limit: int = 1000,
                 warm_start: bool = True, screen: bool = True, least_distance: bool = True):
        if not (primal_tol > 0 and iter_limit >= 1):
            raise ConfigurationError(f"need primal_tol > 0 and iter_limit >= 1, got "
                                     f"{primal_tol}, {iter_limit}")
        self.tolerances = {"primal_tol": float(primal_tol), "iter_limit": int(iter_limit)}
        self.warm_start = bool(warm_start)
        self.screen = bool(screen)
        self.least_distance = bool(least_distance)
        # (the H whose factor is kept, its bytes, the read-only array it came from or None)
        self._hessian: tuple | None = None
        self._inv_factor: tuple | None = None  # (L^-T, identity) for that H
        self._factored = False  # the factor of that H tried
        self.form = "direct"  # the last solve's form: "direct" or "least-distance"
        self.n_init = 0
        self.rows_kept = 0
        self._lam: np.ndarray | None = None  # multipliers of every row, dropped ones 0
        self._n: int | None = None
        self._sums = BlockSums(self.tolerances["primal_tol"])  # the constant blocks' sums
        self._rows_structure: RowStructure | None = None
        self._rows = FactorRows()  # DAQP's rows, the products kept from solve to solve
        self._screen_c: tuple | None = None  # (structure key, `CompiledScreen` or None)
        self._kept_rest: tuple | None = None  # the C screening's (kept, rest) rows
        self._workspace: LeastDistanceWorkspace | None = None
        self._blas: tuple[int, int] | None = None  # numpy's cblas_dgemv, cblas_ddot
        self.fused = False
        self._consumed = -1  # the `FactorRows` pass whose rows the last fused solve took
        # The C parts compiled (or loaded) now, not in a control loop's first solves.
        if screen:
            screen_library()
        if least_distance:
            product_library()
            self.kept_workspace = True
            self.fused = True

    @property
    def compiled(self) -> bool:
        """Screen and multiply in C when it can (`wbc.solvers.screen_c`, `.product_c`).

        False: numpy, and ``daqp.solve`` (setting it sets `kept_workspace` too).
        """
        return self._rows.compiled

    @compiled.setter
    def compiled(self, value: bool) -> None:
        self._rows.compiled = bool(value)
        self.kept_workspace = bool(value)
        self.fused = bool(value)

    @property
    def fused(self) -> bool:
        """The least-distance form's numpy in the kept workspace's call (module docstring).

        `LeastDistanceWorkspace.step`: numpy's bits, through its BLAS. True only with a
        kept workspace and numpy's BLAS reachable (`estimators.observer.tail_c.numpy_blas`);
        False: numpy around the workspace's solve.
        """
        return self._blas is not None

    @fused.setter
    def fused(self, value: bool) -> None:
        blas = numpy_blas() if value else None
        self._blas = None if blas is None else blas[:2]

    @property
    def kept_workspace(self) -> bool:
        """Solve the least-distance form on a DAQP workspace kept from solve to solve.

        `wbc.solvers.daqp_c` (``daqp.solve``'s bits), when its library loaded; False:
        ``daqp.solve``, the reference.
        """
        return self._workspace is not None

    @kept_workspace.setter
    def kept_workspace(self, value: bool) -> None:
        if not value:
            self._workspace = None
        elif self._workspace is None and ldp_library() is not None:
            self._workspace = LeastDistanceWorkspace(**self.tolerances)

    def reset(self) -> None:
        """Forget the previous multipliers (the next solve is cold)."""
        self._lam = None

    @property
    def multipliers(self) -> tuple[np.ndarray | None, np.ndarray | None]:
        """``(z, z_box)`` of the last solve (None before one).

        DAQP's sign convention (qpsolvers' too); ``z`` holds the inequality rows and then
        the equality rows, the screened rows' multipliers 0.
        """
        if self._lam is None or self._n is None:
            return None, None
        return self._lam[self._n:], self._lam[:self._n]

    def _factor(self, H: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
        """``(L^-T, identity)`` for ``H = L L'`` once ``H`` repeats, kept while it does.

        None for a Hessian seen for the first time (a factor pays only when it is used
        again) and when ``H`` is not numerically positive definite (a pivot below DAQP's
        own relative level, 1e-11 of the largest): DAQP then factorises, or regularises,
        it itself.
        """
        kept = self._hessian
        if kept is None or not (H is kept[2] and _frozen(H) or _equal(H, kept)):
            given = H
            H = np.array(H, dtype=float)
            self._hessian = (H, H.tobytes(), given if _frozen(given) else None)
            self._inv_factor, self._factored = None, False
            return None
        if kept[2] is not H and _frozen(H):  # the builder's kept P (`wbc.qp.QPBuilder`):
            self._hessian = (*kept[:2], H)  # the next ticks know it by its identity
        if not self._factored:
            self._factored = True
            try:
                low = np.linalg.cholesky(0.5 * (H + H.T))
            except np.linalg.LinAlgError:
                return None
            pivots = np.diag(low) ** 2
            inv_low, info = lapack.dtrtri(low, lower=1)
            if info == 0 and pivots.min() > 1e-11 * pivots.max():
                self._inv_factor = (np.ascontiguousarray(inv_low.T), np.eye(H.shape[0]))
        return self._inv_factor

    def _structure(self, m_in: int, blocks: tuple, diagonal: tuple = ()) -> RowStructure:
        """The `RowStructure` of a problem's rows, kept while the blocks sit where they did."""
        key = (m_in, tuple((first, block.shape[0]) for first, block in blocks), diagonal)
        if self._rows_structure is None or self._rows_structure[0] != key:
            self._rows_structure = row_structure(key, m_in, blocks, diagonal)
        return self._rows_structure

    def _screen(self, G: np.ndarray, h: np.ndarray, lb, ub, blocks: tuple,
                diagonal: tuple = (), structure: RowStructure | None = None) -> np.ndarray:
        """The rows `redundant_rows` keeps, as indices; a constant block's screening sums kept.

        The constant blocks' sums are kept (`wbc.solvers.box_screen.BlockSums`).
        ``structure``: the rows' `RowStructure`, if the caller has it.
        """
        m_in, n = G.shape
        if not blocks:
            box = _box_terms(lb, ub, n, self.tolerances["primal_tol"])
            return np.flatnonzero(~(_worst(G, box) <= h))
        box, worst = self._sums.sums(m_in, n, blocks, lb, ub)
        if structure is None:
            structure = self._structure(m_in, blocks, diagonal)
        c = self._compiled_screen(G, h, structure)
        found = None if c is None else c.run(G, worst, h, box)
        self._kept_rest = found  # `_times_factor`'s rows, if the C pass found them
        if found is not None:
            return found[0]
        for a, b in structure.gaps:
            worst[a:b] = _worst(G[a:b], box)
        return np.flatnonzero(~(worst <= h))

    def _compiled_screen(self, G: np.ndarray, h: np.ndarray, structure: RowStructure
                         ) -> CompiledScreen | None:
        """The C screening (`wbc.solvers.screen_c`) for this structure; None: numpy's."""
        if not (G.dtype == h.dtype == np.float64 and G.strides[1] == 8 and h.strides[0] == 8
                and self.compiled):
            return None
        return self._screen_of(structure, G.shape[1])

    def _screen_of(self, structure: RowStructure, n: int) -> CompiledScreen | None:
        """The `CompiledScreen` of rows of this structure and n columns, kept."""
        key = (structure.key, n)
        if self._screen_c is None or self._screen_c[0] != key:
            m_in = structure.constant.size
            self._screen_c = (key, compiled_screen(m_in, n, structure.gaps, structure.done))
        return self._screen_c[1]

    def prepare(self, m_in: int, n: int, blocks: tuple, diagonal: tuple, lb, ub) -> None:
        """What the first solve makes of rows like these alone, now (`wbc.structure`).

        ``m_in`` rows of n columns, their constant ``blocks`` and ``diagonal`` rows
        (`wbc.qp.QP`) and bounds (n,) (`wbc.structure.PreparedRows`): the `RowStructure`,
        its C screening, the blocks' sums (kept while their columns' bounds stay); nothing
        of a solve (multipliers, factor, workspace). Other rows: made at their solve.
        """
        if self.screen and m_in and blocks:  # `_screen` keeps nothing without blocks
            structure = self._structure(m_in, blocks, diagonal)
            self._sums.sums(m_in, n, blocks, lb, ub)
            if self.compiled:
                self._screen_of(structure, n)

    def _fused(self, t0: float, G, kept: np.ndarray, inv_t: np.ndarray, a_all, f, lb, ub,
               h, b, m_in: int, m_eq: int, blocks: tuple, diagonal: tuple,
               structure: RowStructure | None) -> QPSolution | None:
        """`solve`'s least-distance form through `LeastDistanceWorkspace.step`.

        None (nothing done) when an argument is not as the C reads it: `solve` then runs
        its numpy.
        """
        n = f.size
        if not (_vector(f, n) and (ub is None or _vector(ub, n)) and (lb is None or _vector(lb, n))
                and (m_in == 0 or _vector(h, m_in)) and (m_eq == 0 or _vector(b, m_eq))
                and kept.dtype == np.int64 and kept.strides[0] == 8
                and inv_t.flags.c_contiguous):
            return None
        a_all = self._rows.least_distance_rows(G, kept, inv_t, blocks, a_all, structure,
                                               self._kept_rest, diagonal)
        n_all = n + m_in + m_eq
        warm = self.warm_start and self._lam is not None and self._lam.size == n_all
        same = self._rows.same_rows(self._consumed)
        self._consumed = self._rows.passes
        x, lam, flag, iterations, warm, call, solved = self._workspace.step(
            self._blas, a_all, inv_t, f, ub, lb, h if m_in else None, kept,
            b if m_eq else None, m_in, self._lam if warm else None, same)
        elapsed = time.perf_counter() - t0
        if not solved:
            self._lam = None
            raise QPSolveError(f"daqp found no solution (exit flag {flag})", "not_found")
        self._lam, self._n = lam, n
        return QPSolution(x, "solved", iterations, elapsed, warm, call)

    def _daqp(self, hessian: np.ndarray, cost: np.ndarray | None, a: np.ndarray,
              upper: np.ndarray, lower: np.ndarray, first_equality: int,
              dual: np.ndarray | None, least_distance: bool
              ) -> tuple[np.ndarray, np.ndarray, int, int]:
        """DAQP's ``(x, multipliers, exit flag, iterations)``, warm started from ``dual``.

        Rows from ``first_equality`` on are equalities; ``dual`` None: cold. The
        least-distance form (the identity for ``hessian``, no ``cost``, every bound a row of
        ``a``) on the kept workspace if there is one, else ``daqp.solve``.
        """
        if least_distance and self._workspace is not None:
            return self._workspace.solve(a, upper, lower, first_equality, dual)
        x, _, flag, info = daqp.solve(hessian, cost, a, upper, lower,
                                      _senses(upper.size, first_equality), dual_start=dual,
                                      **self.tolerances)
        return x, info["lam"], flag, int(info["iterations"])

    def solve(self, problem: qpsolvers.Problem) -> QPSolution:
        """Solve; raise `QPSolveError` if DAQP finds no finite solution."""
        t0 = time.perf_counter()
        H, f = problem.P, problem.q
        n = f.size
        lb, ub = problem.lb, problem.ub
        G, h, A, b = problem.G, problem.h, problem.A, problem.b
        m_in = 0 if G is None else G.shape[0]
        m_eq = 0 if A is None else A.shape[0]
        blocks = getattr(problem, "constant_rows", ())
        diagonal = getattr(problem, "diagonal_rows", ())
        structure = self._structure(m_in, blocks, diagonal) if blocks or diagonal else None
        if self.screen and m_in:
            kept = self._screen(G, h, lb, ub, blocks, diagonal, structure)
        else:
            kept = np.arange(m_in)
        self.rows_kept = m_k = kept.size
        # DAQP's rows: the kept inequalities, then the equalities; its bounds [lower, upper]
        # on x and then on every row (an inequality's lower bound -_BIG).
        factor = (self._factor(H) if self.least_distance and n >= _LEAST_DISTANCE_SIZE
                  else None)
        if m_in == 0:
            a_all = np.zeros((0, n)) if m_eq == 0 else A
        elif factor is not None and (blocks or diagonal) and m_eq == 0:  # G[kept] L^-T, below
            a_all = None
        elif m_k == m_in:  # nothing screened out: DAQP reads G as it is
            a_all = G if m_eq == 0 else np.concatenate([G, A])
        else:
            a_all = G[kept] if m_eq == 0 else np.concatenate([G[kept], A])
        self.form = "direct" if factor is None else "least-distance"
        if factor is not None and self._blas is not None and self._workspace is not None:
            solution = self._fused(t0, G, kept, factor[0], a_all, f, lb, ub, h, b, m_in, m_eq,
                                   blocks, diagonal, structure)
            if solution is not None:
                return solution
        upper = np.empty(n + m_k + m_eq)
        lower = np.empty(n + m_k + m_eq)
        upper[:n] = np.inf if ub is None else ub
        lower[:n] = -np.inf if lb is None else lb
        if m_k:
            upper[n:n + m_k] = h if m_k == m_in else h[kept]
            lower[n:n + m_k] = -np.inf
        if m_eq:
            upper[n + m_k:] = b
            lower[n + m_k:] = b
        if factor is None:
            # (daqp.solve takes writable buffers only; the builder's kept P is read-only)
            hessian, cost = (H if H.flags.writeable else np.array(H)), f
        else:  # the least-distance form: rows [L^-T; a_all L^-T], shifted by a_all x(u=0)
            inv_t, hessian = factor
            v = inv_t.T @ f
            shift = inv_t @ v  # x = L^-T u - shift
            upper[:n] += shift
            lower[:n] += shift
            a_all = self._rows.least_distance_rows(G, kept, inv_t, blocks, a_all, structure,
                                                   self._kept_rest, diagonal)
            row_shift = a_all[n:] @ v
            upper[n:] += row_shift
            lower[n:] += row_shift
            cost = None  # no linear term: DAQP skips its ``M v`` pass (0.02 ms), same bits
        clip(upper, -_BIG, _BIG, out=upper)
        clip(lower, -_BIG, _BIG, out=lower)
        a_all = np.ascontiguousarray(a_all)
        rows = kept if m_eq == 0 else np.concatenate([kept, m_in + np.arange(m_eq)])
        n_all = n + m_in + m_eq
        warm = (self.warm_start and self._lam is not None and self._lam.size == n_all)
        dual = None
        if warm:  # no rows (the whole-body QP): the bounds' multipliers alone
            dual = (np.concatenate([self._lam[:n], self._lam[n + rows]]) if rows.size
                    else self._lam[:n].copy())
        t_call = time.perf_counter()
        x, lam_daqp, flag, iterations = self._daqp(hessian, cost, a_all, upper, lower,
                                                   n + m_k, dual, factor is not None)
        call = time.perf_counter() - t_call
        ok = flag > 0 and _all(np.isfinite(x))
        if warm and not ok:
            warm = False
            t_call = time.perf_counter()
            x, lam_daqp, flag, retry = self._daqp(hessian, cost, a_all, upper, lower,
                                                  n + m_k, None, factor is not None)
            call += time.perf_counter() - t_call
            iterations += retry
            ok = flag > 0 and _all(np.isfinite(x))
        if factor is not None:
            x = factor[0] @ x - shift
            ok = flag > 0 and _all(np.isfinite(x))
        elapsed = time.perf_counter() - t0
        if not ok:
            self._lam = None
            raise QPSolveError(f"daqp found no solution (exit flag {flag})", "not_found")
        lam = np.zeros(n_all)
        lam[:n] = lam_daqp[:n]
        if rows.size:  # no rows (the whole-body QP): nothing to scatter
            lam[n + rows] = lam_daqp[n:]
        self._lam, self._n = lam, n
        return QPSolution(np.asarray(x, float), "solved", iterations, elapsed, warm, call)
