"""The tracking controller's tick in C: its QP's costs and bounds in one pass, the builder's bits.

`WholeBodyQPController` solves a QP of the nine axis accelerations (with a force model also
the wheel-speed scale and the slacks) whose Hessian is constant (its tasks' Jacobians are).
Built by `wbc.qp.QPBuilder` from its tasks, its constraints and a `QPContext`, the nine axes'
costs and bounds were ~30 us of Python a tick (some thirty small numpy calls and as many small
objects) around a 9 us solve. ``tracking_qp`` computes the same numbers in one call on kept
buffers: the references clipped and scaled as `RuckigReference.sample_into` does, the PD
errors of the `JointTask` s, the damping error of the `DampingTask`, their linear terms added
up in the builder's order, the brake acceleration (`AxisLimits.brake_acceleration`), and the
acceleration, velocity and position boxes, the last two by `LIMITS_C`'s own functions (what
`VelocityLimit` and `PositionLimit` run in C), intersected as the builder does.
``tracking_state`` checks the state's magnitudes as `Controller._check_state` does and gives
the reference governor its errors from the positions of the last ``tracking_qp``. The same
IEEE operations in the same order (no contraction into fused multiply-adds: `models.cbuild`),
numpy's rules for ``clip``, ``maximum`` and ``minimum`` (NaN; on ties the bound of ``clip``,
the second argument of ``maximum`` and ``minimum``, as this host's numpy does). The Hessian
is the builder's, and the force model's terms (speed scale, slacks, force rows) are a
builder's of those tasks and constraints alone (`WholeBodyQPController._compiled_qp`).

Why the linear term is the builder's bits: each task's ``J^T W e`` is a product whose row of an
axis has one nonzero entry (``w`` times a selection); the other entries add exact zeros, so the
row is ``w e`` rounded once; and ``q = 0 + c_1 + c_2 + c_3`` starts at +0 and only adds, so a
task that leaves an axis out adds nothing that shows there. Tested against the builder over
closed-loop ticks and random states, bit for bit (`tests/test_tracking_c.py`).
"""

from __future__ import annotations

import ctypes

import numpy as np

from models.cbuild import bind, load_shared
from models.coordinates import N_INDEPENDENT
from wbc.axes import N_AXES
from wbc.constraints import (
    AccelerationLimit,
    NormalForceConstraint,
    PositionLimit,
    SpeedScaleLimit,
    VelocityLimit,
)
from wbc.constraints.limits_c import LIMITS_C
from wbc.tasks import (
    DampingTask,
    JointTask,
    SlackPenaltyTask,
    SpeedScaleTask,
    SuspensionPostureTask,
)

__all__ = ["TRACKING_C", "CompiledTrackingQP", "compiled_tracking_qp", "tracking_library"]

_N_STATE = 12 + 3 * N_INDEPENDENT  # base twist (6), base acceleration (6), q, qd, qdd
_N_REF = 2  # references: the crane's and the suspension's
# Offsets into the input buffer, as TRACKING_C's enum: the state, per tick; the references'
# clocks and samples, per tick; then the constants.
_RAW = _N_STATE
_DT = _RAW + 3 * N_AXES + 2 * _N_REF
_POS = _DT + 1 + 3 * N_AXES
_REF_LO = _POS + 8 * N_AXES + 2
_MAX = _REF_LO + 6 * N_AXES + 1
_N_IN = _MAX + 1
_N_OUT = 4 * N_AXES + _N_REF
# What a controller may have besides: terms of the speed scale and the slacks only.
_REST = (SpeedScaleTask, SlackPenaltyTask, NormalForceConstraint, SpeedScaleLimit)

TRACKING_C = LIMITS_C + f"#define NI {N_INDEPENDENT}\n" + r"""
#include <string.h>
enum { N_REF = 2 };
/* Offsets into `in`: per tick, then the constants (`CompiledTrackingQP` writes them). */
enum {
  Q = 12, QD = Q + NI,    /* the state's magnitudes: twist (6), acceleration (6), q, qd, qdd */
  RAW = QD + 2 * NI,      /* per reference its sample as Ruckig gives it, p (n), v (n),
                             a (n), then its clock's rate and the rate squared */
  DT = RAW + 3 * NA + 2 * N_REF,  /* the control period */
  ACC = DT + 1, VHI = ACC + NA, VLO = VHI + NA,  /* AxisLimits: a_max, v_hi, v_lo */
  POS = VLO + NA,         /* position_bounds' constants: q_hi, q_lo, -b dt, (b dt)^2, 2 b, T, T^2 */
  REF_LO = POS + 8 * NA + 2, REF_HI = REF_LO + NA,  /* each axis's reference's clip limits */
  KP = REF_HI + NA, KD = KP + NA, W = KD + NA,    /* the JointTask of each axis (if any) */
  WD = W + NA, TD = WD + NA,                        /* DampingTask: weights, time constant */
  MAX_STATE = TD + 1                                /* MAX_STATE_MAGNITUDE */
};
/* map: per axis its reference, the offset in RAW of its position and of its reference's
   clock, its reference's size, and 1 if a JointTask has it. out: q (9), lb (9), ub (9), the
   reference positions (9), the governor's error per reference. */
enum { OWNER = 0, SLOT = NA, CLOCK = 2 * NA, SIZE = 3 * NA, JOINT = 4 * NA };
enum { QLIN = 0, LB = NA, UB = 2 * NA, REF_P = 3 * NA, ERR = 4 * NA };

/* numpy's clip with array bounds: NaN passes, ties give the bound. */
static double np_clip(double x, double lo, double hi) {
  double t = (x > lo || isnan(x)) ? x : lo;
  return (t < hi || isnan(t)) ? t : hi;
}
/* numpy's maximum and minimum as this host's builds do them: NaN in the first wins, then NaN
   in the second; ties give the second (LIMITS_C's np_max and np_min give the first). */
static double np_maximum(double a, double b) { return (a > b || isnan(a)) ? a : b; }
static double np_minimum(double a, double b) { return (a < b || isnan(a)) ? a : b; }

/* 1 if max |state| > MAX_STATE (numpy's reduction: a NaN makes it NaN, not greater), else
   0; out[ERR + r]: max |reference position - q| over reference r's axes, the positions
   those of the last tracking_qp. */
int tracking_state(const double* in, const long* map, double* out) {
  double m = fabs(in[0]);
  int i, seen[N_REF] = {0};
  for (i = 1; i < QD + 2 * NI; ++i) m = np_maximum(m, fabs(in[i]));
  for (i = 0; i < NA; ++i) {
    const long r = map[OWNER + i];
    const double e = fabs(out[REF_P + i] - in[Q + i]);
    out[ERR + r] = seen[r] ? np_maximum(out[ERR + r], e) : e;
    seen[r] = 1;
  }
  return m > in[MAX_STATE];
}

/* The QP's linear term and bounds; 1 if a box is empty (lower > upper), else 0. */
int tracking_qp(const double* in, const long* map, double* out) {
  const double dt = in[DT];
  double pin[11 * NA + 3], vin[4 * NA + 1], pos[2 * NA], vel[2 * NA];
  int i, empty = 0;
  for (i = 0; i < NA; ++i) {
    const double qd = in[QD + i];
    const double brake = -np_clip(qd / dt, -in[ACC + i], in[ACC + i]);
    pin[i] = in[Q + i];
    pin[NA + i] = vin[i] = qd;
    pin[2 * NA + i] = vin[NA + i] = brake;
  }
  memcpy(pin + 3 * NA, in + POS, (8 * NA + 2) * sizeof(double));
  pin[11 * NA + 2] = dt;
  memcpy(vin + 2 * NA, in + VHI, 2 * NA * sizeof(double));
  vin[4 * NA] = dt;
  position_bounds(pin, pos);
  velocity_bounds(vin, vel);
  for (i = 0; i < NA; ++i) {
    const double* clock = in + RAW + map[CLOCK + i];
    const double* raw = in + RAW + map[SLOT + i];
    const long n = map[SIZE + i];
    double p = raw[0], v = raw[n] * clock[0], a = raw[2 * n] * clock[1];
    double c = 0.0, lo = -INFINITY, hi = INFINITY;
    p = np_clip(p, in[REF_LO + i], in[REF_HI + i]);  /* a held position: clipped already,
                                                         and clip is idempotent */
    if (map[JOINT + i]) {  /* K_p (q - q_ref) - qdd_ref + K_d (qd - qd_ref), weighted */
      double e = in[Q + i] - p, d = in[QD + i] - v;
      e *= in[KP + i];
      e -= a;
      d *= in[KD + i];
      e += d;
      c += in[W + i] * e;
    }
    c += in[WD + i] * (in[QD + i] / in[TD]);  /* the damping task: w qd / T */
    lo = np_maximum(lo, -in[ACC + i]);
    hi = np_minimum(hi, in[ACC + i]);
    lo = np_maximum(lo, vel[i]);
    hi = np_minimum(hi, vel[NA + i]);
    lo = np_maximum(lo, pos[i]);
    hi = np_minimum(hi, pos[NA + i]);
    out[QLIN + i] = c;
    out[LB + i] = lo;
    out[UB + i] = hi;
    out[REF_P + i] = p;
    if (lo > hi) empty = 1;
  }
  return empty;
}
"""


class CompiledTrackingQP:
    """`TRACKING_C` on kept buffers for one controller's tasks, limits and references.

    Per tick: `load` the state, `set_sample` of each reference, `run`. ``lin``, ``lower``,
    ``upper`` and ``position`` (9,) are then the QP's linear term and bounds and the
    references' positions (clipped); ``errors`` (2,), after `load`, the governor's errors
    from the positions of the last `run`.

    Args:
        lib: The compiled `TRACKING_C`.
        tasks: The crane's and the suspension's `JointTask` (disjoint axes) and a
            `DampingTask`.
        references: The crane's and the suspension's `RuckigReference`, every axis in one.
        limits, dt: The axis limits and the control period [s].
        position_limit: The `PositionLimit` (its constants).
        max_magnitude: The largest magnitude a state may have (`Controller._check_state`).

    Attributes:
        state: The `MachineState` last loaded.
        kept: Per reference, the position array it held (`RuckigReference.kept`) when the
            last `run` wrote ``position``: while it holds the same array, ``errors`` are its.
    """

    def __init__(self, lib, tasks, references, limits, dt: float,
                 position_limit: PositionLimit, max_magnitude: float):
        na = N_AXES
        self.references = tuple(references)
        self.inp = np.zeros(_N_IN)
        self.map = np.zeros(5 * na, dtype=np.int_)
        self.out = np.zeros(_N_OUT)
        self.call = bind(lib.tracking_qp, self.inp, self.map, self.out)
        self._check = bind(lib.tracking_state, self.inp, self.map, self.out)
        inp, (owner, slot, clock, size, joint) = self.inp, self.map.reshape(5, na)
        inp[_DT] = dt
        inp[_DT + 1:_POS] = np.concatenate((limits.acceleration, limits.velocity_upper,
                                            limits.velocity_lower))
        const = position_limit.constants(limits, dt)
        inp[_POS:_REF_LO] = np.concatenate((limits.position_upper, limits.position_lower,
                                            *const[:3], const[3:5]))
        self._blocks = []  # per reference: its sample's and its clock's place in ``inp``
        first = 0  # in RAW
        lo, hi, kp, kd, w, wd = inp[_REF_LO:_REF_LO + 6 * na].reshape(6, na)
        for r, ref in enumerate(self.references):
            owner[ref.axes], size[ref.axes] = r, ref.n
            slot[ref.axes] = first + np.arange(ref.n)
            clock[ref.axes] = first + 3 * ref.n
            lo[ref.axes], hi[ref.axes] = ref.position_lower, ref.position_upper
            self._blocks.append(slice(_RAW + first, _RAW + first + 3 * ref.n + 2))
            first += 3 * ref.n + 2
        for task in tasks[:2]:
            joint[task.axes] = 1
            kp[task.axes], kd[task.axes], w[task.axes] = task.kp, task.kd, task.weight
        wd[:] = tasks[2].weight
        inp[_MAX - 1] = tasks[2].time_constant
        inp[_MAX] = max_magnitude
        self._state_in = inp[:_N_STATE]
        self.lin, self.lower, self.upper, self.position = self.out[:4 * na].reshape(4, na)
        self.errors = self.out[4 * na:]
        self.state = None
        self.kept: list = [None] * _N_REF

    def load(self, state, magnitudes) -> bool:
        """Take ``state`` (its ``magnitudes``: the arrays `Controller._check_state` checks).

        Returns:
            False when an entry's magnitude exceeds the limit (numpy's rule: NaN does not).
        """
        np.concatenate(magnitudes, out=self._state_in)
        self.state = state
        return self._check() == 0

    def set_sample(self, r: int, sample: list, rate: float) -> None:
        """Reference ``r``'s raw sample (`RuckigReference.sample_raw`) and clock rate."""
        self.inp[self._blocks[r]] = sample + [rate, rate**2]  # `sample_into`'s scales

    def run(self) -> bool:
        """Evaluate; False when a box came out empty (lower > upper somewhere)."""
        return self.call() == 0


def compiled_tracking_qp(tasks, constraints, references, limits, dt: float, layout,
                         max_magnitude: float) -> CompiledTrackingQP | None:
    """A `CompiledTrackingQP` for these tasks, constraints and references, or None.

    None without a working C compiler, or unless they are what `TRACKING_C` computes: the
    tasks a crane `JointTask`, a `SuspensionPostureTask` on other axes and a `DampingTask`,
    the constraints `AccelerationLimit`, `VelocityLimit`, `PositionLimit` (in these orders),
    two references that hold every axis once, and a layout of the nine axes of one step.
    After those only the force model's tasks and constraints (`SpeedScaleTask`,
    `SlackPenaltyTask`, `NormalForceConstraint`, `SpeedScaleLimit`): their terms touch the
    speed scale and the slacks only, and a builder of them alone makes those.
    """
    kinds = (JointTask, SuspensionPostureTask, DampingTask, AccelerationLimit,
             VelocityLimit, PositionLimit)
    items = (*tasks[:3], *constraints[:3])
    rest = (*tasks[3:], *constraints[3:])
    if (len(items) != len(kinds) or any(type(x) is not k for x, k in zip(items, kinds))
            or not all(type(x) in _REST for x in rest)):
        return None
    joint = np.concatenate([t.axes for t in tasks[:2]])
    covered = np.sort(np.concatenate([ref.axes for ref in references]))
    if (len(references) != _N_REF or np.unique(joint).size != joint.size
            or not np.array_equal(covered, np.arange(N_AXES)) or layout.n_axes != N_AXES
            or layout.n_steps != 1):
        return None
    lib = tracking_library()
    if lib is None:
        return None
    return CompiledTrackingQP(lib, tasks, references, limits, dt, constraints[2],
                              max_magnitude)


def tracking_library() -> ctypes.CDLL | None:
    """`TRACKING_C` compiled and loaded once per process; None without a compiler."""
    return load_shared(TRACKING_C, "tracking_qp", {
        "tracking_qp": ([ctypes.c_void_p] * 3, ctypes.c_int),
        "tracking_state": ([ctypes.c_void_p] * 3, ctypes.c_int)}, "the QP builder")
