"""What the MPC's tasks and constraints see at one control tick."""

from __future__ import annotations

from dataclasses import MISSING, dataclass, fields

import numpy as np

from wbc.context import ControlContext, ReferenceSample
from wbc.force_models.feedback import ForceFeedback
from wbc.mpc.prediction import CondensedPrediction

__all__ = ["HorizonContext"]


class _kept:  # noqa: N801 (a decorator, named as `property` is)
    """A read-only attribute made on first access and kept in the instance's ``__dict__``.

    `functools.cached_property` without its lock (Python 3.11 takes one on every first
    access): a non-data descriptor, so the kept value is then an ordinary attribute.
    """

    def __init__(self, fget):
        self.fget, self.__doc__ = fget, fget.__doc__

    def __set_name__(self, owner, name: str) -> None:
        self.name = name

    def __get__(self, obj, owner=None):
        if obj is None:
            return self
        value = obj.__dict__[self.name] = self.fget(obj)
        return value


@dataclass(frozen=True)
class HorizonContext(ControlContext):
    """Inputs of one MPC QP (decision variables: ``layout`` with ``n_steps = N``).

    Attributes:
        prediction: Condensed double-integrator prediction.
        reference: Reference at the node times ``0, t_1, ..., t_N``: arrays (N + 1, 9).
        nominal_inputs: The previous plan shifted to now, (N, 9): where the force model is
            linearized (real-time iteration).
        previous_acceleration: The acceleration commanded at the previous tick, (9,).
        speed_scale: The wheel-speed scale commanded at the previous tick.
        free_positions, free_velocities: Zero-input prediction, (N, 9).
        brake_inputs, brake_positions, brake_velocities: Brake-and-hold prediction, (N, 9).
        feedback: The load split measured now (`wbc.force_models.feedback.ForceFeedback`);
            None: the force model alone.
        warp: ``df/dq`` of the chassis warp over the nine axes [N/m or N/rad], (4, 9); None:
            not modelled.
        leveling_offset: Warp change wanted along the diagonal [N]
            (`wbc.force_models.feedback.leveling_offset`).
        warp_drift: Terrain warp predicted along the diagonal at the step start times and
            at the horizon [N], (N + 1,), at the previous speed scale
            (`wbc.force_models.feedback.WarpDrift`); None: none.
    """

    prediction: CondensedPrediction
    reference: ReferenceSample
    nominal_inputs: np.ndarray
    previous_acceleration: np.ndarray
    speed_scale: float
    free_positions: np.ndarray
    free_velocities: np.ndarray
    brake_inputs: np.ndarray
    brake_positions: np.ndarray
    brake_velocities: np.ndarray
    feedback: ForceFeedback | None = None
    warp: np.ndarray | None = None
    leveling_offset: float = 0.0
    warp_drift: np.ndarray | None = None

    @classmethod
    def assemble(cls, *values, **optional) -> HorizonContext:
        """``HorizonContext(*values, **optional)`` without the dataclass's per-field setattr.

        The fields are set as the frozen dataclass's ``__init__`` sets them (it has no
        ``__post_init__``), each with ``object.__setattr__``: 20 of them every tick. The
        instance's dictionary is a copy of one made with every field (the defaults in
        place), then the values written: no resizing while it fills.

        Raises:
            TypeError: Not every field without a default given, or an unknown one.
        """
        if len(values) != len(_REQUIRED) or not optional.keys() <= _OPTIONAL.keys():
            raise TypeError(f"HorizonContext takes {len(_REQUIRED)} positional fields and "
                            f"optional {sorted(_OPTIONAL)}; got {len(values)} and "
                            f"{sorted(optional)}")
        ctx = object.__new__(cls)
        d = _TEMPLATE.copy()
        d.update(zip(_REQUIRED, values))
        d.update(optional)
        object.__setattr__(ctx, "__dict__", d)
        return ctx

    @_kept
    def structure_key(self) -> tuple:
        """What constant Jacobians depend on: layout, step lengths and period.

        Made once per context and kept as its attribute (a dozen tasks and constraints ask
        each tick: an attribute's lookup, no property call).
        """
        return (self.prediction.structure_key, self.dt)

    @property
    def n_steps(self) -> int:
        """Number of steps N."""
        return self.layout.n_steps


_REQUIRED = tuple(f.name for f in fields(HorizonContext) if f.default is MISSING)
_OPTIONAL = {f.name: f.default for f in fields(HorizonContext) if f.default is not MISSING}
_TEMPLATE = {**dict.fromkeys(_REQUIRED), **_OPTIONAL}  # `assemble`'s fields, in their order
