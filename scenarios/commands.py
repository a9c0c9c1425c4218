"""Actuator commands of the simulated machine: servo rates and wheel speeds."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from models.records import trusted
from scenarios.errors import CommandError

__all__ = ["ActuatorCommand", "rates_by_name"]


def _vector(name: str, value, n: int, finite: bool = True) -> np.ndarray:
    try:
        a = np.array(value, dtype=float)  # a copy: the caller may reuse its buffer
    except (TypeError, ValueError) as exc:
        raise CommandError(f"{name} must be numbers, got {value!r}") from exc
    if a.shape != (n,):
        raise CommandError(f"{name} must have shape ({n},), got {a.shape}")
    if finite and not np.isfinite(a).all():
        raise CommandError(f"{name} has non-finite entries: {a}")
    return a


_all = np.logical_and.reduce  # `ndarray.all` of a 1-D array without its Python dispatch
_FIELDS = (("cylinder_rates", 6), ("wrist_rates", 3), ("wheel_speeds", 2))


def rates_by_name(name: str, value, names: tuple[str, ...]):
    """Rates from None (zeros), a mapping by name, or a sequence in ``names`` order.

    Sequences pass through unchecked: `ActuatorCommand` checks them.

    Args:
        name: What the rates are, for error messages.
        value: None, a mapping name -> rate (missing names are zero), or a sequence.
        names: The valid names, in order.

    Returns:
        The rates in ``names`` order (a sequence as given, else of length ``len(names)``).

    Raises:
        CommandError: The mapping has a name not in ``names``.
    """
    if value is None:
        return np.zeros(len(names))
    if isinstance(value, Mapping):
        unknown = set(value) - set(names)
        if unknown:
            raise CommandError(f"{name}: unknown names {sorted(unknown)}; valid: {list(names)}")
        return [value.get(n, 0.0) for n in names]
    return value


@dataclass(frozen=True)
class ActuatorCommand:
    """One command for every actuator; rates beyond the actuator limits are clipped.

    Attributes:
        cylinder_rates: Stroke rates of the hydraulic cylinders [m/s], shape (6,), order
            bogie_L, bogie_R, slew, lift, tilt, telescope (the first six independent
            coordinates). Positive extends.
        wrist_rates: Joint rates [rad/s], shape (3,), order wrist_pitch, wrist_roll, rotator.
        wheel_speeds: Wheel spin speeds [rad/s], shape (2,): (left pair FL+RL, right pair
            FR+RR). Positive drives forward (+x of fb).
    """

    cylinder_rates: np.ndarray
    wrist_rates: np.ndarray
    wheel_speeds: np.ndarray

    def __post_init__(self):
        arrays = [_vector(name, getattr(self, name), n, finite=False) for name, n in _FIELDS]
        every = np.concatenate(arrays)  # one finiteness test for all (a control tick's)
        if not np.isfinite(every).all():
            for (name, n), a in zip(_FIELDS, arrays):
                _vector(name, a, n)  # names the first field with a non-finite entry
        for (name, _), a in zip(_FIELDS, arrays):
            a.setflags(write=False)
            object.__setattr__(self, name, a)
        servo = every[:9]
        servo.setflags(write=False)
        object.__setattr__(self, "_servo_rates", servo)

    @classmethod
    def of_servo_rates(cls, servo_rates: np.ndarray, wheel_speeds: np.ndarray
                       ) -> ActuatorCommand:
        """``ActuatorCommand(servo_rates[:6], servo_rates[6:9], wheel_speeds)``, one copy.

        The closed loop's command every tick: the controller's nine rates (9,) and the two
        wheel speeds (2,), float arrays, copied into one read-only array whose views are
        the fields (the same values as the constructor's three copies, ~5 us less). Anything
        else, or a non-finite entry, goes through the constructor (its checks and errors).
        """
        every = np.concatenate((servo_rates, wheel_speeds))
        if every.shape != (11,) or every.dtype != np.float64 or not _all(np.isfinite(every)):
            return cls(servo_rates[:6], servo_rates[6:9], wheel_speeds)
        every.setflags(write=False)  # its views below are read-only too
        return trusted(cls, cylinder_rates=every[:6], wrist_rates=every[6:9],
                       wheel_speeds=every[9:], _servo_rates=every[:9])

    @classmethod
    def zero(cls) -> ActuatorCommand:
        """Hold every servo and brake the wheels."""
        return cls(np.zeros(6), np.zeros(3), np.zeros(2))

    @property
    def servo_rates(self) -> np.ndarray:
        """Rates of the nine servos in independent order [m/s, rad/s], shape (9,) (read-only)."""
        return self._servo_rates
