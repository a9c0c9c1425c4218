"""Axis limits in C: the whole-body QP's stroke and speed bounds, the MPC's brake inputs.

`PositionLimit` and `VelocityLimit` turn the nine axes' limits into bounds on the
accelerations, element by element; in numpy that is one ufunc call per operation on
18-element arrays (~25 us a tick together, for a few hundred flops). `LIMITS_C` is the same
IEEE operations in the same order (numpy's ``minimum``/``maximum`` NaN rule included),
compiled once with the system compiler (`models.cbuild`, no contraction into fused
multiply-adds) and called through ctypes on kept buffers: the same bits
(`tests/test_limits_c.py`). Without a compiler the numpy code runs. The MPC's brake-to-rest
inputs (`CondensedPrediction.brake_trajectory`, a loop over the steps of a few ufuncs each)
are the same loop in C, the same bits; so are `HorizonEffortLimit`'s rows (a dozen ufuncs
and a strided scatter, ~15 us a tick) with the payload blend and the products with the
brake inputs (numpy's own ``cblas_dgemv``, as its matmul calls it), and `HorizonLimit`'s
right-hand sides.
"""

from __future__ import annotations

import ctypes
import sys

import numpy as np

from models.cbuild import address, bind, load_shared
from models.numpy_blas import numpy_blas
from wbc.axes import N_AXES

__all__ = ["LIMITS_C", "CompiledBounds", "CompiledBrake", "CompiledEffortRows",
           "CompiledHorizonBounds", "compiled_bounds", "compiled_brake", "compiled_effort_rows",
           "compiled_horizon_bounds", "plain_address"]

LIMITS_C = r"""
#include <math.h>
enum { NA = 9 };
typedef void (*gemv_fn)(int, int, long long, long long, double, const double*, long long,
                        const double*, long long, double, double*, long long);
/* numpy's maximum and minimum: NaN in either gives NaN; equal values give the first. */
static double np_max(double a, double b) { return (a >= b || isnan(a)) ? a : b; }
static double np_min(double a, double b) { return (a <= b || isnan(a)) ? a : b; }

/* `PositionLimit.compute`: in = q, qd, brake, q_hi, q_lo, -b dt (18), (b dt)^2 (18),
   2 b (18), then T, T^2, dt; out = lower (9), upper (9) of the step's accelerations. */
int position_bounds(const double* in, double* out) {
  const double *q = in, *qd = in + NA, *brake = in + 2 * NA, *hi = in + 3 * NA;
  const double *lo = in + 4 * NA, *neg_bdt = in + 5 * NA, *bdt2 = in + 7 * NA;
  const double *two_b = in + 9 * NA;
  const double T = in[11 * NA], T2 = in[11 * NA + 1], dt = in[11 * NA + 2];
  double bound[2 * NA];
  int i;
  for (i = 0; i < 2 * NA; ++i) {
    /* the upper side: distance d = q_hi - q, speed v = qd; the lower side mirrored */
    double d = i < NA ? hi[i] - q[i] : q[i - NA] - lo[i - NA];
    double v = i < NA ? qd[i] : -qd[i - NA];
    double x = v * 0.5;
    x *= dt;
    x = d - x;
    x = np_max(x, 0.0);
    x = two_b[i] * x;
    x += bdt2[i];
    x = sqrt(x);
    x += neg_bdt[i];
    x -= v;
    x /= dt;
    v = v * T;
    d = d - v;
    d *= 2.0;
    d /= T2;
    bound[i] = np_min(d, x);
  }
  for (i = 0; i < NA; ++i) {
    out[i] = np_min(-bound[NA + i], brake[i]);
    out[NA + i] = np_max(bound[i], brake[i]);
  }
  return 0;
}

/* `CondensedPrediction.brake_trajectory`'s inputs: every axis braked to rest at its
   acceleration limit a over the steps h (N), from the speeds v0 (n); u (N, n). */
int brake_inputs(const double* v0, const double* a, const double* h, long N, long n,
                 double* u) {
  double v[64];
  long i, j, k;
  if (n > 64 || n < 0 || N < 0) return -1;
  for (i = 0; i < n; ++i) v[i] = v0[i];
  for (j = 0; j < N * n; ++j) u[j] = 0.0;
  for (k = 0; k < N; ++k) {
    int moving = 0;
    for (i = 0; i < n; ++i) {
      double t = np_min(np_max(v[i] / h[k], -a[i]), a[i]);
      u[k * n + i] = -t;
      v[i] = v[i] + h[k] * u[k * n + i];
      if (v[i] != 0.0 || isnan(v[i])) moving = 1;  /* numpy's any(): NaN is true */
    }
    if (!moving) {  /* at rest: the later inputs are -0 */
      for (j = (k + 1) * n; j < N * n; ++j) u[j] = -0.0;
      break;
    }
  }
  return 0;
}

/* `HorizonEffortLimit.compute`'s rows (in: the pointers E, e0, Eu, upper, lower, scale;
   dims: K, N, nb, na, n, col0, as arrays: ctypes converts few arguments): per step k the
   nb upper rows, then the nb lower rows, of G (2 N nb, n) and h (N, 2, nb). E: (K, nb,
   na) with K = 1 (every step's) or N; e0: (K, nb); Eu: (N, nb), step k's E_k times its
   brake input; upper, lower, scale: (nb).
   Step k's rows are +-E_k / scale on the na columns from col0 + k na; the other entries
   of G are left as they are (the caller's zeros). */
int effort_rows(const double* const* in, const long* dims, double* G, double* h) {
  const double *E = in[0], *e0 = in[1], *Eu = in[2], *upper = in[3], *lower = in[4];
  const double* scale = in[5];
  const long K = dims[0], N = dims[1], nb = dims[2], na = dims[3], n = dims[4];
  const long col0 = dims[5];
  long k, r, a;
  if (!(K == 1 || K == N) || N < 0 || nb < 1 || na < 1 || col0 < 0 || col0 + N * na > n)
    return -1;
  for (k = 0; k < N; ++k) {
    const double* Ek = E + (K == 1 ? 0 : k * nb * na);
    const double* ek = e0 + (K == 1 ? 0 : k * nb);
    double* up = G + (2 * k * nb) * n + col0 + k * na;
    double* low = up + nb * n;
    for (r = 0; r < nb; ++r) {
      double brake = Eu[k * nb + r] + ek[r];
      double hi = np_max(upper[r], brake), lo = np_min(lower[r], brake);
      hi = hi - ek[r];
      lo = ek[r] - lo;
      h[(2 * k) * nb + r] = hi / scale[r];
      h[(2 * k + 1) * nb + r] = lo / scale[r];
      for (a = 0; a < na; ++a) {
        double x = Ek[r * na + a] / scale[r];
        up[r * n + a] = x;
        low[r * n + a] = -x;
      }
    }
  }
  return 0;
}

/* `CompiledEffortRows.rows_of_pair`: effort_rows (K = 1) of one node's map blended from
   the two payload masses' maps, as `ActuatorEfforts.affine` blends them, and of the
   products with the brake inputs that numpy's matmul makes. in = effort_rows's pointers;
   axes: the nb rows of the maps bounded; gemv: numpy's cblas_dgemv; E_1 (9, na), e_1 (9),
   E_2, e_2 the maps; brake (N, na); w the mass's weight. Into in[0] (E, (nb, na)) and
   in[1] (e0, nb): E_1 + (E_2 - E_1) w row by row, e_1 + (e_2 - e_1) w; into in[2] (Eu,
   (N, nb)): matmul's call per step, E brake_k. */
int effort_rows_pair(const double* const* in, const long* dims, const long* axes, void* gemv,
                     const double* E1, const double* f1, const double* E2, const double* f2,
                     const double* brake, double w, double* G, double* h) {
  double *E = (double*)in[0], *e0 = (double*)in[1], *Eu = (double*)in[2];
  const long K = dims[0], N = dims[1], nb = dims[2], na = dims[3];
  long k, r, a;
  if (K != 1 || nb < 1 || na < 1) return -1;
  for (r = 0; r < nb; ++r) {
    const long i = axes[r];
    if (i < 0 || i >= NA) return -1;
    for (a = 0; a < na; ++a) {
      double x = E2[i * na + a] - E1[i * na + a];
      x = x * w;
      E[r * na + a] = E1[i * na + a] + x;
    }
    {
      double x = f2[i] - f1[i];
      x = x * w;
      e0[r] = f1[i] + x;
    }
  }
  for (k = 0; k < N; ++k)
    ((gemv_fn)gemv)(102, 112, na, nb, 1.0, E, na, brake + k * na, 1, 0.0, Eu + k * nb, 1);
  return effort_rows(in, dims, G, h);
}

/* `HorizonLimit.compute`'s h: in = brake (N, NA), free (N, NA), upper (NA), lower (NA);
   h = [max(upper, brake) - free; free - min(lower, brake)], (2, N, NA). */
int horizon_bounds(const double* in, long N, double* h) {
  const double *brake = in, *free = in + N * NA, *upper = in + 2 * N * NA;
  const double* lower = upper + NA;
  long k, i;
  if (N < 0) return -1;
  for (k = 0; k < N; ++k)
    for (i = 0; i < NA; ++i) {
      const long j = k * NA + i;
      h[j] = np_max(upper[i], brake[j]) - free[j];
      h[N * NA + j] = free[j] - np_min(lower[i], brake[j]);
    }
  return 0;
}

/* `VelocityLimit.compute`: in = qd, brake, v_hi, v_lo, then dt; out = lower, upper. */
int velocity_bounds(const double* in, double* out) {
  const double *qd = in, *brake = in + NA, *hi = in + 2 * NA, *lo = in + 3 * NA;
  const double dt = in[4 * NA];
  int i;
  for (i = 0; i < NA; ++i) {
    double lower = lo[i] - qd[i], upper = hi[i] - qd[i];
    lower /= dt;
    upper /= dt;
    out[i] = np_min(lower, brake[i]);
    out[NA + i] = np_max(upper, brake[i]);
  }
  return 0;
}
"""


class CompiledBounds:
    """One of `LIMITS_C`'s functions with its own input and output buffers.

    ``inp`` (the function's input layout), ``out`` (lower, upper: (2, 9)); `call` evaluates
    the one on the other. Not shared between threads (each constraint makes its own).
    """

    def __init__(self, fun, n_in: int):
        self.inp = np.zeros(n_in)
        self.out = np.zeros((2, N_AXES))
        self.call = bind(fun, self.inp, self.out)


class CompiledBrake:
    """``brake_inputs`` on kept buffers: steps of lengths ``steps``, ``n`` axes (<= 64).

    `inputs` fills the buffers, calls, and returns a fresh ``u``.
    """

    def __init__(self, fun, steps: np.ndarray, n: int):
        self.v0, self.a = np.zeros(n), np.zeros(n)
        self.h = np.array(steps, float)
        self.u = np.zeros((self.h.size, n))
        self.call = bind(fun, self.v0, self.a, self.h, self.h.size, n, self.u)

    def inputs(self, qd0, acceleration) -> np.ndarray:
        """The brake inputs ``u`` (N, n) from the speeds ``qd0`` at limits ``acceleration``."""
        self.v0[:] = qd0
        self.a[:] = acceleration
        if self.call() != 0:
            raise ValueError(f"brake inputs: {self.v0.size} axes, at most 64")
        return self.u.copy()


class CompiledEffortRows:
    """``effort_rows`` on kept input buffers, for one structure (K, N, nb, na, n, col0).

    `set_bounds` keeps the constraint's bounds and bounded axes (`source`: the upper
    bounds' array they were taken from, `source_lower` the lower); `rows` fills the other
    buffers, calls, and returns ``(G, h)``; `rows_of_pair` takes one node's map as the
    payload pair and the brake inputs (K = 1): the blend, the products and the rows in one
    call (``effort_rows_pair``).

    ``G`` is kept between calls and is the last call's array again when nothing else holds
    it any more (its reference count says so: the builder copies it, then drops it). The C
    writes only the blocks, so its other entries stay the zeros it was made with: don't
    write into a returned ``G`` (as `wbc.qp.QPBuilder` keeps its own). ``h`` is fresh.
    """

    def __init__(self, lib, K: int, N: int, nb: int, na: int, n: int, col0: int,
                 gemv: int | None):
        self.E, self.e0 = np.zeros((K, nb, na)), np.zeros((K, nb))
        self.Eu = np.zeros((N, nb))
        self.bounds = np.zeros((3, nb))  # upper, lower, scale: `set_bounds`
        self.axes = np.zeros(nb, np.int_)  # the maps' rows bounded: `set_bounds`
        self.source = self.source_lower = None
        self.shape = ((2 * N * nb, n), (N, 2, nb))
        self.N, self.na = N, na
        self._G: np.ndarray | None = None  # the last G (see the class docstring)
        self._in = np.array([a.ctypes.data for a in (self.E, self.e0, self.Eu, *self.bounds)],
                            np.uintp)
        self._map_shape = (N_AXES, na)  # `rows_of_pair`'s E_1, E_2
        self._dims = np.array([K, N, nb, na, n, col0], np.int_)
        self.call = bind(lib.effort_rows, self._in, self._dims)
        self._pair_call = (None if gemv is None or K != 1 else
                           bind(lib.effort_rows_pair, self._in, self._dims, self.axes, gemv))

    def set_bounds(self, upper, lower, scale, axes) -> None:
        """Take the bounds ``upper[axes]``, ``lower[axes]`` (kept as `source`), the scale.

        And the bounded axes ``axes`` (a slice or an index of the nine: `rows_of_pair`).
        """
        self.bounds[:] = upper[axes], lower[axes], scale
        self.axes[:] = np.arange(N_AXES)[axes]
        self.source, self.source_lower = upper, lower

    def rows(self, E, e0, Eu) -> tuple[np.ndarray, np.ndarray]:
        """``(G (2 N nb, n), h (2 N nb,))`` of E (K, nb, na), e0 (K, nb), Eu (N, nb)."""
        self.E[:] = E
        self.e0[:] = e0
        self.Eu[:] = Eu
        return self._rows(self.call)

    def rows_of_pair(self, pair: tuple, brake: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
        """`rows` of one node's map ``E = E_1 + w (E_2 - E_1)``, ``e_0 = e_1 + w (e_2 - e_1)``.

        ``pair``: `estimators.efforts.ActuatorEfforts.affine_pair`'s ``((E_1, e_1), (E_2,
        e_2), w)`` (9 x na, 9); only the rows of the bounded axes (`set_bounds`) blended,
        with `affine`'s operations (a product's operands commute), into the kept ``E``,
        ``e0`` (K = 1). ``Eu`` is ``E[None] @ brake[:N, :, None]`` written into the kept
        buffer: the very matmul (numpy's ``cblas_dgemv`` per step on the same operands,
        `models.numpy_blas`) that `wbc.constraints.HorizonEffortLimit`'s numpy path makes.
        ``brake``: (>= N, na).

        Returns:
            ``(G, h)``; None without numpy's BLAS, for K > 1, or for maps or brake inputs
            that are not C-contiguous float64 arrays of those shapes (the caller's numpy
            path then makes the rows).
        """
        call = self._pair_call
        (E1, f1), (E2, f2), w = pair
        if (call is None or E1.shape != self._map_shape or E2.shape != self._map_shape
                or f1.shape != _AXES_SHAPE or f2.shape != _AXES_SHAPE
                or brake.shape[0] < self.N or brake.shape[1:] != self._map_shape[1:]):
            return None
        pointers = (plain_address(E1), plain_address(f1), plain_address(E2),
                    plain_address(f2), plain_address(brake))
        if None in pointers:
            return None
        return self._rows(call, *pointers, w)

    def _rows(self, call, *args) -> tuple[np.ndarray, np.ndarray]:
        """``call(*args, G, h)`` on the filled buffers: the kept G (if free), a fresh h."""
        # References to a free kept G: the attribute and getrefcount's argument.
        if self._G is None or sys.getrefcount(self._G) != 2:
            self._G = np.zeros(self.shape[0])
        G, h = self._G, np.empty(self.shape[1])
        if call(*args, address(G), address(h)) != 0:
            raise ValueError(f"effort rows: inconsistent sizes or axes {self.shape}")
        return G, h.reshape(-1)


class CompiledHorizonBounds:
    """``horizon_bounds`` on a kept input buffer, for N steps.

    `h` copies the inputs (the bounds only when they are other arrays than the last
    call's, or writable), calls, and returns a fresh ``h``.
    """

    def __init__(self, fun, N: int):
        self.inp = np.zeros(2 * N * N_AXES + 2 * N_AXES)
        self._brake = self.inp[:N * N_AXES].reshape(N, N_AXES)
        self._free = self.inp[N * N_AXES:2 * N * N_AXES].reshape(N, N_AXES)
        self._bounds = self.inp[2 * N * N_AXES:].reshape(2, N_AXES)
        self._source: tuple | None = None  # the bound arrays last copied
        self.size = 2 * N * N_AXES
        self.call = bind(fun, self.inp, N)

    def h(self, upper, lower, brake, free) -> np.ndarray:
        """``[max(upper, brake) - free; free - min(lower, brake)]``, (2 N 9,)."""
        kept = self._source
        if (kept is None or kept[0] is not upper or kept[1] is not lower
                or upper.flags.writeable or lower.flags.writeable):
            self._bounds[0] = upper
            self._bounds[1] = lower
            self._source = (upper, lower)
        self._brake[...] = brake
        self._free[...] = free
        h = np.empty(self.size)
        self.call(address(h))
        return h


_F64 = np.dtype(float)
_AXES_SHAPE = (N_AXES,)
_char_view = ctypes.c_char.from_buffer


def plain_address(a) -> int | None:
    """The data's address of a C-contiguous float64 ndarray (the C reads it as one), else None.

    The check and `models.cbuild.address` in one: a writable C-contiguous array's buffer
    gives its address (0.2 us); a read-only one takes ``a.ctypes.data``.
    """
    if type(a) is not np.ndarray or a.dtype is not _F64:
        return None
    try:
        return ctypes.addressof(_char_view(a))
    except (TypeError, ValueError, BufferError):
        return a.ctypes.data if a.flags.c_contiguous else None


def compiled_horizon_bounds(N: int) -> CompiledHorizonBounds | None:
    """A new `CompiledHorizonBounds` of N steps; None without a working C compiler."""
    lib = _library()
    return None if lib is None else CompiledHorizonBounds(lib.horizon_bounds, N)


def compiled_effort_rows(K: int, N: int, nb: int, na: int, n: int,
                         col0: int) -> CompiledEffortRows | None:
    """A new `CompiledEffortRows`; None without a working C compiler."""
    lib = _library()
    if lib is None:
        return None
    blas = numpy_blas()
    return CompiledEffortRows(lib, K, N, nb, na, n, col0, None if blas is None else blas[0])


def compiled_brake(steps, n: int) -> CompiledBrake | None:
    """A new `CompiledBrake`; None without a working C compiler or for more than 64 axes."""
    lib = _library()
    return None if lib is None or not 0 <= n <= 64 else CompiledBrake(lib.brake_inputs,
                                                                      steps, n)


def compiled_bounds(name: str) -> CompiledBounds | None:
    """A new `CompiledBounds` of ``position_bounds`` or ``velocity_bounds``.

    None without a working C compiler (the library is built once per process).
    """
    lib = _library()
    if lib is None:
        return None
    n_in = {"position_bounds": 11 * N_AXES + 3, "velocity_bounds": 4 * N_AXES + 1}[name]
    return CompiledBounds(getattr(lib, name), n_in)


def _library():
    """`LIMITS_C` compiled and loaded once per process; None without a compiler."""
    return load_shared(LIMITS_C, "axis_limits", {
        "position_bounds": ([ctypes.c_void_p] * 2, ctypes.c_int),
        "velocity_bounds": ([ctypes.c_void_p] * 2, ctypes.c_int),
        "brake_inputs": ([ctypes.c_void_p] * 3 + [ctypes.c_long] * 2 + [ctypes.c_void_p],
                         ctypes.c_int),
        "effort_rows": ([ctypes.c_void_p] * 4, ctypes.c_int),
        "effort_rows_pair": ([ctypes.c_void_p] * 9 + [ctypes.c_double] + [ctypes.c_void_p] * 2,
                             ctypes.c_int),
        "horizon_bounds": ([ctypes.c_void_p, ctypes.c_long, ctypes.c_void_p], ctypes.c_int)},
        "numpy")
