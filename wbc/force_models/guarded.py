"""A force model made safe for the closed loop: valid strokes in, finite derivatives out.

Two things the raw estimator does that would make every tick fall back (both seen in
MuJoCo closed loops):

* it rejects a stroke outside its chain's valid range, and the MPC evaluates it at nominal
  states ahead (previous plan shifted) that can lie a little outside; MuJoCo's soft joint
  limits also let a measured stroke overshoot (slew 0.58 m against 0.56 m at long reach);
* with a wheel out of contact its compiled ``constraint_derivatives`` returns NaN in the
  columns of the two bogie strokes (``d f_z / d q``; the forces themselves are finite).

`GuardedModel` clips the strokes into their ranges before every call and replaces
non-finite derivative columns by central differences of ``estimate``.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from models.coordinates import N_INDEPENDENT
from models.description import Machine
from models.state import MachineState
from wbc.errors import ForceModelError
from wbc.force_models.protocol import NormalForceModel

__all__ = ["GuardedDerivatives", "GuardedModel"]

_FD_STEP = 1e-6  # [m, rad] and [m/s, rad/s]


@dataclass(frozen=True)
class GuardedDerivatives:
    """Same fields as the estimator's `ConstraintDerivatives` (see there)."""

    normal_forces: np.ndarray
    d_acceleration: np.ndarray
    d_q: np.ndarray
    d_qd: np.ndarray


class GuardedModel:
    """Wraps a `NormalForceModel`; see the module docstring.

    Args:
        model: The wrapped model (e.g. the estimator).
        machine: Its machine description (for the stroke ranges).

    Attributes:
        n_clipped: States whose strokes were clipped.
        n_repaired: Derivative evaluations whose non-finite columns were replaced.
    """

    def __init__(self, model: NormalForceModel, machine: Machine):
        self.model = model
        names = machine.coordinates.independent_names
        self._lower = np.full(N_INDEPENDENT, -np.inf)
        self._upper = np.full(N_INDEPENDENT, np.inf)
        for i, name in enumerate(names):
            if name in machine.chains:
                self._lower[i], self._upper[i] = machine.chains[name].chain.stroke_range
        self.n_clipped = 0
        self.n_repaired = 0

    def __getattr__(self, name):  # the wrapped model's other attributes (method, fourth...)
        return getattr(self.model, name)

    def _valid(self, state: MachineState) -> MachineState:
        q = np.clip(state.q, self._lower, self._upper)
        if np.array_equal(q, state.q):
            return state
        self.n_clipped += 1
        return replace(state, q=q)

    def estimate(self, state: MachineState):
        """The wrapped model's estimate at the clipped state."""
        return self.model.estimate(self._valid(state))

    def constraint(self, state: MachineState) -> tuple[np.ndarray, np.ndarray]:
        """The wrapped model's (G, g0) at the clipped state."""
        return self.model.constraint(self._valid(state))

    def constraint_derivatives(self, state: MachineState):
        """The wrapped model's derivatives; non-finite columns by central differences.

        Raises:
            ForceModelError: A column stays non-finite.
        """
        st = self._valid(state)
        d = self.model.constraint_derivatives(st)
        dq = getattr(d, "d_q", None)
        dqd = getattr(d, "d_qd", None)
        if dq is None or dqd is None or (np.isfinite(dq).all() and np.isfinite(dqd).all()):
            return d
        self.n_repaired += 1
        dq, dqd = np.array(dq, float), np.array(dqd, float)
        for name, arr in (("q", dq), ("qd", dqd)):
            for j in np.flatnonzero(~np.isfinite(arr).all(axis=0)):
                arr[:, j] = self._central_difference(st, name, j)
        if not (np.isfinite(dq).all() and np.isfinite(dqd).all()):
            raise ForceModelError(f"force model derivatives stay non-finite at "
                                  f"t={state.time:.3f} s")
        return GuardedDerivatives(np.asarray(d.normal_forces, float),
                                  np.asarray(d.d_acceleration, float), dq, dqd)

    def _central_difference(self, state: MachineState, name: str, j: int) -> np.ndarray:
        x = getattr(state, name)
        lo, hi = -_FD_STEP, _FD_STEP
        if name == "q":  # stay inside the stroke range
            lo = max(lo, self._lower[j] - x[j])
            hi = min(hi, self._upper[j] - x[j])
        if hi - lo <= 0:
            return np.zeros(4)
        vals = []
        for step in (lo, hi):
            v = x.copy()
            v[j] += step
            vals.append(np.asarray(self.model.estimate(replace(state, **{name: v}))
                                   .normal_forces, float))
        return (vals[1] - vals[0]) / (hi - lo)
