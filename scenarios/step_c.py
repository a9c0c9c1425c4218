"""The simulator's physics steps in C: the valves, MuJoCo's merged step, the step listeners.

`Simulator.step` advances in chunks of a few steps (its anti-windup period). Per step the
Python path sets the servos' inputs from the valves' setpoint path (numpy on nine numbers),
holds the braked wheels, copies the state for the step listeners, runs MuJoCo's two half
steps with the contact merge between them (`models.mujoco.ContactMerge`) through the
bindings, and calls each listener: ~25 us of Python around MuJoCo's own ~25 us. `STEP_C` runs
a whole chunk in one call, operation for operation as the Python path (IEEE doubles in the
same order, no fused multiply-adds: `models.cbuild`; ``np.maximum``/``np.minimum`` as
``a >= b || a != a ? a : b``), with MuJoCo's own functions (the library the bindings loaded),
so the simulation is the same bits; `tests/test_step_c.py` compares the two paths.

Step listeners take part through their step hooks (`StepHook`): C functions
``int record(void* ctx, const mjModel* m, mjData* d, const double* qpos,
const double* qvel, double t)`` (the listener's call after a step, 0 when recorded) and
``int room(void* ctx, long steps)`` (1 when ``steps`` records fit), with the listener's own
record ``ctx``. A listener without a hook (a Python callable) sends the simulator back to
the Python path, as does a host without a C compiler.
"""

from __future__ import annotations

import ctypes
from typing import Callable, NamedTuple

import numpy as np

from models.cbuild import address, load_shared
from models.mujoco.contacts import MERGE_C
from scenarios.errors import SimulatorError

__all__ = ["MAX_CHUNK", "STEP_C", "CompiledStep", "StepHook", "compiled_step"]

MAX_CHUNK = 8  # steps per call at most (the simulator's chunks are 5)
_MAX_SERVOS = 16

# One chunk of `Simulator.step`: the setpoint path of the chunk clipped to the stroke range,
# each step's servo inputs (path - lead * joint speed) and wheel hold, MuJoCo's step with the
# contacts merged (`MERGE_C`'s `merge`, then the constraints rebuilt as `ContactMerge._rebuild`)
# and the hooks' records; the snapshot of step `snap` (-1: none) before its inputs are set,
# into `snapshot` (qpos, qvel, setpoint, time); the next setpoint, the path's end within `band`
# of each stroke (anti-windup), in place. Returns 0; 1 when one of MuJoCo's warnings of a
# diverged simulation has been counted; -1 - l before any step when hook l has no room for
# `chunk` records; -100 - l when hook l did not record after all (a broken hook).
STEP_C = MERGE_C + r"""
#include <stddef.h>
#include <stdlib.h>
#include <mujoco/mujoco.h>
typedef int (*hook_record)(void*, const mjModel*, mjData*, const double*, const double*,
                           double);
typedef int (*hook_room)(void*, long);

typedef struct {
  long n_servo, servo_ctrl;
  const long *servo_dof, *servo_qpos;
  const double *lo, *hi, *band, *rates, *lead;
  const long *wheel_qpos, *wheel_ctrl;
  const double *wheel_lo, *wheel_hi;
  double hold_gain, dt;
  const int* owner_of_geom;
  long n_wheels;
  double cos_angle, distance2;
  long n_hooks;
  void* const* record;
  void* const* room;
  void* const* ctx;
  double *qpos, *qvel;  /* the hooks' copy of the state a step starts from */
} step_setup;

static double max_np(double a, double b) { return (a >= b || a != a) ? a : b; }
static double min_np(double a, double b) { return (a <= b || a != a) ? a : b; }

static void merged_step(const mjModel* m, mjData* d, const step_setup* s) {
  int stack[512], *scratch = stack, n;
  mj_step1(m, d);
  n = d->ncon;
  if (n > 256 && !(scratch = (int*)malloc(2 * (size_t)n * sizeof(int)))) scratch = NULL;
  if (scratch && merge((char*)d->contact, n, (long)sizeof(mjContact),
                       (long)offsetof(mjContact, dist), (long)offsetof(mjContact, pos),
                       (long)offsetof(mjContact, frame), (long)offsetof(mjContact, geom),
                       (long)offsetof(mjContact, exclude),
                       (long)offsetof(mjContact, efc_address), s->owner_of_geom,
                       (int)s->n_wheels, s->cos_angle, s->distance2, scratch, scratch + n)) {
    mj_makeConstraint(m, d);
    mj_island(m, d);
    mj_projectConstraint(m, d);
    mj_referenceConstraint(m, d);
  }
  if (scratch != stack) free(scratch);
  mj_step2(m, d);
}

int step_chunk(const mjModel* m, mjData* d, const step_setup* s, int chunk, int snap,
               double* setpoint, const double* hold, double* snapshot) {
  const double *rates = s->rates, *lead = s->lead;
  double path[""" + str(MAX_CHUNK + 1) + "][" + str(_MAX_SERVOS) + r"""];
  long i, k, l, ns = s->n_servo;
  for (l = 0; l < s->n_hooks; ++l)
    if (!((hook_room)s->room[l])(s->ctx[l], chunk)) return (int)(-1 - l);
  for (k = 0; k <= chunk; ++k)
    for (i = 0; i < ns; ++i)
      path[k][i] = min_np(max_np(setpoint[i] + (double)k * (s->dt * rates[i]), s->lo[i]),
                          s->hi[i]);
  for (k = 0; k < chunk; ++k) {
    double t = d->time;
    if (k == snap) {
      for (i = 0; i < m->nq; ++i) snapshot[i] = d->qpos[i];
      for (i = 0; i < m->nv; ++i) snapshot[m->nq + i] = d->qvel[i];
      for (i = 0; i < ns; ++i) snapshot[m->nq + m->nv + i] = path[k][i];
      snapshot[m->nq + m->nv + ns] = t;
    }
    for (i = 0; i < ns; ++i)
      d->ctrl[s->servo_ctrl + i] = path[k][i] - lead[i] * d->qvel[s->servo_dof[i]];
    if (hold)
      for (i = 0; i < 4; ++i)
        d->ctrl[s->wheel_ctrl[i]] = min_np(max_np(
            s->hold_gain * (hold[i] - d->qpos[s->wheel_qpos[i]]), s->wheel_lo[i]),
            s->wheel_hi[i]);
    if (s->n_hooks) {
      for (i = 0; i < m->nq; ++i) s->qpos[i] = d->qpos[i];
      for (i = 0; i < m->nv; ++i) s->qvel[i] = d->qvel[i];
    }
    merged_step(m, d, s);
    for (l = 0; l < s->n_hooks; ++l)
      if (((hook_record)s->record[l])(s->ctx[l], m, d, s->qpos, s->qvel, t))
        return (int)(-100 - l);
  }
  for (i = 0; i < ns; ++i) {
    double x = d->qpos[s->servo_qpos[i]];
    setpoint[i] = min_np(max_np(path[chunk][i], x - s->band[i]), x + s->band[i]);
  }
  return d->warning[mjWARN_BADQPOS].number || d->warning[mjWARN_BADQVEL].number
         || d->warning[mjWARN_BADQACC].number || d->warning[mjWARN_BADCTRL].number;
}
"""


class StepHook(NamedTuple):
    """A step listener's C form (module docstring).

    Attributes:
        record: Address of its ``record`` function.
        room: Address of its ``room`` function.
        ctx: Address of its record (the functions' first argument).
        make_room: Called with a number of steps when ``room`` said no: grows the buffers
            (and updates ``ctx``) so that that many records fit.
    """

    record: int
    room: int
    ctx: int
    make_room: Callable[[int], None]


class _Setup(ctypes.Structure):
    _fields_ = [(name, ctypes.c_long if kind == "l" else ctypes.c_double if kind == "d"
                 else ctypes.c_void_p) for name, kind in (
        ("n_servo", "l"), ("servo_ctrl", "l"), ("servo_dof", "p"), ("servo_qpos", "p"),
        ("lo", "p"), ("hi", "p"), ("band", "p"), ("rates", "p"), ("lead", "p"),
        ("wheel_qpos", "p"), ("wheel_ctrl", "p"),
        ("wheel_lo", "p"), ("wheel_hi", "p"), ("hold_gain", "d"), ("dt", "d"),
        ("owner_of_geom", "p"), ("n_wheels", "l"), ("cos_angle", "d"), ("distance2", "d"),
        ("n_hooks", "l"), ("record", "p"), ("room", "p"), ("ctx", "p"), ("qpos", "p"),
        ("qvel", "p"))]


def _library():
    _P = ctypes.c_void_p
    return load_shared(STEP_C, "sim_step", {"step_chunk": (
        [_P, _P, _P, ctypes.c_int, ctypes.c_int] + [_P] * 3, ctypes.c_int)},
        "the Python simulator step", mujoco=True)


class CompiledStep:
    """`STEP_C` bound to one simulator and its step hooks (see `compiled_step`)."""

    def __init__(self, fun, model, data, merge, valve: dict, hooks: list[StepHook]):
        m = model
        owner, n_wheels, cos_angle, distance2 = merge.c_arguments()
        ints = {k: np.ascontiguousarray(valve[k], np.int64)
                for k in ("servo_dof", "servo_qpos", "wheel_qpos", "wheel_ctrl")}
        floats = {k: np.ascontiguousarray(valve[k], float)
                  for k in ("lo", "hi", "band", "wheel_lo", "wheel_hi")}
        for k in ("rates", "lead"):  # the simulator's own arrays, written in place
            floats[k] = valve[k]
            _read(floats[k])
        tables = [np.array([getattr(h, f) for h in hooks] or [0], np.uint64)
                  for f in ("record", "room", "ctx")]
        self._scratch = (np.zeros(m.nq), np.zeros(m.nv))
        self._setup = _Setup(
            n_servo=len(floats["lo"]), servo_ctrl=int(valve["servo_ctrl"]),
            hold_gain=float(valve["hold_gain"]), dt=float(m.opt.timestep),
            owner_of_geom=owner.ctypes.data, n_wheels=n_wheels, cos_angle=cos_angle,
            distance2=distance2, n_hooks=len(hooks),
            record=tables[0].ctypes.data, room=tables[1].ctypes.data,
            ctx=tables[2].ctypes.data, qpos=self._scratch[0].ctypes.data,
            qvel=self._scratch[1].ctypes.data,
            **{k: a.ctypes.data for k, a in {**ints, **floats}.items()})
        self._keep = (owner, ints, floats, tables)  # the C reads them
        self._hooks = hooks
        self._n_servo, self._nq, self._nv = len(floats["lo"]), m.nq, m.nv
        self._call = fun
        self._fixed = (m._address, data._address, ctypes.addressof(self._setup))
        self._setpoint_at = (None, 0)  # `run`'s last setpoint and its address (kept alive)

    def run(self, chunk: int, snap: int, setpoint: np.ndarray, hold: np.ndarray | None):
        """One chunk of `chunk` steps; the snapshot taken before step ``snap`` (if in it).

        Args:
            chunk: Steps, 1 to `MAX_CHUNK`.
            snap: The step whose starting state is the snapshot; outside the chunk: none.
            setpoint: The valves' setpoints [m, rad] (a float array, one per servo): the
                next ones on return (in place).
            hold: The braked wheels' held angles [rad] (4,), or None.

        Returns:
            ``(snapshot, warned)``: ``((qpos, qvel, time), setpoint)`` of the snapshot (new
            arrays) or None; whether MuJoCo counted a warning of a diverged simulation.
        """
        if not 1 <= chunk <= MAX_CHUNK:
            raise SimulatorError(f"a compiled chunk has 1 to {MAX_CHUNK} steps, got {chunk}")
        taken = 0 <= snap < chunk
        buffer = np.empty(self._nq + self._nv + self._n_servo + 1) if taken else None
        kept = self._setpoint_at
        if setpoint is not kept[0]:  # the simulator's setpoint, checked once an array
            kept = self._setpoint_at = (setpoint, _read(setpoint))
        args = (*self._fixed, chunk, snap if taken else -1, kept[1],
                None if hold is None else _read(hold), None if buffer is None else address(buffer))
        code = self._call(*args)
        while -100 < code < 0:  # a hook's buffers are full: grow them, then step
            self._hooks[-1 - code].make_room(chunk)
            code = self._call(*args)
        if code < 0:
            raise SimulatorError(f"step hook {-100 - code} did not record a step")
        if not taken:
            return None, code == 1
        nq, nv = self._nq, self._nv
        return ((buffer[:nq], buffer[nq:nq + nv], float(buffer[-1])), buffer[nq + nv:-1]), \
            code == 1


def _read(a: np.ndarray) -> int:
    """The address of a float array the C reads or writes (contiguous float64, checked)."""
    if (type(a) is not np.ndarray or a.dtype != np.float64 or not a.flags.c_contiguous
            or not a.flags.writeable):
        raise SimulatorError(f"expected a contiguous float64 array, got {a!r}")
    return address(a)


def compiled_step(model, data, merge, valve: dict, listeners) -> CompiledStep | None:
    """`STEP_C` for MuJoCo's ``model``, ``data`` and the ``listeners``, or None (Python).

    None without a compiler, without the compiled contact merge, or when a listener has no
    step hook (``listener.step_hook()`` returning a `StepHook`).

    Args:
        model: MuJoCo's model.
        data: MuJoCo's data.
        merge: The simulator's `models.mujoco.ContactMerge`.
        valve: The valves' constants: ``servo_ctrl`` (first servo actuator), ``servo_dof``,
            ``servo_qpos``, ``lo``, ``hi`` (stroke range), ``band`` (anti-windup),
            ``wheel_qpos``, ``wheel_ctrl``, ``wheel_lo``, ``wheel_hi``, ``hold_gain``; and the
            simulator's ``rates`` and ``lead`` arrays, which the C reads at every call (the
            simulator writes them in place).
        listeners: The step listeners, in their order.
    """
    if not merge.compiled or len(valve["lo"]) > _MAX_SERVOS:
        return None
    hooks = []
    for listener in listeners:
        hook = getattr(listener, "step_hook", None)
        hook = hook() if callable(hook) else None
        if not isinstance(hook, StepHook):
            return None
        hooks.append(hook)
    fun = _library()
    return None if fun is None else CompiledStep(fun.step_chunk, model, data, merge, valve,
                                                 hooks)
