"""How the base-drive wheel-speed scale changes the base and wheel accelerations.

The carrier's hydrostatic drive tracks ``s * nominal`` wheel speeds with a first-order lag of
time constant ``tau``. With the drive settled at the previous scale ``s_prev`` (so the measured
speeds are ``s_prev * nominal``), a new scale ``s`` gives the accelerations::

    a_base_lin = (s - s_prev) / s_prev * v_base / tau * exp(-t / tau)      (fb axes)
    qdd_wheel  = (s - s_prev) / s_prev * qd_wheel / tau * exp(-t / tau)

(angular base acceleration and vertical motion are not modelled: the base's terrain-induced
motion is predicted at constant twist). Both are linear in ``s``; this module gives the
direction ``da/ds`` in the generalized acceleration ``a = [base (6), qdd (13)]``.
"""

from __future__ import annotations

import numpy as np

from estimators.linearization import N_GENERALIZED
from models.coordinates import WHEELS
from models.state import MachineState

__all__ = ["speed_scale_direction", "speed_scale_factor"]

_MIN_SCALE = 0.05  # below this the nominal speed cannot be inferred from the measured one


def speed_scale_factor(speed_scale: float, tau: float) -> float:
    """``k = 1 / (tau max(s, s_min))`` [1/s], `speed_scale_direction`'s factor of the speeds."""
    return 1.0 / (tau * max(speed_scale, _MIN_SCALE))


def speed_scale_direction(state: MachineState, speed_scale: float, tau: float) -> np.ndarray:
    """``da/ds`` at t = 0 [m/s^2 per unit scale], shape (19,); multiply by ``exp(-t/tau)``."""
    d = np.zeros(N_GENERALIZED)
    k = speed_scale_factor(speed_scale, tau)
    d[0:2] = k * state.base_twist[0:2]  # horizontal base velocity only
    d[6 + WHEELS.start:6 + WHEELS.stop] = k * state.qd[WHEELS]
    return d
