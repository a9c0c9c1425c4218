"""What tasks and constraints see at one control tick: the shared part and the whole-body QP's.

`ControlContext` holds what the whole-body QP (`QPContext`) and the MPC
(`wbc.mpc.context.HorizonContext`) share; each adds its own fields.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from models.state import MachineState
from wbc.axes import N_AXES, AxisLimits
from wbc.layout import VariableLayout

__all__ = ["ControlContext", "QPContext", "ReferenceSample"]


@dataclass(frozen=True)
class ReferenceSample:
    """Reference of the nine axes at one or more times.

    Attributes:
        position: [m or rad], shape (9,) or (N, 9).
        velocity: [m/s or rad/s], same shape.
        acceleration: [m/s^2 or rad/s^2], same shape.
    """

    position: np.ndarray
    velocity: np.ndarray
    acceleration: np.ndarray


@dataclass(frozen=True)
class ControlContext:
    """What every QP of the controller sees at one tick.

    Attributes:
        state: The measured machine state.
        q: Positions of the nine axes [m or rad], shape (9,) (``state.q[:9]``, or the
            servos' filtered view of them).
        qd: Their velocities [m/s or rad/s], shape (9,).
        dt: Control period [s]: how long the first accelerations act before the next solve.
        layout: Decision vector layout.
        limits: Axis limits.
    """

    state: MachineState
    q: np.ndarray
    qd: np.ndarray
    dt: float
    layout: VariableLayout
    limits: AxisLimits

    @functools.cached_property
    def brake(self) -> np.ndarray:
        """``limits.brake_acceleration(qd, dt)`` (9,), once per context (read-only)."""
        a = self.limits.brake_acceleration(self.qd, self.dt)
        a.setflags(write=False)
        return a

    @property
    def structure_key(self) -> tuple:
        """What constant Jacobians depend on: layout and period."""
        return (self.layout, self.dt)


@dataclass(frozen=True)
class QPContext(ControlContext):
    """Inputs of one whole-body QP (decision variables: ``layout`` with ``n_steps = 1``).

    Attributes:
        reference: Reference at the current time, shapes (9,), or None (no task reference).
        speed_scale: Wheel-speed scale commanded at the previous tick [-].
    """

    reference: ReferenceSample | None = None
    speed_scale: float = 1.0

    @classmethod
    def from_state(cls, state: MachineState, dt: float, layout: VariableLayout,
                   limits: AxisLimits, reference: ReferenceSample | None = None,
                   speed_scale: float = 1.0) -> QPContext:
        """Context whose axis positions and velocities are read off ``state``."""
        return cls(state, state.q[:N_AXES].copy(), state.qd[:N_AXES].copy(), dt, layout,
                   limits, reference, speed_scale)
