"""Linearizations of states along a trajectory in one compiled call (a controller's nodes).

A controller linearizes the model at a few states of a nominal trajectory every tick (the
MPC's nodes): the state now moved on by ``dt``, with other base rotations and coordinates,
the same contacts, measurements and payload, no accelerations. One
`NormalForceEstimator.linearize` per node spends more in Python (a `MachineState`, its range
check and packing, the call, the checks) than in the kernel. `linearize_states` packs the
state now once; `NODES_C` makes each node's input row from it, checks its coordinates'
ranges, calls the derivative kernel and checks its output row, in one C loop (the same
kernel on the same input rows: the bits of one call per state). What it does not cover (no
compiled kernel, the quasi-static method, a tipping contact pattern, a coordinate out of its
range, a singular or non-finite row) it leaves to `NormalForceEstimator.linearize`, state by
state, which clips, counts or raises as it does. `linearize_rows` is the same loop with the
base rotations predicted in it and the rows left in their buffer, for a caller that reads
them by their offsets (the MPC's force map: no Python object per node).
"""

from __future__ import annotations

import ctypes
from collections.abc import Callable

import numpy as np

from estimators._kernel_calls import Compiled
from estimators._row_views import LINEARIZATION_VIEWS, ROW_CHECKS
from estimators._symbolic import LAYOUT
from estimators.batch import SINGULAR_CONDITION, range_bounds
from estimators.linearization import ForceLinearization
from models.cbuild import bind, load_shared
from models.state import MachineState

__all__ = ["NODES_C", "library", "linearize_first", "linearize_rows", "linearize_states",
           "prepare_rows"]

NODES_C = r"""
#include <float.h>
#include <math.h>
typedef long long ci;
typedef int (*kernel_t)(const double** arg, double** res, ci* iw, double* w, int mem);
enum { N, N_IN, N_OUT, M, NQ, SZ_ARG, SZ_RES, ROT, ACC, N_ACC, Q, QD, QDD, COND, SUM, TWIST,
       PREDICT, FIRST };

/* rot = r0 exp(w t), row-major (9): the rotation of pinocchio's `SE3(r0, p) * exp6(twist t)`
   (`wbc.mpc.prediction.predict_base_rotations`) to the bit: exp6's rotation as
   `pinocchio/spatial/explog.hxx` writes it, the product's sums in the order of pinocchio's
   Eigen build (rows 0 and 1 left to right, row 2 its last two products first). */
static void rotation_at(const double* r0, const double* w, double t, double* rot) {
  const double v[3] = {w[0] * t, w[1] * t, w[2] * t};
  const double t2 = (v[0] * v[0] + v[1] * v[1]) + v[2] * v[2] + DBL_EPSILON * DBL_EPSILON;
  const double th = sqrt(t2), taylor = pow(DBL_EPSILON, 1.0 / 4.0);
  double a_wxv, a_v, diag, e[3][3];
  int i, j;
  if (th < taylor) {
    a_wxv = 0.5 - t2 / 24; a_v = 1.0 - t2 / 6; diag = 1.0 - t2 / 2;
  } else {
    const double ct = cos(th);
    a_wxv = (1.0 - ct) * (1.0 / t2); a_v = sin(th) / th; diag = ct;
  }
  for (i = 0; i < 3; ++i)
    for (j = 0; j < 3; ++j) e[i][j] = (a_wxv * v[i]) * v[j];
  e[0][1] -= a_v * v[2]; e[1][0] += a_v * v[2];
  e[0][2] += a_v * v[1]; e[2][0] -= a_v * v[1];
  e[1][2] -= a_v * v[0]; e[2][1] += a_v * v[0];
  e[0][0] += diag; e[1][1] += diag; e[2][2] += diag;
  for (i = 0; i < 2; ++i)
    for (j = 0; j < 3; ++j)
      rot[3 * i + j] = (r0[3 * i] * e[0][j] + r0[3 * i + 1] * e[1][j]) + r0[3 * i + 2] * e[2][j];
  for (j = 0; j < 3; ++j)
    rot[6 + j] = r0[6] * e[0][j] + (r0[7] * e[1][j] + r0[8] * e[2][j]);
}

/* Row k: the template row with the base rotation rot[k] (9) (with iv[PREDICT], the
   template's rotation moved on at its angular velocity for dt[k], `rotation_at`, written to
   rot[k] first), no
   accelerations, coordinates 0..m-1 and their velocities qa[k], va[k], the others moved on
   at their velocities: q + dt[k] * qd (the template's). With iv[FIRST], the template row
   itself first (its q replaced by q0 where iv[FIRST] is 2: clipped), out's row 0, and the
   n rows after it. Returns 0; -2: row k's q leaves [lo, hi] (k not evaluated); -3: row k's
   output is not finite or its condition not below max_cond; -4: so is the template's
   (nothing else evaluated). p: template, rot, qa, va, dt, lo, hi, q0. */
int linearize_rows(kernel_t f, const double* const* p, const ci* iv, const double* max_cond,
                   double* out, ci* iw, double* w) {
  const ci n = iv[N], n_in = iv[N_IN], n_out = iv[N_OUT], m = iv[M], nq = iv[NQ];
  const double *tmpl = p[0], *qa = p[2], *va = p[3], *dt = p[4];
  const double *lo = p[5], *hi = p[6], *q0 = p[7];
  double* rot = (double*)p[1];
  double row[n_in];
  const double* arg[iv[SZ_ARG]];
  double* res[iv[SZ_RES]];
  ci k, c;
  for (c = 0; c < n_in; ++c) row[c] = tmpl[c];
  arg[0] = row;
  if (iv[FIRST]) {  /* the state itself, with its accelerations */
    if (iv[FIRST] == 2)
      for (c = 0; c < nq; ++c) row[iv[Q] + c] = q0[c];
    res[0] = out;
    if (f(arg, res, iw, w, 0)) return -4;
    if (!(isfinite(out[iv[SUM]]) && out[iv[COND]] < max_cond[0])) return -4;
    out += n_out;
  }
  for (c = 0; c < iv[N_ACC]; ++c) row[iv[ACC] + c] = 0.0;
  for (c = 0; c < nq; ++c) row[iv[QDD] + c] = 0.0;
  for (k = 0; k < n; ++k) {
    double* q = row + iv[Q];
    double* qd = row + iv[QD];
    double* o = out + k * n_out;
    if (iv[PREDICT]) rotation_at(tmpl + iv[ROT], tmpl + iv[TWIST] + 3, dt[k], rot + k * 9);
    for (c = 0; c < 9; ++c) row[iv[ROT] + c] = rot[k * 9 + c];
    for (c = 0; c < m; ++c) { q[c] = qa[k * m + c]; qd[c] = va[k * m + c]; }
    for (c = m; c < nq; ++c) q[c] = tmpl[iv[Q] + c] + dt[k] * tmpl[iv[QD] + c];
    for (c = 0; c < nq; ++c)
      if (!(q[c] >= lo[c] && q[c] <= hi[c])) return -2;
    res[0] = o;
    if (f(arg, res, iw, w, 0)) return -3;
    if (!(isfinite(o[iv[SUM]]) && o[iv[COND]] < max_cond[0])) return -3;
  }
  return 0;
}
"""
_IV = ("n", "n_in", "n_out", "m", "nq", "sz_arg", "sz_res", "rot", "acc", "n_acc", "q", "qd",
       "qdd", "cond", "sum", "twist", "predict", "first")
_PREDICT, _FIRST = _IV.index("predict"), _IV.index("first")
_ALL_IN = np.ones(4, bool)


class _Nodes:
    """One thread's buffers for up to ``capacity`` rows of ``m`` given coordinates.

    The template row, the rows' inputs (``rot``: the base rotations given, or those the C
    predicted; ``q0``: the state's clipped coordinates) and outputs (one row more, for the
    state itself), and the C call bound to them.
    """

    def __init__(self, lib, kernel, capacity: int, m: int):
        lay = LAYOUT
        nq = lay.q.stop - lay.q.start
        self.capacity, self.m = capacity, m
        self.template = np.zeros(lay.size)
        self.raw = memoryview(self.template).cast("B")
        self.rot = np.zeros((capacity, 3, 3))
        self.qa, self.va = np.zeros((capacity, m)), np.zeros((capacity, m))
        self.dt = np.zeros(capacity)
        self.q0 = np.zeros(nq)
        self.out = np.zeros((capacity + 1, lay.der_size))
        cond, total = ROW_CHECKS["nf_derivatives"]
        self.iv = np.array([capacity, lay.size, lay.der_size, m, nq, kernel.sz_arg,
                            kernel.sz_res, lay.rotation.start, lay.acceleration.start,
                            lay.acceleration.stop - lay.acceleration.start, lay.q.start,
                            lay.qd.start, lay.qdd.start, cond, total, lay.twist.start, 0,
                            0], np.int64)
        self.max_cond = np.array([SINGULAR_CONDITION])
        self.ranges = self.bounds = None  # an estimator's ``_bounds``, `range_bounds`
        self._lib, self._kernel = lib, kernel

    def bound(self, est) -> Callable[[], int]:
        """The C call on these buffers for ``est``'s coordinate ranges."""
        if self.ranges is not est._bounds:
            self.ranges, self.bounds = est._bounds, range_bounds(est)  # kept: pointed at
            arrays = (self.template, self.rot, self.qa, self.va, self.dt, *self.bounds,
                      self.q0)
            self.pointers = (ctypes.c_void_p * len(arrays))(*(a.ctypes.data for a in arrays))
            iw, w = self._kernel.workspace()
            self.call = bind(self._lib.linearize_rows, self._kernel.address, self.pointers,
                             self.iv, self.max_cond, self.out, iw, w)
        return self.call


def library():
    """`NODES_C` compiled and loaded (once per process); None without a compiler."""
    return load_shared(NODES_C, "linearize_rows", {"linearize_rows": (
        [ctypes.c_void_p] * 7, ctypes.c_int)}, "one linearization per state", "-O2")


def linearize_states(est, state: MachineState, dt: np.ndarray, rotation: np.ndarray,
                     q_head: np.ndarray, qd_head: np.ndarray) -> list[ForceLinearization] | None:
    """``est.linearize`` of ``state`` moved on by ``dt[k]`` to other poses and coordinates.

    State k: ``state``'s time plus ``dt[k]``, base rotation ``rotation[k]``, the first m
    coordinates and velocities ``q_head[k]``, ``qd_head[k]``, the other coordinates moved on
    at their velocities (``q + dt[k] qd``), no base acceleration and no ``qdd``; the twist,
    contacts and measurements ``state``'s. The linearizations are those of
    `NormalForceEstimator.linearize` (their arrays the kernel's bits, views of one read-only
    block of rows).

    Args:
        est: A `NormalForceEstimator`.
        state: The validated state the nodes move on from.
        dt: Time after ``state`` [s], shape (n,).
        rotation: Base rotations (world <- fb), shape (n, 3, 3).
        q_head: The first m coordinates, shape (n, m).
        qd_head: Their velocities, shape (n, m).

    Returns:
        The n linearizations, or None (nothing counted or kept) for what `est.linearize`
        must do state by state (the module docstring).
    """
    done = _evaluate(est, state, dt, rotation, q_head, qd_head)
    if done is None:
        return None
    rows, sel, flags, _ = done
    rows = rows.copy()
    rows.flags.writeable = False
    mode = sel.mode
    return [ForceLinearization.from_row(
        {"in_contact": flags, "mode": mode, "clipped": (), "time": t},
        LINEARIZATION_VIEWS, rows[k]) for k, t in enumerate((state.time + dt).tolist())]


def linearize_rows(est, state: MachineState, dt: np.ndarray, q_head: np.ndarray,
                   qd_head: np.ndarray) -> np.ndarray | None:
    """The kernel rows of `linearize_states` with the base at its constant twist, or None.

    The base rotation of state k is ``state``'s moved on at its angular velocity for
    ``dt[k]``, computed in the C loop with the bits of pinocchio's
    ``SE3(R, p) * exp6(twist dt)`` (`wbc.mpc.prediction.predict_base_rotations`, the MPC's
    nominal base; `tests/test_linearize_batch.py` compares them). For a caller that reads
    the rows by their offsets (`LINEARIZATION_VIEWS`): no `ForceLinearization` per state.

    Returns:
        The n output rows of the derivative kernel, shape (n, der_size): a view of this
        thread's kept buffer, valid until its next call (the caller copies what it keeps);
        None as for `linearize_states`.
    """
    done = _evaluate(est, state, dt, None, q_head, qd_head)
    return None if done is None else done[0]


def linearize_first(est, state: MachineState, dt: np.ndarray, q_head: np.ndarray,
                    qd_head: np.ndarray) -> tuple[ForceLinearization, np.ndarray | None] | None:
    """``est.linearize(state)`` and the rows of `linearize_rows`, in one C call.

    The state itself is the loop's first row: its input row is the one `est.linearize`
    packs (the same template; coordinates outside their ranges clipped as the estimator's
    ``strokes="clip"`` policy does, counted in its ``n_clipped``), evaluated by the same
    kernel: its `ForceLinearization` is `est.linearize`'s, bit for bit.

    Returns:
        (the state's linearization, the n later rows (a view of the kept buffer, valid until
        the next call) or None where `linearize_rows` gives None: the later states then
        go one by one). None, with nothing counted, where ``est.linearize`` must take the
        state (no compiled kernel, the quasi-static method, tipping, a coordinate out of
        range under ``strokes="raise"``, a singular or non-finite row: it raises or solves).
    """
    if not isinstance(state, MachineState):
        return None
    values = state.q.tolist()
    for i, lo, hi in est._bounds:  # `NormalForceEstimator._checked`'s test
        if not lo <= values[i] <= hi:
            if est.strokes == "raise":
                return None
            q0, clipped = est._packer.clipped(state.q)
            break
    else:
        q0, clipped = None, ()
    done = _evaluate(est, state, dt, None, q_head, qd_head, 1 if q0 is None else 2, q0)
    if done is None:
        return None
    out, sel, flags, status = done
    if status == -4:  # the state's own row: `est.linearize` says why
        return None
    if q0 is not None:
        est.n_clipped += 1
    # a read-only copy of the row, as `NormalForceEstimator.linearize` makes it
    first = ForceLinearization.from_row(
        {"in_contact": flags, "mode": sel.mode, "clipped": clipped, "time": state.time},
        LINEARIZATION_VIEWS, np.frombuffer(out[0].tobytes()))
    return first, (out[1:] if status == 0 else None)


def prepare_rows(est, n: int, m: int) -> tuple | None:
    """Make this thread's buffers and C call for `linearize_first` of n states now.

    What the first call with n states of m given coordinates makes (`_Nodes`, bound to
    ``est``'s coordinate ranges), made before a controller's clock starts; nothing is
    counted or kept of a state. The buffers are the first call's: ``capacity``
    ``max(n, 1)`` unless this thread has some for n already. The C call runs once on what
    the buffers hold (new ones: zeros, a row of no state and no rotation: a status, no
    rows): the kernel's first run is paid here, not by the first tick (measured in the MPC's
    benchmark: its call 0.17 ms at the first tick without, 0.05 ms with, 0.03 ms hot); what
    it writes (the output rows, the kernel's workspace) every call writes before it reads,
    its inputs untouched.
    Also the packer's selectors of a state with every wheel in contact, with and without
    suspension forces (`RowPacker.selectors`, a memo of `full_dynamics.select_system`: the
    likely first states; another contact pattern makes its own at its first call).

    Returns:
        ``(views, width)``: the `RowViews` and width of the kernel rows that
        `linearize_first` and `linearize_rows` give (`LINEARIZATION_VIEWS`); None where
        they give none (no compiled kernel, the quasi-static method).
    """
    nodes = _nodes(est, n, m)
    if nodes is None:
        return None
    nodes.bound(est)()  # the kernel's first run, before the clock (see above)
    for suspension_force in (False, True):
        est._packer.selectors(_ALL_IN, suspension_force, est.D, est.beta)
    return LINEARIZATION_VIEWS, nodes.out.shape[1]


def _nodes(est, n: int, m: int) -> _Nodes | None:
    """This thread's `_Nodes` for n states of m coordinates (made if it has none that fit).

    None: no compiled kernel or loop here (`_evaluate` leaves the states to ``est``).
    """
    if est.backend != "compiled" or est._qs is not None:
        return None
    calls = est._calls.__dict__
    nodes = calls.get("linearize_rows")
    if nodes is None or nodes.capacity < n or nodes.m != m:
        lib = library()
        if lib is None:
            return None
        kernel = est._kernels.kernel("nf_derivatives")
        if not isinstance(kernel, Compiled):  # it did not compile: CasADi's VM
            return None
        nodes = calls["linearize_rows"] = _Nodes(lib, kernel, max(n, 1), m)
    return nodes


def _evaluate(est, state: MachineState, dt: np.ndarray, rotation: np.ndarray | None,
              q_head: np.ndarray, qd_head: np.ndarray, first: int = 0,
              q0: np.ndarray | None = None) -> tuple | None:
    """(kept output rows, `Selectors`, contact flags, C status) of the n states, or None.

    ``rotation`` None: each state's rotation predicted in C (`linearize_rows`). ``first``
    1: the state itself first (out's row 0, then the n states), 2: with its coordinates
    ``q0`` (`linearize_first`). None: nothing evaluated; without ``first``, also a nonzero
    status.
    """
    n, m = q_head.shape
    if n + first == 0:
        return None
    nodes = _nodes(est, n, m)
    if nodes is None:
        return None
    sel, flags = est._pack(nodes.template, state, est.D, est.beta, nodes.raw)
    if sel.tipping:
        return None
    iv = nodes.iv
    iv[_FIRST] = bool(first) + (q0 is not None)
    if q0 is not None:
        nodes.q0[:] = q0
    if rotation is None:
        iv[_PREDICT] = 1
    else:
        iv[_PREDICT] = 0
        nodes.rot[:n] = rotation
    nodes.qa[:n] = q_head
    nodes.va[:n] = qd_head
    nodes.dt[:n] = dt
    iv[0] = n
    status = nodes.bound(est)()
    if status != 0 and not first:
        return None
    return nodes.out[:n + bool(first)], sel, flags, status
