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

__all__ = ["ServoState"]

_RESYNC = 2e-3  # [m or rad] setpoint mismatch that is not explained by a delay
_DELAY_ALLOWANCE = 5  # control periods of measurement delay the mismatch may come from
_any = np.logical_or.reduce  # `ndarray.any` of a 1-D array without its Python dispatch


class ServoState:
    """Setpoints, commanded rates and filtered deflection of the nine axes.

    Args:
        dt: Control period [s].
        deflection_time_constant: T of the deflection filter [s].
        lower, upper: Setpoint range (the stroke and joint ranges), shapes (9,).
    """

    def __init__(self, dt: float, deflection_time_constant: float, lower, upper):
        self.dt = float(dt)
        self.time_constant = float(deflection_time_constant)
        self.lower = np.asarray(lower, float)
        self.upper = np.asarray(upper, float)
        self.reset()

    def reset(self) -> None:
        """Forget everything (the next `observe` initializes from the state)."""
        self.setpoint: np.ndarray | None = None
        self.rates = np.zeros(N_AXES)
        self.deflection = np.zeros(N_AXES)
        self._last_time: float | None = None

    def observe(self, state: MachineState) -> tuple[np.ndarray, np.ndarray]:
        """(q, qd) of the axes to predict from, shapes (9,) (see the module docstring)."""
        q_meas = state.q[:N_AXES]
        measured = state.servo_setpoint
        if measured is not None:
            measured = np.asarray(measured, float)[:N_AXES]
        if self.setpoint is None:  # the servos move as measured, nothing else is known
            self.setpoint = (measured.copy() if measured is not None else q_meas.copy())
            self.deflection = q_meas - self.setpoint
            self.rates = state.qd[:N_AXES].copy()
        elif measured is not None:
            allowance = _RESYNC + _DELAY_ALLOWANCE * self.dt * np.abs(self.rates)
            off = np.abs(measured - self.setpoint) > allowance
            if _any(off):  # seldom: the masked copy only then
                self.setpoint[off] = measured[off]
        elapsed = (self.dt if self._last_time is None
                   else max(state.time - self._last_time, 0.0))
        self._last_time = state.time
        a = elapsed / (self.time_constant + elapsed) if self.time_constant > 0 else 1.0
        self.deflection += a * (q_meas - self.setpoint - self.deflection)
        self.deflection[SUSPENSION] = 0.0
        return self.setpoint + self.deflection, self.rates.copy()

    def commanded(self, rates: np.ndarray) -> None:
        """Advance the setpoints by the rates just commanded, over one period."""
        self.rates = np.asarray(rates, float).copy()
        if self.setpoint is not None:
            self.setpoint = clip(self.setpoint + self.dt * self.rates, self.lower,
                                 self.upper)
