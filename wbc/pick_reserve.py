"""The pick reserve: plan for the largest load the operator may pick, until the pick is known.

A pick changes the machine's load in a fraction of a second, faster than the observer can
estimate the new mass (`estimators.observer.payload_rls`) and faster than the suspension can
move the load split. The operator's grapple command comes first: when the grapple closes, a
pick is coming. From then on the MPC's force constraint plans with the **rated payload** at
the crane's current pose and the chassis' current attitude (the load chart,
`models.load_chart.rated_payload`: the largest load the cylinders can hold there without a
wheel below the threshold, with the best split the suspension can set), so picking any rated
load keeps every wheel above the threshold. Once the observer has seen the pick and its
estimate has settled (std below `SETTLED_STD_KG`, at least `MIN_HOLD_SECONDS` after the
pick), the estimate takes over; with no pick within `TIMEOUT_SECONDS` of the grapple
command the reserve lapses (an empty grab).

The reserve enters the force constraint as a per-wheel shift: the extra mass ``dm`` (rated
less estimated) moves the wheel forces by ``S dm``, with ``S`` the equilibrium rows'
least-norm payload sensitivity at the pose [N/kg] (`RatedLoad.sensitivity`: the load change
spread over the wheels as the rigid chassis takes it, before the suspension moves the split;
the MPC then finds the split); each wheel whose force it lowers keeps ``-S dm`` more margin.
Simplification: the shift is static (the extra mass's effect on the planned accelerations is
left out) and constant over the horizon.
"""

from __future__ import annotations

import numpy as np

from models.description import Machine
from models.load_chart import rated_payload
from wbc.errors import ConfigurationError

__all__ = ["MIN_HOLD_SECONDS", "REFRESH_SECONDS", "SETTLED_STD_KG", "TIMEOUT_SECONDS",
           "PickReserve"]

REFRESH_SECONDS = 0.5  # [s] the rated payload is recomputed this often while armed (~4 ms)
SETTLED_STD_KG = 25.0  # [kg] the observer's estimate takes over below this std
MIN_HOLD_SECONDS = 0.5  # [s] the reserve holds at least this long after the pick is seen
TIMEOUT_SECONDS = 6.0  # [s] no pick seen this long after the grapple command: lapse


class PickReserve:
    """The extra payload the MPC plans with around a pick (module docstring).

    Args:
        machine: The machine description.
        threshold_n: The normal-force threshold the load chart keeps [N].
    """

    def __init__(self, machine: Machine, threshold_n: float):
        if not (np.isfinite(threshold_n) and threshold_n >= 0):
            raise ConfigurationError(f"threshold_n must be a finite force >= 0 [N], got "
                                     f"{threshold_n!r}")
        self.machine = machine
        self.threshold_n = float(threshold_n)
        self.rated = 0.0
        self.limit = ""
        self.sensitivity = np.zeros(4)
        self._armed_at: float | None = None
        self._picked_at: float | None = None
        self._rated_at = -np.inf

    @property
    def active(self) -> bool:
        """Whether the reserve is held."""
        return self._armed_at is not None

    def close_grapple(self, time: float) -> None:
        """The operator's grapple command at ``time`` [s]: a pick is coming."""
        self._armed_at = float(time)
        self._picked_at = None
        self._rated_at = -np.inf

    def update(self, time: float, q, base_rotation, payload_mass: float, payload_std: float,
               payload_event: str | None) -> np.ndarray:
        """One tick: the margin [N] (4,) the reserve adds to each wheel's threshold.

        Args:
            time: [s].
            q: Independent coordinates (13,) of the observed state.
            base_rotation: Observed attitude (world <- fb), (3, 3).
            payload_mass: The observer's estimate [kg].
            payload_std: Its std [kg].
            payload_event: The observer's event this tick (``pick``, ``release`` or None).
        """
        if self._armed_at is None:
            return np.zeros(4)
        if payload_event == "pick" and self._picked_at is None:
            self._picked_at = float(time)
        settled = (self._picked_at is not None and payload_std <= SETTLED_STD_KG
                   and time - self._picked_at >= MIN_HOLD_SECONDS)
        lapsed = self._picked_at is None and time - self._armed_at > TIMEOUT_SECONDS
        if settled or lapsed:
            self._armed_at = None
            return np.zeros(4)
        if time - self._rated_at >= REFRESH_SECONDS:
            r = rated_payload(self.machine, q, self.threshold_n, base_rotation)
            self.rated, self.limit, self._rated_at = r.mass, r.limit, float(time)
            self.sensitivity = r.sensitivity
        extra = max(self.rated - float(payload_mass), 0.0)
        return np.maximum(-self.sensitivity * extra, 0.0)
