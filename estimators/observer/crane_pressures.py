r"""The sliding crane cylinders' accelerations from their chamber pressures.

The crane's dynamics (`estimators.efforts`, at the estimated payload) give each cylinder's
force affine in the axes' accelerations, ``F = E u + e_0``; a sliding cylinder's pressures
report ``F`` plus its seals' friction against the motion. The sliding cylinders' ``u`` solve
their rows with every other axis at the encoders' estimate. Measured against MuJoCo's
accelerations: the slew's comes out at 0.015 m/s^2 RMS against the Kalman filter's 0.041;
the lift's and tilt's are no closer (0.06 against 0.045), but they make the closure's
inertial forces consistent with the measured cylinder forces, which is what the normal
forces need (closure error 2.45 -> 1.49 % on the rough run). A cylinder standing still keeps
the encoders' value (its seals hold an unknown force up to their rating).
"""

from __future__ import annotations

import numpy as np

from estimators.efforts import ActuatorEfforts
from estimators.observer._linalg import solve
from models.sensing import PRESSURE_CYLINDERS
from models.state import N_SERVO_AXES, MachineState

__all__ = ["SLIDING_SPEED", "CranePressures"]

SLIDING_SPEED = 4e-3  # [m/s] stroke speed above which a seal slides (the observer's estimate)
_CRANE_CYLINDERS = np.array([2, 3, 4])  # slew, lift, tilt: independent coordinates
_PRESS_CRANE = [PRESSURE_CYLINDERS.index(c) for c in ("slew", "lift", "tilt")]


class CranePressures:
    """The slew, lift and tilt accelerations from their pressures (module docstring).

    Args:
        efforts: The machine's `ActuatorEfforts` (its payload mass is set per call).
        seal: The seals' friction rating of each cylinder of `PRESSURE_CYLINDERS` [N], (5,).
    """

    def __init__(self, efforts: ActuatorEfforts, seal: np.ndarray):
        self.efforts = efforts
        self._seal = np.asarray(seal, float)
        self._patterns: dict[tuple, tuple] = {}

    def accelerations(self, state: MachineState, forces: np.ndarray,
                      mass: float) -> np.ndarray:
        """``state.qdd`` (13,), the sliding cylinders' from their forces ``forces`` [N] (5,).

        ``mass``: the payload [kg].
        """
        sliding = tuple(abs(v) > SLIDING_SPEED for v in state.qd[2:5].tolist())
        qdd = state.qdd.copy()
        if not any(sliding):
            return qdd
        self.efforts.payload_mass = mass
        e, e0 = self.efforts.affine(state)
        rows, press, seal, ix_known, ix_rows, known = self._pattern(sliding)
        speeds = state.qd[rows]
        rhs = (forces[press] - seal * np.sign(speeds) - e0[rows] - e[ix_known] @ qdd[known])
        u = solve(e[ix_rows], rhs)  # NaN if singular (it is not: a block of a mass matrix)
        if np.isfinite(u).all():
            qdd[rows] = u
        return qdd

    def _pattern(self, sliding: tuple) -> tuple:
        """The index arrays of `accelerations` for one pattern of sliding cylinders.

        (rows, their pressure channels, seal ratings, the known and the free blocks' index
        tuples, the known axes); made once per pattern (eight at most).
        """
        hit = self._patterns.get(sliding)
        if hit is None:
            mask = np.array(sliding)
            rows = _CRANE_CYLINDERS[mask]
            free = np.zeros(N_SERVO_AXES, bool)
            free[rows] = True
            known = np.flatnonzero(~free)
            hit = self._patterns[sliding] = (
                rows, np.array(_PRESS_CRANE)[mask], self._seal[_PRESS_CRANE][mask],
                np.ix_(rows, known), np.ix_(rows, rows), known)
        return hit
