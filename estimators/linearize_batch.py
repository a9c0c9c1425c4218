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
state, which clips, counts or raises as it does.
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

__all__ = ["NODES_C", "library", "linearize_states"]

NODES_C = r"""
#include <math.h>
typedef long long ci;
typedef int (*kernel_t)(const double** arg, double** res, ci* iw, double* w, int mem);
enum { N, N_IN, N_OUT, M, NQ, SZ_ARG, SZ_RES, ROT, ACC, N_ACC, Q, QD, QDD, COND, SUM };

/* Row k: the template row with the base rotation rot[k] (9), no accelerations, coordinates
   0..m-1 and their velocities qa[k], va[k], the others moved on at their velocities:
   q + dt[k] * qd (the template's). Returns 0; -2: row k's q leaves [lo, hi] (k not
   evaluated); -3: row k's output is not finite or its condition not below max_cond.
   p: template, rot, qa, va, dt, lo, hi. */
int linearize_rows(kernel_t f, const double* const* p, const ci* iv, const double* max_cond,
                   double* out, ci* iw, double* w) {
  const ci n = iv[N], n_in = iv[N_IN], n_out = iv[N_OUT], m = iv[M], nq = iv[NQ];
  const double *tmpl = p[0], *rot = p[1], *qa = p[2], *va = p[3], *dt = p[4];
  const double *lo = p[5], *hi = p[6];
  double row[n_in];
  const double* arg[iv[SZ_ARG]];
  double* res[iv[SZ_RES]];
  ci k, c;
  for (c = 0; c < n_in; ++c) row[c] = tmpl[c];
  for (c = 0; c < iv[N_ACC]; ++c) row[iv[ACC] + c] = 0.0;
  for (c = 0; c < nq; ++c) row[iv[QDD] + c] = 0.0;
  arg[0] = row;
  for (k = 0; k < n; ++k) {
    double* q = row + iv[Q];
    double* qd = row + iv[QD];
    double* o = out + k * n_out;
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
       "qdd", "cond", "sum")


class _Nodes:
    """One thread's buffers for up to ``capacity`` rows of ``m`` given coordinates.

    The template row, the rows' inputs and outputs, and the C call bound to them.
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
        self.out = np.zeros((capacity, lay.der_size))
        cond, total = ROW_CHECKS["nf_derivatives"]
        self.iv = np.array([capacity, lay.size, lay.der_size, m, nq, kernel.sz_arg,
                            kernel.sz_res, lay.rotation.start, lay.acceleration.start,
                            lay.acceleration.stop - lay.acceleration.start, lay.q.start,
                            lay.qd.start, lay.qdd.start, cond, total], np.int64)
        self.max_cond = np.array([SINGULAR_CONDITION])
        self.ranges = self.bounds = None  # an estimator's ``_bounds``, `range_bounds`
        self._lib, self._kernel = lib, kernel

    def bound(self, est) -> Callable[[], int]:
        """The C call on these buffers for ``est``'s coordinate ranges."""
        if self.ranges is not est._bounds:
            self.ranges, self.bounds = est._bounds, range_bounds(est)  # kept: pointed at
            arrays = (self.template, self.rot, self.qa, self.va, self.dt, *self.bounds)
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
    n, m = q_head.shape
    if est.backend != "compiled" or est._qs is not None or n == 0:
        return None
    lib = library()
    if lib is None:
        return None
    calls = est._calls.__dict__
    nodes = calls.get("linearize_rows")
    if nodes is None or nodes.capacity < n or nodes.m != m:
        kernel = est._kernels.kernel("nf_derivatives")
        if not isinstance(kernel, Compiled):  # it did not compile: CasADi's VM
            return None
        nodes = calls["linearize_rows"] = _Nodes(lib, kernel, n, m)
    sel, flags = est._pack(nodes.template, state, est.D, est.beta, nodes.raw)
    if sel.tipping:
        return None
    nodes.rot[:n] = rotation
    nodes.qa[:n] = q_head
    nodes.va[:n] = qd_head
    nodes.dt[:n] = dt
    nodes.iv[0] = n
    if nodes.bound(est)() != 0:
        return None
    rows = nodes.out[:n].copy()
    rows.flags.writeable = False
    mode = sel.mode
    return [ForceLinearization.from_row(
        {"in_contact": flags, "mode": mode, "clipped": (), "time": t},
        LINEARIZATION_VIEWS, rows[k]) for k, t in enumerate((state.time + dt).tolist())]
