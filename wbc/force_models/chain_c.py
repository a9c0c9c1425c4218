"""The MPC's measured-load-split chain in one C call, on kept buffers.

Every control tick `wbc.controllers.mpc.MpcController.context` carries the split measured
by `ClosureFeedback` through five small steps: the warp's Smith predictor
(``f += W (s_now - s_state)``, `MpcController._compensated`), `leveling_offset`,
`WarpDrift.update` and ``drift``, `SpeedGovernor.update` and ``cap``, and the speed filter of
`SideLoadFluctuation` (its swing when it is off). In numpy and Python they are ~40 calls on
(4,) and (9,) arrays (~30 us a tick in the closed loop); here they are one call on buffers
kept by `FeedbackChain`, doing numpy's and Python's IEEE operations in their order
(compiled with ``-ffp-contract=off``, `models.cbuild`):

* the two products through the BLAS numpy's ``@`` calls (`estimators.observer.tail_c.
  numpy_blas`): ``W @ v`` of a C-ordered (4, 9) matrix is matmul's ``cblas_dgemv``
  (column-major, transposed: ``(102, 112, 9, 4, 1.0, W, 9, v, 1, 0.0, y, 1)``),
  ``DIAGONAL @ f`` of two vectors its ``DOUBLE_dot``: ``0.0 + cblas_ddot(4, ...)``;
* Python's ``min`` of two floats keeps the first unless the second is smaller, numpy's
  ``clip`` is ``min(max(x, lo), hi)`` with a NaN ``x`` passed, ``np.minimum`` keeps its
  first operand unless the second is smaller and the first is not NaN; the governor's cap
  takes numpy's smallest ratio (a NaN wins; a signed zero's sign is lost in the clip that
  follows), then its clip to [0, 1];
* the governor's own steps are `fluctuation_c.GOVERNOR_C`'s functions, on the governor's
  buffers (`fluctuation_c.GovernorPass`).

The parts' settings (time constants, limits, z) are read when the chain is made, with the
parts (`MpcController._set_feedback`). The filters' state is the parts' own: the caller
passes it in and writes it back (`MpcController._chained_feedback`).
`tests/test_feedback_chain_c.py` compares the call with the numpy path bit for bit on
closed-loop ticks. Without a compiler or without numpy's BLAS the numpy path runs.
"""

from __future__ import annotations

import ctypes

import numpy as np

from models.cbuild import address, bind, load_shared
from models.numpy_blas import numpy_blas
from wbc.axes import N_AXES, SUSPENSION_AXES
from wbc.force_models.feedback import DIAGONAL
from wbc.force_models.fluctuation import _MIN_SCALE
from wbc.force_models.fluctuation_c import GOVERNOR_C

__all__ = ["CHAIN_C", "IO", "POINTERS", "FeedbackChain"]

# The pointer table ``p`` of the call, in this order.
POINTERS = ("f", "contact", "measured", "setpoint", "warp", "thresholds", "starts",
            "forces", "drift", "diagonal", "gov_mean", "gov_square", "gov_out", "gov_state",
            "gov_per_speed", "ratios", "fn_gemv", "fn_ddot")
# The scalars' places in ``io``: the tick's inputs, the parts' state (in and out), the
# results, then the settings (set once).
IO = ("time", "difference", "twist_x", "twist_y", "speed_scale", "measured_on",
      "drift_on", "governor_on", "side_on",
      "gov_has_time", "gov_time", "gov_has_mean",
      "drift_has_last", "drift_last_time", "drift_last_value", "drift_rate",
      "side_has_time", "side_time", "side_speed",
      "compensated", "offset", "speed", "cap", "per_speed_changed",
      "leveling_limit", "stiffness", "drift_tc", "drift_horizon", "drift_limit",
      "gov_z", "gov_drive_tc", "gov_high_pass", "gov_window", "gov_min_speed", "min_scale",
      "side_window", "n_starts")

_DEFINES = "\n".join([f"#define P_{n} {i}" for i, n in enumerate(POINTERS)]
                     + [f"#define S_{n} {i}" for i, n in enumerate(IO)]
                     + [f"#define N_AXES {N_AXES}",
                        f"#define SUSP_L {SUSPENSION_AXES[0]}",
                        f"#define SUSP_R {SUSPENSION_AXES[1]}"])

CHAIN_C = GOVERNOR_C + r"""
@DEFINES@

typedef void (*gemv_fn)(int, int, long long, long long, double, const double*, long long,
                        const double*, long long, double, double*, long long);
typedef double (*ddot_fn)(long long, const double*, long long, const double*, long long);

#define D(name) ((double*)p[P_##name])

/* numpy's clip ufunc of a double: min(max(x, lo), hi), a NaN x passed */
static double np_clip(double x, double lo, double hi) {
  if (!isnan(x)) x = x > lo ? x : lo;
  if (!isnan(x)) x = x < hi ? x : hi;
  return x;
}

void feedback_chain(void* const* p, double* s) {
  const double *f = D(f), *thr = D(thresholds);
  const unsigned char* contact = (const unsigned char*)p[P_contact];
  double *forces = D(forces);
  double time = s[S_time];
  int i, all = contact[0] && contact[1] && contact[2] && contact[3];

  /* MpcController._compensated: f + W (s_now - s_state) on four wheels */
  s[S_compensated] = 0.0;
  if (s[S_measured_on] != 0.0 && all) {
    double v[N_AXES], shift[4];
    const double *now = D(setpoint), *then = D(measured);
    for (i = 0; i < N_AXES; ++i) v[i] = now[i] - then[i];
    ((gemv_fn)p[P_fn_gemv])(102, 112, N_AXES, 4, 1.0, D(warp), N_AXES, v, 1, 0.0, shift, 1);
    for (i = 0; i < 4; ++i) forces[i] = f[i] + shift[i];
    s[S_compensated] = 1.0;
  } else {
    for (i = 0; i < 4; ++i) forces[i] = f[i];
  }

  /* leveling_offset: margins of the wheels (0 N off the ground), Python's min of two */
  {
    double m[4], a, b;
    for (i = 0; i < 4; ++i) m[i] = (contact[i] ? forces[i] : 0.0) - thr[i];
    a = m[2] < m[1] ? m[2] : m[1];
    b = m[3] < m[0] ? m[3] : m[0];
    s[S_offset] = np_clip(0.5 * (a - b), -s[S_leveling_limit], s[S_leveling_limit]);
  }

  /* WarpDrift.update and drift */
  if (s[S_drift_on] != 0.0) {
    double rate = s[S_drift_rate], *drift = D(drift);
    const double* starts = D(starts);
    long k, n = (long)s[S_n_starts];
    if (!all) {
      rate = 0.0;
      s[S_drift_has_last] = 0.0;
    } else {
      double d = 0.0;
      d += ((ddot_fn)p[P_fn_ddot])(4, D(diagonal), 1, forces, 1);
      d = d / 4.0 - s[S_stiffness] * s[S_difference];
      if (s[S_drift_has_last] != 0.0 && time > s[S_drift_last_time]) {
        double dt = time - s[S_drift_last_time];
        double raw = (d - s[S_drift_last_value]) / dt;
        rate += dt / (s[S_drift_tc] + dt) * (raw - rate);
        rate = np_clip(rate, -s[S_drift_limit], s[S_drift_limit]);
      }
      s[S_drift_has_last] = 1.0;
      s[S_drift_last_time] = time;
      s[S_drift_last_value] = d;
    }
    s[S_drift_rate] = rate;
    for (k = 0; k < n; ++k) {
      double t = starts[k], h = s[S_drift_horizon];
      drift[k] = rate * ((t <= h || isnan(t)) ? t : h);  /* np.minimum */
    }
  }

  double speed = hypot(s[S_twist_x], s[S_twist_y]);
  s[S_speed] = speed;

  /* SpeedGovernor.update and cap (its compiled steps) */
  s[S_per_speed_changed] = 0.0;
  if (s[S_governor_on] != 0.0) {
    double dt = s[S_gov_has_time] != 0.0 ? time - s[S_gov_time] : 0.0;
    double *mean = D(gov_mean), *st = D(gov_state), *per_speed = D(gov_per_speed);
    s[S_gov_has_time] = 1.0;
    s[S_gov_time] = time;
    if (s[S_gov_has_mean] != 0.0) {
      if (governor_update(mean, D(gov_square), D(gov_out), st, forces, contact, dt, speed,
                          s[S_speed_scale], s[S_gov_drive_tc], s[S_gov_high_pass],
                          s[S_gov_window], s[S_gov_min_speed])) {
        s[S_per_speed_changed] = 1.0;
        per_speed = D(gov_out);
      }
    } else {
      if (dt > 0) st[0] += dt / (s[S_gov_drive_tc] + dt) * (s[S_speed_scale] - st[0]);
      int usable = all && isfinite(speed);
      for (i = 0; i < 4; ++i) usable = usable && isfinite(forces[i]);
      if (usable) {
        for (i = 0; i < 4; ++i) mean[i] = forces[i];
        s[S_gov_has_mean] = 1.0;
      }
    }
    double cap = 1.0;
    if (s[S_gov_has_mean] != 0.0) {
      double* ratios = D(ratios);
      int n = governor_ratios(mean, per_speed, thr, contact, st[0], speed, s[S_gov_z],
                              s[S_min_scale], ratios);
      if (n > 0) {
        double r = ratios[0];  /* numpy's minimum.reduce: a NaN wins */
        for (i = 1; i < n && !isnan(r); ++i) if (isnan(ratios[i]) || ratios[i] < r) r = ratios[i];
        cap = np_clip(r, 0.0, 1.0);
      }
    }
    s[S_cap] = cap;
  }

  /* SideLoadFluctuation.update without the swing: the speed filter */
  if (s[S_side_on] != 0.0) {
    double dt = s[S_side_has_time] != 0.0 ? time - s[S_side_time] : 0.0;
    s[S_side_has_time] = 1.0;
    s[S_side_time] = time;
    if (dt > 0 && isfinite(speed))
      s[S_side_speed] += dt / (s[S_side_window] + dt) * (speed - s[S_side_speed]);
  }
}
""".replace("@DEFINES@", _DEFINES)

_P = ctypes.c_void_p


def _library():
    return load_shared(CHAIN_C, "feedback_chain",
                       {"feedback_chain": ([_P, _P], None)}, "the feedback chain's numpy")


class FeedbackChain:
    """The chain's buffers and its call (made with the MPC's feedback parts).

    Attributes:
        io: The scalars (`IO`).
        f, contact, measured, setpoint, thresholds: A tick's inputs, copied in (the
            measured servo setpoints at their full length).
        forces: The compensated split [N] (4,); drift: ``WarpDrift.drift`` of the starts.
        starts: The node start times (`MpcPlanner.node_starts`), copied when they change.
    """

    def __init__(self, lib, blas: tuple[int, int, int], warp: np.ndarray, n_servo: int):
        self._lib, self._blas = lib, blas
        self.io = np.zeros(len(IO))
        self.io[IO.index("min_scale")] = _MIN_SCALE
        self.f, self.forces = np.zeros(4), np.zeros(4)
        self.contact = np.zeros(4, bool)
        self.measured, self.setpoint = np.zeros(n_servo), np.zeros(N_AXES)
        self.warp = np.array(warp, float, order="C")
        self.thresholds, self.per_speed, self.ratios = np.zeros(4), np.zeros(4), np.zeros(4)
        self.diagonal = DIAGONAL.copy()
        self.starts: np.ndarray | None = None  # the planner's array copied, its buffer
        self._starts_of: np.ndarray | None = None
        self.drift = np.zeros(0)
        self.governor_pass = None  # the `GovernorPass` whose buffers are in the table
        self._per_speed_of: np.ndarray | None = None  # the array `per_speed` holds
        self._table = np.zeros(len(POINTERS), np.uint64)
        for name in ("f", "contact", "measured", "setpoint", "warp", "thresholds", "forces",
                     "diagonal", "per_speed", "ratios"):
            key = "gov_per_speed" if name == "per_speed" else name
            self._table[POINTERS.index(key)] = address(getattr(self, name))
        self._table[POINTERS.index("fn_gemv")] = blas[0]
        self._table[POINTERS.index("fn_ddot")] = blas[1]
        self._call = bind(lib.feedback_chain, self._table, self.io)

    @classmethod
    def make(cls, warp: np.ndarray, n_servo: int) -> FeedbackChain | None:
        """A chain for the warp matrix ``warp`` (4, 9), or None without a compiler or BLAS."""
        blas = numpy_blas()
        lib = None if blas is None else _library()
        return None if lib is None else cls(lib, blas, warp, n_servo)

    def __deepcopy__(self, memo) -> FeedbackChain:
        """A chain of its own: its call bound to its own buffers (the parts bind anew)."""
        new = FeedbackChain(self._lib, self._blas, self.warp, self.measured.size)
        new.io[:] = self.io
        memo[id(self)] = new
        return new

    def set(self, **values: float) -> None:
        """Write scalars of `IO` by name (the settings, once)."""
        for name, value in values.items():
            self.io[IO.index(name)] = value

    def bind_starts(self, starts: np.ndarray) -> None:
        """Take the node start times (a read-only array kept by the planner)."""
        self._starts_of = starts
        self.starts = np.array(starts, float)
        self.drift = np.zeros(self.starts.size)
        self._table[POINTERS.index("starts")] = address(self.starts)
        self._table[POINTERS.index("drift")] = address(self.drift)
        self.io[IO.index("n_starts")] = self.starts.size

    def starts_are(self, starts: np.ndarray) -> bool:
        """Whether ``starts`` is the array bound last."""
        return starts is self._starts_of

    def bind_governor(self, governor_pass) -> None:
        """Point the table at a `fluctuation_c.GovernorPass`'s buffers."""
        self.governor_pass = governor_pass
        for name in ("mean", "square", "out", "state"):
            self._table[POINTERS.index("gov_" + name)] = address(getattr(governor_pass, name))

    def __call__(self) -> None:
        """One tick on the buffers and ``io`` as they are."""
        self._call()

    def run(self, measured, setpoint, measured_setpoint, difference: float, twist,
            speed_scale: float, thresholds: np.ndarray, starts: np.ndarray, drift, governor,
            side) -> tuple | None:
        """One tick of the chain with the parts' state; None: the numpy path must run it.

        Args:
            measured: The split `ClosureFeedback.measure` gave (`ForceFeedback`).
            setpoint: The servo setpoints now (9,), or None: no compensation.
            measured_setpoint: The servo setpoints at the state's time (9,), or None.
            difference: ``q_L - q_R`` of the suspension axes' prediction start [m].
            twist: The base twist (6,) (its horizontal speed).
            speed_scale: The scale commanded over the last period.
            thresholds: The force rows' thresholds [N] (4,).
            starts: `MpcPlanner.node_starts`.
            drift: The `WarpDrift`, or None.
            governor: The `SpeedGovernor`, or None.
            side: The `SideLoadFluctuation` whose speed filter runs here (its swing not
                measured), or None.

        Returns:
            (forces [N] (4,) a new array or None when not compensated, leveling offset [N],
            drift [N] (N + 1,) a new array or None, horizontal speed [m/s], cap or None).
        """
        gp = None
        if governor is not None:
            gp = governor._c
            per_speed = governor.per_speed
            if (gp is None or governor._square is not gp.square
                    or (governor.mean is not None and governor.mean is not gp.mean)):
                return None
            if gp is not self.governor_pass:
                self.bind_governor(gp)
            if per_speed is not self._per_speed_of:  # the governor replaces it, not writes
                if not _quad(per_speed):
                    return None
                np.copyto(self.per_speed, per_speed)
                self._per_speed_of = per_speed
        if drift is not None and starts is not self._starts_of:
            self.bind_starts(starts)
        on = setpoint is not None and measured_setpoint is not None
        if on:
            np.copyto(self.setpoint, setpoint)
            np.copyto(self.measured, measured_setpoint)
        np.copyto(self.f, measured.forces)
        np.copyto(self.contact, measured.in_contact)
        np.copyto(self.thresholds, thresholds)
        g_time = None if governor is None else governor._time
        last = None if drift is None else drift._last
        s_time = None if side is None else side._time
        self.io[:_N_STATE] = (
            measured.time, difference, twist[0], twist[1], speed_scale, on,
            drift is not None, governor is not None, side is not None,
            g_time is not None, g_time or 0.0, gp is not None and governor.mean is not None,
            last is not None, *(last or (0.0, 0.0)), 0.0 if drift is None else drift.rate,
            s_time is not None, s_time or 0.0, 0.0 if side is None else side.speed)
        self._call()
        s = self.io.tolist()
        time = measured.time
        cap = None
        if governor is not None:
            governor._time = time
            if governor.mean is None and s[_GOV_HAS_MEAN]:
                governor.mean = gp.mean
            if s[_CHANGED]:
                governor.per_speed = gp.out.copy()
            cap = s[_CAP]
        drift_now = None
        if drift is not None:
            drift.rate = s[_RATE]
            drift._last = (time, s[_LAST_VALUE]) if s[_HAS_LAST] else None
            drift_now = self.drift.copy()
        if side is not None:
            side._time = time
            side.speed = s[_SIDE_SPEED]
        return (self.forces.copy() if s[_COMPENSATED] else None, s[_OFFSET], drift_now,
                s[_SPEED], cap)


def _quad(a) -> bool:
    """``a`` is a (4,) float array (what the governor's buffers take)."""
    return type(a) is np.ndarray and a.shape == (4,) and a.dtype == float


_N_STATE = IO.index("compensated")
_GOV_HAS_MEAN, _CHANGED, _CAP = (IO.index(n) for n in ("gov_has_mean", "per_speed_changed",
                                                       "cap"))
_RATE, _HAS_LAST, _LAST_VALUE = (IO.index(n) for n in ("drift_rate", "drift_has_last",
                                                       "drift_last_value"))
_SIDE_SPEED, _COMPENSATED, _OFFSET, _SPEED = (IO.index(n) for n in (
    "side_speed", "compensated", "offset", "speed"))
