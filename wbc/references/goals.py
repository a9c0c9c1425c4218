"""Goals an operator or a scenario gives the controller."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from wbc.errors import WbcInputError

__all__ = ["JointGoal", "TcpGoal"]


def _vec(name: str, value, n: int) -> np.ndarray | None:
    if value is None:
        return None
    try:
        if np.iscomplexobj(value):
            raise TypeError("complex values")
        a = np.array(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise WbcInputError(f"{name} must be numeric: {exc}") from exc
    if a.shape != (n,) or not np.all(np.isfinite(a)):
        raise WbcInputError(f"{name} must be finite with shape ({n},), got {value}")
    a.setflags(write=False)
    return a


@dataclass(frozen=True)
class JointGoal:
    """Goal in independent coordinates.

    Attributes:
        crane: [x_slew, x_lift, x_tilt, telescope (m), wrist_pitch, wrist_roll, rotator
            (rad)], shape (7,), or None (keep the crane's current goal).
        suspension: [x_bogie_L, x_bogie_R] strokes [m], shape (2,), or None.
    """

    crane: np.ndarray | None = None
    suspension: np.ndarray | None = None

    def __post_init__(self):
        object.__setattr__(self, "crane", _vec("crane goal", self.crane, 7))
        object.__setattr__(self, "suspension", _vec("suspension goal", self.suspension, 2))


@dataclass(frozen=True)
class TcpGoal:
    """Tool-point position goal in the chassis frame fb.

    The controller turns it into crane joint goals with `solve_tcp_ik` from the measured
    configuration, then follows a Ruckig reference to them.

    Attributes:
        position_in_fb: [m], shape (3,).
        suspension: Optional suspension goal [m], shape (2,).
    """

    position_in_fb: np.ndarray
    suspension: np.ndarray | None = None

    def __post_init__(self):
        object.__setattr__(self, "position_in_fb", _vec("TCP position", self.position_in_fb, 3))
        object.__setattr__(self, "suspension", _vec("suspension goal", self.suspension, 2))
