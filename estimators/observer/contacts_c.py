"""The observer's contact geometry, longitudinal forces and flags (`contacts`) in C.

`contacts.ContactTracker` spends ~20 us a tick in Python on a few dozen floats: the wheels'
centres and the ground's normal, each side's drive torque split between its wheels, the
contact flags' hysteresis, and the arrays they go into. `CONTACTS_C` is the same arithmetic
in the same order (element-wise IEEE operations, compiled by `models.cbuild` without fused
multiply-adds): the same bits (`tests/test_observer_contacts_c.py`). Two calls a tick.
Without a compiler the Python code runs.
"""

from __future__ import annotations

import ctypes

from models.cbuild import load_shared

__all__ = ["CONSTANTS", "CONTACTS_C", "compiled_contacts"]

# The constants' places: wheel radius, the wheel's spin inertia, 1.0 for sphere wheels,
# then the flags' thresholds CONTACT_ON_N, CONTACT_OFF_N, CONTACT_TICKS, CONTACT_LANDING_N.
CONSTANTS = ("radius", "inertia", "sphere", "on", "off", "ticks", "landing")

CONTACTS_C = r"""
#include <math.h>

static double norm3(double x, double y, double z) { return sqrt(x * x + y * y + z * z); }

/* _vec3.ground_normal: the unit normal (z up) of the plane through the touching centres. */
static void ground_normal(const double* c, const double* touching, double* n) {
  int idx[4], m = 0, i;
  double u[3], v[3], len;
  for (i = 0; i < 4; ++i)
    if (touching[i] != 0.0) idx[m++] = i;
  n[0] = 0.0; n[1] = 0.0; n[2] = 1.0;
  if (m == 4) {  /* the quad's diagonals */
    for (i = 0; i < 3; ++i) { u[i] = c[9 + i] - c[i]; v[i] = c[3 + i] - c[6 + i]; }
  } else if (m == 3) {
    const double *a = c + 3 * idx[0], *b = c + 3 * idx[1], *d = c + 3 * idx[2];
    for (i = 0; i < 3; ++i) { u[i] = b[i] - a[i]; v[i] = d[i] - a[i]; }
  } else {
    return;
  }
  {
    double x = u[1] * v[2] - u[2] * v[1], y = u[2] * v[0] - u[0] * v[2];
    double z = u[0] * v[1] - u[1] * v[0];
    len = norm3(x, y, z);
    if (!(len > 1e-9)) return;
    if (z > 0) { n[0] = x / len; n[1] = y / len; n[2] = z / len; }
    else { n[0] = -x / len; n[1] = -y / len; n[2] = -z / len; }
  }
}

/* ContactTracker._longitudinal: force (4, 3) zero but its x, each side's drive torque
   (drive: flag, left, right) less its wheels' spin over the radius, split in proportion to
   the normal forces fz (4). Returns 1 if the forces are finite. */
static int longitudinal(const double* k, const double* drive, const double* acc,
                        const double* fz, double* force) {
  int i, side, ok = 1;
  for (i = 0; i < 12; ++i) force[i] = 0.0;
  if (drive[0] == 0.0) return 1;
  for (side = 0; side < 2; ++side) {
    int a = 2 * side, b = a + 1;
    double total = (drive[1 + side] - k[1] * (acc[a] + acc[b])) / k[0];
    double fa = (0.0 > fz[a]) ? 0.0 : fz[a], fb = (0.0 > fz[b]) ? 0.0 : fz[b];
    double s = fa + fb, sa = 0.5, sb = 0.5;
    if (s > 0) { sa = fa / s; sb = fb / s; }
    force[3 * a] = total * sa;
    force[3 * b] = total * sb;
    if (!isfinite(force[3 * a]) || !isfinite(force[3 * b])) ok = 0;
  }
  return ok;
}

/* ContactTracker.points: lowest (4, 3) the wheels' lowest points, up (3) R^T e_z, touching
   (4) the flags -> points (4, 3), normals (4, 3, each the ground's), and the longitudinal
   force (4, 3) at the normal forces fz (4). Returns bit 0: points and normal finite; bit 1:
   the force finite. */
int contact_points(const double* k, const double* lowest, const double* up_in,
                   const double* touching, const double* drive, const double* acc,
                   const double* fz, double* points, double* normals, double* force) {
  double up[3] = {up_in[0], up_in[1], up_in[2]}, n, r = k[0], ru[3], centre[12], nr[3];
  double rn[3];
  int i, j, finite = 1;
  if (k[2] == 0.0) {  /* a disc: lowest in its plane */
    up[1] = 0.0;
    n = norm3(up[0], up[1], up[2]);
    for (i = 0; i < 3; ++i) up[i] = up[i] / n;
  }
  for (j = 0; j < 3; ++j) ru[j] = r * up[j];
  for (i = 0; i < 4; ++i)
    for (j = 0; j < 3; ++j) centre[3 * i + j] = lowest[3 * i + j] + ru[j];
  ground_normal(centre, touching, nr);
  if (k[2] == 0.0) {
    nr[1] = 0.0;
    n = norm3(nr[0], nr[1], nr[2]);
    for (i = 0; i < 3; ++i) nr[i] = nr[i] / n;
  }
  for (j = 0; j < 3; ++j) {
    rn[j] = r * nr[j];
    if (!isfinite(nr[j])) finite = 0;
  }
  for (i = 0; i < 4; ++i)
    for (j = 0; j < 3; ++j) {
      points[3 * i + j] = centre[3 * i + j] - rn[j];
      normals[3 * i + j] = nr[j];
      if (!isfinite(points[3 * i + j])) finite = 0;
    }
  return finite | (longitudinal(k, drive, acc, fz, force) << 1);
}

/* ContactTracker.update: the flags' hysteresis on the forces fz (4) (above: ticks above
   CONTACT_ON_N; touching: 1.0 or 0.0), then the longitudinal force as in contact_points.
   Returns 1 if that force is finite. */
int contact_flags(const double* k, double* above, double* touching, const double* drive,
                  const double* acc, const double* fz, double* force) {
  int i;
  for (i = 0; i < 4; ++i) {
    double x = fz[i];
    int c = touching[i] != 0.0;
    above[i] = x > k[3] ? above[i] + 1.0 : 0.0;
    touching[i] = ((c && x >= k[4]) || (!c && (above[i] >= k[5] || x > k[6]))) ? 1.0 : 0.0;
  }
  return longitudinal(k, drive, acc, fz, force);
}
"""


def compiled_contacts():
    """The loaded `CONTACTS_C` (``contact_points``, ``contact_flags``), or None."""
    return load_shared(CONTACTS_C, "observer_contacts", {
        "contact_points": ([ctypes.c_void_p] * 10, ctypes.c_int),
        "contact_flags": ([ctypes.c_void_p] * 7, ctypes.c_int)}, "Python")
