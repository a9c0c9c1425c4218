"""A control tick's ground truth in C: `Simulator.measure` and the log's truth columns at once.

A closed loop logs at every tick the measured state, MuJoCo's wheel contacts in fb, the
suspension forces, the servos' setpoints, the loop-closure gap, ``qpos``, ``qvel`` and the
centre of mass (`scenarios.truth_log`). In Python that is some 70 numpy calls and a few
objects a tick, each slow right after the controller's tick has evicted the interpreter's
caches. `TRUTH_C` writes the tick's row of every one of those columns in one call.

It does what the Python path does (`scenarios.measured`, `scenarios.ground_truth`,
`Simulator.closure_violation`, `models.log.ScenarioLog.append`), operation for operation
(IEEE doubles, no contraction: `models.cbuild`), where numpy's order is known:

* elementwise operations and copies: the same operations;
* each wheel's sums over its contacts (numpy's ``select @ x``, BLAS): a wheel with one or two
  contacts has the same sum in any order; a wheel with more (or one off the ground, whose
  point and normal come from the terrain) goes to the Python path for that tick;
* the three-term products, whose order is numpy's and its BLAS's choice: a contact's force
  in the contact frame (``f @ frame``) and ``R^T v`` left to right, ``x @ R`` as the chain
  of fused multiply-adds of the BLAS's kernel, ``einsum('ij,ij->i')`` as ``(x0 y0 + x2 y2) +
  x1 y1``: `numpy_orders_agree` checks once that this host's numpy computes exactly these
  (the C path is off otherwise), and `tests/test_truth_log.py` compares whole runs' columns
  with the Python path's, to the bit;
* the chains' stroke rates (`models.chain.CylinderChain.driven_rate_coefficients`) with the C
  library's ``acos``, ``sin``, ``cos``, which Python's ``math`` calls.

A row it cannot make to the bit (those wheels; a flat chain triangle, where Python raises;
a non-finite value or an improper rotation, which `models.state` refuses) returns -1 and
the caller writes the row with the Python path.
"""

from __future__ import annotations

import ctypes
import functools

import numpy as np

from models.cbuild import load_shared

__all__ = ["TRUTH_C", "TruthSetup", "compiled_truth", "numpy_orders_agree"]

# truth_row: row k of the columns from MuJoCo's data of the measured instant (qpos, qvel,
# t: its snapshot; setpoint: the servos' setpoints). The primitives are exported for the
# probe (`numpy_orders_agree`).
TRUTH_C = r"""
#include <math.h>
#include <mujoco/mujoco.h>

typedef struct {
  long base_body, nq, nv, n_servo, n_pairs, n_chains;
  const long *base_dof, *iq, *idof, *susp, *wheel_of_geom, *pairs, *chain_i, *chain_dof;
  const double *chain_par, *lower, *upper;  /* la, lb, lx0, sigma per chain; q's range */
  double threshold, tolerance;
  double *time, *base_position, *base_rotation, *base_twist, *base_acceleration, *q, *qd,
         *qdd, *contacts, *normal_force, *fz, *suspension, *servo_setpoint, *closure,
         *qpos, *qvel, *com, *true_q;
  unsigned char* in_contact;
} truth_setup;

double dot_left(const double* x, long sx, const double* y, long sy) {  /* numpy's R^T v */
  return (x[0] * y[0] + x[sx] * y[sy]) + x[2 * sx] * y[2 * sy];
}
double dot_fused(const double* x, long sx, const double* y, long sy) {  /* BLAS's x @ R */
  return fma(x[2 * sx], y[2 * sy], fma(x[sx], y[sy], x[0] * y[0]));
}
double dot_einsum(const double* x, const double* y) {  /* einsum('ij,ij->i') */
  return (x[0] * y[0] + x[2] * y[2]) + x[1] * y[1];
}
static double __attribute__((noinline)) cos_alone(double x) { return cos(x); }  /* no sincos */

static int all_finite(const double* x, long n) {
  long i;
  for (i = 0; i < n; ++i) if (!isfinite(x[i])) return 0;
  return 1;
}

static int proper_rotation(const double* r, double tol) {  /* `models.state.check_rotation` */
  double a = r[0], b = r[1], c = r[2], d = r[3], e = r[4], f = r[5], g = r[6], h = r[7],
         i = r[8], big = 0.0, err = 0.0, x[6];
  int k;
  for (k = 0; k < 9; ++k) if (fabs(r[k]) > big) big = fabs(r[k]);
  if (!(big <= 1.0 + tol)) return 0;
  x[0] = a * a + b * b + c * c - 1.0; x[1] = d * d + e * e + f * f - 1.0;
  x[2] = g * g + h * h + i * i - 1.0; x[3] = a * d + b * e + c * f;
  x[4] = a * g + b * h + c * i; x[5] = d * g + e * h + f * i;
  for (k = 0; k < 6; ++k) if (fabs(x[k]) > err) err = fabs(x[k]);
  return err <= tol && a * (e * i - f * h) - b * (d * i - f * g) + c * (d * h - e * g) > 0;
}

int truth_row(const mjModel* m, const mjData* d, const truth_setup* s, long k,
              const double* qpos, const double* qvel, double t, const double* setpoint) {
  double force[4][3] = {{0}}, point[4][3] = {{0}}, normal[4][3] = {{0}}, nf[4] = {0};
  double *q = s->q + 13 * k, *qd = s->qd + 13 * k, *qdd = s->qdd + 13 * k;
  double *twist = s->base_twist + 6 * k, *acc = s->base_acceleration + 6 * k;
  double *out = s->contacts + 36 * k, *pos = s->base_position + 3 * k;
  double *rot = s->base_rotation + 9 * k, v[3], a[3], w[3], big = 0.0;
  int count[4] = {0}, i, j, w_;
  const double *qacc = d->qacc, *xmat = d->xmat + 9 * s->base_body;
  for (i = 0; i < 9; ++i) rot[i] = xmat[i];
  for (i = 0; i < 3; ++i) pos[i] = d->xpos[3 * s->base_body + i];
  if (!proper_rotation(rot, s->tolerance)) return -1;
  /* the ground's force on each wheel: its contacts' forces summed (scenarios.ground_truth) */
  for (i = 0; i < d->ncon; ++i) {
    const mjContact* c = d->contact + i;
    long wheel = s->wheel_of_geom[c->geom[1]];
    double sign = 1.0, fn;
    const double *f = d->efc_force + c->efc_address, *F = c->frame;
    if (wheel < 0) { wheel = s->wheel_of_geom[c->geom[0]]; sign = -1.0; }
    if (wheel < 0 || c->efc_address < 0) continue;
    if (++count[wheel] > 2) return -1;
    fn = f[0];
    for (j = 0; j < 3; ++j) {
      force[wheel][j] += sign * dot_left(f, 1, F + j, 3);
      point[wheel][j] += fn * c->pos[j];
      normal[wheel][j] += sign * fn * F[j];
    }
    nf[wheel] += fn;
  }
  for (w_ = 0; w_ < 4; ++w_) {
    double norm;
    if (!(nf[w_] > s->threshold)) return -1;  /* off the ground: the terrain's normal */
    s->in_contact[4 * k + w_] = 1;
    for (j = 0; j < 3; ++j) point[w_][j] = point[w_][j] / nf[w_] - pos[j];
    norm = sqrt(dot_einsum(normal[w_], normal[w_]));
    for (j = 0; j < 3; ++j) normal[w_][j] /= norm;
    for (j = 0; j < 3; ++j) {  /* force, point, normal in fb: x @ R */
      out[3 * w_ + j] = dot_fused(force[w_], 1, rot + j, 3);
      out[12 + 3 * w_ + j] = dot_fused(point[w_], 1, rot + j, 3);
      out[24 + 3 * w_ + j] = dot_fused(normal[w_], 1, rot + j, 3);
    }
    s->normal_force[4 * k + w_] = dot_einsum(out + 3 * w_, out + 24 + 3 * w_);
    s->fz[4 * k + w_] = out[3 * w_ + 2];
  }
  /* the chassis' twist and its derivative (scenarios.base_motion) */
  for (j = 0; j < 3; ++j) {
    v[j] = dot_left(rot + j, 3, qvel + s->base_dof[0], 1);
    a[j] = dot_left(rot + j, 3, qacc + s->base_dof[0], 1);
    w[j] = qvel[s->base_dof[3 + j]];
    twist[j] = v[j];
    twist[3 + j] = w[j];
    acc[3 + j] = qacc[s->base_dof[3 + j]];
  }
  acc[0] = a[0] - (w[1] * v[2] - w[2] * v[1]);
  acc[1] = a[1] - (w[2] * v[0] - w[0] * v[2]);
  acc[2] = a[2] - (w[0] * v[1] - w[1] * v[0]);
  /* independent coordinates; stroke rates through the driven joints (scenarios.measured) */
  for (j = 0; j < 13; ++j) {
    q[j] = qpos[s->iq[j]];
    qd[j] = qvel[s->idof[j]];
    qdd[j] = qacc[s->idof[j]];
  }
  for (j = 0; j < s->n_chains; ++j) {
    const double* p = s->chain_par + 4 * j;
    double la = p[0], lb = p[1], lx = p[2] + q[s->chain_i[j]], c, qa, sn, dq, ddq, rate;
    c = (la * la + lb * lb - lx * lx) / (2 * la * lb);
    if (c < -1.0) c = -1.0;
    if (1.0 < c) c = 1.0;
    qa = -acos(c);
    sn = sin(qa);
    if (sn == 0.0) return -1;  /* Python divides by zero: it raises */
    dq = lx / (la * lb * sn);
    ddq = -(-1.0 / (la * lb) + cos_alone(qa) * dq * dq) / sn;
    rate = qvel[s->chain_dof[j]] / (p[3] * dq);
    qd[s->chain_i[j]] = rate;
    qdd[s->chain_i[j]] = (qacc[s->chain_dof[j]] - p[3] * ddq * rate * rate) / (p[3] * dq);
  }
  for (j = 0; j < 13; ++j) s->true_q[j] = q[j];
  for (j = 0; j < s->n_chains; ++j) {  /* the task's error reads the strokes in range: np.clip */
    long i = s->chain_i[j];
    double x = q[i] > s->lower[i] ? q[i] : s->lower[i];
    s->true_q[i] = x < s->upper[i] ? x : s->upper[i];
  }
  for (j = 0; j < 2; ++j) s->suspension[2 * k + j] = d->actuator_force[s->susp[j]];
  for (j = 0; j < s->n_servo; ++j) s->servo_setpoint[s->n_servo * k + j] = setpoint[j];
  for (j = 0; j < s->nq; ++j) s->qpos[s->nq * k + j] = qpos[j];
  for (j = 0; j < s->nv; ++j) s->qvel[s->nv * k + j] = qvel[j];
  for (j = 0; j < 3; ++j) s->com[3 * k + j] = d->subtree_com[3 * s->base_body + j];
  for (j = 0; j < s->n_pairs; ++j) {  /* the largest loop-closure gap */
    const double *x0 = d->site_xpos + 3 * s->pairs[2 * j],
                 *x1 = d->site_xpos + 3 * s->pairs[2 * j + 1];
    double gap[3] = {x0[0] - x1[0], x0[1] - x1[1], x0[2] - x1[2]}, e = dot_einsum(gap, gap);
    if (j == 0 || e > big) big = e;
  }
  s->closure[k] = sqrt(big);
  s->time[k] = t;
  if (!(all_finite(twist, 6) && all_finite(acc, 6) && all_finite(q, 13)
        && all_finite(qd, 13) && all_finite(qdd, 13) && all_finite(out, 36)
        && all_finite(s->suspension + 2 * k, 2) && isfinite(t)
        && all_finite(s->servo_setpoint + s->n_servo * k, s->n_servo)))
    return -1;  /* models.state refuses it: the Python path says so */
  return 0;
}
"""


class TruthSetup(ctypes.Structure):
    """`TRUTH_C`'s ``truth_setup`` (field for field)."""

    _fields_ = ([(n, ctypes.c_long) for n in ("base_body", "nq", "nv", "n_servo", "n_pairs",
                                               "n_chains")]
                + [(n, ctypes.c_void_p) for n in ("base_dof", "iq", "idof", "susp",
                                                   "wheel_of_geom", "pairs", "chain_i",
                                                   "chain_dof", "chain_par", "lower", "upper")]
                + [("threshold", ctypes.c_double), ("tolerance", ctypes.c_double)]
                + [(n, ctypes.c_void_p) for n in (
                    "time", "base_position", "base_rotation", "base_twist",
                    "base_acceleration", "q", "qd", "qdd", "contacts", "normal_force", "fz",
                    "suspension", "servo_setpoint", "closure", "qpos", "qvel", "com",
                    "true_q", "in_contact")])


def _library():
    p = ctypes.c_void_p
    return load_shared(TRUTH_C, "truth_row", {
        "truth_row": ([p, p, p, ctypes.c_long, p, p, ctypes.c_double, p], ctypes.c_int),
        "dot_left": ([p, ctypes.c_long, p, ctypes.c_long], ctypes.c_double),
        "dot_fused": ([p, ctypes.c_long, p, ctypes.c_long], ctypes.c_double),
        "dot_einsum": ([p, p], ctypes.c_double)}, "the Python ground truth", mujoco=True)


def compiled_truth():
    """`TRUTH_C`'s ``truth_row``, or None without a compiler or where numpy's orders differ."""
    lib = _library()
    return None if lib is None or not numpy_orders_agree() else lib.truth_row


@functools.cache
def numpy_orders_agree() -> bool:
    """Whether this host's numpy computes the three-term products as `TRUTH_C` does.

    Random inputs of the shapes and layouts the Python path uses: ``R.T @ v`` (3, 3) by
    (3,), a contact's ``f @ frame`` (batched (k, 1, 3) @ (k, 3, 3), contiguous and strided
    like MuJoCo's contact array), ``x @ R`` (4, 3) by (3, 3), ``einsum('ij,ij->i')`` on
    (4, 3) and (5, 3). False without a compiler.
    """
    lib = _library()
    if lib is None:
        return False
    rng = np.random.default_rng(20260501)

    def c_dot(fun, x, sx, y, sy):
        return fun(x.ctypes.data, sx, y.ctypes.data, sy)

    for _ in range(200):
        r = np.linalg.qr(rng.normal(size=(3, 3)))[0].copy()
        v6 = rng.normal(size=6) * 10.0 ** rng.integers(-3, 4)
        x = rng.normal(size=(4, 3)) * 10.0 ** rng.integers(-3, 5)
        y = rng.normal(size=(5, 3))
        records = np.zeros((3, 30))  # contact frames inside longer records, as MuJoCo's
        records[:, 4:13] = rng.normal(size=(3, 9))
        frames_strided = records[:, 4:13].reshape(3, 3, 3)
        f = rng.normal(size=(3, 3)) * 1e3
        checks = [
            (r.T @ v6[:3], [c_dot(lib.dot_left, r[:, j], 3, v6, 1) for j in range(3)]),
            (x @ r, [[c_dot(lib.dot_fused, x[i], 1, r[:, j], 3) for j in range(3)]
                     for i in range(4)]),
            (np.einsum("ij,ij->i", x, x), [lib.dot_einsum(a.ctypes.data, a.ctypes.data)
                                           for a in x]),
            (np.einsum("ij,ij->i", y, y), [lib.dot_einsum(a.ctypes.data, a.ctypes.data)
                                           for a in y])]
        for frames in (frames_strided, np.ascontiguousarray(frames_strided)):
            fc = np.ascontiguousarray(frames)
            checks.append(((f[:, None, :] @ frames)[:, 0], [
                [c_dot(lib.dot_left, f[i], 1, fc[i, :, j].copy(), 1) for j in range(3)]
                for i in range(3)]))
        for numpy_value, c_value in checks:
            if np.asarray(numpy_value).tobytes() != np.asarray(c_value, float).tobytes():
                return False
    return True
