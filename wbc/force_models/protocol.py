"""The interface the controller needs from a wheel normal-force model: one typed seam.

The estimator of the `estimators` package (`NormalForceEstimator`) satisfies it, and so do
the test doubles of `testkit.force_models`. The controller consumes exactly one type from
the model, `estimators.linearization.ForceLinearization`: the forces exactly affine in the
generalized accelerations (paper eqs. 20-28 are linear in the accelerations once the
configuration and the velocities are fixed) and their sensitivities to the configuration
and the velocities, used to predict the forces along the MPC horizon::

    f_z(q + dq, qd + dqd, a) ~= g0 + G a + d_q dq + d_qd dqd,
    a = [base_acceleration (6), qdd (13)].

Besides, ``estimate`` gives the forces and contact flags alone (the contact flags of a
state without measured contacts, and the closure feedback).
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np

from estimators.errors import EstimatorError
from estimators.linearization import ForceLinearization
from models.state import MachineState
from wbc.errors import ForceModelError

__all__ = ["MODEL_ERRORS", "NormalForceEstimate", "NormalForceModel", "contact_flags",
           "linearize_forces", "linearize_nodes", "linearized_contact_flags"]

# What a force model may raise at a state it cannot evaluate (singular system, stroke out
# of range under the "raise" policy, a non-finite linearization): the loop falls back.
MODEL_ERRORS = (EstimatorError, ArithmeticError, np.linalg.LinAlgError)


@runtime_checkable
class NormalForceEstimate(Protocol):
    """What `NormalForceModel.estimate` returns (attributes only)."""

    normal_forces: np.ndarray  # [N], shape (4,), order FL, RL, FR, RR
    in_contact: np.ndarray  # shape (4,), bool


@runtime_checkable
class NormalForceModel(Protocol):
    """A wheel normal-force model usable as a QP constraint."""

    def estimate(self, state: MachineState) -> NormalForceEstimate:
        """Normal forces [N] and contact flags at ``state``."""
        ...

    def linearize(self, state: MachineState) -> ForceLinearization:
        """The forces, ``G`` (4, 19), ``g0`` (4,), ``d_q`` and ``d_qd`` (4, 13) at ``state``.

        Its ``in_contact`` are ``estimate(state).in_contact`` (`linearized_contact_flags`).
        """
        ...


def _failure(state: MachineState, exc: Exception) -> ForceModelError:
    return ForceModelError(f"force model failed at t={state.time:.3f} s: "
                           f"{type(exc).__name__}: {exc}")


def linearize_forces(model: NormalForceModel, state: MachineState) -> ForceLinearization:
    """``model.linearize(state)``, its failures turned into `ForceModelError`.

    Raises:
        ForceModelError: The model raised one of `MODEL_ERRORS` (for example a singular
            system, or a non-finite array, which `ForceLinearization` refuses), or returned
            something other than a `ForceLinearization`.
    """
    try:
        lin = model.linearize(state)
    except MODEL_ERRORS as exc:  # the model's own failure at this state: the loop falls back
        raise _failure(state, exc) from exc
    if not isinstance(lin, ForceLinearization):
        raise ForceModelError(f"force model returned a {type(lin).__name__}, expected an "
                              f"estimators.linearization.ForceLinearization")
    return lin


def linearize_nodes(model, state: MachineState, dt: np.ndarray, q_head: np.ndarray,
                    qd_head: np.ndarray) -> tuple[ForceLinearization, np.ndarray | None]:
    """``model.linearize_nodes(...)`` (`estimators.payload.PayloadEstimator`), failures typed.

    A model's optional fast path for a horizon: `linearize_forces` of ``state`` and the
    kernel rows of the states after it (or None: they go one by one), in one call.

    Raises:
        ForceModelError: As `linearize_forces`.
    """
    try:
        lin, rows = model.linearize_nodes(state, dt, q_head, qd_head)
    except MODEL_ERRORS as exc:
        raise _failure(state, exc) from exc
    if not isinstance(lin, ForceLinearization):
        raise ForceModelError(f"force model returned a {type(lin).__name__}, expected an "
                              f"estimators.linearization.ForceLinearization")
    return lin, rows


def contact_flags(model: NormalForceModel, state: MachineState) -> np.ndarray:
    """Wheels in contact, shape (4,) bool.

    The state's measured flags if it has them, else the model's `estimate(state).in_contact`.

    Raises:
        ForceModelError: The model raised one of `MODEL_ERRORS`, or gave flags of a wrong
            shape.
    """
    if state.contacts is not None:
        return np.asarray(state.contacts.in_contact, dtype=bool).reshape(4)
    try:
        flags = np.asarray(model.estimate(state).in_contact)
    except MODEL_ERRORS as exc:
        raise _failure(state, exc) from exc
    if flags.shape != (4,):
        raise ForceModelError(f"force model returned in_contact of shape {flags.shape}, "
                              f"expected (4,)")
    return flags.astype(bool)


def linearized_contact_flags(state: MachineState, lin: ForceLinearization) -> np.ndarray:
    """`contact_flags` of ``state`` read from the model's linearization ``lin`` at ``state``.

    The state's measured flags if it has them, else ``lin.in_contact``: a model linearizes
    with the flags its `estimate` gives at the same state (`NormalForceModel.linearize`), so
    a caller that linearizes at ``state`` anyway needs no estimate for them.
    """
    if state.contacts is not None:
        return np.asarray(state.contacts.in_contact, dtype=bool).reshape(4)
    return lin.in_contact
