"""The estimator over a log of states (`NormalForceEstimator.estimate_batch`).

Running the compiled kernel over chunks of many states (in threads), and the least-squares
rows. The kernel assembles each row from the state's fields on the stack, checks its strokes'
ranges and writes the chunk straight into one output block whose columns the
`BatchEstimate` fields view (no packed input, no copy, no scatter: `Compiled.gather`); the
contact modes come from a table of the 16 contact patterns, indexed in each chunk's thread.
"""

from __future__ import annotations

import functools
from collections.abc import Mapping, Sequence

import numpy as np

from estimators import full_dynamics as fd
from estimators._kernel_calls import assemble_rows
from estimators._symbolic import LAYOUT
from estimators.checks import check_finite_result
from estimators.errors import EstimatorInputError, SingularSystemError, range_message
from estimators.results import BatchEstimate
from estimators.tipping import least_squares
from models.errors import StateError
from models.reference_machine import MAX_PAYLOAD_MASS
from models.state_batch import StateBatch

__all__ = ["as_batch", "estimate_batch", "pack_rows", "range_bounds", "validate_batch"]

SINGULAR_CONDITION = 1e12  # 1-norm condition number above which a system counts as singular
_ZEROS12, _ZEROS4, _ONES4, _ZEROS2 = np.zeros(12), np.zeros(4), np.ones(4), np.zeros(2)
_PATTERNS = ((np.arange(16)[:, None] >> np.arange(4)) & 1).astype(bool)  # row k: bits of k


def estimate_batch(est, states, *, strict: bool = True, chunk: int = 4096,
                   threads: int = 2, payload_mass=None) -> BatchEstimate:
    """`NormalForceEstimator.estimate_batch` (see there) of the estimator ``est``."""
    for name, value in (("chunk", chunk), ("threads", threads)):
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
            raise EstimatorInputError(f"{name} must be an integer >= 1, got {value!r}")
    sb = as_batch(states)
    lay = LAYOUT
    n = len(sb)
    payload = None if payload_mass is None else _payload_column(payload_mass, n)
    out = np.empty((n, lay.out_size))  # every row is written by the kernel
    kernel = est._kernels.kernel("nf_estimate") if est._kernels is not None else None
    ic = sb.in_contact if sb.in_contact is not None else np.ones((n, 4), bool)
    # Row-wise arithmetic: selecting the 16 patterns' systems and indexing them by each row's
    # pattern gives the values `select_systems(ic, ...)` gives. Each chunk indexes its own
    # rows (in its thread), so the serial part of a batch stays small.
    table = fd.select_systems(_PATTERNS, est.fourth, sb.suspension_force is not None)
    pattern = np.empty(n, np.uint8)  # bit k: wheel k in contact
    bounds = range_bounds(est)
    out_of_range = []  # chunks with a coordinate outside its range: not evaluated
    threaded = threads > 1 and kernel is not None and n > chunk
    size = int(chunk)
    if threaded:  # equal chunks, as many per thread, none longer than ``chunk``
        size = -(-n // (threads * -(-n // (threads * size))))

    def run(lo: int) -> None:
        sl = slice(lo, min(lo + size, n))
        pattern[sl] = np.packbits(ic[sl], axis=1, bitorder="little")[:, 0]
        if kernel is not None:  # each row assembled, range-checked and evaluated (in C)
            if not kernel.gather(row_parts(est, sb, sl, table, pattern[sl], payload), out[sl],
                                 (lay.q.start, *bounds)):
                out_of_range.append(lo)
        else:
            q = sb.q[sl]
            if not (np.all(q >= bounds[0]) and np.all(q <= bounds[1])):
                out_of_range.append(lo)
                return
            inp = pack_rows(est, sb, sl, table, pattern[sl], payload)
            sel = table.rows(pattern[sl])
            out[sl] = np.array([est._reference_row(row, sel.row(i))
                                for i, row in enumerate(inp)]).reshape(-1, lay.out_size)

    starts = range(0, n, size)
    if threaded:
        list(est._kernels.pool(threads).map(run, starts))
    else:
        for lo in starts:
            run(lo)
    if out_of_range:
        validate_batch(est, sb)  # raises, naming the first row and the range
    x = out[:, lay.out_x]
    xi = out[:, lay.out_xi]
    a = out[:, lay.out_a].reshape(-1, 3, 4)
    b = out[:, lay.out_b]
    cond = out[:, lay.out_cond]
    residual = out[:, lay.out_residual]
    points = out[:, lay.out_points].reshape(-1, 4, 3)
    # Each row's checksum is finite exactly when all its outputs are: one column to test.
    finite = bool(np.isfinite(out[:, lay.out_sum]).all())
    if not finite:
        check_finite_result("the normal-force systems", sb, a, b, xi)
    tip = table.tipping[pattern]
    mode = table.mode.astype(object)[pattern]
    singular = ~tip & ~(cond < SINGULAR_CONDITION)
    if strict and singular.any():
        i = int(np.flatnonzero(singular)[0])
        raise SingularSystemError(
            f"row {i}: {mode[i]} system is singular (1-norm condition "
            f"{cond[i]:.3g}); {int(singular.sum())} singular rows in all", cond[i])
    solved = np.flatnonzero(tip | singular)
    for i in solved:
        x[i], cond[i] = least_squares(a[i], b[i], ic[i].astype(float))
        residual[i] = a[i] @ x[i] - b[i]
    if not finite:
        check_finite_result("the normal forces", sb, x, residual, points)
    elif solved.size:  # the other rows are the kernel's, finite
        check_finite_result("the normal forces", sb, x[solved], residual[solved])
    # Without logged normals, the world z axis in fb for all four wheels: a read-only view.
    normals = sb.normal_in_fb if sb.normal_in_fb is not None else np.broadcast_to(
        sb.base_rotation[:, 2][:, None, :], (n, 4, 3))
    friction = sb.force_in_fb if sb.force_in_fb is not None else np.zeros((n, 4, 3))
    return BatchEstimate(x, ic.copy(), xi, cond, mode, tip, residual, points, a, b,
                         singular, est.backend, normals, friction)


def validate_batch(est, sb: StateBatch) -> None:
    """Raise `EstimatorInputError` for a stroke out of its chain's range in ``sb``.

    Shapes, finiteness and the rotations were checked when the `StateBatch` was built.
    (`estimate_batch` tests every row against `range_bounds` as it evaluates it, and calls
    this only when one leaves a range.)
    """
    for (name, unit, i, lo, hi), (_, lo_tol, hi_tol) in zip(est._ranges, est._bounds):
        x = sb.q[:, i]
        bad = ~((x >= lo_tol) & (x <= hi_tol))
        if bad.any():
            k = int(np.flatnonzero(bad)[0])
            raise EstimatorInputError(
                f"row {k} ({int(bad.sum())} rows in all): "
                + range_message(name, unit, i, float(x[k]), (lo, hi)))


def range_bounds(est) -> tuple[np.ndarray, np.ndarray]:
    """(lower, upper) bounds of q's coordinates, shape (13,) each, with the tolerance.

    +-inf where a coordinate has no range; the packer's widened bounds
    (`packing.RANGE_TOLERANCE`), as `validate_batch` and the per-state check use.
    Read-only, made once per set of bounds.
    """
    return _bounds_arrays(est._bounds)


@functools.lru_cache(maxsize=8)
def _bounds_arrays(bounds: tuple) -> tuple[np.ndarray, np.ndarray]:
    n = LAYOUT.q.stop - LAYOUT.q.start
    lower, upper = np.full(n, -np.inf), np.full(n, np.inf)
    for i, lo, hi in bounds:
        lower[i], upper[i] = max(lower[i], lo), min(upper[i], hi)
    lower.flags.writeable = upper.flags.writeable = False
    return lower, upper


def pack_rows(est, sb: StateBatch, sl: slice, table: fd.Selectors,
              pattern: np.ndarray, payload: np.ndarray | None = None) -> np.ndarray:
    """Kernel input rows (n, input size) of the states ``sl`` of a validated batch.

    ``table``: `full_dynamics.select_systems` of the 16 contact patterns (`_PATTERNS`);
    ``pattern``: each state's pattern (bit k: wheel k in contact), shape (rows of ``sl``,).
    """
    return assemble_rows(row_parts(est, sb, sl, table, pattern, payload), len(pattern))


def row_parts(est, sb: StateBatch, sl: slice, table: fd.Selectors,
              pattern: np.ndarray, payload: np.ndarray | None = None) -> list:
    """The kernel input of the states ``sl`` as `Compiled.gather` parts.

    In the layout's order (`_symbolic.Layout`): ``(array, None)`` per field (one row repeated
    where the batch has no such field), and ``(table's selector block (16, 16), pattern)``
    for the selectors (`pack_rows` has the arguments). ``payload``: every state's payload
    mass [kg], an (N, 1) column of the whole batch; None: the estimator's.
    """
    twist, acc, qd, qdd = (sb.base_twist[sl], sb.base_acceleration[sl], sb.qd[sl],
                           sb.qdd[sl])
    if est._qs is not None:
        twist, acc, qd, qdd = est._qs.apply(twist, acc, qd, qdd)
    no_point = sb.point_in_fb is None
    fields = (sb.base_rotation[sl], twist, acc, sb.q[sl], qd, qdd,
              _ZEROS12 if no_point else sb.point_in_fb[sl],
              _ZEROS4 if no_point else _ONES4,
              _ZEROS12 if sb.force_in_fb is None else sb.force_in_fb[sl],
              _ZEROS2 if sb.suspension_force is None else sb.suspension_force[sl],
              est._packer.payload if payload is None else payload[sl])
    parts = [(a, None) for a in fields]
    parts.insert(-2, (_selector_block(table, est.D, est.beta), pattern))
    return parts


def _payload_column(payload_mass, n: int) -> np.ndarray:
    """Each row's payload [kg] as the (n, 1) column `row_parts` reads, checked."""
    m = np.asarray(payload_mass, dtype=float)
    if m.shape != (n,):
        raise EstimatorInputError(f"payload_mass must have one mass per state, shape ({n},), "
                                  f"got {m.shape}")
    bad = ~((m >= 0.0) & (m <= MAX_PAYLOAD_MASS))  # NaN too
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise EstimatorInputError(f"payload_mass[{i}] = {m[i]!r} kg outside [0, "
                                  f"{MAX_PAYLOAD_MASS:g}] kg")
    return np.ascontiguousarray(m[:, None])


def _selector_block(table: fd.Selectors, d: float, beta: float) -> np.ndarray:
    """The 16 patterns' input columns from ``mask`` to ``beta``, shape (16, 16).

    In the layout's order, as `RowPacker.selectors` packs them for one state.
    """
    k = len(table.mask)
    return np.column_stack([table.mask, table.height_weights, table.s_dbeta,
                            table.s_cylinder, table.lost, np.full(k, d), np.full(k, beta)])


def as_batch(states) -> StateBatch:
    """``states`` as a validated `StateBatch`; a bad field is an `EstimatorInputError`."""
    if isinstance(states, StateBatch):
        return states
    try:
        if isinstance(states, Mapping):
            return StateBatch(**states)
        if isinstance(states, Sequence) or hasattr(states, "__iter__"):
            return StateBatch.from_states(list(states))
    except (TypeError, ValueError) as exc:
        raise EstimatorInputError(f"bad state log fields: {exc}") from exc
    except StateError as exc:
        raise EstimatorInputError(str(exc)) from exc
    raise EstimatorInputError(f"cannot read states from a {type(states).__name__}")
