"""The closed loop's margin ``z sigma`` in one compiled pass (`estimators.uncertainty`).

A control tick asks for the margin once: `normal_force_std` on the closure's linearization
with the load split the two models disagree on (``G_c - G_m``), the suspension sensitivity
from the stepped forces and the payload's, then `force_margin`. In numpy that is ~25 small
calls (~15 us); here it is one call of C that does the same IEEE operations in numpy's order:
each row's sum of squares is numpy's pairwise summation (`pairwise`, numpy's
``pairwise_sum`` for rows shorter than its 128-element block: eight running sums, combined in
a tree, then the rest in turn), so the margin is the same bits
(`tests/test_uncertainty_c.py` compares them). Without a compiler the numpy path runs.
"""

from __future__ import annotations

import ctypes

import numpy as np

from models.cbuild import address, bind, load_shared

__all__ = ["MARGIN_C", "MarginPass", "compiled_margin"]

# margin[i] = z sqrt(sum_k (g_ik sa_k)^2 + sum_j (dqd_ij sqd_j)^2 + sum_s (ds_is ss_s)^2
#                    + (dm_i sm)^2), 0 for a wheel off the ground; g = gc - gm (gm NULL: gc).
# ds_is = (stepped[1 + s][i] - stepped[0][i]) / step (stepped NULL: no suspension term);
# dm NULL: no payload term. Returns 1, writing nothing, if g is not finite.
MARGIN_C = r"""
#include <math.h>
static double pairwise(const double* a, int n) {
  double r[8], res = 0.0;
  int i, j;
  if (n < 8) {
    for (i = 0; i < n; ++i) res += a[i];
    return res;
  }
  for (j = 0; j < 8; ++j) r[j] = a[j];
  for (i = 8; i < n - n % 8; i += 8)
    for (j = 0; j < 8; ++j) r[j] += a[i + j];
  res = ((r[0] + r[1]) + (r[2] + r[3])) + ((r[4] + r[5]) + (r[6] + r[7]));
  for (; i < n; ++i) res += a[i];
  return res;
}

int force_margin(const double* gc, const double* gm, int na, const double* sa,
                 const double* dqd, int nq, const double* sqd, const double* stepped,
                 double step, const double* ss, const double* dm, double sm,
                 const unsigned char* in_contact, double z, double* margin) {
  double g[4 * 64], sq[64], total[4], ds[2];
  int i, k;
  if (na > 64 || nq > 64) return 2;
  for (k = 0; k < 4 * na; ++k) {
    g[k] = gm ? gc[k] - gm[k] : gc[k];
    if (!isfinite(g[k])) return 1;
  }
  for (i = 0; i < 4; ++i) {
    for (k = 0; k < na; ++k) { double v = g[i * na + k] * sa[k]; sq[k] = v * v; }
    total[i] = pairwise(sq, na);
    for (k = 0; k < nq; ++k) { double v = dqd[i * nq + k] * sqd[k]; sq[k] = v * v; }
    total[i] = total[i] + pairwise(sq, nq);
    if (stepped) {
      for (k = 0; k < 2; ++k) {
        ds[k] = (stepped[4 * (1 + k) + i] - stepped[i]) / step;
        double v = ds[k] * ss[k];
        sq[k] = v * v;
      }
      total[i] += pairwise(sq, 2);
    }
    if (dm) { double v = dm[i] * sm; total[i] += v * v; }
  }
  for (i = 0; i < 4; ++i) margin[i] = z * (in_contact[i] ? sqrt(total[i]) : 0.0);
  return 0;
}
"""

_P = ctypes.c_void_p


def compiled_margin():
    """`MARGIN_C`'s ``force_margin``, or None without a working compiler."""
    lib = load_shared(MARGIN_C, "force_margin", {"force_margin": (
        [_P, _P, ctypes.c_int, _P, _P, ctypes.c_int, _P, _P, ctypes.c_double, _P, _P,
         ctypes.c_double, _P, ctypes.c_double, _P], ctypes.c_int)}, "numpy's margin")
    return None if lib is None else lib.force_margin


class MarginPass:
    """`MARGIN_C`'s ``force_margin`` on buffers kept for its life, bound once.

    A tick's arrays (the linearizations', the stepped forces', the uncertainty's, most of
    them read-only, whose ``ctypes.data`` costs ~1.5 us each) are copied into the kept
    buffers (the same values, so the same bits) and the function is called on the
    buffers' addresses, bound at construction: ~4 us a tick instead of ~15.

    Args:
        fun: `compiled_margin`'s function.
        n_acceleration, n_qd: The lengths of ``a`` and of the joint velocities.
        step: The suspension forces' step [N] of the stepped forces.
    """

    def __init__(self, fun, n_acceleration: int, n_qd: int, step: float):
        na, nq = n_acceleration, n_qd
        self.g_closure, self.g_model = np.zeros((4, na)), np.zeros((4, na))
        self.sigma_a, self.d_qd, self.sigma_qd = np.zeros(na), np.zeros((4, nq)), np.zeros(nq)
        self.stepped, self.sigma_s = np.zeros((3, 4)), np.zeros(2)
        self.d_payload, self.in_contact = np.zeros(4), np.zeros(4, np.uint8)
        tail = (na, self.sigma_a, self.d_qd, nq, self.sigma_qd, self.stepped, float(step),
                self.sigma_s)
        self._call = {True: bind(fun, self.g_closure, self.g_model, *tail),
                      False: bind(fun, self.g_closure, None, *tail)}
        self._d_payload, self._in_contact = address(self.d_payload), address(self.in_contact)
        self._sigmas = None  # the uncertainty's arrays last copied, if they cannot change

    def _copy_sigmas(self, uncertainty) -> None:
        """The uncertainty's three arrays into the buffers, unless they are there already.

        The observer hands the same read-only arrays every tick (only the payload's std
        changes): arrays that own their read-only data cannot change, so the last ones
        copied, kept here, need no copy again.
        """
        a, qd, s = uncertainty.acceleration, uncertainty.qd, uncertainty.suspension_force
        kept = self._sigmas
        if kept is not None and a is kept[0] and qd is kept[1] and s is kept[2]:
            return
        sigmas = (a, qd, s)
        np.copyto(self.sigma_a, sigmas[0])
        np.copyto(self.sigma_qd, sigmas[1])
        np.copyto(self.sigma_s, sigmas[2])
        fixed = all(type(a) is np.ndarray and a.base is None and not a.flags.writeable
                    for a in sigmas)
        self._sigmas = sigmas if fixed else None

    def __call__(self, g_closure, g_model, d_qd, stepped, d_payload, in_contact,
                 uncertainty, z: float) -> np.ndarray | None:
        """The margin ``z sigma`` [N] (4,), a new array; None if ``G_c - G_m`` is not finite.

        Args:
            g_closure: ``G`` of the closure (4, na).
            g_model: ``G`` of the model (4, na); None: ``G_c`` alone.
            d_qd: The closure's ``df/dqd`` (4, nq).
            stepped: The closure's forces at the suspension forces and each stepped (3, 4).
            d_payload: ``df/dm`` (4,), or None: no payload term.
            in_contact: Contact flags (4,).
            uncertainty: The `estimators.uncertainty.StateUncertainty`.
            z: The confidence's quantile.
        """
        np.copyto(self.g_closure, g_closure)
        if g_model is not None:
            np.copyto(self.g_model, g_model)
        self._copy_sigmas(uncertainty)
        np.copyto(self.d_qd, d_qd)
        np.copyto(self.stepped, stepped)
        if d_payload is not None:
            np.copyto(self.d_payload, d_payload)
        np.copyto(self.in_contact, in_contact)
        margin = np.empty(4)
        if self._call[g_model is not None](
                None if d_payload is None else self._d_payload, uncertainty.payload_mass,
                self._in_contact, z, address(margin)):
            return None
        return margin
