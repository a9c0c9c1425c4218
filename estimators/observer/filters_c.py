"""The observer's chassis and joint filters in C: one call each per control tick.

(And the tick's mean cylinder forces from the chamber pressures, `cylinder_forces`; and
`observer_tick`, which runs those with the observer's checks and wheels in one call: `_tick`.)

`base_filter.BaseFilter` and `joint_filter.JointFilter` are a few hundred floating-point
operations a tick, which Python spends ~70 us on (float arithmetic and numpy calls on
3-vectors and 9x3 arrays). `FILTERS_C` is the same arithmetic in the same order, compiled
once with the system compiler (`models.cbuild`, no contraction into fused multiply-adds) and
called through ctypes on the filters' own state buffers. The element-wise operations are
the Python code's, bit for bit; the 3x3 and 9x3 matrix products sum left to right, where
numpy's BLAS may fuse multiply-adds: the results agree to round-off
(`tests/test_observer_filters_c.py`). Without a compiler the Python code runs.
"""

from __future__ import annotations

import ctypes

from models.cbuild import load_shared

__all__ = ["BASE_FIELDS", "BASE_STATE", "FILTERS_C", "compiled_filters"]

# The chassis filter's state buffer: places of its fields. The first 21 are a
# `MachineState`'s base fields after its position (rotation row-major, twist [v; w],
# acceleration [v_dot; alpha]): the observer copies them in one slice.
BASE_STATE = {"rotation": slice(0, 9), "v": slice(9, 12), "w": slice(12, 15),
              "v_dot": slice(15, 18), "alpha": slice(18, 21), "last_rate": slice(21, 24),
              "odometry": slice(24, 27), "f": slice(27, 30), "age": 30, "rotation_valid": 31}
BASE_FIELDS = slice(0, 21)
BASE_STATE_SIZE = 32
# Its constants: lever arm p (3), g, wheel radius, the three time constants,
# `models.state.ROTATION_TOLERANCE`.
BASE_CONSTANTS_SIZE = 9

FILTERS_C = r"""
#include <math.h>
#include <string.h>

static void mat3_mul(const double* a, const double* b, double* out) {
  double t[9];
  int i, j;
  for (i = 0; i < 3; ++i)
    for (j = 0; j < 3; ++j)
      t[3 * i + j] = a[3 * i] * b[j] + a[3 * i + 1] * b[3 + j] + a[3 * i + 2] * b[6 + j];
  memcpy(out, t, sizeof t);
}

static double norm3(double x, double y, double z) { return sqrt(x * x + y * y + z * z); }

/* base_filter._exp: Rodrigues of the rotation vector (x, y, z). */
static void rot_exp(double x, double y, double z, double* out) {
  double angle = norm3(x, y, z), ax, ay, az, n, s, c, kk[9];
  int i;
  if (angle < 1e-12) {
    for (i = 0; i < 9; ++i) out[i] = (i % 4 == 0) ? 1.0 : 0.0;
    return;
  }
  ax = x / angle; ay = y / angle; az = z / angle;
  n = norm3(ax, ay, az);
  ax = ax / n; ay = ay / n; az = az / n;
  {
    double k[9] = {0.0, -az, ay, az, 0.0, -ax, -ay, ax, 0.0};
    mat3_mul(k, k, kk);
    s = sin(angle);
    c = 1.0 - cos(angle);
    for (i = 0; i < 9; ++i) out[i] = ((i % 4 == 0 ? 1.0 : 0.0) + s * k[i]) + c * kk[i];
  }
}

/* base_filter._orthonormal: rows re-orthonormalised (Gram-Schmidt from the third). */
static void orthonormal(double* r) {
  double n = norm3(r[6], r[7], r[8]);
  double z0 = r[6] / n, z1 = r[7] / n, z2 = r[8] / n;
  double d = r[0] * z0 + r[1] * z1 + r[2] * z2;
  double x0 = r[0] - d * z0, x1 = r[1] - d * z1, x2 = r[2] - d * z2;
  n = norm3(x0, x1, x2);
  x0 = x0 / n; x1 = x1 / n; x2 = x2 / n;
  r[0] = x0; r[1] = x1; r[2] = x2;
  r[3] = z1 * x2 - z2 * x1; r[4] = z2 * x0 - z0 * x2; r[5] = z0 * x1 - z1 * x0;
  r[6] = z0; r[7] = z1; r[8] = z2;
}

/* models.state.check_rotation's test (its expressions, in its order): 1.0 if r passes. */
static double rotation_valid(const double* r, double tol) {
  double a = r[0], b = r[1], c = r[2], d = r[3], e = r[4], f = r[5], g = r[6], h = r[7];
  double i = r[8], m = 0.0, err = 0.0, x[6], det;
  int k;
  for (k = 0; k < 9; ++k) {
    if (!isfinite(r[k])) return 0.0;
    if (fabs(r[k]) > m) m = fabs(r[k]);
  }
  if (!(m <= 1.0 + tol)) return 0.0;
  x[0] = fabs(a * a + b * b + c * c - 1.0); x[1] = fabs(d * d + e * e + f * f - 1.0);
  x[2] = fabs(g * g + h * h + i * i - 1.0); x[3] = fabs(a * d + b * e + c * f);
  x[4] = fabs(a * g + b * h + c * i); x[5] = fabs(d * g + e * h + f * i);
  for (k = 0; k < 6; ++k)
    if (x[k] > err) err = x[k];
  det = a * (e * i - f * h) - b * (d * i - f * g) + c * (d * h - e * g);
  return (err <= tol && det > 0) ? 1.0 : 0.0;
}

/* BaseFilter.update after its first tick's checks: s the state (BASE_STATE), c the
   constants (p, g, wheel radius, tau_alpha, tau_odometry, attitude time constant, the
   rotation's tolerance), in = dt,
   the tick's mean rate (3) and specific force (3), wheel flag, left, right (used when the
   flag is set and both are finite). Returns 1, the state untouched, if a mean is not
   finite. */
int base_step(double* s, const double* c, const double* in) {
  double *R = s, *v = s + 9, *w = s + 12, *vd = s + 15, *al = s + 18, *lr = s + 21;
  double *od = s + 24, *f = s + 27;
  const double *p = c;
  const double dt = in[0], wx = in[1], wy = in[2], wz = in[3];
  const double fx = in[4], fy = in[5], fz = in[6];
  double e[9], c1x, c1y, c1z, cx, cy, cz, c2x, c2y, c2z, vx, vy, vz;
  int i;
  for (i = 1; i < 7; ++i)
    if (!isfinite(in[i])) return 1;
  if (dt > 0) {
    double a;
    rot_exp(wx * dt, wy * dt, wz * dt, e);
    mat3_mul(R, e, R);
    a = dt / (c[5] + dt);
    al[0] = al[0] + a * ((wx - lr[0]) / dt - al[0]);
    al[1] = al[1] + a * ((wy - lr[1]) / dt - al[1]);
    al[2] = al[2] + a * ((wz - lr[2]) / dt - al[2]);
  }
  w[0] = lr[0] = wx; w[1] = lr[1] = wy; w[2] = lr[2] = wz;
  /* f_o = f_p - alpha x p - w x (w x p) */
  c1x = al[1] * p[2] - al[2] * p[1]; c1y = al[2] * p[0] - al[0] * p[2];
  c1z = al[0] * p[1] - al[1] * p[0];
  cx = wy * p[2] - wz * p[1]; cy = wz * p[0] - wx * p[2]; cz = wx * p[1] - wy * p[0];
  c2x = wy * cz - wz * cy; c2y = wz * cx - wx * cz; c2z = wx * cy - wy * cx;
  f[0] = fx - c1x - c2x; f[1] = fy - c1y - c2y; f[2] = fz - c1z - c2z;
  vx = v[0]; vy = v[1]; vz = v[2];
  if (in[7] != 0.0 && isfinite(in[8]) && isfinite(in[9])) {
    vx = c[4] * 0.5 * (in[8] + in[9]); vy = 0.0; vz = 0.0;
  }
  if (dt > 0) {
    double cc = dt / (c[6] + dt), gx, gy, gz, b, n, ux, uy, uz, x, y, z, t;
    od[0] = od[0] + cc * ((vx - v[0]) / dt - od[0]);
    od[1] = od[1] + cc * ((vy - v[1]) / dt - od[1]);
    od[2] = od[2] + cc * ((vz - v[2]) / dt - od[2]);
    cx = wy * vz - wz * vy; cy = wz * vx - wx * vz; cz = wx * vy - wy * vx;
    gx = f[0] - od[0] - cx; gy = f[1] - od[1] - cy; gz = f[2] - od[2] - cz;
    s[30] += dt;
    t = 0.05 + s[30];
    b = dt / ((t < c[7] ? t : c[7]) + dt);
    n = norm3(gx, gy, gz);
    ux = gx / n; uy = gy / n; uz = gz / n;
    x = uy * R[8] - uz * R[7]; y = uz * R[6] - ux * R[8]; z = ux * R[7] - uy * R[6];
    rot_exp(b * x, b * y, b * z, e);
    mat3_mul(R, e, R);
    orthonormal(R);
  }
  v[0] = vx; v[1] = vy; v[2] = vz;
  /* BaseFilter._v_dot: f - w x v - g R^T e_z */
  cx = wy * vz - wz * vy; cy = wz * vx - wx * vz; cz = wx * vy - wy * vx;
  vd[0] = f[0] - cx - c[3] * R[6];
  vd[1] = f[1] - cy - c[3] * R[7];
  vd[2] = f[2] - cz - c[3] * R[8];
  s[31] = rotation_valid(R, c[8]);
  return 0;
}

/* JointFilter.predict transposed into rows of `stride`: out (3, stride) the positions,
   velocities and accelerations of the n axes dt after the state x (n, 3). */
static void predict_into(const double* x, long n, double* out, long stride, double dt) {
  long i;
  for (i = 0; i < n; ++i) {
    const double* xi = x + 3 * i;
    out[i] = xi[0] + dt * xi[1] + 0.5 * dt * dt * xi[2];
    out[stride + i] = xi[1] + dt * xi[2];
    out[2 * stride + i] = xi[2];
  }
}

/* JointFilter.predict transposed: out (3, n). */
int joint_predict(const double* x, long n, double* out, double dt) {
  predict_into(x, n, out, n, dt);
  return 0;
}

/* Observer._cylinder_forces: out (5) the mean over k samples p (k, 10) of each cylinder's
   p_A A_A - p_B A_B, summed in numpy's order (row after row). Returns 1 if one is not
   finite. */
int cylinder_forces(const double* aa, const double* ab, double* out, const double* p,
                    long k) {
  long i, j;
  int bad = 0;
  for (j = 0; j < 5; ++j) out[j] = p[2 * j] * aa[j] - p[2 * j + 1] * ab[j];
  for (i = 1; i < k; ++i)
    for (j = 0; j < 5; ++j)
      out[j] = out[j] + (p[10 * i + 2 * j] * aa[j] - p[10 * i + 2 * j + 1] * ab[j]);
  for (j = 0; j < 5; ++j) {
    out[j] = out[j] / (double)k;
    if (!isfinite(out[j])) bad = 1;
  }
  return bad;
}

/* JointFilter.update's loop: x (n, 3) through k samples z (k, n); F (3, 3), K (n, 3). */
int joint_step(double* x, long n, const double* F, const double* K, const double* z,
               long k) {
  long i, j;
  for (j = 0; j < k; ++j) {
    const double* zj = z + j * n;
    for (i = 0; i < n; ++i) {
      double* xi = x + 3 * i;
      double p = xi[0] * F[0] + xi[1] * F[1] + xi[2] * F[2];
      double v = xi[0] * F[3] + xi[1] * F[4] + xi[2] * F[5];
      double a = xi[0] * F[6] + xi[1] * F[7] + xi[2] * F[8];
      double e = zj[i] - p;
      xi[0] = p + K[3 * i] * e;
      xi[1] = v + K[3 * i + 1] * e;
      xi[2] = a + K[3 * i + 2] * e;
    }
  }
  return 0;
}

/* Observer._update's first part (`_tick.TickPass`): the streams' checks, the chassis and
   joint filters, the wheels, the cylinder forces and the state's float fields, in one call.
   sc (in): base dt, the observer's dt, the joints' prediction dt, the wheels' acceleration
   time constant, the row counts of the IMU rates and forces, positions, pressures, wheel
   speeds and drive torques, 1.0 once levelled, 1.0 once the joints started, 1.0 once a
   pressure came, the gyroscope's and the accelerometer's full scales. The samples'
   buffers in that order, each of `rows` rows. wheels (12): the wheels' angles, rates,
   accelerations; forces (5): the cylinders' (kept when none come); out: the `StateBuffer`
   layout (65). Returns 0; 1 a non-finite wheel speed or drive torque; 7 an IMU sample
   beyond its full scale (NaN is code 2's); 2 a non-finite IMU mean; 3 a non-finite
   position; 6 a position outside its gate (lo[9 + i], hi[9 + i]; the ranges of the clip
   are lo[i], hi[i]); 4 a non-finite cylinder force (the earlier steps done, as the Python
   code's order); 5: not levelled (`in` holds the means, nothing else done). */
int observer_tick(const double* sc, double* s, const double* c, double* in, double* x,
                  const double* F, const double* K, double* wheels, const double* aa,
                  const double* ab, double* forces, double* out, const double* lo,
                  const double* hi, const double* rates, const double* spec, const double* z,
                  const double* p, const double* ws, const double* drive) {
  const long kw = (long)sc[4], kf = (long)sc[5], kz = (long)sc[6], kp = (long)sc[7];
  const long kws = (long)sc[8], kd = (long)sc[9];
  const double dt = sc[1];
  double *angle = wheels, *rate = wheels + 4, *acc = wheels + 8, f[5];
  long i, j;
  for (i = 0; i < 2 * kws; ++i)
    if (!isfinite(ws[i])) return 1;
  for (i = 0; i < 2 * kd; ++i)
    if (!isfinite(drive[i])) return 1;
  for (i = 0; i < 3 * kw; ++i)
    if (fabs(rates[i]) > sc[13]) return 7;
  for (i = 0; i < 3 * kf; ++i)
    if (fabs(spec[i]) > sc[14]) return 7;
  if (kw > 0 && kf > 0) {  /* mean(axis=0): row after row, then the division */
    for (j = 0; j < 3; ++j) { in[1 + j] = rates[j]; in[4 + j] = spec[j]; }
    for (i = 1; i < kw; ++i)
      for (j = 0; j < 3; ++j) in[1 + j] = in[1 + j] + rates[3 * i + j];
    for (i = 1; i < kf; ++i)
      for (j = 0; j < 3; ++j) in[4 + j] = in[4 + j] + spec[3 * i + j];
    for (j = 0; j < 3; ++j) {
      in[1 + j] = in[1 + j] / (double)kw;
      in[4 + j] = in[4 + j] / (double)kf;
    }
    for (j = 1; j < 7; ++j)
      if (!isfinite(in[j])) return 2;
    if (sc[10] == 0.0) return 5;
    in[0] = sc[0];
    in[7] = kws > 0 ? 1.0 : 0.0;
    if (kws > 0) { in[8] = ws[2 * kws - 2]; in[9] = ws[2 * kws - 1]; }
    base_step(s, c, in);
  }
  for (i = 0; i < 9 * kz; ++i)
    if (!isfinite(z[i])) return 3;
  for (i = 0; i < 9 * kz; ++i)  /* the gate: lo, hi hold it after the ranges */
    if (z[i] < lo[9 + i % 9] || z[i] > hi[9 + i % 9]) return 6;
  if (kz > 0) {
    if (sc[11] == 0.0)
      for (i = 0; i < 9; ++i) x[3 * i] = z[i];
    joint_step(x, 9, F, K, z, kz);
  }
  if (kws > 0) {
    double r[4] = {ws[2 * kws - 2], ws[2 * kws - 2], ws[2 * kws - 1], ws[2 * kws - 1]};
    if (dt > 0) {
      double a = dt / (sc[3] + dt);
      for (i = 0; i < 4; ++i) acc[i] = acc[i] + a * ((r[i] - rate[i]) / dt - acc[i]);
    }
    for (i = 0; i < 4; ++i) rate[i] = r[i];
  }
  for (i = 0; i < 4; ++i) angle[i] = angle[i] + dt * rate[i];
  if (kp > 0) {
    if (cylinder_forces(aa, ab, f, p, kp)) return 4;
    for (i = 0; i < 5; ++i) forces[i] = f[i];
  }
  /* the state: position zero, the base's fields, q qd qdd (3, 13), the suspension */
  for (i = 0; i < 3; ++i) out[i] = 0.0;
  for (i = 0; i < 21; ++i) out[3 + i] = s[i];
  predict_into(x, 9, out + 24, 13, sc[2]);
  for (i = 0; i < 4; ++i) {
    out[24 + 9 + i] = angle[i];
    out[24 + 13 + 9 + i] = rate[i];
    out[24 + 26 + 9 + i] = acc[i];
  }
  for (i = 0; i < 9; ++i) {  /* np.clip's: NaN stays */
    double q = out[24 + i];
    if (!isnan(q)) q = q > lo[i] ? q : lo[i];
    if (!isnan(q)) q = q < hi[i] ? q : hi[i];
    out[24 + i] = q;
  }
  out[63] = sc[12] != 0.0 ? forces[0] : 0.0;
  out[64] = sc[12] != 0.0 ? forces[1] : 0.0;
  return 0;
}
"""

def compiled_filters():
    """The loaded `FILTERS_C` (its five functions), or None without a compiler."""
    return load_shared(FILTERS_C, "observer_filters", {
        "base_step": ([ctypes.c_void_p] * 3, ctypes.c_int),
        "joint_step": ([ctypes.c_void_p, ctypes.c_long, ctypes.c_void_p, ctypes.c_void_p,
                        ctypes.c_void_p, ctypes.c_long], ctypes.c_int),
        "joint_predict": ([ctypes.c_void_p, ctypes.c_long, ctypes.c_void_p, ctypes.c_double],
                          ctypes.c_int),
        "cylinder_forces": ([ctypes.c_void_p] * 4 + [ctypes.c_long], ctypes.c_int),
        "observer_tick": ([ctypes.c_void_p] * 20, ctypes.c_int)},
        "Python")
