"""`ServoState.observe` and the free response of its result in one compiled pass.

Every MPC tick `ServoState.observe` (the setpoint's resync, the deflection filter: a dozen
ufuncs on nine numbers) and `CondensedPrediction.free_response` of the ``(q, qd)`` it gives
(two (N, 9) arrays) take ~15 us of the closed loop's tick for a few hundred flops. `SERVO_C`
does numpy's IEEE operations in numpy's order, element by element as the ufuncs do (compiled
with ``-ffp-contract=off``, `models.cbuild`: no fused multiply-adds), so the same bits
(`tests/test_servo_state_c.py` compares the two paths). Without a compiler the numpy path
runs.
"""

from __future__ import annotations

import ctypes

import numpy as np

from models.cbuild import address, bind, load_shared

__all__ = ["SERVO_C", "ServoPass"]

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
"""

_P, _L, _D = ctypes.c_void_p, ctypes.c_long, ctypes.c_double


def _library():
    return load_shared(SERVO_C, "servo_state", {
        "servo_observe": ([_P] * 5 + [_L] * 3 + [_P, _L] + [_D] * 3 + [_P], ctypes.c_int)},
        "the servo state's numpy")


class ServoPass:
    """``servo_observe`` bound to kept buffers (made at construction).

    Attributes:
        setpoint, deflection, rates: The servo state's arrays (9,) (`ServoState` keeps its
            state here).
        q_meas, measured: A call's measured positions and servo setpoints, copied in.

    Args:
        lib: `_library`'s library.
        n: The number of axes.
        suspension: The axes whose deflection is zero, a slice.
        times: The free response's times [s] (m,), kept.
    """

    def __init__(self, lib, n: int, suspension: slice, times: np.ndarray):
        self._lib, self._suspension = lib, suspension
        self.setpoint, self.deflection, self.rates = np.zeros(n), np.zeros(n), np.zeros(n)
        self.q_meas, self.measured = np.zeros(n), np.zeros(n)
        self.times = np.array(times, float)
        self.n, self.m = n, self.times.size
        head = (self.setpoint, self.deflection, self.rates, self.q_meas)
        tail = (n, suspension.start, suspension.stop, self.times, self.m)
        self._call = {True: bind(lib.servo_observe, *head, self.measured, *tail),
                      False: bind(lib.servo_observe, *head, None, *tail)}

    @classmethod
    def make(cls, n: int, suspension: slice, times: np.ndarray) -> ServoPass | None:
        """A pass, or None without a compiler."""
        lib = _library()
        return None if lib is None else cls(lib, n, suspension, times)

    def __deepcopy__(self, memo) -> ServoPass:
        """A pass of its own (its call bound to its own buffers), the buffers' values copied.

        The copied buffers are entered in ``memo``: a servo state copied with its pass keeps
        its state in the new pass's buffers.
        """
        new = ServoPass(self._lib, self.n, self._suspension, self.times)
        memo[id(self)] = new
        for name in ("setpoint", "deflection", "rates", "q_meas", "measured", "times"):
            old = getattr(self, name)
            getattr(new, name)[:] = old
            memo[id(old)] = getattr(new, name)
        return new

    def observe(self, q_meas, measured, resync: float, delay: float, a: float
                ) -> tuple[np.ndarray, ...]:
        """One observe and the free response: (q (n,), qd (n,), qf (m, n), vf (m, n)).

        Views of one new array. ``measured``: the servo setpoints (n,), or None;
        ``delay``: the allowance per unit of rate [s]; ``a``: the filter's gain.
        """
        n, m = self.n, self.m
        np.copyto(self.q_meas, q_meas)
        if measured is not None:
            np.copyto(self.measured, measured)
        out = np.empty(2 * n * (m + 1))
        self._call[measured is not None](resync, delay, a, address(out))
        return (out[:n], out[n:2 * n], out[2 * n:(m + 2) * n].reshape(m, n),
                out[(m + 2) * n:].reshape(m, n))
