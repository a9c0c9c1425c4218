"""`SpeedGovernor`'s tick in C: its filters' update and the cap's ratios, on kept buffers.

`wbc.force_models.fluctuation.SpeedGovernor` runs every control tick on four wheels: ~20
numpy calls on (4,) arrays and a Python loop (~15 us a tick in the closed loop). Here the
update is one call and the cap's per-wheel ratios another, doing numpy's and Python's IEEE
operations in their order (compiled with ``-ffp-contract=off``, `models.cbuild`): each
element's filter steps are independent of the others, so an element-wise loop is numpy's
whole-array steps. The cap's smallest ratio and its clip stay numpy's (`_min`, `clip`: its
rules for NaN and signed zeros). Without a compiler the Python path runs;
`tests/test_fluctuation_c.py` compares the two bit for bit.
"""

from __future__ import annotations

import ctypes

import numpy as np

from models.cbuild import address, bind, load_shared

__all__ = ["GOVERNOR_C", "GovernorPass"]

# st: [scale_lag, speed_square]. update: 1 when per_speed (written to `per_speed`) changed,
# 0 otherwise. ratios: the number of wheels written to `ratios` (-1: no ratio to take,
# the cap is 1).
GOVERNOR_C = r"""
#include <math.h>
int governor_update(double* mean, double* square, double* per_speed, double* st,
                    const double* f, const unsigned char* contact, double dt, double speed,
                    double speed_scale, double drive_tc, double high_pass, double window,
                    double min_speed) {
  int i;
  if (dt > 0) st[0] += dt / (drive_tc + dt) * (speed_scale - st[0]);
  for (i = 0; i < 4; ++i) if (!contact[i]) return 0;
  for (i = 0; i < 4; ++i) if (!isfinite(f[i])) return 0;
  if (!isfinite(speed)) return 0;
  if (!(dt > 0)) return 0;
  double a = dt / (high_pass + dt);
  for (i = 0; i < 4; ++i) mean[i] += a * (f[i] - mean[i]);
  if (!(speed >= min_speed)) return 0;
  double b = dt / (window + dt);
  for (i = 0; i < 4; ++i) {
    double h = f[i] - mean[i];
    square[i] += b * (h * h - square[i]);
  }
  st[1] += b * (speed * speed - st[1]);
  for (i = 0; i < 4; ++i) per_speed[i] = sqrt(square[i] / st[1]);
  return 1;
}

int governor_ratios(const double* mean, const double* per_speed, const double* thresholds,
                    const unsigned char* contact, double scale_lag, double speed, double z,
                    double min_scale, double* ratios) {
  int i, n = 0, any = 0;
  for (i = 0; i < 4; ++i) if (per_speed[i] > 0) any = 1;
  if (!any) return -1;
  double lag = min_scale > scale_lag ? min_scale : scale_lag;  /* Python's max */
  double v_nom = speed / lag;
  if (!(isfinite(v_nom) && v_nom > 0)) return -1;
  for (i = 0; i < 4; ++i) {
    double need = z * per_speed[i] * v_nom;
    if (contact[i] && need > 0) ratios[n++] = (mean[i] - thresholds[i]) / need;
  }
  return n ? n : -1;
}
"""

_P, _D = ctypes.c_void_p, ctypes.c_double


def _library():
    return load_shared(GOVERNOR_C, "speed_governor", {
        "governor_update": ([_P] * 6 + [_D] * 7, ctypes.c_int),
        "governor_ratios": ([_P] * 4 + [_D] * 4 + [_P], ctypes.c_int)},
        "the speed governor's numpy")


class GovernorPass:
    """One governor's C calls, bound to its kept buffers (made at construction).

    Attributes:
        mean, square: The governor's slow loads and mean squares [N, N^2], (4,), its own
            arrays (`SpeedGovernor` keeps them here).
        state: ``[scale_lag, speed_square]`` (`SpeedGovernor` keeps them here).
        forces, contact, thresholds, per_speed: A call's inputs, copied in.
        out, quotients: The new ``per_speed``; the cap's ratios of the wheels that count.
    """

    def __init__(self, lib):
        self._lib = lib
        self.mean, self.square, self.state = np.zeros(4), np.zeros(4), np.zeros(2)
        self.forces, self.contact = np.zeros(4), np.zeros(4, bool)
        self.thresholds, self.per_speed = np.zeros(4), np.zeros(4)
        self.out, self.quotients = np.zeros(4), np.zeros(4)
        self._update = bind(lib.governor_update, self.mean, self.square, self.out,
                            self.state, self.forces, self.contact)
        self._ratios = bind(lib.governor_ratios, self.mean, self.per_speed, self.thresholds,
                            self.contact)
        self._quotients_at = address(self.quotients)

    def __deepcopy__(self, memo) -> GovernorPass:
        """A pass of its own (its calls bound to its own buffers), the buffers' values copied.

        The copied buffers are entered in ``memo``: a governor copied with its pass keeps
        its state in the new pass's buffers.
        """
        new = GovernorPass(self._lib)
        memo[id(self)] = new
        for name in ("mean", "square", "state", "forces", "contact", "thresholds",
                     "per_speed", "out", "quotients"):
            old = getattr(self, name)
            getattr(new, name)[:] = old
            memo[id(old)] = getattr(new, name)
        return new

    @classmethod
    def make(cls) -> GovernorPass | None:
        """A pass, or None without a compiler."""
        lib = _library()
        return None if lib is None else cls(lib)

    def update(self, forces, in_contact, dt: float, speed: float, speed_scale: float,
               constants: tuple) -> np.ndarray | None:
        """One update; the new ``per_speed`` (a new array) if it changed, else None.

        ``constants``: (drive time constant, high pass, window, min speed) [s, s, s, m/s].
        """
        np.copyto(self.forces, forces)
        np.copyto(self.contact, in_contact)
        if self._update(dt, speed, speed_scale, *constants):
            return self.out.copy()
        return None

    def ratios(self, per_speed, thresholds, in_contact, speed: float, z: float,
               min_scale: float) -> np.ndarray | None:
        """The cap's ratios (a view of `quotients`), or None: no wheel to cap by (cap 1)."""
        np.copyto(self.per_speed, per_speed)
        np.copyto(self.thresholds, thresholds)
        np.copyto(self.contact, in_contact)
        n = self._ratios(self.state[0], speed, z, min_scale, self._quotients_at)
        return None if n < 0 else self.quotients[:n]
