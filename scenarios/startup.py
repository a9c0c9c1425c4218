"""Start-up: the operator's commands wait until the machine stands on all four wheels.

A machine placed on rough ground can stand with a wheel unloaded. Before the operator's
commands start, the controller holds the crane and (the MPC) levels the chassis through the
suspension; the run is *ready* once the machine's own estimate of the four normal forces (the
cylinder-force closure on the state the controller sees, not MuJoCo's contacts) has stayed
above `READY_FACTOR` times the threshold for `READY_HOLD_SECONDS`, at the earliest after
`models.log.SETTLE_SECONDS`, at the latest after `READY_TIMEOUT_SECONDS` (then it starts
anyway and the run reports ``ready_timed_out``). The scenario's clock (goals, driving,
payload events) starts at the ready time, and the safety metrics count from there.
"""

from __future__ import annotations

import numpy as np

from models.description import Machine
from models.log import SETTLE_SECONDS
from models.state import MachineState
from wbc.force_models.estimator import load_closure

__all__ = ["READY_FACTOR", "READY_HOLD_SECONDS", "READY_TIMEOUT_SECONDS", "Readiness"]

READY_FACTOR = 1.5  # of the threshold, every wheel
# Longer than the chassis' rocking between its diagonals on rough ground (about 0.3 s,
# development draw random 119 of master seed 1), so that a rocking machine is not ready while
# one diagonal is loaded.
READY_HOLD_SECONDS = 0.5
READY_TIMEOUT_SECONDS = 5.0


class Readiness:
    """Decides when the run is ready (module docstring).

    Args:
        machine: The machine.
        threshold_n: The normal-force threshold [N].
    """

    def __init__(self, machine: Machine, threshold_n: float):
        self._estimator = load_closure(machine, "full")
        self._level = READY_FACTOR * float(threshold_n)
        self._since: float | None = None
        self.time: float | None = None
        self.timed_out = False

    def set_payload(self, mass: float) -> None:
        """The payload the machine believes it holds [kg] (the estimate's run-time input)."""
        self._estimator.payload_mass = mass

    def update(self, state: MachineState) -> bool:
        """Take the state the controller sees at a tick; True once ready (and after)."""
        if self.time is not None:
            return True
        t = state.time
        f = np.asarray(self._estimator.estimate(state).normal_forces, float)
        if np.all(f > self._level):
            self._since = t if self._since is None else self._since
        else:
            self._since = None
        held = self._since is not None and t - self._since >= READY_HOLD_SECONDS - 1e-9
        if t >= SETTLE_SECONDS - 1e-9 and held:
            self.time = t
        elif t >= READY_TIMEOUT_SECONDS - 1e-9:
            self.time, self.timed_out = t, True
        return self.time is not None

    @property
    def offset(self) -> float:
        """How much later than planned the scenario's clock started [s] (0 until ready).

        The scenario files time their events from a run start whose first
        `models.log.SETTLE_SECONDS` are for settling: a run ready at once keeps them.
        """
        return 0.0 if self.time is None else max(self.time - SETTLE_SECONDS, 0.0)
