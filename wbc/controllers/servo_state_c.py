"""`ServoState.observe` and the free response of its result in one compiled pass.

Every MPC tick `ServoState.observe` (the setpoint's resync, the deflection filter: a dozen
ufuncs on nine numbers) and `CondensedPrediction.free_response` of the ``(q, qd)`` it gives
(two (N, 9) arrays) take ~15 us of the closed loop's tick for a few hundred flops. `SERVO_C`
does numpy's IEEE operations in numpy's order, element by element as the ufuncs do (compiled
with ``-ffp-contract=off``, `models.cbuild`: no fused multiply-adds), so the same bits
(`tests/test_servo_state_c.py` compares the two paths). Without a compiler the numpy path
runs.

The MPC's tick takes more from the same pass (`tests/test_servo_brake_c.py`):
`SERVO_BRAKE_C` adds the brake trajectory of the observed state
(`CondensedPrediction.brake_trajectory`: `LIMITS_C`'s brake inputs, then numpy's products
through the ``cblas_dgemm`` numpy calls) to the observe, ``servo_command`` makes the rates
the controller commands and advances the setpoints by them (`ServoState.command`). Both are
called with their arguments packed in kept arrays: ctypes converts two.
"""

from __future__ import annotations

import ctypes

import numpy as np

from models.cbuild import address, bind, load_shared
from models.numpy_blas import numpy_gemm
from wbc.constraints.limits_c import LIMITS_C

__all__ = ["SERVO_BRAKE_C", "SERVO_C", "ServoPass"]

# One `ServoState.observe` after the first (the setpoint known): the setpoint reset to the
# measured one (measured NULL: none) where they differ by more than resync + delay |rate|,
# the deflection low-pass filtered with gain a and zero on the axes [s0, s1); out = q (n),
# qd (n), then the zero-input prediction of (q, qd) at the m times: positions (m, n),
# velocities (m, n).
SERVO_C = r"""
#include <math.h>
int servo_observe(double* setpoint, double* deflection, const double* rates,
                  const double* q_meas, const double* measured, long n, long s0, long s1,
                  const double* times, long m, double resync, double delay, double a,
                  double* out) {
  double *q = out, *qd = out + n, *qf = out + 2 * n, *vf = out + 2 * n + m * n;
  long j, k;
  if (measured)
    for (j = 0; j < n; ++j) {
      double allowance = resync + delay * fabs(rates[j]);
      if (fabs(measured[j] - setpoint[j]) > allowance) setpoint[j] = measured[j];
    }
  for (j = 0; j < n; ++j) deflection[j] += a * (q_meas[j] - setpoint[j] - deflection[j]);
  for (j = s0; j < s1; ++j) deflection[j] = 0.0;
  for (j = 0; j < n; ++j) {
    q[j] = setpoint[j] + deflection[j];
    qd[j] = rates[j];
  }
  for (k = 0; k < m; ++k)
    for (j = 0; j < n; ++j) {
      qf[k * n + j] = q[j] + times[k] * qd[j];
      vf[k * n + j] = qd[j];
    }
  return 0;
}

/* numpy's clip ufunc of a double: min(max(x, lo), hi), a NaN x passed */
static double np_clip(double x, double lo, double hi) {
  if (!isnan(x)) x = x > lo ? x : lo;
  if (!isnan(x)) x = x < hi ? x : hi;
  return x;
}

/* The rates commanded for the accelerations qdd over dt, clipped to [vlo, vhi] (out), then
   `ServoState.commanded` of them: rates = out, the setpoint advanced by them over step and
   clipped to [lower, upper]. */
int servo_command(double* setpoint, double* rates, const double* lower, const double* upper,
                  long n, const double* qdd, double dt, const double* vlo, const double* vhi,
                  double step, double* out) {
  long j;
  for (j = 0; j < n; ++j) out[j] = np_clip(rates[j] + qdd[j] * dt, vlo[j], vhi[j]);
  for (j = 0; j < n; ++j) rates[j] = out[j];
  for (j = 0; j < n; ++j) setpoint[j] = np_clip(setpoint[j] + step * rates[j], lower[j], upper[j]);
  return 0;
}

/* `servo_command` of the packed arguments (`POINTERS`, `SCALARS`): ctypes converts two */
@DEFINES@
#define PTR(name) ((double*)p[P_##name])
int servo_command_packed(void* const* p, const double* s) {
  return servo_command(PTR(setpoint), PTR(rates), PTR(lower), PTR(upper), (long)s[S_n],
                       PTR(qdd), s[S_dt], PTR(vlo), PTR(vhi), s[S_step], PTR(command_out));
}
"""

# `servo_observe`, then the brake-and-hold trajectory of its (q, qd) at the same m node
# times (`CondensedPrediction.brake_trajectory`): out continues with the inputs u,
# positions and velocities, (m, n) each. The inputs are `LIMITS_C`'s ``brake_inputs`` of qd
# at the limits acc over the steps h (m); the nodes numpy's ``qf + Lq @ u`` and
# ``vf + Lv @ u``: matmul's ``cblas_dgemm`` (`models.numpy_blas.numpy_gemm`, with numpy's
# arguments: row-major, no transposes, the C-ordered operands' row lengths, alpha 1, beta
# 0), then the sums. -1: more axes than ``brake_inputs`` takes.
SERVO_BRAKE_C = SERVO_C + LIMITS_C + r"""
typedef void (*gemm_fn)(int, int, int, long long, long long, long long, double,
                        const double*, long long, const double*, long long, double, double*,
                        long long);

int servo_observe_brake(void* gemm, const double* h, const double* acc, const double* Lq,
                        const double* Lv, double* setpoint, double* deflection,
                        const double* rates, const double* q_meas, const double* measured,
                        long n, long s0, long s1, const double* times, long m,
                        double resync, double delay, double a, double* out) {
  const double *qd = out + n, *qf = out + 2 * n, *vf = out + 2 * n + m * n;
  double *u = out + 2 * n * (m + 1), *qb = u + m * n, *vb = qb + m * n;
  long i;
  servo_observe(setpoint, deflection, rates, q_meas, measured, n, s0, s1, times, m, resync,
                delay, a, out);
  if (brake_inputs(qd, acc, h, m, n, u) != 0) return -1;
  ((gemm_fn)gemm)(101, 111, 111, m, n, m, 1.0, Lq, m, u, n, 0.0, qb, n);
  for (i = 0; i < m * n; ++i) qb[i] = qf[i] + qb[i];
  ((gemm_fn)gemm)(101, 111, 111, m, n, m, 1.0, Lv, m, u, n, 0.0, vb, n);
  for (i = 0; i < m * n; ++i) vb[i] = vf[i] + vb[i];
  return 0;
}

/* `servo_observe_brake` of the packed arguments (measured: NULL for none) */
int servo_observe_brake_packed(void* const* p, const double* s) {
  return servo_observe_brake(p[P_gemm], PTR(h), PTR(acc), PTR(Lq), PTR(Lv), PTR(setpoint),
                             PTR(deflection), PTR(rates), PTR(q_meas), PTR(measured),
                             (long)s[S_n], (long)s[S_s0], (long)s[S_s1], PTR(times),
                             (long)s[S_m], s[S_resync], s[S_delay], s[S_a], PTR(out));
}
"""

# The packed calls' pointer table and scalars, in their order: a call through ctypes
# converts every argument (~1 us for the observe's nineteen), two here.
POINTERS = ("setpoint", "deflection", "rates", "lower", "upper", "q_meas", "measured",
            "times", "out", "gemm", "h", "acc", "Lq", "Lv", "qdd", "vlo", "vhi",
            "command_out")
SCALARS = ("n", "s0", "s1", "m", "resync", "delay", "a", "dt", "step")
_DEFINES = "\n".join([f"#define P_{n} {i}" for i, n in enumerate(POINTERS)]
                     + [f"#define S_{n} {i}" for i, n in enumerate(SCALARS)])
SERVO_C = SERVO_C.replace("@DEFINES@", _DEFINES)
SERVO_BRAKE_C = SERVO_BRAKE_C.replace("@DEFINES@", _DEFINES)
_P_ = {name: i for i, name in enumerate(POINTERS)}
_S_ = {name: i for i, name in enumerate(SCALARS)}

_P, _L, _D = ctypes.c_void_p, ctypes.c_long, ctypes.c_double


def _library():
    return load_shared(SERVO_C, "servo_state", {
        "servo_observe": ([_P] * 5 + [_L] * 3 + [_P, _L] + [_D] * 3 + [_P], ctypes.c_int),
        "servo_command_packed": ([_P, _P], ctypes.c_int)},
        "the servo state's numpy")


def _brake_library():
    return load_shared(SERVO_BRAKE_C, "servo_state_brake", {
        "servo_observe_brake_packed": ([_P, _P], ctypes.c_int)},
        "the servo state's and the brake's numpy")


class ServoPass:
    """``servo_observe`` bound to kept buffers (made at construction).

    Attributes:
        setpoint, deflection, rates: The servo state's arrays (9,) (`ServoState` keeps its
            state here).
        lower, upper: The setpoint range (9,) (`ServoState` keeps it here).
        q_meas, measured: A call's measured positions and servo setpoints, copied in.
        braking: Whether `observe_brake` runs (the pass was made with a brake).

    Args:
        lib: `_library`'s library.
        n: The number of axes.
        suspension: The axes whose deflection is zero, a slice.
        times: The free response's times [s] (m,), kept.
        brake: ``(brake library, gemm address, Lq, Lv, step lengths, acceleration limits)``
            of the prediction at ``times`` (`make`), kept as copies; None: no brake.
    """

    def __init__(self, lib, n: int, suspension: slice, times: np.ndarray,
                 brake: tuple | None = None):
        self._lib, self._suspension = lib, suspension
        self.setpoint, self.deflection, self.rates = np.zeros(n), np.zeros(n), np.zeros(n)
        self.lower, self.upper = np.zeros(n), np.zeros(n)
        self.q_meas, self.measured = np.zeros(n), np.zeros(n)
        self.times = np.array(times, float)
        self.n, self.m = n, self.times.size
        head = (self.setpoint, self.deflection, self.rates, self.q_meas)
        tail = (n, suspension.start, suspension.stop, self.times, self.m)
        self._call = {True: bind(lib.servo_observe, *head, self.measured, *tail),
                      False: bind(lib.servo_observe, *head, None, *tail)}
        # the packed calls' arguments: the buffers' now, a call's own at each call
        self._table, self._scalars = np.zeros(len(POINTERS), np.uint64), np.zeros(len(SCALARS))
        for name in ("setpoint", "deflection", "rates", "lower", "upper", "q_meas", "times"):
            self._table[_P_[name]] = address(getattr(self, name))
        self._scalars[:4] = n, suspension.start, suspension.stop, self.m
        self._measured_at = address(self.measured)
        self._limits: tuple | None = None  # (velocity limits' arrays, their kept copies)
        self._command = bind(lib.servo_command_packed, self._table, self._scalars)
        self.braking = brake is not None
        self._brake = None
        if brake is not None:
            blib, gemm, *parts = brake
            self._brake = (blib, gemm, *(np.array(a, float, order="C") for a in parts))
            self._table[_P_["gemm"]] = gemm
            for name, a in zip(("Lq", "Lv", "h", "acc"), self._brake[2:]):
                self._table[_P_[name]] = address(a)
            self._call_brake = bind(blib.servo_observe_brake_packed, self._table,
                                    self._scalars)

    @classmethod
    def make(cls, n: int, suspension: slice, times: np.ndarray,
             brake: tuple | None = None) -> ServoPass | None:
        """A pass, or None without a compiler.

        ``brake``: ``(Lq, Lv, step lengths, acceleration limits)`` of the prediction at
        ``times`` for `observe_brake`; without numpy's BLAS, with other shapes, or with one
        step or one axis (numpy's products are matrix-vector ones then) the pass has no
        brake.
        """
        lib = _library()
        if lib is None:
            return None
        if brake is not None:
            m = np.size(times)
            shapes = [np.shape(a) for a in brake]
            fits = shapes == [(m, m), (m, m), (m,), (n,)] and m > 1 and n > 1
            gemm = numpy_gemm() if fits else None
            blib = None if gemm is None else _brake_library()
            brake = None if blib is None else (blib, gemm, *brake)
        return cls(lib, n, suspension, times, brake)

    def __deepcopy__(self, memo) -> ServoPass:
        """A pass of its own (its call bound to its own buffers), the buffers' values copied.

        The copied buffers are entered in ``memo``: a servo state copied with its pass keeps
        its state in the new pass's buffers.
        """
        new = ServoPass(self._lib, self.n, self._suspension, self.times, self._brake)
        memo[id(self)] = new
        for name in ("setpoint", "deflection", "rates", "lower", "upper", "q_meas",
                     "measured", "times"):
            old = getattr(self, name)
            getattr(new, name)[:] = old
            memo[id(old)] = getattr(new, name)
        return new

    def _inputs(self, q_meas, measured) -> None:
        np.copyto(self.q_meas, q_meas)
        if measured is not None:
            np.copyto(self.measured, measured)

    def observe(self, q_meas, measured, resync: float, delay: float, a: float
                ) -> tuple[np.ndarray, ...]:
        """One observe and the free response: (q (n,), qd (n,), qf (m, n), vf (m, n)).

        Views of one new array. ``measured``: the servo setpoints (n,), or None;
        ``delay``: the allowance per unit of rate [s]; ``a``: the filter's gain.
        """
        self._inputs(q_meas, measured)
        out = np.empty((2 * (self.m + 1), self.n))
        self._call[measured is not None](resync, delay, a, address(out))
        m = self.m
        return out[0], out[1], out[2:m + 2], out[m + 2:]

    def observe_brake(self, q_meas, measured, resync: float, delay: float, a: float
                      ) -> tuple[np.ndarray, ...]:
        """`observe` and the brake trajectory of its (q, qd) at the limits (`make`).

        Returns:
            (q, qd, qf, vf, brake inputs, positions, velocities): views of one new array,
            the last three (m, n).

        Raises:
            ValueError: The brake's call refused the axes (more than 64).
        """
        self._inputs(q_meas, measured)
        m, table, scalars = self.m, self._table, self._scalars
        out = np.empty((5 * m + 2, self.n))
        table[_MEASURED] = 0 if measured is None else self._measured_at
        table[_OUT] = address(out)
        scalars[_RESYNC], scalars[_DELAY], scalars[_A] = resync, delay, a
        if self._call_brake() != 0:
            raise ValueError(f"brake inputs: {self.n} axes, at most 64")
        return (out[0], out[1], out[2:m + 2], out[m + 2:2 * m + 2], out[2 * m + 2:3 * m + 2],
                out[3 * m + 2:4 * m + 2], out[4 * m + 2:])

    def command(self, qdd: np.ndarray, dt: float, lower: np.ndarray, upper: np.ndarray,
                step: float) -> np.ndarray | None:
        """``clip(rates + qdd dt, lower, upper)`` (a new array), commanded.

        Then taken as the rates, the setpoint advanced by them over ``step`` and clipped to
        the setpoint range (`ServoState.commanded`). ``qdd``: float64, contiguous (n,);
        ``lower``, ``upper``: the velocity limits, taken when they are read-only float64
        (n,) arrays that own their data (the axis limits', which nobody changes: kept as
        copies while the same arrays come). None (nothing done) for other limits.
        """
        kept, table, scalars = self._limits, self._table, self._scalars
        if kept is None or kept[0] is not lower or kept[1] is not upper:
            constant = all(type(a) is np.ndarray and a.base is None and not a.flags.writeable
                           and a.shape == (self.n,) and a.dtype == np.float64
                           for a in (lower, upper))
            kept = self._limits = (lower, upper, *((np.array(lower), np.array(upper))
                                                  if constant else (None, None)))
            if constant:
                table[_VLO], table[_VHI] = address(kept[2]), address(kept[3])
        if kept[2] is None:
            return None
        out = np.empty(self.n)
        table[_QDD], table[_COMMAND_OUT] = address(qdd), address(out)
        scalars[_DT], scalars[_STEP] = dt, step
        self._command()
        return out


_MEASURED, _OUT, _QDD, _VLO, _VHI, _COMMAND_OUT = (
    _P_[n] for n in ("measured", "out", "qdd", "vlo", "vhi", "command_out"))
_RESYNC, _DELAY, _A, _DT, _STEP = (_S_[n] for n in ("resync", "delay", "a", "dt", "step"))
