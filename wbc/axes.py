"""The controllable coordinates and their limits, read from the machine description.

The controller acts on the first nine independent coordinates of `models.coordinates`
(``N_AXES = 9``, the first nine rows of the coordinate table), in this order::

    [x_bogie_L, x_bogie_R,                  suspension cylinder strokes [m]
     x_slew, x_lift, x_tilt, telescope,     crane cylinder strokes and telescope [m]
     wrist_pitch, wrist_roll, rotator]      wrist joint angles [rad]

The four wheel angles are not controlled here (the carrier drive only gets a speed scale).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from models.coordinates import CRANE, SUSPENSION
from models.description import Machine
from models.numeric import clip
from wbc.errors import ConfigurationError

__all__ = ["CRANE_AXES", "N_AXES", "SUSPENSION_AXES", "AxisLimits", "axis_index"]

N_AXES = 9
SUSPENSION_AXES = np.arange(SUSPENSION.start, SUSPENSION.stop)  # (0, 1)
CRANE_AXES = np.arange(CRANE.start, CRANE.stop)  # (2, ..., 8)


def axis_index(axes: np.ndarray) -> slice | np.ndarray:
    """``axes`` (indices, (n,), n >= 1) as a slice where they are contiguous, else unchanged.

    Basic indexing by the slice is cheaper than by the index array and reads the same entries.
    """
    first = int(axes[0])
    if np.array_equal(axes, np.arange(first, first + axes.size)):
        return slice(first, first + axes.size)
    return axes


def _frozen(name: str, x) -> np.ndarray:
    """``x`` as a read-only finite float array of shape (9,); `ConfigurationError` else."""
    try:
        a = np.array(x, dtype=float) if not np.iscomplexobj(x) else None
    except (TypeError, ValueError):
        a = None
    if a is None or a.shape != (N_AXES,) or not np.all(np.isfinite(a)):
        raise ConfigurationError(f"AxisLimits.{name} must be finite with shape ({N_AXES},), "
                                 f"got {x!r}")
    a.setflags(write=False)
    return a


@dataclass(frozen=True)
class AxisLimits:
    """Per-axis limits of the nine controllable coordinates, shapes (9,).

    Attributes:
        names: Coordinate names, order above.
        position_lower, position_upper: Usable position range [m or rad], the description's
            range shrunk by the margin.
        velocity_lower, velocity_upper: Rate limits [m/s or rad/s]; cylinders are asymmetric
            (retract Q/A_b, extend Q/A_a); direct drives are symmetric.
        acceleration: Symmetric acceleration limit [m/s^2 or rad/s^2].
    """

    names: tuple[str, ...]
    position_lower: np.ndarray
    position_upper: np.ndarray
    velocity_lower: np.ndarray
    velocity_upper: np.ndarray
    acceleration: np.ndarray

    def __post_init__(self):
        names = self.names
        if (not isinstance(names, (tuple, list)) or len(names) != N_AXES
                or not all(isinstance(n, str) for n in names)):
            raise ConfigurationError(f"AxisLimits.names must be {N_AXES} strings, got "
                                     f"{names!r}")
        object.__setattr__(self, "names", tuple(names))
        for f in ("position_lower", "position_upper", "velocity_lower", "velocity_upper",
                  "acceleration"):
            object.__setattr__(self, f, _frozen(f, getattr(self, f)))
        bad = ((self.position_lower >= self.position_upper) | (self.velocity_lower >= 0)
               | (self.velocity_upper <= 0) | (self.acceleration <= 0))
        if np.any(bad):
            i = int(np.argmax(bad))
            raise ConfigurationError(
                f"inconsistent limits for axis '{self.names[i]}': position "
                f"[{self.position_lower[i]}, {self.position_upper[i]}], velocity "
                f"[{self.velocity_lower[i]}, {self.velocity_upper[i]}], acceleration "
                f"{self.acceleration[i]} (need lower < upper, velocity_lower < 0 < "
                f"velocity_upper, acceleration > 0)")

    @classmethod
    def from_machine(cls, machine: Machine, position_margin: float = 0.01) -> AxisLimits:
        """Read the limits of the nine controllable coordinates from ``machine``.

        Positions from the coordinate table (`Machine.coordinates`: the chain's valid
        stroke range, or the joint range); cylinder chains give the cylinder's flow-limited
        speeds (`HydraulicCylinder.velocity_range`) and its ``max_acceleration``; direct
        drives give ``velocity_limit`` and ``acceleration_limit``.

        Args:
            machine: The machine description.
            position_margin: Fraction of each position range kept free at both ends, in
                [0, 0.25).
        """
        if (isinstance(position_margin, (bool, np.bool_))
                or not isinstance(position_margin, (int, float, np.integer, np.floating))
                or not 0.0 <= position_margin < 0.25):
            raise ConfigurationError(f"position_margin {position_margin} outside [0, 0.25)")
        coordinates = machine.coordinates
        table = coordinates.table[:N_AXES]
        plo, pup, vlo, vup, acc = [], [], [], [], []
        for c in table:
            if c.kind == "stroke":
                cylinder = coordinates.binding(c.index).cylinder
                v = cylinder.velocity_range
                a = cylinder.max_acceleration
            elif c.name in machine.direct_drives:
                d = machine.direct_drives[c.name]
                v = (-d.velocity_limit, d.velocity_limit)
                a = d.acceleration_limit
            else:
                raise ConfigurationError(f"coordinate '{c.name}' is neither a cylinder chain "
                                         f"nor a direct drive")
            lo, hi = c.lower, c.upper
            if not (np.isfinite(lo) and np.isfinite(hi)):
                raise ConfigurationError(f"axis '{c.name}' has no finite position range")
            m = position_margin * (hi - lo)
            plo.append(lo + m)
            pup.append(hi - m)
            vlo.append(v[0])
            vup.append(v[1])
            acc.append(a)
        return cls(tuple(c.name for c in table), np.array(plo), np.array(pup),
                   np.array(vlo), np.array(vup), np.array(acc))

    def brake_acceleration(self, velocity: np.ndarray, dt: float) -> np.ndarray:
        """Acceleration that brakes each axis to rest at the acceleration limit, shape (9,).

        ``-clip(velocity / dt, -a_max, a_max)``: full deceleration while the axis moves,
        exactly the acceleration that reaches zero velocity in the last step. Every limit
        constraint of this package admits it, so a QP built from them is never infeasible
        because of the limits alone.
        """
        return -clip(velocity / dt, -self.acceleration, self.acceleration)
