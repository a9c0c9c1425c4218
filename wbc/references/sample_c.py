"""A Ruckig trajectory sampled in C: every axis at every node time in one call.

The MPC samples its references at the 13 node times of its horizon every tick; through
Ruckig's Python binding that is one ``Trajectory.at_time`` call per time (lists of Python
floats back), ~25 us a tick for the two references. A trajectory without intermediate
waypoints is one section of a profile per axis: seven phases of constant jerk, each axis
possibly preceded by a two-phase brake profile (a start above the limits), every phase's
start state in the profile (``t``, ``j``, ``a``, ``v``, ``p`` and the brake's, exposed by the
binding). `SAMPLE_C` evaluates them as Ruckig's ``Trajectory::at_time`` does
(``state_to_integrate_from``, then ``integrate``: ``p0 + t (v0 + t (a0 / 2 + t j / 6))``,
the same operations in the same order, the phases' end times summed as Ruckig sums them),
then does what `RuckigReference.sample_many_into` does with the samples: positions clipped
into the limits (numpy's clip), velocities times the clock rate, accelerations times its
square. The same bits as the binding's samples (`tests/test_ruckig_sample_c.py`, random
trajectories with brake phases); Ruckig's wheel is built without fused multiply-adds and so
is this (`models.cbuild`).
"""

from __future__ import annotations

import ctypes
import math

import numpy as np

from models.cbuild import address, bind, load_shared

__all__ = ["NODE_POINTERS", "NODE_SCALARS", "PROFILE_SIZE", "SAMPLE_C", "CompiledTrajectory",
           "compiled_trajectory"]

# ``sample_nodes``'s packed arguments, in their order.
NODE_POINTERS = ("profiles", "offsets", "times", "lower", "upper", "position", "velocity",
                 "acceleration")
NODE_SCALARS = ("duration", "t0", "tau", "rate", "rate2", "m", "ld", "n")

PROFILE_SIZE = 56  # doubles per axis: t, j (7), a, v, p (8), t_sum (7), the brake (11)

SAMPLE_C = r"""
#include <math.h>
/* One axis's profile: t[7], j[7], a[8], v[8], p[8], t_sum[7] (the phases' end times),
   brake duration, t[2], j[2], a[2], v[2], p[2]. */
enum { T = 0, J = 7, A = 14, V = 22, P = 30, TS = 38, BD = 45, BT = 46, BJ = 48, BA = 50,
       BV = 52, BP = 54, SIZE = 56 };

static inline void integrate(double t, double p0, double v0, double a0, double j,
                             double* p, double* v, double* a) {
  *p = p0 + t * (v0 + t * (a0 / 2 + t * j / 6));
  *v = v0 + t * (a0 + t * j / 2);
  *a = a0 + t * j;
}

/* numpy's clip of a float: the maximum with lo, then the minimum with hi, NaN kept */
static inline double clip(double x, double lo, double hi) {
  double m = isnan(x) ? x : (x > lo ? x : lo);
  return isnan(m) ? m : (m < hi ? m : hi);
}

/* Ruckig's at_time of n axes (profiles prof[n * SIZE], one section of length duration) at
   max(times[k] - t0, 0) (NaN kept; -0 gives +0, as numpy's SIMD maximum does, though the
   callers' times never tie at -0), k < m: position clipped into [lo, hi], velocity times
   rate, acceleration times rate2, into rows k of pos, vel, acc (row stride ld). */
void sample(const double* prof, long n, double duration, double t0, const double* times,
            long m, double rate, double rate2, const double* lo, const double* hi,
            double* pos, double* vel, double* acc, long ld) {
  for (long k = 0; k < m; ++k) {
    double time = times[k] - t0;
    time = (time > 0.0 || isnan(time)) ? time : 0.0;
    for (long d = 0; d < n; ++d) {
      const double* f = prof + d * SIZE;
      double p, v, a;
      if (time >= duration) { /* past the end: the last state, constant acceleration */
        integrate(time - (f[BD] + f[TS + 6]), f[P + 7], f[V + 7], f[A + 7], 0.0, &p, &v, &a);
      } else {
        double td = time;
        int done = 0;
        if (f[BD] > 0) {
          if (td < f[BD]) {
            int i = (td < f[BT]) ? 0 : 1;
            if (i > 0) td -= f[BT];
            integrate(td, f[BP + i], f[BV + i], f[BA + i], f[BJ + i], &p, &v, &a);
            done = 1;
          } else {
            td -= f[BD];
          }
        }
        if (!done) {
          if (td >= f[TS + 6]) {
            integrate(td - f[TS + 6], f[P + 7], f[V + 7], f[A + 7], 0.0, &p, &v, &a);
          } else {
            int i = 0;
            while (i < 7 && !(td < f[TS + i])) ++i; /* std::upper_bound */
            if (i > 0) td -= f[TS + i - 1];
            integrate(td, f[P + i], f[V + i], f[A + i], f[J + i], &p, &v, &a);
          }
        }
      }
      pos[k * ld + d] = clip(p, lo[d], hi[d]);
      vel[k * ld + d] = v * rate;
      acc[k * ld + d] = a * rate2;
    }
  }
}

/* `sample` at the times tau + rate * offsets[k] (numpy's product, then its sum), written
   to times[k] too; the arguments packed (`NODE_POINTERS`, `NODE_SCALARS`). */
void sample_nodes(void* const* p, const double* s) {
  const double* offsets = (const double*)p[1];
  double* times = (double*)p[2];
  long k, m = (long)s[5];
  for (k = 0; k < m; ++k) times[k] = s[2] + s[3] * offsets[k];
  sample((const double*)p[0], (long)s[7], s[0], s[1], times, m, s[3], s[4],
         (const double*)p[3], (const double*)p[4], (double*)p[5], (double*)p[6],
         (double*)p[7], (long)s[6]);
}
"""


_addressof, _char_view = ctypes.addressof, ctypes.c_char.from_buffer


def _library():
    p, lg, d = ctypes.c_void_p, ctypes.c_long, ctypes.c_double
    return load_shared(SAMPLE_C, "ruckig_sample", {
        "sample": ([p, lg, d, d, p, lg, d, d, p, p, p, p, p, lg], None),
        "sample_nodes": ([p, p], None)},
        "Ruckig's at_time")


class CompiledTrajectory:
    """The profiles of one n-axis Ruckig trajectory, sampled in C (module docstring).

    Args:
        fun: `SAMPLE_C`'s ``sample``.
        lower, upper: The position limits the samples are clipped into, (n,).
        nodes: `SAMPLE_C`'s ``sample_nodes`` (`sample_nodes`); None: not offered.
    """

    def __init__(self, fun, lower: np.ndarray, upper: np.ndarray, nodes=None):
        self.n = n = lower.size
        self.lower = np.ascontiguousarray(lower, dtype=float)
        self.upper = np.ascontiguousarray(upper, dtype=float)
        self.profiles = np.zeros((n, PROFILE_SIZE))
        self.duration = 0.0
        self._times = np.zeros(0)
        self._fun = fun
        self._args = (self.profiles.ctypes.data, n)
        self._limits = (self.lower.ctypes.data, self.upper.ctypes.data)
        # `sample_nodes`'s packed arguments: the offsets copied when another array comes
        self._node_p = np.zeros(len(NODE_POINTERS), np.uint64)
        self._node_s = np.zeros(len(NODE_SCALARS))
        self._node_p[[0, 3, 4]] = (self._args[0], *self._limits)
        self._offsets_of: np.ndarray | None = None
        self._nodes = bind(nodes, self._node_p, self._node_s) if nodes is not None else None

    def load(self, trajectory) -> bool:
        """Take ``trajectory``'s profiles (after each `Ruckig.calculate`).

        False (nothing taken) for a trajectory of several sections (intermediate
        waypoints) or another number of axes.
        """
        sections = trajectory.profiles
        if len(sections) != 1 or len(sections[0]) != self.n:
            return False
        rows = []
        for pr in sections[0]:
            t, b = list(pr.t), pr.brake
            t_sum = [t[0]]
            for dt in t[1:]:
                t_sum.append(t_sum[-1] + dt)  # Ruckig's own sums, in its order
            rows.append(t + list(pr.j) + list(pr.a) + list(pr.v) + list(pr.p) + t_sum
                        + [b.duration] + list(b.t) + list(b.j) + list(b.a) + list(b.v)
                        + list(b.p))
        self.profiles[:] = rows
        self.duration = float(trajectory.duration)
        return True

    def sample_into(self, times: np.ndarray, t0: float, rate: float, position: np.ndarray,
                    velocity: np.ndarray, acceleration: np.ndarray) -> bool:
        """Samples at ``max(times - t0, 0)`` written into arrays of shape (len(times), n).

        Positions clipped into the limits, velocities times ``rate``, accelerations times
        ``rate**2``. The three arrays: float64 with unit column stride and one row stride
        (views of one node array's columns are fine); ``times``: float64, contiguous.
        False (nothing written) for arrays it cannot take.
        """
        m = times.shape[0]
        ld = position.strides[0]
        for a in (position, velocity, acceleration):
            if (a.dtype != np.float64 or a.shape != (m, self.n) or a.strides[0] != ld
                    or (self.n > 1 and a.strides[1] != 8) or ld % 8 or ld <= 0
                    or not a.flags.writeable):
                return False
        if times.dtype != np.float64 or not times.flags.c_contiguous:
            return False
        self._fun(*self._args, self.duration, t0, address(times), m, rate, rate**2,
                  *self._limits, address(position), address(velocity),
                  address(acceleration), ld // 8)
        return True


    def sample_columns(self, times: np.ndarray, t0: float, rate: float, first: int,
                       position: np.ndarray, velocity: np.ndarray,
                       acceleration: np.ndarray) -> bool:
        """`sample_into` the columns ``first .. first + n`` of three (len(times), k) arrays.

        The arrays: float64, C-contiguous, of one shape (the MPC's node arrays of all nine
        axes, each reference writing its own columns): their addresses cost a fifth of a
        strided view's. False (nothing written) for arrays it cannot take.
        """
        m, k = position.shape
        if not (position.shape == velocity.shape == acceleration.shape and m == times.shape[0]
                and 0 <= first and first + self.n <= k and position.dtype == velocity.dtype
                == acceleration.dtype == times.dtype == np.float64):
            return False
        if not (position.flags.c_contiguous and velocity.flags.c_contiguous
                and acceleration.flags.c_contiguous and times.flags.c_contiguous
                and position.flags.writeable and velocity.flags.writeable
                and acceleration.flags.writeable):
            return False
        self._fun(*self._args, self.duration, t0, address(times), m, rate, rate**2,
                  *self._limits, address(position) + 8 * first, address(velocity) + 8 * first,
                  address(acceleration) + 8 * first, k)
        return True


    def sample_nodes(self, tau: float, rate: float, offsets: np.ndarray, t0: float,
                     first: int, position: np.ndarray, velocity: np.ndarray,
                     acceleration: np.ndarray) -> float | None:
        """`sample_columns` at the times ``tau + rate * offsets``, computed in the same call.

        The MPC's node times every tick: numpy's ``tau + rate * offsets`` in C (its product,
        then its sum, per element), the arguments packed, the offsets (a read-only array
        kept by its owner, not changed in place) copied when another array comes. The
        arrays as `sample_columns` takes them. Returns the first time (or NaN without
        offsets), or None (nothing written) for arrays it cannot take.
        """
        m, k = position.shape
        if not (self._nodes is not None and offsets.ndim == 1
                and position.shape == velocity.shape
                == acceleration.shape and m == offsets.shape[0] and 0 <= first
                and first + self.n <= k and position.dtype == velocity.dtype
                == acceleration.dtype == offsets.dtype == np.float64):
            return None
        try:  # a ctypes view takes writable, C-contiguous, non-empty buffers only
            at_p = _addressof(_char_view(position))
            at_v = _addressof(_char_view(velocity))
            at_a = _addressof(_char_view(acceleration))
        except (TypeError, ValueError, BufferError):
            if m:
                return None
            at_p = at_v = at_a = 0  # no node: nothing is written
        p = self._node_p
        if offsets is not self._offsets_of:
            self._offsets = np.array(offsets, float)
            self._node_times = np.zeros(max(m, 1))
            p[1], p[2] = address(self._offsets), address(self._node_times)
            self._offsets_of = offsets
        p[5], p[6], p[7] = at_p + 8 * first, at_v + 8 * first, at_a + 8 * first
        self._node_s[:] = (self.duration, t0, tau, rate, rate**2, m, k, self.n)
        self._nodes()
        return float(self._node_times[0]) if m else math.nan


def compiled_trajectory(lower: np.ndarray, upper: np.ndarray) -> CompiledTrajectory | None:
    """A `CompiledTrajectory` for these limits; None without a C compiler."""
    lib = _library()
    return None if lib is None else CompiledTrajectory(lib.sample, lower, upper,
                                                       lib.sample_nodes)
