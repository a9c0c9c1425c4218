"""The normal forces at a state and at each suspension cylinder force stepped, in one pack.

`estimators.uncertainty.suspension_sensitivity` differences the forces at a state with those
at the state with each of its two suspension cylinder forces stepped (the forces are affine
in them). Through `NormalForceEstimator.estimate` that is three states made and packed per
payload anchor; here the state is packed once into the compiled estimate kernel's input row
and only the two cylinder-force entries change between its three calls: the same input rows,
hence the same forces to the bit, at a third of the cost. The calls and their checks run in
one C loop (`STEPPED_C`, the kernel called by its address on the same buffers; Python's loop
spent more around the four calls than the kernel in them), else in Python.
"""

from __future__ import annotations

import ctypes
import math

import numpy as np

from estimators._kernel_calls import Compiled
from estimators._symbolic import LAYOUT
from estimators.batch import SINGULAR_CONDITION
from models.cbuild import bind, load_shared
from models.state import MachineState

__all__ = ["STEPPED_C", "library", "stepped_forces"]

STEPPED_C = r"""
#include <math.h>
typedef long long ci;
typedef int (*kernel_t)(const double** arg, double** res, ci* iw, double* w, int mem);
enum { ROWS, AT, PAYLOAD, X, COND, SUM, SZ_ARG, SZ_RES };
/* `stepped_forces`' loop: row k of forces is the kernel's x at the packed input `in` with
   (k = 1, 2) suspension force k - 1 plus dv[0], (k = 3) the payload mass plus dv[1]; `in`
   and `out` are left as the Python loop leaves them. -1: a row not finite or its
   condition not below dv[2] (the rows from it on not made). */
int stepped_rows(kernel_t f, double* in, const ci* iv, const double* dv, double* out,
                 double* forces, ci* iw, double* w) {
  const double* arg[iv[SZ_ARG]];
  double* res[iv[SZ_RES]];
  const double base[2] = {in[iv[AT]], in[iv[AT] + 1]};
  ci k, c;
  for (c = 0; c < iv[SZ_ARG]; ++c) arg[c] = 0;
  for (c = 0; c < iv[SZ_RES]; ++c) res[c] = 0;
  arg[0] = in;
  res[0] = out;
  for (k = 0; k < iv[ROWS]; ++k) {
    if (k) {
      in[iv[AT]] = base[0];
      in[iv[AT] + 1] = base[1];
      if (k < 3) in[iv[AT] + k - 1] = base[k - 1] + dv[0];
      else in[iv[PAYLOAD]] += dv[1];
    }
    f(arg, res, iw, w, 0);
    if (!(isfinite(out[iv[SUM]]) && out[iv[COND]] < dv[2])) return -1;
    for (c = 0; c < 4; ++c) forces[4 * k + c] = out[iv[X] + c];
  }
  return 0;
}
"""


def library():
    """`STEPPED_C` compiled and loaded (once per process); None without a compiler."""
    return load_shared(STEPPED_C, "stepped_rows", {"stepped_rows": (
        [ctypes.c_void_p] * 8, ctypes.c_int)}, "the stepped forces' Python loop", "-O2")


class _Stepped:
    """This thread's `STEPPED_C` call bound to the estimate kernel's buffers."""

    def __init__(self, lib, kernel: Compiled):
        lay = LAYOUT
        inp, out = kernel.buffers()
        self.iv = np.array([4, lay.suspension_force.start, lay.payload_mass, lay.out_x.start,
                            lay.out_cond, lay.out_sum, kernel.sz_arg, kernel.sz_res],
                           np.int64)
        self.dv = np.array([0.0, 0.0, SINGULAR_CONDITION])
        self.forces = np.zeros((4, 4))
        iw, w = kernel.workspace()
        self.call = bind(lib.stepped_rows, kernel.address, inp, self.iv, self.dv, out,
                         self.forces, iw, w)


def _compiled(estimator) -> _Stepped | None:
    """This thread's bound `STEPPED_C` call of ``estimator``, or None (no library, no C)."""
    calls = estimator._calls.__dict__
    hit = calls.get("stepped_rows")
    if hit is None:
        lib = library()
        kernel = estimator._kernels.kernel("nf_estimate")
        if lib is None or not isinstance(kernel, Compiled):
            return None
        hit = calls["stepped_rows"] = _Stepped(lib, kernel)
    return hit


def stepped_forces(estimator, state: MachineState, step: float,
                   payload_step: float | None = None, compiled: bool = True
                   ) -> np.ndarray | None:
    """Forces (3, 4) [N]: at ``state``, then with suspension force 0, then 1, plus ``step``.

    With ``payload_step`` [kg], a fourth row (4, 4): the forces at ``state`` with the
    payload's mass (a run-time input of the kernel) plus ``payload_step``.

    ``estimator``: a `NormalForceEstimator`. None where the estimate would not take the
    kernel's regular path (no compiled kernels, the quasi-static method's zeroed inputs, no
    suspension forces, a tipping, singular or non-finite system): the caller then goes
    through ``estimate``, which handles or raises those. ``compiled``: the loop in C
    (`STEPPED_C`, the same bits) when it is there; False: Python.
    """
    if (getattr(estimator, "_kernels", None) is None or estimator._packer.zeroed is not None
            or state.suspension_force is None):
        return None
    state, _ = estimator._checked(state)
    inp, out, call, raw, _ = estimator._call("nf_estimate")
    sel, _ = estimator._pack(inp, state, estimator.D, estimator.beta, raw)
    if sel.tipping:
        return None
    n = 3 if payload_step is None else 4
    fused = _compiled(estimator) if compiled else None
    if fused is not None:
        fused.iv[0] = n
        fused.dv[:2] = (step, 0.0 if payload_step is None else payload_step)
        if fused.call():
            return None
        return fused.forces[:n].copy()
    lay = LAYOUT
    at = lay.suspension_force.start
    base = inp[at:at + 2].tolist()
    forces = np.empty((n, 4))
    for k in range(n):
        if k:
            inp[at:at + 2] = base
            if k < 3:
                inp[at + k - 1] = base[k - 1] + step
            else:
                inp[lay.payload_mass] += payload_step
        call()
        if not (math.isfinite(out[lay.out_sum]) and out[lay.out_cond] < SINGULAR_CONDITION):
            return None
        forces[k] = out[lay.out_x]
    return forces
