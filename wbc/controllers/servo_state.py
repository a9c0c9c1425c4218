r"""The state the MPC predicts from: the servo setpoints it commands, not the raw strokes.

The nine axes are valve-controlled servos that follow rate commands: the setpoint moves at
the commanded rate and the cylinder follows it with a proportional force, so each stroke
sits ``F / k_p`` behind its setpoint and rings about it in the structure's modes. Measured
on the MuJoCo machine: the boom bounces at ~2.2 Hz (lift stroke +-0.3 mm, front-left wheel
+-3 kN) while driving on rough ground, and a prediction started from the measured stroke
and velocity feeds that bounce back into the commands (a sustained limit cycle with the
crane weights of the MPC); the suspension's strokes hardly move at all when its setpoints
twist the chassis against the wheels (`wbc.force_models.feedback`).

`ServoState` therefore gives the MPC, per axis,

.. math:: q = s + \mathrm{LPF}_T(q_{meas} - s), \qquad \dot q = r_{prev},

with ``s`` the setpoint (integrated commanded rates ``r``), the deflection low-pass filtered
over ``T`` (it keeps the static sag under load, which the tracking must make up, and drops
the vibration) and zero for the suspension (whose warp model is in setpoints). When the
servo's own setpoint (``state.servo_setpoint``, e.g. clipped at the stroke range or
dragged by the anti-windup of a saturated cylinder) differs from the integrated one by more
than a delay allowance, the servo's value is taken.
"""

from __future__ import annotations

import numpy as np

from models.coordinates import SUSPENSION  # SUSPENSION_AXES as a slice
from models.numeric import clip
from models.state import MachineState
from wbc.axes import N_AXES
from wbc.controllers.servo_state_c import ServoPass

__all__ = ["ServoState"]

_RESYNC = 2e-3  # [m or rad] setpoint mismatch that is not explained by a delay
_DELAY_ALLOWANCE = 5  # control periods of measurement delay the mismatch may come from
_any = np.logical_or.reduce  # `ndarray.any` of a 1-D array without its Python dispatch
_UNIT_STRIDE = (8,)  # a contiguous float64 vector's (no `flags` object to ask)


class ServoState:
    """Setpoints, commanded rates and filtered deflection of the nine axes.

    The three arrays are kept for the state's life and written in place (`observe`,
    `commanded`, `reset`); with ``times`` and a C compiler they are the buffers of the
    compiled `observe_free` (`wbc.controllers.servo_state_c`, the same bits).

    Args:
        dt: Control period [s].
        deflection_time_constant: T of the deflection filter [s].
        lower, upper: Setpoint range (the stroke and joint ranges), shapes (9,).
        times: The times [s] (m,) of `observe_free`'s free response
            (`CondensedPrediction.times`); None: numpy's `observe_free` only.
        compiled: Use the compiled pass where it can; False: numpy always.
        brake: ``(Lq, Lv, step_lengths, acceleration)``: the arrays of the prediction at
            ``times`` and the acceleration limits of `observe_brake`'s brake trajectory,
            made in the compiled pass's call (`wbc.controllers.servo_state_c`); None:
            numpy's.
    """

    def __init__(self, dt: float, deflection_time_constant: float, lower, upper,
                 times=None, compiled: bool = True, brake: tuple | None = None):
        self.dt = float(dt)
        self.time_constant = float(deflection_time_constant)
        # Loaded here, not in a tick; the state lives in its buffers then (before the
        # arrays: a deep copy maps them to the copied pass's buffers).
        self._c = (ServoPass.make(N_AXES, SUSPENSION, times, brake)
                   if compiled and times is not None else None)
        if self._c is None:
            self.lower, self.upper = np.array(lower, float), np.array(upper, float)
        else:  # the pass's buffers, as the state's arrays below
            self.lower, self.upper = self._c.lower, self._c.upper
            self.lower[:], self.upper[:] = lower, upper
        self._times = times  # the array `observe_free`'s prediction has (its times, kept)
        # the prediction's and the limits' arrays `observe_brake`'s pass was made with
        self._brake_of = brake if self._c is not None and self._c.braking else None
        if self._c is None:
            self._setpoint, self.deflection, self.rates = (np.zeros(N_AXES), np.zeros(N_AXES),
                                                           np.zeros(N_AXES))
        else:
            self._setpoint, self.deflection, self.rates = (self._c.setpoint, self._c.deflection,
                                                           self._c.rates)
        self.reset()

    def reset(self) -> None:
        """Forget everything (the next `observe` initializes from the state)."""
        self.setpoint: np.ndarray | None = None  # `_setpoint` once observed
        self.rates[:] = 0.0
        self.deflection[:] = 0.0
        self._last_time: float | None = None

    def _gain(self, state: MachineState) -> float:
        """The deflection filter's gain over the time since the last observe."""
        elapsed = (self.dt if self._last_time is None
                   else max(state.time - self._last_time, 0.0))
        self._last_time = state.time
        return elapsed / (self.time_constant + elapsed) if self.time_constant > 0 else 1.0

    def observe(self, state: MachineState) -> tuple[np.ndarray, np.ndarray]:
        """(q, qd) of the axes to predict from, shapes (9,) (see the module docstring)."""
        q_meas = state.q[:N_AXES]
        measured = state.servo_setpoint
        if measured is not None:
            measured = np.asarray(measured, float)[:N_AXES]
        if self.setpoint is None:  # the servos move as measured, nothing else is known
            self.setpoint = self._setpoint
            self.setpoint[:] = measured if measured is not None else q_meas
            np.subtract(q_meas, self.setpoint, out=self.deflection)
            self.rates[:] = state.qd[:N_AXES]
        elif measured is not None:
            allowance = _RESYNC + _DELAY_ALLOWANCE * self.dt * np.abs(self.rates)
            off = np.abs(measured - self.setpoint) > allowance
            if _any(off):  # seldom: the masked copy only then
                self.setpoint[off] = measured[off]
        a = self._gain(state)
        self.deflection += a * (q_meas - self.setpoint - self.deflection)
        self.deflection[SUSPENSION] = 0.0
        return self.setpoint + self.deflection, self.rates.copy()

    def observe_free(self, state: MachineState, prediction) -> tuple[np.ndarray, ...]:
        """`observe` and ``prediction.free_response`` of its (q, qd): (q, qd, qf, vf).

        In one compiled call (`wbc.controllers.servo_state_c`, the same bits) after the
        first observe when ``prediction.times`` is the constructor's ``times`` array (a
        prediction's times are not changed in place); else numpy's `observe` and
        `CondensedPrediction.free_response`.
        """
        c = self._c
        if (c is None or self.setpoint is not c.setpoint or self.deflection is not c.deflection
                or self.rates is not c.rates or prediction.times is not self._times):
            q, qd = self.observe(state)
            return (q, qd, *prediction.free_response(q, qd))
        measured = state.servo_setpoint
        if measured is not None:
            measured = np.asarray(measured, float)[:N_AXES]
        return c.observe(state.q[:N_AXES], measured, _RESYNC, _DELAY_ALLOWANCE * self.dt,
                         self._gain(state))

    def observe_brake(self, state: MachineState, prediction, acceleration
                      ) -> tuple[np.ndarray, ...]:
        """`observe_free`, then ``prediction.brake_trajectory`` of its (q, qd).

        Returns (q, qd, qf, vf, brake inputs, positions, velocities), the brake at the
        limits ``acceleration``. In one compiled call (the same bits) when the prediction's
        times, factors and step lengths and ``acceleration`` are the arrays of the
        constructor's ``times`` and ``brake`` (a prediction's and the limits' arrays are not
        changed in place); else `observe_free` and numpy's brake.
        """
        kept, c = self._brake_of, self._c
        if (kept is None or acceleration is not kept[3] or prediction.Lq is not kept[0]
                or prediction.Lv is not kept[1] or prediction.step_lengths is not kept[2]
                or prediction.times is not self._times or self.setpoint is not c.setpoint
                or self.deflection is not c.deflection or self.rates is not c.rates):
            q, qd, qf, vf = self.observe_free(state, prediction)
            return (q, qd, qf, vf,
                    *prediction.brake_trajectory(q, qd, acceleration, (qf, vf)))
        measured = state.servo_setpoint
        if measured is not None:
            measured = np.asarray(measured, float)[:N_AXES]
        return c.observe_brake(state.q[:N_AXES], measured, _RESYNC,
                               _DELAY_ALLOWANCE * self.dt, self._gain(state))

    def command(self, qdd: np.ndarray, dt: float, lower: np.ndarray,
                upper: np.ndarray) -> np.ndarray:
        """The rates ``clip(rates + qdd dt, lower, upper)`` commanded now, a new array (9,).

        ``qdd``: the accelerations (9,) over ``dt`` [s]; ``lower``, ``upper``: the velocity
        limits (9,). `commanded` of them follows. In one compiled call (the same bits)
        after the first observe, for float64 accelerations and read-only limits that own
        their data (the axis limits', not changed); else numpy's.
        """
        c = self._c
        rates = None
        if (c is not None and self.setpoint is c.setpoint and self.rates is c.rates
                and self.lower is c.lower and self.upper is c.upper
                and type(qdd) is np.ndarray and qdd.shape == (N_AXES,)
                and qdd.dtype == np.float64 and qdd.strides == _UNIT_STRIDE):
            rates = c.command(qdd, dt, lower, upper, self.dt)
        if rates is None:
            rates = clip(self.rates + qdd * dt, lower, upper)
            self.commanded(rates)
        return rates

    def commanded(self, rates: np.ndarray) -> None:
        """Advance the setpoints by the rates just commanded, over one period."""
        self.rates[:] = rates
        if self.setpoint is not None:
            clip(self.setpoint + self.dt * self.rates, self.lower, self.upper,
                 out=self.setpoint)
