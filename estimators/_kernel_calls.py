"""Calling a compiled estimator kernel through ctypes, or the same kernel in CasADi's VM.

`Compiled` wraps one kernel of a shared library built by `estimators._symbolic.Kernels`:
per-thread input and output buffers, a one-pointer call (the cheapest through ctypes, about
a third of a microsecond) and a C loop over the rows of a batch (`BATCH_C`, appended to the
generated source). `Interpreted` offers the same interface on CasADi's virtual machine.
"""

from __future__ import annotations

import ctypes
import functools
import math
import threading

import casadi as ca
import numpy as np

__all__ = ["BATCH_C", "Compiled", "Interpreted"]


BATCH_C = """
int {name}_batch(const casadi_real* in, casadi_real* out, casadi_int n, casadi_int* iw,
                 casadi_real* w) {{
  const casadi_real* arg[{sz_arg}];
  casadi_real* res[{sz_res}];
  casadi_int i;
  int flag = 0;
  for (i = 0; i < n; ++i) {{
    arg[0] = in + i * {n_in};
    res[0] = out + i * {n_out};
    flag |= {name}(arg, res, iw, w, 0);
  }}
  return flag;
}}

/* Rows assembled from parts (the state's fields) on the stack, each then evaluated: row i
   is, part after part, width[k] values from src[k] + r * stride[k], with r = index[k][i]
   if part k has an index, else i (a stride of 0 repeats one row). Entries b_start ..
   b_start + b_len - 1 of each row must lie in [lo, hi] (NaN does not): else -2, the rows
   from that one on not evaluated. -1: the widths do not make an input row. */
int {name}_gather(const casadi_real* const* src, const casadi_int* width,
                  const casadi_int* stride, const unsigned char* const* index,
                  casadi_int n_parts, casadi_int b_start, casadi_int b_len,
                  const casadi_real* lo, const casadi_real* hi, casadi_real* out,
                  casadi_int n, casadi_int* iw, casadi_real* w) {{
  casadi_real row[{n_in}];
  const casadi_real* arg[{sz_arg}];
  casadi_real* res[{sz_res}];
  const casadi_real* from;
  casadi_int i, k, j, at;
  int flag = 0;
  if (b_start < 0 || b_len < 0 || b_start + b_len > {n_in}) return -1;
  arg[0] = row;
  for (i = 0; i < n; ++i) {{
    at = 0;
    for (k = 0; k < n_parts && at + width[k] <= {n_in}; ++k) {{
      from = src[k] + (index[k] ? (casadi_int)index[k][i] : i) * stride[k];
      for (j = 0; j < width[k]; ++j) row[at + j] = from[j];
      at += width[k];
    }}
    if (at != {n_in}) return -1;
    for (j = 0; j < b_len; ++j) {{
      if (!(row[b_start + j] >= lo[j] && row[b_start + j] <= hi[j])) return -2;
    }}
    res[0] = out + i * {n_out};
    flag |= {name}(arg, res, iw, w, 0);
  }}
  return flag;
}}

/* One pointer argument (a block {{arg, res, iw, w}}): the cheapest call through ctypes. */
int {name}_call(void** p) {{
  return {name}((const casadi_real**)p[0], (casadi_real**)p[1], (casadi_int*)p[2],
                (casadi_real*)p[3], 0);
}}
"""


_EMPTY = np.zeros(0)


class Compiled:
    """One compiled kernel in a shared library, called through ctypes."""

    def __init__(self, lib: ctypes.CDLL, fun: ca.Function):
        if not (fun.sparsity_in(0).is_dense() and fun.sparsity_out(0).is_dense()):
            raise OSError(f"kernel {fun.name()} must have dense input and output")
        self.name = fun.name()
        self.n_in = fun.size1_in(0)
        self.n_out = fun.size1_out(0)
        self.sz_arg, self.sz_res = fun.sz_arg(), fun.sz_res()
        self.sz_iw, self.sz_w = max(fun.sz_iw(), 1), max(fun.sz_w(), 1)
        self._batch = getattr(lib, self.name + "_batch")
        self._batch.argtypes = [ctypes.c_void_p, ctypes.c_void_p, ctypes.c_longlong,
                                ctypes.c_void_p, ctypes.c_void_p]
        self._batch.restype = ctypes.c_int
        self._gather = getattr(lib, self.name + "_gather")
        self._gather.argtypes = ([ctypes.c_void_p] * 4 + [ctypes.c_longlong] * 3
                                 + [ctypes.c_void_p] * 3
                                 + [ctypes.c_longlong, ctypes.c_void_p, ctypes.c_void_p])
        self._gather.restype = ctypes.c_int
        # The kernel itself, for C code that calls it (`estimators.linearize_batch`).
        self.address = ctypes.cast(getattr(lib, self.name), ctypes.c_void_p).value
        self._call = getattr(lib, self.name + "_call")
        self._call.argtypes = [ctypes.c_void_p]
        self._call.restype = ctypes.c_int
        self._local = threading.local()

    def _work(self):
        loc = self._local
        if not hasattr(loc, "w"):
            loc.iw = np.zeros(self.sz_iw, np.int64)
            loc.w = np.zeros(self.sz_w)
            loc.inp = np.zeros(self.n_in)
            loc.out = np.zeros(self.n_out)
            loc.arg = (ctypes.c_void_p * self.sz_arg)(loc.inp.ctypes.data)
            loc.res = (ctypes.c_void_p * self.sz_res)(loc.out.ctypes.data)
            loc.block = (ctypes.c_void_p * 4)(ctypes.addressof(loc.arg),
                                              ctypes.addressof(loc.res), loc.iw.ctypes.data,
                                              loc.w.ctypes.data)
            loc.call = functools.partial(self._call, ctypes.addressof(loc.block))
        return loc

    def buffers(self):
        """This thread's (input, output) buffers for `call_buffers`."""
        loc = self._work()
        return loc.inp, loc.out

    def call_buffers(self) -> None:
        """Evaluate on this thread's input buffer into its output buffer."""
        self._work().call()

    def bound_call(self):
        """A no-argument callable evaluating this thread's buffers (the fastest path)."""
        return self._work().call

    def workspace(self) -> tuple[np.ndarray, np.ndarray]:
        """This thread's work arrays (integer, float) of the kernel: a C caller's ``iw, w``."""
        loc = self._work()
        return loc.iw, loc.w

    def batch(self, inp: np.ndarray, out: np.ndarray) -> None:
        """Evaluate the rows of ``inp`` (C-contiguous (n, n_in)) into ``out`` (n, n_out)."""
        loc = self._work()
        self._batch(inp.ctypes.data, out.ctypes.data, inp.shape[0], loc.iw.ctypes.data,
                    loc.w.ctypes.data)

    def gather(self, parts, out: np.ndarray, bounds=None) -> bool:
        """Evaluate rows assembled from ``parts`` into ``out`` (n, n_out), C-contiguous.

        ``parts``: ``(array, index)`` pairs in the input's order; ``array`` a float64 array
        whose rows (leading axis, C-contiguous) are the part's values, or one row repeated
        (ndim 1); ``index``, a uint8 array of n rows into ``array``, or None (row i).
        ``bounds``: ``(start, lower, upper)``, the input entries from ``start`` on that
        must lie in ``[lower, upper]`` (arrays of one length), or None.

        Returns:
            False if a row left the bounds (the rows from it on are not evaluated).

        Raises:
            ValueError: ``out`` is not a C-contiguous float64 (n, n_out) array, a part has
                fewer rows than ``out`` (or an index past its rows), the row widths do not
                add up to the input size, or the bounds do not fit in it.
        """
        if not (isinstance(out, np.ndarray) and out.dtype == np.float64 and out.ndim == 2
                and out.shape[1] == self.n_out and out.flags.c_contiguous):
            raise ValueError(f"out must be a C-contiguous float64 (n, {self.n_out}) array")
        n = out.shape[0]
        k = len(parts)
        src = (ctypes.c_void_p * k)()
        width = np.empty(k, np.int64)
        stride = np.empty(k, np.int64)
        index = (ctypes.c_void_p * k)()
        keep = []  # the contiguous copies the pointers point into, alive for the call
        for j, (a, idx) in enumerate(parts):
            a = np.ascontiguousarray(a, dtype=float)
            keep.append(a)
            row = a.size if a.ndim == 1 else math.prod(a.shape[1:])
            width[j] = row
            stride[j] = 0 if a.ndim == 1 else row
            src[j] = a.ctypes.data
            if idx is not None:
                idx = np.ascontiguousarray(idx, dtype=np.uint8)
                if idx.shape != (n,) or (n and int(idx.max()) >= max(len(a), 1)) \
                        or (a.ndim == 1 and n and int(idx.max()) > 0):
                    raise ValueError(f"part {j}: its index must be (n,) = ({n},) rows of "
                                     f"its {len(a) if a.ndim > 1 else 1}")
                keep.append(idx)
                index[j] = idx.ctypes.data
            elif a.ndim > 1 and len(a) < n:
                raise ValueError(f"part {j} has {len(a)} rows, out {n}")
        if int(width.sum()) != self.n_in:
            raise ValueError(f"parts give rows of {int(width.sum())} values, the kernel "
                             f"takes {self.n_in}")
        start, lo, hi = (0, _EMPTY, _EMPTY) if bounds is None else bounds
        lo = np.ascontiguousarray(lo, dtype=float)
        hi = np.ascontiguousarray(hi, dtype=float)
        if lo.shape != hi.shape or lo.ndim != 1:
            raise ValueError(f"bounds of shapes {lo.shape}, {hi.shape}: need two (m,)")
        loc = self._work()
        flag = self._gather(src, width.ctypes.data, stride.ctypes.data, index, k, int(start),
                            lo.size, lo.ctypes.data, hi.ctypes.data, out.ctypes.data, n,
                            loc.iw.ctypes.data, loc.w.ctypes.data)
        if flag == -1:
            raise ValueError(f"bounds from entry {start} of {lo.size} do not fit an input "
                             f"row of {self.n_in}")
        return flag != -2


class Interpreted:
    """The same kernel evaluated by CasADi's virtual machine (no compiler available)."""

    def __init__(self, fun: ca.Function):
        self.fun = fun
        self.n_in = fun.size1_in(0)
        self.n_out = fun.size1_out(0)
        self._local = threading.local()

    def buffers(self):
        """This thread's (input, output) buffers for `call_buffers`."""
        loc = self._local
        if not hasattr(loc, "inp"):
            loc.inp = np.zeros(self.n_in)
            loc.out = np.zeros(self.n_out)
        return loc.inp, loc.out

    def call_buffers(self) -> None:
        """Evaluate on this thread's input buffer into its output buffer."""
        loc = self._local
        loc.out[:] = np.asarray(self.fun(loc.inp)).ravel()

    def bound_call(self):
        """A no-argument callable evaluating this thread's buffers."""
        return self.call_buffers

    def batch(self, inp: np.ndarray, out: np.ndarray) -> None:
        """Evaluate the rows of ``inp`` into ``out``."""
        if inp.shape[0] == 0:
            return
        fm = self.fun.map(inp.shape[0], "thread", 2)
        out[:] = np.asarray(fm(inp.T)).T

    def gather(self, parts, out: np.ndarray, bounds=None) -> bool:
        """`Compiled.gather`: the rows assembled in numpy, checked, then `batch`."""
        rows = assemble_rows(parts, out.shape[0])
        if bounds is not None:
            start, lo, hi = bounds
            x = rows[:, start:start + len(lo)]
            if not ((x >= lo) & (x <= hi)).all():
                return False
        self.batch(rows, out)
        return True


def assemble_rows(parts, n: int) -> np.ndarray:
    """The (n, total width) rows that `Compiled.gather` assembles from ``parts``."""
    cols = []
    for a, idx in parts:
        a = np.asarray(a, dtype=float)
        if a.ndim == 1:
            cols.append(np.broadcast_to(a, (n, a.size)))
        else:
            rows = a.reshape(len(a), -1)
            cols.append(rows if idx is None else rows[np.asarray(idx, dtype=np.intp)])
    return np.concatenate(cols, axis=1) if cols else np.zeros((n, 0))
