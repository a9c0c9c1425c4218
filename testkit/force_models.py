"""A synthetic, exactly affine normal-force model: a test double and a benchmark stand-in.

    f_z = f_static + K (q - q_ref) + G a,    a = [base_acceleration (6), qdd (13)].

It is *not* a physical model; it has the interface of `wbc.force_models.NormalForceModel`
and simple, controllable sensitivities, so that tests can say beforehand which constraint
must bind.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from estimators.linearization import N_GENERALIZED, ForceLinearization
from models.coordinates import N_INDEPENDENT
from models.description import Machine
from models.state import MachineState

__all__ = ["AffineForceEstimate", "AffineForceModel"]


@dataclass(frozen=True)
class AffineForceEstimate:
    """Normal forces [N] (4,) and contact flags (4,), order FL, RL, FR, RR."""

    normal_forces: np.ndarray
    in_contact: np.ndarray


class AffineForceModel:
    """``f_z = f_static + K (q - q_ref) + G a`` with constant K and G.

    Args:
        f_static: Forces at ``q_ref`` at rest [N], shape (4,).
        q_ref: Reference configuration, shape (13,).
        K: ``df_z/dq`` [N/m, N/rad], shape (4, 13).
        G: ``df_z/da`` [N per m/s^2 or rad/s^2], shape (4, 19).
        in_contact: Fixed contact flags, shape (4,); None: in contact while f_z > 0.
    """

    def __init__(self, f_static, q_ref, K=None, G=None, in_contact=None):
        self.f_static = np.asarray(f_static, float).reshape(4)
        self.q_ref = np.asarray(q_ref, float).reshape(N_INDEPENDENT)
        self.K = (np.zeros((4, N_INDEPENDENT)) if K is None
                  else np.asarray(K, float).reshape(4, N_INDEPENDENT))
        self.G = (np.zeros((4, N_GENERALIZED)) if G is None
                  else np.asarray(G, float).reshape(4, N_GENERALIZED))
        self.in_contact = None if in_contact is None else np.asarray(in_contact, bool)
        self.calls = 0  # number of model evaluations (for tests of the linearization count)

    @classmethod
    def reference(cls, machine: Machine, q_ref) -> AffineForceModel:
        """Plausible sensitivities for the reference machine (crane pointing forward).

        Extending the telescope or lowering the boom moves load from the rear to the front
        wheels; slewing (stroke increase) moves it from the right to the left; accelerating
        the telescope outward unloads the rear wheels. Magnitudes are rough statics of the
        ~800 kg boom end and payload over a 2.3 m wheelbase.
        """
        w = machine.total_mass * machine.gravity / 4
        K = np.zeros((4, N_INDEPENDENT))
        front, rear, left, right = [0, 2], [1, 3], [0, 1], [2, 3]
        K[front, 5] += 1800.0   # telescope [N/m]
        K[rear, 5] -= 1800.0
        K[front, 3] -= 2500.0   # lift stroke raises the boom: load back to the rear
        K[rear, 3] += 2500.0
        K[left, 2] += 3000.0    # slew stroke
        K[right, 2] -= 3000.0
        K[[0, 3], 0] += 1500.0  # suspension: diagonal load transfer
        K[[1, 2], 0] -= 1500.0
        K[[2, 1], 1] += 1500.0
        K[[3, 0], 1] -= 1500.0
        G = np.zeros((4, N_GENERALIZED))
        G[front, 6 + 5] += 350.0
        G[rear, 6 + 5] -= 350.0
        G[front, 0] += 400.0    # base deceleration (negative x acceleration) unloads front
        G[rear, 0] -= 400.0
        G[:, 2] += machine.total_mass / 4
        return cls(np.full(4, w), q_ref, K, G)

    def _g0(self, state: MachineState) -> np.ndarray:
        return self.f_static + self.K @ (state.q - self.q_ref)

    def estimate(self, state: MachineState) -> AffineForceEstimate:
        """Forces at the state's accelerations; contact while the force is positive."""
        self.calls += 1
        a = np.concatenate([state.base_acceleration, state.qdd])
        f = self.G @ a + self._g0(state)
        flags = f > 0.0 if self.in_contact is None else self.in_contact.copy()
        return AffineForceEstimate(f, flags)

    def linearize(self, state: MachineState) -> ForceLinearization:
        """``G``, ``g0 = f_static + K (q - q_ref)``, ``d_q = K``, ``d_qd = 0`` at ``state``."""
        self.calls += 1
        a = np.concatenate([state.base_acceleration, state.qdd])
        g0 = self._g0(state)
        f = self.G @ a + g0
        flags = f > 0.0 if self.in_contact is None else self.in_contact.copy()
        return ForceLinearization(f, self.G, g0, self.K, np.zeros((4, N_INDEPENDENT)), flags,
                                  "d-beta", (), state.time)
