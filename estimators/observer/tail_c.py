"""The observer's tick after its filters, in one C call (`_tail.TailPass`).

Between the filters' pass (`_tick`) and the `ObserverEstimate` the observer runs the link
accelerometers' fit, the payload regression and its filter, the sliding crane cylinders'
accelerations, the contact points and the flags' four-wheel forces: five compiled kernels
and a dozen small C and BLAS calls, glued by ~50 us of Python (states, contacts, arrays).
``tail_head`` (up to the payload filter), the filter (`payload_rls.PayloadRLS.update` on
its state array, ~10 us of Python in a closed loop: `payload_rls_c`) and ``tail_end`` run that
glue on the state's buffer, in one call, ``tail_run``, and call the compiled parts by
address:

* the estimator's and the efforts' CasADi kernels (`estimators._kernel_calls.Compiled`,
  each on buffers of its own), the link fit and the contacts' C (`fusion_c`, `contacts_c`);
* the BLAS and LAPACK routines numpy's ``ndarray.dot``, ``@`` and ``linalg.solve`` call
  (`numpy_blas`: ``cblas_dgemv``, ``cblas_ddot``, ``dgesv`` of numpy's own library, with the
  arguments numpy passes), so the products and solves keep numpy's bits;
* everything else element-wise in the Python code's order (`models.cbuild`: no fused
  multiply-adds).

The results are the Python steps' bits (`tests/test_observer_tail_c.py`). Each call checks
what the Python path would treat otherwise (a buffer not finite, a kernel row not finite
or not regular, a coordinate outside its range) before it changes anything kept, and then
returns a code: the observer runs the rest of the tick in Python.
"""

from __future__ import annotations

import ctypes

from estimators._symbolic import LAYOUT
from estimators.batch import SINGULAR_CONDITION
from estimators.efforts_kernel import INPUTS
from estimators.observer._states import STATE_SIZE
from estimators.observer.payload_rls_c import RLS_C
from models.cbuild import load_shared
from models.numpy_blas import numpy_blas
from models.sensing import PRESSURE_CYLINDERS

__all__ = ["HEAD_CODES", "POINTERS", "RUN_CODES", "SCALARS", "TAIL_C", "compiled_tail",
           "numpy_blas"]

# The pointer table both calls read (`void** p`), in this order.
POINTERS = (
    "buf", "s", "forces", "seal", "regression",
    "link_samples", "link_mean", "link_w", "link_prior", "link_io", "fn_link_mean",
    "fn_link_fuse",
    "row",  # the efforts' and points' kernels' input (`efforts_kernel.INPUTS`)
    "pk_fn", "pk_arg", "pk_res", "pk_iw", "pk_w", "pk_out",
    "ek_fn", "ek_arg", "ek_res", "ek_iw", "ek_w", "ek_out",
    "nk_fn", "nk_arg", "nk_res", "nk_iw", "nk_w", "nk_in", "nk_out",
    "selectors", "payload", "bound_index", "bound_lo", "bound_hi",
    "c_k", "c_touching", "c_above", "c_drive", "c_acc", "c_prev", "c_out", "c_four",
    "fn_contact_points", "fn_contact_flags", "drive_samples", "tick_sc",
    "fn_gemv", "fn_ddot", "fn_gesv",
    "rls", "rls_ring")  # the payload filter's state (`payload_rls.RLS_STATE`) and ring
# The scalars' places in ``s`` (in: set by the caller; out: written by the calls).
SCALARS = (
    "dt", "link_n", "link_m", "link_ok",  # link_ok out: the fit was taken
    "pk_out_n",  # the points kernel's output row length
    "z0", "z1", "z2", "z3", "z4", "z5", "band0", "band1",  # out: the filtered regression
    "filter_time", "sliding_speed", "m1", "m2",
    "mass", "crane", "sliding",  # crane: 1 to take the pressures' accelerations; sliding out
    "n_bounds", "flags_finite",  # flags_finite out
    "time", "lam", "max_mass", "rls_cap",  # `tail_run`'s: the tick, `payload_rls.forgetting`
    "std", "b0", "b1")  # std out: `PayloadRLS.std` after the update; b0, b1 its bias_std
# ``tail_run``'s returns besides those: the payload filter's update (5: its ring is full)
# or the mass's setting (6: outside the estimator's range) in Python, then ``tail_end``.
# ``tail_head``'s and ``tail_end``'s returns: where the Python steps take over.
HEAD_CODES = {0: "done", 1: "buffer", 2: "links", 3: "payload", 4: "contacts"}
RUN_CODES = {5: "payload filter", 6: "payload mass"}

_LIFT_PRESS = PRESSURE_CYLINDERS.index("lift")
_TILT_PRESS = PRESSURE_CYLINDERS.index("tilt")
_CRANE_PRESS = tuple(PRESSURE_CYLINDERS.index(c) for c in ("slew", "lift", "tilt"))

_TEMPLATE = r"""
#include <math.h>
#include <string.h>

@DEFINES@

typedef int (*kernel_fn)(const double**, double**, long long*, double*, int);
typedef void (*gemv_fn)(int, int, long long, long long, double, const double*, long long,
                        const double*, long long, double, double*, long long);
typedef double (*ddot_fn)(long long, const double*, long long, const double*, long long);
typedef void (*gesv_fn)(const long long*, const long long*, double*, const long long*,
                        long long*, double*, const long long*, long long*);
typedef int (*mean_fn)(const double*, double*, long, long);
typedef int (*fuse_fn)(long, const double*, const double*, const double*, double*,
                       const double*);
typedef int (*points_fn)(const double*, const double*, const double*, const double*,
                         const double*, const double*, const double*, double*, double*,
                         double*);
typedef int (*flags_fn)(const double*, double*, double*, const double*, const double*,
                        const double*, double*);

#define D(name) ((double*)p[P_##name])

/* A CasADi kernel on its own buffers: p[at .. at + 4] = fn, arg, res, iw, w. */
static int run_kernel(void* const* p, int at) {
  return ((kernel_fn)p[at])((const double**)p[at + 1], (double**)p[at + 2],
                            (long long*)p[at + 3], (double*)p[at + 4], 0);
}

/* The state buffer (`_states.StateBuffer`): rotation 3, twist 12, acceleration 18, q 24,
   qd 37, qdd 50 (13 each), suspension forces 63. */
#define B_ROT 3
#define B_Q 24
#define B_QD 37
#define B_QDD 50
#define B_SUSP 63

/* Links, then the payload regression's sides through the low-pass. Returns 0, or where
   the Python steps take over (nothing kept changed before it): 1 the buffer is not finite,
   2 the points kernel's row is not (the links' fit not done), 3 the efforts kernel's row
   is not (the fit done). */
int tail_head(void* const* p) {
  double *buf = D(buf), *s = D(s), *row = D(row), *eo = D(ek_out), *reg = D(regression);
  const double *forces = D(forces), *seal = D(seal);
  double at1[9], at2[9], now[6];
  long n = (long)s[S_link_n], m = (long)s[S_link_m];
  int i, j;
  s[S_link_ok] = 0.0;
  for (i = 0; i < STATE_SIZE; ++i)
    if (!isfinite(buf[i])) return 1;
  /* the kernels' input: rotation .. qd, then the wheels' accelerations */
  for (i = 0; i < IN_REST; ++i) row[i] = buf[B_ROT + i];
  for (i = 0; i < 4; ++i) row[IN_REST + i] = buf[B_QDD + 9 + i];
  if (n > 0 && ((mean_fn)p[P_fn_link_mean])(D(link_samples), D(link_mean), m, n) == 0) {
    double *io = D(link_io), *po = D(pk_out);
    run_kernel(p, P_pk_fn);
    if (!isfinite(po[(long)s[S_pk_out_n] - 1])) return 2;
    for (i = 0; i < 9; ++i) io[i] = buf[B_QDD + i];
    if (((fuse_fn)p[P_fn_link_fuse])(m, D(link_mean), D(link_w), D(link_prior), io,
                                     po) == 0) {
      for (i = 2; i < 6; ++i) buf[B_QDD + i] = io[i];
      s[S_link_ok] = 1.0;
    }
  }
  run_kernel(p, P_ek_fn);
  if (!isfinite(eo[EK_OUT - 1])) return 3;
  /* ActuatorEfforts.payload_regressor_at: e_k u + e_0k (ndarray.dot: dgemv), lift, tilt */
  memset(at1, 0, sizeof at1);
  memset(at2, 0, sizeof at2);
  ((gemv_fn)p[P_fn_gemv])(101, 111, 9, 9, 1.0, eo, 9, buf + B_QDD, 1, 0.0, at1, 1);
  ((gemv_fn)p[P_fn_gemv])(101, 111, 9, 9, 1.0, eo + 90, 9, buf + B_QDD, 1, 0.0, at2, 1);
  for (i = 0; i < 9; ++i) {
    at1[i] = at1[i] + eo[81 + i];
    at2[i] = at2[i] + eo[171 + i];
  }
  {
    const double m1 = s[S_m1], span = s[S_m2] - m1;
    const int axis[2] = {3, 4}, press[2] = {LIFT_PRESS, TILT_PRESS};
    for (j = 0; j < 2; ++j) {  /* payload_rls.without_seal_friction */
      double y = (at2[axis[j]] - at1[axis[j]]) / span, v = buf[B_QD + axis[j]];
      int sliding = fabs(v) > s[S_sliding_speed];
      now[j] = forces[press[j]] - (sliding ? copysign(seal[press[j]], v) : 0.0);
      s[S_band0 + j] = sliding ? 0.0 : seal[press[j]];
      now[2 + j] = at1[axis[j]] - m1 * y;
      now[4 + j] = y;
    }
  }
  /* Observer._filtered */
  if (reg[0] == 0.0 || !(s[S_dt] > 0)) {
    for (j = 0; j < 6; ++j) reg[1 + j] = now[j];
    reg[0] = 1.0;
  } else {
    double a = s[S_dt] / (s[S_filter_time] + s[S_dt]);
    for (j = 0; j < 6; ++j) reg[1 + j] = reg[1 + j] + a * (now[j] - reg[1 + j]);
  }
  for (j = 0; j < 6; ++j) s[S_z0 + j] = reg[1 + j];
  return 0;
}

/* crane_pressures.CranePressures.accelerations at the mass s[S_mass]. */
static void crane(void* const* p, double* buf, double* s) {
  const double *eo = D(ek_out), *forces = D(forces), *seal = D(seal);
  const int press_of[3] = {SLEW_PRESS, LIFT_PRESS, TILT_PRESS};
  int rows[3], press[3], known[9], k = 0, nk = 0, i, r, c;
  double w, kb[27], qk[9], mv[3], rhs[3], a[9];
  long long kk, one = 1, ipiv[3], info = 0;
  for (i = 0; i < 3; ++i)
    if (fabs(buf[B_QD + 2 + i]) > s[S_sliding_speed]) { rows[k] = 2 + i; press[k++] = press_of[i]; }
  s[S_sliding] = (double)k;
  if (k == 0) return;
  for (i = 0; i < 9; ++i) {
    int is_free = 0;
    for (r = 0; r < k; ++r) is_free |= rows[r] == i;
    if (!is_free) known[nk++] = i;
  }
  w = (s[S_mass] - s[S_m1]) / (s[S_m2] - s[S_m1]);
#define E(i, j) (eo[9 * (i) + (j)] + w * (eo[90 + 9 * (i) + (j)] - eo[9 * (i) + (j)]))
  for (r = 0; r < k; ++r) {
    for (c = 0; c < nk; ++c) kb[r * nk + c] = E(rows[r], known[c]);
    for (c = 0; c < k; ++c) a[c * k + r] = E(rows[r], rows[c]);  /* column-major */
  }
  for (c = 0; c < nk; ++c) qk[c] = buf[B_QDD + known[c]];
  if (k == 1) {  /* numpy's matmul of a row and a vector: its dot (cblas_ddot) */
    mv[0] = ((ddot_fn)p[P_fn_ddot])(nk, kb, 1, qk, 1);
  } else {  /* matmul's gemv: column-major, transposed */
    memset(mv, 0, sizeof mv);
    ((gemv_fn)p[P_fn_gemv])(102, 112, nk, k, 1.0, kb, nk, qk, 1, 0.0, mv, 1);
  }
  for (r = 0; r < k; ++r) {
    double v = buf[B_QD + rows[r]], sign = v > 0 ? 1.0 : (v < 0 ? -1.0 : 0.0);
    double e0 = eo[81 + rows[r]] + w * (eo[171 + rows[r]] - eo[81 + rows[r]]);
    rhs[r] = forces[press[r]] - seal[press[r]] * sign - e0 - mv[r];
  }
#undef E
  kk = k;
  ((gesv_fn)p[P_fn_gesv])(&kk, &one, a, &kk, ipiv, rhs, &kk, &info);
  if (info != 0) return;  /* numpy: NaN, not taken */
  for (r = 0; r < k; ++r)
    if (!isfinite(rhs[r])) return;
  for (r = 0; r < k; ++r) buf[B_QDD + rows[r]] = rhs[r];
}

/* The estimate kernel's row at the buffer's state: contacts none (points == 0) or the
   measured points and forces. Returns 1 if regular (PayloadEstimator._regular_row). */
static int estimate_row(void* const* p, const double* buf, const double* points,
                        const double* force) {
  double *in = D(nk_in), *out = D(nk_out);
  const double *sel = D(selectors);
  int i;
  for (i = 0; i < 60; ++i) in[i] = buf[B_ROT + i];  /* rotation .. qdd */
  for (i = 0; i < 12; ++i) in[NF_POINTS + i] = points ? points[i] : 0.0;
  for (i = 0; i < 4; ++i) in[NF_USE + i] = points ? 1.0 : 0.0;
  for (i = 0; i < 12; ++i) in[NF_FORCE + i] = points ? force[i] : 0.0;
  for (i = 0; i < 16; ++i) in[NF_MASK + i] = sel[i];
  in[NF_SUSP] = buf[B_SUSP];
  in[NF_SUSP + 1] = buf[B_SUSP + 1];
  in[NF_MASS] = D(payload)[0];
  run_kernel(p, P_nk_fn);
  return isfinite(out[NF_SUM]) && out[NF_COND] < SINGULAR;
}

/* The crane's accelerations, the contact points, the four-wheel forces, the flags. Returns
   0, or 4: a coordinate outside its range or a kernel row not regular, the crane's done
   (the Python steps take over at the contacts; nothing of theirs changed but the drive's
   means, which they compute again). */
int tail_end(void* const* p) {
  double *buf = D(buf), *s = D(s), *out = D(nk_out), *cout = D(c_out), *drive = D(c_drive);
  const double *lo = D(bound_lo), *hi = D(bound_hi), *bi = D(bound_index);
  double lowest[12];
  long nd = (long)D(tick_sc)[9], nb = (long)s[S_n_bounds], i;
  int j, bits;
  s[S_sliding] = 0.0;
  if (s[S_crane] != 0.0) crane(p, buf, s);
  for (i = 0; i < nb; ++i) {
    double v = buf[B_Q + (long)bi[i]];
    if (!(lo[i] <= v && v <= hi[i])) return 4;
  }
  if (!estimate_row(p, buf, 0, 0)) return 4;
  for (i = 0; i < 12; ++i) lowest[i] = out[NF_OUT_POINTS + i];
  if (nd > 0) {  /* ContactTracker.set_drive: np.add.reduce over the rows, / n */
    const double* t = D(drive_samples);
    double l = t[0], r = t[1];
    for (i = 1; i < nd; ++i) { l = l + t[2 * i]; r = r + t[2 * i + 1]; }
    drive[1] = l / (double)nd;
    drive[2] = r / (double)nd;
    drive[0] = 1.0;
  }
  bits = ((points_fn)p[P_fn_contact_points])(
      D(c_k), lowest, buf + B_ROT + 6, D(c_touching), drive, D(c_acc), D(c_prev),
      cout + 12, cout + 24, cout);
  if (bits != 3) return 4;
  if (!estimate_row(p, buf, cout + 12, cout)) return 4;
  for (j = 0; j < 4; ++j) D(c_four)[j] = out[NF_X + j];
  s[S_flags_finite] = (double)((flags_fn)p[P_fn_contact_flags])(
      D(c_k), D(c_above), D(c_touching), drive, D(c_acc), D(c_four), cout);
  return 0;
}

@RLS_C@
/* The tick after the filters in one call: tail_head, the payload filter (rls_update) and
   its std, the mass min(max(m, 0), 1e4) set as the estimator's (check_payload_mass's
   range), tail_end.
   Returns tail_head's code, 5 or 6 (RUN_CODES), or tail_end's. */
int tail_run(void* const* p) {
  double *s = D(s), m;
  int code = tail_head(p);
  if (code) return code;
  code = rls_update(p, D(rls), D(rls_ring), (long)s[S_rls_cap], s[S_time], s[S_lam],
                    s + S_z0);
  if (code) return code;
  s[S_std] = rls_std(D(rls), s[S_b0], s[S_b1]);
  m = D(rls)[R_mass];
  if (0.0 > m) m = 0.0;
  if (1e4 < m) m = 1e4;
  s[S_mass] = m;
  if (!(isfinite(m) && 0.0 <= m && m <= s[S_max_mass])) return 6;
  D(payload)[0] = m;
  return tail_end(p);
}
"""


def _source() -> str:
    lay = LAYOUT
    names = {
        "STATE_SIZE": STATE_SIZE, "IN_REST": INPUTS["qdd_rest"].start,
        "EK_OUT": 2 * (81 + 9) + 1,
        "LIFT_PRESS": _LIFT_PRESS, "TILT_PRESS": _TILT_PRESS, "SLEW_PRESS": _CRANE_PRESS[0],
        "NF_POINTS": lay.points.start, "NF_USE": lay.use_measured.start,
        "NF_FORCE": lay.force.start, "NF_MASK": lay.mask.start,
        "NF_SUSP": lay.suspension_force.start, "NF_MASS": lay.payload_mass,
        "NF_SUM": lay.out_sum, "NF_COND": lay.out_cond, "NF_OUT_POINTS": lay.out_points.start,
        "NF_X": lay.out_x.start, "SINGULAR": repr(float(SINGULAR_CONDITION))}
    lines = [f"#define P_{n} {i}" for i, n in enumerate(POINTERS)]
    lines += [f"#define S_{n} {i}" for i, n in enumerate(SCALARS)]
    lines += [f"#define {k} {v}" for k, v in names.items()]
    return _TEMPLATE.replace("@DEFINES@", "\n".join(lines)).replace("@RLS_C@", RLS_C)


TAIL_C = _source()


def _layout_fits() -> bool:
    """Whether the layouts `TAIL_C` is written for are the ones in force."""
    lay = LAYOUT
    return (STATE_SIZE == 65 and lay.rotation.start == 0 and lay.qdd.stop == 60
            and lay.mask.start + 15 == lay.beta and lay.suspension_force.stop
            == lay.payload_mass and INPUTS["size"] == INPUTS["qdd_rest"].start + 4
            and INPUTS["qdd_rest"].start == 47)


def compiled_tail():
    """The loaded `TAIL_C` (``tail_head``, ``tail_end``, ``tail_run``), or None (no compiler)."""
    if not _layout_fits():
        return None
    return load_shared(TAIL_C, "observer_tail", {
        "tail_head": ([ctypes.c_void_p], ctypes.c_int),
        "tail_end": ([ctypes.c_void_p], ctypes.c_int),
        "tail_run": ([ctypes.c_void_p], ctypes.c_int),
        "rls_update": ([ctypes.c_void_p] * 3 + [ctypes.c_long, ctypes.c_double,
                                                ctypes.c_double, ctypes.c_void_p],
                       ctypes.c_int)}, "Python")


