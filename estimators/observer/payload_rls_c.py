"""The payload filter's update in C (`payload_rls.PayloadRLS.update`), for the tail's call.

`tail_c.TAIL_C` includes `RLS_C` (its ``tail_run`` runs ``rls_update`` between
``tail_head`` and ``tail_end``; the table's ``fn_gesv`` is numpy's ``dgesv``,
`models.numpy_blas`): `PayloadRLS.update` and `PayloadRLS.std` on the filter's state array
(`payload_rls.RLS_STATE`) and its window's ring, the Python steps' operations in their order,
hence their bits (`tests/test_payload_rls_c.py`).
"""

from __future__ import annotations

from estimators.observer import payload_rls as rls

__all__ = ["RLS_C"]

_DEFINES = {f"R_{n}": i for i, n in enumerate(rls.RLS_STATE)} | {
    "MIN_SENSITIVITY": repr(float(rls._MIN_SENSITIVITY)),
    "UNUSED_VARIANCE": repr(float(rls._UNUSED_VARIANCE)),
    "EVENT_CHI2": repr(float(rls.EVENT_CHI2)), "EVENT_TICKS": int(rls.EVENT_TICKS),
    "EVENT_WINDOW": repr(float(rls.EVENT_WINDOW)),
    "EVENT_MASS_CHANGE": repr(float(rls.EVENT_MASS_CHANGE)),
    "RESET_VARIANCE": repr(float(rls._RESET_STD ** 2))}

RLS_C = "\n".join(f"#define {k} {v}" for k, v in _DEFINES.items()) + r"""

/* payload_rls._sign: np.sign of a float (NaN stays NaN) */
static double sign_of(double x) {
  return x > 0 ? 1.0 : (x < 0 ? -1.0 : (x != x ? x * 0.0 : 0.0));
}

/* payload_rls._gain: solve([[y0 y0 p + r0, yy + 0], [yy + 0, y1 y1 p + r1]], rhs) by
   numpy's dgesv (the matrix is symmetric: its column-major copy is itself); NaN if
   singular, as the Python solve gives. */
static void rls_gain(void* const* p, double y0, double y1, double pp, double r0, double r1,
                     const double* rhs, double* x) {
  double yy = y0 * y1 * pp;
  double a[4];
  long long n = 2, one = 1, ipiv[2], info = 0;
  a[0] = y0 * y0 * pp + r0;
  a[1] = yy + 0.0;
  a[2] = yy + 0.0;
  a[3] = y1 * y1 * pp + r1;
  x[0] = rhs[0];
  x[1] = rhs[1];
  ((gesv_fn)p[P_fn_gesv])(&n, &one, a, &n, ipiv, x, &n, &info);
  if (info != 0) x[0] = x[1] = NAN;
}

/* PayloadRLS.update(time, dt, z[0:2], z[2:4], z[4:6], band z[6:8]) on its state and ring
   (times, then masses, cap each), lam = forgetting(dt): the Python steps' operations in
   their order. Returns 0, or 5 with nothing changed: the ring is full (Python grows it).
   Of the table p only fn_gesv is read. */
int rls_update(void* const* p, double* st, double* ring, long cap, double time, double lam,
               const double* z) {
  const double y0 = z[4], y1 = z[5], m0 = z[0], m1 = z[1], f00 = z[2], f01 = z[3];
  double mass, nu[2], r[2], x[2], k[2], yv[2], pp, chi2, new_mass, new_p;
  long head = (long)st[R_head], count = (long)st[R_count], ticks, at;
  int in0, in1, moved, event;
  if (count >= cap) return 5;
  st[R_event] = 0.0;
  st[R_y0] = y0;
  st[R_y1] = y1;
  if ((fabs(y0) < MIN_SENSITIVITY && fabs(y1) < MIN_SENSITIVITY)
      || !(isfinite(m0) && isfinite(m1)))
    return 0;
  if (!(isfinite(f00) && isfinite(f01))) return 0;
  mass = st[R_mass];
  nu[0] = m0 - f00 - y0 * mass;
  nu[1] = m1 - f01 - y1 * mass;
  r[0] = st[R_R0];
  r[1] = st[R_R1];
  in0 = fabs(nu[0]) <= z[6];
  in1 = fabs(nu[1]) <= z[7];
  if (in0 && in1) {
    st[R_run] = 0.0;
    return 0;
  }
  if (in0) { nu[0] = 0.0; r[0] = UNUSED_VARIANCE; } else nu[0] = nu[0] - sign_of(nu[0]) * z[6];
  if (in1) { nu[1] = 0.0; r[1] = UNUSED_VARIANCE; } else nu[1] = nu[1] - sign_of(nu[1]) * z[7];
  pp = st[R_P] / lam;
  rls_gain(p, y0, y1, pp, r[0] * st[R_event_variance_scale],
           r[1] * st[R_event_variance_scale], nu, x);
  chi2 = nu[0] * x[0] + nu[1] * x[1];
  st[R_run] = chi2 > EVENT_CHI2 ? st[R_run] + 1.0 : 0.0;
  ticks = EVENT_TICKS;
  if (time > st[R_expect_until])
    st[R_expect_until] = -INFINITY;
  else if (y0 * x[0] + y1 * x[1] > 0)
    ticks = (long)st[R_expected_pick_ticks];
  /* PayloadRLS._moved */
  if (time < st[R_settle_until]) {
    head = 0;
    count = 0;
  } else {
    while (count && ring[head] < time - EVENT_WINDOW) {
      head = (head + 1) % cap;
      --count;
    }
  }
  at = (head + count) % cap;
  ring[at] = time;
  ring[cap + at] = mass;
  st[R_head] = (double)head;
  st[R_count] = (double)(count + 1);
  moved = time < st[R_settle_until] ? 0 : fabs(mass - ring[cap + head]) > EVENT_MASS_CHANGE;
  event = st[R_run] >= (double)ticks || moved;
  if (event) {
    pp = RESET_VARIANCE;
    st[R_run] = 0.0;
  }
  yv[0] = y0;
  yv[1] = y1;
  rls_gain(p, y0, y1, pp, r[0], r[1], yv, k);
  k[0] = pp * k[0];
  k[1] = pp * k[1];
  new_mass = mass + (k[0] * nu[0] + k[1] * nu[1]);
  new_p = pp - pp * (k[0] * y0 + k[1] * y1);
  if (!(new_p > 0) && pp > 0) new_p = 1.0 / (1.0 / pp + y0 * y0 / r[0] + y1 * y1 / r[1]);
  if (!(isfinite(new_mass) && isfinite(new_p))) {
    st[R_run] = 0.0;
    return 0;
  }
  st[R_mass] = new_mass;
  st[R_P] = new_p;
  if (event) {
    st[R_event] = new_mass > ring[cap + head] ? 1.0 : 2.0;  /* pick, release */
    st[R_event_time] = time;
    st[R_settle_until] = time + EVENT_WINDOW;
    if (st[R_event] == 1.0) st[R_expect_until] = -INFINITY;
  }
  return 0;
}

/* PayloadRLS.std: the covariance and the offsets' floor, the same operations (Python's
   floor ** 2: pow(floor, 2), correctly rounded, as floor * floor is). */
static double rls_std(const double* st, double b0, double b1) {
  const double y0 = st[R_y0], y1 = st[R_y1];
  double floor = 0.0;
  if (y0 == y0 && y1 == y1 && !(fabs(y0) < MIN_SENSITIVITY && fabs(y1) < MIN_SENSITIVITY)) {
    double w0 = y0 / st[R_R0], w1 = y1 / st[R_R1], a0 = w0 * b0, a1 = w1 * b1;
    floor = sqrt(a0 * a0 + a1 * a1) / (w0 * y0 + w1 * y1);
  }
  return sqrt(st[R_P] + floor * floor);
}

"""
