"""What a controller step returns: actuator rate commands and a wheel-speed scale."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from models.records import trusted
from wbc.axes import CRANE_AXES, SUSPENSION_AXES

__all__ = ["ControlCommand"]


@dataclass(frozen=True)
class ControlCommand:
    """Commands for the velocity-servoed actuators.

    Attributes:
        rates: Rate commands of the nine axes, ``clip(qd + qdd dt, v_lo, v_hi)``, order of
            `wbc.axes` [m/s for strokes and telescope, rad/s for the wrist], shape (9,).
        wheel_speed_scale: Scale of the operator's wheel-speed commands, in [0, 1].
        accelerations: The accelerations behind ``rates`` [m/s^2, rad/s^2], shape (9,).
        fallback: True when the solve failed and the safe action was taken.
        info: Diagnostics: solver status, iterations, timings [s], predicted forces [N],
            slacks, fallback reason.
    """

    rates: np.ndarray
    wheel_speed_scale: float
    accelerations: np.ndarray
    fallback: bool = False
    info: dict = field(default_factory=dict)

    @classmethod
    def of(cls, rates: np.ndarray, wheel_speed_scale: float, accelerations: np.ndarray,
           fallback: bool, info: dict) -> ControlCommand:
        """``ControlCommand(...)`` of every field, without the frozen dataclass's setattr.

        The fields set as its ``__init__`` sets them (it has no ``__post_init__``): one a
        tick.
        """
        return trusted(cls, rates=rates, wheel_speed_scale=wheel_speed_scale,
                       accelerations=accelerations, fallback=fallback, info=info)

    @property
    def suspension_rates(self) -> np.ndarray:
        """Stroke rates of the bogie cylinders L, R [m/s], shape (2,)."""
        return self.rates[SUSPENSION_AXES]

    @property
    def crane_rates(self) -> np.ndarray:
        """Crane rates, shape (7,).

        Slew, lift, tilt stroke rates and telescope rate [m/s]; wrist pitch, roll and rotator
        rates [rad/s].
        """
        return self.rates[CRANE_AXES]

    @property
    def cylinder_rates(self) -> np.ndarray:
        """Stroke rates of the six cylinders [m/s], shape (6,).

        Order bogie_L, bogie_R, slew, lift, tilt, telescope (the simulator's).
        """
        return self.rates[:6]

    @property
    def wrist_rates(self) -> np.ndarray:
        """Wrist pitch, roll and rotator rates [rad/s], shape (3,)."""
        return self.rates[6:9]

    def wheel_speeds(self, left: float, right: float) -> np.ndarray:
        """The operator's side wheel speeds [rad/s] scaled by `wheel_speed_scale`, (2,)."""
        return self.wheel_speed_scale * np.array([left, right], dtype=float)

    def rates_by_name(self, names: tuple[str, ...]) -> dict[str, float]:
        """Rates keyed by the axis names (`AxisLimits.names`)."""
        return {n: float(r) for n, r in zip(names, self.rates)}
