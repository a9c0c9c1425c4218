"""The physics-rate step listeners' work in C: the sensors' truths and the wheels' forces.

`scenarios.sensors.SensorSimulator` and `scenarios.physics_rate.NormalForceRecorder` run after
every physics step (500 per simulated second). In Python each cost 20-40 us a step, mostly the
calls into MuJoCo's bindings and the numpy scalars around them: a third of a closed loop's
simulation time. Here each is one call of a few lines of C that reads MuJoCo's ``mjData``
directly and calls MuJoCo's own functions (the library the bindings loaded,
`models.cbuild.mujoco_options`).

Both compute what the Python listeners compute, operation for operation (IEEE doubles in the
same order, no fused multiply-adds: `models.cbuild`), so the recordings are the same bits;
`tests/test_listeners_c.py` compares them. Without a compiler the Python listeners run.
Each also has a step hook (``*_hook_record``, ``*_hook_room``: one record of its arguments)
through which `scenarios.step_c` calls it from its own loop of physics steps.
"""

from __future__ import annotations

import ctypes
import functools

import numpy as np

from models.cbuild import load_shared
from models.state import N_SERVO_AXES

__all__ = ["DELIVER_C", "DELIVER_WORDS", "FORCES_C", "N_STREAMS", "SENSORS_C", "compiled_delivery",
           "compiled_forces", "compiled_sensors", "forces_hooks", "sensors_hooks"]

N_STREAMS = 8  # IMU accelerometer, gyroscope, strokes, angles, pressures, wheels, drive, links

# One physics step of `SensorSimulator.__call__`. Streams in the order above; a stream s is
# due when n % every[s] == 0 (the links' only with n_links > 0); its truth goes to row
# count[s] of truths[s] (width[s] columns), its time to times[s][count[s]]. Returns 1, and
# records nothing, when a due stream's buffer is full (count == cap): the caller grows it.
# ix: base body, the base's six dofs, the nine axes' qpos, five pressure cylinders'
# actuators, four wheel dofs, four wheel actuators, the link accelerometers' bodies.
# par: the IMU's position (3) in fb, gravity, the link accelerometers' positions (3 each).
SENSORS_C = r"""
#include <mujoco/mujoco.h>
enum {ACC, GYRO, LIN, ANG, PRESS, WHEELS, DRIVE, LINK, N_STREAMS};
static const int width0[N_STREAMS] = {3, 3, 6, 3, 5, 2, 2, 0};

int sensors_record(const mjModel* m, mjData* d, const double* qpos, const double* qvel,
                   double t, long n, const long* every, long* count, const long* cap,
                   double* const* times, double* const* truths, const long* ix,
                   const double* par, int n_links) {
  int due[N_STREAMS], s, i, k;
  const long *base_dof = ix + 1, *axes = ix + 7, *press = ix + 16, *wdof = ix + 21,
             *wact = ix + 25, *links = ix + 29;
  for (s = 0; s < N_STREAMS; ++s) {
    due[s] = (s != LINK || n_links > 0) && n % every[s] == 0;
    if (due[s] && count[s] >= cap[s]) return 1;
  }
#define ROW(s) (truths[s] + count[s] * (s == LINK ? 3 * n_links : width0[s]))
  if (due[ACC] || due[GYRO]) {
    const double* rot = d->xmat + 9 * ix[0];  /* row-major world <- fb */
    double w0 = qvel[base_dof[3]], w1 = qvel[base_dof[4]], w2 = qvel[base_dof[5]];
    if (due[ACC]) {
      double al0 = d->qacc[base_dof[3]], al1 = d->qacc[base_dof[4]],
             al2 = d->qacc[base_dof[5]];
      double p0 = par[0], p1 = par[1], p2 = par[2];
      double c0 = w1 * p2 - w2 * p1, c1 = w2 * p0 - w0 * p2, c2 = w0 * p1 - w1 * p0;
      double ax = d->qacc[base_dof[0]], ay = d->qacc[base_dof[1]],
             az = d->qacc[base_dof[2]] + par[3];
      double* r = ROW(ACC);
      r[0] = rot[0] * ax + rot[3] * ay + rot[6] * az + al1 * p2 - al2 * p1 + w1 * c2 - w2 * c1;
      r[1] = rot[1] * ax + rot[4] * ay + rot[7] * az + al2 * p0 - al0 * p2 + w2 * c0 - w0 * c2;
      r[2] = rot[2] * ax + rot[5] * ay + rot[8] * az + al0 * p1 - al1 * p0 + w0 * c1 - w1 * c0;
    }
    if (due[GYRO]) {
      double* r = ROW(GYRO);
      r[0] = w0; r[1] = w1; r[2] = w2;
    }
  }
  if (due[LIN]) for (i = 0; i < 6; ++i) ROW(LIN)[i] = qpos[axes[i]];
  if (due[ANG]) for (i = 0; i < 3; ++i) ROW(ANG)[i] = qpos[axes[6 + i]];
  if (due[PRESS]) for (i = 0; i < 5; ++i) ROW(PRESS)[i] = d->actuator_force[press[i]];
  if (due[WHEELS]) {  /* FL, RL, FR, RR */
    ROW(WHEELS)[0] = 0.5 * (qvel[wdof[0]] + qvel[wdof[1]]);
    ROW(WHEELS)[1] = 0.5 * (qvel[wdof[2]] + qvel[wdof[3]]);
  }
  if (due[DRIVE]) {
    ROW(DRIVE)[0] = d->actuator_force[wact[0]] + d->actuator_force[wact[1]];
    ROW(DRIVE)[1] = d->actuator_force[wact[2]] + d->actuator_force[wact[3]];
  }
  if (due[LINK]) {
    double acc[6], vel[6], *r = ROW(LINK);
    mj_rnePostConstraint(m, d);  /* fills cacc (outputs only: the physics is as is) */
    for (k = 0; k < n_links; ++k) {
      const double* p = par + 4 + 3 * k;
      mj_objectAcceleration(m, d, mjOBJ_XBODY, (int)links[k], acc, 1);
      mj_objectVelocity(m, d, mjOBJ_XBODY, (int)links[k], vel, 1);
      /* acc + alpha x p + w x (w x p), as `cross3` and numpy's sums */
      double wp0 = vel[1] * p[2] - vel[2] * p[1], wp1 = vel[2] * p[0] - vel[0] * p[2],
             wp2 = vel[0] * p[1] - vel[1] * p[0];
      r[3 * k] = acc[3] + (acc[1] * p[2] - acc[2] * p[1]) + (vel[1] * wp2 - vel[2] * wp1);
      r[3 * k + 1] = acc[4] + (acc[2] * p[0] - acc[0] * p[2]) + (vel[2] * wp0 - vel[0] * wp2);
      r[3 * k + 2] = acc[5] + (acc[0] * p[1] - acc[1] * p[0]) + (vel[0] * wp1 - vel[1] * wp0);
    }
  }
  for (s = 0; s < N_STREAMS; ++s)
    if (due[s]) times[s][count[s]++] = t;
  return 0;
}

/* The same as a step hook of `scenarios.step_c`: the step counter n and the arguments after
   it in one record (kept by `SensorSimulator`). */
typedef struct {
  long* n; const long* every; long* count; const long* cap; double* const* times;
  double* const* truths; const long* ix; const double* par; long n_links;
} sensors_hook;

int sensors_hook_record(void* ctx, const mjModel* m, mjData* d, const double* qpos,
                        const double* qvel, double t) {
  sensors_hook* h = (sensors_hook*)ctx;
  if (sensors_record(m, d, qpos, qvel, t, *h->n, h->every, h->count, h->cap, h->times,
                     h->truths, h->ix, h->par, (int)h->n_links)) return 1;
  ++*h->n;
  return 0;
}

int sensors_hook_room(void* ctx, long steps) {  /* every stream can take `steps` records */
  const sensors_hook* h = (const sensors_hook*)ctx;
  int s;
  for (s = 0; s < N_STREAMS; ++s)
    if (h->times[s] && h->count[s] + steps > h->cap[s]) return 0;
  return 1;
}
"""

# One physics step of `NormalForceRecorder.__call__`: each wheel's normal force, the sum of
# its live contacts' normal rows in contact order from 0.0, into out (4,).
FORCES_C = r"""
#include <mujoco/mujoco.h>
void forces_record(const mjData* d, const long* wheel_of_geom, double* out) {
  int i;
  out[0] = out[1] = out[2] = out[3] = 0.0;
  for (i = 0; i < d->ncon; ++i) {
    const mjContact* c = d->contact + i;
    long w0 = wheel_of_geom[c->geom[0]], w1 = wheel_of_geom[c->geom[1]];
    long wheel = w0 > w1 ? w0 : w1;
    if (wheel >= 0 && c->efc_address >= 0) out[wheel] += d->efc_force[c->efc_address];
  }
}

/* The same as a step hook of `scenarios.step_c`: samples n of cap, times, forces (cap, 4). */
typedef struct { long n, cap; double* time; double* force; const long* wheel_of_geom; }
    forces_hook;

int forces_hook_record(void* ctx, const mjModel* m, mjData* d, const double* qpos,
                       const double* qvel, double t) {
  forces_hook* h = (forces_hook*)ctx;
  if (h->n >= h->cap) return 1;
  forces_record(d, h->wheel_of_geom, h->force + 4 * h->n);
  h->time[h->n++] = t;
  return 0;
}

int forces_hook_room(void* ctx, long steps) {
  const forces_hook* h = (const forces_hook*)ctx;
  return h->n + steps <= h->cap;
}
"""

# `SensorSimulator.readings` in two passes over the streams (the slots of `SENSORS_C`; a
# stream with times[s] == NULL is absent). `deliver_count`: k[s], the readings recorded by
# tick - latency[s] (as `_Stream.deliver`), and the standard normals they need. The caller
# draws those at once (numpy's generator gives the same numbers as one draw per stream and
# kind), then `deliver_fill` applies `_Stream._errors` stream by stream in `order` (the
# order the Python path draws in), operation for operation: the chamber pressures of the
# pressure stream's forces, the bias random walk (its cumulative sum from the first step),
# scale, noise, quantization (rint: numpy's round half to even). Each stream's times and
# values go to out_t, out_y one after the other in `order`; what stays queued moves to
# the front of its buffer.
DELIVER_C = f"#define N_SETPOINT {N_SERVO_AXES}\n" + r"""
#include <math.h>
#include <string.h>
long deliver_count(int ns, const long* count, double* const* times, const double* latency,
                   double tick, const long* width, const double* walk, const double* noise,
                   long* k) {
  long total = 0, j;
  int s;
  for (s = 0; s < ns; ++s) {
    double limit = tick - latency[s] + 1e-9;
    k[s] = 0;
    if (!times[s]) continue;
    for (j = count[s]; j && times[s][j - 1] > limit; --j) {}
    k[s] = j;
    total += j * width[s] * ((walk[s] != 0.0) + (noise[s] != 0.0));
  }
  return total;
}

void deliver_fill(int ns, const long* order, const long* k, long* count,
                  double* const* times, double* const* truths, const long* width,
                  const long* twidth, double* const* scale, const int* scaled,
                  double* const* bias, const double* walk, const double* noise,
                  const double* res, long press, const double* areas, double back,
                  const double* z, double* out_t, double* out_y) {
  int o;
  for (o = 0; o < ns; ++o) {
    long s = order[o], kk = k[s], n = width[s], m = twidth[s], i, j, rest;
    double *y = out_y, *b = bias[s], cs[64], last[64];
    if (!times[s] || n > 64) continue;
    memcpy(out_t, times[s], kk * sizeof(double));
    for (i = 0; i < kk; ++i) {
      const double* f = truths[s] + i * m;
      if (s == press)
        for (j = 0; j < m; ++j) {
          double a_a = areas[2 * j], a_b = areas[2 * j + 1];
          double p_a = (f[j] + back * a_b) / a_a, p_b = (back * a_a - f[j]) / a_b;
          if (f[j] >= 0) p_b = back; else p_a = back;
          y[i * n + 2 * j] = p_a;
          y[i * n + 2 * j + 1] = p_b;
        }
      else
        memcpy(y + i * n, f, n * sizeof(double));
    }
    for (i = 0; i < kk; ++i)
      for (j = 0; j < n; ++j) {
        double v = y[i * n + j], bj = b[j];
        if (walk[s] != 0.0) {
          double step = walk[s] * z[i * n + j];
          cs[j] = i ? cs[j] + step : step;
          bj = b[j] + cs[j] - step;
          if (i == kk - 1) last[j] = bj + step;
        }
        y[i * n + j] = scaled[s] ? scale[s][j] * v + bj : v + bj;
      }
    if (walk[s] != 0.0) {
      if (kk) memcpy(b, last, n * sizeof(double));
      z += kk * n;
    }
    if (noise[s] != 0.0) {
      for (i = 0; i < kk * n; ++i) y[i] += noise[s] * z[i];
      z += kk * n;
    }
    if (res[s] != 0.0)
      for (i = 0; i < kk * n; ++i) y[i] = rint(y[i] / res[s]) * res[s];
    rest = count[s] - kk;
    memmove(times[s], times[s] + kk, rest * sizeof(double));
    memmove(truths[s], truths[s] + kk * m, rest * m * sizeof(double));
    count[s] = rest;
    out_t += kk;
    out_y += kk * n;
  }
}

/* The two passes with their fixed arguments read from one array of words (`DELIVER_WORDS`,
   pointers and counts as 64-bit integers): a ctypes call converts each argument it is
   given (~0.15 us each), and these take 2 and 6 instead of 9 and 20. The fill also copies
   the servos' setpoints (N_SETPOINT) into the reading; 1 if one is not finite. */
enum {W_NS, W_COUNT, W_TIMES, W_LATENCY, W_WIDTH, W_WALK, W_NOISE, W_K, W_NO, W_ORDER,
      W_TRUTHS, W_TWIDTH, W_SCALE, W_SCALED, W_BIAS, W_RES, W_PRESS, W_AREAS, W_BACK};

long deliver_count_words(const long* w, double tick) {
  return deliver_count((int)w[W_NS], (const long*)w[W_COUNT], (double* const*)w[W_TIMES],
                       (const double*)w[W_LATENCY], tick, (const long*)w[W_WIDTH],
                       (const double*)w[W_WALK], (const double*)w[W_NOISE], (long*)w[W_K]);
}

int deliver_fill_words(const long* w, const double* z, double* out_t, double* out_y,
                       const double* setpoint, double* out_setpoint) {
  int i, finite = 1;
  for (i = 0; i < N_SETPOINT; ++i) {  /* the reading's copy of the servos' setpoints */
    out_setpoint[i] = setpoint[i];
    finite = finite && isfinite(setpoint[i]);
  }
  deliver_fill((int)w[W_NO], (const long*)w[W_ORDER], (const long*)w[W_K],
               (long*)w[W_COUNT], (double* const*)w[W_TIMES], (double* const*)w[W_TRUTHS],
               (const long*)w[W_WIDTH], (const long*)w[W_TWIDTH], (double* const*)w[W_SCALE],
               (const int*)w[W_SCALED], (double* const*)w[W_BIAS], (const double*)w[W_WALK],
               (const double*)w[W_NOISE], (const double*)w[W_RES], w[W_PRESS],
               (const double*)w[W_AREAS], *(const double*)w[W_BACK], z, out_t, out_y);
  return !finite;
}
"""

# `DELIVER_C`'s words (``deliver_*_words``' first argument), in their order: the number of
# slots; the counts, times' buffers, latencies, widths, walks, noises and k of the slots;
# the number of streams in `order` and `order`; the truths' buffers, truths' widths, scales,
# scaled flags, biases, resolutions, the pressure stream's slot, the cylinders' areas and
# (the address of) the back pressure.
DELIVER_WORDS = ("ns", "count", "times", "latency", "width", "walk", "noise", "k", "n_order",
                 "order", "truths", "twidth", "scale", "scaled", "bias", "res", "press",
                 "areas", "back")

_P = ctypes.c_void_p


def _sensors_lib():
    return load_shared(SENSORS_C, "sensors_record", {"sensors_record": (
        [_P, _P, _P, _P, ctypes.c_double, ctypes.c_long] + [_P] * 7 + [ctypes.c_int],
        ctypes.c_int)}, "the Python sensors", mujoco=True)


def _forces_lib():
    return load_shared(FORCES_C, "forces_record", {"forces_record": ([_P, _P, _P], None)},
                       "the Python force recorder", mujoco=True)


def _hooks(lib, prefix: str) -> tuple[int, int] | None:
    """The library's step hooks ``(record, room)`` as function addresses (`scenarios.step_c`)."""
    if lib is None:
        return None
    return tuple(ctypes.cast(getattr(lib, f"{prefix}_hook_{part}"), _P).value
                 for part in ("record", "room"))


def compiled_sensors():
    """`SENSORS_C`'s ``sensors_record``, or None without a working compiler."""
    lib = _sensors_lib()
    return None if lib is None else lib.sensors_record


def sensors_hooks() -> tuple[int, int] | None:
    """`SENSORS_C`'s step hooks (record, room) as addresses, or None without a compiler."""
    return _hooks(_sensors_lib(), "sensors")


def compiled_delivery():
    """``bind`` of `DELIVER_C`'s two passes to their words, or None without a compiler.

    ``bind(words)``: ``words`` the `DELIVER_WORDS` by name (ints, or arrays whose addresses
    are packed: the caller keeps them alive) gives ``(count, fill, packed)``:
    ``count(tick)`` and ``fill(z, out_t, out_y, setpoint, out_setpoint)`` (addresses), the
    passes on the words (the fill's 1: a setpoint is not finite, all written still), and
    the int64 array of the words they read (to keep too).
    """
    lib = load_shared(DELIVER_C, "sensors_deliver", {
        "deliver_count_words": ([_P, ctypes.c_double], ctypes.c_long),
        "deliver_fill_words": ([_P] * 6, ctypes.c_int)}, "the Python sensor errors")
    if lib is None:
        return None

    def bind(words: dict) -> tuple:
        packed = np.array([v if type(v) is int else v.ctypes.data
                           for v in (words[name] for name in DELIVER_WORDS)], np.int64)
        at = packed.ctypes.data
        return (functools.partial(lib.deliver_count_words, at),
                functools.partial(lib.deliver_fill_words, at), packed)

    return bind


def compiled_forces():
    """`FORCES_C`'s ``forces_record``, or None without a working compiler."""
    lib = _forces_lib()
    return None if lib is None else lib.forces_record


def forces_hooks() -> tuple[int, int] | None:
    """`FORCES_C`'s step hooks (record, room) as addresses, or None without a compiler."""
    return _hooks(_forces_lib(), "forces")
