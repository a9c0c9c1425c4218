"""Measurement noise of the simulated sensors."""

from __future__ import annotations

import math
from dataclasses import dataclass

from scenarios.errors import SimulatorError

__all__ = ["DEFAULT_NOISE", "MeasurementNoise"]


@dataclass(frozen=True)
class MeasurementNoise:
    """Zero-mean Gaussian noise added to the measured `MachineState` (not the ground truth).

    Attributes:
        base_twist: Std of each twist component [m/s, rad/s].
        base_acceleration: Std of each acceleration component [m/s^2, rad/s^2].
        q: Std of each independent coordinate [m or rad].
        qd: Std of each independent velocity [m/s or rad/s].
        qdd: Std of each independent acceleration [m/s^2 or rad/s^2].
        contact_force: Std of each wheel force component in `MachineState.contacts` [N].
        suspension_force: Std of each suspension cylinder force [N].
        seed: Seed of the noise generator.
    """

    base_twist: float = 0.0
    base_acceleration: float = 0.0
    q: float = 0.0
    qd: float = 0.0
    qdd: float = 0.0
    contact_force: float = 0.0
    suspension_force: float = 0.0
    seed: int = 0

    def __post_init__(self):
        for name in ("base_twist", "base_acceleration", "q", "qd", "qdd", "contact_force",
                     "suspension_force"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise SimulatorError(f"noise '{name}' must be a finite std >= 0, got {v!r}")
        if isinstance(self.seed, bool) or not isinstance(self.seed, int) or self.seed < 0:
            raise SimulatorError(f"noise seed must be a non-negative integer, got {self.seed!r}")


# The command line's ``--noise default``: encoder-grade coordinates and rates, and the
# suspension cylinders' pressure-derived forces (the closed-loop tests run the MPC with it).
DEFAULT_NOISE = MeasurementNoise(q=1e-4, qd=1e-3, suspension_force=100.0)
