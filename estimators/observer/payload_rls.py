r"""The payload mass from the crane cylinders' pressures: recursive least squares, with events.

The lift and tilt cylinders' forces are affine in the payload mass at the measured motion,
``F = F_0(q, qd, qdd, base) + m Y(q, qd, qdd, base)`` (`estimators.efforts`, the same rigid-body
dynamics as the normal-force estimator). With the measured forces ``y`` (from the chamber
pressures) the mass is a recursive least-squares estimate with forgetting factor
``lambda = exp(-dt / T)`` (`FORGETTING_TIME`), the two cylinders weighted by their force noise.

Pick and release: a normalised innovation ``nu^2 / (Y^T P Y + R)`` above `EVENT_CHI2` on
`EVENT_TICKS` ticks in a row is a payload change; the covariance is reset so the estimate
moves to the new mass within a few ticks, and the event is reported (``pick`` when the mass
grew, else ``release``).

Its standard deviation: the RLS covariance and a floor for what averaging does not remove
(the transducers' zero offsets mapped through ``Y``).
"""

from __future__ import annotations

import numpy as np

__all__ = ["EVENT_CHI2", "EVENT_TICKS", "FORGETTING_TIME", "PayloadRLS"]

FORGETTING_TIME = 2.0  # [s]
EVENT_CHI2 = 25.0  # normalised innovation (5 sigma)
EVENT_TICKS = 5
_RESET_STD = 300.0  # [kg] after an event
_MIN_SENSITIVITY = 5.0  # [N/kg] below this the cylinders do not see the payload
_UNUSED_VARIANCE = 1e18  # [N^2] a cylinder inside its dead band this tick


class PayloadRLS:
    """Scalar RLS of the payload mass (module docstring).

    Args:
        initial_mass: Prior [kg].
        initial_std: Its std [kg].
        force_std: Std of each measured cylinder force per tick [N], (2,).
        bias_std: Std of each cylinder force's constant offset [N], (2,).
        event_variance_scale: Factor on the force variance in the event test (below 1 when
            the caller low-passes the regression: the per-tick noise is smaller then, while
            the ticks are correlated, so the estimate's own update keeps ``force_std``).
    """

    def __init__(self, initial_mass: float, initial_std: float, force_std, bias_std,
                 event_variance_scale: float = 1.0):
        self.event_variance_scale = float(event_variance_scale)
        self.mass = float(initial_mass)
        self.P = float(initial_std) ** 2
        self.R = np.asarray(force_std, float) ** 2
        self.bias_std = np.asarray(bias_std, float)
        self._run = 0
        self._last_y = np.zeros(2)
        self.event: str | None = None
        self.event_time: float | None = None

    def update(self, time: float, dt: float, measured: np.ndarray, f0: np.ndarray,
               y: np.ndarray, band: np.ndarray | None = None) -> None:
        """One tick: measured forces (2,), and ``F_0``, ``Y`` of the two cylinders (2,).

        ``band`` (2,) [N]: a dead band about each measured force (a standing cylinder's
        seals hold anything up to their rating, so an innovation inside it says nothing
        and one beyond it counts only by what lies beyond). A tick whose every cylinder
        lies inside its band is skipped, forgetting included: no information, no loss.
        """
        self.event = None
        self._last_y = y
        if np.abs(y).max() < _MIN_SENSITIVITY or not np.all(np.isfinite(measured)):
            return
        nu = measured - f0 - y * self.mass
        r = self.R.copy()
        if band is not None:
            inside = np.abs(nu) <= band
            if inside.all():
                self._run = 0
                return
            nu = np.where(inside, 0.0, nu - np.sign(nu) * band)
            r[inside] = _UNUSED_VARIANCE
        lam = np.exp(-dt / FORGETTING_TIME) if dt > 0 else 1.0
        p = self.P / lam
        s = np.outer(y, y) * p + np.diag(r)
        s_event = np.outer(y, y) * p + np.diag(r * self.event_variance_scale)
        chi2 = float(nu @ np.linalg.solve(s_event, nu))
        self._run = self._run + 1 if chi2 > EVENT_CHI2 else 0
        if self._run >= EVENT_TICKS:
            old = self.mass
            p = _RESET_STD ** 2
            self._run = 0
            # one step with the reset covariance moves the mass to the new load
            s = np.outer(y, y) * p + np.diag(r)
            k = p * np.linalg.solve(s, y)
            self.mass = self.mass + float(k @ nu)
            self.event = "pick" if self.mass > old else "release"
            self.event_time = time
            self.P = float(p - p * (k @ y))
            return
        k = p * np.linalg.solve(s, y)
        self.mass = self.mass + float(k @ nu)
        self.P = float(p - p * (k @ y))

    @property
    def std(self) -> float:
        """Std of the mass [kg]: the covariance and the offsets' floor."""
        y = self._last_y
        floor = 0.0
        if np.abs(y).max() >= _MIN_SENSITIVITY:
            w = y / self.R
            floor = float(np.sqrt(np.sum((w * self.bias_std) ** 2)) / (w @ y))
        return float(np.sqrt(self.P + floor ** 2))
