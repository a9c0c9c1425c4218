"""The QP's linear term ``q`` in C: every task's ``c`` and their sum in one call per tick.

`wbc.qp.QPBuilder` sums the active tasks' ``c = J^T W e`` in task order, ``q = +0 + c_1 +
c_2 + ...``. With constant Jacobians (`ConstantJacobianTask`) only ``e`` moves from tick
to tick, and the MPC's terms are a few small numpy operations each, mostly call overhead
in the closed loop (~30 us a tick for seven tasks). A task that can say its term as one of
the kinds below hands the builder a `LinearTerm` (`Task.linear_term`) instead; the builder
runs them all with `LinearProgram`: one ctypes call that writes each term's ``c`` as numpy
would and adds it into ``q`` in the same order.

Each kind is the arithmetic of its task's numpy ``_linear_term``, operation for operation
(IEEE operations in the source's order, compiled without fused multiply-adds:
`models.cbuild`), and each product of a matrix and a vector is numpy's own ``cblas_dgemv``
with the arguments ``matmul`` passes (`models.numpy_blas`): the same bits.

* ``CONSTANT``: a read-only ``c`` (`SpeedScaleTask`, `SlackPenaltyTask`).
* ``TRACKING``: ``(J^T W) e``, ``e`` the zero-input prediction minus the reference at nodes
  1..N on some axes, positions then velocities (`HorizonTrackingTask`).
* ``INPUT``: ``w * -a_ref`` on the accelerations, zeros elsewhere (`HorizonInputTask`).
* ``SMOOTHNESS``: ``-u_prev * w`` on step 0's inputs, zeros elsewhere
  (`HorizonSmoothnessTask`).
* ``LEVELING``: ``(J^T W) e``, ``e = (q_free - q_0) row + drift / F_s - offset / F_s``
  (`HorizonLevelingTask`).

The context's arrays go to the C as objects, their shapes, order and type checked there
(`wbc.tasks.object_fields_c`). The numpy path (each task's ``compute_qp_objective``) stays
the reference and the fallback without a compiler or numpy's OpenBLAS
(`tests/test_linear_c.py` compares them on real ticks, bit for bit).
"""

from __future__ import annotations

import copy
import ctypes
import functools
import operator
from dataclasses import dataclass

import numpy as np

from models.cbuild import address, bind, compile_shared, load_shared
from models.numpy_blas import numpy_blas
from wbc.tasks.object_fields_c import ARRAY_FIELDS_C, fields_readable

__all__ = ["CONSTANT", "INPUT", "LEVELING", "LINEAR_C", "SMOOTHNESS", "TRACKING",
           "LinearProgram", "LinearTerm", "available"]

CONSTANT, TRACKING, INPUT, SMOOTHNESS, LEVELING = range(5)
_N_ARRAYS = {CONSTANT: 1, TRACKING: 1, INPUT: 1, SMOOTHNESS: 1, LEVELING: 3}
_HORIZON = {TRACKING, INPUT, SMOOTHNESS, LEVELING}  # kinds that read the context's arrays

LINEAR_C = ARRAY_FIELDS_C + r"""
#include <string.h>
typedef void (*gemv_fn)(int, int, long long, long long, double, const double*, long long,
                        const double*, long long, double, double*, long long);
enum { CONSTANT, TRACKING, INPUT, SMOOTHNESS, LEVELING };

/* matmul's product of A (rows, cols) and x: its cblas_dgemv call for either order.
   C-ordered: column-major, transposed, lda = cols; Fortran-ordered: row-major,
   transposed, lda = rows. */
static void matvec(gemv_fn gemv, long long fortran, long long rows, long long cols,
                   const double* A, const double* x, double* y) {
  memset(y, 0, (size_t)rows * sizeof(double));
  if (fortran) gemv(101, 112, cols, rows, 1.0, A, rows, x, 1, 0.0, y, 1);
  else gemv(102, 112, cols, rows, 1.0, A, cols, x, 1, 0.0, y, 1);
}

/* prog: the number of terms, then per term its kind and integers (see LinearProgram);
   cp: per term its arrays; in: free positions, free velocities (N, A), the reference's
   positions, velocities, accelerations (N + 1, A), previous acceleration, q0 (A), warp
   drift (N + 1) or NULL. q (n) = +0 + c_1 + c_2 + ..., c: scratch (n), e: scratch. */
void linear_terms(const long long* prog, const double* const* cp, gemv_fn gemv, long long n,
                  double* c, double* e, const double* fp, const double* fv,
                  const double* rp, const double* rv, const double* ra, const double* up,
                  const double* q0, const double* drift, double offset, double* q) {
  long long t, i, n_terms = *prog++;
  for (i = 0; i < n; ++i) q[i] = 0.0;
  for (t = 0; t < n_terms; ++t) {
    long long kind = *prog++;
    const double* own = c;
    if (kind == CONSTANT) {
      own = *cp++;
    } else if (kind == TRACKING) {  /* HorizonTrackingTask._linear_term */
      long long N = prog[0], A = prog[1], k = prog[2], fortran = prog[3], s, j;
      const long long* col = prog + 4;
      const double* jw = *cp++;
      double* ev = e;
      for (s = 0; s < N; ++s)
        for (j = 0; j < k; ++j) *ev++ = fp[s * A + col[j]] - rp[(s + 1) * A + col[j]];
      for (s = 0; s < N; ++s)
        for (j = 0; j < k; ++j) *ev++ = fv[s * A + col[j]] - rv[(s + 1) * A + col[j]];
      matvec(gemv, fortran, n, 2 * N * k, jw, e, c);
      prog += 4 + k;
    } else if (kind == INPUT) {  /* HorizonInputTask._linear_term */
      long long start = prog[0], count = prog[1];
      const double* w = *cp++;
      memset(c, 0, (size_t)n * sizeof(double));
      for (i = 0; i < count; ++i) c[start + i] = w[i] * -ra[i];
      prog += 2;
    } else if (kind == SMOOTHNESS) {  /* HorizonSmoothnessTask._linear_term */
      long long start = prog[0], count = prog[1];
      const double* w = *cp++;
      memset(c, 0, (size_t)n * sizeof(double));
      for (i = 0; i < count; ++i) c[start + i] = -up[i] * w[start + i];
      prog += 2;
    } else {  /* LEVELING: HorizonLevelingTask.compute_error, then (J^T W) e */
      long long N = prog[0], A = prog[1], fortran = prog[2], s, a;
      const double *row = cp[0], *jw = cp[1], fs = cp[2][0];
      double* d = e + N;
      cp += 3;
      for (s = 0; s < N; ++s)
        for (a = 0; a < A; ++a) d[s * A + a] = fp[s * A + a] - q0[a];
      matvec(gemv, 0, N, A, d, row, e);
      if (drift)
        for (s = 0; s < N; ++s) e[s] += drift[s + 1] / fs;
      for (s = 0; s < N; ++s) e[s] -= offset / fs;
      matvec(gemv, fortran, n, N, jw, e, c);
      prog += 3;
    }
    for (i = 0; i < n; ++i) q[i] += own[i];
  }
}

/* linear_terms with the context's arrays as objects, checked here: 1 (nothing written)
   when one is not what the program reads, else 0. q: a writable (n,) array. */
int linear_objects(const long long* prog, const double* const* cp, gemv_fn gemv,
                   long long n, double* c, double* e, const void* ndarray, const void* none,
                   long long N, long long A, const void* fp, const void* fv,
                   const void* rp, const void* rv, const void* ra, const void* up,
                   const void* q0, const void* drift, double offset, const void* q) {
  const char *d_fp = array_data(fp, ndarray, 2, N, A), *d_fv = array_data(fv, ndarray, 2, N, A);
  const char *d_rp = array_data(rp, ndarray, 2, N + 1, A);
  const char *d_rv = array_data(rv, ndarray, 2, N + 1, A);
  const char *d_ra = array_data(ra, ndarray, 2, N + 1, A);
  const char *d_up = array_data(up, ndarray, 1, A, 0), *d_q0 = array_data(q0, ndarray, 1, A, 0);
  const char* d_drift = drift == none ? 0 : array_data(drift, ndarray, 1, N + 1, 0);
  char* d_q = array_data(q, ndarray, 1, n, 0);
  if (!(d_fp && d_fv && d_rp && d_rv && d_ra && d_up && d_q0 && d_q)
      || (drift != none && !d_drift) || !(((const np_array*)q)->flags & WRITEABLE))
    return 1;
  linear_terms(prog, cp, gemv, n, c, e, (const double*)d_fp, (const double*)d_fv,
               (const double*)d_rp, (const double*)d_rv, (const double*)d_ra,
               (const double*)d_up, (const double*)d_q0, (const double*)d_drift, offset,
               (double*)d_q);
  return 0;
}
"""

_P, _O = ctypes.c_void_p, ctypes.py_object


def _library():
    return load_shared(LINEAR_C, "linear_terms",
                       {"linear_terms": ([_P, _P, _P, ctypes.c_longlong, _P, _P, _P, _P, _P,
                                          _P, _P, _P, _P, _P, ctypes.c_double, _P], None)},
                       "the tasks' numpy linear terms")


@functools.cache
def available() -> bool:
    """Whether `LINEAR_C` compiles here and numpy's BLAS is the one it calls (once)."""
    return numpy_blas() is not None and _library() is not None


@functools.cache
def _objects_function():
    """``linear_objects`` (the context's arrays passed as objects), or None.

    Loaded as a `ctypes.PyDLL` function (it reads Python objects: the GIL held), and only
    where `object_fields_c.fields_readable` (numpy's array fields where the C reads them):
    else the arrays' addresses are taken in Python (`LinearProgram.__call__`).
    """
    if _library() is None or not fields_readable():
        return None
    py = ctypes.PyDLL(str(compile_shared(LINEAR_C, "linear_terms")))  # the same file
    fun = py.linear_objects
    fun.argtypes = [_P, _P, _P, ctypes.c_longlong, _P, _P, _P, _P, ctypes.c_longlong,
                    ctypes.c_longlong, *[_O] * 8, ctypes.c_double, _O]
    fun.restype = ctypes.c_int
    return fun


@dataclass(frozen=True, eq=False)
class LinearTerm:
    """One task's ``(H, c)`` with ``c`` said as a kind of `LINEAR_C` (`Task.linear_term`).

    A task returns the same object while the numbers it was made from stay (its cache):
    `wbc.qp.QPBuilder` keeps its program while the terms are the same objects.

    Attributes:
        kind: `CONSTANT`, `TRACKING`, `INPUT`, `SMOOTHNESS` or `LEVELING`.
        H: The task's read-only Hessian (n, n).
        ints: The kind's integers: `TRACKING` the task's axis columns; `INPUT` and
            `SMOOTHNESS` the first entry of x they write and how many; else none.
        arrays: The kind's arrays: `CONSTANT` ``c`` (n,); `TRACKING` ``J^T W`` (n, 2 N k);
            `INPUT` the weights (N A,); `SMOOTHNESS` the weights (N A,); `LEVELING` the
            row (A,), ``J^T W`` (n, N) and ``[F_s]``.
        guard: What the task's activity and this term depend on besides the context's
            ``structure_key``: attribute paths of the context (``"ctx.warp"``) and of the
            task (``"task.weight"``). While each is the same object (an array also still
            read-only) and the structure key is equal, the task is active and returns
            this term: `wbc.qp.QPBuilder` then does not ask it. None: ask every tick.
    """

    kind: int
    H: np.ndarray
    ints: tuple = ()
    arrays: tuple = ()
    guard: tuple | None = None


class LinearProgram:
    """The terms of the active tasks in order, run in one call: ``q`` of `QPBuilder.build`.

    Made by `make` when every term fits the layout (else None: the numpy path). Checks the
    context's arrays each tick (the C reads them unchecked): passed as objects and checked
    in C where `object_fields_c.fields_readable`, else their shapes, types and addresses
    taken in Python.
    """

    def __init__(self, lib, gemv: int, terms: tuple, layout):
        self.terms, self.layout = terms, layout
        lay = layout
        n, N, A = lay.n, lay.n_steps, lay.n_axes
        self.n, self.horizon = n, any(t.kind in _HORIZON for t in terms)
        # (shape, dtype) of the context's arrays, in `_inputs`'s order
        self._meta = [((N, A), _F8)] * 2 + [((N + 1, A), _F8)] * 3 + [((A,), _F8)] * 2 \
            + [((N + 1,), _F8)]
        prog, arrays, scratch = [len(terms)], [], N
        for t in terms:
            if t.kind == TRACKING:  # J^T W F- or C-ordered, as the task's product reads it
                k, jw = len(t.ints), t.arrays[0]
                prog += [TRACKING, N, A, k, int(jw.flags.f_contiguous), *t.ints]
                scratch = max(scratch, 2 * N * k)
            elif t.kind == LEVELING:
                prog += [LEVELING, N, A, int(t.arrays[1].flags.f_contiguous)]
                scratch = max(scratch, N + N * A)
            elif t.kind in (INPUT, SMOOTHNESS):
                prog += [t.kind, *t.ints]
            else:
                prog += [CONSTANT]
            arrays += t.arrays  # read as they are at each tick (`_fits`: no copies)
        self._prog = np.array(prog, np.int64)
        self._arrays = arrays  # kept alive: the table holds their addresses
        self._table = np.array([a.ctypes.data for a in arrays] or [0], np.uint64)
        self._c, self._e = np.zeros(n), np.zeros(max(scratch, 1))
        self._lib, self._gemv = lib, gemv
        self._call = bind(lib.linear_terms, self._prog, self._table, gemv, n, self._c,
                          self._e)
        objects = _objects_function()
        self._objects = None if objects is None else bind(
            objects, self._prog, self._table, gemv, n, self._c, self._e, id(np.ndarray),
            id(None), N, A)

    @classmethod
    def make(cls, terms: tuple, layout) -> LinearProgram | None:
        """The program of ``terms`` on ``layout``, or None (the numpy path).

        None without a compiler or numpy's OpenBLAS, or when a term does not fit the layout
        (the numpy path then says what is wrong).
        """
        if not all(_fits(t, layout) for t in terms) or not available():
            return None
        return cls(_library(), numpy_blas()[0], terms, layout)

    def __deepcopy__(self, memo) -> LinearProgram:
        """A program of its own: its call bound to its own buffers."""
        new = LinearProgram(self._lib, self._gemv, copy.deepcopy(self.terms, memo),
                            copy.deepcopy(self.layout, memo))
        memo[id(self)] = new
        return new

    def __call__(self, ctx) -> np.ndarray | None:
        """``q`` at ``ctx`` (a new array); None when a context array has another shape."""
        q = np.empty(self.n)
        if not self.horizon:
            self._call(None, None, None, None, None, None, None, None, 0.0, address(q))
            return q
        arrays = _inputs(ctx)
        if self._objects is not None:
            return None if self._objects(*arrays, float(ctx.leveling_offset), q) else q
        drift = arrays[7]
        if drift is None:
            arrays = arrays[:7]
        try:
            if list(map(_shape_and_type, arrays)) != self._meta[:len(arrays)]:
                return None
            pointers = list(map(ctypes.addressof, map(_char_view, arrays)))
        except (AttributeError, TypeError, ValueError, BufferError):
            try:  # read-only or strided arrays
                pointers = [_address(a) for a in arrays]
            except (AttributeError, TypeError, ValueError, BufferError):
                return None  # not float64 arrays in C order: the numpy path
        if drift is None:
            pointers.append(None)
        self._call(*pointers, float(ctx.leveling_offset), address(q))
        return q


_F8 = np.dtype(np.float64)
_char_view = ctypes.c_char.from_buffer
_shape_and_type = operator.attrgetter("shape", "dtype")
_inputs = operator.attrgetter("free_positions", "free_velocities", "reference.position",
                              "reference.velocity", "reference.acceleration",
                              "previous_acceleration", "q", "warp_drift")


def _address(a: np.ndarray) -> int:
    """The address of ``a``'s data, a C-ordered float64 array (else TypeError, ValueError).

    A writable array's through a ctypes view of its buffer (`models.cbuild.address`: that
    view needs the C order), a read-only one's checked and then ``a.ctypes.data``.
    """
    if a.dtype != _F8:
        raise TypeError("not a float64 array")
    try:
        return ctypes.addressof(_char_view(a))
    except TypeError:  # read-only
        if not a.flags.c_contiguous:
            raise ValueError("not in C order") from None
        return a.ctypes.data


def _fits(t: LinearTerm, layout) -> bool:
    """Whether term ``t``'s arrays and integers fit ``layout`` (the C reads them unchecked).

    Its arrays aligned native float64 in one block (a 1-D one C-ordered; a ``J^T W`` in
    either order).
    """
    n, N, A = layout.n, layout.n_steps, layout.n_axes
    a = t.arrays
    if (not isinstance(t, LinearTerm) or len(a) != _N_ARRAYS.get(t.kind, -1)
            or not all(isinstance(x, np.ndarray) and x.dtype == _F8 and x.flags.aligned
                       and (x.flags.c_contiguous or x.flags.f_contiguous) for x in a)
            or t.H.shape != (n, n) or t.H.flags.writeable):
        return False
    if t.kind == CONSTANT:
        return a[0].shape == (n,) and not t.ints
    if t.kind == TRACKING:
        k = len(t.ints)
        return (k > 0 and all(0 <= i < A for i in t.ints) and a[0].shape == (n, 2 * N * k)
                and (a[0].flags.c_contiguous or a[0].flags.f_contiguous))
    if t.kind in (INPUT, SMOOTHNESS):
        if len(t.ints) != 2 or a[0].shape != (N * A,):
            return False
        start, count = t.ints
        limit = N * A if t.kind == INPUT else A  # the accelerations; step 0's inputs
        return 0 <= start and 0 <= count <= limit and start + count <= min(n, N * A)
    return (t.kind == LEVELING and not t.ints and a[0].shape == (A,)
            and a[1].shape == (n, N) and a[2].shape == (1,)
            and (a[1].flags.c_contiguous or a[1].flags.f_contiguous))
