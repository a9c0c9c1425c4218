"""Named layout of the QP decision vector.

The decision vector of both the whole-body QP (one step) and the MPC (``n_steps`` steps) is::

    x = [qdd_0 (n_axes), ..., qdd_{n_steps-1} (n_axes),   axis accelerations [m/s^2, rad/s^2]
         s (1, if speed_scale),                          base-drive wheel-speed scale [-]
         eps (n_slack, if n_slack)]                      normal-force slacks [-], >= 0

Every task and constraint addresses x through these named slices, never through raw index
arithmetic of its own.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from wbc.errors import ConfigurationError

__all__ = ["VariableLayout"]


@dataclass(frozen=True)
class VariableLayout:
    """Layout of the decision vector.

    Attributes:
        n_axes: Controlled axes per step.
        n_steps: Number of acceleration steps (1 for the whole-body QP).
        speed_scale: Whether the wheel-speed scale ``s`` is a decision variable.
        n_slack: Number of normal-force slack variables (0: hard force constraint).
    """

    n_axes: int = 9
    n_steps: int = 1
    speed_scale: bool = False
    n_slack: int = 0

    def __post_init__(self):
        if self.n_axes < 1 or self.n_steps < 1 or self.n_slack < 0:
            raise ConfigurationError(f"invalid layout: {self}")

    @property
    def n(self) -> int:
        """Size of x."""
        return self.n_axes * self.n_steps + int(self.speed_scale) + self.n_slack

    @property
    def accelerations(self) -> slice:
        """All axis accelerations, step-major."""
        return slice(0, self.n_axes * self.n_steps)

    def step(self, k: int) -> slice:
        """Accelerations of step ``k``."""
        return slice(k * self.n_axes, (k + 1) * self.n_axes)

    @property
    def scale(self) -> int | None:
        """Index of the wheel-speed scale, or None."""
        return self.n_axes * self.n_steps if self.speed_scale else None

    @property
    def slack(self) -> slice | None:
        """Slice of the slack variables, or None."""
        if not self.n_slack:
            return None
        start = self.n_axes * self.n_steps + int(self.speed_scale)
        return slice(start, start + self.n_slack)

    def default_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """(lb, ub) before any constraint: free, except slacks >= 0."""
        lb = np.full(self.n, -np.inf)
        ub = np.full(self.n, np.inf)
        if self.n_slack:
            lb[self.slack] = 0.0
        return lb, ub
