"""What the whole-body QP's tasks and constraints see at one control tick."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from models.state import MachineState
from wbc.axes import N_AXES, AxisLimits
from wbc.layout import VariableLayout

__all__ = ["QPContext", "ReferenceSample"]


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
class QPContext:
    """Inputs of one whole-body QP (decision variables: ``layout`` with ``n_steps = 1``).

    Attributes:
        state: The measured machine state.
        q: Positions of the nine axes [m or rad], shape (9,) (``state.q[:9]``).
        qd: Their velocities, shape (9,).
        dt: Control period [s]: the time over which the accelerations act.
        layout: Decision vector layout.
        limits: Axis limits.
        reference: Reference at the current time, shapes (9,), or None (no task reference).
        speed_scale: Wheel-speed scale commanded at the previous tick [-].
    """

    state: MachineState
    q: np.ndarray
    qd: np.ndarray
    dt: float
    layout: VariableLayout
    limits: AxisLimits
    reference: ReferenceSample | None = None
    speed_scale: float = 1.0

    @property
    def structure_key(self) -> tuple:
        """What constant Jacobians depend on: layout and period."""
        return (self.layout, self.dt)

    @classmethod
    def from_state(cls, state: MachineState, dt: float, layout: VariableLayout,
                   limits: AxisLimits, reference: ReferenceSample | None = None,
                   speed_scale: float = 1.0) -> QPContext:
        """Context whose axis positions and velocities are read off ``state``."""
        return cls(state, state.q[:N_AXES].copy(), state.qd[:N_AXES].copy(), dt, layout,
                   limits, reference, speed_scale)
