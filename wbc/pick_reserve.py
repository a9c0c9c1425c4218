"""The pick reserve: plan for the largest load the operator may pick, until the pick is known.

A pick changes the machine's load in a fraction of a second, faster than the observer can
estimate the new mass (`estimators.observer.payload_rls`) and faster than the suspension can
move the load split. The operator's grapple command comes first: when the grapple closes, a
pick is coming. From then on the MPC's force constraint plans with the **rated payload** at
the crane's pose and the chassis' attitude of that moment (the load chart,
`models.load_chart.rated_payload`: the largest load the cylinders can hold there with every
wheel above the threshold plus the controller's other margins, with the best split the
suspension can set), so picking any rated load keeps every wheel above them. The rating is
read once, at the grapple command (the pick's pose): read again as the crane moves, a
tipping-limited rating would grow as the MPC pulls the load in, and the reserve would chase
it. Its margin rises over `RAMP_SECONDS` (a step in the demand made the MPC swing the
suspension). Once the observer has seen the pick (its ``pick`` event, or its estimate
`PICK_SEEN_KG` above the estimate at the grapple command: a load taken up gradually raises no
event) and its estimate has settled (std below `SETTLED_STD_KG`, at least `MIN_HOLD_SECONDS`
after the pick), the estimate takes over; with no pick within `TIMEOUT_SECONDS` of the grapple
command the reserve lapses (an empty grab).

The reserve enters the force constraint as a per-wheel shift: the extra mass ``dm`` (rated
less estimated) moves the wheel forces by ``S dm``, with ``S`` the equilibrium rows'
least-norm payload sensitivity [N/kg] (`RatedLoad.sensitivity`: the load change spread over
the wheels as the rigid chassis takes it, before the suspension moves the split; the MPC then
finds the split), read again every `REFRESH_SECONDS` at the current pose (pulling the crane
in shrinks it); each wheel whose force it lowers keeps ``-S dm`` more margin.
Simplification: the shift is static (the extra mass's effect on the planned accelerations is
left out) and constant over the horizon.
"""

from __future__ import annotations

import numpy as np

from models.description import Machine
from models.load_chart import rated_payload
from wbc.errors import ConfigurationError

__all__ = ["MIN_HOLD_SECONDS", "RAMP_SECONDS", "REFRESH_SECONDS", "PICK_SEEN_KG",
           "SETTLED_STD_KG", "TIMEOUT_SECONDS", "PickReserve"]

RAMP_SECONDS = 0.5  # [s] the reserve's margin rises over this time (no step in the demand)
REFRESH_SECONDS = 0.5  # [s] the sensitivity is recomputed this often while armed (~4 ms)
SETTLED_STD_KG = 25.0  # [kg] the observer's estimate takes over below this std
MIN_HOLD_SECONDS = 0.5  # [s] the reserve holds at least this long after the pick is seen
PICK_SEEN_KG = 50.0  # [kg] an estimate this far above its value at the grapple command: picked
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
        self._armed_mass: float | None = None  # the estimate at the grapple command
        self._picked_at: float | None = None
        self._rated_at = -np.inf

    @property
    def active(self) -> bool:
        """Whether the reserve is held."""
        return self._armed_at is not None

    def close_grapple(self, time: float) -> None:
        """The operator's grapple command at ``time`` [s]: a pick is coming."""
        self._armed_at = float(time)
        self._armed_mass = None
        self._picked_at = None
        self._rated_at = -np.inf

    def update(self, time: float, q, base_rotation, payload_mass: float, payload_std: float,
               payload_event: str | None, margin=None) -> np.ndarray:
        """One tick: the margin [N] (4,) the reserve adds to each wheel's threshold.

        Args:
            time: [s].
            q: Independent coordinates (13,) of the observed state.
            base_rotation: Observed attitude (world <- fb), (3, 3).
            payload_mass: The observer's estimate [kg].
            payload_std: Its std [kg].
            payload_event: The observer's event this tick (``pick``, ``release`` or None).
            margin: The controller's other per-wheel margins [N] (4,) (its uncertainty),
                kept on top of the threshold by the rating too; None: none.
        """
        if self._armed_at is None:
            return np.zeros(4)
        if self._armed_mass is None:  # the first tick after the grapple command
            self._armed_mass = float(payload_mass)
        if self._picked_at is None and (
                payload_event == "pick"
                or payload_mass - self._armed_mass > PICK_SEEN_KG):
            self._picked_at = float(time)
        settled = (self._picked_at is not None and payload_std <= SETTLED_STD_KG
                   and time - self._picked_at >= MIN_HOLD_SECONDS)
        lapsed = self._picked_at is None and time - self._armed_at > TIMEOUT_SECONDS
        if settled or lapsed:
            self._armed_at = None
            return np.zeros(4)
        if time - self._rated_at >= REFRESH_SECONDS:
            keep = self.threshold_n + (np.zeros(4) if margin is None
                                       else np.asarray(margin, float))
            r = rated_payload(self.machine, q, keep, base_rotation)
            if self._rated_at == -np.inf:  # the pick's pose: the rating holds till the pick
                self.rated, self.limit = r.mass, r.limit
            self._rated_at = float(time)
            self.sensitivity = r.sensitivity
        extra = max(self.rated - float(payload_mass), 0.0)
        ramp = min((time - self._armed_at) / RAMP_SECONDS, 1.0)
        return ramp * np.maximum(-self.sensitivity * extra, 0.0)
