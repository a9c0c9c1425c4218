"""What tasks and constraints see at one control tick: the shared part and the whole-body QP's.

`ControlContext` holds what the whole-body QP (`QPContext`) and the MPC
(`wbc.mpc.context.HorizonContext`) share; each adds its own fields.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from models.records import trusted
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

    @classmethod
    def of(cls, position: np.ndarray, velocity: np.ndarray,
           acceleration: np.ndarray) -> ReferenceSample:
        """``ReferenceSample(...)`` without the frozen dataclass's per-field setattr.

        The fields set as its ``__init__`` sets them (it has no ``__post_init__``): the
        MPC samples its horizon every tick.
        """
        return trusted(cls, position=position, velocity=velocity, acceleration=acceleration)


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

    @property
    def brake(self) -> np.ndarray:
        """``limits.brake_acceleration(qd, dt)`` (9,), once per context (read-only).

        Kept in the instance's ``__dict__`` as `functools.cached_property` would, without
        its lock (Python 3.11 takes one on every first access; a context is one tick's).
        """
        a = self.__dict__.get("_brake")
        if a is None:
            a = self.limits.brake_acceleration(self.qd, self.dt)
            a.setflags(write=False)
            self.__dict__["_brake"] = a
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
        """Context whose axis positions and velocities are read off ``state``.

        ``q`` and ``qd`` are views of the state's read-only arrays (a `MachineState` is
        immutable). The fields are set as the dataclass's ``__init__`` sets them, without
        its per-field ``object.__setattr__`` (this runs every tick; `QPContext` has no
        ``__post_init__`` to skip).
        """
        ctx = object.__new__(cls)
        fields = ctx.__dict__
        fields["state"] = state
        fields["q"] = state.q[:N_AXES]
        fields["qd"] = state.qd[:N_AXES]
        fields["dt"] = dt
        fields["layout"] = layout
        fields["limits"] = limits
        fields["reference"] = reference
        fields["speed_scale"] = speed_scale
        return ctx
